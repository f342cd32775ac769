"""Metrics and divergence at their edges, hand-computed from docs/simulation.md and the
EpisodeMetrics docstrings: the window after the move, the steady-state tail, the ticks a
diverged episode ran, both sides of the travel and error bounds, amplifier saturation.
"""

from __future__ import annotations

import dataclasses
import math

import numpy as np
import pytest

from servogym.chips.pmd import PMDParams
from servogym.plants import get_plant
from servogym.sim import METRIC_NAMES, EpisodeMetrics, ServoLoop
from tests.sim.test_runner import metrics_of, ramp


def test_metrics_window_starts_after_the_move():
    # dt = 0.5 s, band 1. The move ends at tick 1 (move_end = 1), where the actual is already
    # 3 past the target: that tick belongs to the move, not to the overshoot or the settling.
    # After it: 11 (1 past), 10. Overshoot 1; |e| > 1 never after tick 1: settled at once,
    # settling time (max(-1 + 1, 1) - 1) * 0.5 = 0.
    m = metrics_of([5, 10, 10, 10], [0, 13, 11, 10], [0] * 4, move_end=1, target=10,
                   direction=1)  # fmt: skip
    assert m["overshoot"] == 1
    assert m["settled"] == 1.0 and m["settling_time"] == 0.0
    # max_following_error covers ticks 0..move_end: |5|, |-3| -> 5 (tick 2's -1 is after).
    assert m["max_following_error"] == 5
    # |e| = 2 > 1 at tick 2: settles from tick 3, (3 - 1) * 0.5 = 1.0 s.
    m = metrics_of([5, 10, 10, 10], [0, 13, 12, 10], [0] * 4, move_end=1, target=10,
                   direction=1)  # fmt: skip
    assert m["overshoot"] == 2 and m["settling_time"] == 1.0


def test_metrics_move_ending_on_the_last_tick_never_settles():
    # move_end = n - 1: no tick after the move. Not settled; settling time = (n - end) ticks
    # = 1 * 0.5 s; no overshoot window at all.
    m = metrics_of([1, 2, 3], [1, 2, 3], [0] * 3, move_end=2, target=3, direction=1)
    assert m["settled"] == 0.0 and m["settling_time"] == 0.5 and m["overshoot"] == 0


def test_metrics_without_a_move():
    # move_end = -1, direction 0: every tick is "after the move"; max following error is
    # over the whole episode; settling measured from tick 0: |e| > 1 last at tick 1 ->
    # (2 - 0) * 0.5 = 1.0 s; overshoot 0 (no direction).
    m = metrics_of([0, 0, 0, 0], [2, -3, 1, 0], [0] * 4, move_end=-1, target=0, direction=0)
    assert m["max_following_error"] == 3
    assert m["settling_time"] == 1.0 and m["settled"] == 1.0
    assert m["overshoot"] == 0
    # The whole episode includes the last tick.
    m = metrics_of([0, 0, 0, 0], [2, -3, 1, 7], [0] * 4, move_end=-1, target=0, direction=0)
    assert m["max_following_error"] == 7 and m["settled"] == 0.0


def test_episode_metrics_refuse_non_finite_values_and_are_frozen():
    fields = dict.fromkeys(METRIC_NAMES, 0.0)
    extra = dict(settled=True, diverged=False, divergence_tick=-1, divergence_reason="none",
                 n_ticks=1, dt=0.001)  # fmt: skip
    m = EpisodeMetrics(**fields, **extra)
    with pytest.raises(dataclasses.FrozenInstanceError):
        m.iae = 1.0
    for name in METRIC_NAMES:
        with pytest.raises(ValueError, match=f"metric {name} is not finite: nan"):
            EpisodeMetrics(**{**fields, name: math.nan}, **extra)


def test_metrics_steady_state_tail_is_the_last_tenth():
    # n = 25: the tail is n // 10 = 2 ticks: errors 3 and 5 -> 4.0 (the tick before, 9, is
    # not in it).
    errors = [0] * 22 + [9, 3, 5]
    commanded = [100] * 25
    actual = [100 - e for e in errors]
    m = metrics_of(commanded, actual, [0] * 25, move_end=-1, target=100, direction=0)
    assert m["steady_state_error"] == 4.0
    # n = 9: n // 10 = 0, at least one tick: the last error alone.
    m = metrics_of(commanded[:9], [100, 100, 100, 100, 100, 100, 100, 91, 97], [0] * 9,
                   move_end=-1, target=100, direction=0)  # fmt: skip
    assert m["steady_state_error"] == 3.0
    # n = 30: 3 ticks, |-6|, 0, 3 -> 3.0.
    actual = [100] * 27 + [106, 100, 97]
    m = metrics_of([100] * 30, actual, [0] * 30, move_end=-1, target=100, direction=0)
    assert m["steady_state_error"] == 3.0
    # n = 19: 19 // 10 = 1 tick (a ninth would be 2): the last error, 1, alone.
    actual = [100] * 17 + [93, 99]
    m = metrics_of([100] * 19, actual, [0] * 19, move_end=-1, target=100, direction=0)
    assert m["steady_state_error"] == 1.0


