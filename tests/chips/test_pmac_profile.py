"""PMAC profile (docs/chips/pmac.md, section 5), the family entry, and a compiled closed loop."""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from numba import njit

from servogym.chips import FAMILY_CODES, Move, ParameterError, families, family_of, get_chip
from servogym.chips.pmac import (
    PMAC,
    STATE_SIZE,
    PMACAssumptions,
    PMACParams,
    PMACReferenceFilter,
    Profile,
    from_json,
    move,
    pmac_step,
    to_json,
)
from servogym.chips.pmac._kernel import S_TRIPPED

T = PMACParams().sample_time_s


def check(p: Profile, start: int, distance: int, v: float, a: float, extra_ticks: int) -> None:
    """Properties every point-to-point profile has."""
    n = p.n_ticks
    assert all(arr.dtype == np.int64 and arr.shape == (n,) for arr in (p.position, p.velocity))
    np.testing.assert_array_equal(p.acceleration, np.diff(p.commanded_velocity, prepend=0))
    assert p.velocity.min() >= 0 and p.velocity.max() <= 31
    fine = p.fine_position
    assert fine[-1] == 32 * (start + distance) and p.fraction is p.velocity
    assert p.position[-1] == ((start + distance + 2**31) % 2**32) - 2**31
    assert n == max(1, p.move_ticks + extra_ticks)
    if distance:
        assert fine[p.move_ticks - 1] == fine[-1]
    cv = p.commanded_velocity * np.sign(distance or 1)
    assert cv.min() >= 0  # never moves backwards
    # Speed within the limit, to the 1/32-count quantization of each entry.
    assert cv.max() <= 32 * v * T + 1.0
    dv = np.diff(cv, prepend=0)
    assert np.abs(dv).max() <= 32 * a * T * T + 2.0


@settings(max_examples=60, deadline=None)
@given(
    start=st.integers(-(2**31), 2**31 - 1),
    distance=st.integers(-(10**6), 10**6),
    v=st.floats(1e3, 5e6),
    a=st.floats(1e5, 1e9),
    settle=st.integers(0, 50),
)
def test_trapezoidal_properties(start, distance, v, a, settle):
    p = move("trapezoidal", start, distance, v, a, T, settle_ticks=settle)
    check(p, start, distance, v, a, settle)
    # The move takes the time-optimal trapezoid's duration, rounded up to whole updates.
    length = abs(distance)
    duration = v / a + length / v if length * a >= v * v else 2 * math.sqrt(length / a)
    assert p.move_ticks == (math.ceil(duration / T - 1e-9) if distance else 0) or (
        p.move_ticks == 1 and duration < T
    )


def test_trapezoidal_worked_numbers():
    # 10,000 counts at 2e5 counts/s and 2e7 counts/s^2: 10 ms ramps of 1000 counts each,
    # 8000 counts at speed in 40 ms, 60 ms total = 135.52 updates of 442.74 us -> 136
    # entries; first entry: 2e7 * T^2 / 2 = 1.96 counts = 62.7 / 32 -> 63 / 32.
    p = move("trapezoidal", 0, 10_000, 2e5, 2e7, T, settle_ticks=10)
    assert p.move_ticks == 136 and p.n_ticks == 146
    assert p.fine_position[0] == math.floor(32 * 0.5 * 2e7 * T * T + 0.5) == 63
    assert (p.position[0], p.velocity[0]) == (1, 31)
    assert p.position[-11:].tolist() == [10_000] * 11


