"""A tuning session: the study, the budget, parallel evaluation and persistence.

Two Optuna studies work together:

* the *working study* lives in memory. Samplers ask and tell there, so a sampler never
  waits on a database;
* the *stored study* (a SQLite file by default, any Optuna RDB URL when given) receives every
  finished trial, complete with its parameters, values, constraints, user and system
  attributes, by ``Study.add_trial`` as soon as it and every trial before it have finished.
  It therefore always holds a prefix ``0 .. m`` of the working study's trials, with the
  same numbers. This is the study ``optuna-dashboard`` opens and ``--resume`` continues.

Determinism. Samplers ask in batches of ``batch_size`` trials, all of a batch before any of
it is evaluated; a batch is evaluated in a thread pool (each thread owns its own
:class:`~servogym.sim.Evaluator`, so no plant is shared) and told as its trials finish. The
sampler is rebuilt before every ask with a seed derived from ``(seed, trial number)``. A
trial's parameters are thus a function of the seed, its number and the trials of earlier
batches only: the same seed gives the same study whatever the number of workers, and a
resumed study continues exactly as the uninterrupted one would have (the batch that was
running is asked again from the state saved at its start, its stored trials are checked
against the re-asked ones and kept, the rest evaluated).
"""

from __future__ import annotations

import concurrent.futures as cf
import contextlib
import dataclasses
import json
import threading
import warnings
from collections.abc import Callable, Iterator, Mapping, Sequence
from pathlib import Path
from typing import Any

import numpy as np

from servogym.autotune._problem import Outcome, TuneProblem, aggregate
from servogym.autotune._space import register_values
from servogym.sim._scenario import Evaluator

DEFAULT_BATCH_SIZE = 8
"""Trials asked per batch: enough to keep 8 cores busy, few enough for TPE to learn."""

CONFIG_KEY = "servogym:config"
BATCH_KEY = "servogym:batch"

KINDS = ("warm_start", "sample", "candidate", "experiment")
"""What a trial is: the warm-start set, a sampler's proposal, a classical tuner's candidate
(scored on the scenario), or a classical tuner's experiment (a measurement, no cost; stored
as a PRUNED trial)."""


class TuneError(ValueError):
    """A tuning run cannot start or continue as asked (the message says why and what to do)."""


class BudgetExhausted(Exception):
    """A tuner asked for an evaluation beyond its budget."""


ProgressCallback = Callable[[int, int, float | None], None]
"""Called with (evaluations done, budget, best cost so far or None) after every trial."""


def trial_seed(seed: int, number: int) -> int:
    """The sampler seed used to ask trial ``number`` of a study seeded with ``seed``."""
    return int(np.random.SeedSequence([seed, number, 0x5EED]).generate_state(1)[0])


def default_storage_url(out_dir: str | Path) -> str:
    """``sqlite:///DIR/study.db``, the default storage of a run folder.

    Built with SQLAlchemy's URL API, so a folder name with ``?``, ``%``, ``#`` or ``@`` is
    quoted and names that folder (``--out 'q?x=1'`` stores into ``q?x=1/study.db``).
    """
    from sqlalchemy.engine import URL

    path = (Path(out_dir) / "study.db").resolve()
    return URL.create("sqlite", database=str(path)).render_as_string(hide_password=False)


def open_storage(url: str) -> Any:
    """An Optuna RDB storage for ``url``.

    A SQLite file is switched to write-ahead logging with ``synchronous=NORMAL``: a commit is
    then durable against the process being killed (only an OS crash could lose the last
    commits), and about 50 times faster than a synced commit.
    """
    import optuna

    storage = optuna.storages.RDBStorage(url)
    if url.startswith("sqlite:"):
        from sqlalchemy import event

        def _pragmas(dbapi_connection: Any, _record: Any) -> None:
            cursor = dbapi_connection.cursor()
            cursor.execute("PRAGMA journal_mode=WAL")
            cursor.execute("PRAGMA synchronous=NORMAL")
            cursor.close()

        event.listen(storage.engine, "connect", _pragmas)
        storage.engine.dispose()  # reconnect with the pragmas
    return storage


