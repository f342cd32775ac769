"""The held motor current within a tick: exact pieces, exact moments, the quadratic RK4 sees."""

from __future__ import annotations

import math

import numpy as np
import pytest
from scipy.integrate import quad

from servogym.sim._inputs import current_at, exp_moment, substep_input

T = 154e-6


def moments_by_quadrature(a, h, i0, r_old, r_new, latency, tau):
    def f(t, j):
        return (t - a) ** j * current_at.py_func(t, i0, r_old, r_new, latency, tau)

    points = [latency] if a < latency < a + h else None
    return [quad(f, a, a + h, args=(j,), points=points, epsabs=0, epsrel=1e-12)[0]
            for j in range(3)]  # fmt: skip


@pytest.mark.parametrize("m", [0, 1, 2])
@pytest.mark.parametrize("x", [1e-9, 1e-4, 0.3, 0.49, 0.51, 2.0, 40.0])
def test_exponential_moments_match_quadrature_on_both_sides_of_the_series_switch(m, x):
    tau = 1e-4
    w = x * tau
    want = quad(lambda u: u**m * math.exp(-u / tau), 0, w, epsabs=0, epsrel=1e-13)[0]
    assert exp_moment.py_func(m, w, tau) == pytest.approx(want, rel=1e-12)
    assert exp_moment(m, w, tau) == pytest.approx(want, rel=1e-12)


def test_an_ideal_loop_without_a_switch_holds_the_level_exactly():
    out = np.zeros(6)
    assert substep_input(out, 0.0, T, 0.0, -1.5, 2.5, 0.0, 0.0)
    assert list(out[:4]) == [2.5] * 4  # latency 0: the new command from the start
    assert substep_input(out, 0.0, T, 0.0, -1.5, 2.5, T, 0.0)
    assert list(out[:4]) == [-1.5] * 4  # a full period: the old command all tick


@pytest.mark.parametrize("latency_fraction", [0.0, 0.25, 0.5, 0.9, 1.0])
@pytest.mark.parametrize("tau", [0.0, 20e-6, 80e-6, 2e-3])
@pytest.mark.parametrize("n_sub", [1, 3])
def test_the_quadratic_has_the_moments_of_the_exact_current(latency_fraction, tau, n_sub):
    i0, r_old, r_new = 0.7, -1.2, 3.4
    latency = latency_fraction * T
    h = T / n_sub
    out = np.zeros(6)
    for j in range(n_sub):
        a = j * h
        substep_input(out, a, h, i0, r_old, r_new, latency, tau)
        want = moments_by_quadrature(a, h, i0, r_old, r_new, latency, tau)
        # the quadratic through p(0), p(h/2), p(h) has these moments
        p0, pm, p1 = out[0], out[1], out[2]
        c2 = 2 * (p1 - 2 * pm + p0) / h**2
        c1 = (p1 - p0) / h - c2 * h
        got = [p0 * h + c1 * h**2 / 2 + c2 * h**3 / 3,
               p0 * h**2 / 2 + c1 * h**3 / 3 + c2 * h**4 / 4,
               p0 * h**3 / 3 + c1 * h**4 / 4 + c2 * h**5 / 5]  # fmt: skip
        scale = [h * 3.4, h**2 * 3.4, h**3 * 3.4]
        for g, w, s in zip(got, want, scale, strict=True):
            assert abs(g - w) <= 1e-9 * s
        assert out[3] == pytest.approx(want[0] / h, rel=1e-9, abs=1e-12)


def test_current_is_continuous_through_the_switch_and_reaches_its_reference():
    tau, latency = 50e-6, 0.3 * T
    i0, r_old, r_new = 0.0, 1.0, -2.0
    before = current_at.py_func(latency * (1 - 1e-12), i0, r_old, r_new, latency, tau)
    after = current_at.py_func(latency, i0, r_old, r_new, latency, tau)
    assert after == pytest.approx(before, abs=1e-9)
    # one time constant after the switch: 63 % of the way to the new reference
    i_l = after
    one_tau = current_at.py_func(latency + tau, i0, r_old, r_new, latency, tau)
    assert (one_tau - i_l) / (r_new - i_l) == pytest.approx(1 - math.exp(-1), rel=1e-12)
    assert current_at.py_func(100 * tau, i0, r_old, r_new, latency, tau) == pytest.approx(r_new)


def test_the_plants_amplifier_recurrence_is_the_exact_current_at_sample_instants():
    from servogym.plants import PLANTS, amplifier_current

    io = PLANTS["rotary"].build({"current_bandwidth_hz": 1500.0}).io
    tau = 1 / (2 * math.pi * 1500.0)
    i = 0.0
    for command in (16384, 16384, -3000, 32767, 0):
        r = command * io.amp_amps_per_count
        exact = current_at.py_func(T, i, r, r, 0.0, tau)
        i = amplifier_current(command, i, io, T)
        assert i == pytest.approx(exact, rel=1e-13, abs=1e-15)


def test_any_positive_bandwidth_is_a_lag():
    from servogym.sim._runner import current_loop_tau

    # 0.5 Hz is slow but real: tau = 1 / (2 pi 0.5) s; only 0 (or less) is the ideal loop
    assert current_loop_tau(0.5) == pytest.approx(1 / math.pi)
    assert current_loop_tau(1.0) == pytest.approx(1 / (2 * math.pi))
    assert current_loop_tau(-1.0) == 0.0
