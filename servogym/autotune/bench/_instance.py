"""A benchmark instance: one fully specified tuning problem any optimizer can use.

The instance is an optunahub benchmark problem (``optunahub.benchmarks.BaseProblem``):
``search_space`` (Optuna distributions), ``directions``, ``evaluate(params)`` and
``evaluate_constraints(params)`` (a dict, feasible when every value is <= 0) take the
``search_space`` keys, and ``__call__(trial)`` is an Optuna objective that sets the trial's
constraints. It needs none of servogym's tuners.

Two views of the same search space, both accepted by ``evaluate``:

* the unit cube (``search_space``): ``u_<register>`` in [-1, 1], mapped onto a legal value by
  ``ParamSpec.from_unit`` (log-uniform for log-scaled gains, 0 reachable at the bottom).
  servogym's tuners search the same cube, so every optimizer faces the same problem;
* registers (``space``): each searched register by name with its legal integer range
  (:class:`servogym.chips.ParamSpec`), e.g. a set read from a parameter file.

The constraints are the ones ``servogym tune`` sets (:class:`~servogym.autotune.Constraints`):
following error within 1 % of the move, at most 5 % of ticks at the motor limit, no
divergence and, in servobench-v1, gain margin >= 6 dB and phase margin >= 30 deg at every
loop-latency choice. The last evaluation is kept, so ``evaluate`` and
``evaluate_constraints`` of the same point simulate once.

Thread safety: the plant is edited in place during an evaluation, so each thread gets its
own evaluator (built lazily on first use); a process pool gets one per process.
"""

from __future__ import annotations

import threading
from collections.abc import Mapping, Sequence
from typing import Any

from optunahub.benchmarks import BaseProblem

from servogym.autotune._problem import Constraints, Outcome, TuneProblem, aggregate
from servogym.autotune._space import UNIT_PREFIX, SearchSpace
from servogym.autotune.bench._suite import SUITE_VERSION, InstanceSpec
from servogym.chips._space import ParameterError, ParamSpec
from servogym.sim._scenario import Evaluation, Evaluator

CONSTRAINT_NAMES = ("max_following_error", "saturation_fraction", "diverged")
"""servobench-v0's constraint values, in order (feasible when every value is <= 0)."""

CONSTRAINT_NAMES_V1 = (*CONSTRAINT_NAMES, "gain_margin", "phase_margin")
"""servobench-v1's: v0's and the margin minima (:meth:`TuneProblem.constraint_values`)."""


