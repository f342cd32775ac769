"""Closed-loop stability decided from the poles, and the margins found by root-finding.

Hand-derived poles (a discrete double integrator closed by a pure gain, with and without a
tick of latency), the sets of issue 18 on the real plants, the linear loop run as a
difference equation on random sets of every chip family, and the margins' own definitions
(a gain change of exactly the gain margin reaches the unit circle).
"""

from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np
import pytest

from servogym.chips import families, get_chip
from servogym.plants import PLANTS, get_plant
from servogym.sim import Evaluator, Scenario
from servogym.sim._margins import (
    STABILITY_EPS,
    LinearPlant,
    Margins,
    Stability,
    analyse_loop,
    characteristic_polynomial,
    closed_loop_matrix,
    closed_loop_stability,
    continuous_model,
    count_roots_inside,
    frequency_margins,
    linearize,
)

SETS = json.loads((Path(__file__).parent / "data" / "convergence_sets.json").read_text())

KNOWN_UNSTABLE = {"MC2100/two-mass/default": 1.0000915, "MC2100/two-mass/slowest": 1.00644}
"""Safe sets of tests/sim/data whose linear loop (nominal plant, default latency) is
unstable: a slowly growing resonance (0.0092 % and 0.64 % per tick) that the simulated
plant's Coulomb friction holds down. Issue 18 (their re-tuning is the check's job)."""


def double_integrator(latency_ticks: int = 0) -> LinearPlant:
    """``x = (position, velocity)``, T = 1, unit input: ``P = (z + 1) / (2 (z - 1)^2)`` with
    the command applied at once, times ``z^-1`` with a full tick of latency."""
    phi = np.array([[1.0, 1.0], [0.0, 1.0]])
    g = np.array([0.5, 1.0])
    zero = np.zeros(2)
    g_new, g_old = (g, zero) if latency_ticks == 0 else (zero, g)
    return LinearPlant(phi=phi, g_new=g_new, g_old=g_old, drift=zero,
                       c=np.array([1.0, 0.0]), dt=1.0, latency=float(latency_ticks))  # fmt: skip


def loop_on(chip_model: str, plant: str, values: dict, plant_values: dict | None = None):
    family, model = get_chip(chip_model)
    params = family.make_params(model, values)
    asm = family.default_assumptions()
    pf = get_plant(plant)
    built = pf.build({**pf.nominal(), **(plant_values or {})})
    lin = linearize(built, family.sample_time_s(params), family.loop_latency_s(params, asm))
    return family, params, asm, lin


def set_loop(key: str):
    rec = SETS[key]
    scenario = Scenario(rec["chip"], rec["plant"])
    params = scenario.params(rec["values"])
    family = scenario.chip
    asm = family.default_assumptions()
    pf = get_plant(rec["plant"])
    lin = linearize(pf.build(pf.nominal()), family.sample_time_s(params),
                    family.loop_latency_s(params, asm))  # fmt: skip
    return family, params, asm, lin


# --- hand-derived poles ------------------------------------------------------------------


@pytest.mark.parametrize("k", [0.01, 0.5, 3.0])
def test_a_pure_gain_on_a_double_integrator_is_never_stable(k):
    """1 + k P = 0: z^2 + (k/2 - 2) z + (1 + k/2) = 0, the poles' product 1 + k/2 > 1."""
    s = closed_loop_stability((np.array([k]), np.array([1.0])), double_integrator())
    want = np.roots([1.0, k / 2 - 2, 1 + k / 2])
    assert s.method == "eigenvalues" and not s.stable
    assert s.spectral_radius == pytest.approx(np.max(np.abs(want)), rel=1e-12)
    assert s.n_unstable == 2


def test_pd_on_a_double_integrator_by_hand():
    """C = kp + kd (1 - z^-1): z (z - 1)^2 + (z + 1)((kp + kd) z - kd)/2 = 0, a cubic."""
    kp, kd = 0.1, 0.6
    want = np.roots(np.polyadd([1.0, -2.0, 1.0, 0.0], np.polymul([0.5, 0.5], [kp + kd, -kd])))
    s = closed_loop_stability((np.array([kp + kd, -kd]), np.array([1.0])), double_integrator())
    assert s.stable and s.spectral_radius == pytest.approx(np.max(np.abs(want)), rel=1e-12)
    assert np.max(np.abs(want)) < 1


