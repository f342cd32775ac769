"""The unit-interval mapping of a register (``ParamSpec.from_unit``): midpoints and spread.

Linear registers: ``round(low + t (high - low))`` with ``t = (u + 1) / 2``, Python's
``round`` (halves to even). Over a uniform ``u`` every interior value gets an equal share of
the interval and the two end values half a share each. Log-scaled gains: the lowest
:data:`ZERO_FRACTION` gives 0, the rest is log-uniform over ``max(low, 1)..high``.
"""

from __future__ import annotations

import math
from collections import Counter

import numpy as np
import pytest

from servogym.chips import ParamSpec
from servogym.chips._space import ZERO_FRACTION

FIVE = ParamSpec("five", 0, 4, 0, "u3")
SIGNED = ParamSpec("signed", -2, 2, 0, "s3")
GAIN = ParamSpec("kp", 0, 32767, 100, "u16", log=True)


def grid(n: int) -> np.ndarray:
    """``n`` cell midpoints of [-1, 1]: a uniform u that never lands on a tie."""
    return -1.0 + (np.arange(n) + 0.5) * (2.0 / n)


@pytest.mark.parametrize("spec", [FIVE, SIGNED], ids=["0..4", "-2..2"])
def test_linear_midpoints_round_half_to_even(spec):
    # u = -0.75, -0.25, 0.25, 0.75 give t = 1/8, 3/8, 5/8, 7/8 and low + 4t = low + 0.5,
    # low + 1.5, low + 2.5, low + 3.5 exactly (binary fractions). Halves go to the even
    # neighbour: 0..4 -> 0, 2, 2, 4; -2..2 -> -1.5, -0.5, 0.5, 1.5 -> -2, 0, 0, 2.
    got = [spec.from_unit(u) for u in (-0.75, -0.25, 0.25, 0.75)]
    lo = spec.low
    assert got == [lo, lo + 2, lo + 2, lo + 4]
    # Just either side of a midpoint: the nearer value.
    assert spec.from_unit(-0.75 - 1e-9) == lo and spec.from_unit(-0.75 + 1e-9) == lo + 1
    assert spec.from_unit(0.25 + 1e-9) == lo + 3 and spec.from_unit(0.25 - 1e-9) == lo + 2


@pytest.mark.parametrize("spec", [FIVE, SIGNED], ids=["0..4", "-2..2"])
def test_linear_spread_is_even_inside_and_half_at_the_ends(spec):
    # Value k takes u with |4t - k| < 1/2: a quarter of t's range inside, an eighth at each
    # end. 8000 cell midpoints: 1000, 2000, 2000, 2000, 1000.
    counts = Counter(spec.from_unit(float(u)) for u in grid(8000))
    assert [counts[spec.low + k] for k in range(5)] == [1000, 2000, 2000, 2000, 1000]
    # to_unit gives the centre of a value's share: t = k / 4.
    assert [spec.to_unit(spec.low + k) for k in range(5)] == [-1.0, -0.5, 0.0, 0.5, 1.0]


def test_wide_linear_register_reaches_every_value_in_order():
    # s16 bias: 65536 values, 2^17 cell midpoints: each interior value twice, the ends once
    # (their half share), and the mapping never decreases.
    bias = ParamSpec("bias", -32768, 32767, 0, "s16")
    values = [bias.from_unit(float(u)) for u in grid(2 * 65535)]
    counts = Counter(values)
    assert len(counts) == 65536
    assert counts[-32768] == counts[32767] == 1
    assert all(counts[v] == 2 for v in range(-32767, 32767))
    assert values == sorted(values)


def test_log_spread_zero_share_and_geometric_middle():
    # The lowest ZERO_FRACTION (5 %) of the interval gives 0: 1000 of 20000 cell midpoints.
    values = np.array([GAIN.from_unit(float(u)) for u in grid(20000)])
    assert int((values == 0).sum()) == round(ZERO_FRACTION * 20000)
    assert np.all(np.diff(values) >= 0)
    # The first midpoint past the zero zone gives 1 (log position ~0); the top needs u = 1.
    assert values[1000] == 1 and GAIN.from_unit(1.0) == 32767
    # Above it, log-uniform over 1..32767: round(v) <= 181 iff v < 181.5, i.e. a share
    # ln(181.5) / ln(32767) = 0.500254 of the log part: 0.05 + 0.95 * 0.500254 = 0.525241.
    share = float((values <= 181).mean())
    assert share == pytest.approx(0.05 + 0.95 * math.log(181.5) / math.log(32767), abs=1e-4)
    # A value's to_unit is the u of its exact log position; 0 sits mid-way in its zone.
    assert GAIN.to_unit(0) == pytest.approx(-0.95)
    assert GAIN.to_unit(1) == pytest.approx(2 * ZERO_FRACTION - 1)
    assert GAIN.to_unit(32767) == pytest.approx(1.0)


def test_single_value_register():
    one = ParamSpec("one", 7, 7, 7, "u3")
    assert one.from_unit(-1.0) == one.from_unit(0.3) == one.from_unit(1.0) == 7
    assert one.to_unit(7) == -1.0


def test_unknown_name_suggests_at_most_three_close_matches():
    from servogym.chips import ParameterError
    from servogym.chips._space import resolve_name

    known = ["XA", "XB", "XC", "XD"]  # every one as close to "X" as the others
    assert resolve_name("xb", known, "model") == "XB"
    with pytest.raises(ParameterError, match=r"Did you mean X., X., X.\?$"):
        resolve_name("X", known, "model")


def test_log_register_with_a_low_above_one():
    # low 10, high 1000: log-uniform over 10..1000, no zero zone. u = 0 is t = 1/2, the
    # geometric middle 100; to_unit(100) = 2 * 1/2 - 1 = 0; to_unit(10) = -1.
    spec = ParamSpec("x", 10, 1000, 100, "u16", log=True)
    assert spec.from_unit(0.0) == 100 and spec.from_unit(-1.0) == 10
    assert spec.to_unit(100) == pytest.approx(0.0, abs=1e-12)
    assert spec.to_unit(10) == -1.0


def test_param_specs_are_frozen_and_unknown_registers_get_three_suggestions():
    import dataclasses

    from servogym.chips import ParameterError
    from servogym.chips._space import ParameterSpace

    with pytest.raises(dataclasses.FrozenInstanceError):
        FIVE.high = 5
    space = ParameterSpace("M", [ParamSpec(n, 0, 1, 0, "u1") for n in ("ka", "kb", "kc", "kd")])
    with pytest.raises(ParameterError, match=r"Did you mean k., k., k.\?$"):
        space["k"]