class BenchmarkInstance(BaseProblem):
    """One instance of a suite (see :class:`servogym.autotune.bench.Suite`).

    Args:
        spec: What the instance id stands for.
        best_known: The instance's best-known record (``None``: read from the suite's data
            file, when it holds one).

    Attributes:
        id: The instance id.
        spec: The :class:`InstanceSpec`.
        problem: The :class:`~servogym.autotune.TuneProblem` servogym's tuners are given
            (nominal plant, the tune command's default constraints, seed 0).
        constraint_names: Names of the constraint values, in order.
    """

    def __init__(self, spec: InstanceSpec, best_known: Mapping[str, Any] | None = None) -> None:
        self.spec = spec
        self.id = spec.id
        scenario = spec.scenario()
        self.problem = TuneProblem(
            scenario=scenario,
            space=SearchSpace.for_chip(scenario.chip_model, fixed=spec.fixed),
            constraints=Constraints(),
        )
        self.constraint_names = (
            CONSTRAINT_NAMES if spec.suite == SUITE_VERSION else CONSTRAINT_NAMES_V1
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
        """Register values of a point of the unit cube (keys ``u_<register>``; the fixed
        registers included)."""
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
        """Register values of ``params``: the unit cube (every ``u_<register>`` of
        ``search_space``) or registers (missing ones at the chip's defaults)."""
        dists = self.search_space
        if params and all(str(k).startswith(UNIT_PREFIX) for k in params):
            missing = [k for k in dists if k not in params]
            unknown = [k for k in params if k not in dists]
            if missing or unknown:
                raise ParameterError(
                    f"{self.id}: a unit-cube point needs exactly the search_space keys "
                    f"({', '.join(dists)}); missing {', '.join(missing) or 'none'}, unknown "
                    f"{', '.join(map(str, unknown)) or 'none'}."
                )
            for k, v in params.items():
                if not (isinstance(v, int | float) and -1.0 <= v <= 1.0):
                    raise ParameterError(
                        f"{self.id}: {k} must satisfy -1 <= {k} <= 1; got {k}={v!r}."
                    )
            return self.values_from_unit(params)
        space = self.space
        fixed = self.problem.space.fixed
        unknown = [k for k in params if k not in space and k not in fixed]
        if unknown:
            raise ParameterError(
                f"{self.id} searches {', '.join(space)} (or the unit cube "
                f"{', '.join(dists)}); got unknown register(s) {', '.join(map(str, unknown))}."
            )
        held = [k for k in params if k in fixed and params[k] != fixed[k]]
        if held:
            raise ParameterError(
                f"{self.id} holds {', '.join(f'{k}={fixed[k]}' for k in held)}; got "
                f"{', '.join(f'{k}={params[k]!r}' for k in held)}."
            )
        return {**fixed, **{k: space[k].validate(v) for k, v in params.items() if k not in fixed}}

    def evaluate_details(self, params: Mapping[str, Any]) -> Evaluation:
        """The full :class:`~servogym.sim.Evaluation` of a point (unit cube or registers;
        missing registers keep the chip's defaults; an illegal value raises
        ``ParameterError`` with its range). The last one is kept per thread."""
        values = self._check(params)
        key = tuple(sorted(values.items()))
        last = getattr(self._local, "last", None)
        if last is not None and last[0] == key:
            return last[1]
        ev = self.evaluator.evaluate(self.problem.space.make_params(values))
        self._local.last = (key, ev)
        return ev

    def outcome(self, params: Mapping[str, Any]) -> Outcome:
        """The evaluation as a tuner sees it (:class:`~servogym.autotune.Outcome`)."""
        return aggregate(self._check(params), [self.evaluate_details(params)], "mean")

    def evaluate(self, params: Mapping[str, Any]) -> float:
        """Cost (docs/cost.md) of a point of ``search_space`` or of register values:
        finite, lower is better."""
        return float(self.evaluate_details(params).cost)

    def evaluate_unit(self, unit: Mapping[str, float]) -> float:
        """Cost of a point of the unit cube (keys ``u_<register>``)."""
        return self.evaluate(unit)

    def constraint_values(self, evaluation: Evaluation | Outcome) -> list[float]:
        """Constraint values of an evaluation, in :attr:`constraint_names` order."""
        outcome = evaluation
        if isinstance(evaluation, Evaluation):
            outcome = aggregate({}, [evaluation], "mean")
        named = self.problem.constraint_values(outcome, self.following_error_limit)
        return [float(named[n]) for n in self.constraint_names]

    def evaluate_constraints(self, params: Mapping[str, Any]) -> dict[str, float]:
        """Constraint values of a point, by name (feasible when all are <= 0): following
        error beyond 1 % of the move, more than 5 % of ticks at the motor limit, divergence
        (which includes the chip's own position-error trip) and, in v1, the gain and phase
        margin minima."""
        values = self.constraint_values(self.evaluate_details(params))
        return dict(zip(self.constraint_names, values, strict=True))

    def __call__(self, trial: Any) -> float:
        """An Optuna objective: suggests the unit cube and returns the cost (one simulation).

        The constraint values are stored both ways: ``trial.set_constraint`` (Optuna >= 5,
        read by its samplers) and ``trial.user_attrs["constraints"]`` (optunahub's older
        ``constraints_func`` convention, see :meth:`constraints_func`)."""
        unit = {name: trial._suggest(name, d) for name, d in self.search_space.items()}
        evaluation = self.evaluate_details(unit)
        values = self.constraint_values(evaluation)
        trial.set_user_attr("constraints", values)
        for name, value in zip(self.constraint_names, values, strict=True):
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

            self._best_known = load_best_known(self.spec.suite).get(self.id, {})
        return self._best_known or None

    def describe(self) -> dict[str, Any]:
        """JSON-ready: the spec, the search space and the constraints."""
        return {
            **self.spec.describe(),
            "space": self.problem.space.describe(),
            "constraints": {
                "names": list(self.constraint_names),
                "max_following_error_counts": self.following_error_limit,
                "max_saturation": self.problem.constraints.max_saturation,
                "no_divergence": True,
                **(
                    {}
                    if self.spec.suite == SUITE_VERSION
                    else {
                        "min_gain_margin_db": self.problem.constraints.min_gain_margin_db,
                        "min_phase_margin_deg": self.problem.constraints.min_phase_margin_deg,
                    }
                ),
            },
        }