def test_pure_p_on_a_rigid_body_with_a_tick_of_latency():
    """u acts a tick late: z (z - 1)^2 + k (z + 1)/2 = 0; unstable for every k > 0 too, and
    the encirclement count of the characteristic polynomial says the same."""
    for k in (0.05, 0.4):
        polys = (np.array([k]), np.array([1.0]))
        lin = double_integrator(latency_ticks=1)
        want = np.roots([1.0, -2.0, 1.0 + k / 2, k / 2])
        s = closed_loop_stability(polys, lin)
        assert s.spectral_radius == pytest.approx(np.max(np.abs(want)), rel=1e-12)
        n_out = int(np.sum(np.abs(want) >= 1))
        assert s.n_unstable == n_out >= 1
        chi = characteristic_polynomial(polys, lin)
        assert count_roots_inside(chi, 1 / (1 - STABILITY_EPS)) == n_out


def test_a_loop_with_poles_on_the_circle_is_not_stable():
    """No gain at all: the rigid body's double pole at z = 1 stays (marginal, not stable);
    the encirclement count finds a root on its circle, or counts it as unstable."""
    polys = (np.array([0.0]), np.array([1.0]))
    s = closed_loop_stability(polys, double_integrator())
    assert not s.stable and s.spectral_radius >= 1 - STABILITY_EPS
    chi = characteristic_polynomial(polys, double_integrator())
    assert count_roots_inside(chi, 1 / (1 - STABILITY_EPS)) in (None, 2)
    # A pure derivative: one pole stays at z = 1 (the position is not held).
    s = closed_loop_stability((np.array([0.3, -0.3]), np.array([1.0])), double_integrator())
    assert not s.stable and s.n_unstable == 1


def test_count_roots_inside_by_hand():
    roots = np.array([0.5, -0.9, 1.2, 0.3 + 2j, 0.3 - 2j, 0.999, 1.001])
    coef = np.real(np.poly(roots))[::-1]
    assert count_roots_inside(coef, 1.0) == 3
    assert count_roots_inside(coef, 1.1) == 4
    assert count_roots_inside(np.array([-1.0, 1.0]), 1.0) is None  # a root on the circle


# --- margins of analytic loops -----------------------------------------------------------

STABLE = Stability(True, 0, 0.5, 2, "eigenvalues")


def analytic(loop_of_hz, dt=1e-4, stability=STABLE) -> Margins:
    return frequency_margins(lambda t: loop_of_hz(np.asarray(t) / (2 * np.pi * dt)), dt, stability)


def test_an_integrator_with_a_delay_by_hand():
    """L = wc e^{-jwD} / (jw), fc = 100 Hz, D = 1 ms: PM = 90 - 36 = 54 degrees at 100 Hz,
    delay margin (pi/2 - wc D) / wc = 1.5 ms; the phase is -180 at w D = pi/2 (250 Hz)
    where |L| = 0.4: GM 7.96 dB; again at -540 (1250 Hz), |L| = 0.08: 21.9 dB."""
    m = analytic(lambda f: 100.0 * np.exp(-2j * np.pi * f * 1e-3) / (1j * f))
    assert m.stable and m.gain_crossover_hz == pytest.approx(100.0, rel=1e-9)
    assert m.phase_margin_deg == pytest.approx(54.0, abs=1e-6)
    assert m.delay_margin_s == pytest.approx(1.5e-3, rel=1e-6)
    assert m.crossovers == (pytest.approx((100.0, 54.0, 1.5e-3), rel=1e-6),)
    assert m.phase_crossover_hz == pytest.approx(250.0, rel=1e-9)
    assert m.gain_margin_db == pytest.approx(20 * math.log10(2.5), abs=1e-6)
    hz = [h for h, _ in m.phase_crossovers]
    assert hz[:3] == pytest.approx([250.0, 1250.0, 2250.0], rel=1e-9)
    assert m.phase_crossovers[1][1] == pytest.approx(20 * math.log10(12.5), abs=1e-6)


def test_an_unstable_integrator_loop_has_negative_margins():
    """D = 4 ms: at 100 Hz the phase is -90 - 144 = -234: PM = 180 - 234 = -54 (a lead of 54
    degrees stabilises it); the phase is -180 at 62.5 Hz where |L| = 1.6: the gain must fall
    by 4.08 dB. Neither margin is ever 'unbounded'."""
    unstable = Stability(False, 2, 1.1, 3, "eigenvalues")
    m = analytic(lambda f: 100.0 * np.exp(-2j * np.pi * f * 4e-3) / (1j * f), stability=unstable)
    assert not m.stable
    assert m.phase_margin_deg == pytest.approx(-54.0, abs=1e-6)
    assert m.crossovers[0][1] == pytest.approx(-54.0, abs=1e-6)
    assert m.crossovers[0][2] == pytest.approx(-math.radians(54) / (2 * math.pi * 100), rel=1e-6)
    assert m.delay_margin_s < 0
    assert m.gain_margin_db == pytest.approx(-20 * math.log10(1.6), abs=1e-6)
    assert m.phase_crossover_hz == pytest.approx(62.5, rel=1e-9)
    assert m.phase_crossovers[0][1] == pytest.approx(-20 * math.log10(1.6), abs=1e-6)


