"""The multi-axis check (servogym.sim._multicheck): the N-input linearisation against the
simulation, the N-loop closed loop against the single-axis one, the margins of a decoupled
machine against its single axes, and the verdict on sets that pass and sets that fail."""

from __future__ import annotations

import dataclasses
import json
import math
from types import SimpleNamespace

import numpy as np
import pytest

from servogym.autotune._gains import ServoDesign, design_registers
from servogym.autotune._space import register_values
from servogym.chips._family import get_chip
from servogym.chips._space import ParameterError
from servogym.plants import MULTI_PLANTS, get_plant
from servogym.sim import CheckLimits, MultiServoLoop
from servogym.sim._contour import LinePath
from servogym.sim._machine import SEQUENCING, axis_latencies, machine_params
from servogym.sim._margins import (
    STABILITY_EPS,
    analyse_loop,
    closed_loop_matrix,
    closed_loop_stability,
    linearize,
)
from servogym.sim._multicheck import (
    MachineLinear,
    _AxisView,
    characteristic_values,
    check_machine_params,
    count_zeros_inside,
    machine_closed_loop_matrix,
    machine_continuous_model,
    machine_linearize,
    machine_loops,
    machine_qpos,
    machine_response,
    machine_stability,
)
from servogym.sim._multieval import ContourSpec, CoordinatedSpec, MultiEvaluator

MODELS = {"pmd": "MC2100", "pmac": "TurboPMAC2", "parker6k": "6250"}
"""One model per chip family."""

CROSSOVER_HZ = {"pmd": 60.0, "pmac": 40.0, "parker6k": 40.0}
"""The designed sets' crossover per family (the MC2100's feed-forward registers clamp at
40 Hz on the stage's Y axis, so its error needs the higher gain)."""

SHORT = {
    "xy-stage": (
        CoordinatedSpec((0.3, 0.3), (5.0, 5.0), targets=(0.01, 0.02), settle_s=0.03),
        ContourSpec(LinePath((0.0, 0.0), (0.008, 0.008)), 0.1, 2.0, settle_s=0.03),
    ),
    "two-link-arm": (
        CoordinatedSpec((2.0, 3.0), (10.0, 15.0), targets=(0.4, -0.4), settle_s=0.03),
    ),
}
"""Small tasks that keep the tests quick (the defaults are checked by the CLI test)."""

FAST = CheckLimits(reference_substeps=4)
"""The check with 4 RK4 substeps per period (32 by default)."""


def designed_sets(plant: str, model: str, crossover_hz: float) -> list:
    """A PID with velocity and acceleration feed-forward per axis, from the axis's own
    acceleration per command count at the zero configuration (a rigid-body design, the
    coupling ignored): crossover ``crossover_hz``, the derivative's zero at a third of it,
    the integral's at a twentieth."""
    family = MULTI_PLANTS[plant]
    machine = family.build()
    chip, _ = get_chip(model)
    base = machine_params(model, family.n_axes)
    a, b, _, _ = machine_continuous_model(machine)
    nv = machine.model.nv
    w = 2 * math.pi * crossover_hz
    out = []
    for k, io in enumerate(machine.ios):
        acc = b[nv + io.qvel_adr, k] * io.amp_amps_per_count * io.counts_per_unit
        viscous = -a[nv + io.qvel_adr, nv + io.qvel_adr]
        d = w / (acc * math.sqrt(1 + 1 / 9))
        design = ServoDesign(p=d * w / 3, d=d, i=d * w * w / 60, integral_limit=3000,
                             vff=viscous / acc, aff=1 / acc)  # fmt: skip
        vals = design_registers(design, base[k], register_values(base[k]))
        if "fatal_following_error_limit" in vals:
            vals["fatal_following_error_limit"] = 0  # PMAC Ixx11: no fatal limit
        out.append(chip.make_params(model, vals))
    return out


def single_axis(lin_plant, cont, k, dt, latency):
    """Axis ``k`` alone: its own position, velocity and current states of the machine's
    continuous model, the single-axis linearisation of them."""
    a, b, c, d = cont
    nv = lin_plant.model.nv
    io = lin_plant.ios[k]
    idx = [io.qpos_adr, nv + io.qvel_adr]
    idx += [i for i in range(2 * nv, a.shape[0]) if b[i, k] != 0]
    sub = (a[np.ix_(idx, idx)], b[idx, k], c[k, idx], d[idx])
    return linearize(_AxisView(lin_plant.model, io), dt, latency, sub)


