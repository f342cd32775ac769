"""The PMAC and Parker 6K gain maps: what they realise, legality, and the classical tuners."""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from servogym.autotune import ServoDesign, design_registers, gain_map_for, run_study
from servogym.autotune._gains import Parker6kGainMap, PMACGainMap
from servogym.chips._family import get_chip
from servogym.chips.parker6k import Parker6kAssumptions, Parker6kReferenceFilter
from servogym.chips.pmac import PMACReferenceFilter
from servogym.sim import Evaluator

from .helpers import short_problem

PMAC_MODELS = ("TurboPMAC2", "GeoBrickLV")
PARKER_MODELS = ("6250", "6K")
PARKER_ASSUMPTIONS = [
    Parker6kAssumptions(),
    Parker6kAssumptions(velocity_feedback="error_rate"),
    Parker6kAssumptions(gain_unit="mV"),
]


def _base(model, **changes):
    family, model = get_chip(model)
    values = {**family.parameter_space(model).defaults(), **changes}
    return family.make_params(model, values), values


def _realise(model, design, assumptions=None, **changes):
    """The legal parameter set the family's map gives ``design`` (validated)."""
    base, values = _base(model, **changes)
    regs = design_registers(design, base, values, assumptions)
    family, model = get_chip(model)
    return family.make_params(model, regs), regs, base


def test_both_families_are_registered():
    assert isinstance(gain_map_for("pmac"), PMACGainMap)
    assert isinstance(gain_map_for("parker6k"), Parker6kGainMap)


# ------------------------------------------------------------------------------------------
# Round trip: design -> registers -> design, within one register step
# ------------------------------------------------------------------------------------------

REALISTIC = ServoDesign(
    p=12.5, i=300.0, d=0.021, integral_limit=4000.0, vff=0.004, aff=9.5e-5, bias=-310.0,
    motor_limit=20000.0,
)  # fmt: skip


@pytest.mark.parametrize("model", PMAC_MODELS)
@pytest.mark.parametrize("scales", [(96, 96), (1000, 250)])
def test_pmac_round_trip_within_one_register_step(model, scales):
    _, regs, base = _realise(
        model, REALISTIC, position_loop_scale=scales[0], velocity_loop_scale=scales[1]
    )
    back = PMACGainMap().design(regs, base)
    dt = base.sample_time_s
    ix08, ix09, kp = scales[0], scales[1], regs["proportional_gain"]
    unit_v = kp * ix08 * dt / 2**26  # one step of Ixx32 (command per count/s)
    step_d = kp * ix09 * dt / 2**26
    assert back.p == pytest.approx(REALISTIC.p, abs=0.5 * ix08 / 2**19)
    assert back.d == pytest.approx(REALISTIC.d, abs=0.5 * step_d)
    assert back.vff == pytest.approx(REALISTIC.vff, abs=0.5 * (unit_v + step_d))
    assert back.aff == pytest.approx(REALISTIC.aff, abs=0.5 * unit_v * dt)
    assert back.i == pytest.approx(REALISTIC.i, abs=0.5 * kp * ix08 / (dt * 2**42))
    assert back.integral_limit == pytest.approx(
        REALISTIC.integral_limit, abs=0.5 * ix08 * kp / 2**23
    )
    assert back.bias == REALISTIC.bias and back.motor_limit == REALISTIC.motor_limit
    assert regs["integration_mode"] == 0  # integrate while moving, as the design does
    # Mapping the recovered design again gives the same registers.
    again = design_registers(back, base, dict(regs))
    assert {k: again[k] for k in regs} == regs


@pytest.mark.parametrize("model", PARKER_MODELS)
@pytest.mark.parametrize("assumptions", PARKER_ASSUMPTIONS, ids=["uV", "error_rate", "mV"])
def test_parker_round_trip_within_one_register_step(model, assumptions):
    _, regs, base = _realise(model, REALISTIC, assumptions)
    back = Parker6kGainMap().design(regs, base, assumptions)
    c = (1e9 if assumptions.gain_unit == "uV" else 1e6) / 32768  # q per command count
    mv = 10000 / 32768
    assert back.p == pytest.approx(REALISTIC.p, abs=0.5 / c)
    assert back.d == pytest.approx(REALISTIC.d, abs=0.5 / c)
    assert back.vff == pytest.approx(REALISTIC.vff, abs=1.0 / c)
    assert back.aff == pytest.approx(REALISTIC.aff, abs=0.5 / (100 * c))
    assert back.i == pytest.approx(REALISTIC.i, abs=0.5 / c)
    assert back.integral_limit == pytest.approx(REALISTIC.integral_limit, abs=0.5 / mv)
    assert back.bias == pytest.approx(REALISTIC.bias, abs=0.5 / mv)
    again = design_registers(back, base, dict(regs), assumptions)
    assert {k: again[k] for k in regs} == regs


