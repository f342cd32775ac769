"""Studies persist; a killed or interrupted run resumes without losing a finished trial."""

from __future__ import annotations

import os
import pathlib
import signal
import sqlite3
import subprocess
import sys
import time

import optuna
import pytest

from servogym.autotune import TuneError, run_study

from .helpers import short_problem, trial_table

ROOT = str(pathlib.Path(__file__).resolve().parents[2])

WORKER = """
import sys
sys.path.insert(0, {root!r})
from tests.autotune.helpers import short_problem
from servogym.autotune import run_study
run_study(short_problem(seed=7), "tpe", {budget}, storage={url!r}, study_name="kill",
          n_workers=2, batch_size=8, resume={resume})
"""


def n_stored(db: pathlib.Path) -> int:
    try:
        with sqlite3.connect(f"file:{db}?mode=ro", uri=True, timeout=1) as con:
            return con.execute("SELECT COUNT(*) FROM trials").fetchone()[0]
    except sqlite3.Error:
        return 0


def test_a_killed_run_resumes_keeps_every_finished_trial_and_equals_an_uninterrupted_one(
    tmp_path,
):
    budget = 96
    db = tmp_path / "study.db"
    url = f"sqlite:///{db}"
    proc = subprocess.Popen(
        [sys.executable, "-c", WORKER.format(root=ROOT, budget=budget, url=url, resume=False)],
        stdout=subprocess.PIPE, stderr=subprocess.PIPE,
    )  # fmt: skip
    deadline = time.monotonic() + 240
    while n_stored(db) < 13 and proc.poll() is None and time.monotonic() < deadline:
        time.sleep(0.02)
    assert proc.poll() is None, "the worker ended before it could be killed"
    os.kill(proc.pid, signal.SIGKILL)  # no chance to clean up
    proc.wait(timeout=30)
    assert proc.returncode == -signal.SIGKILL

    storage = optuna.storages.RDBStorage(url)
    before = optuna.load_study(study_name="kill", storage=storage).get_trials()
    assert 13 <= len(before) < budget
    assert all(t.state.name == "COMPLETE" for t in before)
    assert [t.number for t in before] == list(range(len(before)))

    resumed = run_study(
        short_problem(seed=7), "tpe", budget, storage=url, study_name="kill",
        n_workers=2, batch_size=8, resume=True,
    )  # fmt: skip
    after = optuna.load_study(study_name="kill", storage=storage).get_trials()
    assert len(after) == len(resumed.trials) == budget
    assert trial_table(after[: len(before)]) == trial_table(before)  # nothing lost or changed
    for old, new in zip(before, after, strict=False):
        assert old.datetime_complete == new.datetime_complete  # kept, not re-run
    uninterrupted = run_study(
        short_problem(seed=7), "tpe", budget, storage=None, n_workers=1, batch_size=8
    )
    assert trial_table(after) == trial_table(uninterrupted.trials)


class Interrupt(Exception):
    pass


@pytest.mark.parametrize("tuner", ["model-based", "sobol"])
def test_an_interrupted_run_resumes_to_the_same_study(tmp_path, tuner):
    url = f"sqlite:///{tmp_path / 'study.db'}"
    problem = short_problem(seed=2)

    def stop_after_five(done, budget, best):
        if done >= 5:
            raise KeyboardInterrupt

    with pytest.raises(KeyboardInterrupt):
        run_study(problem, tuner, 12, storage=url, batch_size=4, progress=stop_after_five)
    resumed = run_study(problem, tuner, 12, storage=url, resume=True)
    full = run_study(problem, tuner, 12, storage=None, batch_size=4)
    assert trial_table(resumed.trials) == trial_table(full.trials)
    assert resumed.best_values == full.best_values


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