def test_bandwidth_is_root_found():
    """L = fc / (jf): |T| = 1 / sqrt(1 + (f/fc)^2), 3 dB below its low-frequency value at fc
    (to the 1e-8 the reference at the lowest searched frequency, 0.01 Hz, leaves), not at
    the next grid point."""
    m = analytic(lambda f: 100.0 / (1j * f))
    assert m.bandwidth_hz == pytest.approx(100.0, rel=2e-8)
    assert math.isinf(m.gain_margin_db) and m.phase_margin_deg == pytest.approx(90.0)
    never = analytic(lambda f: np.full(np.shape(f), 10.0 + 0j))
    assert math.isnan(never.bandwidth_hz) and math.isinf(never.phase_margin_deg)
    assert never.to_dict()["phase_margin_deg"] is None and never.to_dict()["crossovers"] == []


def test_to_dict_is_json_ready():
    m = analytic(lambda f: 100.0 * np.exp(-2j * np.pi * f * 1e-3) / (1j * f))
    d = json.loads(json.dumps(m.to_dict(), allow_nan=False))
    assert d["stable"] is True and math.isnan(m.spectral_radius) is False
    assert d["crossovers"][0] == pytest.approx([100.0, 54.0, 1.5e-3], rel=1e-6)
    assert isinstance(d["phase_crossovers"][0], list)


# --- the sets of issue 18 ----------------------------------------------------------------


def test_mc2100_on_rotary_at_616_us_is_unstable():
    """kp 400, kd 8000 at 616 us: read 'GM unbounded, PM unbounded' on the old grid."""
    family, params, asm, lin = loop_on("MC2100", "rotary",
                                       dict(kp=400, kd=8000, sample_time_us=616))  # fmt: skip
    assert family.sample_time_s(params) == pytest.approx(616e-6)
    m = analyse_loop(family, params, asm, lin).margins
    assert not m.stable and m.spectral_radius > 1.1
    assert m.gain_margin_db <= 0 and m.phase_margin_deg <= 0
    assert math.isfinite(m.phase_margin_deg)


def test_an_unstable_two_mass_set_grows_per_tick_and_saturates():
    """The MC2100 two-mass safe set with Kout doubled: the linear loop grows 1.12x per tick;
    simulated, the motor is at its limit on most ticks."""
    rec = SETS["MC2100/two-mass/default"]
    values = {**rec["values"], "kout": 2 * rec["values"]["kout"]}
    family, params, asm, lin = loop_on("MC2100", "two-mass", values)
    m = analyse_loop(family, params, asm, lin).margins
    assert not m.stable and m.spectral_radius == pytest.approx(1.1176, abs=1e-3)
    assert m.gain_margin_db <= 0 and m.phase_margin_deg <= 0 and m.delay_margin_s <= 0
    scenario = Scenario("MC2100", "two-mass")
    ev = Evaluator(scenario).evaluate(scenario.params(values))
    assert ev.diverged or ev.saturation_fraction > 0.5


def test_mc58000_on_two_mass_reports_every_crossover():
    """48.8 degrees at 41 Hz, but a crossover at 404 Hz sets the delay margin: 0.34 ms."""
    family, params, asm, lin = set_loop("MC58000/two-mass/default")
    m = analyse_loop(family, params, asm, lin).margins
    assert m.stable
    hz = [c[0] for c in m.crossovers]
    assert len(hz) == 3 and hz[0] == pytest.approx(41.3, abs=0.1)
    assert hz[-1] == pytest.approx(404.4, abs=0.2)
    assert m.phase_margin_deg == pytest.approx(48.8, abs=0.1)
    assert m.crossovers[0][2] == pytest.approx(3.3e-3, abs=0.05e-3)
    assert m.delay_margin_s == pytest.approx(m.crossovers[-1][2])
    assert m.delay_margin_s == pytest.approx(0.336e-3, abs=2e-6)
    for f in hz:  # each a root of |L| = 1
        z = np.exp(2j * np.pi * f * lin.dt)
        assert abs(family.filter_response(params, asm, z) * lin.response(np.array([z]))[0]) == (
            pytest.approx(1.0, abs=1e-7)
        )


