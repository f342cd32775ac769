"""The tuner interface, the Optuna-backed tuners and the registry of every tuner by name."""

from __future__ import annotations

import abc
import difflib
from typing import Any, ClassVar

from servogym.autotune._problem import TuneProblem
from servogym.autotune._session import Session, TuneError


class Tuner(abc.ABC):
    """Chooses chip parameters for a :class:`TuneProblem` within a budget of evaluations.

    A tuner only talks to its :class:`Session`: it asks it to evaluate register sets
    (:meth:`Session.run_sampler` for Optuna samplers, :meth:`Session.candidates` and
    :meth:`Session.experiment` for procedures), and the session enforces the budget, runs
    the evaluations in parallel and stores every trial.

    Attributes:
        name: Registry name (``"tpe"``, ``"vendor-step"``, ...).
        supports_multi_objective: Whether the tuner can minimize several objectives.
        supports_multi_axis: Whether the tuner can tune the axes of a machine together (a
            search of the unit cube can; the classical procedures experiment on one axis).
        min_budget: Smallest budget the tuner can work with.
    """

    name: ClassVar[str]
    supports_multi_objective: ClassVar[bool] = False
    supports_multi_axis: ClassVar[bool] = False
    min_budget: ClassVar[int] = 1

    def check(self, problem: TuneProblem, budget: int) -> None:
        """Raise :class:`TuneError` if the tuner cannot solve ``problem`` in ``budget``."""
        if problem.multi_objective and not self.supports_multi_objective:
            multi = [n for n, t in TUNERS.items() if t.supports_multi_objective]
            raise TuneError(
                f"the {self.name!r} tuner minimizes one objective; a multi-objective study "
                f"needs one of {', '.join(multi)}."
            )
        if problem.n_axes > 1 and not self.supports_multi_axis:
            multi = [n for n, t in TUNERS.items() if t.supports_multi_axis]
            raise TuneError(
                f"the {self.name!r} tuner experiments on one axis; a machine of "
                f"{problem.n_axes} axes needs one of {', '.join(multi)}."
            )
        if budget < self.min_budget:
            raise TuneError(
                f"the {self.name!r} tuner needs a budget of at least {self.min_budget} "
                f"evaluations; got budget={budget}."
            )

    @abc.abstractmethod
    def run(self, session: Session) -> None:
        """Use the session's budget (or less) to search; the session records every trial."""


class OptunaTuner(Tuner):
    """An Optuna sampler searching every register on u in [-1, 1].

    Subclasses say how to build the sampler from a seed; the session rebuilds it before
    every ask with a seed derived from the study seed and the trial number.
    """

    supports_multi_objective = True
    supports_multi_axis = True

    @abc.abstractmethod
    def make_sampler(self, seed: int, session: Session) -> Any:
        """The sampler that asks the next trial."""

    def run(self, session: Session) -> None:
        session.evaluate_warm_start()
        session.run_sampler(lambda seed: self.make_sampler(seed, session))


class TPETuner(OptunaTuner):
    """Multivariate Tree-structured Parzen Estimator (``optuna.samplers.TPESampler``).

    Constraints are used through the trials' constraint values; pending trials of a batch
    are given a constant liar value, so one batch spreads out.
    """

    name = "tpe"

    def make_sampler(self, seed: int, session: Session) -> Any:
        import optuna

        return optuna.samplers.TPESampler(seed=seed, multivariate=True, constant_liar=True)


class GPTuner(OptunaTuner):
    """Gaussian-process Bayesian optimization (``optuna.samplers.GPSampler``; imports torch)
    on a capped history (:class:`servogym.autotune._gp.CappedGPSampler`).

    What the GP sees: the best :data:`~servogym.autotune._gp.GP_KEEP_BEST` completed trials
    (feasible ones by cost first, then the least violating) and the
    :data:`~servogym.autotune._gp.GP_KEEP_RECENT` most recent others, plus the pending
    trials of the batch; the objective and every constraint get their own process (logCEI,
    qLogCEI with pending trials). The cost is deterministic (the simulation has no noise),
    which the GP is told. Every trial is asked by a new sampler seeded with the trial's
    seed, its processes fitted from Optuna's default kernel parameters: nothing is kept
    between asks, so the same seed gives the same study, and an ask costs about the same
    at trial 200 as at trial 60. The acquisition is optimized from
    :data:`~servogym.autotune._gp.GP_PRELIMINARY_SAMPLES` points and
    :data:`~servogym.autotune._gp.GP_LOCAL_SEARCHES` local searches (docs/autotune.md,
    "GP's per-trial overhead").

    Args:
        keep_best: Completed trials the GP sees for being the best (default
            :data:`~servogym.autotune._gp.GP_KEEP_BEST`), >= 1.
        keep_recent: Further completed trials it sees for being the most recent (default
            :data:`~servogym.autotune._gp.GP_KEEP_RECENT`), >= 0; the two sum to >= 10.
    """

    name = "gp"

    def __init__(self, keep_best: int | None = None, keep_recent: int | None = None) -> None:
        from servogym.autotune import _gp

        best = _gp.GP_KEEP_BEST if keep_best is None else keep_best
        recent = _gp.GP_KEEP_RECENT if keep_recent is None else keep_recent
        self.keep_best, self.keep_recent = _gp.check_keep(best, recent)

    def make_sampler(self, seed: int, session: Session) -> Any:
        from servogym.autotune._gp import CappedGPSampler

        return CappedGPSampler(seed=seed, keep_best=self.keep_best, keep_recent=self.keep_recent)


