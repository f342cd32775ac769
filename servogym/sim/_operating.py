"""Where a set operates: the loop linearised at each point where the axis holds still.

A plant under gravity (the arm) has a linearisation that depends on where it stands: the
gravity torque's slope changes with the angle. The loop's margins are computed at every
holding point of the scenario's moves (the start and the end of each move, where the
controller holds the load against gravity) and the worst is the set's margin on that plant
instance. A plant without position-dependent forces has the same linear model at every point (one
``mjd_transitionFD`` per point tells); its loop is then analysed once.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Sequence
from typing import Any

import numpy as np

from servogym.sim._margins import LoopAnalysis, Margins, analyse_loop, continuous_model, linearize

POSITION_DECIMALS = 9
"""Holding points closer than this (joint units, as decimals) are one point."""


def holding_positions(moves: Sequence[Any]) -> tuple[float, ...]:
    """Offsets from the start position (joint units) where the moves hold still: the start
    and each move's end, distinct, in the order visited."""
    out: list[float] = [0.0]
    at = 0.0
    for spec in moves:
        at += float(spec.distance)
        p = round(at, POSITION_DECIMALS)
        if p not in out:
            out.append(p)
    return tuple(out)


def qpos_at(plant: Any, offset: float) -> np.ndarray:
    """The model's reset position with the measured joint moved by ``offset`` (joint units)."""
    qpos = np.array(plant.model.qpos0, dtype=float)
    qpos[plant.io.qpos_adr] += offset
    return qpos


def _same_loop(a: Any, b: Any) -> bool:
    """Whether two continuous models ``(A, B, C, d)`` have the same transfer function
    (``d``, the gravity at the point, does not enter it)."""
    return all(np.array_equal(x, y) for x, y in zip(a[:3], b[:3], strict=True))


@dataclasses.dataclass(frozen=True)
class OperatingMargins:
    """The loop of one set on one plant instance, at every holding point.

    Attributes:
        points: The holding points (offsets from the start, joint units).
        analyses: The loop analysis at each point, in the same order.
        worst: Index of the worst point (unstable first, then the smallest margin relative
            to its minimum).
    """

    points: tuple[float, ...]
    analyses: tuple[LoopAnalysis, ...]
    worst: int

    @property
    def margins(self) -> Margins:
        """The margins at the worst holding point."""
        return self.analyses[self.worst].margins

    @property
    def position_dependent(self) -> bool:
        """Whether the loop differs between the holding points (gravity's slope changes)."""
        return len({id(a) for a in self.analyses}) > 1

    @property
    def analysis(self) -> LoopAnalysis:
        """The loop at the worst holding point (for the Bode plot)."""
        return self.analyses[self.worst]


def severity(m: Margins, min_gain_margin_db: float = 6.0, min_phase_margin_deg: float = 30.0):
    """Sort key: smaller is worse (an unstable loop first, then the margin furthest below,
    or least above, its minimum, each relative to its minimum)."""
    gm = m.gain_margin_db / max(min_gain_margin_db, 1.0)
    pm = m.phase_margin_deg / max(min_phase_margin_deg, 1.0)
    return (bool(m.stable), min(gm, pm))


def operating_margins(
    chip: Any,
    params: Any,
    assumptions: Any,
    plant: Any,
    moves: Sequence[Any],
    *,
    latency_s: float | None = None,
    cache: dict | None = None,
    limits: tuple[float, float] = (6.0, 30.0),
) -> OperatingMargins:
    """The loop of ``params`` on ``plant`` (its current values) at every holding point.

    Args:
        chip: The chip family.
        params: The parameter set.
        assumptions: The chip's assumption switches (``None``: defaults).
        plant: A built plant (its values as set).
        moves: The scenario's moves (:class:`~servogym.sim.MoveSpec`).
        latency_s: Loop latency (s); default the chip's for ``assumptions``.
        cache: A dict reused across calls: the continuous model per (plant values, point)
            and its discretisation per (plant values, point, period, latency).
        limits: The minima (dB, degrees) that rank the points.
    """
    asm = assumptions if assumptions is not None else chip.default_assumptions()
    dt = chip.sample_time_s(params)
    latency = chip.loop_latency_s(params, asm) if latency_s is None else latency_s
    instance = tuple(sorted(plant.values.items()))
    points = holding_positions(moves)
    analyses = []
    cache = {} if cache is None else cache
    models: list[Any] = []
    for p in points:
        key = (instance, p)
        if key not in cache:
            cache[key] = continuous_model(plant, qpos=qpos_at(plant, p))
        same = next((i for i, m in enumerate(models) if _same_loop(m, cache[key])), None)
        models.append(cache[key])
        if same is not None:  # no position-dependent force: the same loop as there
            analyses.append(analyses[same])
            continue
        lin_key = (instance, p, dt, latency)
        if lin_key not in cache:
            cache[lin_key] = linearize(plant, dt, latency, cache[key])
        analyses.append(analyse_loop(chip, params, asm, cache[lin_key]))
    keys = [severity(a.margins, *limits) for a in analyses]
    worst = min(range(len(points)), key=keys.__getitem__)
    return OperatingMargins(points=points, analyses=tuple(analyses), worst=worst)
