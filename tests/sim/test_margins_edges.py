"""Hand-computed cases for the margins, the held input, the check and the agreement rule
(issue 14: the paths the defaults hide, comparisons at their exact boundaries).

Every expected number is derived in the comments from docs/simulation.md and the modules'
docstrings, not read off the code.
"""

from __future__ import annotations

import math
from fractions import Fraction
from types import SimpleNamespace

import mujoco
import numpy as np
import pytest

from servogym.chips._space import ParameterError
from servogym.sim import CheckLimits
from servogym.sim._inputs import current_at, exp_moment, piece_moments, substep_input
from servogym.sim._margins import (
    LinearPlant,
    continuous_model,
    continuous_phase,
    frequency_grid,
    frequency_margins,
    linearize,
)

# --- the linearised plant ----------------------------------------------------------------

MASS, GEAR, DAMPING = 2.0, 3.0, 0.8
"""A slide of 2 kg driven through gear 3 (force = 3 x ctrl), viscous damping 0.8 N s/m."""
KT, KA, KC = 0.5, 0.01, 1e6
"""Torque constant (N m/A), amperes per command count, encoder counts per metre."""


def slide_plant(damping: float = 0.0, gravity: bool = False, bandwidth_hz: float = 0.0):
    """A bare MuJoCo slide with the plant interface continuous_model reads (model, io)."""
    axis = "0 0 1" if gravity else "1 0 0"
    xml = f"""
    <mujoco>
      <option gravity="0 0 {-9.81 if gravity else 0}"/>
      <worldbody><body>
        <joint name="x" type="slide" axis="{axis}" damping="{damping}"/>
        <inertial pos="0 0 0" mass="{MASS}" diaginertia="1 1 1"/>
      </body></worldbody>
      <actuator><motor joint="x" gear="{GEAR}"/></actuator>
    </mujoco>"""
    io = SimpleNamespace(ctrl_index=0, qpos_adr=0, torque_constant_nm_per_a=KT,
                         amp_amps_per_count=KA, counts_per_unit=KC,
                         current_bandwidth_hz=bandwidth_hz)  # fmt: skip
    return SimpleNamespace(model=mujoco.MjModel.from_xml_string(xml), io=io)


def test_continuous_model_of_a_damped_slide_with_a_current_lag():
    # m x'' = -b x' + GEAR Kt i, tau i' = r - i with tau = 1 / (2 pi 500 Hz); y = KC x.
    # State (x, v, i): A = [[0, 1, 0], [0, -b/m, GEAR Kt/m], [0, 0, -1/tau]], B = (0, 0, 1/tau).
    a, b, c, d = continuous_model(slide_plant(DAMPING, bandwidth_hz=500.0))
    tau = 1 / (2 * math.pi * 500.0)
    want = [[0, 1, 0], [0, -DAMPING / MASS, GEAR * KT / MASS], [0, 0, -1 / tau]]
    np.testing.assert_allclose(a, want, rtol=1e-6, atol=1e-9)
    np.testing.assert_allclose(b, [0, 0, 1 / tau], rtol=1e-12)
    np.testing.assert_array_equal(c, [KC, 0, 0])
    np.testing.assert_array_equal(d, [0, 0, 0])
    # An ideal current loop (bandwidth 0): no current state, the input acts on v directly.
    a, b, c, d = continuous_model(slide_plant(DAMPING))
    np.testing.assert_allclose(a, [[0, 1], [0, -DAMPING / MASS]], rtol=1e-6, atol=1e-9)
    np.testing.assert_allclose(b, [0, GEAR * KT / MASS], rtol=1e-6)


def test_continuous_model_of_three_free_slides_driving_the_second():
    """Three separate slides (1, 2, 4 kg), the motor and encoder on the second (nv = 3, more
    than any shipped plant): x2'' = GEAR Kt i / 2, the others free; y = KC x2."""
    bodies = "".join(
        f'<body><joint name="j{k}" type="slide" axis="1 0 0"/>'
        f'<inertial pos="0 0 0" mass="{m}" diaginertia="1 1 1"/></body>'
        for k, m in enumerate((1, 2, 4))
    )
    model = mujoco.MjModel.from_xml_string(
        f'<mujoco><option gravity="0 0 0"/><worldbody>{bodies}</worldbody>'
        f'<actuator><motor joint="j1" gear="{GEAR}"/></actuator></mujoco>'
    )
    for bandwidth, n in ((0.0, 6), (0.5, 7)):
        io = SimpleNamespace(ctrl_index=0, qpos_adr=1, torque_constant_nm_per_a=KT,
                             amp_amps_per_count=KA, counts_per_unit=KC,
                             current_bandwidth_hz=bandwidth)  # fmt: skip
        a, b, c, d = continuous_model(SimpleNamespace(model=model, io=io))
        want_a = np.zeros((n, n))
        want_a[:3, 3:6] = np.eye(3)
        want_b = np.zeros(n)
        if n == 7:  # 0.5 Hz is a lag too: tau = 1 / (2 pi 0.5) = 1 / pi
            want_a[4, 6] = GEAR * KT / 2
            want_a[6, 6] = -math.pi
            want_b[6] = math.pi
        else:
            want_b[4] = GEAR * KT / 2
        np.testing.assert_allclose(a, want_a, rtol=1e-6, atol=1e-9)
        np.testing.assert_allclose(b, want_b, rtol=1e-6, atol=1e-12)
        np.testing.assert_array_equal(c, KC * (np.arange(n) == 1))
        np.testing.assert_array_equal(d, np.zeros(n))


