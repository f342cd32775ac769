"""servobench on Dask distributed (issue 20): ``run_jobs(..., scheduler=)`` and
``servogym benchmark --scheduler``.

A LocalCluster of two worker processes (one thread each) runs a small benchmark (2 instances x
2 tuners x 2 seeds, budget 2): the records stored equal the in-process run's cell for cell
(timing fields aside); a worker killed mid-run loses nothing and stores nothing twice; an
interrupted run resumed with ``--scheduler`` runs only the missing jobs.
"""

from __future__ import annotations

import json
import math
import os
import signal
from pathlib import Path

import pytest
from distributed import Client, LocalCluster
from typer.testing import CliRunner

from servogym.autotune.bench import _runner, get_suite, pack_results, plan_jobs, run_jobs
from servogym.autotune.bench._runner import (
    RUNS_FILE,
    ClusterError,
    Job,
    check_scheduler_address,
    check_workers,
    compute_job,
    environment,
    load_job,
    store_record,
)
from servogym.cli import app

SUITE_NAME = "servobench-v0"
SUITE = get_suite(SUITE_NAME)
IDS = SUITE.ids("train")[:2]
TUNERS = ["random", "cmaes"]
BUDGET = 2
SEEDS = [0, 1]
TIMING = ("wall_s", "t", "check_s")
"""Fields that measure time: the only ones that may differ between two runs of a job."""


def _jobs() -> list[Job]:
    jobs, skipped = plan_jobs([SUITE.instance(i) for i in IDS], TUNERS, [BUDGET], SEEDS)
    assert len(jobs) == len(IDS) * len(TUNERS) * len(SEEDS) and not skipped
    return jobs


def _stored(out: Path) -> dict[str, dict]:
    """The records of ``out/runs.jsonl`` by job key, timing fields removed; every job once."""
    pack_results(out)
    lines = (out / RUNS_FILE).read_text().splitlines()
    recs = {}
    for line in lines:
        rec = json.loads(line)
        key = Job(rec["tuner"], rec["instance"], rec["seed"], rec["budget"]).key
        assert key not in recs, f"{key} stored twice"
        recs[key] = {k: v for k, v in rec.items() if k not in TIMING}
    return recs


@pytest.fixture(scope="module")
def cluster():
    with LocalCluster(
        n_workers=2, threads_per_worker=1, processes=True, dashboard_address=None
    ) as c:
        yield c


@pytest.fixture(scope="module")
def in_process(tmp_path_factory) -> dict[str, dict]:
    out = tmp_path_factory.mktemp("in-process")
    jobs = _jobs()
    assert run_jobs(jobs, out) == (len(jobs), 0)
    recs = _stored(out)
    assert set(recs) == {j.key for j in jobs}
    # A comparison that can fail: every job has its trials, and seeds give different ones.
    for rec in recs.values():
        assert len(rec["cost"]) == BUDGET and rec["best_values"]
        assert all(c is None or math.isfinite(c) for c in rec["cost"])
    for tuner in TUNERS:
        s0, s1 = (recs[Job(tuner, IDS[0], s, BUDGET).key]["cost"] for s in SEEDS)
        assert s0 != s1
    a, b = (recs[Job(tuner, IDS[0], 0, BUDGET).key]["best_values"] for tuner in TUNERS)
    assert a != b
    return recs


# --------------------------------------------------------------------- without a cluster


def test_a_record_is_stored_once(tmp_path):
    job = Job("random", IDS[0], 0, BUDGET)
    first = {"format": _runner.FORMAT_VERSION, "tuner": job.tuner, "instance": job.instance,
             "seed": job.seed, "budget": job.budget, "cost": [1.0], "wall_s": 1.0}  # fmt: skip
    assert store_record(tmp_path, job, first) is True
    # The same job arriving again (a rerun after a worker died) leaves the first record.
    assert store_record(tmp_path, job, {**first, "cost": [2.0], "wall_s": 9.0}) is False
    assert load_job(tmp_path, job) == first
    assert [p.name for p in (tmp_path / "jobs").rglob("*") if p.is_file()] == [f"s0-b{BUDGET}.json"]
    # A damaged record is not a finished job: the next record replaces it.
    (tmp_path / "jobs" / job.key).write_text("{")
    assert load_job(tmp_path, job) is None
    assert store_record(tmp_path, job, first) is True
    assert load_job(tmp_path, job) == first


def test_a_worker_with_other_versions_refuses_the_job():
    job = Job("random", IDS[0], 0, BUDGET)
    other = {**environment(), "numba": "0.1.0"}
    with pytest.raises(ClusterError, match=r"numba .* \(benchmark process: 0\.1\.0\)"):
        compute_job(job, other)


class _Answers:
    """A stand-in for ``distributed.Client`` whose workers give fixed answers to ``run``."""

    def __init__(self, answers):
        self.answers = answers

    def run(self, function, on_error):
        assert on_error == "return"
        return self.answers

    def nthreads(self):
        return {addr: 1 for addr in self.answers}


def test_workers_that_cannot_run_the_jobs_are_named():
    good = environment()
    assert check_workers(_Answers({"tcp://a:1": good, "tcp://b:1": good})) == {
        "tcp://a:1": 1,
        "tcp://b:1": 1,
    }
    missing = ModuleNotFoundError("No module named 'servogym'")
    with pytest.raises(ClusterError, match=r"worker tcp://b:1 cannot run servogym's jobs "
                       r"\(ModuleNotFoundError: No module named 'servogym'\)"):  # fmt: skip
        check_workers(_Answers({"tcp://a:1": good, "tcp://b:1": missing}))
    other = {**good, "mujoco": "1.0.0"}
    with pytest.raises(
        ClusterError, match=r"worker tcp://a:1 has other versions .*: mujoco 1\.0\.0"
    ):
        check_workers(_Answers({"tcp://a:1": other}))


