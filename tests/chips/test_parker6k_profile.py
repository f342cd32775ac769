"""Parker 6000 profiles: a hand-computed trapezoid from docs/chips/parker6k.md, properties."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from servogym.chips import ParameterError
from servogym.chips._family import Move
from servogym.chips.parker6k import PARKER6K, ProfileAssumptions, profile_move
from servogym.chips.parker6k._profile import period_steps, ssfr_of

S32_MIN, S32_MAX = -(2**31), 2**31 - 1


def test_hand_computed_trapezoid():
    # SSFR4: servo 160 us, trajectory period Tt = 640 us. V = 1e4 counts/s -> 6.4e6
    # micro-counts per period; A = 1e6 counts/s^2 -> 1e6 * 640^2 / 1e6 = 409,600 per period^2.
    # D = 10 counts = 1e7: m = min(6.4e6 // 409600 = 15, isqrt(1e7 // 409600 = 24) = 4) = 4;
    # ramp 409600 .. 1638400 (A*m*m = 6,553,600), rest 3,446,400 = 2 cruise periods of
    # 1,638,400 + remainder 169,600, inserted after the ramp down's last step (it is smaller).
    a = 409_600
    steps = [a, 2 * a, 3 * a, 4 * a, 4 * a, 4 * a, 3 * a, 2 * a, a, 169_600, 0]
    assert period_steps(10_000_000, 6_400_000, a).tolist() == steps
    p = profile_move(0, 10, 1e4, 1e6, 4, settle_ticks=3)
    assert p.move_ticks == 44 and p.n_ticks == 47 and p.start == 0 and p.ssfr == 4
    # Linear interpolation: sample i of period j is at P_{j-1} + step_j * i / 4 (floor).
    # Period 1: 409600 * i / 4 < 1e6 -> 0; period 2: (1638400 + 819200 i) / 4e6 -> 0, 0, 1, 1.
    assert p.position[:8].tolist() == [0, 0, 0, 0, 0, 0, 1, 1]
    assert p.position[-4:].tolist() == [10] * 4
    # Velocity: step / 640 us: 640, 1280, ..., 2560 counts/s; remainder 169600 / 640 = 265.
    assert p.velocity[:44:4].tolist() == [
        640,
        1280,
        1920,
        2560,
        2560,
        2560,
        1920,
        1280,
        640,
        265,
        0,
    ]
    # Acceleration: change * 1e6 / 640^2: 409600 -> 1e6; -240000 -> -585937.5 -> -585938;
    # -169600 -> -414062.5 -> -414063 (halves away from 0).
    assert p.acceleration[:44:4].tolist() == [10**6] * 4 + [0, 0] + [-(10**6)] * 3 + [
        -585938,
        -414063,
    ]
    assert not p.velocity[44:].any() and not p.acceleration[44:].any()


def test_hold_and_nearest_and_negative_moves():
    hold = profile_move(100, 10, 1e4, 1e6, 4, assumptions=ProfileAssumptions("hold"))
    # Held at the newest trajectory point: P_1 = 409600 -> 0; P_2 = 1228800 -> 1 (+100).
    assert hold.position[:8].tolist() == [100] * 4 + [101] * 4
    near = profile_move(0, -10, 1e4, 1e6, 4, assumptions=ProfileAssumptions("linear", "nearest"))
    # Nearest on the distance travelled: period 2, i = 2: 0.82 -> 1; a negative move.
    assert near.position[:8].tolist() == [0, 0, 0, 0, -1, -1, -1, -1]
    assert near.velocity[0] == -640 and near.acceleration[0] == -(10**6)
    assert near.position[-1] == -10


def test_wrap_and_zero_distance():
    p = profile_move(S32_MAX - 2, 10, 1e5, 1e7, 1)
    assert p.position[-1] == S32_MIN + 7
    travelled = ((p.position - (S32_MAX - 2) - S32_MIN) % 2**32) + S32_MIN
    assert (np.diff(travelled) >= 0).all() and travelled[-1] == 10
    z = profile_move(5, 0, 1e5, 1e7, 8, settle_ticks=2)
    assert z.position.tolist() == [5] * 10 and z.move_ticks == 8


@st.composite
def move_args(draw):
    ssfr = draw(st.sampled_from([1, 2, 4, 8]))
    v = draw(st.floats(1e2, 1e7))
    a = draw(st.floats(1e4, 1e9))
    reach = int(min(200_000, v * 0.5 + a * 0.01))  # moves of at most about half a second
    dist = draw(st.integers(-reach, reach))
    start = draw(st.integers(S32_MIN, S32_MAX))
    asm = ProfileAssumptions(
        draw(st.sampled_from(["linear", "hold"])), draw(st.sampled_from(["floor", "nearest"]))
    )
    kind = draw(st.sampled_from(["trapezoidal", "s_curve"]))
    jerk = draw(st.floats(a * 10, a * 1e4)) if kind == "s_curve" else None
    return start, dist, v, a, ssfr, kind, jerk, asm


@settings(max_examples=100, deadline=None)
@given(move_args())
def test_profile_properties(args):
    start, dist, v, a, ssfr, kind, jerk, asm = args
    try:
        p = profile_move(
            start, dist, v, a, ssfr, kind=kind, jerk_counts_per_s3=jerk, assumptions=asm
        )
    except ParameterError as exc:
        assert "servo samples" in str(exc)  # too long for MAX_TICKS
        return
    target = ((start + dist - S32_MIN) % 2**32) + S32_MIN
    assert p.position[-1] == target and p.velocity[-1] == 0
    assert p.n_ticks == p.move_ticks and p.n_ticks % ssfr == 0
    travelled = ((p.position - start - S32_MIN) % 2**32) + S32_MIN
    sign = 1 if dist >= 0 else -1
    assert (np.diff(sign * travelled, prepend=0) >= 0).all()  # never backwards
    assert (sign * travelled <= abs(dist)).all()
    # Within the limits (rounded to whole counts/s and counts/s^2, plus the remainder step).
    assert np.abs(p.velocity).max() <= v + 1
    tt = ssfr * {1: 330, 2: 185, 4: 160, 8: 150}[ssfr]
    # PK-P1 rounds the limit to the nearest micro-count/period^2 (+0.5); the S-curve's floored
    # moving average (PK-P6) moves a second difference by less than 2 more; the report
    # rounds to the nearest count/s^2 (+0.5, within the +1).
    slack = (1.0 if kind == "trapezoidal" else 2.5) * 1e6 / tt**2
    assert np.abs(p.acceleration).max() <= a + slack + 1
    assert (np.sign(p.velocity) * sign >= 0).all()


def test_family_profile_picks_ssfr_from_the_period():
    m = Move(50_000, 2e5, 5e6, settle_s=0.016)
    for ssfr, t in {1: 330e-6, 2: 185e-6, 4: 160e-6, 8: 150e-6}.items():
        p = PARKER6K.profile(m, t)
        assert p.ssfr == ssfr == ssfr_of(t)
        assert p.position[-1] == 50_000 and p.n_ticks == p.move_ticks + round(0.016 / t)
    s = PARKER6K.profile(Move(-5000, 2e5, 5e6, kind="s_curve", jerk_counts_per_s3=1e9), 160e-6)
    assert s.position[-1] == -5000
    # L = floor(0.5 + 5e6 * 1e6 / (1e9 * 640)) = 8 periods: the acceleration ramps in steps
    # of 5e6 / 8 = 625,000 counts/s^2 per period and never exceeds the limit; where the
    # trapezoid turns from +A straight to -A (this short move has no cruise), 2A / 8.
    assert s.acceleration[0] == -625_000 and np.abs(s.acceleration).max() <= 5e6
    assert np.abs(np.diff(s.acceleration[::4])).max() <= 2 * 625_000 + 1
    with pytest.raises(ParameterError, match="sample_time_s must be a 6000-series servo period"):
        PARKER6K.profile(m, 154e-6)


BAD = [
    ((2**31, 10, 1e4, 1e6, 4), "-2147483648 <= start <= 2147483647"),
    ((0, 2**31, 1e4, 1e6, 4), "-2147483648 <= distance <= 2147483647"),
    ((0, 10, 1e4, 1e6, 3), "ssfr must be one of 1, 2, 4, 8"),
    ((0, 10, 0.0, 1e6, 4), "0 < max_velocity_counts_per_s <= 1e"),
    ((0, 10, 2e9, 1e6, 4), "0 < max_velocity_counts_per_s <= 1e"),
    ((0, 10, 1e-4, 1e6, 4), "max_velocity_counts_per_s must convert to at least 1 micro-count"),
    ((0, 10, 1e4, 1e-3, 4), "max_acceleration_counts_per_s2 must convert to at least 1"),
    ((0, 10, 1e4, float("nan"), 4), "0 < max_acceleration_counts_per_s2"),
    ((0, 2**31 - 1, 1.0, 1e3, 1), "more than the 16777216"),
]


@pytest.mark.parametrize(("args", "match"), BAD, ids=[m for _, m in BAD])
def test_illegal_arguments(args, match):
    with pytest.raises(ParameterError, match=match):
        profile_move(*args)


def test_illegal_keywords():
    with pytest.raises(ParameterError, match="needs jerk_counts_per_s3"):
        profile_move(0, 10, 1e4, 1e6, 4, kind="s_curve")
    with pytest.raises(ParameterError, match="applies to kind='s_curve' only"):
        profile_move(0, 10, 1e4, 1e6, 4, jerk_counts_per_s3=1e9)
    with pytest.raises(ParameterError, match="0 <= settle_ticks <= 16777216"):
        profile_move(0, 10, 1e4, 1e6, 4, settle_ticks=-1)
    with pytest.raises(ParameterError, match="PK-P2 interpolation must be one of"):
        ProfileAssumptions(interpolation="cubic")
    with pytest.raises(ParameterError, match="kind must be 'trapezoidal' or 's_curve'"):
        profile_move(0, 10, 1e4, 1e6, 4, kind="scurve")