def test_a_close_pair_of_crossovers_at_a_resonance_is_found():
    """The two-mass resonance peak raised just above 0 dB: two crossovers well under 1 %
    apart, both found and both roots of |L| = 1."""
    rec = SETS["MC58000/two-mass/default"]
    family, params, asm, lin = set_loop("MC58000/two-mass/default")

    def peak_crossovers(kout):
        p = params.replace(kout=kout)
        return p, analyse_loop(family, p, asm, lin).margins.crossovers

    lo, hi = 1, rec["values"]["kout"]  # bisect Kout to the last value with one crossover
    while hi - lo > 1:
        mid = (lo + hi) // 2
        lo, hi = (mid, hi) if len(peak_crossovers(mid)[1]) < 3 else (lo, mid)
    p, cross = peak_crossovers(hi)
    pair = [c[0] for c in cross[1:]] if len(cross) == 3 else []
    assert len(cross) == 3 and pair[1] / pair[0] < 1.01
    for f in pair:
        z = np.exp(2j * np.pi * f * lin.dt)
        loop = family.filter_response(p, asm, z) * lin.response(np.array([z]))[0]
        assert abs(loop) == pytest.approx(1.0, abs=1e-7)


def test_safe_sets_are_stable():
    """Every safe set of every chip on every plant family (nominal plant, default latency)
    has a stable linear loop, but the two in KNOWN_UNSTABLE."""
    unstable = {}
    for key in sorted(SETS):
        family, params, asm, lin = set_loop(key)
        m = analyse_loop(family, params, asm, lin).margins
        if not m.stable:
            unstable[key] = m.spectral_radius
        else:
            assert m.gain_margin_db > 0 and m.phase_margin_deg > 0 and m.delay_margin_s > 0
    assert unstable == pytest.approx(KNOWN_UNSTABLE, abs=1e-5)
    assert {k.split("/")[1] for k in SETS} == set(PLANTS)


@pytest.mark.parametrize("key", ["TurboPMAC2/rotary/default", "6250/two-mass/default",
                                 "MC58000/two-mass/default", "MC2100/arm/default"])  # fmt: skip
def test_the_gain_margin_is_the_gain_change_that_reaches_the_circle(key):
    """Scaling C by the gain margin (up or down, the side it was found on) less 1e-6 keeps
    the loop stable; 1e-6 past it does not."""
    family, params, asm, lin = set_loop(key)
    m = analyse_loop(family, params, asm, lin).margins
    num, den = family.filter_polynomials(params, asm)
    (gm,) = [g for hz, g in m.phase_crossovers if hz == m.phase_crossover_hz]
    assert abs(gm) == pytest.approx(m.gain_margin_db)
    factor = 10 ** (gm / 20)
    inside = closed_loop_stability((num * factor ** (1 - 1e-6), den), lin)
    outside = closed_loop_stability((num * factor ** (1 + 1e-6), den), lin)
    assert inside.stable and not outside.stable


# --- stability against the loop run as a difference equation ---------------------------


def simulate(polys, lin: LinearPlant, n_ticks: int = 2000) -> np.ndarray:
    """|x| over the ticks of the LTI loop from a small initial state: the plant's update,
    the filter as its difference equation on E = -y (direct form I)."""
    num, den = polys
    x = np.full(lin.phi.shape[0], 1e-3)
    e_hist = np.zeros(num.size)
    u_hist = np.zeros(max(den.size, 2))
    norms = []
    for _ in range(n_ticks):
        e_hist = np.roll(e_hist, 1)
        e_hist[0] = -(lin.c @ x)
        u = (num @ e_hist - den[1:] @ u_hist[: den.size - 1]) / den[0]
        x = lin.phi @ x + lin.g_new * u + lin.g_old * u_hist[0]
        u_hist = np.roll(u_hist, 1)
        u_hist[0] = u
        norms.append(np.linalg.norm(x) + abs(u))
        if norms[-1] > 1e150:  # grown beyond doubt (and before overflow)
            break
    return np.array(norms)


