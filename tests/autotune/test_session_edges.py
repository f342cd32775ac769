"""Edges of the tuning session that the end-to-end studies do not reach (issue 14).

Opening a storage while another process creates its schema, the password kept out of
messages, the running best (the progress callback) inside a batch and after trials of other
workers, abandoned trials in the log, a queued retry evaluated even when this worker has
not yet seen the failure it replaces, the warm start evaluated on its own, and an
experiment at the last evaluation of the budget. "Another worker" is a second
``optuna.Study`` on the same storage, acting from inside the progress callback, which the
session calls between its look at the study and its asks.
"""

from __future__ import annotations

import inspect
import logging
import sqlite3
import threading
import time

import optuna
import pytest
import sqlalchemy.exc

import servogym.autotune._session as session_module
from servogym.autotune import TuneError
from servogym.autotune._session import (
    BudgetExhausted,
    Session,
    _redact,
    _retry_callback,
    open_storage,
)
from servogym.autotune._space import register_values

from .helpers import short_problem

# ------------------------------------------------------------------ schema-creation races


def _error(text: str) -> sqlalchemy.exc.OperationalError:
    """The error SQLAlchemy raises for a driver's ``text`` (what RDBStorage lets through)."""
    return sqlalchemy.exc.OperationalError("CREATE TABLE studies", None,
                                           sqlite3.OperationalError(text))  # fmt: skip


@pytest.fixture
def flaky_rdb(monkeypatch):
    """RDBStorage failing with given errors before it succeeds; records calls and pauses."""
    real = optuna.storages.RDBStorage
    record = {"calls": 0, "errors": [], "sleeps": []}

    class Flaky(real):
        __signature__ = inspect.signature(real)  # the session picks its callback keyword

        def __init__(self, url, *args, **kwargs):
            record["calls"] += 1
            if record["errors"]:
                raise record["errors"].pop(0)
            super().__init__(url, *args, **kwargs)

    monkeypatch.setattr(optuna.storages, "RDBStorage", Flaky)
    monkeypatch.setattr(session_module.time, "sleep", record["sleeps"].append)
    return record


def test_a_schema_race_is_retried_seven_times_with_growing_pauses(flaky_rdb, tmp_path):
    # Another process creating the tables: "already exists" seven times, then the schema is
    # there. Attempts 0..6 each wait 0.1 s * (attempt + 1); the eighth opens the storage.
    flaky_rdb["errors"] = [_error("table studies already exists")] * 7
    storage = open_storage(f"sqlite:///{tmp_path / 'study.db'}")
    assert flaky_rdb["calls"] == 8
    assert flaky_rdb["sleeps"] == pytest.approx([0.1, 0.2, 0.3, 0.4, 0.5, 0.6, 0.7])
    study = optuna.create_study(storage=storage, study_name="s")  # the storage works
    assert study.study_name == "s"


def test_a_race_lasting_eight_attempts_is_reported_in_one_line(flaky_rdb, tmp_path):
    flaky_rdb["errors"] = [_error("database is locked")] * 8
    url = f"sqlite:///{tmp_path / 'study.db'}"
    with pytest.raises(TuneError, match=r"cannot open the study storage .*: database is locked\.$"):
        open_storage(url)
    assert flaky_rdb["calls"] == 8 and len(flaky_rdb["sleeps"]) == 7


def test_an_error_other_than_a_race_is_not_retried(flaky_rdb, tmp_path):
    flaky_rdb["errors"] = [_error("unable to open database file")]
    with pytest.raises(TuneError, match=r"unable to open database file\.$"):
        open_storage(f"sqlite:///{tmp_path / 'study.db'}")
    assert flaky_rdb["calls"] == 1 and flaky_rdb["sleeps"] == []


