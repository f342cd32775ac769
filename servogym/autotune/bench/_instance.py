"""A benchmark instance: one fully specified tuning problem any optimizer can use.

The instance follows the shape of optunahub's benchmark problems: ``search_space`` (Optuna
distributions), ``directions``, ``evaluate(params)``, ``__call__(trial)`` (an Optuna
objective) and, for constraints, ``evaluate_constraints(params)`` and
``constraints_func(trial)``. It needs neither optunahub nor servogym's tuners.

Two views of the same search space:

* registers (``space``): each searched register by name with its legal integer range
  (:class:`servogym.chips.ParamSpec`); ``evaluate`` takes register values;
* the unit cube (``search_space``): ``u_<register>`` in [-1, 1], mapped onto a legal value by
  ``ParamSpec.from_unit`` (log-uniform for log-scaled gains, 0 reachable at the bottom).
  ``__call__`` suggests these; servogym's tuners search the same cube, so every optimizer
  faces the same problem.

Thread safety: the plant is edited in place during an evaluation, so each thread gets its
own evaluator (built lazily on first use); a process pool gets one per process.
"""

from __future__ import annotations

import threading
from collections.abc import Mapping, Sequence
from typing import Any

from servogym.autotune._problem import Constraints, Outcome, TuneProblem, aggregate
from servogym.autotune._space import UNIT_PREFIX, SearchSpace
from servogym.autotune.bench._suite import InstanceSpec
from servogym.chips._space import ParameterError, ParamSpec
from servogym.sim._scenario import Evaluation, Evaluator

CONSTRAINT_NAMES = ("max_following_error", "saturation_fraction", "diverged")
"""The constraint values, in order (feasible when every value is <= 0)."""


