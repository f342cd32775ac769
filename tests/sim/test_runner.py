"""The compiled closed loop: equal to its plain-Python twin, deterministic, safe on bad gains."""

from __future__ import annotations

import hashlib
import math
import subprocess
import sys
from types import SimpleNamespace

import numpy as np
import pytest

from servogym.chips import all_models
from servogym.chips.pmd import PMDParams
from servogym.plants import PLANTS, get_plant
from servogym.sim import METRIC_NAMES, ServoLoop
from servogym.sim._loop import INTEGRATORS
from servogym.sim._metrics import compute_metrics
from servogym.sim._pyloop import python_closed_loop
from servogym.sim._runner import TRAVEL_MARGIN, current_loop_tau


def ramp(distance: int, move_ticks: int, n_ticks: int) -> SimpleNamespace:
    """A commanded ramp from 0 to ``distance`` counts, then a hold (no feed-forward)."""
    pos = np.round(np.linspace(0, distance, move_ticks + 1)[1:]).astype(np.int64)
    pos = np.concatenate([pos, np.full(n_ticks - move_ticks, distance, np.int64)])
    zeros = np.zeros(n_ticks, np.int64)
    return SimpleNamespace(position=pos, velocity=zeros, acceleration=zeros.copy(), start=0)


def small_move(plant, n_ticks=600):
    io = plant.io
    distance = int(0.02 * (io.travel_max - io.travel_min) * io.counts_per_unit)
    return ramp(distance, n_ticks // 3, n_ticks)


def python_traces(loop: ServoLoop, profile) -> tuple[int, int, list, list, list]:
    """The Python twin of the loop, with the chip family's reference filter."""
    plant = loop.plant
    plant.reset()
    io = plant.io
    span = io.travel_max - io.travel_min
    return python_closed_loop(
        plant.model, plant.data, io, INTEGRATORS[loop.integrator], loop.substeps,
        loop.full_stages, loop.dt,
        loop.latency_s, current_loop_tau(io.current_bandwidth_hz),
        io.travel_min + TRAVEL_MARGIN * span, io.travel_max - TRAVEL_MARGIN * span,
        min(int(span * io.counts_per_unit), 2**31 - 1),
        int(np.floor(plant.data.qpos[io.qpos_adr] * io.counts_per_unit)) - profile.start,
        loop.chip.reference_filter(loop.params, loop.assumptions), profile.position,
        profile.velocity, profile.acceleration,
    )  # fmt: skip


TWIN_PARAMS = {
    "pmd": ("MC2100", dict(kp=300, kd=2000, ki=40)),
    "parker6k": ("6250", {}),
    "pmac": (
        "TurboPMAC2",
        dict(
            proportional_gain=60000,
            derivative_gain=3000,
            integral_gain=1000,
            fatal_following_error_limit=0,
        ),
    ),
}


def latency_settings(chip: str) -> list[str]:
    """Every ``loop_latency`` choice of a family (its default first)."""
    family = all_models()[TWIN_PARAMS[chip][0]]
    return list(family.assumptions_type.CHOICES["loop_latency"])


TWIN_CASES = [
    (chip, latency, integrator, substeps)
    for chip in sorted(TWIN_PARAMS)
    for latency in latency_settings(chip)
    for integrator, substeps in (("rk4", None), ("rk4", 3), ("euler", 1), ("euler", 2))
]


@pytest.mark.parametrize(("chip", "latency", "integrator", "substeps"), TWIN_CASES)
@pytest.mark.parametrize("plant_name", list(PLANTS))
@pytest.mark.parametrize("bandwidth_hz", [0.0, 2000.0])
def test_compiled_loop_equals_python_loop(
    chip, latency, integrator, substeps, plant_name, bandwidth_hz
):
    family = get_plant(plant_name)
    values = family.sample(np.random.default_rng(7))
    values["current_bandwidth_hz"] = bandwidth_hz  # 2000: exercise the current-loop lag
    plant = family.build(values)
    model, gains = TWIN_PARAMS[chip]
    chip_family = all_models()[model]
    params = chip_family.make_params(model, gains)
    asm = chip_family.assumptions_type(loop_latency=latency)
    loop = ServoLoop(plant, params, asm, integrator=integrator, substeps=substeps)
    profile = small_move(plant)
    result = loop.run(profile, traces=True)
    n_run, _reason, actual, command, current = python_traces(loop, profile)
    assert result.metrics.n_ticks == n_run
    np.testing.assert_array_equal(result.traces.actual, actual)
    np.testing.assert_array_equal(result.traces.command, command)
    np.testing.assert_array_equal(result.traces.current_a, current)
    assert np.any(result.traces.command != 0)


@pytest.mark.parametrize("plant_name", list(PLANTS))
def test_in_place_edit_equals_fresh_model(plant_name):
    family = get_plant(plant_name)
    a, b = (family.sample(np.random.default_rng(s)) for s in (1, 2))
    params = PMDParams(model="MC3110", kp=200, kd=1500)
    edited = family.build(a)
    loop = ServoLoop(edited, params)
    profile = small_move(edited)
    loop.run(profile)  # run instance a first, so state is left behind
    model_id = id(edited.model)
    edited.set_params(b)
    got = loop.run(profile, traces=True)
    assert id(edited.model) == model_id
    fresh = ServoLoop(family.build(b), params).run(profile, traces=True)
    np.testing.assert_array_equal(got.traces.actual, fresh.traces.actual)
    np.testing.assert_array_equal(got.traces.command, fresh.traces.command)
    assert got.metrics == fresh.metrics


def digest(plant_name: str) -> str:
    family = get_plant(plant_name)
    plant = family.build(family.sample(np.random.default_rng(3)))
    loop = ServoLoop(plant, PMDParams(model="MC58000", kp=150, kd=900, ki=30))
    r = loop.run(small_move(plant), traces=True)
    h = hashlib.sha256()
    for arr in (r.traces.actual, r.traces.command, r.traces.current_a):
        h.update(np.ascontiguousarray(arr).tobytes())
    return h.hexdigest()


def test_same_inputs_same_traces_across_runs_and_processes():
    here = {name: digest(name) for name in PLANTS}
    assert here == {name: digest(name) for name in PLANTS}
    code = (
        "import json, sys; sys.path.insert(0, 'tests/sim'); "
        "from tests.sim.test_runner import digest; from servogym.plants import PLANTS; "
        "print(json.dumps({n: digest(n) for n in PLANTS}))"
    )
    out = subprocess.run(
        [sys.executable, "-c", code], capture_output=True, text=True, check=True
    ).stdout
    import json

    assert json.loads(out.strip().splitlines()[-1]) == here


@pytest.mark.parametrize("model", sorted(all_models()))
@pytest.mark.parametrize("plant_name", list(PLANTS))
def test_every_chip_model_runs_with_every_plant(model, plant_name):
    plant = get_plant(plant_name).build()
    family = all_models()[model]
    params = family.make_params(model)
    loop = ServoLoop(plant, params)
    r = loop.run(small_move(plant, 300))
    assert r.metrics.n_ticks >= 1
    assert all(math.isfinite(getattr(r.metrics, n)) for n in METRIC_NAMES)
    assert plant.model.opt.timestep == pytest.approx(family.sample_time_s(params) / loop.substeps)


WILD = [
    dict(kp=32767, kd=32767, kout=32767, ki=32767, integration_limit=2**31 - 1),
    dict(kp=32767, kd=0, kout=32767, ki=0),
    dict(kp=0, kd=0, ki=0, bias=32767, kout=0),
    dict(kp=32767, kd=32767, kout=32767, derivative_time=32767),
]


@pytest.mark.parametrize("plant_name", list(PLANTS))
@pytest.mark.parametrize("wild", WILD, ids=range(len(WILD)))
def test_unstable_gains_end_early_with_finite_metrics(plant_name, wild):
    plant = get_plant(plant_name).build()
    params = PMDParams(model="MC2100", position_error_limit=2**31 - 1, **wild)
    r = ServoLoop(plant, params).run(small_move(plant, 3000))
    m = r.metrics
    assert all(math.isfinite(getattr(m, n)) for n in METRIC_NAMES)
    assert math.isfinite(plant.data.qpos[plant.io.qpos_adr]) or m.diverged
    if m.diverged:
        assert m.divergence_reason in {"error_bound", "travel_limit", "non_finite_state"}
        assert m.n_ticks == m.divergence_tick + 1 < 3000


def test_bias_alone_drives_into_the_travel_limit():
    plant = get_plant("rotary").build()
    params = PMDParams(model="MC2100", kp=0, kd=0, ki=0, bias=32767, kout=0,
                       position_error_limit=2**31 - 1)  # fmt: skip
    r = ServoLoop(plant, params, max_error_counts=2**31 - 1).run(ramp(0, 1, 200_000))
    assert r.metrics.diverged and r.metrics.divergence_reason == "travel_limit"


def test_chip_motion_error_ends_the_episode():
    plant = get_plant("rotary").build()
    params = PMDParams(model="MC2100", kp=1, kd=0, ki=0, position_error_limit=50)
    r = ServoLoop(plant, params).run(small_move(plant), traces=True)
    assert r.metrics.divergence_reason == "chip_motion_error"
    assert abs(r.traces.error[-1]) > 50
    assert np.all(np.abs(r.traces.error[:-1]) <= 50)
    assert r.traces.command[-1] == 0  # PMD-A10: the chip stops driving the motor


def test_substeps_set_the_timestep():
    plant = get_plant("rotary").build()
    ServoLoop(plant, PMDParams(model="MC2100"), substeps=4)
    assert plant.model.opt.timestep == pytest.approx(154e-6 / 4)
    with pytest.raises(ValueError, match="substeps must be an integer >= 1; got substeps=0"):
        ServoLoop(plant, PMDParams(model="MC2100"), substeps=0)


# --- metrics on hand-made traces --------------------------------------------------------


def metrics_of(commanded, actual, command, move_end, target, direction, band=1.0, limit=100):
    c, a, u = (np.asarray(x, np.int64) for x in (commanded, actual, command))
    vals = compute_metrics(c, a, u, len(c), move_end, target, direction, 0.5, band, limit)
    return dict(zip([*METRIC_NAMES, "settled"], vals.tolist(), strict=True))


def test_metrics_by_hand():
    # dt = 0.5 s. Move 0 -> 10 ends at tick 2; actual overshoots to 12 and settles at tick 5.
    commanded = [5, 10, 10, 10, 10, 10, 10, 10, 10, 10]
    actual = [0, 4, 9, 12, 11, 10, 10, 10, 10, 10]
    command = [50, 100, 100, -100, -50, 0, 0, 0, 0, 0]
    m = metrics_of(commanded, actual, command, move_end=2, target=10, direction=1)
    errors = [5, 6, 1, -2, -1, 0, 0, 0, 0, 0]
    assert m["iae"] == 0.5 * 15
    assert m["itae"] == 0.25 * sum(k * abs(e) for k, e in enumerate(errors))
    assert m["max_following_error"] == 6  # during ticks 0..2
    assert m["overshoot"] == 2  # 12 - 10 after the move
    # |e| > band (1) last at tick 3; inside from tick 4: (4 - 2) ticks * 0.5 s.
    assert m["settling_time"] == 1.0 and m["settled"] == 1.0
    assert m["steady_state_error"] == 0.0  # last 10 % = the last tick
    assert m["rms_command"] == pytest.approx(math.sqrt((3 * 100**2 + 2 * 50**2) / 10) / 32768)
    assert m["saturation_fraction"] == 0.3  # |command| >= limit 100 at ticks 1, 2, 3
    assert m["chatter"] == pytest.approx((50 + 0 + 200 + 50 + 50) / 9 / 32768)


def test_metrics_never_settled_and_negative_move():
    commanded = [-5, -10, -10, -10]
    actual = [0, -3, -13, -14]
    m = metrics_of(commanded, actual, [0, 0, 0, 0], move_end=1, target=-10, direction=-1)
    assert m["overshoot"] == 4  # -14 is 4 counts past -10 in the move's direction
    assert m["settled"] == 0.0
    assert m["settling_time"] == 1.5  # from tick 1 to the end (4 - 1 ticks)


@pytest.mark.parametrize("plant_name", ["vertical-axis", "two-mass"])
def test_consecutive_moves_continue_exactly(plant_name):
    # Two calls, the second with reset=False, equal one call over the joined profile:
    # plant, filter state, amplifier current and encoder origin all carry over.
    family = get_plant(plant_name)
    values = {**family.nominal(), "current_bandwidth_hz": 1500.0}
    params = PMDParams(model="MC2100", kp=300, kd=2000, ki=200)
    first = small_move(family.build(values), 400)
    back = ramp(-int(first.position[-1]), 150, 300)
    back.position = back.position + first.position[-1]
    back.start = int(first.position[-1])
    loop = ServoLoop(family.build(values), params)
    a = loop.run(first, traces=True)
    b = loop.run(back, traces=True, reset=False)
    joined = SimpleNamespace(
        position=np.concatenate([first.position, back.position]),
        velocity=np.zeros(700, np.int64),
        acceleration=np.zeros(700, np.int64),
        start=0,
    )
    whole = ServoLoop(family.build(values), params).run(joined, traces=True)
    for name in ("actual", "command", "current_a"):
        np.testing.assert_array_equal(
            np.concatenate([getattr(a.traces, name), getattr(b.traces, name)]),
            getattr(whole.traces, name),
        )
