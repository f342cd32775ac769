"""Several worker processes share one study: the budget is the study's, nothing is lost or
evaluated twice, on a journal file, SQLite and a real PostgreSQL server."""

from __future__ import annotations

import json
import pathlib
import subprocess
import sys

import optuna
import pytest

from servogym.autotune import TuneError, run_study
from servogym.autotune._session import counts_toward_budget, open_storage

from .helpers import short_problem

ROOT = str(pathlib.Path(__file__).resolve().parents[2])

WORKER = """
import json, sys
sys.path.insert(0, {root!r})
from tests.autotune.helpers import short_problem
from servogym.autotune import run_study
r = run_study(short_problem(seed=11), "tpe", {budget}, storage={url!r}, study_name="shared",
              n_workers=1, batch_size=4, load_if_exists=True)
print(json.dumps({{"best": r.best.number, "values": r.best_values}}))
"""


def run_workers(url: str, budget: int, n: int = 3) -> list[dict]:
    procs = [
        subprocess.Popen(
            [sys.executable, "-c", WORKER.format(root=ROOT, budget=budget, url=url)],
            stdout=subprocess.PIPE,
            stderr=subprocess.PIPE,
            text=True,
        )
        for _ in range(n)
    ]
    outs = []
    for p in procs:
        out, err = p.communicate(timeout=600)
        assert p.returncode == 0, err[-2000:]
        outs.append(json.loads(out.strip().splitlines()[-1]))
    return outs


def check_study(url: str, budget: int, outs: list[dict]) -> None:
    trials = optuna.load_study(study_name="shared", storage=open_storage(url)).get_trials()
    counted = [t for t in trials if counts_toward_budget(t)]
    assert len(counted) == budget
    assert sum(t.state.name == "COMPLETE" for t in trials) == budget
    assert all(t.state.name == "COMPLETE" for t in counted)
    for t in trials:  # the only other trials: asked in a race for the last evaluation
        assert counts_toward_budget(t) or t.user_attrs.get("over_budget") is True
    params = [tuple(sorted(t.params.items())) for t in counted]
    assert len(set(params)) == len(params)  # no set evaluated twice
    # every worker waited for the others and reports the study's one best trial
    assert len({o["best"] for o in outs}) == 1
    assert len({json.dumps(o["values"], sort_keys=True) for o in outs}) == 1


def test_three_workers_share_one_journal_file(tmp_path):
    url = str(tmp_path / "study.journal")
    outs = run_workers(url, 40)
    check_study(url, 40, outs)


def test_three_workers_share_one_sqlite_study(tmp_path):
    url = f"sqlite:///{tmp_path / 'study.db'}"
    outs = run_workers(url, 30)
    check_study(url, 30, outs)


def test_three_workers_share_one_postgresql_study(postgres_url):
    outs = run_workers(postgres_url, 30)
    check_study(postgres_url, 30, outs)


def test_a_worker_with_other_settings_or_a_classical_tuner_cannot_join(tmp_path):
    url = str(tmp_path / "study.journal")
    run_study(short_problem(seed=1), "random", 4, storage=url, study_name="s")
    with pytest.raises(TuneError, match=r"other settings.*seed: stored 1, now 2"):
        run_study(short_problem(seed=2), "random", 8, storage=url, study_name="s",
                  load_if_exists=True)  # fmt: skip
    more = run_study(short_problem(seed=1), "random", 8, storage=url, study_name="s",
                     load_if_exists=True)  # fmt: skip
    assert len(more.trials) == 8
    run_study(short_problem(seed=1), "model-based", 7, storage=url, study_name="c")
    with pytest.raises(TuneError, match="sequential procedure and cannot share"):
        run_study(short_problem(seed=1), "model-based", 9, storage=url, study_name="c",
                  load_if_exists=True)  # fmt: skip


@pytest.mark.parametrize(
    ("url", "message"),
    [
        ("nosuchdb://x/y", "cannot open the study storage 'nosuchdb://x/y': "),
        (
            "postgresql://u:secret@127.0.0.1:1/db",
            "cannot open the study storage 'postgresql://u:\\*\\*\\*@127.0.0.1:1/db': ",
        ),
        ("sqlite:////no/such/folder/study.db", "cannot open the study storage "),
        ("/no/such/folder/study.journal", "the folder '/no/such/folder' does not exist"),
    ],
)
def test_bad_or_unreachable_storages_give_one_line_errors(url, message):
    with pytest.raises(TuneError, match=message) as info:
        open_storage(url)
    assert "\n" not in str(info.value)
    assert "secret" not in str(info.value)


def test_the_cli_reports_a_bad_storage_in_one_line(tmp_path):
    out = subprocess.run(
        [sys.executable, "-m", "servogym", "tune", "--chip", "MC2100", "--plant", "rotary",
         "--budget", "4", "--out", str(tmp_path / "r"), "--storage", "nosuchdb://x"],
        capture_output=True, text=True, timeout=300,
    )  # fmt: skip
    assert out.returncode == 2
    lines = [line for line in (out.stdout + out.stderr).splitlines() if line.strip()]
    assert lines == ["error: --storage 'nosuchdb://x' cannot be opened as a study: "
                     + lines[0].split(": ", 2)[2]]  # fmt: skip
    assert "nosuchdb" in lines[0].split(": ", 2)[2]  # the driver's reason