@settings(max_examples=40, deadline=None)
@given(
    distance=st.integers(-(10**5), 10**5).filter(bool),
    v=st.floats(1e4, 1e6),
    a=st.floats(1e6, 1e8),
    jerk_ratio=st.floats(2.0, 200.0),
)
def test_s_curve_properties(distance, v, a, jerk_ratio):
    jerk = a * jerk_ratio  # S-curve time a / jerk = 1 / jerk_ratio s
    s = move("s_curve", 5, distance, v, a, T, jerk_counts_per_s3=jerk, settle_ticks=3)
    check(s, 5, distance, v, a, 3)
    trap = move("trapezoidal", 5, distance, v, a, T, settle_ticks=0)
    # The S-curve lasts the S-curve time longer (PMAC-P2) when the trapezoid cruises that
    # long; a shorter move peaks lower and lasts longer still.
    if abs(distance) >= v * v / a + v / jerk_ratio:
        assert abs((s.move_ticks - trap.move_ticks) * T - 1 / jerk_ratio) <= 2 * T
    else:
        assert s.move_ticks * T >= trap.move_ticks * T + 1 / jerk_ratio - 2 * T
    # Jerk within the limit, to the quantization: each position is off by at most 1/64
    # count, so a third difference by about 4/32 count (5.5/32 with the monotone clamp).
    cv = s.commanded_velocity.astype(float) / 32
    jerk_seen = np.abs(np.diff(np.diff(cv, prepend=0), prepend=0)) / T**3
    assert jerk_seen.max() <= jerk * 1.001 + 5.5 / 32 / T**3


def test_moves_across_the_32_bit_wrap_and_empty_moves():
    p = move("trapezoidal", 2**31 - 5, 10, 2e5, 2e7, T, settle_ticks=2)
    assert p.position[-1] == -(2**31) + 5 and p.start == 2**31 - 5
    assert np.diff(p.fine_position).min() >= 0
    z = move("trapezoidal", 7, 0, 1.0, 1.0, T, settle_ticks=0)
    assert z.n_ticks == 1 and z.move_ticks == 0 and z.position.tolist() == [7]
    assert move("trapezoidal", 7, 0, 1.0, 1.0, T, settle_ticks=5).n_ticks == 5


@pytest.mark.parametrize(
    ("kwargs", "match"),
    [
        ({"kind": "scurve"}, "kind must be one of 'trapezoidal', 's_curve'"),
        ({"start": 2**31}, "-2147483648 <= start <= 2147483647"),
        ({"distance": 1.5}, "distance must be an integer"),
        ({"max_velocity_counts_per_s": 0.0}, "max_velocity_counts_per_s must be a finite"),
        ({"max_acceleration_counts_per_s2": math.inf}, "max_acceleration_counts_per_s2 must"),
        ({"sample_time_s": -1.0}, "sample_time_s must be a finite number > 0"),
        ({"settle_ticks": -1}, "0 <= settle_ticks <= 16777216"),
        ({"kind": "s_curve"}, "jerk_counts_per_s3 is required"),
        ({"jerk_counts_per_s3": 1e9}, "jerk_counts_per_s3 applies to kind='s_curve' only"),
        ({"max_velocity_counts_per_s": 1e-6}, "more than the 16777216"),
    ],
)
def test_illegal_move_arguments(kwargs, match):
    args = dict(
        kind="trapezoidal",
        start=0,
        distance=1000,
        max_velocity_counts_per_s=1e5,
        max_acceleration_counts_per_s2=1e7,
        sample_time_s=T,
    )
    args.update(kwargs)
    with pytest.raises(ParameterError, match=match):
        move(**args)


def test_profile_checks_its_arrays():
    with pytest.raises(ValueError, match="same length"):
        Profile(np.zeros(3), np.zeros(3), np.zeros(2))
    with pytest.raises(ValueError, match=r"fraction, 0\.\.31"):
        Profile(np.zeros(2), np.full(2, 32), np.zeros(2))


# --- the family entry ----------------------------------------------------------------------------


def test_family_is_registered():
    assert families()["pmac"] is PMAC and PMAC.code == FAMILY_CODES["pmac"] == 1
    assert get_chip("geobricklv") == (PMAC, "GeoBrickLV")
    assert get_chip("TurboPMAC2") == (PMAC, "TurboPMAC2")
    assert PMAC.formats == ("json", "ivar")
    p = PMAC.make_params("GeoBrickLV", {"proportional_gain": 30_000})
    assert isinstance(p, PMACParams) and family_of(p) is PMAC
    assert PMAC.sample_time_s(p) == p.sample_time_s and PMAC.motor_limit(p) == 20480
    assert PMAC.parameter_space("GeoBrickLV")["proportional_gain"].default == 2000
    assert PMAC.default_assumptions() == PMACAssumptions()
    params, asm = PMAC.kernel_arrays(p, None)
    assert params.dtype == asm.dtype == np.int64 and not asm.any()
    assert PMAC.new_state().shape == (STATE_SIZE,)
    with pytest.raises(TypeError, match="must be PMACAssumptions"):
        PMAC.kernel_arrays(p, {"rounding": "trunc"})
    with pytest.raises(ParameterError, match="Did you mean proportional_gain"):
        PMAC.make_params("TurboPMAC2", {"proportional": 1})
    assert PMAC.from_json(to_json(p)).params == p == from_json(PMAC.export(p, "json")).params
    assert PMAC.export(p, "ivar", axis=2).count("I230=30000") == 1
    assert from_json(PMAC.export(p, "json", axis=2, assumptions=PMACAssumptions())).params == p
    ref = PMAC.reference_filter(p, PMACAssumptions(rounding="trunc"))
    assert isinstance(ref, PMACReferenceFilter) and ref.assumptions.rounding == "trunc"
    assert ref.step(10, 0, 0, 0) == PMACReferenceFilter(p).step(10, 0) and not ref.motion_error