def test_pure_inertia_response_with_and_without_latency():
    """Encoder counts per command count of x'' = k u, k = GEAR Kt KA / m, held per tick.

    Over a tick of length T, u_old acts on [0, L) and u_new on [L, T):
    v gains k (L u_old + (T - L) u_new), x gains v T + k ((L T - L^2/2) u_old + (T - L)^2/2 u_new).
    So Phi = [[1, T], [0, 1]], G_new = k ((T-L)^2/2, T-L), G_old = k (L T - L^2/2, L) and
    P(z) = KC / (z-1)^2 [(z-1)(G_new,x + G_old,x / z) + T (G_new,v + G_old,v / z)]:
    L = 0:     KC k T^2/2 (z + 1) / (z - 1)^2 (the classical hold of a double integrator),
    L = T/2:   KC k T^2/8 (z^2 + 6 z + 1) / (z (z - 1)^2),
    L = T:     KC k T^2/2 (z + 1) / (z (z - 1)^2) (one whole tick of delay).
    """
    plant = slide_plant()
    k = GEAR * KT * KA / MASS
    dt = 1e-3
    z = np.exp(2j * np.pi * np.array([3.0, 40.0, 250.0, 499.0]) * dt)
    cases = {
        0.0: KC * k * dt**2 / 2 * (z + 1) / (z - 1) ** 2,
        dt / 2: KC * k * dt**2 / 8 * (z**2 + 6 * z + 1) / (z * (z - 1) ** 2),
        dt: KC * k * dt**2 / 2 * (z + 1) / (z * (z - 1) ** 2),
    }
    for latency, want in cases.items():
        lin = linearize(plant, dt, latency)
        np.testing.assert_allclose(lin.response(z), want, rtol=1e-6)
        assert lin.dt == dt and lin.latency == latency
    lin = linearize(plant, dt, dt / 4)
    # L = T/4: G_new = k (9 T^2/32, 3T/4), G_old = k (7 T^2/32, T/4).
    np.testing.assert_allclose(lin.g_new, k * np.array([9 * dt**2 / 32, 0.75 * dt]), rtol=1e-6)
    np.testing.assert_allclose(lin.g_old, k * np.array([7 * dt**2 / 32, 0.25 * dt]), rtol=1e-6)
    np.testing.assert_allclose(lin.phi, [[1, dt], [0, 1]], rtol=1e-6, atol=1e-12)


def test_drift_is_gravity_over_one_tick():
    # A vertical slide at rest, no command: in a tick x falls g T^2/2 and v becomes -g T.
    dt = 1e-3
    lin = linearize(slide_plant(gravity=True), dt, 0.3 * dt)
    np.testing.assert_allclose(lin.drift, [-9.81 * dt**2 / 2, -9.81 * dt], rtol=1e-9)


def test_response_of_a_first_order_plant_by_hand():
    # x[k+1] = 0.5 x + 2 u[k] + 3 u[k-1], y = 4 x: P(z) = 4 (2 + 3 z^-1) / (z - 0.5).
    lin = LinearPlant(phi=np.array([[0.5]]), g_new=np.array([2.0]), g_old=np.array([3.0]),
                      drift=np.zeros(1), c=np.array([4.0]), dt=1e-3, latency=0.0)  # fmt: skip
    z = np.array([1.0, -1.0, 1j, 2.0 + 1j])
    np.testing.assert_allclose(lin.response(z), 4 * (2 + 3 / z) / (z - 0.5), rtol=1e-14)
    # at z = 1: 4 * 5 / 0.5 = 40; at z = -1: 4 * (2 - 3) / (-1.5) = 8/3.
    assert lin.response(np.array([1.0]))[0] == pytest.approx(40.0)
    assert lin.response(np.array([-1.0]))[0] == pytest.approx(8 / 3)


