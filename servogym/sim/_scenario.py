"""Scenarios and the cost: what envs, tuners and benchmarks all evaluate a parameter set on.

A :class:`Scenario` is a chip model, a plant family with its instance distribution, and a
sequence of evaluation moves in the plant's joint units. An :class:`Evaluator` compiles the
plant once and returns the documented cost of a parameter set on one plant instance
(docs/cost.md). The cost is always finite.
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Mapping, Sequence
from typing import Any

import numpy as np

from servogym.chips._family import Move, get_chip
from servogym.plants import check_motor, get_plant
from servogym.sim._margins import Margins
from servogym.sim._metrics import EpisodeMetrics
from servogym.sim._operating import operating_margins, severity
from servogym.sim._runner import EpisodeResult, ServoLoop

COST_CAP = 100.0
"""Largest cost of a move that did not diverge."""
DIVERGENCE_PENALTY = 1000.0
"""Cost of an episode that diverged at its very end; it rises to 2x for one that diverged at
once: ``DIVERGENCE_PENALTY * (2 - fraction of the episode's ticks that ran)``."""


@dataclasses.dataclass(frozen=True)
class MoveSpec:
    """A point-to-point move in the plant's joint units (rad for hinges, m for slides).

    Attributes:
        distance: Signed move length (rad or m).
        max_velocity: Velocity limit (rad/s or m/s).
        max_acceleration: Acceleration limit (rad/s^2 or m/s^2).
        settle_s: Time at rest on the target after the move (s).
        kind: ``"trapezoidal"`` or ``"s_curve"``.
        jerk: Jerk limit for ``"s_curve"`` (rad/s^3 or m/s^3).
    """

    distance: float
    max_velocity: float
    max_acceleration: float
    settle_s: float = 0.1
    kind: str = "trapezoidal"
    jerk: float | None = None

    def to_move(self, counts_per_unit: float, start_counts: int = 0) -> Move:
        """The same move in encoder counts."""
        return Move(
            distance_counts=round(self.distance * counts_per_unit),
            max_velocity_counts_per_s=self.max_velocity * counts_per_unit,
            max_acceleration_counts_per_s2=self.max_acceleration * counts_per_unit,
            settle_s=self.settle_s,
            kind=self.kind,
            jerk_counts_per_s3=None if self.jerk is None else self.jerk * counts_per_unit,
            start_counts=start_counts,
        )


# Out and back for every family, sized for the nominal motor (peak torque 2 N*m): about a
# third of the peak torque accelerates the nominal load, and the moves stay well inside travel.
DEFAULT_MOVES: dict[str, tuple[MoveSpec, ...]] = {
    "rotary": (MoveSpec(2 * math.pi, 60.0, 3000.0, 0.08),
               MoveSpec(-2 * math.pi, 60.0, 3000.0, 0.08)),
    "two-mass": (MoveSpec(math.pi, 30.0, 1500.0, 0.1), MoveSpec(-math.pi, 30.0, 1500.0, 0.1)),
    "vertical-axis": (MoveSpec(0.05, 0.2, 2.0, 0.1), MoveSpec(-0.05, 0.2, 2.0, 0.1)),
    "arm": (MoveSpec(0.6, 2.0, 20.0, 0.15), MoveSpec(-0.6, 2.0, 20.0, 0.15)),
}  # fmt: skip


@dataclasses.dataclass(frozen=True)
class CostWeights:
    """Weights of the terms of a move's cost (docs/cost.md).

    The error scale is ``e_ref = max(4, 0.001 * |distance|)`` counts; ``T`` is the move's
    duration including its settle time.

    Attributes:
        mean_error: on ``IAE / T / e_ref`` (the mean error in units of e_ref).
        peak_error: on ``max_following_error / e_ref``.
        overshoot: on ``overshoot / e_ref``.
        settling: on ``settling_time / settle_s`` (1 = never settled in the settle window).
        steady_state: on ``steady_state_error / e_ref``.
        effort: on ``rms_command`` (fraction of full scale).
        saturation: on ``saturation_fraction``.
        chatter: on ``100 * chatter`` (1 = a mean change of 1 % of full scale per tick).
    """

    mean_error: float = 1.0
    peak_error: float = 0.1
    overshoot: float = 0.5
    settling: float = 1.0
    steady_state: float = 1.0
    effort: float = 0.1
    saturation: float = 1.0
    chatter: float = 1.0


def move_cost(m: EpisodeMetrics, distance_counts: int, settle_s: float, w: CostWeights) -> float:
    """Cost of one move that did not diverge, capped at :data:`COST_CAP` (docs/cost.md)."""
    e_ref = max(4.0, 0.001 * abs(distance_counts))
    duration = m.n_ticks * m.dt
    raw = (
        w.mean_error * m.iae / duration / e_ref
        + w.peak_error * m.max_following_error / e_ref
        + w.overshoot * m.overshoot / e_ref
        + w.settling * m.settling_time / max(settle_s, m.dt)
        + w.steady_state * m.steady_state_error / e_ref
        + w.effort * m.rms_command
        + w.saturation * m.saturation_fraction
        + w.chatter * 100.0 * m.chatter
    )
    return min(raw, COST_CAP) if math.isfinite(raw) else COST_CAP


@dataclasses.dataclass(frozen=True)
class Scenario:
    """What a parameter set is evaluated on.

    Attributes:
        chip_model: Chip model name (any family, e.g. ``"MC2100"``).
        plant: Plant family name (``"rotary"``, ``"two-mass"``, ``"vertical-axis"``, ``"arm"``).
        plant_values: Fixed plant parameters; the rest are nominal or drawn.
        randomise: Whether each episode draws a plant instance from the family's
            distribution (the fixed ``plant_values`` excepted).
        sample_scale: Width of that distribution relative to the family's legal range
            (0 = nominal, 1 = the whole range).
        moves: Evaluation moves, run one after the other without reset; ``()`` uses the
            plant family's :data:`DEFAULT_MOVES`.
        weights: Cost weights.
        integrator: ``"rk4"`` (default) or ``"euler"`` (see :class:`ServoLoop`).
        substeps: Integration substeps per servo tick; ``None``: the integrator's default.
        assumptions: The chip's assumption switches (``None``: defaults), the loop
            latency among them.
        margins: Whether each evaluation also computes the loop's stability margins on its
            plant instance (``Evaluation.margins``; the tuners' margin constraints).
        margin_latencies: ``"own"``: the margins at the scenario's loop latency;
            ``"every"``: the worst over every choice of the chip's ``loop_latency``
            assumption, as the check computes them (``servogym tune``'s constraints).
        plant_ranges: ``name -> (low, high)``: the part of a parameter's legal range a
            randomised draw takes it from (``--plant-range NAME=LO:HI``), instead of the
            family's default sampling range; a parameter given a range is drawn even if the
            family does not randomise it by default. Validated on construction
            (``PlantFamily.validate_ranges``: known name, ``low <= high``, inside the legal
            range, not also in ``plant_values``).
        motor_check: Refuse, on construction, a plant the motor cannot move with the moves
            (``servogym.plants.check_motor``): the nominal instance with ``plant_values``,
            and every corner of the box of ranges it may draw from (``plant_ranges`` ends,
            and with ``randomise`` the family's default sampling ranges at
            ``sample_scale``). The check's stress cases turn it off (an overload on
            purpose).
    """

    chip_model: str
    plant: str
    plant_values: Mapping[str, float] = dataclasses.field(default_factory=dict)
    randomise: bool = False
    sample_scale: float = 1.0
    moves: tuple[MoveSpec, ...] = ()
    weights: CostWeights = CostWeights()
    integrator: str = "rk4"
    substeps: int | None = None
    assumptions: Any = None
    margins: bool = False
    margin_latencies: str = "own"
    plant_ranges: Mapping[str, tuple[float, float]] = dataclasses.field(default_factory=dict)
    motor_check: bool = True

    def __post_init__(self) -> None:
        _, model = get_chip(self.chip_model)
        object.__setattr__(self, "chip_model", model)
        if self.margin_latencies not in ("own", "every"):
            raise ValueError(
                "margin_latencies must be 'own' or 'every'; "
                f"got margin_latencies={self.margin_latencies!r}."
            )
        family = get_plant(self.plant)
        base = family.validate(dict(self.plant_values))
        ranges = family.validate_ranges(
            self.plant_ranges, option="plant_ranges (--plant-range)", fixed=self.plant_values
        )
        object.__setattr__(self, "plant_ranges", ranges)
        if not self.moves:
            object.__setattr__(self, "moves", DEFAULT_MOVES[self.plant])
        if self.motor_check:
            box = dict(ranges)
            if self.randomise:
                scale = self.sample_scale
                box = family.sample_bounds(scale, ranges=ranges)
                for name in self.plant_values:
                    box.pop(name, None)  # held fixed: the draw keeps the given value
            what = {n: "plant_values, --plant-param" for n in self.plant_values}
            what |= {n: "a plant_ranges end, --plant-range" for n in ranges}
            check_motor(family, base, box, self.moves, what=what)

    @property
    def chip(self):
        """The chip family."""
        return get_chip(self.chip_model)[0]

    def default_params(self) -> Any:
        """The chip model's default parameter set."""
        return self.chip.make_params(self.chip_model)

    def params(self, values: Mapping[str, Any] | None = None) -> Any:
        """A parameter set: the chip's defaults updated with ``values`` (validated)."""
        return self.chip.make_params(self.chip_model, values)

    def draw_plant(self, rng: np.random.Generator) -> dict[str, float]:
        """A plant instance: nominal (or drawn when ``randomise``), with the fixed values.

        A draw takes every randomised parameter, and every one in ``plant_ranges``, from its
        range (``PlantFamily.sample``); the fixed ``plant_values`` override it.
        """
        return plant_draw(get_plant(self.plant), rng, self.randomise, self.sample_scale,
                          self.plant_ranges, self.plant_values)  # fmt: skip


def plant_draw(
    family: Any,
    rng: np.random.Generator,
    randomise: bool,
    sample_scale: float,
    plant_ranges: Mapping[str, tuple[float, float]],
    plant_values: Mapping[str, float],
) -> dict[str, float]:
    """A plant instance of ``family``: drawn (``PlantFamily.sample`` at ``sample_scale``,
    ``plant_ranges`` overriding the family's ranges) when ``randomise``, else nominal; the
    fixed ``plant_values`` override it (every scenario's ``draw_plant``)."""
    if randomise:
        values = family.sample(rng, sample_scale, ranges=plant_ranges)
    else:
        values = family.nominal()
    values.update(plant_values)
    return values


@dataclasses.dataclass(frozen=True)
class Evaluation:
    """The outcome of one parameter set on one plant instance.

    Attributes:
        cost: Mean move cost, or the divergence penalty (finite, always).
        move_costs: Cost of each move that ran to its end.
        metrics: Metrics of each move run (the last one may have diverged).
        diverged: Whether the episode ended early.
        max_following_error: Largest following error over the moves (counts).
        saturation_fraction: Fraction of all ticks run whose command hit the motor limit.
        results: Each move's :class:`EpisodeResult` (traces when asked for).
        margins: The loop's stability margins on this plant instance (``Scenario.margins``).
    """

    cost: float
    move_costs: tuple[float, ...]
    metrics: tuple[EpisodeMetrics, ...]
    diverged: bool
    max_following_error: float
    saturation_fraction: float
    results: tuple[EpisodeResult, ...] = ()
    margins: Margins | None = None

    def summary(self) -> dict[str, Any]:
        """JSON-ready: cost, safety figures and each move's metrics."""
        extra = {} if self.margins is None else {"margins": self.margins.to_dict()}
        return extra | {
            "cost": self.cost,
            "diverged": self.diverged,
            "max_following_error": self.max_following_error,
            "saturation_fraction": self.saturation_fraction,
            "move_costs": list(self.move_costs),
            "moves": [m.to_dict() for m in self.metrics],
        }


class Evaluator:
    """Runs a scenario's moves for any parameter set on any plant instance of it.

    The plant is compiled once, here; each evaluation edits it in place.

    Args:
        scenario: The scenario.
    """

    def __init__(self, scenario: Scenario) -> None:
        self.scenario = scenario
        family = get_plant(scenario.plant)
        self.plant = family.build(scenario.draw_plant(np.random.default_rng(0)))
        self.loop = ServoLoop(
            self.plant,
            scenario.default_params(),
            scenario.assumptions,
            integrator=scenario.integrator,
            substeps=scenario.substeps,
        )
        self._profiles: dict[tuple, list] = {}
        self._linear: dict[tuple, Any] = {}  # linearisations, see margins()

    def margins(self, params: Any) -> Margins:
        """Stability and margins of ``params`` on the current plant instance, at its worst
        holding point (``_operating``: the start and the end of every move) and, with
        ``Scenario.margin_latencies="every"``, its worst loop-latency choice.

        The plant's linearisation at each point is computed once per plant instance, its
        discretisation once per plant instance, servo period and latency, then reused.
        """
        asm = self.scenario.assumptions or self.scenario.chip.default_assumptions()
        choices = [asm.loop_latency]
        if self.scenario.margin_latencies == "every":
            choices += [c for c in type(asm).CHOICES["loop_latency"] if c != asm.loop_latency]
        found = [
            operating_margins(
                self.scenario.chip, params, dataclasses.replace(asm, loop_latency=c),
                self.plant, self.scenario.moves, cache=self._linear,
            ).margins
            for c in choices
        ]  # fmt: skip
        return min(found, key=severity)

    def profiles(self, params: Any) -> list:
        """The chip profiles of the scenario's moves at this plant's encoder resolution."""
        io = self.plant.io
        dt = self.scenario.chip.sample_time_s(params)
        key = (io.counts_per_unit, dt)
        if key not in self._profiles:
            out, start = [], 0
            for spec in self.scenario.moves:
                move = spec.to_move(io.counts_per_unit, start)
                out.append(self.scenario.chip.profile(move, dt))
                start = int(out[-1].position[-1])
            self._profiles[key] = out
        return self._profiles[key]

    def evaluate(
        self,
        params: Any,
        plant_values: Mapping[str, float] | None = None,
        *,
        traces: bool = False,
    ) -> Evaluation:
        """Cost of ``params`` on one plant instance (the current one when ``None``)."""
        if plant_values is not None:
            self.plant.set_params(dict(plant_values))
        profiles = self.profiles(params)
        self.loop.set_params(params)
        results, costs = [], []
        total = sum(p.n_ticks for p in profiles)
        ran = 0
        diverged = False
        for i, (spec, profile) in enumerate(zip(self.scenario.moves, profiles, strict=True)):
            r = self.loop.run(profile, traces=traces, reset=i == 0)
            results.append(r)
            ran += r.metrics.n_ticks
            if r.metrics.diverged:
                diverged = True
                break
            distance = int(profile.position[-1]) - int(profile.start)
            costs.append(move_cost(r.metrics, distance, spec.settle_s, self.scenario.weights))
        metrics = tuple(r.metrics for r in results)
        if diverged:
            cost = DIVERGENCE_PENALTY * (2.0 - ran / total)
        else:
            cost = float(np.mean(costs))
        return Evaluation(
            margins=self.margins(params) if self.scenario.margins else None,
            cost=cost,
            move_costs=tuple(costs),
            metrics=metrics,
            diverged=diverged,
            max_following_error=max(m.max_following_error for m in metrics),
            saturation_fraction=sum(m.saturation_fraction * m.n_ticks for m in metrics) / ran,
            results=tuple(results),
        )


def robust_cost(evaluations: Sequence[Evaluation], mode: str = "mean") -> float:
    """Aggregate costs over plant draws: ``"mean"`` or ``"worst"``."""
    costs = [e.cost for e in evaluations]
    if mode == "mean":
        return float(np.mean(costs))
    if mode == "worst":
        return float(np.max(costs))
    raise ValueError(f"mode must be 'mean' or 'worst'; got mode={mode!r}")
