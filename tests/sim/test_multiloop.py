"""The N-axis compiled loop: bit for bit the single-axis loop for one axis, bit for bit its
Python twin for several, each family's axis sequencing and period rule, and the coupling."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from servogym.chips import MultiAxisParams, all_models, max_axes
from servogym.chips._space import ParameterError
from servogym.plants import MULTI_PLANTS, get_plant
from servogym.sim import (
    SEQUENCING,
    MultiServoLoop,
    ServoLoop,
    axis_latencies,
    check_machine,
    machine_params,
)
from servogym.sim._loop import INTEGRATORS, REASONS, TRAVEL
from servogym.sim._machine import SIMULATOR_LIMIT
from servogym.sim._pymultiloop import python_multi_closed_loop
from servogym.sim._runner import TRAVEL_MARGIN, current_loop_tau
from tests.sim.test_runner import TWIN_PARAMS, latency_settings, ramp, small_move


def chip_params(chip: str, n_axes: int = 1):
    model, gains = TWIN_PARAMS[chip]
    return model, machine_params(model, n_axes, gains)


@pytest.mark.parametrize("chip", list(TWIN_PARAMS))
@pytest.mark.parametrize(
    ("plant_name", "integrator", "bandwidth_hz", "latency_index"),
    [("arm", "rk4", 0.0, 0), ("two-mass", "rk4", 2000.0, 1), ("vertical-axis", "euler", 0.0, 2)],
)
def test_one_axis_machine_equals_the_single_axis_loop_to_the_bit(
    chip, plant_name, integrator, bandwidth_hz, latency_index
):
    family = get_plant(plant_name)
    values = family.sample(np.random.default_rng(3))
    values["current_bandwidth_hz"] = bandwidth_hz
    model, (params,) = chip_params(chip)
    chip_family = all_models()[model]
    asm = chip_family.assumptions_type(loop_latency=latency_settings(chip)[latency_index])
    single = ServoLoop(family.build(values), params, asm, integrator=integrator)
    multi = MultiServoLoop(family.build(values), [params], asm, integrator=integrator)
    assert multi.latencies_s == [single.latency_s] and multi.substeps == single.substeps
    profile = small_move(single.plant, 400)
    a = single.run(profile, traces=True)
    b = multi.run([profile], traces=True)
    assert b.metrics[0] == a.metrics and b.axis == -1
    for name in ("actual", "command", "current_a", "error", "commanded"):
        np.testing.assert_array_equal(getattr(b.traces[0], name), getattr(a.traces, name))
    assert np.any(a.traces.command != 0)
    # a second episode continuing from the first (reset=False) stays identical too
    a2 = single.run(profile, traces=True, reset=False)
    b2 = multi.run([profile], traces=True, reset=False)
    np.testing.assert_array_equal(b2.traces[0].actual, a2.traces.actual)
    np.testing.assert_array_equal(b2.traces[0].current_a, a2.traces.current_a)


def python_twin(loop: MultiServoLoop, profiles):
    plant = loop.plant
    plant.reset()
    ios = loop.ios
    spans = [io.travel_max - io.travel_min for io in ios]
    pos = np.stack([p.position for p in profiles])
    vel = np.stack([p.velocity for p in profiles])
    acc = np.stack([p.acceleration for p in profiles])
    return python_multi_closed_loop(
        plant.model, plant.data, ios, INTEGRATORS[loop.integrator], loop.substeps,
        loop.full_stages, loop.dt, loop.latencies_s,
        [current_loop_tau(io.current_bandwidth_hz) for io in ios],
        [io.travel_min + TRAVEL_MARGIN * s for io, s in zip(ios, spans, strict=True)],
        [io.travel_max - TRAVEL_MARGIN * s for io, s in zip(ios, spans, strict=True)],
        [min(int(s * io.counts_per_unit), 2**31 - 1) for io, s in zip(ios, spans, strict=True)],
        [int(np.floor(plant.data.qpos[io.qpos_adr] * io.counts_per_unit)) - p.start
         for io, p in zip(ios, profiles, strict=True)],
        [loop.chip.reference_filter(p, loop.assumptions) for p in loop.params], pos, vel, acc,
    )  # fmt: skip


def axis_moves(plant, n_ticks, fraction):
    return [
        ramp(
            int(f * 0.02 * (io.travel_max - io.travel_min) * io.counts_per_unit),
            n_ticks // 3,
            n_ticks,
        )
        for io, f in zip(plant.ios, fraction, strict=True)
    ]


@settings(max_examples=12, deadline=None)
@given(
    chip=st.sampled_from(list(TWIN_PARAMS)),
    plant_name=st.sampled_from(list(MULTI_PLANTS)),
    latency_index=st.integers(0, 2),
    sequencing_index=st.integers(0, 1),
    integrator=st.sampled_from(["rk4", "euler"]),
    bandwidth_hz=st.sampled_from([0.0, 3000.0]),
    seed=st.integers(0, 2**16),
    fraction=st.tuples(st.floats(-1, 1), st.floats(-1, 1)),
)
def test_compiled_n_axis_loop_equals_its_python_twin(
    chip, plant_name, latency_index, sequencing_index, integrator, bandwidth_hz, seed, fraction
):
    family = MULTI_PLANTS[plant_name]
    values = family.sample(np.random.default_rng(seed))
    values["vertical" if plant_name == "two-link-arm" else "x_drive"] = seed % 2
    for axis in family.axes:
        values[f"{axis}_current_bandwidth_hz"] = bandwidth_hz
    model, params = chip_params(chip, 2)
    asm = all_models()[model].assumptions_type(loop_latency=latency_settings(chip)[latency_index])
    loop = MultiServoLoop(
        family.build(values), params, asm, integrator=integrator,
        sequencing=SEQUENCING[all_models()[model].name].choices[sequencing_index],
    )  # fmt: skip
    profiles = axis_moves(loop.plant, 45, fraction)
    result = loop.run(profiles, traces=True)
    n_run, reason, axis, actual, command, current = python_twin(loop, profiles)
    assert result.metrics[0].n_ticks == n_run and result.axis == axis
    assert result.metrics[0].divergence_reason == REASONS[reason]
    for i in range(2):
        np.testing.assert_array_equal(result.traces[i].actual, actual[i])
        np.testing.assert_array_equal(result.traces[i].command, command[i])
        np.testing.assert_array_equal(result.traces[i].current_a, current[i])


def test_pmd_sequences_its_axes_in_turn_and_its_period_follows_the_axes():
    params = machine_params("MC2100", 3)
    assert params[0].sample_time_us == 3 * 154  # the cycle is time-sliced per enabled axis
    assert axis_latencies(params) == pytest.approx([154e-6, 308e-6, 462e-6])
    assert axis_latencies(params, sequencing="simultaneous") == pytest.approx([154e-6] * 3)
    asm = all_models()["MC2100"].assumptions_type(loop_latency="full_period")
    assert axis_latencies(params, asm) == pytest.approx([462e-6] * 3)  # never past the period
    magellan = machine_params("MC58000", 4)
    assert magellan[0].sample_time_us == 4 * 52
    assert axis_latencies(magellan) == pytest.approx([52e-6, 104e-6, 156e-6, 208e-6])
    too_fast = machine_params("MC2100", 1) * 2
    with pytest.raises(ParameterError, match=r"308 <= sample_time_us <= 65535 for 2 enabled axes"):
        check_machine(too_fast)
    with pytest.raises(ParameterError, match="at most 1 axes"):
        machine_params("MC3110", 2)  # a Pilot is a one-axis chip


def test_pmac_and_parker_update_every_axis_at_once_by_default():
    pmac = machine_params("TurboPMAC2", 8)
    period = pmac[0].sample_time_s
    assert pmac[0].sample_time_us == machine_params("TurboPMAC2", 1)[0].sample_time_us
    phase = period / 4  # PMAC-A14 phase_edge at the default clocks (I7002 = 3)
    assert axis_latencies(pmac) == pytest.approx([phase] * 8)
    staggered = axis_latencies(pmac, sequencing="in_turn")
    assert staggered == pytest.approx([phase + k * 0.01 * period for k in range(8)])
    six = machine_params("6250", 2)
    assert axis_latencies(six) == pytest.approx([six[0].sample_time_s] * 2)  # PK-A9 full period
    assert axis_latencies(six, all_models()["6250"].assumptions_type(loop_latency="same_tick"),
                          "in_turn") == pytest.approx([0.0, six[0].sample_time_s / 2])  # fmt: skip
    with pytest.raises(ParameterError, match="PK-M1 sequencing must be one of 'each_sample'"):
        axis_latencies(six, sequencing="in_turm")
    with pytest.raises(ParameterError, match="at most 2 axes"):
        machine_params("6250", 3)


def test_a_controller_is_one_chip_model_at_one_period():
    a = machine_params("MC2100", 2)
    b = machine_params("MC2300", 2)
    with pytest.raises(ParameterError, match="same chip model; axis 1 is 'MC2100'"):
        check_machine([a[0], b[1]])
    slow = all_models()["MC2100"].make_params("MC2100", {"sample_time_us": 500})
    with pytest.raises(ParameterError, match="sample_time_us is one setting of the whole"):
        check_machine([a[0], slow])
    with pytest.raises(ParameterError, match="one parameter set per axis, got 1"):
        MultiServoLoop(MULTI_PLANTS["xy-stage"].build(), a[:1])
    with pytest.raises(ParameterError, match="params must be parameter sets, one per axis"):
        check_machine(a[0])


def test_check_machine_and_max_axes_agree_for_every_model():
    """One source of the axis count: the sim takes as many axes as the chip layer's
    max_axes (a Geo Brick LV 8 motors, not the 32 its firmware addresses) and no more."""
    for model in all_models():
        most = max_axes(model)
        sets = machine_params(model, most)
        assert check_machine(sets) is all_models()[model]
        assert check_machine(MultiAxisParams(sets)) is all_models()[model]
        with pytest.raises(ParameterError, match=rf"the {model} drives at most {most} "):
            machine_params(model, most + 1)
        with pytest.raises(ParameterError, match=rf"the {model} drives at most {most} "):
            check_machine(sets + sets[:1])


def test_the_only_simulator_limit_is_one_filter_period():
    """A PMAC servoes motors at different Ixx60 (the controller takes it); the N-axis loop
    runs one period, and says that this is its own limit."""
    pmac = all_models()["TurboPMAC2"]
    sets = [pmac.make_params("TurboPMAC2", {"servo_cycle_extension": e}) for e in (0, 1)]
    assert MultiAxisParams(sets).numbers == (1, 2)
    assert SIMULATOR_LIMIT.startswith("the N-axis loop runs every axis at one servo period")
    with pytest.raises(ParameterError, match=r"Ixx60.*a limit of this simulator.*motor 1 at"):
        check_machine(sets)


def test_the_loop_takes_a_multi_axis_params_or_a_mapping():
    _model, params = chip_params("pmac", 2)
    stage = MULTI_PLANTS["xy-stage"].build()
    profiles = axis_moves(stage, 60, (1.0, 1.0))
    by_list = MultiServoLoop(stage, params).run(profiles)
    for sets in (MultiAxisParams(params), {1: params[0], 2: params[1]}):
        loop = MultiServoLoop(stage, sets)
        assert loop.params == params
        assert loop.run(profiles).metrics == by_list.metrics


def test_the_elbow_moving_alone_torques_the_shoulder():
    arm = MULTI_PLANTS["two-link-arm"].build()
    _model, params = chip_params("pmd", 2)
    loop = MultiServoLoop(arm, params)
    hold, elbow = axis_moves(arm, 600, (0.0, 1.0))
    result = loop.run([hold, elbow], traces=True)
    shoulder = result.traces[0]
    assert not result.metrics[1].diverged and np.all(shoulder.commanded == 0)
    assert np.abs(shoulder.error).max() > 0 and np.abs(shoulder.command).max() > 0
    # the same elbow move on an arm whose upper link is immovable leaves the shoulder at rest
    stage = MULTI_PLANTS["xy-stage"].build()
    still, y = axis_moves(stage, 600, (0.0, 1.0))
    res = MultiServoLoop(stage, params).run([still, y], traces=True)
    assert np.all(res.traces[0].error == 0)  # X does not feel Y's motion (orthogonal slides)


def test_a_diverging_axis_is_named_and_ends_every_axis():
    stage = MULTI_PLANTS["xy-stage"].build()
    _model, params = chip_params("pmd", 2)
    loop = MultiServoLoop(stage, params)
    io = stage.ios[1]
    far = int(0.995 * io.travel_max * io.counts_per_unit)  # beyond the travel margin
    hold, _ = axis_moves(stage, 2000, (0.0, 0.0))
    result = loop.run([hold, ramp(far, 600, 2000)])
    assert result.axis == 1 and result.metrics[1].divergence_reason == REASONS[TRAVEL]
    assert result.metrics[0].diverged and result.metrics[0].n_ticks < 2000


@pytest.mark.parametrize(("family", "doc"), [("pmd", "pmd"), ("pmac", "pmac"),
                                             ("parker6k", "parker6k")])  # fmt: skip
def test_each_chip_spec_documents_its_sequencing_switch(family, doc):
    import pathlib

    text = (pathlib.Path(__file__).parents[2] / "docs" / "chips" / f"{doc}.md").read_text()
    seq = SEQUENCING[family]
    default, *alternatives = seq.choices
    row = f"| {seq.ident} | `sequencing` | `{default}` | " + ", ".join(
        f"`{a}`" for a in alternatives
    )
    assert row + " |" in text


@pytest.mark.parametrize(
    ("plant_name", "changes"),
    [
        ("xy-stage", {"x_screw_lead_m": 0.02, "x_peak_current_a": 5.0}),
        ("two-link-arm", {"shoulder_gear_ratio": 80.0, "elbow_encoder_counts_per_rev": 65536}),
    ],
)
def test_a_plant_edited_in_place_runs_as_a_fresh_build_of_it(plant_name, changes):
    family = MULTI_PLANTS[plant_name]
    _model, params = chip_params("pmd", 2)
    plant = family.build()
    loop = MultiServoLoop(plant, params)
    before = plant.ios
    plant.set_params(changes)
    assert plant.ios != before  # encoder, gearing or amplifier changed
    loop.set_params(params)
    fresh = MultiServoLoop(family.build(changes), params)
    assert loop.ios == fresh.ios == plant.ios
    profiles = axis_moves(fresh.plant, 300, (1.0, -0.5))
    a = loop.run(profiles, traces=True)
    b = fresh.run(profiles, traces=True)
    assert a.metrics == b.metrics
    for i in range(2):
        np.testing.assert_array_equal(a.traces[i].actual, b.traces[i].actual)
        np.testing.assert_array_equal(a.traces[i].current_a, b.traces[i].current_a)


def test_set_params_refuses_a_set_count_other_than_the_axes():
    _model, params = chip_params("pmd", 2)
    loop = MultiServoLoop(MULTI_PLANTS["xy-stage"].build(), params)
    with pytest.raises(ParameterError, match=r"'xy-stage' plant has 2 axes.*got 1"):
        loop.set_params(params[:1])
    with pytest.raises(ParameterError, match=r"'xy-stage' plant has 2 axes.*got 3"):
        loop.set_params(machine_params("MC2100", 3))
    assert loop.params == params  # a refused call changes nothing
    hold = axis_moves(loop.plant, 10, (0.0, 0.0))
    with pytest.raises(ValueError, match=r"one start_counts per axis \(2\); got 1"):
        loop.run(hold, start_counts=[0])