def test_frequency_grid_spans_the_documented_range():
    # From 1e-4 of the sample rate to 0.999 of Nyquist, logarithmically.
    f = frequency_grid(1e-3, 50)
    assert f.size == 50
    assert f[0] == pytest.approx(0.1, rel=1e-12) and f[-1] == pytest.approx(499.5, rel=1e-12)
    ratios = f[1:] / f[:-1]
    np.testing.assert_allclose(ratios, ratios[0], rtol=1e-9)


# --- the margins ------------------------------------------------------------------------------


def test_continuous_phase_starts_in_the_half_open_turn_below_zero():
    # Phase at the low-frequency end in (-360, 0] degrees: 0 stays 0, -90 stays -90,
    # +90 (a differentiator) becomes -270, 180 becomes -180; later points follow continuously.
    for start_deg, want_deg in ((0.0, 0.0), (-90.0, -90.0), (90.0, -270.0), (180.0, -180.0)):
        loop = np.exp(1j * np.radians([start_deg, start_deg - 60.0, start_deg - 120.0]))
        got = np.degrees(continuous_phase(loop))
        np.testing.assert_allclose(got, [want_deg, want_deg - 60.0, want_deg - 120.0], atol=1e-9)


# --- the held input ---------------------------------------------------------------------------


def test_an_ideal_loop_at_a_full_period_of_latency_ends_the_tick_on_the_new_command():
    # i(t) = r_new for L <= t <= T (docs/simulation.md): with L = T the tick ends on r_new.
    T = 1e-4
    assert current_at.py_func(T, 0.0, 1.0, -2.0, T, 0.0) == -2.0
    assert current_at(T, 0.0, 1.0, -2.0, T, 0.0) == -2.0
    assert current_at.py_func(0.5 * T, 0.0, 1.0, -2.0, T, 0.0) == 1.0


def test_a_lag_starting_exactly_one_ampere_above_its_level():
    # i(s) = 0 + 1 * exp(-s / tau) on [0, w], w = tau: moments
    # int e^{-s/tau} = tau (1 - e^-1), int s e^{-s/tau} = tau^2 (1 - 2 e^-1),
    # int s^2 e^{-s/tau} = tau^3 (2 - 5 e^-1).
    tau = 1e-4
    out = np.zeros(3)
    piece_moments.py_func(out, 0.0, tau, 0.0, 1.0, tau)
    e = math.exp(-1)
    want = [tau * (1 - e), tau**2 * (1 - 2 * e), tau**3 * (2 - 5 * e)]
    np.testing.assert_allclose(out, want, rtol=1e-12)
    out = np.zeros(3)
    piece_moments(out, 0.0, tau, 0.0, 1.0, tau)
    np.testing.assert_allclose(out, want, rtol=1e-12)


# --- the check's limits -----------------------------------------------------------------------

EDGES = [
    ("min_gain_margin_db", 0.0, 60.0),
    ("min_phase_margin_deg", 0.0, 90.0),
    ("load_spread", 0.0, 0.9),
    ("friction_spread", 0.0, 0.9),
]


@pytest.mark.parametrize(("name", "low", "high"), EDGES)
def test_check_limits_accept_their_edges_and_refuse_past_them(name, low, high):
    assert getattr(CheckLimits(**{name: low}), name) == low
    assert getattr(CheckLimits(**{name: high}), name) == high
    for bad in (low - 0.01, high + 0.01, "1"):
        with pytest.raises(ParameterError, match=f"{name} must satisfy {low:g} <= {name} <= "
                           f"{high:g}; got {name}={bad!r}"):  # fmt: skip
            CheckLimits(**{name: bad})


def test_reference_substeps_between_1_and_1024_and_an_integer():
    assert CheckLimits(reference_substeps=1).reference_substeps == 1
    assert CheckLimits(reference_substeps=1024).reference_substeps == 1024
    for bad in (0, 1025, True, 4.0):
        with pytest.raises(ParameterError, match=f"got reference_substeps={bad!r}"):
            CheckLimits(reference_substeps=bad)
    d = CheckLimits()
    assert (d.min_gain_margin_db, d.min_phase_margin_deg) == (6.0, 30.0)
    assert (d.load_spread, d.friction_spread) == (0.2, 0.5)


# --- the check: margins at their minimum, extra plants ----------------------------------------