# --- the linear machine ----------------------------------------------------------------------


@pytest.mark.parametrize("sequencing", ["each_sample", "in_turn"])
def test_linear_machine_replays_the_simulated_coupled_arm(sequencing):
    """x[k+1] = Phi x + G_new u[k] + G_old u[k-1], fed both axes' command traces, reproduces
    both encoders of the reference integration on the coupled arm (each axis's own latency,
    each with a current-loop lag, Coulomb friction at its smallest)."""
    family = MULTI_PLANTS["two-link-arm"]
    values = {"shoulder_current_bandwidth_hz": 800.0, "elbow_current_bandwidth_hz": 1500.0}
    for p in family.params:
        if "coulomb" in p.name:
            values[p.name] = p.low
    plant = family.build(values)
    params = machine_params("6250", 2, {"sgp": 8000, "sgv": 60, "sgi": 0})
    asm = dataclasses.replace(get_chip("6250")[0].default_assumptions(), loop_latency="half_period")
    loop = MultiServoLoop(plant, params, asm, sequencing=sequencing, substeps=32)
    assert (loop.latencies_s[0] == loop.latencies_s[1]) == (sequencing == "each_sample")
    n = 500
    zeros = np.zeros(n, np.int64)
    steps = (20000, -30000)  # counts; Coulomb friction (left out) costs some 40 counts
    profiles = [SimpleNamespace(position=np.full(n, s, np.int64), velocity=zeros,
                                acceleration=zeros.copy(), start=0) for s in steps]  # fmt: skip
    r = loop.run(profiles, traces=True)
    assert r.axis == -1
    start = [io.start_qpos for io in plant.ios]
    cont = machine_continuous_model(plant, machine_qpos(plant, start))
    lin = machine_linearize(plant, loop.dt, loop.latencies_s, cont)
    commands = np.stack([t.command for t in r.traces]).astype(float)
    actual = np.stack([t.actual for t in r.traces]).astype(float)
    x = np.zeros(lin.phi.shape[0])
    u_old = np.zeros(2)
    ys = []
    for u in commands.T:
        ys.append(lin.c @ x)
        x = lin.phi @ x + lin.g_new @ u + lin.g_old @ u_old
        u_old = u
    ys = np.array(ys).T
    window = slice(0, 150)
    for k in range(2):
        peak = np.max(np.abs(actual[k, window]))
        assert peak > 500
        assert np.max(np.abs(ys[k, window] - actual[k, window])) <= 2 + 0.01 * peak
    # the coupling is in the model: the shoulder moves when only the elbow's command acts
    g = machine_response(lin, np.exp(1j * np.array([0.01])))[0]
    assert abs(g[0, 1]) > 0.05 * abs(g[0, 0])


@pytest.mark.parametrize("family", sorted(MODELS))
def test_one_axis_machine_is_the_single_axis_loop_exactly(family):
    """For one axis, the N-loop closed-loop matrix is the single-axis matrix to the bit, the
    stability the same, and the response the single-axis plant's."""
    plant = get_plant("rotary").build({"current_bandwidth_hz": 1200.0})
    model = MODELS[family]
    chip, _ = get_chip(model)
    params = designed_sets("xy-stage", model, CROSSOVER_HZ[family])[0]
    dt = chip.sample_time_s(params)
    lin = linearize(plant, dt, chip.loop_latency_s(params))
    machine = MachineLinear(lin.phi, lin.g_new[:, None], lin.g_old[:, None], lin.c[None],
                            lin.dt, (lin.latency,))  # fmt: skip
    polys = chip.filter_polynomials(params, None)
    np.testing.assert_array_equal(machine_closed_loop_matrix(machine, [polys]),
                                  closed_loop_matrix(polys, lin))  # fmt: skip
    assert machine_stability(machine, [polys]) == closed_loop_stability(polys, lin)
    z = np.exp(1j * np.linspace(0.01, 3.0, 50))
    np.testing.assert_allclose(machine_response(machine, z)[:, 0, 0], lin.response(z),
                               rtol=1e-12)  # fmt: skip
    # an axis left open: the plant's own poles (the rigid body's on the unit circle)
    open_loop = machine_closed_loop_matrix(machine, [None])
    np.testing.assert_array_equal(open_loop, lin.phi)


