"""What a tuner optimizes: a scenario, the plant instances, the objective and the constraints.

One *evaluation* (one trial, one unit of the budget) runs one parameter set through the
scenario's moves on each of the problem's K plant instances (K = 1 unless robust) and
aggregates: the cost is the mean or worst case of the K episode costs (``robust_cost``), the
safety figures are the worst over the K instances.
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Mapping, Sequence
from typing import Any

import numpy as np

from servogym.autotune._space import SearchSpace
from servogym.chips._space import ParameterError
from servogym.sim._scenario import Evaluation, Evaluator, Scenario, robust_cost

OBJECTIVES: dict[str, str] = {
    "cost": "the scenario cost of docs/cost.md (mean or worst over the plant instances)",
    "max_following_error": "largest following error over moves and instances (counts)",
    "saturation_fraction": "largest fraction of ticks at the motor limit over instances",
    "rms_command": "largest RMS motor command over moves and instances (fraction of full scale)",
    "chatter": "largest mean command change per tick over moves and instances",
    "settling_time": "longest settling time over moves and instances (s)",
}
"""What a (multi-)objective study can minimize."""

DEFAULT_MULTI_OBJECTIVES = ("cost", "max_following_error")
"""The two objectives of ``--multi-objective``: the overall cost against the peak error."""


@dataclasses.dataclass(frozen=True)
class Constraints:
    """Limits a tuned set must meet; Optuna treats a trial as feasible when all hold.

    Attributes:
        enabled: Whether constraints are reported to Optuna at all.
        max_following_error: Largest allowed following error (counts); ``None``: 1 % of
            the longest move of the scenario.
        max_saturation: Largest allowed fraction of ticks at the motor limit.
        no_divergence: Whether a diverged episode makes a trial infeasible.
        min_gain_margin_db: Smallest gain margin of the loop (dB) on every plant instance;
            ``None``: no margin constraint (docs/simulation.md, "The check").
        min_phase_margin_deg: Smallest phase margin (degrees); ``None``: none.
    """

    enabled: bool = True
    max_following_error: float | None = None
    max_saturation: float = 0.05
    no_divergence: bool = True
    min_gain_margin_db: float | None = 6.0
    min_phase_margin_deg: float | None = 30.0

    @property
    def margins(self) -> bool:
        """Whether the constraints need the loop's margins."""
        return self.enabled and (
            self.min_gain_margin_db is not None or self.min_phase_margin_deg is not None
        )

    def __post_init__(self) -> None:
        if self.max_following_error is not None and not self.max_following_error > 0:
            raise ParameterError(
                "max_following_error must be > 0 counts (or None for 1 % of the longest move); "
                f"got max_following_error={self.max_following_error!r}."
            )
        if not 0.0 <= self.max_saturation <= 1.0:
            raise ParameterError(
                "max_saturation must satisfy 0 <= max_saturation <= 1; "
                f"got max_saturation={self.max_saturation!r}."
            )
        for name, high in (("min_gain_margin_db", 60.0), ("min_phase_margin_deg", 90.0)):
            value = getattr(self, name)
            if value is not None and not (isinstance(value, int | float) and 0.0 <= value <= high):
                raise ParameterError(
                    f"{name} must satisfy 0 <= {name} <= {high:g} (or None for no margin "
                    f"constraint); got {name}={value!r}."
                )