def test_a_sqlite_study_waits_a_minute_for_a_lock_in_wal_mode(monkeypatch, tmp_path):
    # Several processes share a SQLite study: every connection waits up to 60 s for
    # another's write lock, in write-ahead-log mode with synchronous=NORMAL (docstring of
    # open_storage).
    real, timeouts = sqlite3.dbapi2.connect, []

    def connect(*args, **kwargs):
        timeouts.append(kwargs.get("timeout"))
        return real(*args, **kwargs)

    monkeypatch.setattr(sqlite3.dbapi2, "connect", connect)
    storage = open_storage(f"sqlite:///{tmp_path / 'study.db'}")
    optuna.create_study(storage=storage, study_name="s")
    with storage.engine.connect() as conn:
        mode = conn.exec_driver_sql("PRAGMA journal_mode").scalar()
        sync = conn.exec_driver_sql("PRAGMA synchronous").scalar()
    assert timeouts and set(timeouts) == {60}
    assert mode == "wal" and sync == 1  # 1 = NORMAL


def test_redact_hides_the_password_and_keeps_the_user_and_host():
    assert _redact("postgresql://alice:s3cret@db.example:5432/tune") == (
        "postgresql://alice:***@db.example:5432/tune"
    )
    # A password holding ':' or '@': the user is what precedes the first ':', the host
    # what follows the last '@'.
    assert _redact("postgresql://bob:a:b@c@host/db") == "postgresql://bob:***@host/db"
    assert _redact("postgresql://carol@host/db") == "postgresql://carol@host/db"  # no password
    assert _redact("sqlite:///run/study.db") == "sqlite:///run/study.db"
    assert _redact("run/study.journal") == "run/study.journal"


# ------------------------------------------------------------------ sessions


def _session(
    budget: int, progress=None, objectives=("cost",), **kw
) -> tuple[Session, optuna.Study]:
    """A session on a memory storage (constraints off: every trial is feasible), and
    another worker's view of its study."""
    storage = optuna.storages.InMemoryStorage()
    problem = short_problem(constraints=False, objectives=objectives)
    s = Session(problem, budget=budget, storage=storage,
                study_name="s", tuner_name="random", progress=progress, **kw)  # fmt: skip
    return s, optuna.load_study(study_name="s", storage=storage)


def _random(seed: int):
    return optuna.samplers.RandomSampler(seed=seed)


def _lowest_cost(study: optuna.Study) -> float | None:
    costs = [t.values[0] for t in study.get_trials() if t.state.name == "COMPLETE"]
    return min(costs) if costs else None


@pytest.mark.parametrize("objectives", [("cost",), ("cost", "max_following_error")])
def test_the_running_best_follows_every_trial_told_within_a_batch(objectives):
    # One batch of 4: the progress callback runs after each trial is told, before the
    # session looks at the study again; the best it reports is already that of the trials
    # told so far (all feasible here), in the first objective when there are several.
    seen = []

    def progress(done, budget, best):
        seen.append((done, best, _lowest_cost(other)))

    s, other = _session(4, progress, objectives, batch_size=4)
    with s:
        s.run_sampler(_random)
    in_batch = [(best, lowest) for done, best, lowest in seen if lowest is not None]
    assert len(in_batch) >= 4
    assert all(best == lowest for best, lowest in in_batch), seen


def test_the_running_best_includes_trials_of_other_workers():
    # Another worker tells a trial cheaper than any this one finds (cost 0) while this
    # worker is asking: the next look at the study makes it the best reported.
    seen = []

    def progress(done, budget, best):
        if not seen:
            dists = s.problem.space.distributions()
            trial = other.ask(dists)
            other.tell(trial, [0.0])
        seen.append(best)

    s, other = _session(3, progress, batch_size=2)
    with s:
        s.run_sampler(_random)
    assert len(s.trials()) == 3 and s.n_done == 3
    assert seen[-1] == 0.0
    best, feasible = s.best_trial()
    assert best.number == 0 and best.values == [0.0] and feasible


def test_abandoned_trials_are_logged_when_their_number_grows(caplog):
    # A failed trial without an error (a dead worker's) counts for nothing. Already there
    # when the session starts, it is not news: nothing is logged. A second one, failed by
    # another worker while this one runs, is logged once, as one.
    caplog.set_level(logging.INFO, logger=session_module.__name__)
    fail = optuna.trial.TrialState.FAIL
    calls = []

    def progress(done, budget, best):
        calls.append(done)
        if len(calls) == 3:  # after the first trial of this worker was told
            other.add_trial(optuna.trial.create_trial(state=fail))

    s, other = _session(3, progress, batch_size=1)
    other.add_trial(optuna.trial.create_trial(state=fail))
    with s:
        s.run_sampler(_random)
    states = [t.state.name for t in s.trials()]
    assert states.count("FAIL") == 2 and states.count("COMPLETE") == 3
    logged = [r.getMessage() for r in caplog.records if "abandoned" in r.getMessage()]
    assert logged == ["1 abandoned trial(s) failed and queued again"]