def test_margins_exactly_at_their_minimum_pass_and_a_shortfall_is_stated():
    """A margin equal to its minimum meets it (docs/simulation.md: "below its minimum"
    fails); a drawn plant instance runs as a case that lists only what differs from the
    scenario's fixed values."""
    from servogym.plants import get_plant
    from servogym.sim import Scenario, check_params
    from servogym.sim._check import loop_margins

    from .test_check import safe

    scenario, params = safe("6250", "rotary")
    scenario = Scenario("6250", "rotary", plant_values={"peak_current_a": 10.0},
                        moves=scenario.moves[:1])  # fmt: skip
    asm = scenario.chip.default_assumptions()
    m = loop_margins(scenario, params)[asm.loop_latency].margins
    assert 6 < m.gain_margin_db < 50 and 30 < m.phase_margin_deg < 80  # 22.9 dB, 64.7 deg
    draw = {**get_plant("rotary").nominal(), "load_inertia_kgm2": 1e-4}  # a complete instance
    none = CheckLimits(min_gain_margin_db=0, min_phase_margin_deg=0, reference_substeps=4)
    base = check_params(params, scenario, none, extra_plants=[draw], workers=1)
    assert base.passed and base.margins == m  # the reference case is the scenario's own
    wgm, wpm = base.worst["gain_margin_db"], base.worst["phase_margin_deg"]
    at_gain = CheckLimits(
        min_gain_margin_db=wgm["value"], min_phase_margin_deg=wpm["value"] + 1,
        reference_substeps=4,
    )  # fmt: skip
    report = check_params(params, scenario, at_gain, extra_plants=[draw], workers=1)
    lim = wpm["value"] + 1
    short = [c for c in report.cases if c.margins.phase_margin_deg < lim]
    assert report.failures == tuple(
        f"{c.name}: phase margin: {c.margins.phase_margin_deg:.2f} deg < {lim:g} deg "
        f"({lim - c.margins.phase_margin_deg:.2f} deg short)"
        for c in short
    )
    assert wpm["case"] in {c.name for c in short}
    case = report.cases[-1]
    assert case.name == "plant draw 1" and case.loop_latency == asm.loop_latency
    assert "peak_current_a" not in case.plant_changes  # the scenario fixes it already
    assert case.plant_changes["load_inertia_kgm2"] == 1e-4
    assert not case.diverged and case.divergence_reason == "none"
    assert case.to_dict()["divergence_time_s"] is None
    at_phase = CheckLimits(
        min_gain_margin_db=wgm["value"] + 1, min_phase_margin_deg=wpm["value"],
        reference_substeps=4,
    )  # fmt: skip
    report = check_params(params, scenario, at_phase, extra_plants=[draw], workers=1)
    lim = wgm["value"] + 1
    assert all(": gain margin: " in f and f.endswith("dB short)") for f in report.failures)
    assert f"{wgm['case']}: gain margin: {wgm['value']:.2f} dB < {lim:g} dB (1.00 dB short)" in (
        report.failures
    )
    assert not report.passed and report.to_dict()["passed"] is False


# --- the agreement rule at its thresholds -------------------------------------------------


def test_agreement_rule_at_its_exact_thresholds():
    from servogym.sim._convergence import compare

    from .test_convergence import _evaluation as ev

    # Settling set of cost 0: the cost tolerance is 0.05 * 0 + 0.02 = 0.02, inclusive.
    zero = ev(0.0, trace=(0, 100, 200))
    assert compare(ev(0.02, trace=(0, 100, 200)), zero).ok
    assert not compare(ev(0.0201, trace=(0, 100, 200)), zero).ok
    # Not settled (a move did not settle): 10 % of 50 = 5, inclusive, either side.
    osc = ev(50.0, settled=False)
    assert compare(ev(55.0, settled=False), osc).ok
    assert compare(ev(45.0, settled=False), osc).ok
    assert not compare(ev(44.9, settled=False), osc).ok
    # Only one of the two at the cap (100) is no agreement; both at it is.
    assert not compare(ev(100.0, settled=False), ev(60.0, settled=False)).ok
    assert not compare(ev(60.0, settled=False), ev(100.0, settled=False)).ok
    # Both diverged: the same verdict is all the rule asks, whatever the costs.
    a = compare(ev(1500.0, diverged=True, settled=False), ev(1100.0, diverged=True, settled=False))
    assert a.ok and a.why == "" and a.diverged and a.reference_diverged and not a.settled


def test_well_damped_means_a_cost_below_ten():
    from servogym.sim._convergence import compare, settled

    from .test_convergence import _evaluation as ev

    # A settled reference of cost 9.99 is well damped: the trace rule applies (8 counts).
    assert settled(ev(9.99)) and not settled(ev(10.0))
    a = compare(ev(9.99, trace=(0, 100, 200)), ev(9.99, trace=(0, 100, 200)))
    assert a.settled and a.trace_tolerance == 8 and a.max_trace_difference == 0
    # At cost 10 it is not: only the cost counts (10 %), a trace 300 counts off agrees.
    a = compare(ev(10.9, trace=(0, 400, 200)), ev(10.0, trace=(0, 100, 200)))
    assert a.ok and not a.settled and a.trace_tolerance == 0 and a.max_trace_difference == 300
    assert not settled(ev(5.0, diverged=True)) and not settled(ev(5.0, settled=False))