def test_metrics_of_perfect_tracking_are_zero():
    # Actual = commanded on every tick, no command: every error metric is exactly 0.
    m = metrics_of([1, 2, 3, 3, 3], [1, 2, 3, 3, 3], [0] * 5, move_end=2, target=3,
                   direction=1)  # fmt: skip
    for name in ("iae", "itae", "max_following_error", "overshoot", "steady_state_error",
                 "rms_command", "saturation_fraction", "chatter", "settling_time"):  # fmt: skip
        assert m[name] == 0.0, name
    assert m["settled"] == 1.0


def test_metrics_cover_only_the_ticks_run():
    # Traces longer than n (a diverged episode in reused buffers): only the first 3 ticks.
    # Saturated (|c| >= 100): ticks 0 and 2 -> 2/3; the stale ticks 3..5 do not count.
    from servogym.sim._metrics import compute_metrics

    c = np.array([10, 10, 10, 10, 10, 10], np.int64)
    a = np.array([0, 5, 10, 10, 10, 10], np.int64)
    u = np.array([100, 0, -100, 100, 100, 100], np.int64)
    vals = compute_metrics(c, a, u, 3, -1, 10, 0, 0.5, 1.0, 100)
    assert vals[7] == pytest.approx(2 / 3)  # saturation_fraction
    assert vals[0] == 0.5 * (10 + 5 + 0)  # iae
    # rms over 3 ticks: sqrt((100^2 + 0 + 100^2) / 3) / 32768; chatter (100 + 100) / 2.
    assert vals[6] == pytest.approx(np.sqrt(20000 / 3) / 32768)
    assert vals[8] == pytest.approx(100 / 32768)


def hold(positions) -> object:
    """A profile of the given commanded positions (counts), starting at 0, no feed-forward."""
    from types import SimpleNamespace

    pos = np.asarray(positions, np.int64)
    zeros = np.zeros(pos.shape[0], np.int64)
    return SimpleNamespace(position=pos, velocity=zeros, acceleration=zeros.copy(), start=0)


OFF = dict(model="MC2100", kp=0, ki=0, kd=0, kvff=0, kaff=0, position_error_limit=2**31 - 1)


@pytest.mark.parametrize("sign", [1, -1])
def test_error_bound_both_sides_at_equality(sign):
    # No gains, no bias: the command is 0 and the plant stays at rest (actual 0), so the
    # error is the commanded position. max_error_counts = 10: |e| = 10 does not exceed it;
    # 11 at tick 2 ends the episode there.
    plant = get_plant("rotary").build()
    loop = ServoLoop(plant, PMDParams(**OFF), max_error_counts=10)
    r = loop.run(hold([5 * sign, 10 * sign, 11 * sign, 12 * sign]), traces=True)
    m = r.metrics
    assert m.diverged and m.divergence_reason == "error_bound"
    assert m.divergence_tick == 2 and m.n_ticks == 3
    assert r.traces.error.tolist() == [5 * sign, 10 * sign, 11 * sign]


def test_negative_bias_drives_into_the_lower_travel_limit():
    # Full negative bias, no gains: the axis runs into the margin in front of the lower hard
    # stop; the episode ends there, every tick ran saturated (|command| = motor_limit).
    plant = get_plant("rotary").build()
    params = PMDParams(**{**OFF, "bias": -32767, "kout": 0})
    r = ServoLoop(plant, params, max_error_counts=2**31 - 1).run(ramp(0, 1, 200_000),
                                                                 traces=True)  # fmt: skip
    m = r.metrics
    assert m.diverged and m.divergence_reason == "travel_limit"
    io = plant.io
    lo = io.travel_min + 0.01 * (io.travel_max - io.travel_min)
    assert plant.data.qpos[io.qpos_adr] < lo
    # The traces end at the divergence tick, where the position first crossed the margin:
    # the tick before was still inside it (the axis moves far less than the margin per tick).
    assert r.traces.actual.shape[0] == m.n_ticks and r.traces.actual[-1] < 0
    assert r.traces.actual[-1] < lo * io.counts_per_unit <= r.traces.actual[-2] + 1
    # saturation_fraction counts the ticks that ran: all of them.
    assert np.all(r.traces.command == -32767)
    assert m.saturation_fraction == 1.0


