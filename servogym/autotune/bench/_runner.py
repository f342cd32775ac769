"""Run tuners on the instances of a suite: tuner x instance x seed jobs in a process pool.

Each job runs one study through :func:`servogym.autotune.run_study` (in memory, one
evaluation thread, batches of one trial: every sampler sees every result before it asks
again) and writes one compact JSON file with every trial's cost, safety flags and time. A
finished job's file exists; a rerun skips it, so an interrupted benchmark resumes where it
stopped and, the studies being deterministic, ends with the same results.

Anytime results (as COCO): the Optuna samplers never look at the total budget, so one run at
the largest budget gives the best-so-far at every smaller budget exactly. The classical
procedures plan with their budget, so they run once per budget. They use no random numbers,
so one run (seed 0) stands for every seed.
"""

from __future__ import annotations

import concurrent.futures as cf
import dataclasses
import functools
import json
import multiprocessing
import os
import time
from collections.abc import Callable, Mapping, Sequence
from pathlib import Path
from typing import Any

ANYTIME_TUNERS = ("tpe", "gp", "cmaes", "random", "sobol")
"""Tuners whose trial n does not depend on the budget (one run serves every budget)."""

DETERMINISTIC_TUNERS = ("vendor-step", "relay", "model-based")
"""Tuners that use no seed (one run stands for every seed)."""

FLAG_DIVERGED = 1
FLAG_FOLLOWING_ERROR = 2
FLAG_SATURATION = 4
FLAG_EXPERIMENT = 8
FLAG_FAILED = 16
UNSAFE_FLAGS = FLAG_DIVERGED | FLAG_FOLLOWING_ERROR | FLAG_SATURATION
"""A trial is unsafe (a risk on hardware) when any of these is set."""

FORMAT_VERSION = 1


@dataclasses.dataclass(frozen=True)
class Job:
    """One study: a tuner on an instance with a seed and a budget.

    Attributes:
        tuner: Tuner name.
        instance: Instance id.
        seed: Study seed.
        budget: Evaluations.
    """

    tuner: str
    instance: str
    seed: int
    budget: int

    @property
    def key(self) -> str:
        """Relative path of the job's result file."""
        inst = self.instance.replace("/", "__")
        return f"{self.tuner}/{inst}/s{self.seed}-b{self.budget}.json"