@dataclasses.dataclass(frozen=True)
class Outcome:
    """One parameter set evaluated on every plant instance of a problem.

    Attributes:
        values: The chip values of the set (every register).
        cost: Aggregated cost (mean or worst over instances).
        costs: Cost on each instance.
        n_diverged: Number of instances on which the episode diverged.
        max_following_error: Largest following error over moves and instances (counts).
        saturation_fraction: Largest saturation fraction over instances.
        rms_command, chatter, settling_time: Largest over moves and instances.
        gain_margin_db, phase_margin_deg: Smallest loop margins over instances (``inf``:
            unbounded, or not computed; <= 0 for a loop that is unstable).
        delay_margin_s: Smallest delay margin over instances (s; ``inf`` as above).
        bandwidth_hz: Lowest closed-loop bandwidth over instances (Hz; ``nan``: not
            computed).
        n_unstable: Instances on which the loop's closed-loop poles are not all inside the
            unit circle (``servogym.sim._margins``).
    """

    values: dict[str, int]
    cost: float
    costs: tuple[float, ...]
    n_diverged: int
    max_following_error: float
    saturation_fraction: float
    rms_command: float
    chatter: float
    settling_time: float
    gain_margin_db: float = math.inf
    phase_margin_deg: float = math.inf
    delay_margin_s: float = math.inf
    bandwidth_hz: float = math.nan
    n_unstable: int = 0

    def objective(self, name: str) -> float:
        """The value of one of :data:`OBJECTIVES`."""
        return float(getattr(self, name))

    def to_attrs(self) -> dict[str, Any]:
        """JSON-ready, for a trial's user attributes."""
        out = dataclasses.asdict(self) | {"costs": list(self.costs)}
        for name in _MARGIN_FIELDS:  # JSON has no infinity
            if not math.isfinite(out[name]):
                out[name] = None
        return out

    @classmethod
    def from_attrs(cls, attrs: Mapping[str, Any]) -> Outcome:
        """Inverse of :meth:`to_attrs`."""
        names = [f.name for f in dataclasses.fields(cls) if f.name not in _MARGIN_FIELDS]
        kw = {n: attrs[n] for n in names if n != "n_unstable"}
        kw["n_unstable"] = int(attrs.get("n_unstable", 0))  # absent in older studies
        for name, missing in _MARGIN_FIELDS.items():  # absent in studies from before them
            value = attrs.get(name)
            kw[name] = missing if value is None else float(value)
        kw["costs"] = tuple(kw["costs"])
        kw["values"] = {k: int(v) for k, v in kw["values"].items()}
        return cls(**kw)


_MARGIN_FIELDS = {
    "gain_margin_db": math.inf,
    "phase_margin_deg": math.inf,
    "delay_margin_s": math.inf,
    "bandwidth_hz": math.nan,
}
"""The margin fields of :class:`Outcome` and their value when not computed (JSON: null)."""

MARGIN_CONSTRAINT_BOUND = 1000.0
"""Margin constraint values are clipped to +-this (Optuna's samplers need finite values)."""


def aggregate(values: Mapping[str, int], evaluations: Sequence[Evaluation], mode: str) -> Outcome:
    """Combine the evaluations of one set on each plant instance into an :class:`Outcome`."""
    metrics = [m for e in evaluations for m in e.metrics]
    computed = [e.margins for e in evaluations if e.margins is not None]
    return Outcome(
        gain_margin_db=min((m.gain_margin_db for m in computed), default=math.inf),
        phase_margin_deg=min((m.phase_margin_deg for m in computed), default=math.inf),
        delay_margin_s=min((m.delay_margin_s for m in computed), default=math.inf),
        bandwidth_hz=min(
            (m.bandwidth_hz for m in computed if not math.isnan(m.bandwidth_hz)),
            default=math.nan,
        ),
        n_unstable=sum(not m.stable for m in computed),
        values=dict(values),
        cost=robust_cost(evaluations, mode),
        costs=tuple(float(e.cost) for e in evaluations),
        n_diverged=sum(bool(e.diverged) for e in evaluations),
        max_following_error=float(max(e.max_following_error for e in evaluations)),
        saturation_fraction=float(max(e.saturation_fraction for e in evaluations)),
        rms_command=float(max(m.rms_command for m in metrics)),
        chatter=float(max(m.chatter for m in metrics)),
        settling_time=float(max(m.settling_time for m in metrics)),
    )


