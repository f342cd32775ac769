"""PMD profile generator (servogym/chips/pmd/_profile.py, docs/chips/pmd-profile.md)."""

from __future__ import annotations

import math
import re

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from servogym.chips._space import ParameterError
from servogym.chips.pmd import _profile as prof
from servogym.chips.pmd._profile import (
    MAX_TICKS,
    Profile,
    ProfileAssumptions,
    VelocitySegment,
    acceleration_from_1616,
    acceleration_to_1616,
    jerk_from_032,
    jerk_to_032,
    move,
    s_curve,
    trapezoidal,
    velocity_contouring,
    velocity_from_1616,
    velocity_to_1616,
)

U = 1 << 16  # one count/cycle (or count/cycle^2) in 16.16
S32_MIN, S32_MAX = -(1 << 31), (1 << 31) - 1
FAST = settings(max_examples=120, deadline=None, suppress_health_check=[HealthCheck.too_slow])
SETTINGS = ProfileAssumptions.all_settings()


def wrap32(x: int) -> int:
    return (x + (1 << 31)) % (1 << 32) - (1 << 31)


def expected_positions(start: int, velocity: np.ndarray, a: ProfileAssumptions) -> list[int]:
    """The documented relation (PMD-P1..P3), in Python integers.

    A 32.16 accumulator starts at ``start * 2^16`` and adds each cycle's 16.16 velocity
    (velocity_first: the velocity of this cycle; position_first: of the previous cycle);
    the position is its floor (or rounded) integer part, wrapped to 32 bits.
    """
    acc = start * U
    out = []
    prev = 0
    for v in velocity.tolist():
        acc += v if a.update_order == "velocity_first" else prev
        prev = v
        half = U // 2 if a.position_rounding == "round" else 0
        out.append(wrap32((acc + half) // U))
    return out


def check_common(p: Profile, start: int) -> None:
    for arr in (p.position, p.velocity, p.acceleration):
        assert arr.dtype == np.int64
        assert arr.flags.c_contiguous
        assert arr.shape == (p.n_ticks,)
    assert p.position.min() >= S32_MIN and p.position.max() <= S32_MAX


def check_rate_limits(p: Profile, v_max: int, acc: int, dec: int) -> None:
    """|v| <= v_max; |a| <= acc while the speed grows, <= dec while it falls."""
    v = p.velocity.tolist()
    assert max(abs(x) for x in v) <= v_max
    prev = 0
    for x, a in zip(v, p.acceleration.tolist(), strict=True):
        assert abs(a) <= (acc if abs(x) > abs(prev) else dec)
        prev = x


# --------------------------------------------------------------------------------------
# Hand-computed cases (16.16 values written as multiples of U = 1 count/cycle)
# --------------------------------------------------------------------------------------


def test_trapezoid_10_counts_v2_a1():
    # Ramp 1, 2; cruise at 2 while a stop from 2 (1 more count) still fits; a last step of
    # 1 lands on 10; the entry at rest ends the move.
    p = trapezoidal(0, 10, 2 * U, 1 * U)
    assert p.position.tolist() == [1, 3, 5, 7, 9, 10, 10]
    assert p.velocity.tolist() == [1 * U, 2 * U, 2 * U, 2 * U, 2 * U, 1 * U, 0]
    assert p.acceleration.tolist() == [1 * U, 1 * U, 0, 0, 0, -1 * U, -1 * U]
    assert p.n_ticks == p.move_ticks == 7


def test_trapezoid_triangular_never_reaches_velocity_limit():
    # 5 counts at v=10, a=1: after 1 and 2 (3 counts) 2 counts remain; the largest velocity
    # u with u + (u - 1) <= 2 is 1.5, then 0.5 lands exactly: peak 2 << 10.
    p = trapezoidal(0, 5, 10 * U, 1 * U)
    assert p.velocity.tolist() == [U, 2 * U, 3 * U // 2, U // 2, 0]
    assert p.acceleration.tolist() == [U, U, -U // 2, -U, -U // 2]
    assert p.position.tolist() == [1, 3, 4, 5, 5]  # 4.5 floors to 4 (PMD-P3)


def test_trapezoid_negative_is_mirrored_and_floor_vs_round():
    p = trapezoidal(0, -5, 10 * U, 1 * U)
    assert p.velocity.tolist() == [-U, -2 * U, -3 * U // 2, -U // 2, 0]
    assert p.position.tolist() == [-1, -3, -5, -5, -5]  # floor(-4.5) = -5
    r = trapezoidal(0, -5, 10 * U, 1 * U, assumptions=ProfileAssumptions(position_rounding="round"))
    assert r.position.tolist() == [-1, -3, -4, -5, -5]  # floor(-4.5 + 0.5) = -4


def test_trapezoid_position_first_lags_one_cycle():
    a = ProfileAssumptions(update_order="position_first")
    p = trapezoidal(0, 10, 2 * U, 1 * U, assumptions=a)
    assert p.velocity.tolist() == [1 * U, 2 * U, 2 * U, 2 * U, 2 * U, 1 * U, 0]
    assert p.position.tolist() == [0, 1, 3, 5, 7, 9, 10]


def test_trapezoid_full_rate_deceleration_inserts_one_cycle():
    # Up to 2 as in the exact rule; then 2 counts remain: full-rate ramp [1] covers 1, the
    # leftover 1 is one more cycle at 1, placed after the ramp velocities >= 1.
    a = ProfileAssumptions(deceleration="full_rate")
    p = trapezoidal(0, 5, 10 * U, 1 * U, assumptions=a)
    assert p.velocity.tolist() == [U, 2 * U, U, U, 0]
    assert p.position.tolist() == [1, 3, 4, 5, 5]


def test_trapezoid_asymmetric_deceleration():
    # v=2, a=2, d=1: 2 in one cycle; a stop from 2 needs 1 more count (u + (u - 1)).
    # 7 counts: 2, 2, 2 leave 1 count, covered at 1.
    p = trapezoidal(0, 7, 2 * U, 2 * U, U)
    assert p.velocity.tolist() == [2 * U, 2 * U, 2 * U, U, 0]
    assert p.position.tolist() == [2, 4, 6, 7, 7]
    # 6 counts: 2, 2 leave 2 counts; the largest u with u + (u - 1) <= 2 is 1.5, then 0.5.
    p = trapezoidal(0, 6, 2 * U, 2 * U, U)
    assert p.velocity.tolist() == [2 * U, 2 * U, 3 * U // 2, U // 2, 0]
    assert p.position.tolist() == [2, 4, 5, 6, 6]


def test_trapezoid_hold_and_zero_distance():
    p = trapezoidal(0, 10, 2 * U, U, n_ticks=10)
    assert p.position.tolist() == [1, 3, 5, 7, 9, 10, 10, 10, 10, 10]
    assert p.velocity[6:].tolist() == [0] * 4 and p.acceleration[7:].tolist() == [0] * 3
    assert p.move_ticks == 7
    z = trapezoidal(42, 42, 0, 0)
    assert (z.position.tolist(), z.velocity.tolist(), z.move_ticks) == ([42], [0], 1)


def test_trapezoid_crosses_the_32_bit_wrap():
    p = trapezoidal(S32_MAX - 2, S32_MIN + 3, 2 * U, 1 * U)
    assert p.position.tolist() == [
        S32_MAX - 1,
        S32_MIN,
        S32_MIN + 2,
        S32_MIN + 3,
        S32_MIN + 3,
    ]
    # PMD-P4 "linear": the same two positions are 2^32 - 5 counts apart, the other way.
    lin = ProfileAssumptions(distance="linear")
    with pytest.raises(ParameterError, match="more than the 16777216"):
        trapezoidal(S32_MAX - 2, S32_MIN + 3, 2 * U, 1 * U, assumptions=lin)
    p = trapezoidal(S32_MAX - 2, S32_MIN + 3, S32_MAX, S32_MAX, assumptions=lin)
    assert p.position[-1] == S32_MIN + 3 and (p.velocity <= 0).all()


def test_s_curve_hand_window_2():
    # jerk 0.5 counts/cycle^3 (2^31 in 0.32), a=1, v=2, 10 counts: window L = 1/0.5 = 2;
    # the trapezoid 1,2,2,2,2,1 (accumulated 1,3,5,7,9,10) averaged over 2 cycles gives the
    # accumulator 0.5, 2, 4, 6, 8, 9.5, 10, 10.
    p = s_curve(0, 10, 2 * U, 1 * U, 1 << 31)
    assert p.position.tolist() == [0, 2, 4, 6, 8, 9, 10, 10]
    assert p.velocity.tolist() == [U // 2, 3 * U // 2, 2 * U, 2 * U, 2 * U, 3 * U // 2, U // 2, 0]
    assert p.acceleration.tolist() == [U // 2, U, U // 2, 0, 0, -U // 2, -U, -U // 2]
    assert p.move_ticks == 8


def test_s_curve_with_large_jerk_is_the_trapezoid():
    # jerk >= acceleration * 2^16: the window is one cycle (PMD-P8), and a trapezoid with a
    # cruise between its ramps is already an S-curve.
    for target in (10, 1000, -1000):
        t = trapezoidal(0, target, 2 * U, U // 2)
        s = s_curve(0, target, 2 * U, U // 2, 1 << 31)
        for name in ("position", "velocity", "acceleration"):
            np.testing.assert_array_equal(getattr(s, name), getattr(t, name))
    # 7 counts: the trapezoid's velocity rises and then falls on the next cycle (its
    # acceleration drops by 0.75 in one cycle, more than the jerk of 0.5); the S-curve lowers
    # its peak velocity to keep a cycle at zero acceleration in between.
    t = trapezoidal(0, 7, 2 * U, U // 2)
    s = s_curve(0, 7, 2 * U, U // 2, 1 << 31)
    assert np.abs(np.diff(t.acceleration)).max() == 3 * U // 4
    assert np.abs(np.diff(s.acceleration, append=0)).max() <= U // 2
    assert s.position[-1] == 7 and np.abs(s.velocity).max() < 2 * U


def test_velocity_contouring_hand():
    p = velocity_contouring(0, [(2 * U, U, 4), (-U, U, 4)])
    assert p.velocity.tolist() == [U, 2 * U, 2 * U, 2 * U, U, 0, -U, -U]
    assert p.position.tolist() == [1, 3, 5, 7, 8, 8, 7, 6]
    assert p.move_ticks is None


def test_velocity_contouring_stops_at_zero_before_reversing():
    # 0.5 toward -1.5 at 1/cycle would be -0.5: the velocity stops at 0 for one cycle.
    p = velocity_contouring(0, [VelocitySegment(U // 2, U, 1), VelocitySegment(-3 * U // 2, U, 4)])
    assert p.velocity.tolist() == [U // 2, 0, -U, -3 * U // 2, -3 * U // 2]


def test_velocity_contouring_deceleration_and_wrap():
    p = velocity_contouring(S32_MAX - 3, [(3 * U, 3 * U, 2, U), (0, 3 * U, 4, U)], n_ticks=7)
    assert p.velocity.tolist() == [3 * U, 3 * U, 2 * U, U, 0, 0, 0]
    assert (
        p.position.tolist() == [S32_MAX, S32_MIN + 2, S32_MIN + 4, S32_MIN + 5] + [S32_MIN + 5] * 3
    )


# --------------------------------------------------------------------------------------
# Properties
# --------------------------------------------------------------------------------------


@st.composite
def trapezoid_args(draw):
    v = draw(st.integers(1 << 10, 1 << 22))  # 1/64 .. 64 counts/cycle
    acc = draw(st.integers(max(1, v // 300), 1 << 22))  # ramps <= 300 cycles
    dec = draw(st.integers(max(1, v // 300), 1 << 22))
    max_dist = (v * 1500) >> 16  # cruise <= 1500 cycles
    dist = draw(st.integers(-max_dist, max_dist))
    start = draw(
        st.one_of(
            st.integers(S32_MIN, S32_MAX),
            st.integers(S32_MAX - 2 * max_dist, S32_MAX),
            st.integers(S32_MIN, S32_MIN + 2 * max_dist),
        )
    )
    a = draw(st.sampled_from(SETTINGS))
    if a.distance == "linear":  # keep start + dist inside 32 bits
        start = min(max(start, S32_MIN - min(dist, 0)), S32_MAX - max(dist, 0))
    return start, wrap32(start + dist), v, acc, dec, a


@FAST
@given(trapezoid_args())
def test_trapezoid_properties(args):
    start, target, v, acc, dec, a = args
    p = trapezoidal(start, target, v, acc, dec, assumptions=a)
    check_common(p, start)
    # Lands exactly, at rest, on the last entry.
    assert p.position[-1] == target and p.velocity[-1] == 0 and p.move_ticks == p.n_ticks
    if p.n_ticks > 1:
        assert p.velocity[-2] != 0
    check_rate_limits(p, v, acc, dec)
    # Exact relations: acceleration is the velocity change; position is the 32.16
    # accumulator of the velocity.
    np.testing.assert_array_equal(np.cumsum(p.acceleration), p.velocity)
    assert p.position.tolist() == expected_positions(start, p.velocity, a)
    # Never moves backwards.
    assert (p.velocity.astype(object) * (wrap32(target - start) or 1) >= 0).all()
    longer = trapezoidal(start, target, v, acc, dec, n_ticks=p.n_ticks + 5, assumptions=a)
    np.testing.assert_array_equal(longer.position[: p.n_ticks], p.position)
    assert longer.position[-5:].tolist() == [target] * 5 and not longer.velocity[-5:].any()


@st.composite
def s_curve_args(draw):
    v = draw(st.integers(1 << 12, 1 << 20))
    acc = draw(st.integers(max(1, v // 200), 1 << 18))
    jerk = draw(st.integers(max(1, (acc << 16) // 150), min((1 << 32) - 1, acc << 17)))
    max_dist = (v * 1500) >> 16
    dist = draw(st.integers(-max_dist, max_dist))
    start = draw(
        st.one_of(st.integers(S32_MIN, S32_MAX), st.integers(S32_MAX - 2 * max_dist, S32_MAX))
    )
    a = draw(st.sampled_from(SETTINGS))
    if a.distance == "linear":
        start = min(max(start, S32_MIN - min(dist, 0)), S32_MAX - max(dist, 0))
    return start, wrap32(start + dist), v, acc, jerk, a


@FAST
@given(s_curve_args())
def test_s_curve_properties(args):
    start, target, v, acc, jerk, a = args
    p = s_curve(start, target, v, acc, jerk, assumptions=a)
    check_common(p, start)
    assert p.position[-1] == target and p.velocity[-1] == 0 and p.move_ticks == p.n_ticks
    assert np.abs(p.velocity).max() <= v
    assert np.abs(p.acceleration).max() <= acc
    # The internal acceleration changes by at most jerk / 2^16 (16.16 units) per cycle; the
    # reported one is its floor, so it changes by at most ceil(jerk / 2^16).
    da = np.diff(p.acceleration, prepend=0, append=0)
    assert np.abs(da).max() <= -(-jerk // U)
    # Position is the exact accumulator of the reported velocity; the reported velocity
    # follows the reported acceleration within 2 LSB.
    assert p.position.tolist() == expected_positions(start, p.velocity, a)
    assert np.abs(np.diff(p.velocity, prepend=0) - p.acceleration).max() <= 2


def test_s_curve_realistic_limits():
    # 154 us cycle, 1e5 counts/s, 1e6 counts/s^2, 1e8 counts/s^3.
    t = 154e-6
    v, acc, jerk = velocity_to_1616(1e5, t), acceleration_to_1616(1e6, t), jerk_to_032(1e8, t)
    for dist in (1, 37, 1000, 100_000, -54_321):
        p = s_curve(0, dist, v, acc, jerk)
        assert p.position[-1] == dist
        assert np.abs(p.velocity).max() <= v and np.abs(p.acceleration).max() <= acc
        assert np.abs(np.diff(p.acceleration, prepend=0, append=0)).max() <= -(-jerk // U)
    # The jerk phase shortens for short moves (peak acceleration below the limit).
    short = s_curve(0, 37, v, acc, jerk)
    assert np.abs(short.acceleration).max() < acc


@st.composite
def segments_args(draw):
    n = draw(st.integers(1, 4))
    segs = []
    for _ in range(n):
        vel = draw(st.integers(-(1 << 22), 1 << 22))
        acc = draw(st.integers(0, 1 << 20))
        dur = draw(st.integers(0, 200))
        dec = draw(st.one_of(st.none(), st.integers(0, 1 << 20)))
        segs.append((vel, acc, dur) if dec is None else (vel, acc, dur, dec))
    start = draw(st.integers(S32_MIN, S32_MAX))
    extra = draw(st.integers(1, 50))
    return start, segs, extra, draw(st.sampled_from(SETTINGS))


@FAST
@given(segments_args())
def test_velocity_contouring_properties(args):
    start, segs, extra, a = args
    total = sum(s[2] for s in segs)
    p = velocity_contouring(start, segs, n_ticks=total + extra, assumptions=a)
    check_common(p, start)
    assert p.n_ticks == total + extra
    np.testing.assert_array_equal(np.cumsum(p.acceleration), p.velocity)
    assert p.position.tolist() == expected_positions(start, p.velocity, a)
    # Per segment: the rate limit in force, never through zero within a cycle, and the
    # target velocity once there has been time to reach it.
    bounds = np.cumsum([0] + [s[2] for s in segs])
    bounds[-1] += extra
    prev = 0
    for i, s in enumerate(segs):
        vel, acc = s[0], s[1]
        dec = s[3] if len(s) == 4 else acc
        for k in range(bounds[i], bounds[i + 1]):
            x = int(p.velocity[k])
            assert prev * x >= 0
            assert abs(x - prev) <= (acc if abs(x) > abs(prev) else dec)
            if x != prev:
                assert abs(vel - x) < abs(vel - prev)
            prev = x


# --------------------------------------------------------------------------------------
# The fast-forwarded core against a slow per-cycle reference
# --------------------------------------------------------------------------------------


def slow_span(u: int, d: int) -> int:
    total, w = u, u - d
    while w > 0:
        total, w = total + w, w - d
    return total


def slow_plan(dist: int, v_max: int, acc: int, dec: int, rule: str) -> list[int]:
    """PMD-P5 as written in the spec, one cycle at a time, by brute-force search."""
    out, v, r = [], 0, dist
    while r > 0:
        u = next(c for c in range(min(v_max, v + acc), -1, -1) if slow_span(c, dec) <= r)
        if u < v and rule == "full_rate":
            ramp = list(range(v - dec, 0, -dec))
            left = r - sum(ramp)
            if left:
                ramp.insert(sum(w >= left for w in ramp), left)
            out += ramp
            break
        out.append(u)
        r -= u
        v = u
    return [*out, 0]


@settings(max_examples=300, deadline=None)
@given(st.integers(0, 400), st.integers(1, 30))
def test_max_stoppable_matches_brute_force(r, d):
    expected = max(u for u in range(0, r + 1) if slow_span(u, d) <= r)
    assert prof._max_stoppable(r, d) == expected
    assert prof._stop_span(expected, d) == slow_span(expected, d)


@settings(max_examples=300, deadline=None)
@given(
    st.integers(1, 3000),
    st.integers(1, 60),
    st.integers(1, 25),
    st.integers(1, 25),
    st.sampled_from(["exact", "full_rate"]),
)
def test_plan_matches_slow_reference(dist, v_max, acc, dec, rule):
    fast = prof._plan_move(dist, v_max, acc, dec, rule).velocities().tolist()
    assert fast == slow_plan(dist, v_max, acc, dec, rule)


# --------------------------------------------------------------------------------------
# Units
# --------------------------------------------------------------------------------------


def test_unit_formulas():
    t = 154e-6
    for x in (0.0, 1.0, 123.4, 1e5, -2.5e4, 7.77e5):
        assert velocity_to_1616(x, t) == math.floor(0.5 + 65536 * x * t)
        assert acceleration_to_1616(x * 100, t) == math.floor(0.5 + 65536 * x * 100 * t * t)
    assert jerk_to_032(1e8, t) == math.floor(0.5 + 2**32 * 1e8 * t**3)
    # Worked values: 1e5 counts/s * 154 us = 15.4 counts/cycle.
    assert velocity_to_1616(1e5, t) == 1009254  # floor(0.5 + 1009254.4)
    assert velocity_to_1616(1.0, 1.0) == U
    assert acceleration_to_1616(1.0, 0.5) == U // 4
    assert jerk_to_032(1.0, 0.5) == 1 << 29
    assert velocity_to_1616(0.5 / U, 1.0) == 1  # a half LSB rounds up
    assert velocity_to_1616(-0.5 / U, 1.0) == 0  # floor(0.5 - 0.5)


@given(st.integers(S32_MIN, S32_MAX), st.sampled_from([52e-6, 154e-6, 1e-3, 0.1]))
def test_unit_round_trips(x, t):
    assert velocity_to_1616(velocity_from_1616(x, t), t) == x
    assert acceleration_to_1616(acceleration_from_1616(x, t), t) == x
    j = x - S32_MIN  # 0 .. 2^32 - 1
    assert jerk_to_032(jerk_from_032(j, t), t) == j


@given(st.floats(-1e6, 1e6, allow_nan=False))
def test_unit_inverse_within_half_lsb(cps):
    t = 154e-6
    back = velocity_from_1616(velocity_to_1616(cps, t), t)
    assert abs(back - cps) <= 0.5 / (U * t) * (1 + 1e-9)


# --------------------------------------------------------------------------------------
# move()
# --------------------------------------------------------------------------------------


def test_move_trapezoidal_and_s_curve():
    t = 154e-6
    p = move("trapezoidal", 100, 5000, 1e5, 1e6, t, settle_ticks=40)
    q = trapezoidal(100, 5100, velocity_to_1616(1e5, t), acceleration_to_1616(1e6, t))
    assert p.n_ticks == q.n_ticks + 40 and p.move_ticks == q.move_ticks
    np.testing.assert_array_equal(p.position[: q.n_ticks], q.position)
    assert p.position[-41:].tolist() == [5100] * 41 and not p.velocity[q.n_ticks :].any()
    s = move("s_curve", S32_MAX, 10, 1e5, 1e6, t, jerk_counts_per_s3=1e8, settle_ticks=0)
    assert s.position[-1] == S32_MIN + 9 and s.n_ticks == s.move_ticks
    d = move("trapezoidal", 0, -300, 1e5, 1e6, t, max_deceleration_counts_per_s2=5e5)
    assert d.position[-1] == -300 and d.n_ticks == d.move_ticks + 100


def test_profiles_are_deterministic():
    a = s_curve(5, 12345, 3 * U, U // 10, 1 << 20)
    b = s_curve(5, 12345, 3 * U, U // 10, 1 << 20)
    for name in ("position", "velocity", "acceleration"):
        np.testing.assert_array_equal(getattr(a, name), getattr(b, name))


# --------------------------------------------------------------------------------------
# Illegal arguments
# --------------------------------------------------------------------------------------

T = 154e-6
BAD = [
    (trapezoidal, (2**31, 0, U, U), "-2147483648 <= start <= 2147483647"),
    (trapezoidal, (0, -(2**31) - 1, U, U), "-2147483648 <= target <= 2147483647"),
    (trapezoidal, (0.5, 10, U, U), "start must be an integer"),
    (trapezoidal, (0, 10, -1, U), "0 <= velocity <= 2147483647"),
    (trapezoidal, (0, 10, 2**31, U), "0 <= velocity <= 2147483647"),
    (trapezoidal, (0, 10, True, U), "velocity must be an integer"),
    (trapezoidal, (0, 10, 0, U), "1 <= velocity <= 2147483647 .*nonzero.*velocity=0"),
    (trapezoidal, (0, 10, U, 2**31), "0 <= acceleration <= 2147483647"),
    (trapezoidal, (0, 10, U, 0), "1 <= acceleration <= 2147483647 .*acceleration=0"),
    (trapezoidal, (0, 10, U, U, -1), "0 <= deceleration <= 2147483647"),
    (trapezoidal, (0, 10, U, U, 0), "1 <= deceleration <= 2147483647 .*deceleration=0"),
    (trapezoidal, (0, 10, U, U, None, 0), "1 <= n_ticks <= 16777216"),
    (trapezoidal, (0, 10, 2 * U, U, None, 6), "needs 7 ticks.*7 <= n_ticks.*n_ticks=6"),
    (trapezoidal, (0, S32_MAX, 1, 1), "more than the 16777216"),
    (s_curve, (0, 10, U, U, -1), "0 <= jerk <= 4294967295"),
    (s_curve, (0, 10, U, U, 2**32), "0 <= jerk <= 4294967295"),
    (s_curve, (0, 10, U, U, 0), "1 <= jerk <= 4294967295 .*jerk=0"),
    (s_curve, (0, 10, 0, U, 5), "1 <= velocity <= 2147483647"),
    (s_curve, (0, 1, U, U, 1), "jerk=1 is too small"),
    (s_curve, (0, 10, U, U, 1 << 31, 3), "needs 12 ticks.*n_ticks=3"),
    (velocity_contouring, (0, []), "segments must be a non-empty sequence"),
    (velocity_contouring, (0, [(1, 2)]), r"segments\[0\] must be \(velocity, acceleration"),
    (
        velocity_contouring,
        (0, [(U, U, 3), (2**31, U, 1)]),
        r"-2147483648 <= segments\[1\]\.velocity <= 2147483647",
    ),
    (velocity_contouring, (0, [(U, -1, 3)]), r"0 <= segments\[0\]\.acceleration <= 2147483647"),
    (velocity_contouring, (0, [(U, U, -3)]), r"0 <= segments\[0\]\.duration <= 16777216"),
    (velocity_contouring, (0, [(U, U, 3, -1)]), r"0 <= segments\[0\]\.deceleration <= 2147483647"),
    (velocity_contouring, (0, [(U, U, 3)], 2), "segments last 3 ticks.*3 <= n_ticks"),
    (velocity_contouring, (0, [(U, U, 0)]), "at least one cycle"),
    (velocity_contouring, (2**31, [(U, U, 3)]), "-2147483648 <= start <= 2147483647"),
    (velocity_to_1616, (float("nan"), T), "counts_per_s must be a finite number"),
    (
        velocity_to_1616,
        (1e12, T),
        "counts_per_s must convert to a 16.16 value in -2147483648..2147483647",
    ),
    (velocity_to_1616, (1.0, 0.0), "sample_time_s must be a finite number > 0"),
    (acceleration_to_1616, ("1", T), "counts_per_s2 must be a finite number"),
    (jerk_to_032, (-1.0, 1e-3), "counts_per_s3 must convert to a 0.32 value in 0..4294967295"),
    (velocity_from_1616, (2**31, T), "-2147483648 <= velocity <= 2147483647"),
    (jerk_from_032, (-1, T), "0 <= jerk <= 4294967295"),
    (move, ("scurve", 0, 10, 1e5, 1e6, T), "kind must be one of 'trapezoidal', 's_curve'"),
    (move, ("trapezoidal", 0, 2**31, 1e5, 1e6, T), "-2147483648 <= distance <= 2147483647"),
    (
        move,
        ("trapezoidal", 0, 10, 0.0, 1e6, T),
        "max_velocity_counts_per_s must be a finite number > 0",
    ),
    (
        move,
        ("trapezoidal", 0, 10, 1e-3, 1e6, T),
        "must convert to a velocity register value 1 <= velocity <= 2147483647",
    ),
    (move, ("trapezoidal", 0, 10, 1e5, 1e20, T), "max_acceleration_counts_per_s2 must convert"),
    (move, ("trapezoidal", 0, 10, 1e5, 1e6, -T), "sample_time_s must be a finite number > 0"),
]


@pytest.mark.parametrize(("func", "args", "match"), BAD, ids=[m for _, _, m in BAD])
def test_illegal_arguments(func, args, match):
    with pytest.raises(ParameterError, match=match):
        func(*args)


@pytest.mark.parametrize(
    ("kwargs", "match"),
    [
        ({"kind": "s_curve"}, "jerk_counts_per_s3 is required"),
        ({"kind": "s_curve", "jerk_counts_per_s3": 0.0}, "jerk_counts_per_s3 must be a finite"),
        ({"kind": "s_curve", "jerk_counts_per_s3": 1e-9}, "jerk_counts_per_s3 must convert"),
        (
            {"kind": "s_curve", "jerk_counts_per_s3": 1e8, "max_deceleration_counts_per_s2": 1e6},
            "max_deceleration_counts_per_s2 applies to kind='trapezoidal' only",
        ),
        ({"jerk_counts_per_s3": 1e8}, "jerk_counts_per_s3 applies to kind='s_curve' only"),
        ({"settle_ticks": -1}, "0 <= settle_ticks <= 16777216"),
        (
            {
                "start": S32_MAX,
                "distance": 10,
                "assumptions": ProfileAssumptions(distance="linear"),
            },
            re.escape("-4294967295 <= distance <= 0"),
        ),
        ({"assumptions": "floor"}, "assumptions must be a ProfileAssumptions or None"),
    ],
)
def test_illegal_move_keywords(kwargs, match):
    args = {
        "kind": "trapezoidal",
        "start": 0,
        "distance": 10,
        "max_velocity_counts_per_s": 1e5,
        "max_acceleration_counts_per_s2": 1e6,
        "sample_time_s": T,
    }
    args.update(kwargs)
    with pytest.raises(ParameterError, match=match):
        move(**args)


def test_illegal_assumptions():
    for name in ("update_order", "position_rounding", "distance", "deceleration"):
        ident = prof.PROFILE_ASSUMPTION_IDS[name]
        with pytest.raises(ParameterError, match=f"{ident} {name} must be one of .*{name}='x'"):
            ProfileAssumptions(**{name: "x"})


def test_profile_shape_checked():
    with pytest.raises(ValueError, match="same length"):
        Profile(np.zeros(3), np.zeros(3), np.zeros(2))
    p = Profile([1, 2], [0, 0], [0, 0])
    assert p.position.dtype == np.int64 and p.n_ticks == 2
    assert MAX_TICKS == 2**24


def test_profile_records_its_start():
    # The runner sets the chip's position register from it at reset.
    assert trapezoidal(5, 15, 2 * U, 1 * U).start == 5
    assert trapezoidal(-7, -7, 2 * U, 1 * U, n_ticks=4).start == -7
    held = move("trapezoidal", 100, 50, 2000.0, 1e5, 1e-3, settle_ticks=30)
    assert held.start == 100 and held.position[-1] == 150