@dataclasses.dataclass(frozen=True)
class TunerLimit:
    """A reduced plan for one tuner (e.g. GP, whose trials cost seconds each).

    Attributes:
        seeds: Use only the first N seeds (``None``: all).
        budget: Largest budget run (``None``: the largest asked).
        instances: Use N instances spread evenly over the suite order (``None``: all).
    """

    seeds: int | None = None
    budget: int | None = None
    instances: int | None = None

    @classmethod
    def parse(cls, text: str) -> tuple[str, TunerLimit]:
        """``"gp:seeds=1,budget=50,instances=8"`` -> ``("gp", TunerLimit(1, 50, 8))``."""
        name, sep, rest = text.partition(":")
        kw: dict[str, int] = {}
        for item in rest.split(",") if sep else []:
            key, eq, value = item.partition("=")
            key = key.strip()
            if (
                not eq
                or key not in ("seeds", "budget", "instances")
                or not value.strip().isdigit()
                or int(value) < 1
            ):
                raise ValueError(
                    "--limit takes TUNER:seeds=N,budget=B,instances=K (any of the three, "
                    f"integers >= 1); got --limit {text!r}."
                )
            if key in kw:
                raise ValueError(f"--limit names {key} twice; got --limit {text!r}.")
            kw[key] = int(value)
        if not sep or not kw or not name.strip():
            raise ValueError(
                f"--limit takes TUNER:seeds=N,budget=B,instances=K; got --limit {text!r}."
            )
        return name.strip(), cls(**kw)

    def pick(self, items: Sequence[Any]) -> list[Any]:
        """``instances`` items spread evenly over ``items`` (all when not limited)."""
        n = len(items)
        if self.instances is None or self.instances >= n:
            return list(items)
        return [items[(j * n) // self.instances] for j in range(self.instances)]


def plan_jobs(
    instances: Sequence[Any],
    tuners: Sequence[str],
    budgets: Sequence[int],
    seeds: Sequence[int],
    limits: Mapping[str, TunerLimit] | None = None,
) -> tuple[list[Job], list[tuple[str, str, str]]]:
    """The jobs of a benchmark and the (tuner, instance, reason) triples that cannot run.

    Args:
        instances: :class:`BenchmarkInstance` objects.
        tuners: Tuner names.
        budgets: Budgets reported; anytime tuners run once at the largest.
        seeds: Seeds of every tuner.
        limits: Reduced plans for some tuners (:class:`TunerLimit`).
    """
    from servogym.autotune._gains import GAIN_MAPS
    from servogym.autotune._tuners import get_tuner

    jobs, skipped = [], []
    for name in tuners:
        tuner = get_tuner(name)  # raises for an unknown name, with close matches
        limit = (limits or {}).get(name, TunerLimit())
        use_seeds = list(seeds)[: limit.seeds] if limit.seeds is not None else list(seeds)
        top = max(budgets) if limit.budget is None else min(max(budgets), limit.budget)
        anytime = name in ANYTIME_TUNERS
        if name in DETERMINISTIC_TUNERS:
            use_seeds = use_seeds[:1]
        for inst in limit.pick(list(instances)):
            family = inst.problem.space.family.name
            if name in DETERMINISTIC_TUNERS and family not in GAIN_MAPS:
                skipped.append((name, inst.id, f"no gain map for chip family {family!r}"))
                continue
            run_budgets = [top] if anytime else sorted(b for b in set(budgets) if b <= top)
            for b in run_budgets:
                if b < tuner.min_budget:
                    skipped.append((name, inst.id, f"budget {b} < min_budget {tuner.min_budget}"))
                    continue
                jobs.extend(Job(name, inst.id, s, b) for s in use_seeds)
    return jobs, skipped


SAMPLER_OVERHEAD_S = {"tpe": 0.040, "cmaes": 0.035, "random": 0.010, "sobol": 0.010}
"""Measured seconds per trial the session and sampler add to an evaluation (2-core machine,
batches of one). GP grows with the trials: about 0.11 * n seconds at trial n."""


def estimate_seconds(jobs: Sequence[Job], eval_s: Mapping[str, float]) -> float:
    """CPU seconds the jobs will take, from measured seconds per evaluation of each
    instance (``eval_s``) and :data:`SAMPLER_OVERHEAD_S`; classical procedures count 3
    evaluations per trial (experiments are long) and use about a third of their budget."""
    total = 0.0
    for job in jobs:
        e = eval_s[job.instance]
        if job.tuner == "gp":
            total += job.budget * e + 0.11 * job.budget * job.budget / 2
        elif job.tuner in SAMPLER_OVERHEAD_S:
            total += job.budget * (e + SAMPLER_OVERHEAD_S[job.tuner])
        else:
            total += min(job.budget, 30) * 3 * e
    return total


def _trial_rows(trials: Sequence[Any]) -> tuple[list[float | None], list[int]]:
    costs: list[float | None] = []
    flags: list[int] = []
    for t in trials:
        f = 0
        kind = t.user_attrs.get("kind")
        if kind == "experiment":
            f |= FLAG_EXPERIMENT
            if t.user_attrs.get("experiment", {}).get("diverged"):
                f |= FLAG_DIVERGED
            costs.append(None)
        elif t.state.name != "COMPLETE":
            f |= FLAG_FAILED
            costs.append(None)
        else:
            c = t.constraints
            if c.get("diverged", 0) > 0:
                f |= FLAG_DIVERGED
            if c.get("max_following_error", 0) > 0:
                f |= FLAG_FOLLOWING_ERROR
            if c.get("saturation_fraction", 0) > 0:
                f |= FLAG_SATURATION
            costs.append(float(f"{t.values[0]:.6g}"))
        flags.append(f)
    return costs, flags


def run_job(job: Job, out_dir: str) -> dict[str, Any]:
    """Run one job and write its result file; returns the record written."""
    import warnings

    from servogym.autotune._job import run_study
    from servogym.autotune._session import TuneError
    from servogym.autotune.bench._suite import get_suite

    if job.tuner == "gp":  # one process per core: keep torch on one thread
        import torch

        torch.set_num_threads(1)
    suite_name = job.instance.split("/")[0]
    inst = get_suite(suite_name).instance(job.instance)
    problem = dataclasses.replace(inst.problem, seed=job.seed)
    stamps: list[float] = []
    t0 = time.perf_counter()

    def progress(done: int, budget: int, best: float | None) -> None:
        while len(stamps) < done:
            stamps.append(round(time.perf_counter() - t0, 4))

    record: dict[str, Any] = {
        "format": FORMAT_VERSION,
        **dataclasses.asdict(job),
        "anytime": job.tuner in ANYTIME_TUNERS,
    }
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        try:
            result = run_study(problem, job.tuner, job.budget, storage=None,
                               n_workers=1, batch_size=1, progress=progress)  # fmt: skip
        except TuneError as exc:  # a procedure that cannot tune this plant: no result
            record.update(error=str(exc), wall_s=time.perf_counter() - t0, cost=[], flags=[],
                          t=[])  # fmt: skip
        else:
            costs, flags = _trial_rows(result.trials)
            record.update(
                wall_s=round(time.perf_counter() - t0, 3),
                cost=costs,
                flags=flags,
                t=stamps[: len(costs)],
                best_values=result.best_values,
                best_feasible=result.feasible,
            )
    path = Path(out_dir) / "jobs" / job.key
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = path.with_suffix(f".tmp{os.getpid()}")
    tmp.write_text(json.dumps(record, separators=(",", ":")))
    os.replace(tmp, path)  # atomic: a killed job leaves no result file
    return record


def load_job(out_dir: str | Path, job: Job) -> dict[str, Any] | None:
    """The result of a finished job, or ``None``."""
    from servogym._input import read_json

    packed = _packed(Path(out_dir))
    if job.key in packed:
        return packed[job.key]
    path = Path(out_dir) / "jobs" / job.key
    try:  # a damaged record counts as not finished: the job runs again and replaces it
        rec = read_json(path, "a job record")
    except ValueError:
        return None
    return rec if _is_record(rec) else None


RUNS_FILE = "runs.jsonl"
"""Every job's record, one JSON line each (written by :func:`pack_results`)."""


def _packed(out_dir: Path) -> dict[str, dict[str, Any]]:
    path = out_dir / RUNS_FILE
    if not path.exists():
        return {}
    stat = path.stat()
    return _read_packed(str(path), stat.st_mtime_ns, stat.st_size)


@functools.lru_cache(maxsize=4)
def _read_packed(path: str, _mtime_ns: int, _size: int) -> dict[str, dict[str, Any]]:
    from servogym._input import InputError, parse_json, read_text

    out = {}
    text = read_text(path, "the benchmark's records", max_bytes=1 << 30)
    for n, line in enumerate(text.splitlines(), start=1):
        if line.strip():
            rec = parse_json(line, f"{path!r} line {n}")
            if not _is_record(rec):
                raise InputError(
                    f"{path!r} line {n} is not a benchmark job record (tuner, instance, seed, "
                    f"budget); remove the line or the file (its jobs then run again)."
                )
            job = Job(rec["tuner"], rec["instance"], rec["seed"], rec["budget"])
            out[job.key] = rec
    return out


def _is_record(rec: Any) -> bool:
    return (
        isinstance(rec, dict)
        and rec.get("format") == FORMAT_VERSION
        and isinstance(rec.get("tuner"), str)
        and isinstance(rec.get("instance"), str)
        and all(isinstance(rec.get(k), int) for k in ("seed", "budget"))
    )


def pack_results(out_dir: str | Path) -> Path:
    """Write every finished job's record into ``out_dir/runs.jsonl`` (sorted, one line
    each): the whole raw result of a benchmark in one file."""
    recs = load_results(out_dir)
    recs.sort(key=lambda r: (r["tuner"], r["instance"], r["seed"], r["budget"]))
    path = Path(out_dir) / RUNS_FILE
    tmp = path.with_suffix(".tmp")
    tmp.write_text("".join(json.dumps(r, separators=(",", ":")) + "\n" for r in recs))
    os.replace(tmp, path)
    return path


def load_results(out_dir: str | Path) -> list[dict[str, Any]]:
    """Every finished job's record: ``out_dir/runs.jsonl`` and ``out_dir/jobs``."""
    from servogym._input import read_json

    found = dict(_packed(Path(out_dir)))
    for path in sorted((Path(out_dir) / "jobs").rglob("*.json")):
        try:  # a damaged record is a job that has not finished (it runs again)
            rec = read_json(path, "a job record")
        except ValueError:
            continue
        if _is_record(rec):
            job = Job(rec["tuner"], rec["instance"], rec["seed"], rec["budget"])
            found[job.key] = rec
    return list(found.values())


def _cost_weight(job: Job) -> float:
    """Relative run time, for scheduling the long jobs first."""
    w = {"gp": 40.0, "tpe": 1.5, "cmaes": 1.3}.get(job.tuner, 1.0)
    return w * job.budget * (3.0 if "mc58000" in job.instance else 1.0)


def run_jobs(
    jobs: Sequence[Job],
    out_dir: str | Path,
    *,
    workers: int = 1,
    on_done: Callable[[Job, dict[str, Any] | None, bool], None] | None = None,
) -> tuple[int, int]:
    """Run the jobs that have no result file yet, longest first, in ``workers`` processes.

    Args:
        jobs: The jobs.
        out_dir: Output folder (results under ``out_dir/jobs``).
        workers: Processes (1: in this process).
        on_done: Called as ``on_done(job, record, skipped)`` for each job.

    Returns:
        (jobs run now, jobs skipped because already finished).
    """
    out_dir = str(out_dir)
    todo = []
    n_skipped = 0
    for job in jobs:
        if load_job(out_dir, job) is not None:
            n_skipped += 1
            if on_done is not None:
                on_done(job, None, True)
        else:
            todo.append(job)
    todo.sort(key=_cost_weight, reverse=True)
    if workers <= 1:
        for job in todo:
            rec = run_job(job, out_dir)
            if on_done is not None:
                on_done(job, rec, False)
        return len(todo), n_skipped
    ctx = multiprocessing.get_context("spawn")
    with cf.ProcessPoolExecutor(workers, mp_context=ctx) as pool:
        futures = {pool.submit(run_job, job, out_dir): job for job in todo}
        try:
            for fut in cf.as_completed(futures):
                rec = fut.result()
                if on_done is not None:
                    on_done(futures[fut], rec, False)
        except BaseException:
            for fut in futures:
                fut.cancel()
            raise
    return len(todo), n_skipped
