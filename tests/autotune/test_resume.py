"""Studies persist; a killed or interrupted worker loses no trial, and none is evaluated twice."""

from __future__ import annotations

import os
import pathlib
import signal
import subprocess
import sys
import time

import optuna
import pytest

from servogym.autotune import TuneError, run_study
from servogym.autotune._session import counts_toward_budget

from .helpers import short_problem, trial_table

ROOT = str(pathlib.Path(__file__).resolve().parents[2])

WORKER = """
import sys
sys.path.insert(0, {root!r})
import servogym.autotune._session as session
session.HEARTBEAT_INTERVAL_S, session.GRACE_PERIOD_S = 1, 2
from tests.autotune.helpers import short_problem
from servogym.autotune import run_study
run_study(short_problem(seed=7), "tpe", {budget}, storage={url!r}, study_name="kill",
          n_workers=2, batch_size=8, resume={resume})
"""


def load(url: str) -> list:
    from servogym.autotune._session import open_storage

    return optuna.load_study(study_name="kill", storage=open_storage(url)).get_trials()


def n_complete(url: str) -> int:
    try:
        return sum(t.state.name == "COMPLETE" for t in load(url))
    except Exception:  # not created yet
        return 0


@pytest.fixture
def short_heartbeat(monkeypatch):
    import servogym.autotune._session as session

    monkeypatch.setattr(session, "HEARTBEAT_INTERVAL_S", 1)
    monkeypatch.setattr(session, "GRACE_PERIOD_S", 2)


@pytest.mark.parametrize("kind", ["journal", "sqlite"])
def test_a_killed_worker_loses_nothing_its_running_trials_are_retried(
    tmp_path, kind, short_heartbeat
):
    budget = 48
    url = str(tmp_path / "study.journal") if kind == "journal" else f"sqlite:///{tmp_path}/s.db"
    proc = subprocess.Popen(
        [sys.executable, "-c", WORKER.format(root=ROOT, budget=budget, url=url, resume=False)],
        stdout=subprocess.PIPE, stderr=subprocess.PIPE,
    )  # fmt: skip
    deadline = time.monotonic() + 240
    while n_complete(url) < 13 and proc.poll() is None and time.monotonic() < deadline:
        time.sleep(0.05)
    assert proc.poll() is None, "the worker ended before it could be killed"
    os.kill(proc.pid, signal.SIGKILL)  # no chance to clean up
    proc.wait(timeout=30)
    assert proc.returncode == -signal.SIGKILL

    before = load(url)
    done = [t for t in before if t.state.name == "COMPLETE"]
    running = [t for t in before if t.state.name == "RUNNING"]
    assert 13 <= len(done) < budget and len(done) + len(running) == len(before)

    resumed = run_study(
        short_problem(seed=7), "tpe", budget, storage=url, study_name="kill",
        n_workers=2, batch_size=8, resume=True,
    )  # fmt: skip
    after = load(url)
    assert [t.number for t in resumed.trials] == [t.number for t in after]
    counted = [t for t in after if counts_toward_budget(t)]
    assert len(counted) == budget  # the budget is exact
    assert all(t.state.name == "COMPLETE" for t in counted)
    by_number = {t.number: t for t in after}
    for old in done:  # kept, not re-run
        assert by_number[old.number].datetime_complete == old.datetime_complete
        assert trial_table([by_number[old.number]]) == trial_table([old])
    for old in running:  # failed for the dead worker, then evaluated once with its parameters
        assert by_number[old.number].state.name == "FAIL"
        (retry,) = [t for t in counted if t.system_attrs.get("failed_trial") == old.number]
        # (a trial killed before its parameters were written is asked anew; one killed while
        # they were written keeps those written, and the rest are sampled)
        assert old.params.items() <= retry.params.items()
        assert set(retry.params) == set(counted[0].params)
    params = [tuple(sorted(t.params.items())) for t in counted]
    assert len(set(params)) == len(params)  # no parameter set evaluated twice


class Interrupt(Exception):
    pass


def test_an_interrupted_classical_run_resumes_to_the_same_study(tmp_path):
    url = f"sqlite:///{tmp_path / 'study.db'}"
    problem = short_problem(seed=2)

    def stop_after_five(done, budget, best):
        if done >= 5:
            raise KeyboardInterrupt

    with pytest.raises(KeyboardInterrupt):
        run_study(problem, "model-based", 12, storage=url, progress=stop_after_five)
    resumed = run_study(problem, "model-based", 12, storage=url, resume=True)
    full = run_study(problem, "model-based", 12, storage=None)
    assert trial_table(resumed.trials) == trial_table(full.trials)
    assert resumed.best_values == full.best_values


@pytest.mark.parametrize("tuner", ["sobol", "tpe"])
def test_an_interrupted_sampler_requeues_its_trials_and_a_resume_evaluates_them(tmp_path, tuner):
    url = str(tmp_path / "study.journal")
    problem = short_problem(seed=2)

    def stop_after_five(done, budget, best):
        if done >= 5:
            raise KeyboardInterrupt

    with pytest.raises(KeyboardInterrupt):
        run_study(problem, tuner, 16, storage=url, batch_size=4, progress=stop_after_five)
    from servogym.autotune._session import open_storage

    stopped = optuna.load_study(study_name="servogym", storage=open_storage(url)).get_trials()
    failed = [t for t in stopped if t.state.name == "FAIL"]
    queued = [t for t in stopped if t.state.name == "WAITING"]
    assert failed and len(queued) == len(failed)  # re-queued at once, no heartbeat wait
    assert not [t for t in stopped if t.state.name == "RUNNING"]
    resumed = run_study(problem, tuner, 16, storage=url, resume=True)
    counted = [t for t in resumed.trials if counts_toward_budget(t)]
    assert len(counted) == 16 and all(t.state.name == "COMPLETE" for t in counted)
    for f in failed:
        (retry,) = [t for t in counted if t.system_attrs.get("failed_trial") == f.number]
        assert retry.params == f.params


def test_resume_refuses_what_it_cannot_continue(tmp_path):
    url = f"sqlite:///{tmp_path / 'study.db'}"
    problem = short_problem(seed=2)
    with pytest.raises(TuneError, match="nothing to resume"):
        run_study(problem, "tpe", 4, storage=url, resume=True)
    run_study(problem, "tpe", 4, storage=url, batch_size=4)
    with pytest.raises(TuneError, match=r"already exists.*pass --resume"):
        run_study(problem, "tpe", 4, storage=url)
    with pytest.raises(TuneError, match=r"other settings.*seed: stored 2, now 3"):
        run_study(short_problem(seed=3), "tpe", 8, storage=url, resume=True)
    with pytest.raises(TuneError, match="tuner: stored 'tpe', now 'random'"):
        run_study(problem, "random", 8, storage=url, resume=True)
    with pytest.raises(TuneError, match="holds 4 trials, more than budget=3"):
        run_study(problem, "tpe", 3, storage=url, resume=True)
    more = run_study(problem, "tpe", 8, storage=url, resume=True)  # a larger budget continues
    assert len(more.trials) == 8