def growth_per_tick(norms: np.ndarray) -> float:
    """The loop's growth factor per tick over the second half of the run (peak to peak,
    a quarter of the run apart, so an oscillation's phase does not matter)."""
    n = norms.size
    q = max(n // 4, 1)
    return (norms[-q:].max() / norms[n // 2 - q : n // 2].max()) ** (1 / (n - n // 2))


SAFE_ON_ROTARY = {"pmd": "MC2100", "pmac": "TurboPMAC2", "parker6k": "6250"}
GAINS = ("kp", "ki", "kd", "kout", "proportional_gain", "derivative_gain", "integral_gain",
         "sgp", "sgi", "sgv")  # fmt: skip


def random_values(family, model, rng) -> dict:
    """The family's safe rotary set with every gain scaled by a random factor in
    [1/12, 12] (log-uniform, kept in its legal range): stable and unstable sets alike."""
    values = dict(SETS[f"{model}/rotary/default"]["values"])
    space = family.parameter_space(model)
    for name in GAINS:
        if name in values:
            spec = space[name]
            scaled = round(values[name] * math.exp(rng.uniform(-2.5, 2.5)))
            values[name] = min(spec.high, max(spec.low, scaled))
    return values


@pytest.mark.parametrize("family_name", sorted(families()))
def test_stability_agrees_with_the_difference_equation(family_name):
    """Random sets of each family on the rotary plant (a current-loop lag, one rigid body):
    the loop run for 2000 ticks grows exactly when a pole is outside the circle, by the
    spectral radius per tick."""
    family = families()[family_name]
    model = SAFE_ON_ROTARY[family_name]
    rng = np.random.default_rng(18)
    pf = get_plant("rotary")
    plant = pf.build(pf.nominal())
    cont = continuous_model(plant)
    seen = {True: 0, False: 0}
    for _ in range(60):
        params = family.make_params(model, random_values(family, model, rng))
        asm = family.default_assumptions()
        lin = linearize(plant, family.sample_time_s(params), family.loop_latency_s(params, asm),
                        cont)  # fmt: skip
        polys = family.filter_polynomials(params, asm)
        s = closed_loop_stability(polys, lin)
        if abs(s.spectral_radius - 1) < 0.003:
            continue  # too slow to tell apart in 2000 ticks
        norms = simulate(polys, lin)
        growth = growth_per_tick(norms)
        assert (growth > 1) == (not s.stable), (params, s, growth)
        assert growth == pytest.approx(s.spectral_radius, rel=0.01)
        seen[s.stable] += 1
    assert seen[True] >= 3 and seen[False] >= 3


def test_long_derivative_times_by_encirclement_agree_with_eigenvalues():
    """A PMD DerivativeTime of 40 (filter order 80) on the two-mass plant: the eigenvalues
    and the encirclement count of the characteristic polynomial agree, stable or not; at
    300 (order 600) the encirclement count decides (no spectral radius)."""
    rec = SETS["MC2100/two-mass/default"]
    for kd, d in ((0, 40), (rec["values"]["kd"], 40), (32767, 40)):
        values = {**rec["values"], "kd": kd, "derivative_time": d}
        family, params, asm, lin = loop_on("MC2100", "two-mass", values)
        polys = family.filter_polynomials(params, asm)
        poles = np.linalg.eigvals(closed_loop_matrix(polys, lin))
        n_out = int(np.sum(np.abs(poles) >= 1 - STABILITY_EPS))
        chi = characteristic_polynomial(polys, lin)
        assert count_roots_inside(chi, 1 / (1 - STABILITY_EPS)) == n_out
    family, params, asm, lin = loop_on("MC2100", "two-mass",
                                       {**rec["values"], "derivative_time": 300})  # fmt: skip
    s = closed_loop_stability(family.filter_polynomials(params, asm), lin)
    assert s.method == "encirclement" and math.isnan(s.spectral_radius)
    m = analyse_loop(family, params, asm, lin).margins
    assert m.stable == s.stable and (m.stable or m.phase_margin_deg <= 0)


def test_continuous_model_at_a_holding_point():
    """The arm linearised at another angle: gravity's slope (the position column of the
    acceleration rows) changes; the rest stays."""
    pf = get_plant("arm")
    plant = pf.build(pf.nominal())
    a0, b0, c0, _ = continuous_model(plant)
    qpos = np.array(plant.model.qpos0, dtype=float)
    qpos[plant.io.qpos_adr] += 0.7
    a1, b1, c1, _ = continuous_model(plant, qpos=qpos)
    np.testing.assert_allclose(b0, b1, rtol=1e-8)
    np.testing.assert_array_equal(c0, c1)
    nv = plant.model.nv
    assert not np.allclose(a0[nv : 2 * nv, :nv], a1[nv : 2 * nv, :nv])
    np.testing.assert_allclose(continuous_model(plant, qpos=plant.model.qpos0)[0], a0)