def test_traces_compared_over_their_common_ticks():
    from servogym.sim._convergence import compare

    from .test_convergence import _evaluation as ev

    # The default run is one tick longer: only the three common ticks count (1 count apart).
    a = compare(ev(1.0, trace=(0, 101, 200, 9999)), ev(1.0, trace=(0, 100, 200)))
    assert a.ok and a.max_trace_difference == 1
    assert a.cost == 1.0 and a.reference_cost == 1.0
    # No common tick (a run that ended before its first tick): no difference, 0 counts.
    a = compare(ev(1.0, trace=()), ev(1.0, trace=(0, 100, 200)))
    assert a.ok and a.max_trace_difference == 0
    # 0.5 % of a 3000-count peak error: 15 counts, more than 8.
    a = compare(ev(1.0, trace=(0, 100, 200)), ev(1.0, trace=(0, 100, 215), fe=3000.0))
    assert a.ok and a.trace_tolerance == 15 and a.max_trace_difference == 15


# --- the stress set, the periods, the cases' runs -------------------------------------------


def test_stress_case_names_state_the_spreads_in_percent():
    # Spreads of 0.9: "load -90%", "load +90%", "friction -90%", "friction +90%"; the load
    # of the rotary plant (9e-5 kg m^2) times 0.1 and 1.9, each kept inside its legal range.
    from servogym.plants import get_plant
    from servogym.sim import Scenario
    from servogym.sim._check import stress_cases

    family = get_plant("rotary")
    limits = CheckLimits(load_spread=0.9, friction_spread=0.9)
    cases = {c.name: c for c in stress_cases(Scenario("6250", "rotary"), limits)}
    assert [n for n in cases if n.startswith(("load", "friction"))] == [
        "load -90%", "load +90%", "friction -90%", "friction +90%"]  # fmt: skip
    p = family.param("load_inertia_kgm2")
    for name, factor in (("load -90%", 0.1), ("load +90%", 1.9)):
        want = min(max(9e-5 * factor, p.low), p.high)
        assert cases[name].plant_changes == {"load_inertia_kgm2": pytest.approx(want)}


def test_period_settings_by_hand():
    # PMD: one slot per axis, n_axes x minimum (docs/chips/pmd.md, PMD-A13): the 4-axis
    # Navigator 4 x 154 = 616 us, the 1-axis MC3110 154 us, the 4-axis Magellan 4 x 52 = 208 us.
    from servogym.sim._convergence import period_settings

    assert period_settings("MC2100")["slowest"] == {"sample_time_us": 616}
    assert period_settings("MC3110")["slowest"] == {"sample_time_us": 154}
    assert period_settings("MC58000")["slowest"] == {"sample_time_us": 208}
    assert period_settings("TurboPMAC2") == {"default": {}, "slowest": {"servo_cycle_extension": 1}}
    assert period_settings("6K") == {"default": {}, "slowest": {"ssfr": 1}}


def test_check_cases_run_the_nominal_plant_at_the_reference_and_time_a_divergence():
    """Each case runs without the scenario's plant draws (randomise off), RK4 at the limits'
    substeps. A divergence in the second move is reported with that move's reason and timed
    from the start of the moves: move 1 (0.0002 rad, a triangular profile of
    2 sqrt(0.0002 / 3000) = 0.52 ms, then 20 ms at rest) stays within the 20-count error
    limit; move 2 (30000 rad/s^2) trips the chip's motion error in its first ticks."""
    import dataclasses

    from servogym.sim import Scenario, check_params
    from servogym.sim._scenario import Evaluator, MoveSpec

    from .test_convergence import SETS

    moves = (MoveSpec(0.0002, 60.0, 3000.0, settle_s=0.02),
             MoveSpec(6.283, 200.0, 30000.0, settle_s=0.02))  # fmt: skip
    # 30000 rad/s^2 is more than the motor has: refused unless the motor check is off.
    scenario = Scenario("MC2100", "rotary", randomise=True, moves=moves, motor_check=False)
    values = {**SETS["MC2100/rotary/default"]["values"], "position_error_limit": 20}
    params = scenario.params(values)
    report = check_params(params, scenario, CheckLimits(reference_substeps=4), workers=1)
    fixed = dataclasses.replace(scenario, randomise=False, integrator="rk4", substeps=4)
    ev = Evaluator(fixed).evaluate(params)
    ref = report.cases[0]
    assert ref.name == "reference" and ref.cost == ev.cost and ref.diverged == ev.diverged
    assert ref.max_following_error == ev.max_following_error
    assert [m.diverged for m in ev.metrics] == [False, True]
    assert ref.divergence_reason == "chip_motion_error"
    assert 0.0205 < ref.divergence_time_s < 0.0205 + 0.003
    assert ref.to_dict()["divergence_time_s"] == ref.divergence_time_s
    line = f"reference: diverged (chip_motion_error) at t = {ref.divergence_time_s:.4g} s"
    assert line in report.failures


