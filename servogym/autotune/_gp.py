"""GP Bayesian optimization on a capped history: what :class:`~servogym.autotune.GPTuner` asks with.

Optuna's ``GPSampler`` fits one Gaussian process to the objective and one to every
constraint on all completed trials, then optimizes the acquisition function over 2048
preliminary points and 10 L-BFGS searches, each evaluation of it a posterior over the whole
history. Its cost grows with the history (about a second per ask at 60 trials with the five
constraints of ``servogym tune``). :class:`CappedGPSampler` gives a fresh ``GPSampler`` a view
of the study that holds only the trials a local search needs (:func:`capped_history`: the
best ``keep_best`` and the most recent ``keep_recent`` completed trials, plus every
unfinished one), so an ask costs the same at trial 200 as at trial 60.

The view is an ordinary :class:`optuna.Study` over a storage that delegates every call to
the study's own storage and filters only :meth:`~optuna.storages.BaseStorage.get_all_trials`:
whatever the GP sampler reads of the study (its trials, their constraints, its directions)
it reads through Optuna's public storage interface, and what it writes (the relative
parameters of the trial being asked, shared with other processes) goes to the real study.
"""

from __future__ import annotations

from collections.abc import Container, Sequence
from typing import Any

import numpy as np
import optuna
from optuna.samplers import BaseSampler
from optuna.storages import BaseStorage
from optuna.study import StudyDirection
from optuna.trial import FrozenTrial, TrialState

GP_KEEP_BEST = 20
"""Completed trials the GP sees for being the best (feasible first, then least violating)."""

GP_KEEP_RECENT = 30
"""Completed trials the GP sees for being the most recent (after the best ones)."""


GP_STARTUP_TRIALS = 10
"""Completed trials before the GP fits (``GPSampler``'s default ``n_startup_trials``)."""


GP_PRELIMINARY_SAMPLES = 512
"""Quasi-random points the acquisition is scored on before the local searches (Optuna: 2048)."""

GP_LOCAL_SEARCHES = 4
"""L-BFGS searches of the acquisition, from the best feasible trial, the best preliminary
point and roulette picks among the others (Optuna: 10)."""

_OPTUNA_ACQF_ATTRS = {"_n_preliminary_samples": 2048, "_n_local_search": 10}
"""``GPSampler``'s private attributes for the acquisition optimizer and Optuna 5.1's values.

Optuna has no public argument for them; :func:`_set_acqf_budget` refuses to run if they are
gone (tests/autotune/test_gp_overhead.py also checks that ``_optimize_acqf`` reads them)."""


def _set_acqf_budget(sampler: Any, n_preliminary_samples: int, n_local_search: int) -> None:
    missing = [a for a in _OPTUNA_ACQF_ATTRS if not isinstance(getattr(sampler, a, None), int)]
    if missing:
        raise RuntimeError(
            f"optuna {optuna.__version__}'s GPSampler has no integer {', '.join(missing)}: "
            "servogym's GP sets its acquisition budget there (written for Optuna 5.1); update "
            "servogym/autotune/_gp.py for this version."
        )
    sampler._n_preliminary_samples = n_preliminary_samples
    sampler._n_local_search = n_local_search


def check_count(name: str, value: Any, low: int) -> int:
    """``value`` as an int, or a ValueError naming ``name`` if it is not an integer >= ``low``."""
    if isinstance(value, bool) or not isinstance(value, (int, np.integer)) or value < low:
        raise ValueError(f"{name} must be an integer >= {low}; got {name}={value!r}.")
    return int(value)


def check_keep(keep_best: Any, keep_recent: Any) -> tuple[int, int]:
    """The history cap, checked: the GP needs ``GP_STARTUP_TRIALS`` completed trials in view."""
    best, recent = (
        check_count("keep_best", keep_best, 1),
        check_count("keep_recent", keep_recent, 0),
    )
    if best + recent < GP_STARTUP_TRIALS:
        raise ValueError(
            f"keep_best + keep_recent must be >= {GP_STARTUP_TRIALS} (the GP's random start: "
            f"with fewer trials in view it never fits); got keep_best={best}, "
            f"keep_recent={recent}."
        )
    return best, recent