class BenchmarkInstance:
    """One instance of a suite (see :class:`servogym.autotune.bench.Suite`).

    Args:
        spec: What the instance id stands for.
        best_known: The instance's best-known record (``None``: read from the suite's data
            file, when it holds one).

    Attributes:
        id: The instance id.
        spec: The :class:`InstanceSpec`.
        problem: The :class:`~servogym.autotune.TuneProblem` servogym's tuners are given
            (nominal plant, default constraints, seed 0).
    """

    def __init__(self, spec: InstanceSpec, best_known: Mapping[str, Any] | None = None) -> None:
        self.spec = spec
        self.id = spec.id
        scenario = spec.scenario()
        self.problem = TuneProblem(
            scenario=scenario,
            space=SearchSpace.for_chip(scenario.chip_model),
            constraints=Constraints(),
        )
        self._best_known = dict(best_known) if best_known is not None else None
        self._local = threading.local()
        self._fe_limit: float | None = None

    def __repr__(self) -> str:
        return f"BenchmarkInstance({self.id!r})"

    # ---------------------------------------------------------------- the space

    @property
    def space(self) -> dict[str, ParamSpec]:
        """Searched registers by name: legal integer range, log scale, default."""
        return {s.name: s for s in self.problem.space.specs}

    @property
    def search_space(self) -> dict[str, Any]:
        """Optuna distributions of the unit cube: ``u_<register>`` -> FloatDistribution(-1, 1)."""
        return self.problem.space.distributions()

    @property
    def directions(self) -> list[Any]:
        """One objective, minimized."""
        from optuna.study import StudyDirection

        return [StudyDirection.MINIMIZE]

    def default_values(self) -> dict[str, int]:
        """The chip model's default value of every searched register."""
        return {n: s.default for n, s in self.space.items()}

    def values_from_unit(self, unit: Mapping[str, float]) -> dict[str, int]:
        """Register values of a point of the unit cube (keys ``u_<register>``)."""
        return self.problem.space.values_from_unit(unit)

    def to_unit(self, values: Mapping[str, int]) -> dict[str, float]:
        """The unit-cube point of register values (every searched register needed)."""
        return self.problem.space.to_unit(values)

    # ---------------------------------------------------------------- evaluation

    @property
    def evaluator(self) -> Evaluator:
        """This thread's evaluator (built on first use)."""
        ev = getattr(self._local, "evaluator", None)
        if ev is None:
            ev = Evaluator(self.problem.scenario)
            self._local.evaluator = ev
        return ev

    @property
    def following_error_limit(self) -> float:
        """The following-error constraint (counts): 1 % of the move."""
        if self._fe_limit is None:
            self._fe_limit = self.problem.following_error_limit(self.evaluator)
        return self._fe_limit

    def _check(self, params: Mapping[str, Any]) -> dict[str, int]:
        space = self.space
        unknown = [k for k in params if k not in space]
        if unknown:
            if all(k.startswith(UNIT_PREFIX) for k in params):
                raise ParameterError(
                    f"evaluate takes register values ({', '.join(space)}); got unit-cube "
                    "coordinates: use evaluate_unit for u_<register> keys."
                )
            raise ParameterError(
                f"{self.id} searches {', '.join(space)}; got unknown register(s) "
                f"{', '.join(map(str, unknown))}."
            )
        return {k: space[k].validate(v) for k, v in params.items()}

    def evaluate_details(self, params: Mapping[str, Any]) -> Evaluation:
        """The full :class:`~servogym.sim.Evaluation` of register values (missing registers
        keep the chip's defaults; an illegal value raises ``ParameterError`` with its range)."""
        values = self._check(params)
        return self.evaluator.evaluate(self.problem.space.make_params(values))

    def outcome(self, params: Mapping[str, Any]) -> Outcome:
        """The evaluation as a tuner sees it (:class:`~servogym.autotune.Outcome`)."""
        values = self._check(params)
        ev = self.evaluator.evaluate(self.problem.space.make_params(values))
        return aggregate(values, [ev], "mean")

    def evaluate(self, params: Mapping[str, Any]) -> float:
        """Cost of register values (docs/cost.md): finite, lower is better."""
        return float(self.evaluate_details(params).cost)

    def evaluate_unit(self, unit: Mapping[str, float]) -> float:
        """Cost of a point of the unit cube (keys ``u_<register>``)."""
        return self.evaluate(self.values_from_unit(unit))

    def constraint_values(self, evaluation: Evaluation | Outcome) -> list[float]:
        """Constraint values of an evaluation, in :data:`CONSTRAINT_NAMES` order."""
        c = self.problem.constraints
        diverged = getattr(evaluation, "n_diverged", None)
        if diverged is None:
            diverged = int(evaluation.diverged)
        return [
            float(evaluation.max_following_error - self.following_error_limit),
            float(evaluation.saturation_fraction - c.max_saturation),
            float(diverged),
        ]

    def evaluate_constraints(self, params: Mapping[str, Any]) -> list[float]:
        """Constraint values of register values (feasible when all are <= 0): following
        error beyond 1 % of the move, more than 5 % of ticks at the motor limit, divergence
        (which includes the chip's own position-error trip)."""
        return self.constraint_values(self.evaluate_details(params))

    def __call__(self, trial: Any) -> float:
        """An Optuna objective: suggests the unit cube and returns the cost.

        The constraint values are stored both ways: ``trial.set_constraint`` (Optuna >= 5,
        read by its samplers) and ``trial.user_attrs["constraints"]`` (optunahub's
        ``constraints_func`` convention, see :meth:`constraints_func`)."""
        unit = {name: trial._suggest(name, d) for name, d in self.search_space.items()}
        evaluation = self.evaluate_details(self.values_from_unit(unit))
        values = self.constraint_values(evaluation)
        trial.set_user_attr("constraints", values)
        if hasattr(trial, "set_constraint"):  # Optuna >= 5: samplers read them from here
            for name, value in zip(CONSTRAINT_NAMES, values, strict=True):
                trial.set_constraint(name, value)
        return float(evaluation.cost)

    @staticmethod
    def constraints_func(trial: Any) -> Sequence[float]:
        """For a sampler's ``constraints_func``: the values ``__call__`` stored."""
        return trial.user_attrs["constraints"]

    # ---------------------------------------------------------------- reference

    @property
    def best_known(self) -> float | None:
        """Best-known cost of a feasible set (``None`` when the data file has no record)."""
        rec = self.best_known_record
        return None if rec is None else float(rec["cost"])

    @property
    def best_known_record(self) -> dict[str, Any] | None:
        """The record: cost, register values, feasibility and how it was found."""
        if self._best_known is None:
            from servogym.autotune.bench._reference import load_best_known

            self._best_known = load_best_known().get(self.id, {})
        return self._best_known or None

    def describe(self) -> dict[str, Any]:
        """JSON-ready: the spec, the search space and the constraints."""
        return {
            **self.spec.describe(),
            "space": self.problem.space.describe(),
            "constraints": {
                "max_following_error_counts": self.following_error_limit,
                "max_saturation": self.problem.constraints.max_saturation,
                "no_divergence": True,
            },
        }
