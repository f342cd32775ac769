"""The cost of one controller's parameter sets on a multi-axis machine (docs/cost.md).

A :class:`MultiEvaluator` runs a machine (a :class:`~servogym.sim.MultiServoLoop` around a
``two-link-arm`` or ``xy-stage``) through tasks, each its own episode from rest: coordinated
point-to-point moves (:class:`CoordinatedSpec`) and contours of the tool point
(:class:`ContourSpec`). Each task gives every axis's :class:`~servogym.sim.EpisodeMetrics`
and the contouring error (:class:`~servogym.sim._contour.ContourError`); its cost is the mean
of the axes' move costs (:func:`~servogym.sim.move_cost`) plus the contouring terms of
:class:`MultiCostWeights`.
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Mapping, Sequence
from typing import Any

import numpy as np

from servogym.chips._family import get_chip
from servogym.chips._space import ParameterError
from servogym.sim._contour import (
    SEGMENTATION_S,
    CirclePath,
    Commands,
    ContourError,
    LinePath,
    contour,
    contour_error,
    coordinated_move,
)
from servogym.sim._machine import MultiServoLoop, machine_params
from servogym.sim._metrics import EpisodeMetrics
from servogym.sim._scenario import COST_CAP, DIVERGENCE_PENALTY, CostWeights, move_cost


@dataclasses.dataclass(frozen=True)
class CoordinatedSpec:
    """A coordinated point-to-point move (:func:`~servogym.sim._contour.coordinated_move`).

    Attributes:
        max_velocity, max_acceleration: Per axis, its limits (joint units per s, s^2).
        targets: Per axis, the target joint position (rad or m); or ``tool_target``.
        tool_target: The tool point's target (m), through the inverse kinematics.
        elbow: ``"up"`` or ``"down"`` (two-link arm, ``tool_target``).
        kind: ``"trapezoidal"`` or ``"s_curve"`` (``jerk`` per axis).
        jerk: Per axis, the jerk limit (joint units per s^3) of an S-curve.
        start_qpos: Per axis, the joint position at rest at the start; ``None``: the
            plant's zero position.
        settle_s: Rest on the targets after the move (s).
    """

    max_velocity: tuple[float, ...]
    max_acceleration: tuple[float, ...]
    targets: tuple[float, ...] | None = None
    tool_target: tuple[float, float] | None = None
    elbow: str = "up"
    kind: str = "trapezoidal"
    jerk: tuple[float, ...] | None = None
    start_qpos: tuple[float, ...] | None = None
    settle_s: float = 0.1

    def commands(self, loop: MultiServoLoop, **_: Any) -> Commands:
        """Every axis's profile on ``loop``'s machine."""
        return coordinated_move(
            loop, self.targets, max_velocity=self.max_velocity,
            max_acceleration=self.max_acceleration, tool_target=self.tool_target,
            elbow=self.elbow, kind=self.kind, jerk=self.jerk, start_qpos=self.start_qpos,
            settle_s=self.settle_s,
        )  # fmt: skip


@dataclasses.dataclass(frozen=True)
class ContourSpec:
    """A contour of the tool point (:func:`~servogym.sim._contour.contour`).

    Attributes:
        path: A :class:`~servogym.sim._contour.LinePath` or
            :class:`~servogym.sim._contour.CirclePath` (m).
        speed: Feed rate along the path (m/s).
        acceleration: Path acceleration (m/s^2).
        kind: ``"trapezoidal"`` or ``"s_curve"`` (``jerk``, m/s^3).
        jerk: Path jerk for an S-curve feed.
        elbow: ``"up"`` or ``"down"`` (two-link arm).
        dwell_s: Rest on the path's start before the motion (s).
        settle_s: Rest on its end after the motion (s).
    """

    path: LinePath | CirclePath
    speed: float
    acceleration: float
    kind: str = "trapezoidal"
    jerk: float | None = None
    elbow: str = "up"
    dwell_s: float = 0.02
    settle_s: float = 0.1

    def commands(self, loop: MultiServoLoop, *, mode: str | None = None,
                 segmentation_s: float = SEGMENTATION_S) -> Commands:  # fmt: skip
        """Every axis's profile on ``loop``'s machine (the family's contour ``mode``)."""
        return contour(
            loop, self.path, self.speed, self.acceleration, kind=self.kind, jerk=self.jerk,
            elbow=self.elbow, dwell_s=self.dwell_s, settle_s=self.settle_s, mode=mode,
            segmentation_s=segmentation_s,
        )  # fmt: skip


DEFAULT_TASKS: dict[str, tuple[CoordinatedSpec | ContourSpec, ...]] = {
    "xy-stage": (
        CoordinatedSpec((0.5, 0.4), (5.0, 5.0), targets=(0.06, 0.03)),
        ContourSpec(LinePath((-0.04, -0.02), (0.04, 0.02)), 0.2, 2.0),
        ContourSpec(CirclePath((0.0, 0.0), 0.02), 0.1, 2.0),
    ),
    "two-link-arm": (
        CoordinatedSpec((2.0, 3.0), (20.0, 30.0), tool_target=(0.4, 0.15)),
        ContourSpec(LinePath((0.4, -0.06), (0.4, 0.06)), 0.15, 2.0),
        ContourSpec(CirclePath((0.4, 0.0), 0.04), 0.1, 2.0),
    ),
}
"""Per multi-axis plant: a coordinated move from the zero position, a line and a full circle
of the tool point, sized well inside the nominal motors' peak torques and the travel."""


@dataclasses.dataclass(frozen=True)
class MultiCostWeights:
    """Weights of a multi-axis task's cost (docs/cost.md, "Multi-axis machines").

    Attributes:
        axis: The per-axis move cost's weights (:class:`~servogym.sim.CostWeights`).
        contour_rms: On ``rms_um / contour_ref_um``.
        contour_peak: On ``max_um / contour_ref_um``.
        contour_ref_um: The contouring error's scale (um), > 0.
    """

    axis: CostWeights = dataclasses.field(default_factory=CostWeights)
    contour_rms: float = 1.0
    contour_peak: float = 0.1
    contour_ref_um: float = 10.0

    def __post_init__(self) -> None:
        for name in ("contour_rms", "contour_peak"):
            x = getattr(self, name)
            if isinstance(x, bool) or not (math.isfinite(x) and x >= 0):
                raise ParameterError(f"{name} must be a finite number >= 0; got {name}={x!r}")
        ref = self.contour_ref_um
        if isinstance(ref, bool) or not (math.isfinite(ref) and ref > 0):
            raise ParameterError(f"contour_ref_um must be a finite number > 0; got {ref!r}")


def task_cost(
    metrics: Sequence[EpisodeMetrics],
    commands: Commands,
    error: ContourError,
    weights: MultiCostWeights = MultiCostWeights(),
) -> float:
    """Cost of one task that did not diverge, capped at :data:`~servogym.sim.COST_CAP`:
    the mean of the axes' move costs (each axis's span of commanded positions as its move
    length) plus ``contour_rms * rms_um / ref + contour_peak * max_um / ref``."""
    axes = [move_cost(m, d, commands.settle_s, weights.axis)
            for m, d in zip(metrics, commands.distances_counts, strict=True)]  # fmt: skip
    ref = weights.contour_ref_um
    raw = (float(np.mean(axes)) + weights.contour_rms * error.rms_um / ref
           + weights.contour_peak * error.max_um / ref)  # fmt: skip
    return min(raw, COST_CAP) if math.isfinite(raw) else COST_CAP


@dataclasses.dataclass(frozen=True)
class TaskResult:
    """One task's episode.

    Attributes:
        metrics: Per axis, its :class:`~servogym.sim.EpisodeMetrics`.
        contour: The contouring error over the ticks run.
        cost: The task's cost (:func:`task_cost`), or ``None`` when it diverged.
        diverged: Whether the episode ended early.
        axis: The axis whose divergence ended it, -1 if none.
        commands: The profiles run.
        traces: Per axis, its traces when asked for.
    """

    metrics: tuple[EpisodeMetrics, ...]
    contour: ContourError
    cost: float | None
    diverged: bool
    axis: int
    commands: Commands
    traces: tuple[Any, ...] | None = None

    def to_dict(self) -> dict[str, Any]:
        """JSON-ready: cost, contouring error and each axis's metrics."""
        return {"cost": self.cost, "diverged": self.diverged, "axis": self.axis,
                "contour": self.contour.to_dict(),
                "axes": [m.to_dict() for m in self.metrics]}  # fmt: skip


@dataclasses.dataclass(frozen=True)
class MultiEvaluation:
    """The outcome of one controller's parameter sets on one machine.

    Attributes:
        cost: Mean task cost, or the divergence penalty (finite, always).
        tasks: Each task run (the last one may have diverged).
        diverged: Whether a task's episode ended early.
    """

    cost: float
    tasks: tuple[TaskResult, ...]
    diverged: bool

    @property
    def max_contour_error_um(self) -> float:
        """Largest contouring error over the tasks (um)."""
        return max(t.contour.max_um for t in self.tasks)

    def summary(self) -> dict[str, Any]:
        """JSON-ready: cost and every task's results."""
        return {"cost": self.cost, "diverged": self.diverged,
                "max_contour_error_um": self.max_contour_error_um,
                "tasks": [t.to_dict() for t in self.tasks]}  # fmt: skip


class MultiEvaluator:
    """Runs a multi-axis machine's tasks for any parameter sets of one controller.

    The plant is compiled once, here; the profiles of each task are computed once per chip
    family, servo period and plant instance.

    Args:
        plant: A multi-axis plant name (``"xy-stage"``, ``"two-link-arm"``) or a built one.
        chip_model: The controller's chip model (any family).
        tasks: The tasks; ``None``: the plant's :data:`DEFAULT_TASKS`.
        plant_values: Plant parameters (a name only), the rest nominal.
        weights: The cost's weights.
        assumptions: The chip's assumption switches (every axis).
        sequencing: The family's axis-sequencing choice (``servogym.sim.SEQUENCING``).
        contour_mode: The family's contour mode (``servogym.sim._contour.CONTOUR_MODES``).
        segmentation_s: PMAC's segmentation time (s).
        integrator, substeps: As for :class:`~servogym.sim.MultiServoLoop`.
    """

    def __init__(
        self,
        plant: Any,
        chip_model: str,
        tasks: Sequence[CoordinatedSpec | ContourSpec] | None = None,
        *,
        plant_values: Mapping[str, Any] | None = None,
        weights: MultiCostWeights = MultiCostWeights(),
        assumptions: Any = None,
        sequencing: str | None = None,
        contour_mode: str | None = None,
        segmentation_s: float = SEGMENTATION_S,
        integrator: str = "rk4",
        substeps: int | None = None,
    ) -> None:
        from servogym.plants import MULTI_PLANTS

        if isinstance(plant, str):
            if plant not in MULTI_PLANTS:
                names = ", ".join(map(repr, MULTI_PLANTS))
                raise ParameterError(
                    f"plant must be a multi-axis plant, one of {names}; got plant={plant!r}"
                )
            plant = MULTI_PLANTS[plant].build(plant_values)
        elif plant_values is not None:
            plant.set_params(dict(plant_values))
        self.chip, self.chip_model = get_chip(chip_model)
        self.tasks = tuple(DEFAULT_TASKS[plant.family.name] if tasks is None else tasks)
        if not self.tasks:
            raise ParameterError("tasks must hold at least one CoordinatedSpec or ContourSpec")
        self.weights = weights
        self.contour_mode = contour_mode
        self.segmentation_s = segmentation_s
        self.loop = MultiServoLoop(
            plant, machine_params(self.chip_model, len(plant.ios)), assumptions,
            sequencing=sequencing, integrator=integrator, substeps=substeps,
        )  # fmt: skip
        self._commands: dict[tuple, tuple[Commands, ...]] = {}

    @property
    def plant(self) -> Any:
        """The compiled plant."""
        return self.loop.plant

    def commands(self) -> tuple[Commands, ...]:
        """Every task's profiles for the loop's current parameter sets and plant."""
        key = (self.chip.name, self.loop.dt, tuple(sorted(self.plant.values.items())))
        if key not in self._commands:
            self._commands[key] = tuple(
                t.commands(self.loop, mode=self.contour_mode, segmentation_s=self.segmentation_s)
                for t in self.tasks
            )
        return self._commands[key]

    def evaluate(
        self,
        params: Any,
        plant_values: Mapping[str, Any] | None = None,
        *,
        traces: bool = False,
    ) -> MultiEvaluation:
        """Cost of ``params`` (one set per axis: a sequence, a mapping of axis numbers or a
        :class:`~servogym.chips.MultiAxisParams`) on the plant (changed by ``plant_values``)."""
        if plant_values is not None:
            self.plant.set_params(dict(plant_values))
        self.loop.set_params(params)
        every = self.commands()
        total = sum(c.n_ticks for c in every)
        ran, results = 0, []
        for cmd in every:
            r = self.loop.run(list(cmd.profiles), start_counts=cmd.start_counts,
                              start_qpos=cmd.start_qpos, traces=True)  # fmt: skip
            n_run = r.metrics[0].n_ticks
            ran += n_run
            actual = np.stack([tr.actual for tr in r.traces])
            err = contour_error(cmd, actual, n_run)
            diverged = any(m.diverged for m in r.metrics)
            cost = None if diverged else task_cost(r.metrics, cmd, err, self.weights)
            results.append(TaskResult(r.metrics, err, cost, diverged, r.axis, cmd,
                                      r.traces if traces else None))  # fmt: skip
            if diverged:
                return MultiEvaluation(DIVERGENCE_PENALTY * (2.0 - ran / total), tuple(results),
                                       True)  # fmt: skip
        return MultiEvaluation(float(np.mean([t.cost for t in results])), tuple(results), False)


__all__ = [
    "DEFAULT_TASKS",
    "ContourSpec",
    "CoordinatedSpec",
    "MultiCostWeights",
    "MultiEvaluation",
    "MultiEvaluator",
    "TaskResult",
    "task_cost",
]