@pytest.mark.parametrize("bias", [32767, -32767, 8000])
def test_amplifier_saturates_on_both_sides_with_a_hand_built_axis(bias):
    # The plants scale the amplifier at peak / 32768 per count, so a 16-bit command never
    # asks for more than the peak current. A hand-built axis with twice that scale does:
    # command -32767 asks for -1.99994 peak and gets -peak; +32767 gets +peak; 8000 asks for
    # 8000 * 2 peak / 32768 = 0.48828125 peak, inside the range, and gets it exactly.
    plant = get_plant("rotary").build()
    peak = plant.io.peak_current_a
    plant.io = dataclasses.replace(plant.io, amp_amps_per_count=2 * peak / 32768)
    params = PMDParams(**{**OFF, "bias": bias, "kout": 0})
    r = ServoLoop(plant, params, max_error_counts=2**31 - 1).run(hold([0] * 50), traces=True)
    expected = max(-peak, min(peak, bias * 2 * peak / 32768))
    assert abs(expected) == peak or expected == 0.48828125 * peak
    assert np.all(r.traces.command == bias)
    # PMD-A13: the command reaches the amplifier one axis slot (here the whole period) after
    # its sample, so tick 0 still holds the reset's zero current.
    assert r.traces.current_a[0] == 0.0
    assert np.all(r.traces.current_a[1:] == expected)


def test_episode_results_are_frozen():
    plant = get_plant("rotary").build()
    r = ServoLoop(plant, PMDParams(**OFF)).run(hold([0, 0]), traces=True)
    with pytest.raises(dataclasses.FrozenInstanceError):
        r.traces = None
    with pytest.raises(dataclasses.FrozenInstanceError):
        r.traces.command = None


@pytest.mark.parametrize("sign", [1, -1])
def test_runner_metrics_follow_their_definitions_on_a_real_move(sign):
    # The runner derives move_end, the target, the direction and the default band
    # (max(4, 0.2 % of the distance)) from the profile; recompute each metric from the
    # traces by its docstring definition.
    from tests.sim.test_runner import small_move

    plant = get_plant("rotary").build()
    profile = small_move(plant, 3000)
    profile.position = sign * profile.position
    params = PMDParams(model="MC2100", kp=3000, kd=30000, ki=100)
    r = ServoLoop(plant, params).run(profile, traces=True)
    m, t = r.metrics, r.traces
    assert not m.diverged
    pos = t.commanded
    move_end = int(np.flatnonzero(np.diff(pos, prepend=0) != 0)[-1])
    target, distance = int(pos[-1]), int(pos[-1])
    band = max(4.0, 0.002 * abs(distance))
    after = slice(move_end + 1, None)
    past = (t.actual[after] - target) * sign
    assert m.overshoot == max(0, past.max()) and m.overshoot > 0
    outside = np.flatnonzero(np.abs(t.error[after]) > band)
    last_out = move_end + 1 + int(outside[-1]) if outside.size else -1
    n = m.n_ticks
    settled = last_out < n - 1
    assert m.settled == settled
    ticks = max(last_out + 1, move_end) - move_end if settled else n - move_end
    assert m.settling_time == pytest.approx(ticks * m.dt)
    assert m.max_following_error == np.abs(t.error[: move_end + 1]).max()
    assert np.array_equal(t.time_s, np.arange(n) * m.dt)
    assert m.divergence_tick == -1 and m.divergence_reason == "none"
    assert np.array_equal(t.error, pos - t.actual)


def test_a_non_finite_state_ends_the_episode_on_its_tick():
    # A first episode fills the trace buffers; then the plant's state is made non-finite
    # and the next episode continues from it (reset=False): it ends at tick 0 with the
    # actual position reported as 0 (no earlier tick), command 0, the current kept.
    plant = get_plant("rotary").build()
    loop = ServoLoop(plant, PMDParams(**{**OFF, "bias": 3000, "kout": 0}))
    first = loop.run(hold([0] * 300), traces=True)
    assert first.traces.actual[-1] != 0 and first.traces.current_a[-1] != 0
    plant.data.qvel[plant.io.qvel_adr] = np.nan
    r = loop.run(hold([0] * 300), traces=True, reset=False)
    m = r.metrics
    assert m.diverged and m.divergence_reason == "non_finite_state"
    assert m.n_ticks == 1 and m.divergence_tick == 0
    assert r.traces.actual.tolist() == [0] and r.traces.command.tolist() == [0]
    assert r.traces.current_a[0] == first.traces.current_a[-1]