def _study_system_attrs(study: Any) -> dict[str, Any]:
    # Optuna 5 has no public accessor; samplers (QMCSampler's sample counter) use these.
    return dict(study._storage.get_study_system_attrs(study._study_id))


def _set_study_system_attrs(study: Any, attrs: Mapping[str, Any]) -> None:
    for key, value in attrs.items():
        study._storage.set_study_system_attr(study._study_id, key, value)


@dataclasses.dataclass
class _Pending:
    trial: Any  # optuna.Trial of the working study
    values: dict[str, int]
    params: Any


class Session:
    """One tuning run of one problem: budget, working and stored study, thread pool.

    Args:
        problem: What is tuned.
        budget: Evaluations (trials) the study may hold in the end, warm start and
            experiments included.
        storage: An Optuna RDB URL (``sqlite:///run/study.db``, ``postgresql://...``);
            ``None`` keeps the study in memory only (no file, nothing to resume).
        study_name: Name of the study in that storage.
        tuner_name: Stored with the study; a resume must use the same tuner.
        resume: Continue the study of that name; without it, the study must not exist.
        n_workers: Threads that evaluate in parallel.
        batch_size: Trials a sampler asks before any is evaluated; default
            :data:`DEFAULT_BATCH_SIZE`. Part of the study's identity: a resume uses the
            stored one.
        warm_start: Register values evaluated first (trial 0) when the study is new.
        progress: Called after every finished trial.
        evaluator_factory: Builds one evaluator per thread (default
            :class:`servogym.sim.Evaluator`).
    """

    def __init__(
        self,
        problem: TuneProblem,
        *,
        budget: int,
        storage: str | None,
        study_name: str,
        tuner_name: str,
        resume: bool = False,
        n_workers: int = 1,
        batch_size: int | None = None,
        warm_start: Mapping[str, int] | None = None,
        progress: ProgressCallback | None = None,
        evaluator_factory: Callable[[Any], Any] = Evaluator,
    ) -> None:
        import optuna

        batch_size_given = batch_size is not None
        batch_size = DEFAULT_BATCH_SIZE if batch_size is None else batch_size
        for name, value, low in (("budget", budget, 1), ("n_workers", n_workers, 1),
                                 ("batch_size", batch_size, 1)):  # fmt: skip
            if isinstance(value, bool) or not isinstance(value, int) or value < low:
                raise TuneError(f"{name} must be an integer >= {low}; got {name}={value!r}.")
        self.problem = problem
        self.budget = budget
        self.tuner_name = tuner_name
        self.n_workers = n_workers
        self.progress = progress
        self.evaluator_factory = evaluator_factory
        self.storage_url = storage
        self.study_name = study_name
        self.directions = ["minimize"] * len(problem.objectives)

        config = json.loads(
            json.dumps(
                {
                    "problem": problem.describe(),
                    "tuner": tuner_name,
                    "batch_size": batch_size,
                    "warm_start": dict(warm_start) if warm_start else None,
                }
            )
        )
        self._storage = (
            open_storage(storage) if storage is not None else optuna.storages.InMemoryStorage()
        )
        exists = study_name in {s.study_name for s in optuna.get_all_study_summaries(self._storage)}
        if exists and not resume:
            raise TuneError(
                f"a study named {study_name!r} already exists in {storage}; pass --resume "
                "(resume=True) to continue it, or choose another --out or --storage."
            )
        if resume and not exists:
            raise TuneError(
                f"nothing to resume: there is no study named {study_name!r} in {storage}. "
                "Run without --resume to start it."
            )
        if exists:
            self.stored = optuna.load_study(study_name=study_name, storage=self._storage)
            old = self.stored.user_attrs.get(CONFIG_KEY) or {}
            # A resume repeats the problem and the tuner; batch size and warm start are the
            # stored ones unless given again (then they must agree).
            if warm_start is None:
                config["warm_start"] = old.get("warm_start")
            if not batch_size_given:
                config["batch_size"] = old.get("batch_size", config["batch_size"])
            if old != config:
                raise TuneError(
                    f"the study {study_name!r} in {storage} was started with other settings; "
                    "a resume must repeat them (only the budget and the number of workers may "
                    f"change). Differences: {_diff(old, config)}."
                )
        else:
            self.stored = optuna.create_study(
                storage=self._storage, study_name=study_name, directions=self.directions
            )
            self.stored.set_user_attr(CONFIG_KEY, config)
        self.batch_size = int(config["batch_size"])
        self.warm_start = dict(config["warm_start"]) if config["warm_start"] else None

        stored_trials = self.stored.get_trials(deepcopy=False)
        if any(t.state.name in ("RUNNING", "WAITING") for t in stored_trials):
            raise TuneError(
                f"the study {study_name!r} holds unfinished trials, so it was not written by "
                "servogym tune (which stores finished trials only); continue it with Optuna."
            )
        if len(stored_trials) > budget:
            raise TuneError(
                f"the study {study_name!r} already holds {len(stored_trials)} trials, more "
                f"than budget={budget}; pass a budget >= {len(stored_trials)}."
            )
        self.work = optuna.create_study(directions=self.directions)
        self._n_stored = len(stored_trials)
        self._resume_batch = self._rebuild(stored_trials)

        self._plants = problem.plant_instances()
        self._local = threading.local()
        self._pool: cf.ThreadPoolExecutor | None = None
        self._main_evaluator = evaluator_factory(problem.scenario)
        self._main_evaluator.plant.set_params(problem.nominal_plant())  # experiments' plant
        self.fe_limit = problem.following_error_limit(self._main_evaluator)
        self._replay = [t for t in stored_trials if t.user_attrs.get("kind") != "warm_start"]
        self._replay_pos = 0
        self._best: float | None = None
        for t in self.work.get_trials(deepcopy=False):
            self._note_best(t)

    # ---------------------------------------------------------------- study bookkeeping

    def _rebuild(self, stored: Sequence[Any]) -> dict[str, Any] | None:
        """Fill the working study from the stored one; return the batch to re-ask, if any."""
        batch = self.stored.user_attrs.get(BATCH_KEY)
        n = len(stored)
        if batch is not None and batch["start"] <= n < batch["end"]:
            # Interrupted inside a batch: keep the trials before it, ask the batch again from
            # the state saved at its start.
            self.work.add_trials(stored[: batch["start"]])
            _set_study_system_attrs(self.work, batch["before"])
            return {
                "start": batch["start"],
                "end": batch["end"],
                "stored": stored[batch["start"] :],
            }
        self.work.add_trials(stored)
        if batch is not None:
            # Study-level sampler state after the last batch's asks (QMCSampler's counter).
            _set_study_system_attrs(self.work, batch.get("after", {}))
        return None

    @property
    def n_done(self) -> int:
        """Trials in the working study (finished or being evaluated)."""
        return len(self.work.get_trials(deepcopy=False))

    @property
    def remaining(self) -> int:
        """Evaluations left in the budget."""
        return self.budget - self.n_done

    def _persist(self) -> None:
        """Store the finished trials that follow the stored ones, in trial order."""
        trials = self.work.get_trials(deepcopy=False)
        while self._n_stored < len(trials) and trials[self._n_stored].state.is_finished():
            self.stored.add_trial(trials[self._n_stored])
            self._n_stored += 1

    def _note_best(self, t: Any) -> None:
        if t.state.name != "COMPLETE" or t.user_attrs.get("kind") == "experiment":
            return
        feasible = all(v <= 0 for v in t.constraints.values())
        value = t.values[0]
        if feasible and (self._best is None or value < self._best):
            self._best = value

    def _report(self) -> None:
        if self.progress is not None:
            self.progress(self.n_done, self.budget, self._best)

    # ---------------------------------------------------------------- evaluation

    def __enter__(self) -> Session:
        self._pool = cf.ThreadPoolExecutor(self.n_workers, thread_name_prefix="servogym-eval")
        return self

    def __exit__(self, *exc: Any) -> None:
        if self._pool is not None:
            self._pool.shutdown(wait=True, cancel_futures=True)
            self._pool = None

    def _evaluate_one(self, params: Any, k: int) -> Any:
        state = self._local.__dict__
        if "evaluator" not in state:
            state["evaluator"] = self.evaluator_factory(self.problem.scenario)
            state["plant"] = None
        plant_values = None if state["plant"] == k else self._plants[k]
        evaluation = state["evaluator"].evaluate(params, plant_values)
        state["plant"] = k
        return evaluation

    def evaluate_sets(
        self, sets: Sequence[tuple[Mapping[str, int], Any]]
    ) -> Iterator[tuple[int, Outcome]]:
        """Evaluate ``(values, params)`` pairs on every plant instance, in parallel.

        Yields ``(index, outcome)`` as each set finishes (not necessarily in order).
        """
        if self._pool is None:
            raise RuntimeError("use the Session as a context manager: with Session(...) as s")
        k_all = len(self._plants)
        futures = {
            self._pool.submit(self._evaluate_one, params, k): (i, k)
            for i, (_, params) in enumerate(sets)
            for k in range(k_all)
        }
        results: dict[int, dict[int, Any]] = {}
        try:
            for fut in cf.as_completed(futures):
                i, k = futures[fut]
                results.setdefault(i, {})[k] = fut.result()
                if len(results[i]) == k_all:
                    evals = [results[i][j] for j in range(k_all)]
                    yield i, aggregate(sets[i][0], evals, self.problem.robust_mode)
        finally:
            for fut in futures:
                fut.cancel()

    def _finish(self, trial: Any, outcome: Outcome, kind: str, extra: Mapping[str, Any]) -> None:
        """Attach an outcome to a running trial of the working study and tell it."""
        trial.set_user_attr("kind", kind)
        trial.set_user_attr("registers", outcome.values)
        attrs = outcome.to_attrs()
        attrs.pop("values")
        trial.set_user_attr("outcome", attrs)
        for key, value in extra.items():
            trial.set_user_attr(key, value)
        if self.problem.constraints.enabled:
            for name, value in self.problem.constraint_values(outcome, self.fe_limit).items():
                trial.set_constraint(name, value)
        with warnings.catch_warnings():
            warnings.filterwarnings("ignore", message=".*CmaEsSampler will not use them.*")
            self.work.tell(trial, self.problem.objective_values(outcome))

    # ---------------------------------------------------------------- sampler tuners

    def run_sampler(self, make_sampler: Callable[[int], Any]) -> None:
        """Ask, evaluate and tell in batches until the budget is used.

        Args:
            make_sampler: Builds the sampler from a seed (called before every ask).
        """
        dists = self.problem.space.distributions()
        if self._resume_batch is not None:
            self._run_batch(self._resume_batch["start"], self._resume_batch["end"],
                            make_sampler, dists, self._resume_batch["stored"])  # fmt: skip
            self._resume_batch = None
        while self.remaining > 0:
            start = self.n_done
            end = min(start + self.batch_size, self.budget)
            self._run_batch(start, end, make_sampler, dists, ())

    def _run_batch(
        self,
        start: int,
        end: int,
        make_sampler: Callable[[int], Any],
        dists: Mapping[str, Any],
        stored: Sequence[Any],
    ) -> None:
        import optuna

        batch = {"start": start, "end": end, "before": _study_system_attrs(self.work)}
        self.stored.set_user_attr(BATCH_KEY, batch)
        pending: list[_Pending] = []
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", category=Warning)
            for number in range(start, end):
                self.work.sampler = make_sampler(trial_seed(self.problem.seed, number))
                trial = self.work.ask(dict(dists))
                if trial.number != number:
                    raise RuntimeError(f"trial numbers out of step: {trial.number} != {number}")
                trial.set_user_attr("batch", [start, end])
                values = self.problem.space.values_from_unit(trial.params)
                try:
                    params = self.problem.space.make_params(values)
                    values = register_values(params)
                except ValueError as exc:  # a family's cross-register rule
                    trial.set_user_attr("kind", "sample")
                    trial.set_user_attr("registers", values)
                    trial.set_user_attr("error", str(exc))
                    self.work.tell(trial, state=optuna.trial.TrialState.FAIL)
                    continue
                pending.append(_Pending(trial, values, params))
        self.stored.set_user_attr(BATCH_KEY, {**batch, "after": _study_system_attrs(self.work)})
        # Trials of this batch already stored before an interruption: keep their results.
        done = {t.number: t for t in stored}
        todo = []
        for p in pending:
            old = done.get(p.trial.number)
            if old is None:
                todo.append(p)
                continue
            if old.params != p.trial.params:
                raise TuneError(
                    f"resuming re-asked trial {p.trial.number} with other parameters than the "
                    "stored one (was the study written by another servogym or Optuna "
                    "version?); start a new study."
                )
            self._finish(p.trial, Outcome.from_attrs(
                {**old.user_attrs["outcome"], "values": old.user_attrs["registers"]}),
                "sample", {})  # fmt: skip
        self._persist()
        self._report()
        for i, outcome in self.evaluate_sets([(p.values, p.params) for p in todo]):
            p = todo[i]
            self._finish(p.trial, outcome, "sample", {})
            self._note_best(self.work.get_trials(deepcopy=False)[p.trial.number])
            self._persist()
            self._report()
        self._persist()

    # ---------------------------------------------------------------- classical tuners

    def _add(self, trial: Any) -> None:
        self.work.add_trial(trial)
        t = self.work.get_trials(deepcopy=False)[-1]
        self._note_best(t)
        self._persist()
        self._report()

    def _next_replay(self, kind: str, values: Mapping[str, int]) -> Any | None:
        if self._replay_pos >= len(self._replay):
            return None
        t = self._replay[self._replay_pos]
        if t.user_attrs.get("kind") != kind or t.user_attrs.get("registers") != dict(values):
            raise TuneError(
                f"the stored study does not follow this tuner's procedure at trial {t.number} "
                f"(stored {t.user_attrs.get('kind')} {t.user_attrs.get('registers')}, now "
                f"{kind} {dict(values)}); start a new study."
            )
        self._replay_pos += 1
        return t

    def _frozen(self, kind: str, values: Mapping[str, int], outcome: Outcome | None,
                extra: Mapping[str, Any]) -> Any:  # fmt: skip
        import optuna

        unit = self.problem.space.to_unit(values)
        user = {"kind": kind, "registers": dict(values), **extra}
        if outcome is None:
            return optuna.trial.create_trial(
                state=optuna.trial.TrialState.PRUNED,
                params=unit,
                distributions=self.problem.space.distributions(),
                user_attrs=user,
            )
        attrs = outcome.to_attrs()
        attrs.pop("values")
        user["outcome"] = attrs
        constraints = None
        if self.problem.constraints.enabled:
            constraints = self.problem.constraint_values(outcome, self.fe_limit)
        return optuna.trial.create_trial(
            values=self.problem.objective_values(outcome),
            params=unit,
            distributions=self.problem.space.distributions(),
            user_attrs=user,
            constraints=constraints,
        )

    def evaluate_warm_start(self) -> None:
        """Evaluate the warm-start set as trial 0 of a new study (no-op otherwise)."""
        if self.warm_start is None or self.n_done > 0:
            return
        values = dict(self.warm_start)
        params = self.problem.space.make_params(values)
        ((_, outcome),) = self.evaluate_sets([(values, params)])
        self._add(self._frozen("warm_start", values, outcome, {"note": "warm start"}))

    def candidates(self, sets: Sequence[tuple[Mapping[str, int], str]]) -> list[Outcome]:
        """Score register sets on the scenario, one budget unit each (classical tuners).

        Args:
            sets: ``(values, note)`` pairs; values are complete register values.

        Raises:
            BudgetExhausted: when the budget cannot hold them all.
        """
        if len(sets) > self.remaining:
            raise BudgetExhausted(f"{len(sets)} candidates but {self.remaining} evaluations left")
        out: list[Outcome | None] = [None] * len(sets)
        todo = []
        for i, (values, _note) in enumerate(sets):
            old = self._next_replay("candidate", values)
            if old is not None:
                out[i] = Outcome.from_attrs(
                    {**old.user_attrs["outcome"], "values": old.user_attrs["registers"]}
                )
            else:
                todo.append(i)
        # Evaluate the rest in parallel, record in order.
        got = dict(self.evaluate_sets(
            [(sets[i][0], self.problem.space.make_params(sets[i][0])) for i in todo]))  # fmt: skip
        for j, i in enumerate(todo):
            out[i] = got[j]
            self._add(self._frozen("candidate", sets[i][0], got[j], {"note": sets[i][1]}))
        return [o for o in out if o is not None]

    def experiment(
        self, values: Mapping[str, int], note: str, run: Callable[[Any], dict[str, Any]]
    ) -> dict[str, Any]:
        """Run one experiment of a classical tuner on the identification plant.

        The experiment counts one evaluation. Its measurements are stored with the trial, so
        a resumed run replays them instead of simulating again.

        Args:
            values: Complete register values used in the experiment (may include registers
                a tuner does not search, such as the motor limit).
            note: What the experiment is.
            run: Runs it: takes the main thread's :class:`~servogym.sim.Evaluator` (plant at
                the nominal instance) and returns JSON-ready measurements.

        Raises:
            BudgetExhausted: when no evaluation is left.
        """
        if self.remaining < 1:
            raise BudgetExhausted("no evaluation left for an experiment")
        old = self._next_replay("experiment", values)
        if old is not None:
            return dict(old.user_attrs["experiment"])
        result = json.loads(json.dumps(run(self._main_evaluator), default=_json_default))
        self._add(self._frozen("experiment", values, None, {"note": note, "experiment": result}))
        return result

    @property
    def identification_evaluator(self) -> Any:
        """The evaluator experiments run on (main thread only), at the nominal plant."""
        return self._main_evaluator

    # ---------------------------------------------------------------- results

    def trials(self) -> list[Any]:
        """Every trial of the working study (a copy of the stored one), in order."""
        return self.work.get_trials(deepcopy=False)

    def best_trial(self) -> tuple[Any, bool]:
        """The best trial and whether it meets the constraints.

        Single objective: the lowest cost among feasible trials, else among all. Several
        objectives: of the feasible Pareto front, the trial best in the first objective.
        """
        return best_trial(self.trials(), self.problem.multi_objective)


