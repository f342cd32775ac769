"""The [-1, 1] mapping of a register's legal range that envs and tuners share."""

import math

import pytest
from hypothesis import given
from hypothesis import strategies as st

from servogym.chips import ParameterError, ParamSpec
from servogym.chips._space import ZERO_FRACTION

GAIN = ParamSpec("kp", 0, 32767, 100, "u16", log=True)
DTIME = ParamSpec("derivative_time", 1, 32767, 10, "u16", log=True)
BIAS = ParamSpec("bias", -32768, 32767, 0, "s16")


@pytest.mark.parametrize("spec", [GAIN, DTIME, BIAS])
@given(u=st.floats(-1.0, 1.0))
def test_every_unit_value_maps_to_a_legal_integer(spec, u):
    v = spec.from_unit(u)
    assert isinstance(v, int) and spec.low <= v <= spec.high


def test_ends_and_zero_are_reachable():
    assert GAIN.from_unit(-1.0) == 0 and GAIN.from_unit(1.0) == 32767
    # The lowest 5 % of [0, 1] switches a log-scaled gain off; just above it gives 1.
    assert GAIN.from_unit(2 * ZERO_FRACTION - 1 - 1e-9) == 0
    assert GAIN.from_unit(2 * ZERO_FRACTION - 1) == 1
    assert DTIME.from_unit(-1.0) == 1 and DTIME.from_unit(1.0) == 32767
    assert BIAS.from_unit(-1.0) == -32768 and BIAS.from_unit(1.0) == 32767
    assert BIAS.from_unit(0.0) == 0  # round(-32768 + 0.5 * 65535) = round(-0.5) = 0


def test_log_scale_is_log_uniform():
    # The midpoint of the log part of the interval is the geometric mean of 1 and 32767.
    mid = 2 * (ZERO_FRACTION + (1 - ZERO_FRACTION) / 2) - 1
    assert GAIN.from_unit(mid) == round(math.sqrt(32767))
    assert DTIME.from_unit(0.0) == round(math.sqrt(32767))


@pytest.mark.parametrize("spec", [GAIN, DTIME, BIAS])
@pytest.mark.parametrize("value", [0, 1, 2, 7, 100, 999, 12345, 32767, -5, -32768])
def test_to_unit_inverts_from_unit(spec, value):
    if not spec.low <= value <= spec.high:
        return
    assert spec.from_unit(spec.to_unit(value)) == value


@pytest.mark.parametrize("u", [1.5, -1.0001, math.nan, math.inf, "0.5", None])
def test_out_of_range_actions_are_refused(u):
    with pytest.raises(
        ParameterError, match=r"the action for kp must be a finite number in \[-1, 1\]"
    ):
        GAIN.from_unit(u)


def test_signed_log_gain_is_off_at_the_bottom():
    signed = ParamSpec("ixx30", -8388608, 8388607, 2000, "s24", log=True)
    assert signed.from_unit(-1.0) == 0
    assert signed.from_unit(1.0) == 8388607
    assert signed.from_unit(signed.to_unit(2000)) == 2000