def test_a_queued_retry_is_evaluated_though_its_failure_is_news_to_this_worker():
    # Budget 2. Another worker runs trial 0. Between this worker's look at the study and its
    # ask, the other worker asks trial 1, and trial 0 is failed as abandoned and queued
    # again as trial 2. This worker still counts trial 0, so trial 2 seems to be its third
    # counted trial; but a queued retry is within the budget by construction (it replaces
    # a failed trial) and must be evaluated, not refused as over the budget.
    tell_first, running = [], []

    def progress(done, budget, best):
        if not tell_first:
            dists = s.problem.space.distributions()
            running.append(other.ask(dists))  # trial 1
            other.tell(first, state=optuna.trial.TrialState.FAIL)
            _retry_callback()(other, other._storage.get_trial(first._trial_id))  # trial 2
            tell_first.append(True)
        elif running:
            other.tell(running.pop(), [1.0])  # the other worker finishes trial 1

    s, other = _session(2, progress, batch_size=2)
    first = other.ask(s.problem.space.distributions())  # trial 0
    with s:
        s.run_sampler(_random)
    trials = s.trials()
    assert [t.state.name for t in trials] == ["FAIL", "COMPLETE", "COMPLETE"]
    retry = trials[2]
    assert retry.system_attrs["failed_trial"] == 0
    assert retry.params == trials[0].params
    assert retry.user_attrs["kind"] == "sample" and "over_budget" not in retry.user_attrs
    assert s.n_done == 2


def test_the_warm_start_is_evaluated_on_its_own_before_any_sample():
    problem = short_problem(constraints=False)
    warm = register_values(problem.scenario.default_params())
    seen = []
    s = Session(problem, budget=3, storage=None, study_name="w", tuner_name="tpe",
                warm_start=warm, progress=lambda *a: seen.append(a))  # fmt: skip
    with s:
        s.evaluate_warm_start()
        (trial,) = s.trials()
        assert trial.state.name == "COMPLETE" and trial.user_attrs["kind"] == "warm_start"
        assert trial.user_attrs["registers"] == warm
        assert s.n_done == 1 and s.remaining == 2
        assert seen == [(1, 3, trial.values[0])]
        s.evaluate_warm_start()  # nothing queued any more: a no-op
        assert len(s.trials()) == 1


def test_an_experiment_may_use_the_last_evaluation_of_the_budget():
    problem = short_problem()
    values = register_values(problem.scenario.default_params())
    with Session(problem, budget=1, storage=None, study_name="e", tuner_name="t") as s:
        assert s.remaining == 1
        assert s.experiment(values, "last", lambda ev: {"peak": 3}) == {"peak": 3}
        assert s.remaining == 0 and s.n_done == 1
        with pytest.raises(BudgetExhausted, match="no evaluation left for an experiment"):
            s.experiment(values, "one too many", lambda ev: {})
    (trial,) = s.trials()
    assert trial.state.name == "PRUNED" and trial.user_attrs["kind"] == "experiment"
    assert trial.user_attrs["experiment"] == {"peak": 3}


@pytest.mark.parametrize("kind", ["journal", "sqlite"])
def test_a_trial_whose_worker_died_before_its_first_heartbeat_is_failed(tmp_path, kind):
    # A worker killed inside study.ask, after the storage created its trial and before the
    # trial's first heartbeat, leaves a running trial without any heartbeat. It must still be
    # failed once the grace period has passed since its start, and queued again; otherwise
    # every worker, and a resume, waits for it forever (Optuna's RDB storage alone skips a
    # trial without a heartbeat row: test_resume's killed-worker test on SQLite hung on it).
    url = str(tmp_path / "s.journal") if kind == "journal" else f"sqlite:///{tmp_path}/s.db"
    storage = open_storage(url, heartbeat_interval=1, grace_period=1)
    study = optuna.create_study(storage=storage, study_name="s")
    study._storage.create_new_trial(study._study_id)  # RUNNING, no heartbeat
    optuna.storages.fail_stale_trials(study)
    assert [t.state.name for t in study.get_trials()] == ["RUNNING"]  # within the grace period
    time.sleep(1.2)
    optuna.storages.fail_stale_trials(study)
    trials = study.get_trials()
    assert [t.state.name for t in trials] == ["FAIL", "WAITING"]
    assert trials[1].system_attrs["failed_trial"] == 0