def scored_trials(trials: Sequence[Any]) -> list[Any]:
    """Complete trials with a cost (not experiments)."""
    return [
        t for t in trials
        if t.state.name == "COMPLETE" and t.user_attrs.get("kind") != "experiment"
    ]  # fmt: skip


def is_feasible(trial: Any) -> bool:
    """Whether every constraint value of a trial is <= 0 (a trial without any is)."""
    return all(v <= 0 for v in trial.constraints.values())


def pareto_front(trials: Sequence[Any]) -> list[Any]:
    """Non-dominated trials (all objectives minimized)."""
    front = []
    for t in trials:
        dominated = any(
            all(a <= b for a, b in zip(o.values, t.values, strict=True))
            and any(a < b for a, b in zip(o.values, t.values, strict=True))
            for o in trials
        )
        if not dominated:
            front.append(t)
    return front


def best_trial(trials: Sequence[Any], multi_objective: bool) -> tuple[Any, bool]:
    """See :meth:`Session.best_trial`."""
    scored = scored_trials(trials)
    if not scored:
        raise TuneError("no trial has a cost yet: raise the budget")
    feasible = [t for t in scored if is_feasible(t)]
    pool = feasible or scored
    if multi_objective:
        pool = pareto_front(pool)
    best = min(pool, key=lambda t: (t.values[0], t.number))
    return best, bool(feasible)


def _json_default(obj: Any) -> Any:
    if isinstance(obj, np.generic):
        return obj.item()
    if isinstance(obj, np.ndarray):
        return obj.tolist()
    raise TypeError(f"{type(obj).__name__} is not JSON serializable")


def _diff(old: Mapping[str, Any], new: Mapping[str, Any], prefix: str = "") -> str:
    out = []
    for key in sorted(set(old) | set(new)):
        a, b = old.get(key), new.get(key)
        if isinstance(a, Mapping) and isinstance(b, Mapping):
            sub = _diff(a, b, f"{prefix}{key}.")
            if sub:
                out.append(sub)
        elif a != b:
            out.append(f"{prefix}{key}: stored {a!r}, now {b!r}")
    return "; ".join(out)


@contextlib.contextmanager
def quiet_optuna() -> Iterator[None]:
    """Optuna's per-trial INFO logging off for the duration."""
    import optuna

    level = optuna.logging.get_verbosity()
    optuna.logging.set_verbosity(optuna.logging.WARNING)
    try:
        yield
    finally:
        optuna.logging.set_verbosity(level)
