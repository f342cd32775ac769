"""Synthetic traces: what a controller would record on a plant servogym simulates.

For tests, benchmarks and the tour: a trace of the scenario's moves on a plant whose values
the caller hides, at a loop latency the caller picks, simulated on the fine reference
integration (so a replay on the default integration is not bit-identical to it, as a real
axis is not), with the encoder's own quantisation and, optionally, noise on the recorded
motor command (a measurement's noise: the plant received the command without it).
"""

from __future__ import annotations

import dataclasses
from collections.abc import Mapping
from typing import Any

import numpy as np

from servogym.calibrate._trace import Trace


def synthetic_trace(
    chip_model: str,
    plant: str,
    plant_values: Mapping[str, float] | None = None,
    *,
    params: Any = None,
    loop_latency: str | None = None,
    moves: tuple = (),
    command_noise_counts: float = 0.0,
    seed: int = 0,
    substeps: int | None = None,
) -> Trace:
    """A trace of the scenario's moves (one after the other) on a hidden plant.

    Args:
        chip_model: Chip model, e.g. ``"MC2100"``.
        plant: Plant family name.
        plant_values: The hidden plant values (the rest nominal).
        params: The register set that runs (default: the chip's defaults).
        loop_latency: The chip's ``loop_latency`` choice (default: the family's).
        moves: ``MoveSpec``s; default the family's ``DEFAULT_MOVES``.
        command_noise_counts: Standard deviation of Gaussian noise added to the recorded
            motor command (counts), rounded to whole counts.
        seed: Seed of that noise (``np.random.default_rng``).
        substeps: RK4 substeps per tick of the simulation (default the reference, 32).

    Returns:
        A :class:`Trace` whose ``aux1``/``aux2`` are the chip profile's own inputs.
    """
    from servogym.sim import REFERENCE_SUBSTEPS, Evaluator, Scenario

    chip_asm = None
    from servogym.chips import get_chip

    family, model = get_chip(chip_model)
    if loop_latency is not None:
        chip_asm = dataclasses.replace(family.default_assumptions(), loop_latency=loop_latency)
    scenario = Scenario(
        model, plant, plant_values=dict(plant_values or {}), moves=tuple(moves),
        assumptions=chip_asm, substeps=substeps or REFERENCE_SUBSTEPS,
    )  # fmt: skip
    params = params if params is not None else scenario.default_params()
    ev = Evaluator(scenario)
    result = ev.evaluate(params, traces=True)
    profiles = ev.profiles(params)
    parts = [r.traces for r in result.results]
    n = sum(p.actual.size for p in parts)
    command = np.concatenate([p.command for p in parts])
    if command_noise_counts > 0:
        rng = np.random.default_rng(seed)
        noise = np.rint(rng.normal(0.0, command_noise_counts, command.shape)).astype(np.int64)
        command = np.clip(command + noise, -32768, 32767)
    aux1 = np.concatenate([p.velocity for p in profiles])[:n]
    aux2 = np.concatenate([p.acceleration for p in profiles])[:n]
    return Trace(
        time_s=np.arange(n) * family.sample_time_s(params),
        commanded=np.concatenate([p.commanded for p in parts]),
        actual=np.concatenate([p.actual for p in parts]),
        command=command,
        aux1=aux1,
        aux2=aux2,
        source=f"synthetic {model} on {plant}",
        fmt="csv",
    )