# --- the Bode plot ------------------------------------------------------------------------------


def _plotted(monkeypatch, *args, **kwargs):
    """Draw a Bode plot and return its figure (saved nowhere) instead of the PNG."""
    import matplotlib.figure

    from servogym.sim._margins import bode_plot

    figures = []
    monkeypatch.setattr(
        matplotlib.figure.Figure, "savefig", lambda fig, *a, **k: figures.append(fig)
    )
    bode_plot("unused.png", *args, **kwargs)
    (fig,) = figures
    return fig


def _analytic(loop_of_hz, dt, stable=True, radius=0.5):
    from servogym.sim._margins import Stability

    s = Stability(stable, 0 if stable else 2, radius, 3, "eigenvalues")
    return frequency_margins(lambda t: loop_of_hz(np.asarray(t) / (2 * np.pi * dt)), dt, s)


def test_bode_plot_draws_the_loop_its_reference_lines_and_its_margins(monkeypatch):
    # The integrator with a 1 ms delay (test_stability): crossover 100 Hz, PM = 90 - 36 = 54
    # degrees, phase -180 at 250 Hz where |L| = 100/250: GM = 20 log10(2.5) = 7.96 dB, and
    # every later crossing of the negative real axis marked as well.
    dt = 1e-4
    f = frequency_grid(dt, 4000)

    def fn(x):
        return 100.0 * np.exp(-2j * np.pi * x * 1e-3) / (1j * x)

    loop = fn(f)
    m = _analytic(fn, dt)
    fig = _plotted(monkeypatch, f, loop, m, "T", (6.0, 30.0))
    ax_m, ax_p = fig.axes
    curve = ax_m.lines[0]
    np.testing.assert_allclose(curve.get_xdata(), f)
    np.testing.assert_allclose(curve.get_ydata(), 20 * np.log10(100.0 / f), rtol=1e-9)
    phase = ax_p.lines[0].get_ydata()
    np.testing.assert_allclose(phase, -90.0 - 360.0 * f * 1e-3, atol=1e-6)  # continuous
    horizontal = [
        ln.get_ydata()[0] for ln in ax_p.lines[1:] if ln.get_ydata()[0] == ln.get_ydata()[1]
    ]
    assert horizontal == [-1620, -1260, -900, -540, -180, 180]  # -180 + 360 k, k = -4 .. 1
    assert all(ln.get_linewidth() > 0 for ax in (ax_m, ax_p) for ln in ax.lines)
    assert [ln.get_ydata()[0] for ln in ax_m.lines[1:2]] == [0]  # the 0 dB line
    assert ax_p.get_ylim() == pytest.approx((phase.min() - 20, 20.0))
    vertical_m = [ln.get_xdata()[0] for ln in ax_m.lines[2:]]
    want = [c[0] for c in m.crossovers] + [c[0] for c in m.phase_crossovers] + [m.bandwidth_hz]
    assert vertical_m == pytest.approx(want)
    (pm_note,) = ax_p.texts
    assert pm_note.get_text() == "PM 54.0 deg at 100 Hz"
    assert pm_note.xy == pytest.approx((100.0, -126.0), abs=1e-3)
    notes = [t.get_text() for t in ax_m.texts]
    assert notes[0] == "GM 8.0 dB at 250 Hz" and len(notes) == len(m.phase_crossovers)
    assert ax_m.texts[0].xy == pytest.approx((m.phase_crossover_hz, -m.gain_margin_db))
    assert ax_m.get_title() == (
        f"stable: gain margin {m.gain_margin_db:.3g} dB, phase margin 54 deg, delay margin "
        f"1.5 ms, closed-loop bandwidth {m.bandwidth_hz:.3g} Hz"
    )
    assert fig.get_suptitle() == "T (minima 6 dB, 30 deg)"