def test_root_count_agrees_with_the_eigenvalues():
    """The argument-principle count of a polynomial given pointwise (the high-order path)
    counts the poles on or outside the circle as the eigenvalues do."""
    rng = np.random.default_rng(3)
    for radii in ([0.5, 0.9, 0.99], [0.5, 1.02, 0.3], [1.2, 1.5, 0.1, 0.999999]):
        poles = np.array(radii) * np.exp(1j * rng.uniform(0.1, 3, len(radii)))
        m = np.zeros((2 * len(radii) + 6,) * 2)
        for i, p in enumerate(poles):
            m[2 * i : 2 * i + 2, 2 * i : 2 * i + 2] = [[p.real, -p.imag], [p.imag, p.real]]
        m[2 * len(radii) :, 2 * len(radii) :] = np.diag(rng.uniform(-0.8, 0.8, 6))
        q = rng.normal(size=m.shape)
        m = q @ m @ np.linalg.inv(q)
        outside = 2 * sum(r >= 1 - STABILITY_EPS for r in radii)

        def det(x, m=m):
            return np.linalg.det(np.eye(m.shape[0])[None] - x[:, None, None] * m[None])

        assert count_zeros_inside(det, m.shape[0], 1 / (1 - STABILITY_EPS)) == outside


@pytest.mark.parametrize("family", sorted(MODELS))
def test_characteristic_values_are_the_closed_loop_determinant(family):
    """The system-matrix determinant the high-order path counts is det(I - x M) of the
    N-loop closed-loop matrix (coupled arm, current-loop lags, PMD's long derivative)."""
    model = MODELS[family]
    chip, _ = get_chip(model)
    plant = MULTI_PLANTS["two-link-arm"].build({"elbow_current_bandwidth_hz": 700.0})
    sets = designed_sets("two-link-arm", model, CROSSOVER_HZ[family])
    if family == "pmd":
        sets = [dataclasses.replace(p, derivative_time=7) for p in sets]
    dt = chip.sample_time_s(sets[0])
    lin = machine_linearize(
        plant,
        dt,
        [0.3 * dt, 0.6 * dt],
        machine_continuous_model(plant, machine_qpos(plant, (0.2, 0.9))),
    )
    polys = [chip.filter_polynomials(p, None) for p in sets]
    m = machine_closed_loop_matrix(lin, polys)
    x = 1.0000001 * np.exp(1j * np.array([1e-3, 0.01, 0.3, 1.0, 2.5, np.pi]))
    direct = np.linalg.det(np.eye(m.shape[0])[None] - x[:, None, None] * m[None])
    np.testing.assert_allclose(characteristic_values(lin, polys, x), direct, rtol=1e-7)


# --- margins with the other loops closed -----------------------------------------------------


@pytest.mark.parametrize("family", sorted(MODELS))
def test_decoupled_stage_margins_are_its_single_axes(family):
    """On the xy-stage (orthogonal slides: the axes do not couple) each loop's margins with
    the other loop closed are those of its axis alone, analysed by the single-axis margins;
    the machine's spectral radius is the larger axis's. One axis with a current-loop lag,
    the axes at different latencies (in turn)."""
    model = MODELS[family]
    sets = designed_sets("xy-stage", model, CROSSOVER_HZ[family])
    plant = MULTI_PLANTS["xy-stage"].build({"x_current_bandwidth_hz": 900.0})
    chip, _ = get_chip(model)
    dt = chip.sample_time_s(sets[0])
    asm = dataclasses.replace(chip.default_assumptions(), loop_latency="half_period")
    lat = axis_latencies(sets, asm, "in_turn")
    assert lat[0] != lat[1]
    cont = machine_continuous_model(plant)
    loops = machine_loops(chip, sets, asm, machine_linearize(plant, dt, lat, cont))
    radii = []
    for k in range(2):
        alone = analyse_loop(chip, sets[k], asm, single_axis(plant, cont, k, dt, lat[k]))
        m, s = loops[k].margins, alone.margins
        assert m.stable and s.stable
        assert m.gain_margin_db == pytest.approx(s.gain_margin_db, abs=1e-6)
        assert m.phase_margin_deg == pytest.approx(s.phase_margin_deg, abs=1e-6)
        assert m.gain_crossover_hz == pytest.approx(s.gain_crossover_hz, rel=1e-8)
        assert m.bandwidth_hz == pytest.approx(s.bandwidth_hz, rel=1e-6)
        radii.append(s.spectral_radius)
    assert loops[0].margins.spectral_radius == pytest.approx(max(radii), rel=1e-12)