@pytest.mark.parametrize(
    "address", ["10.0.0.5:8786", "tcp://10.0.0.5", "tcp://:8786", "tcp://h:0", "tcp://h:70000",
                "nosuch://h:8786", ""],
)  # fmt: skip
def test_a_malformed_scheduler_address_is_refused(address, tmp_path):
    with pytest.raises(ValueError, match=r"SCHEME://HOST:PORT .* 1 <= PORT <= 65535"):
        check_scheduler_address(address)
    out = tmp_path / "bench"
    result = CliRunner().invoke(app, ["benchmark", "--out", str(out), "--scheduler", address])
    assert result.exit_code == 2
    assert f"got --scheduler {address!r}" in result.output
    assert not out.exists()


@pytest.mark.parametrize(
    ("extra", "match"),
    [(["--workers", "4"], "--workers 4 applies to the local process pool"),
     (["--reference"], "--scheduler applies to benchmark jobs, not to --reference")],
)  # fmt: skip
def test_scheduler_with_local_only_options_is_refused(extra, match, tmp_path):
    out = tmp_path / "bench"
    argv = ["benchmark", "--out", str(out), "--scheduler", "tcp://127.0.0.1:8786", *extra]
    result = CliRunner().invoke(app, argv)
    assert result.exit_code == 2 and match in result.output
    assert not out.exists()


def test_no_scheduler_at_the_address_is_refused_before_anything_is_written(tmp_path, monkeypatch):
    monkeypatch.setattr(_runner, "CONNECT_TIMEOUT_S", 1.0)
    out = tmp_path / "bench"
    argv = ["benchmark", "--out", str(out), "--suite", SUITE_NAME, "--tuners", "random",
            "--instance", IDS[0], "--budget", "3", "--seeds", "1",
            "--scheduler", "tcp://127.0.0.1:1"]  # fmt: skip
    result = CliRunner().invoke(app, argv)
    assert result.exit_code == 2
    assert "no Dask scheduler answered at --scheduler 'tcp://127.0.0.1:1' within 1 s" in (
        result.output
    )
    assert not out.exists()


# ------------------------------------------------------------------------ on a cluster


def test_the_cluster_stores_the_same_records_as_one_process(cluster, in_process, tmp_path):
    jobs = _jobs()
    assert run_jobs(jobs, tmp_path, scheduler=cluster.scheduler_address) == (len(jobs), 0)
    assert _stored(tmp_path) == in_process
    # Finished jobs are never run again.
    assert run_jobs(jobs, tmp_path, scheduler=cluster.scheduler_address) == (0, len(jobs))


def test_resume_with_scheduler_runs_only_the_missing_jobs(cluster, in_process, tmp_path):
    jobs = _jobs()
    stored = []

    def interrupt(job, rec, skipped):
        stored.append(job.key)
        if len(stored) == 3:
            raise KeyboardInterrupt

    with pytest.raises(KeyboardInterrupt):
        run_jobs(jobs, tmp_path, scheduler=cluster.scheduler_address, on_done=interrupt)
    files = sorted(str(p.relative_to(tmp_path / "jobs")) for p in (tmp_path / "jobs").rglob("*")
                   if p.is_file())  # fmt: skip
    assert files == sorted(stored)
    mtimes = {k: (tmp_path / "jobs" / k).stat().st_mtime_ns for k in stored}

    argv = ["benchmark", "--suite", SUITE_NAME, "--split", "train", "--tuners", ",".join(TUNERS),
            "--budget", str(BUDGET), "--seeds", str(len(SEEDS)), "--out", str(tmp_path),
            "--scheduler", cluster.scheduler_address]  # fmt: skip
    for i in IDS:
        argv += ["--instance", i]
    result = CliRunner().invoke(app, argv)
    assert result.exit_code == 0, result.output
    text = " ".join(result.output.split())  # rich wraps at the terminal's width
    assert f"{len(jobs) - 3} jobs run, 3 already finished" in text
    assert f"on the 2 worker thread(s) the Dask cluster at {cluster.scheduler_address}" in text
    assert {k: (tmp_path / "jobs" / k).stat().st_mtime_ns for k in stored} == mtimes
    assert _stored(tmp_path) == in_process
    config = json.loads((tmp_path / "config.json").read_text())
    assert config["scheduler"] == cluster.scheduler_address


def test_a_worker_killed_mid_run_loses_nothing(cluster, in_process, tmp_path):
    jobs = _jobs()
    killed: list[tuple[str, list]] = []
    with Client(cluster.scheduler_address, set_as_default=False) as client:
        pids = client.run(os.getpid)
        assert len(pids) == 2

        def kill_a_busy_worker(job, rec, skipped):
            # Once the first record is stored, kill (SIGKILL) a worker running a job.
            busy = {w: keys for w, keys in client.processing().items() if keys}
            if not killed and busy:
                addr = sorted(busy)[0]
                os.kill(pids[addr], signal.SIGKILL)
                killed.append((addr, list(busy[addr])))

        n_run, n_skipped = run_jobs(jobs, tmp_path, scheduler=client, on_done=kill_a_busy_worker)
        workers_after = set(client.scheduler_info()["workers"])
    assert killed, "no worker was running a job when the first record arrived"
    assert killed[0][0] not in workers_after  # the scheduler saw it die
    assert (n_run, n_skipped) == (len(jobs), 0)
    assert _stored(tmp_path) == in_process  # every job exactly once, the same records