def test_bode_plot_of_an_unstable_loop_and_of_one_without_crossings(monkeypatch):
    dt = 1e-4
    f = frequency_grid(dt, 400)

    def fn(x):
        return 100.0 * np.exp(-2j * np.pi * x * 4e-3) / (1j * x)

    m = _analytic(fn, dt, stable=False, radius=1.33)
    title = _plotted(monkeypatch, f, fn(f), m, "T").axes[0].get_title()
    assert title.startswith(
        "unstable (spectral radius 1.33): gain margin -4.08 dB, phase margin -54"
    )
    # L = 10 never crosses 1 nor the negative real axis: no marks, "unbounded" margins, no
    # bandwidth ("none"), no minima in the title when none are given.
    loop = np.full(f.size, 10.0 + 0j)
    m = _analytic(lambda x: np.full(np.shape(x), 10.0 + 0j), dt)
    fig = _plotted(monkeypatch, f, loop, m, "T")
    ax_m, ax_p = fig.axes
    assert not ax_m.texts and not ax_p.texts
    assert len(ax_m.lines) == 2  # the curve and the 0 dB line
    assert np.all(ax_m.lines[0].get_ydata() == 20.0)
    assert ax_m.get_title() == (
        "stable: gain margin unbounded, phase margin unbounded, delay margin unbounded, "
        "closed-loop bandwidth none"
    )
    assert fig.get_suptitle() == "T"
    assert ax_p.get_ylim() == pytest.approx((-220.0, 20.0))
    # An exact zero of L on the grid is drawn (far below the rest), not lost as -inf.
    loop[20] = 0.0
    curve = _plotted(monkeypatch, f, loop, m, "T").axes[0].lines[0].get_ydata()
    assert np.all(np.isfinite(curve)) and curve[20] < -1000


# --- more of the held input -----------------------------------------------------------------


def _exact_moment(m: int, x: float) -> Fraction:
    """``int_0^x u^m e^-u du`` (tau = 1) in exact rational arithmetic: the series
    ``x^(m+1) sum_n (-x)^n / (n! (n + m + 1))`` to 60 terms (the rest below 1e-40 for x <= 5)."""
    big = Fraction(x)
    total, term = Fraction(0), Fraction(1)
    for n in range(60):
        total += term / (n + m + 1)
        term *= -big / (n + 1)
    return big ** (m + 1) * total


@pytest.mark.parametrize("x", [1e-9, 0.3, 0.49, 0.51, 1.0, 1.49, 2.0, 5.0])
def test_exponential_moments_to_a_few_units_of_the_last_place(x):
    # "no cancellation" (the module doc): within 5e-15 of the exact value on both sides of
    # the switch between the series (x < 0.5) and the closed form.
    for m in (0, 1, 2):
        exact = _exact_moment(m, x)
        got = exp_moment.py_func(m, x, 1.0)
        assert abs(Fraction(got) - exact) <= Fraction(5, 10**15) * exact, (m, x)


def test_a_lag_starting_exactly_one_ampere_below_its_level():
    # i(s) = 2 - exp(-s / tau) on [0, tau]: the level's moments 2 tau, tau^2, 2 tau^3 / 3
    # minus those of test_a_lag_starting_exactly_one_ampere_above_its_level.
    tau = 1e-4
    out = np.zeros(3)
    piece_moments.py_func(out, 0.0, tau, 2.0, -1.0, tau)
    e = math.exp(-1)
    want = [2 * tau - tau * (1 - e), tau**2 - tau**2 * (1 - 2 * e),
            2 * tau**3 / 3 - tau**3 * (2 - 5 * e)]  # fmt: skip
    np.testing.assert_allclose(out, want, rtol=1e-12)


def test_substep_input_says_whether_the_current_is_constant():
    T = 1e-4
    out = np.zeros(6)
    # ideal loop, the switch inside the substep: two levels, not constant
    assert not substep_input(out, 0.0, T, 0.0, -1.5, 2.5, 0.5 * T, 0.0)
    # a lag settling from 0 toward 1: not constant even without a switch
    assert not substep_input(out, 0.0, T, 0.0, 1.0, 1.0, 0.0, 1e-4)
    # ideal, no switch: constant
    assert substep_input(out, 0.0, T, 0.0, 1.0, 1.0, 0.0, 0.0)


# --- frozen results ----------------------------------------------------------------------------