def test_coupled_arm_loops_differ_from_their_axes_alone():
    """On the arm, closing the elbow's loop changes what the shoulder's loop sees: its
    margins differ from the axis-alone analysis (the coupling the check exists for)."""
    sets = designed_sets("two-link-arm", "6250", 40.0)
    plant = MULTI_PLANTS["two-link-arm"].build()
    chip, _ = get_chip("6250")
    dt = chip.sample_time_s(sets[0])
    lat = [chip.loop_latency_s(p) for p in sets]
    qpos = machine_qpos(plant, (0.3, 1.2))
    cont = machine_continuous_model(plant, qpos)
    loops = machine_loops(chip, sets, None, machine_linearize(plant, dt, lat, cont))
    alone = analyse_loop(chip, sets[0], None, single_axis(plant, cont, 0, dt, lat[0]))
    assert loops[0].margins.stable
    assert abs(loops[0].margins.phase_margin_deg - alone.margins.phase_margin_deg) > 0.05


def test_long_derivative_filters_take_the_exact_root_count():
    """PMD DerivativeTime 50 on both axes: a closed loop of order > 160, decided by counting
    the zeros of its characteristic determinant; it agrees with each decoupled axis's
    single-axis verdict, pole for pole."""
    model = "MC2100"
    chip, _ = get_chip(model)
    plant = MULTI_PLANTS["xy-stage"].build()
    base = machine_params(model, 2)
    cont = machine_continuous_model(plant)
    dt = chip.sample_time_s(base[0])
    for (kd, kout), expected in (((20, 200), (0, 0)), ((100, 1500), (2, 0)),
                                 ((400, 1500), (2, 2))):  # fmt: skip
        sets = [chip.make_params(model, {**register_values(p), "derivative_time": 50, "kp": 5,
                                         "kd": kd, "ki": 0, "kout": kout})
                for p in base]  # fmt: skip
        lat = [chip.loop_latency_s(p) for p in sets]
        lin = machine_linearize(plant, dt, lat, cont)
        polys = [chip.filter_polynomials(p, None) for p in sets]
        s = machine_stability(lin, polys)
        assert s.method == "encirclement" and s.order > 160
        singles = [closed_loop_stability(polys[k], single_axis(plant, cont, k, dt, lat[k]))
                   for k in range(2)]  # fmt: skip
        assert tuple(x.n_unstable for x in singles) == expected
        assert s.n_unstable == sum(expected) and s.stable == (sum(expected) == 0)


# --- the check -------------------------------------------------------------------------------


def test_a_designed_set_passes_every_case_and_margin():
    sets = designed_sets("xy-stage", "TurboPMAC2", 40.0)
    r = check_machine_params(sets, "xy-stage", FAST, tasks=SHORT["xy-stage"])
    assert r.passed, r.failures
    assert r.stable and r.axes == ("x", "y")
    latencies = get_chip("TurboPMAC2")[0].assumptions_type.CHOICES["loop_latency"]
    names = [c.name for c in r.cases]
    assert names == [
        "reference", *(f"latency {c}" for c in latencies[1:]), "sequencing in_turn",
        "load -20%", "load +20%", "friction -50%", "friction +50%",
    ]  # fmt: skip
    assert r.cases[-4].plant_changes == {"payload_kg": 1.6}
    assert set(r.cases[-1].plant_changes) == {
        "x_viscous_friction_ns_per_m", "x_coulomb_friction_n",
        "y_viscous_friction_ns_per_m", "y_coulomb_friction_n",
    }  # fmt: skip
    assert len(r.timing) == len(latencies) * len(SEQUENCING["pmac"].choices)
    for c in r.cases:
        for a in c.axes:
            assert a.max_following_error <= a.following_error_limit
            assert a.margins.gain_margin_db >= 6 and a.margins.phase_margin_deg >= 30
    for loop, name in zip(r.loops, ("x", "y"), strict=True):
        assert loop.axis == name and loop.margins.stable
        assert r.worst[name]["gain_margin_db"]["value"] <= loop.margins.gain_margin_db
    doc = json.loads(json.dumps(r.to_dict(), allow_nan=False))
    assert doc["passed"] and len(doc["cases"]) == len(names)