class CMAESTuner(OptunaTuner):
    """CMA-ES (``optuna.samplers.CmaEsSampler``): single objective, constraints not used
    for sampling (they still decide the best trial).

    The population size is a multiple of the batch size, so a generation is never split
    over a batch boundary; a warm start becomes the mean ``x0`` with a smaller step size.
    """

    name = "cmaes"
    supports_multi_objective = False

    def make_sampler(self, seed: int, session: Session) -> Any:
        import math

        import optuna

        dim = len(session.problem.space.names)
        b = session.batch_size
        popsize = b * math.ceil((4 + math.floor(3 * math.log(dim))) / b)
        kw: dict[str, Any] = {}
        if session.warm_start is not None:
            kw["x0"] = session.problem.space.to_unit(session.warm_start)
            kw["sigma0"] = 0.2
        return optuna.samplers.CmaEsSampler(
            seed=seed, popsize=popsize, warn_independent_sampling=False, **kw
        )


class RandomTuner(OptunaTuner):
    """Uniform random search on the unit cube (log-uniform on log-scaled registers)."""

    name = "random"

    def make_sampler(self, seed: int, session: Session) -> Any:
        import optuna

        return optuna.samplers.RandomSampler(seed=seed)


class SobolTuner(OptunaTuner):
    """Scrambled Sobol sequence (``optuna.samplers.QMCSampler``), seeded by the study seed.

    Every trial takes the next point of one sequence, so the scramble seed is the study's
    seed, not the per-trial one. The very first trial, asked before the search space is
    known to the sampler, is uniform random.
    """

    name = "sobol"

    def make_sampler(self, seed: int, session: Session) -> Any:
        import optuna

        return optuna.samplers.QMCSampler(
            qmc_type="sobol",
            scramble=True,
            seed=session.problem.seed,
            independent_sampler=optuna.samplers.RandomSampler(seed=seed),
        )


TUNERS: dict[str, type[Tuner]] = {}
"""Every tuner class by name, in the order ``servogym tune --tuner`` lists them."""

DEFAULT_TUNER = "safe"
"""The tuner ``servogym tune`` uses unless ``--tuner`` names another
(:class:`servogym.autotune._safe.SafeTuner`; single objective, so ``--multi-objective``
defaults to :data:`DEFAULT_MULTI_OBJECTIVE_TUNER`)."""

DEFAULT_MULTI_OBJECTIVE_TUNER = "tpe"
"""The tuner ``servogym tune --multi-objective`` uses unless ``--tuner`` names another."""


def register_tuner(cls: type[Tuner]) -> type[Tuner]:
    """Add a tuner class to :data:`TUNERS` (usable as a class decorator)."""
    TUNERS[cls.name] = cls
    return cls


for _cls in (TPETuner, GPTuner, CMAESTuner, RandomTuner, SobolTuner):
    register_tuner(_cls)


def get_tuner(name: str, **kw: Any) -> Tuner:
    """A tuner by registry name, with close matches in the error for a mistyped one."""
    _load_classical()
    try:
        cls = TUNERS[name]
    except KeyError:
        close = difflib.get_close_matches(str(name), list(TUNERS), n=3)
        hint = f" Did you mean {', '.join(close)}?" if close else ""
        raise TuneError(
            f"unknown tuner {name!r}; the tuners are {', '.join(TUNERS)}.{hint}"
        ) from None
    return cls(**kw)


def tuner_names() -> list[str]:
    """Every registered tuner name."""
    _load_classical()
    return list(TUNERS)


def _load_classical() -> None:
    import servogym.autotune._classical
    import servogym.autotune._safe  # noqa: F401  (registers the default tuner)