def test_family_profile_from_a_move():
    m = Move(5000, 1e5, 1e7, settle_s=0.01, start_counts=-3)
    p = PMAC.profile(m, T)
    q = move("trapezoidal", -3, 5000, 1e5, 1e7, T, settle_ticks=round(0.01 / T))
    np.testing.assert_array_equal(p.position, q.position)
    np.testing.assert_array_equal(p.velocity, q.velocity)
    assert p.start == -3 and p.n_ticks == q.n_ticks
    s = PMAC.profile(Move(5000, 1e5, 1e7, kind="s_curve", jerk_counts_per_s3=1e9), T)
    assert s.position[-1] == 5000 and s.move_ticks > q.move_ticks


# --- a compiled closed loop around a tiny plant -------------------------------------------------


@njit
def _double_integrator_loop(state, p, a, pos, vel, acc, start, gain, dt):
    """Counts'' = gain * DAC: pmac_step called from compiled code, as the servo loop does."""
    n = pos.shape[0]
    x = float(start)
    v = 0.0
    out = np.zeros(n, np.int64)
    actual = np.zeros(n, np.int64)
    for k in range(n):
        actual[k] = np.int64(np.floor(x))
        out[k] = pmac_step(state, p, a, pos[k], actual[k], vel[k], acc[k])
        v += gain * out[k] * dt
        x += v * dt
    return out, actual


def test_closed_loop_settles_on_target_and_matches_reference():
    # counts'' = 2000 * DAC at 442.7 us. Ixx30 = 20000 is 2^-19 * 20000 * 96 = 3.7 DAC bits
    # per count; the move's 5e6 counts/s^2 needs 2500 DAC bits, which Ixx35 = 88000 supplies
    # (2^-19 * 20000 * 96 * 88000 * 0.98 count/cycle^2 / 128), so the error stays small.
    params = PMACParams(
        proportional_gain=20_000,
        derivative_gain=2_500,
        velocity_ff=2_500,
        acceleration_ff=88_000,
        integral_gain=100_000,
        output_limit=32767,
    )
    prof = move("trapezoidal", 100, 20_000, 2e5, 5e6, T, settle_ticks=1500)
    p, a = PMAC.kernel_arrays(params, None)
    out, actual = _double_integrator_loop(
        PMAC.new_state(), p, a, prof.position, prof.velocity, prof.acceleration, 100, 2000.0, T
    )
    assert np.abs(prof.position - actual).max() < 40
    assert (actual[-200:] == 20_100).all() and not out[-200:].any()
    # The reference filter, fed the same encoder readings, gives the same commands.
    ref = PMACReferenceFilter(params).run(prof.position, actual, prof.velocity)
    assert ref == out.tolist()


def test_closed_loop_trips_on_fatal_following_error():
    params = PMACParams(fatal_following_error_limit=160)  # 10 counts; default gains are weak
    prof = move("trapezoidal", 0, 5000, 2e5, 2e7, T, settle_ticks=0)
    state = PMAC.new_state()
    p, a = PMAC.kernel_arrays(params, None)
    out, _ = _double_integrator_loop(state, p, a, prof.position, prof.velocity, prof.acceleration,
                                     0, 2000.0, T)  # fmt: skip
    assert state[S_TRIPPED] == 1
    first = int(np.argmax(out == 0))
    assert first > 0 and not out[first:].any()
