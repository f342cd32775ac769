"""Loop margins: the linearised plant against the simulation, the margins against known loops."""

from __future__ import annotations

import math
from types import SimpleNamespace

import numpy as np
import pytest

from servogym.chips.pmd import PMDAssumptions, PMDParams
from servogym.plants import PLANTS, get_plant
from servogym.sim import ServoLoop
from servogym.sim._margins import frequency_grid, linearize, margins


@pytest.mark.parametrize("plant_name", list(PLANTS))
@pytest.mark.parametrize("latency", ["same_tick", "half_period", "axis_slot"])
def test_linear_plant_replays_the_simulated_response(plant_name, latency):
    """x[k+1] = Phi x + G_new u[k] + G_old u[k-1] + drift, fed the loop's command trace,
    reproduces the encoder trace of the reference integration (Coulomb friction at its
    smallest: the linearisation leaves it out)."""
    family = get_plant(plant_name)
    values = {**family.nominal(), "current_bandwidth_hz": 800.0}
    for p in family.params:
        if p.name.startswith("coulomb"):
            values[p.name] = p.low
    plant = family.build(values)
    params = PMDParams(model="MC2100", kp=60, kd=600, ki=0, kout=16384, derivative_time=1)
    loop = ServoLoop(plant, params, PMDAssumptions(loop_latency=latency), substeps=32)
    io = plant.io
    step = int(0.002 * (io.travel_max - io.travel_min) * io.counts_per_unit)
    n = 600
    zeros = np.zeros(n, np.int64)
    profile = SimpleNamespace(position=np.full(n, step, np.int64), velocity=zeros,
                              acceleration=zeros.copy(), start=0)  # fmt: skip
    r = loop.run(profile, traces=True)
    assert not r.metrics.diverged
    lin = linearize(plant, loop.dt, loop.latency_s)
    x = np.zeros(lin.phi.shape[0])
    u_old, ys = 0.0, []
    for u in r.traces.command.astype(float):
        ys.append(lin.c @ x)
        x = lin.phi @ x + lin.g_new * u + lin.g_old * u_old + lin.drift
        u_old = u
    # An open-loop replay integrates any mismatch (the plant has a free rigid-body mode), so
    # only the step's transient is compared, where friction is small against the motor.
    window = slice(0, 200)
    peak = np.max(np.abs(r.traces.actual[window]))
    assert peak > 100
    assert np.max(np.abs(np.array(ys)[window] - r.traces.actual[window])) <= 2 + 0.01 * peak


def test_margins_of_an_integrator_with_a_delay():
    """L(jw) = wc e^{-jwD} / (jw): crossover at wc, PM = 90 - wc D (deg), GM at wc... known."""
    dt = 1e-4
    f = frequency_grid(dt, 4000)
    w = 2 * np.pi * f
    wc, delay = 2 * np.pi * 100.0, 1e-3
    loop = wc * np.exp(-1j * w * delay) / (1j * w)
    m = margins(f, loop)
    assert m.gain_crossover_hz == pytest.approx(100.0, rel=1e-3)
    assert m.phase_margin_deg == pytest.approx(90 - math.degrees(wc * delay), abs=0.05)
    # phase -180 where w D = pi/2: w = pi / (2 D), |L| = wc / w
    w180 = math.pi / (2 * delay)
    assert m.phase_crossover_hz == pytest.approx(w180 / (2 * math.pi), rel=1e-3)
    assert m.gain_margin_db == pytest.approx(-20 * math.log10(wc / w180), abs=0.01)


def test_a_loop_that_never_crosses_has_unbounded_phase_margin():
    f = frequency_grid(1e-4, 200)
    loop = 0.1 / (1 + 1j * f / 50.0)
    m = margins(f, loop)
    assert math.isinf(m.phase_margin_deg) and math.isnan(m.gain_crossover_hz)
    assert math.isinf(m.gain_margin_db)
    assert m.to_dict()["phase_margin_deg"] is None


def test_a_later_crossover_counts_by_its_distance_from_minus_one():
    """A loop that rises above 0 dB again near Nyquist with its phase past -270 degrees:
    the classical formula would give 180 - 300 = -120 degrees; that crossing lies 120
    degrees from -1, and the bandwidth crossover's 55 degrees is the margin."""
    f = np.array([1.0, 100.0, 199.0, 201.0, 600.0, 1070.0, 1090.0])
    mag = np.array([100.0, 3.0, 1.01, 0.99, 0.5, 0.99, 1.01])
    deg = np.array([-180.0, -150.0, -125.0, -125.0, -180.0, -300.0, -300.0])
    loop = mag * np.exp(1j * np.radians(deg))
    m = margins(f, loop)
    assert m.phase_margin_deg == pytest.approx(55.0)
    assert m.gain_crossover_hz == pytest.approx(200.0, rel=1e-3)
    assert m.gain_margin_db == pytest.approx(-20 * math.log10(0.5), abs=0.01)