def _violation(trial: FrozenTrial) -> float:
    """Sum of the positive constraint values (0 when feasible or unconstrained)."""
    values = trial.constraints.values() if trial.constraints else ()
    return float(sum(max(float(v), 0.0) for v in values))


def _pareto_ranks(values: np.ndarray) -> np.ndarray:
    """Non-domination rank (0 = Pareto front) of every row of ``values`` (all minimized)."""
    n = len(values)
    ranks = np.full(n, -1)
    left = np.arange(n)
    rank = 0
    while len(left):
        v = values[left]
        dominated = np.array(
            [bool(np.any(np.all(v <= row, axis=1) & np.any(v < row, axis=1))) for row in v]
        )
        ranks[left[~dominated]] = rank
        left = left[dominated]
        rank += 1
    return ranks


def capped_history(
    trials: Sequence[FrozenTrial],
    directions: Sequence[StudyDirection],
    keep_best: int = GP_KEEP_BEST,
    keep_recent: int = GP_KEEP_RECENT,
) -> list[FrozenTrial]:
    """The trials the capped GP sees, in their order in ``trials``.

    Every trial that is not COMPLETE is kept (running trials are the pending points of a
    batch; the GP ignores pruned and failed ones). Of the completed trials, the best
    ``keep_best`` are kept: the feasible ones first (by objective; by non-domination rank
    with several objectives), then the infeasible ones by their summed constraint violation;
    ties go to the earlier trial. Then the ``keep_recent`` most recent of the others.

    Args:
        trials: The study's trials, in trial-number order.
        directions: The study's directions (one per objective).
        keep_best: Completed trials kept for being the best, >= 1.
        keep_recent: Further completed trials kept for being the most recent, >= 0.
    """
    keep_best = check_count("keep_best", keep_best, 1)
    keep_recent = check_count("keep_recent", keep_recent, 0)
    complete = [t for t in trials if t.state == TrialState.COMPLETE]
    if len(complete) <= keep_best + keep_recent:
        return list(trials)
    sign = np.array([1.0 if d == StudyDirection.MINIMIZE else -1.0 for d in directions])
    values = sign * np.array([t.values for t in complete], dtype=float)
    violation = np.array([_violation(t) for t in complete])
    feasible = violation <= 0
    score = values[:, 0] if len(sign) == 1 else np.zeros(len(complete))
    if len(sign) > 1 and feasible.any():
        score[feasible] = _pareto_ranks(values[feasible])
    numbers = np.array([t.number for t in complete])
    # lexsort sorts by the last key first: feasibility, then violation, then score, then number.
    order = np.lexsort((numbers, score, violation, ~feasible))
    best = set(order[:keep_best].tolist())
    others = [i for i in range(len(complete)) if i not in best]
    others.sort(key=lambda i: numbers[i])
    kept = best | set(others[len(others) - keep_recent :] if keep_recent else [])
    kept_numbers = {int(numbers[i]) for i in kept}
    return [t for t in trials if t.state != TrialState.COMPLETE or t.number in kept_numbers]


class _CappedStorage(BaseStorage):
    """A storage that is ``inner`` except that its trial lists hold the capped history."""

    def __init__(self, inner: BaseStorage, keep_best: int, keep_recent: int) -> None:
        self._inner = inner
        self._keep = (keep_best, keep_recent)

    def get_all_trials(
        self,
        study_id: int,
        deepcopy: bool = True,
        states: Container[TrialState] | None = None,
    ) -> list[FrozenTrial]:
        trials = self._inner.get_all_trials(study_id, deepcopy=deepcopy)
        directions = self._inner.get_study_directions(study_id)
        kept = capped_history(trials, directions, *self._keep)
        return kept if states is None else [t for t in kept if t.state in states]