def test_parker_worked_example_units():
    # SGP85 (8500 steps of 0.01 uV/count) is 85 uV per count: 85e-6 / 10 V * 32768 command
    # counts per count of error.
    _, regs, _ = _realise("6250", ServoDesign(p=85e-6 / 10 * 32768, d=2.3e-6 / 10 * 32768))
    assert regs["sgp"] == 8500 and regs["sgv"] == 230 and regs["sgvf"] == 230


# ------------------------------------------------------------------------------------------
# The chip's own arithmetic realises the design (open loop, reference filters)
# ------------------------------------------------------------------------------------------


def _trajectories(n=400, seed=0):
    """Commanded and actual positions (counts) that move, accelerate and disagree.

    They start together (no step on the first update) and the commanded acceleration is
    -1, 0 or 1 count per update^2, switching every 40 updates.
    """
    rng = np.random.default_rng(seed)
    acc = np.repeat(rng.integers(-1, 2, n // 40), 40)
    vel = np.cumsum(acc)
    commanded = 1000 + np.cumsum(vel)
    wobble = np.round(60 * np.sin(np.arange(n) / 17.0) + 0.1 * np.arange(n))
    actual = commanded - wobble.astype(np.int64)
    return commanded.astype(np.int64), actual.astype(np.int64)


def _signals(commanded, actual, dt, integral_before):
    """Error, velocities, acceleration and integral as the design sees them."""
    e = (commanded - actual).astype(float)
    cv = np.diff(commanded, prepend=actual[0]) / dt  # first update: from the actual position
    av = np.diff(actual, prepend=actual[0]) / dt
    ca = np.diff(cv, prepend=0.0) / dt
    integral = np.cumsum(e) * dt
    if integral_before:  # PMAC-A2: the output of update n integrates the errors before n
        integral = np.concatenate([[0.0], integral[:-1]])
    return {"e": e, "cv": cv, "av": av, "ca": ca, "integral": integral}


def _ideal(design, s):
    """The design's command (DAC bits), unrounded."""
    feedback = design.d * (s["cv"] - s["av"]) + design.p * s["e"] + design.i * s["integral"]
    return design.bias + feedback + design.vff * s["cv"] + design.aff * s["ca"]


def _tolerance(s, steps, bias_step=0.0):
    """Half a register step of every term, the bias step, and 2 bits of output rounding."""
    return 2.0 + bias_step + 0.5 * (
        steps["p"] * np.abs(s["e"]) + steps["i"] * np.abs(s["integral"])
        + steps["d"] * np.abs(s["cv"] - s["av"]) + steps["v"] * np.abs(s["cv"])
        + steps["a"] * np.abs(s["ca"])
    )  # fmt: skip


DESIGN = ServoDesign(p=20.0, i=200.0, d=0.01, integral_limit=30000.0, vff=0.002, aff=1e-4,
                     bias=25.0)  # fmt: skip
"""Within every register's range on both families (Parker's SGI stops at i = 327.68)."""


@pytest.mark.parametrize("model", PMAC_MODELS)
def test_the_pmac_filter_computes_the_designed_command(model):
    params, regs, _ = _realise(model, DESIGN)
    commanded, actual = _trajectories()
    dt = params.sample_time_s
    out = np.array(PMACReferenceFilter(params).run(commanded, actual, np.zeros_like(commanded)))
    s = _signals(commanded, actual, dt, integral_before=True)
    ideal = _ideal(DESIGN, s)
    assert np.abs(ideal).max() < 15000  # no saturation in the comparison
    kp, ix08 = regs["proportional_gain"], params.position_loop_scale
    unit = kp * ix08 * dt / 2**26  # Ixx08 = Ixx09 here
    steps = {"p": ix08 / 2**19, "i": kp * ix08 / (dt * 2**42), "d": unit, "v": unit,
             "a": unit * dt}  # fmt: skip
    err = np.abs(out - ideal)
    assert (err <= _tolerance(s, steps)).all(), err.max()
    assert err.max() < 0.01 * np.abs(ideal).max()


@pytest.mark.parametrize("model", PARKER_MODELS)
@pytest.mark.parametrize("feedback", ["encoder", "error_rate"])
def test_the_parker_filter_computes_the_designed_command(model, feedback):
    a = Parker6kAssumptions(dac_bits="16", velocity_feedback=feedback)
    params, _, _ = _realise(model, DESIGN, a)
    commanded, actual = _trajectories()
    dt = params.sample_time_s
    vc = np.round(np.diff(commanded, prepend=actual[0]) / dt).astype(np.int64)
    ac = np.round(np.diff(vc, prepend=0) / dt).astype(np.int64)
    out = np.array(Parker6kReferenceFilter(params, a).run(commanded, actual, vc, ac))
    s = _signals(commanded, actual, dt, integral_before=False)
    s["cv"], s["ca"] = vc.astype(float), ac.astype(float)  # what the chip is given
    ideal = _ideal(DESIGN, s)
    assert np.abs(ideal).max() < 15000
    c = 1e9 / 32768  # q per command count (PK-A1 uV)
    steps = {"p": 1 / c, "i": 1 / c, "d": 1 / c, "v": 1 / c, "a": 1 / (100 * c)}
    err = np.abs(out - ideal)[1:]  # the first sample has no velocity feedback (PK-A3)
    tol = _tolerance(s, steps, bias_step=0.5 * 32768 / 10000)[1:]
    assert (err <= tol).all(), err.max()
    assert err.max() < 0.01 * np.abs(ideal).max()


# ------------------------------------------------------------------------------------------
# Every produced set is legal, whatever the design asks for
# ------------------------------------------------------------------------------------------

_gain = st.one_of(st.just(0.0), st.floats(1e-12, 1e12), st.floats(-1e6, -1e-9),
                  st.sampled_from([math.inf, -math.inf]))  # fmt: skip
_designs = st.builds(
    ServoDesign,
    p=_gain, i=_gain, d=_gain, integral_limit=_gain, vff=_gain, aff=_gain,
    bias=st.floats(-1e7, 1e7),
    derivative_sample_s=st.one_of(st.none(), st.floats(1e-5, 1.0)),
    motor_limit=st.one_of(st.none(), st.floats(-1e6, 1e6)),
)  # fmt: skip


@settings(max_examples=150, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(
    design=_designs,
    model=st.sampled_from(PMAC_MODELS + PARKER_MODELS),
    ix08=st.sampled_from([0, 1, 96, 8388607]),
    ix09=st.sampled_from([0, 96, 8388607]),
    a=st.sampled_from(PARKER_ASSUMPTIONS),
)
def test_every_produced_set_is_legal(design, model, ix08, ix09, a):
    family, model = get_chip(model)
    pmac = family.name == "pmac"
    changes = {"position_loop_scale": ix08, "velocity_loop_scale": ix09} if pmac else {}
    assumptions = a if family.name == "parker6k" else None
    _, regs, _ = _realise(model, design, assumptions, **changes)  # validates
    space = family.parameter_space(model)
    for name, value in regs.items():
        assert isinstance(value, int)
        assert space[name].low <= value <= space[name].high
    gains = (("proportional_gain", "derivative_gain", "velocity_ff", "integral_gain",
              "acceleration_ff", "integration_limit") if family.name == "pmac"
             else ("sgp", "sgi", "sgv", "sgvf", "sgaf", "sgilim"))  # fmt: skip
    assert all(regs[g] >= 0 for g in gains)  # a negative gain would invert a term


# ------------------------------------------------------------------------------------------
# The classical tuners work on both families (short moves, small budgets)
# ------------------------------------------------------------------------------------------

CASES = [
    ("TurboPMAC2", "vendor-step", 30, {}),
    pytest.param(
        "TurboPMAC2",
        "relay",
        20,
        {},
        # Known limit since the loop latency (issue 13): the relay oscillation is set by
        # PMAC-A14's phase-edge latency (427 Hz), and the rule's best safe set costs 24.7.
        marks=pytest.mark.xfail(strict=True, reason="relay on PMAC with latency: cost 24.7"),
    ),
    # The classical procedures lift only PMD's position_error_limit during their
    # experiments; PMAC's fatal following error (Ixx11, 2000 counts by default) trips the
    # model-based identification moves, so it is held off here (see docs/autotune.md).
    ("TurboPMAC2", "model-based", 10, {"fatal_following_error_limit": 0}),
    ("6250", "vendor-step", 30, {}),
    ("6250", "relay", 20, {}),
    ("6250", "model-based", 10, {}),
]


def _case_id(case) -> str:
    values = case.values if hasattr(case, "values") else case
    return f"{values[0]}-{values[1]}"


@pytest.mark.parametrize(("chip", "tuner", "budget", "fixed"), CASES,
                         ids=[_case_id(c) for c in CASES])  # fmt: skip
def test_each_classical_tuner_improves_on_the_chip_defaults(chip, tuner, budget, fixed):
    problem = short_problem(chip, fixed=fixed)
    default_cost = Evaluator(problem.scenario).evaluate(problem.space.make_params({})).cost
    result = run_study(problem, tuner, budget, storage=None, n_workers=1)
    cost = result.best.values[0]
    assert cost < 0.5 * default_cost
    assert result.best.user_attrs["kind"] == "candidate"
    assert cost < 20.0  # a working loop, not merely a less bad one


def test_model_based_identifies_a_pmac_axis_with_the_default_error_limit():
    # Identification experiments lift the chip's own trip (ChipFamily.error_trip_off: Ixx11 = 0),
    # so the default fatal following-error limit no longer stops the procedure.
    result = run_study(short_problem("TurboPMAC2"), "model-based", 10, storage=None, n_workers=1)
    assert result.best.user_attrs["kind"] == "candidate"
