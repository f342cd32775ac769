"""Shared synthetic traces: hidden plants, a non-default latency, encoder quantisation and
a little noise on the recorded motor command (servogym.calibrate.synthetic_trace)."""

from __future__ import annotations

import pytest

from servogym.calibrate import synthetic_trace
from servogym.chips.pmd import PMDParams
from servogym.sim import MoveSpec

PARAMS = PMDParams(model="MC2100", kp=60, kd=600, ki=20, kout=6000, derivative_time=1)
"""The register set that "ran" (servogym's README example set)."""

ROTARY_HIDDEN = {"load_inertia_kgm2": 1.5e-4, "coulomb_friction_nm": 0.03}
ROTARY_MOVES = (MoveSpec(0.5, 40.0, 3000.0, 0.02), MoveSpec(-0.5, 40.0, 3000.0, 0.02))
HIDDEN_LATENCY = "half_period"
"""Not the MC2100's default (axis_slot, one full period on one axis)."""


@pytest.fixture(scope="session")
def rotary_trace():
    """An out-and-back move (600 samples) on a rotary axis with a hidden load."""
    return synthetic_trace(
        "MC2100", "rotary", ROTARY_HIDDEN, params=PARAMS, loop_latency=HIDDEN_LATENCY,
        moves=ROTARY_MOVES, command_noise_counts=2.0, seed=1,
    )  # fmt: skip


@pytest.fixture(scope="session")
def rotary_fit(rotary_trace):
    """The fit of the rotary trace, latency included."""
    from servogym.calibrate import calibrate

    return calibrate(rotary_trace, PARAMS, "rotary")