def test_a_session_joins_a_study_of_other_workers_by_default():
    # Sessions are shared unless a tuner says otherwise (the classical tuners pass
    # shared=False): a second worker joins the study of the first.
    storage = optuna.storages.InMemoryStorage()
    kw = {"budget": 4, "storage": storage, "study_name": "j", "tuner_name": "random"}
    first = Session(short_problem(), **kw)
    second = Session(short_problem(), load_if_exists=True, **kw)
    assert second.shared and second.study._study_id == first.study._study_id
    with pytest.raises(TuneError, match="sequential procedure and cannot share"):
        Session(short_problem(), load_if_exists=True, shared=False, **kw)


def test_the_heartbeat_thread_never_keeps_a_process_alive(tmp_path):
    # A daemon thread: a program that ends without leaving its session (an application that
    # never closes it) is not held open by the heartbeats; leaving the session stops them.
    s = Session(short_problem(), budget=2, storage=str(tmp_path / "s.journal"),
                study_name="h", tuner_name="random")  # fmt: skip
    with s:
        (beat,) = [t for t in threading.enumerate() if t.name == "servogym-heartbeat"]
        assert beat.daemon and beat.is_alive()
    assert not beat.is_alive()


@pytest.mark.parametrize(("value", "feasible"), [(0.0, True), (0.5, False)])
def test_the_running_best_counts_only_trials_that_meet_their_constraints(
    monkeypatch, value, feasible
):
    # Every trial gets one constraint value: 0 is met (feasible means every value <= 0),
    # 0.5 is not, and then no best is reported at any time, however cheap a trial.
    from servogym.autotune import TuneProblem

    monkeypatch.setattr(TuneProblem, "constraint_values", lambda *a: {"following_error": value})
    seen = []
    s = Session(short_problem(), budget=3, storage=None, study_name="c", tuner_name="random",
                batch_size=3, progress=lambda done, budget, best: seen.append(best))  # fmt: skip
    with s:
        s.run_sampler(_random)
    costs = [t.values[0] for t in s.trials()]
    assert len(costs) == 3 and len(seen) >= 4
    if feasible:
        assert seen[-1] == min(costs) and None not in seen[1:]
    else:
        assert seen == [None] * len(seen)


def test_storages_default_to_a_5_s_heartbeat_and_a_20_s_grace_period(tmp_path):
    # docs/autotune.md: "a heartbeat every 5 s ... a trial without a heartbeat for 20 s is
    # failed"; given values replace them.
    journal = open_storage(str(tmp_path / "s.journal"))
    rdb = open_storage(f"sqlite:///{tmp_path / 's.db'}")
    assert journal.get_heartbeat_interval() == 5 and journal._grace_period == 20
    assert rdb.get_heartbeat_interval() == 5 and rdb.grace_period == 20
    given = open_storage(str(tmp_path / "t.journal"), heartbeat_interval=2, grace_period=7)
    assert given.get_heartbeat_interval() == 2 and given._grace_period == 7


def test_the_overhead_is_the_main_threads_cpu_time_spent_asking_and_telling():
    s, _ = _session(6, batch_size=3)
    assert s.overhead() == {"ask_s": 0.0, "sampler_s": 0.0, "tell_s": 0.0}
    with s:
        t0 = time.thread_time()
        s.run_sampler(_random)
        spent = time.thread_time() - t0
    o = s.overhead()
    assert o["ask_s"] > 0 and o["tell_s"] > 0 and o["ask_s"] + o["tell_s"] <= spent
    assert 0 < o["sampler_s"] < o["ask_s"]  # the sampler's own part of asking
    # A classical tuner's candidates are added, not asked: telling time only.
    s, _ = _session(2)
    values = register_values(s.problem.scenario.default_params())
    with s:
        t0 = time.thread_time()
        s.candidates([(values, "a"), (values, "b")])
        spent = time.thread_time() - t0
    o = s.overhead()
    assert o["ask_s"] == 0.0 and 0 < o["tell_s"] <= spent