def test_current_loop_time_constant_by_hand():
    # tau = 1 / (2 pi bw): bw = 1000 Hz gives 159.15 us; 0 Hz is an ideal loop (tau 0).
    from servogym.sim._runner import current_loop_tau

    assert current_loop_tau(1000.0) == pytest.approx(1.5915494e-4, rel=1e-7)
    assert current_loop_tau(0.0) == 0.0


def test_runner_without_a_move_measures_the_whole_episode():
    # A profile that never changes (move_end = -1): the largest error over every tick, and
    # no direction, so no overshoot. The bias pushes the axis away: the error grows.
    plant = get_plant("rotary").build()
    r = ServoLoop(plant, PMDParams(**{**OFF, "bias": 3000, "kout": 0})).run(
        hold([0] * 300), traces=True
    )
    err = np.abs(r.traces.error)
    assert err[-1] == err.max() > err[0]
    assert r.metrics.max_following_error == err.max() and r.metrics.overshoot == 0


@pytest.mark.parametrize("sign", [1, -1])
def test_runner_step_at_tick_zero_has_a_direction(sign):
    # The commanded position jumps at tick 0 and holds (move_end = 0): the overshoot is
    # measured in the step's direction from tick 1 on.
    plant = get_plant("rotary").build()
    params = PMDParams(model="MC2100", kp=300, kd=2000, ki=0)
    step = 200 * sign
    r = ServoLoop(plant, params).run(hold([step] * 1500), traces=True)
    past = (r.traces.actual[1:] - step) * sign
    assert r.metrics.overshoot == past.max() > 0


@pytest.mark.parametrize("side", ["lower", "upper"])
def test_travel_bounds_at_equality(side):
    # The bound is crossed when q < lo or q > hi: a position exactly on it is not. The plant
    # is placed there and the episode continues from it (reset=False); no torque.
    plant = get_plant("rotary").build()
    io = plant.io
    span = io.travel_max - io.travel_min
    lo, hi = io.travel_min + 0.01 * span, io.travel_max - 0.01 * span
    loop = ServoLoop(plant, PMDParams(**OFF), max_error_counts=2**31 - 1)
    loop.run(hold([0]))
    plant.data.qpos[io.qpos_adr] = lo if side == "lower" else hi
    plant.data.qvel[io.qvel_adr] = 0.0
    r = loop.run(hold([0]), reset=False)
    assert not r.metrics.diverged
    plant.data.qpos[io.qpos_adr] = np.nextafter(lo, -np.inf) if side == "lower" else (
        np.nextafter(hi, np.inf))  # fmt: skip
    r = loop.run(hold([0]), reset=False)
    assert r.metrics.divergence_reason == "travel_limit"


def test_amplifier_current_carries_over_after_a_divergence():
    # A lagging current loop (tau = 1/(2 pi 500 Hz)) and a constant command: the current and
    # the reference in effect when the divergent episode stops are where the next episode
    # (reset=False) starts. With PMD-A13 (latency = the whole period here) the command of
    # tick k acts during tick k+1; its mean current over a tick from i0 towards r is
    # r + (i0 - r) * tau / T * (1 - exp(-T / tau)).
    import math

    from servogym.sim._runner import current_loop_tau

    family = get_plant("rotary")
    plant = family.build({**family.nominal(), "current_bandwidth_hz": 500.0})
    params = PMDParams(**{**OFF, "bias": 3000, "kout": 0})
    loop = ServoLoop(plant, params, max_error_counts=10)
    first = loop.run(hold([0, 0, 0, -100, -100]), traces=True)
    assert first.metrics.divergence_reason == "error_bound" and first.metrics.n_ticks == 4
    tau, dt = current_loop_tau(500.0), loop.dt
    r = 3000 * plant.io.amp_amps_per_count
    # the current at the start of tick 3 (where the episode stopped): three ticks of the
    # command's current from 0, the first of them still at the old (zero) reference
    i0 = r * (1 - math.exp(-2 * dt / tau))
    nxt = loop.run(hold([0]), traces=True, reset=False)
    mean = r + (i0 - r) * tau / dt * (1 - math.exp(-dt / tau))
    assert nxt.traces.current_a[0] == pytest.approx(mean, rel=1e-12)


def test_metrics_without_a_move_always_inside_settle_at_once():
    # No move, |e| <= band on every tick: settled from tick 0, settling time 0; one tick too.
    m = metrics_of([0, 0, 0], [1, 0, -1], [0] * 3, move_end=-1, target=0, direction=0)
    assert m["settled"] == 1.0 and m["settling_time"] == 0.0
    m = metrics_of([0], [0], [0], move_end=-1, target=0, direction=0)
    assert m["settled"] == 1.0 and m["settling_time"] == 0.0