@dataclasses.dataclass(frozen=True)
class TuneProblem:
    """A tuning problem: what every tuner of this package is given.

    Attributes:
        scenario: Chip model, plant family, fixed plant values and moves. Its ``randomise``
            flag is ignored: ``n_plants`` decides.
        space: The searched registers (:class:`SearchSpace`).
        n_plants: K, the plant instances each evaluation runs on. 1: the nominal plant
            (with the scenario's fixed plant values). K > 1: K instances drawn once, with
            ``seed``, from the plant family's distribution at ``sample_scale``, the same K
            for every trial (common random numbers: trials compare on equal terms).
        robust_mode: ``"mean"`` or ``"worst"``: how the K costs aggregate.
        sample_scale: Width of the plant distribution (0 .. 1) for K > 1.
        constraints: Limits reported to Optuna (:class:`Constraints`).
        objectives: What the study minimizes: ``("cost",)``, or several of
            :data:`OBJECTIVES` for a multi-objective study with a Pareto front.
        seed: Seeds the plant draws (and, in the tuners, the samplers).
    """

    scenario: Scenario
    space: SearchSpace
    n_plants: int = 1
    robust_mode: str = "mean"
    sample_scale: float = 1.0
    constraints: Constraints = Constraints()
    objectives: tuple[str, ...] = ("cost",)
    seed: int = 0

    def __post_init__(self) -> None:
        if isinstance(self.n_plants, bool) or not isinstance(self.n_plants, int):
            raise ParameterError(
                f"n_plants must be an integer >= 1; got n_plants={self.n_plants!r}."
            )
        if self.n_plants < 1:
            raise ParameterError(f"n_plants must be >= 1; got n_plants={self.n_plants}.")
        if self.robust_mode not in ("mean", "worst"):
            raise ParameterError(
                f"robust_mode must be 'mean' or 'worst'; got robust_mode={self.robust_mode!r}."
            )
        if not 0.0 <= self.sample_scale <= 1.0:
            raise ParameterError(
                f"sample_scale must satisfy 0 <= sample_scale <= 1; got {self.sample_scale!r}."
            )
        if not self.objectives or len(set(self.objectives)) != len(self.objectives):
            raise ParameterError(
                f"objectives must be distinct names from {', '.join(OBJECTIVES)}; "
                f"got objectives={self.objectives!r}."
            )
        for name in self.objectives:
            if name not in OBJECTIVES:
                raise ParameterError(
                    f"objectives must be names from {', '.join(OBJECTIVES)}; got {name!r}."
                )
        if self.space.chip_model != self.scenario.chip_model:
            raise ParameterError(
                f"the search space is for {self.space.chip_model} but the scenario's chip is "
                f"{self.scenario.chip_model}; build both for the same chip model."
            )
        if isinstance(self.seed, bool) or not isinstance(self.seed, int) or self.seed < 0:
            raise ParameterError(f"seed must be an integer >= 0; got seed={self.seed!r}.")
        if self.constraints.margins:
            object.__setattr__(self, "scenario", self.margin_scenario())

    def margin_scenario(self) -> Any:
        """The scenario with the margins every evaluation needs for margin constraints."""
        sc = self.scenario
        if sc.margins and sc.margin_latencies == "every":
            return sc
        # at every loop-latency choice (the check's latency cases)
        return dataclasses.replace(sc, margins=True, margin_latencies="every")

    @property
    def multi_objective(self) -> bool:
        """Whether the study has more than one objective."""
        return len(self.objectives) > 1

    @property
    def n_axes(self) -> int:
        """Axes tuned together (1; a machine's problem, ``_machine.MachineProblem``, more)."""
        return 1

    def make_evaluator(self) -> Evaluator:
        """A new evaluator of the scenario (each thread of a session builds its own)."""
        return Evaluator(self.scenario)

    def aggregate(self, values: Mapping[str, int], evaluations: Sequence[Evaluation]) -> Outcome:
        """One set's evaluations on the plant instances as one :class:`Outcome`."""
        return aggregate(values, evaluations, self.robust_mode)

    def check(self, params: Any, limits: Any, **kw: Any) -> Any:
        """The check of a result (``servogym.sim.check_params`` on the scenario) before it
        is written; ``kw``: ``extra_plants``, ``workers``."""
        from servogym.sim._check import check_params

        return check_params(params, self.scenario, limits, **kw)

    def nominal_plant(self) -> dict[str, float]:
        """The nominal plant instance with the scenario's fixed values."""
        return dataclasses.replace(self.scenario, randomise=False).draw_plant(
            np.random.default_rng(0)
        )

    def plant_instances(self) -> list[dict[str, float]]:
        """The K plant instances every evaluation runs on (deterministic in ``seed``)."""
        if self.n_plants == 1:
            return [self.nominal_plant()]
        rng = np.random.default_rng(np.random.SeedSequence([self.seed, 0x504C414E]))
        sc = dataclasses.replace(self.scenario, randomise=True, sample_scale=self.sample_scale)
        return [sc.draw_plant(rng) for _ in range(self.n_plants)]

    def following_error_limit(self, evaluator: Evaluator) -> float:
        """The following-error limit in counts (1 % of the longest move unless given)."""
        if self.constraints.max_following_error is not None:
            return float(self.constraints.max_following_error)
        cpu = evaluator.plant.io.counts_per_unit
        return 0.01 * max(abs(m.distance) for m in self.scenario.moves) * cpu

    def constraint_values(self, outcome: Outcome, fe_limit: float) -> dict[str, float]:
        """Optuna constraint values (feasible when every value is <= 0)."""
        c = self.constraints
        out = {
            "max_following_error": outcome.max_following_error - fe_limit,
            "saturation_fraction": outcome.saturation_fraction - c.max_saturation,
        }
        if c.no_divergence:
            out["diverged"] = float(outcome.n_diverged)
        bound = MARGIN_CONSTRAINT_BOUND
        if c.min_gain_margin_db is not None:
            v = c.min_gain_margin_db - outcome.gain_margin_db
            out["gain_margin"] = min(max(v, -bound), bound)
        if c.min_phase_margin_deg is not None:
            v = c.min_phase_margin_deg - outcome.phase_margin_deg
            out["phase_margin"] = min(max(v, -bound), bound)
        return out

    def constraint_scales(self, fe_limit: float) -> dict[str, float]:
        """What the safe tuner divides each constraint value by (a violation of one scale
        is a large one): the following-error limit, the saturation limit, 3 dB, 15 deg."""
        c = self.constraints
        return {
            "max_following_error": max(float(fe_limit), 1.0),
            "saturation_fraction": max(float(c.max_saturation), 0.01),
            "gain_margin": max(float(c.min_gain_margin_db or 0.0), 3.0),
            "phase_margin": max(float(c.min_phase_margin_deg or 0.0), 15.0),
        }

    def objective_values(self, outcome: Outcome) -> list[float]:
        """The study's objective values of an outcome."""
        return [outcome.objective(n) for n in self.objectives]

    def describe(self) -> dict[str, Any]:
        """JSON-ready description (stored with the study and in summary.json)."""
        sc = self.scenario
        return {
            "chip_model": sc.chip_model,
            "plant": sc.plant,
            "plant_values": dict(sc.plant_values),
            "moves": [dataclasses.asdict(m) for m in sc.moves],
            "weights": dataclasses.asdict(sc.weights),
            "integrator": sc.integrator,
            "substeps": sc.substeps,
            "space": self.space.describe(),
            "n_plants": self.n_plants,
            "robust_mode": self.robust_mode,
            "sample_scale": self.sample_scale,
            "constraints": dataclasses.asdict(self.constraints),
            "objectives": list(self.objectives),
            "seed": self.seed,
        }
