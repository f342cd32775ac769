"""The reference amplifier and encoder models do what docs/plants.md says."""

import itertools
import math

import numpy as np
import pytest

from servogym.plants import (
    PLANTS,
    amplifier_alpha,
    amplifier_current,
    encoder_counts,
    motor_torque,
)

IO = PLANTS["rotary"].build().io  # peak 10 A, kt 0.2 N*m/A, ideal current loop
LAGGED = PLANTS["rotary"].build({"current_bandwidth_hz": 2000.0}).io


def test_ideal_amplifier_maps_commands_to_current():
    assert amplifier_current(0, 5.0, IO, 1e-4) == 0.0
    assert amplifier_current(-32768, 0.0, IO, 1e-4) == -IO.peak_current_a
    assert amplifier_current(32767, 0.0, IO, 1e-4) == 32767 * (10.0 / 32768)
    assert amplifier_current(16384, 0.0, IO, 1e-4) == 5.0
    assert amplifier_current(-1, 0.0, IO, 1e-4) == -10.0 / 32768


def test_commands_outside_16_bits_saturate():
    assert amplifier_current(10**6, 0.0, IO, 1e-4) == amplifier_current(32767, 0.0, IO, 1e-4)
    assert amplifier_current(-(10**6), 0.0, IO, 1e-4) == -IO.peak_current_a
    for c in range(-40000, 40001, 997):
        assert abs(amplifier_current(c, 0.0, IO, 1e-4)) <= IO.peak_current_a


def test_current_loop_is_a_first_order_lag():
    dt = 154e-6
    alpha = amplifier_alpha(2000.0, dt)
    assert alpha == 1.0 - math.exp(-2.0 * math.pi * 2000.0 * dt)
    assert amplifier_alpha(0.0, dt) == 1.0
    i, trace = 0.0, []
    for _ in range(50):
        i = amplifier_current(16384, i, LAGGED, dt)
        trace.append(i)
    assert trace[0] == 0.0 + (5.0 - 0.0) * alpha
    # The exact recurrence, step by step: i += (i_ref - i) * alpha.
    expected, j = [], 0.0
    for _ in range(50):
        j = j + (5.0 - j) * alpha
        expected.append(j)
    assert trace == expected
    assert np.all(np.diff(trace) >= 0) and trace[-1] == pytest.approx(5.0, rel=1e-12)
    # 63 % of a step after one time constant 1 / (2*pi*bandwidth).
    tau_steps = 1 / (2 * math.pi * 2000.0) / 1e-6
    i = 0.0
    for _ in range(round(tau_steps)):
        i = amplifier_current(32767, i, LAGGED, 1e-6)
    assert i / (32767 * LAGGED.amp_amps_per_count) == pytest.approx(1 - math.exp(-1), abs=2e-3)


def test_a_bandwidth_whose_alpha_rounds_to_one_is_an_ideal_loop():
    fast = PLANTS["rotary"].build({"current_bandwidth_hz": 10000.0}).io
    assert amplifier_alpha(10000.0, 700e-6) == 1.0
    assert amplifier_current(12345, 0.1, fast, 700e-6) == 12345 * fast.amp_amps_per_count


def test_motor_torque():
    assert motor_torque(IO.peak_current_a, IO) == IO.peak_torque_nm == 2.0


def test_encoder_quantises_with_floor():
    cpu = IO.counts_per_unit
    assert cpu == 131072 / (2 * math.pi)
    assert encoder_counts(0.0, IO) == 0
    assert encoder_counts(0.999 / cpu, IO) == 0
    assert encoder_counts(1.001 / cpu, IO) == 1
    assert encoder_counts(-1e-12, IO) == -1
    assert encoder_counts(2 * math.pi, IO) == 131072
    assert isinstance(encoder_counts(1.0, IO), int)
    slide = PLANTS["vertical-axis"].build().io
    assert slide.counts_per_unit == 131072 / 0.01
    assert encoder_counts(0.01, slide) == 131072  # one screw lead is one motor revolution
    arm = PLANTS["arm"].build().io
    assert arm.counts_per_unit == 131072 * 10.0 / (2 * math.pi)


@pytest.mark.parametrize("name", list(PLANTS))
def test_counts_fit_in_32_bits_over_the_legal_travel(name):
    """In every corner of the ranges, the encoder reading at the end stops fits an int32."""
    family = PLANTS[name]
    worst = 0.0
    ranges = [(p.low, p.high) for p in family.params]
    for corner in itertools.product(*ranges):
        values = dict(zip([p.name for p in family.params], corner, strict=True))
        _, counts_per_unit = family._transmission(values)
        travel = max(
            values[f"travel_max_{family.joint_unit}"], -values[f"travel_min_{family.joint_unit}"]
        )
        worst = max(worst, travel * counts_per_unit)
    assert worst < 2**31 - 1


def test_numba_copy_of_the_documented_arithmetic_is_bit_identical():
    """The compiled runner can match the reference exactly (fastmath off, alpha passed in)."""
    numba = pytest.importorskip("numba")

    @numba.njit(cache=False)
    def kernel(commands, qpos, amps_per_count, peak, alpha, kt, counts_per_unit):
        n = commands.shape[0]
        torque = np.empty(n)
        counts = np.empty(n, dtype=np.int64)
        i = 0.0
        for k in range(n):
            c = min(max(commands[k], -32768), 32767)
            i_ref = float(c) * amps_per_count
            if i_ref > peak:
                i_ref = peak
            if i_ref < -peak:
                i_ref = -peak
            i = i_ref if alpha >= 1.0 else i + (i_ref - i) * alpha
            torque[k] = i * kt
            counts[k] = np.int64(np.floor(qpos[k] * counts_per_unit))
        return torque, counts

    rng = np.random.default_rng(0)
    commands = rng.integers(-40000, 40000, 5000)
    for values in (
        {},
        {"current_bandwidth_hz": 1234.5, "peak_current_a": 7.3},
        {"current_bandwidth_hz": 10000.0},
    ):
        io = PLANTS["arm"].build(values).io
        qpos = rng.uniform(io.travel_min, io.travel_max, commands.size)
        dt = 154e-6 if values.get("current_bandwidth_hz") != 10000.0 else 700e-6  # alpha == 1
        got_torque, got_counts = kernel(
            commands,
            qpos,
            io.amp_amps_per_count,
            io.peak_current_a,
            amplifier_alpha(io.current_bandwidth_hz, dt),
            io.torque_constant_nm_per_a,
            io.counts_per_unit,
        )
        i, want_torque = 0.0, []
        for c in commands:
            i = amplifier_current(int(c), i, io, dt)
            want_torque.append(motor_torque(i, io))
        np.testing.assert_array_equal(got_torque, want_torque)
        np.testing.assert_array_equal(got_counts, [encoder_counts(q, io) for q in qpos])