def test_a_worker_waiting_for_another_ones_last_trial_says_so_once(monkeypatch, caplog):
    # Budget 2: another worker runs trial 0; this one evaluates trial 1, then has nothing
    # left to ask and waits, polling, until trial 0 is finished; it logs the wait once.
    monkeypatch.setattr(session_module, "POLL_S", 0.01)
    caplog.set_level(logging.INFO, logger=session_module.__name__)
    looks = []

    def progress(done, budget, best):
        looks.append(done)
        if done == 1 and looks.count(1) == 4:  # this worker has polled a few times
            other.tell(first, [1.0])

    s, other = _session(2, progress, batch_size=2)
    first = other.ask(s.problem.space.distributions())
    with s:
        s.run_sampler(_random)
    assert [t.state.name for t in s.trials()] == ["COMPLETE", "COMPLETE"]
    waits = [r.getMessage() for r in caplog.records if "waiting" in r.getMessage()]
    assert waits == ["waiting for 1 trial(s) running on other workers"]


def test_a_set_refused_by_a_cross_register_rule_counts_as_done(monkeypatch):
    # The first two sets of a batch of 4 break a family's rule (make_params raises): they
    # are stored as failed with their error, count toward the budget, and the progress
    # reports 3 then 4 done as the two others finish.
    from servogym.autotune import SearchSpace

    real, calls = SearchSpace.make_params, []

    def make_params(self, values):
        calls.append(1)
        if len(calls) <= 2:
            raise ValueError("ki must be 0 when kp is 0")
        return real(self, values)

    monkeypatch.setattr(SearchSpace, "make_params", make_params)
    seen = []
    s, _ = _session(4, lambda done, budget, best: seen.append(done), batch_size=4)
    with s:
        s.run_sampler(_random)
    trials = s.trials()
    assert [t.state.name for t in trials] == ["FAIL", "FAIL", "COMPLETE", "COMPLETE"]
    assert all(t.user_attrs["error"] == "ki must be 0 when kp is 0" for t in trials[:2])
    assert seen == [0, 3, 4, 4] and s.n_done == 4


def test_a_worker_giving_a_warm_start_to_a_study_started_without_one_is_refused():
    problem = short_problem()
    warm = register_values(problem.scenario.default_params())
    storage = optuna.storages.InMemoryStorage()
    kw = {"budget": 4, "storage": storage, "study_name": "w", "tuner_name": "random"}
    Session(problem, **kw)
    with pytest.raises(TuneError, match=r"Differences: warm_start: stored None, now \{'kp': "):
        Session(problem, load_if_exists=True, warm_start=warm, **kw)


@pytest.mark.parametrize(
    "content",
    [b"garbage\n", b'{"a": 1}\n', b"\x00\x01binary", b'{"op_code": 0'],
    ids=["text", "json-not-journal", "binary", "truncated-first-line"],
)
def test_a_file_that_is_no_journal_is_refused_and_left_as_it_was(tmp_path, content):
    # A plain path is a journal file. An existing file that is not one (a parameter file
    # given by mistake, a truncated journal) is refused before anything is appended to it.
    from servogym.autotune._session import TuneError, open_storage

    path = tmp_path / "params.json"
    path.write_bytes(content)
    with pytest.raises(TuneError, match=r"not an Optuna journal file.*nothing was written"):
        open_storage(str(path))
    assert path.read_bytes() == content


def test_a_folder_is_no_journal_file(tmp_path):
    from servogym.autotune._session import TuneError, open_storage

    with pytest.raises(TuneError, match="it is a folder"):
        open_storage(str(tmp_path))
    assert list(tmp_path.iterdir()) == []


def test_an_empty_or_missing_file_is_a_new_journal(tmp_path):
    from servogym.autotune._session import open_storage

    (tmp_path / "empty.journal").write_bytes(b"")
    for name in ("empty.journal", "new.journal"):
        storage = open_storage(str(tmp_path / name))
        assert storage.get_all_studies() == []
