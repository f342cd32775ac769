"""Loop margins: the linearised plant against the simulation, the margins against known loops."""

from __future__ import annotations

from types import SimpleNamespace

import numpy as np
import pytest

from servogym.chips.pmd import PMDAssumptions, PMDParams
from servogym.plants import PLANTS, get_plant
from servogym.sim import ServoLoop
from servogym.sim._margins import linearize


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