def _delegate(name: str) -> Any:
    def method(self: _CappedStorage, *args: Any, **kwargs: Any) -> Any:
        return getattr(self._inner, name)(*args, **kwargs)

    method.__name__ = name
    return method


# Every abstract method of the storage interface, and the lookups of one trial, go to the
# real storage; get_n_trials and get_best_trial keep BaseStorage's versions (on the view).
for _name in [
    *sorted(BaseStorage.__abstractmethods__),
    "get_trial_id_from_study_id_trial_number",
    "get_trial_number_from_id",
    "get_trial_param",
    "get_trial_params",
    "get_trial_user_attrs",
    "get_trial_system_attrs",
    "remove_session",
    "check_trial_is_updatable",
]:
    if _name != "get_all_trials":
        setattr(_CappedStorage, _name, _delegate(_name))
_CappedStorage.__abstractmethods__ = frozenset()


def capped_view(study: optuna.Study, keep_best: int, keep_recent: int) -> optuna.Study:
    """The same study, whose trial lists hold only :func:`capped_history`'s trials."""
    storage = _CappedStorage(study._storage, keep_best, keep_recent)
    return optuna.Study(
        study_name=study.study_name,
        storage=storage,
        sampler=optuna.samplers.RandomSampler(seed=0),  # never asks: only read by the GP
    )


class CappedGPSampler(BaseSampler):
    """``optuna.samplers.GPSampler`` fitted on the capped history of the study.

    Every call reaches a ``GPSampler(seed=seed, deterministic_objective=True)`` with the
    study replaced by :func:`capped_view`: the GP (objective and every constraint, logCEI /
    qLogCEI with the pending trials of the batch) sees the best ``keep_best`` completed
    trials and the ``keep_recent`` most recent others, not the whole history. The first 10
    completed trials are Optuna's random start, as without the cap.

    Args:
        seed: Seed of the GP sampler (its acquisition optimizer and its random start).
        keep_best: Completed trials kept for being the best, >= 1.
        keep_recent: Further completed trials kept for being the most recent, >= 0;
            ``keep_best + keep_recent >= 10``.
    """

    def __init__(
        self, *, seed: int, keep_best: int = GP_KEEP_BEST, keep_recent: int = GP_KEEP_RECENT
    ) -> None:
        self._keep = check_keep(keep_best, keep_recent)
        self._gp = optuna.samplers.GPSampler(
            seed=seed, n_startup_trials=GP_STARTUP_TRIALS, deterministic_objective=True
        )
        _set_acqf_budget(self._gp, GP_PRELIMINARY_SAMPLES, GP_LOCAL_SEARCHES)
        self._study: Any = None
        self._view_of_study: Any = None

    def _view(self, study: optuna.Study) -> optuna.Study:
        if study is not self._study:  # one view per study asked (one, in a session)
            self._study, self._view_of_study = study, capped_view(study, *self._keep)
        return self._view_of_study

    def reseed_rng(self) -> None:
        self._gp.reseed_rng()

    def infer_relative_search_space(self, study: Any, trial: FrozenTrial) -> Any:
        return self._gp.infer_relative_search_space(self._view(study), trial)

    def sample_relative(self, study: Any, trial: FrozenTrial, search_space: Any) -> Any:
        return self._gp.sample_relative(self._view(study), trial, search_space)

    def sample_independent(
        self, study: Any, trial: FrozenTrial, param_name: str, param_distribution: Any
    ) -> Any:
        return self._gp.sample_independent(self._view(study), trial, param_name, param_distribution)

    def before_trial(self, study: Any, trial: FrozenTrial) -> None:
        self._gp.before_trial(study, trial)

    def after_trial(
        self, study: Any, trial: FrozenTrial, state: TrialState, values: Sequence[float] | None
    ) -> None:
        self._gp.after_trial(study, trial, state, values)