def test_the_report_is_the_evaluators_run_on_the_reference_integration():
    """With an evaluator, its tasks, plant and settings are the reference: the reference
    case's cost is the evaluator's on the reference integration, to the bit."""
    sets = designed_sets("xy-stage", "6250", 40.0)
    ev = MultiEvaluator("xy-stage", "6250", SHORT["xy-stage"], plant_values={"payload_kg": 3.0})
    r = check_machine_params(sets, ev, FAST)
    same = MultiEvaluator("xy-stage", "6250", SHORT["xy-stage"], plant_values={"payload_kg": 3.0},
                          integrator="rk4", substeps=4)  # fmt: skip
    assert r.cases[0].cost == same.evaluate(sets).cost
    assert r.cases[3 + 1].plant_changes == {"payload_kg": pytest.approx(2.4)}  # load -20%


def test_destabilising_gains_fail_with_a_named_reason_and_finite_output():
    sets = designed_sets("xy-stage", "TurboPMAC2", 40.0)
    bad = dataclasses.replace(sets[1], proportional_gain=sets[1].proportional_gain * 30,
                              derivative_gain=0)  # fmt: skip
    r = check_machine_params([sets[0], bad], "xy-stage", FAST, tasks=SHORT["xy-stage"][:1])
    assert not r.passed and not r.stable
    assert any("reference: the machine (every loop closed" in f and "unstable closed loop" in f
               for f in r.failures)  # fmt: skip
    assert all(math.isfinite(c.cost) for c in r.cases)
    json.dumps(r.to_dict(), allow_nan=False)  # finite or None, every figure


def test_a_command_limit_below_the_tasks_need_fails_first_naming_the_axis():
    """The single-axis rule per axis: Ixx69 below what the move needs of y's motor."""
    sets = designed_sets("xy-stage", "TurboPMAC2", 40.0)
    low = dataclasses.replace(sets[1], output_limit=200)  # 0.6 % of full scale
    r = check_machine_params([sets[0], low], "xy-stage", FAST, tasks=SHORT["xy-stage"][:1])
    assert not r.passed
    assert r.cases[0].failures[0].startswith("reference: y: command limit: the set limits the "
                                             "motor command to 0.6% of full scale")  # fmt: skip
    assert not any(": x: command limit" in f for f in r.failures)


def test_low_margins_and_a_contour_limit_fail_naming_the_axis_and_the_gap():
    sets = designed_sets("xy-stage", "6250", 40.0)
    r = check_machine_params(sets, "xy-stage", CheckLimits(reference_substeps=4,
                             min_phase_margin_deg=80.0), tasks=SHORT["xy-stage"][1:],
                             max_contour_error_um=0.5)  # fmt: skip
    assert not r.passed
    assert any(f.startswith("reference: x loop (the others closed): phase margin:")
               and "< 80 deg" in f for f in r.failures)  # fmt: skip
    assert any(f.startswith("reference: contouring error:") and "> 0.5 um" in f
               for f in r.failures)  # fmt: skip


def test_bad_arguments_are_refused_naming_them():
    sets = designed_sets("xy-stage", "6250", 40.0)
    with pytest.raises(ParameterError, match="'xy-stage' plant has 2 axes"):
        check_machine_params(sets[:1], "xy-stage", FAST)
    with pytest.raises(ParameterError, match="evaluator_or_plant must be a MultiEvaluator"):
        check_machine_params(sets, "rotary", FAST)
    with pytest.raises(ParameterError, match="the evaluator runs the MC2100"):
        check_machine_params(sets, MultiEvaluator("xy-stage", "MC2100"), FAST)
    with pytest.raises(ParameterError, match="max_contour_error_um must be > 0 um"):
        check_machine_params(sets, "xy-stage", FAST, max_contour_error_um=0)
    with pytest.raises(ParameterError, match="assumption PK-M1 sequencing must be one of"):
        check_machine_params(sets, "xy-stage", FAST, sequencing="same_interrupt")
