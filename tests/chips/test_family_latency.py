"""Each family's loop latency (PMD-A13, PMAC-A14, PK-A9) and the value that turns its
following-error trip off, by hand from the specs (docs/chips/*.md)."""

from __future__ import annotations

import pytest

from servogym.chips import ParameterError, all_models, get_chip


def _latency(model: str, choice: str, **values):
    family, model = get_chip(model)
    params = family.make_params(model, values)
    asm = family.assumptions_type(loop_latency=choice)
    return family.loop_latency_s(params, asm), family.sample_time_s(params)


@pytest.mark.parametrize("model", all_models())
@pytest.mark.parametrize(
    ("choice", "fraction"), [("same_tick", 0.0), ("half_period", 0.5), ("full_period", 1.0)]
)
def test_the_shared_latencies_are_fractions_of_the_period(model, choice, fraction):
    latency, period = _latency(model, choice)
    assert latency == fraction * period


@pytest.mark.parametrize(("model", "slot_us"), [("MC2100", 154), ("MC3110", 154), ("MC58000", 52)])
def test_pmd_axis_slot_is_one_slot_whatever_the_period(model, slot_us):
    # PMD-A13: the filter of one axis runs in its own slot of the model's shortest one-axis
    # period (154 us Navigator/Pilot, 52 us Magellan); a longer SetSampleTime adds idle
    # time after it, not latency. At the shortest period the slot is the whole period.
    latency, period = _latency(model, "axis_slot")
    assert latency == pytest.approx(slot_us * 1e-6, rel=1e-12)
    assert period == pytest.approx(slot_us * 1e-6, rel=1e-12)
    latency, period = _latency(model, "axis_slot", sample_time_us=4 * slot_us)
    assert latency == pytest.approx(slot_us * 1e-6, rel=1e-12)
    assert period == pytest.approx(4 * slot_us * 1e-6, rel=1e-12)


def test_pmac_phase_edge_is_a_phase_period():
    # PMAC-A14: the command goes out at the next phase-clock edge. Factory clocks: the
    # servo period (2 I7000 + 3)(I7001 + 1)(I7002 + 1) / 120 MHz = 6527 * 1 * 4 / 120e6 ...
    # is 442.74 us (docs/chips/pmac.md); a phase period is that over I7002 + 1 = 4.
    latency, period = _latency("TurboPMAC2", "phase_edge")
    family, model = get_chip("TurboPMAC2")
    params = family.make_params(model, {})
    assert params.servo_clock_divider == 3
    assert latency == pytest.approx(params.servo_period_s / 4, rel=1e-12)
    assert latency == pytest.approx(110.69e-6, abs=0.01e-6)
    # I7002 = 0: one phase period per servo period: the latency is the whole servo period.
    latency, period = _latency("TurboPMAC2", "phase_edge", servo_clock_divider=0)
    assert latency == pytest.approx(period, rel=1e-12)


def test_parker_has_no_latency_of_its_own():
    # PK-A9 takes only the shared choices (its default is full_period).
    family, _ = get_chip("6250")
    assert family.assumptions_type().loop_latency == "full_period"
    with pytest.raises(ParameterError, match=r"PK-A9 loop_latency must be one of.*'phase_edge'"):
        _latency("6250", "phase_edge")


@pytest.mark.parametrize(("model", "register", "value"), [
    ("MC2100", "position_error_limit", 2**31 - 1),  # PMD-A10: the largest limit never trips
    ("MC58000", "position_error_limit", 2**31 - 1),
    ("TurboPMAC2", "fatal_following_error_limit", 0),  # Ixx11 = 0 disables the check
    ("6250", "smper", 0),  # PK-A8: SMPER0 disables it
])  # fmt: skip
def test_the_trip_is_turned_off_by_a_legal_value(model, register, value):
    family, model = get_chip(model)
    assert dict(family.error_trip_off) == {register: value}
    space = family.parameter_space(model)
    assert space[register].low <= value <= space[register].high
    family.make_params(model, {register: value})  # legal on its own
    if value:
        assert value == space[register].high