def test_result_types_are_frozen():
    import dataclasses

    from servogym.sim._check import CaseResult
    from servogym.sim._convergence import Agreement
    from servogym.sim._margins import Margins

    m = Margins(1.0, 2.0, 3.0, 4.0, 5.0)
    lin = LinearPlant(np.eye(1), np.ones(1), np.ones(1), np.zeros(1), np.ones(1), 1e-3, 0.0)
    case = CaseResult("reference", "same_tick", {}, 1.0, False, "none", math.nan, 1.0, 0.0)
    agreement = Agreement(True, True, 0, 8.0, 1.0, 1.0, False, False, "")
    for obj, name in ((m, "bandwidth_hz"), (lin, "dt"), (case, "cost"), (agreement, "ok"),
                      (CheckLimits(), "min_gain_margin_db")):  # fmt: skip
        with pytest.raises(dataclasses.FrozenInstanceError):
            setattr(obj, name, 0)


# --- more margins ----------------------------------------------------------------------------


def test_continuous_phase_of_a_start_on_the_negative_axis_from_below():
    # angle(-1 - 0j) = -180 degrees, already in (-360, 0]: kept.
    loop = np.array([complex(-1.0, -0.0), np.exp(-1j * np.radians(200.0))])
    np.testing.assert_allclose(np.degrees(continuous_phase(loop)), [-180.0, -200.0])


def test_plant_response_on_the_grid_and_the_open_loop_by_hand():
    from servogym.chips import get_chip
    from servogym.sim._margins import open_loop, plant_response

    # The slide of test_pure_inertia_response..., L = 0: P = KC k T^2/2 (z+1)/(z-1)^2 at
    # z = exp(2 pi j f T) on the default grid.
    dt = 1e-3
    freqs, p = plant_response(slide_plant(), dt, 0.0)
    np.testing.assert_array_equal(freqs, frequency_grid(dt))
    z = np.exp(2j * np.pi * freqs * dt)
    k = GEAR * KT * KA / MASS
    np.testing.assert_allclose(p, KC * k * dt**2 / 2 * (z + 1) / (z - 1) ** 2, rtol=1e-6)
    # PMD (MC58000, biquads off), Ki = 512 (2 after the 2^-8 shift), Kout = 32768 (0.5):
    # C = 1 / (1 - z^-1); at a quarter of the sample rate z = j, C = 1 / (1 + j) = (1 - j)/2;
    # times P = 2: 1 - j.
    family, model = get_chip("MC58000")
    params = family.make_params(model, dict(kp=0, ki=512, kd=0, kout=32768))
    f = np.array([0.25 / family.sample_time_s(params)])
    got = open_loop(family, params, family.default_assumptions(), f, np.array([2.0 + 0j]))
    assert got[0] == pytest.approx(1 - 1j)


def test_check_keeps_the_scenarios_assumptions(tmp_path, monkeypatch):
    """A scenario with its own assumptions (latency same_tick, a 16-bit DAC, the integral
    on the previous errors): the reference case, the margins and the Bode plot use them."""
    import dataclasses
    import time

    import matplotlib.figure

    from servogym.chips import get_chip
    from servogym.sim import Scenario, check_params
    from servogym.sim._check import loop_margins, stress_cases, write_bode
    from servogym.sim._scenario import Evaluator

    from .test_convergence import SETS

    family, _ = get_chip("6250")
    asm = family.assumptions_type(loop_latency="same_tick", dac_bits="16",
                                  integral_timing="previous")  # fmt: skip
    base = Scenario("6250", "rotary")
    scenario = Scenario("6250", "rotary", moves=base.moves[:1], assumptions=asm)
    params = scenario.params(SETS["6250/rotary/default"]["values"])
    cases = stress_cases(scenario, CheckLimits())
    assert cases[0].loop_latency == "same_tick"
    assert [c.name for c in cases[1:3]] == ["latency full_period", "latency half_period"]
    own = loop_margins(scenario, params)
    assert list(own) == ["same_tick"]
    default = loop_margins(dataclasses.replace(scenario, assumptions=None), params)
    assert own["same_tick"].margins != default["full_period"].margins
    t0 = time.perf_counter()
    report = check_params(params, scenario, CheckLimits(reference_substeps=4), workers=1)
    assert 0 < report.elapsed_s <= time.perf_counter() - t0
    assert report.margins == own["same_tick"].margins
    ref = Evaluator(dataclasses.replace(scenario, integrator="rk4", substeps=4)).evaluate(params)
    assert report.cases[0].cost == ref.cost
    figures = []
    monkeypatch.setattr(
        matplotlib.figure.Figure, "savefig", lambda fig, *a, **k: figures.append(fig)
    )
    write_bode(tmp_path / "bode.png", scenario, params, CheckLimits())
    (fig,) = figures
    assert fig.get_suptitle() == (
        "6250 on rotary: open loop (latency same_tick) (minima 6 dB, 30 deg)"
    )
    curve = fig.axes[0].lines[0].get_ydata()
    np.testing.assert_allclose(curve, 20 * np.log10(np.abs(own["same_tick"].analysis.loop)))
