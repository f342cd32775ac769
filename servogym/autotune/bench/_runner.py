"""Run tuners on the instances of a suite: tuner x instance x seed jobs in a process pool
or on a Dask cluster.

Each job (a cell of the benchmark) runs one study through :func:`servogym.autotune.run_study`
(in memory, one evaluation thread, batches of one trial: every sampler sees every result
before it asks again) and returns one compact record with every trial's cost, safety flags
and time. The process that runs the benchmark (never a worker) stores each record, as it
arrives, in one file named by the job's key, written once: a finished job's file exists, a
rerun skips it, so an interrupted benchmark resumes where it stopped and, the studies being
deterministic, ends with the same results.

Where the jobs run: in this process (``workers=1``), in a local process pool (``workers``
processes), or on an existing Dask cluster (``scheduler``: the address ``dask scheduler``
prints). Dask reruns the job of a worker that dies on another worker; its record still
arrives once, and is stored once.

Anytime results (as COCO): the Optuna samplers never look at the total budget, so one run at
the largest budget gives the best-so-far at every smaller budget exactly. The classical
procedures plan with their budget, so they run once per budget. They use no random numbers,
so one run (seed 0) stands for every seed.
"""

from __future__ import annotations

import concurrent.futures as cf
import contextlib
import dataclasses
import functools
import json
import multiprocessing
import os
import time
import uuid
from collections.abc import Callable, Iterator, Mapping, Sequence
from pathlib import Path
from typing import Any

ANYTIME_TUNERS = ("safe", "tpe", "gp", "cmaes", "random", "sobol")
"""Tuners whose trial n does not depend on the budget (one run serves every budget: the
smaller budgets are the prefix of the largest run; tested for each)."""

DETERMINISTIC_TUNERS = ("vendor-step", "relay", "model-based")
"""Tuners that use no seed (one run stands for every seed)."""

FLAG_DIVERGED = 1
FLAG_FOLLOWING_ERROR = 2
FLAG_SATURATION = 4
FLAG_EXPERIMENT = 8
FLAG_FAILED = 16
FLAG_MARGINS = 32
UNSAFE_FLAGS = FLAG_DIVERGED | FLAG_FOLLOWING_ERROR | FLAG_SATURATION | FLAG_MARGINS
"""A trial is unsafe (a risk on hardware) when any of these is set: it diverged or violated
a constraint the tune command sets (following error, saturation, gain or phase margin)."""

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


SAMPLER_OVERHEAD_S = {
    "tpe": 0.040, "cmaes": 0.035, "random": 0.010, "sobol": 0.010, "gp": 0.45, "safe": 0.010,
}  # fmt: skip
"""Measured seconds per trial the session and sampler add to an evaluation (2-core machine,
batches of one). GP's is constant since its history is capped (``CappedGPSampler``: 100
trials of servobench-v1/mc2100/rotary/light/fast and 6250/vertical-axis/light/fast took 58
and 33 s, about 0.3-0.55 s per trial; it grew as about 0.11 * n s at trial n before)."""


def estimate_seconds(jobs: Sequence[Job], eval_s: Mapping[str, float]) -> float:
    """CPU seconds the jobs will take, from measured seconds per evaluation of each
    instance (``eval_s``) and :data:`SAMPLER_OVERHEAD_S`; classical procedures count 3
    evaluations per trial (experiments are long) and use about a third of their budget."""
    total = 0.0
    for job in jobs:
        e = eval_s[job.instance]
        if job.tuner in SAMPLER_OVERHEAD_S:
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
            if c.get("gain_margin", 0) > 0 or c.get("phase_margin", 0) > 0:
                f |= FLAG_MARGINS
            costs.append(float(f"{t.values[0]:.6g}"))
        flags.append(f)
    return costs, flags


RESULT_PACKAGES = ("servogym", "optuna", "numpy", "scipy", "mujoco", "numba", "cmaes", "torch")
"""Packages a job's result depends on: every Dask worker must have the versions the
benchmark process has (:func:`environment`)."""


@functools.cache
def environment() -> dict[str, str]:
    """The versions a job's result depends on in this process: :data:`RESULT_PACKAGES`
    and the chip arithmetic specs (the spec version changes with any change of a chip's
    arithmetic)."""
    from importlib.metadata import PackageNotFoundError, version

    from servogym.chips.parker6k import SPEC_VERSION as PARKER6K_SPEC
    from servogym.chips.pmac import SPEC_VERSION as PMAC_SPEC
    from servogym.chips.pmd import SPEC_VERSION as PMD_SPEC

    out = {}
    for name in RESULT_PACKAGES:
        try:
            out[name] = version(name)
        except PackageNotFoundError:
            out[name] = "not installed"
    out.update(pmd_spec=PMD_SPEC, parker6k_spec=PARKER6K_SPEC, pmac_spec=PMAC_SPEC)
    out["servogym_source"] = source_digest()
    return out


@functools.cache
def source_digest() -> str:
    """SHA-256 (16 hex digits) of servogym's Python sources and package data, path by path:
    two installs of the same commit agree, an edit or another commit differs (the package
    version alone does not change between commits)."""
    import hashlib

    import servogym

    root = Path(servogym.__file__).parent
    h = hashlib.sha256()
    for path in sorted(root.rglob("*")):
        if path.suffix in (".py", ".json", ".yml") and "__pycache__" not in path.parts:
            h.update(path.relative_to(root).as_posix().encode() + b"\0")
            h.update(path.read_bytes() + b"\0")
    return h.hexdigest()[:16]


class ClusterError(RuntimeError):
    """The Dask cluster cannot run the benchmark: no scheduler at the address, a worker
    without servogym or with other versions, or a job that failed or killed its workers."""


def _version_diff(expected: Mapping[str, str], found: Mapping[str, str]) -> str:
    """``"numba 0.60.0 (benchmark process: 0.61.0); ..."``, or ``""`` when equal."""
    return "; ".join(f"{k} {found.get(k)} (benchmark process: {v})"
                     for k, v in expected.items() if found.get(k) != v)  # fmt: skip


def _mismatch(where: str, diff: str) -> ClusterError:
    return ClusterError(
        f"{where} has other versions than the benchmark process, so its results would not "
        f"be comparable: {diff}. Install the same servogym and packages on every worker "
        "(docs/benchmark.md, 'On several machines')."
    )


ONE_THREAD_ENV = {"OMP_NUM_THREADS": "1", "OPENBLAS_NUM_THREADS": "1", "MKL_NUM_THREADS": "1"}
"""Environment of the benchmark's worker processes: one BLAS thread each. The margin analysis
takes eigenvalues of matrices up to order 160; with one process per core, OpenBLAS's own
threads only contend (measured: ``eigvals`` 0.49 s a call on the loaded 2-core machine, a
third of an evaluation's time, against a few ms on one thread)."""


@contextlib.contextmanager
def one_blas_thread() -> Iterator[None]:
    """Set :data:`ONE_THREAD_ENV` (unless already set) while worker processes start, then
    restore this process's environment. (Dask's nanny starts its worker processes with the
    same three variables at 1: ``distributed.nanny.pre-spawn-environ``.)"""
    saved = {k: os.environ.get(k) for k in ONE_THREAD_ENV}
    for k, v in ONE_THREAD_ENV.items():
        os.environ.setdefault(k, v)
    try:
        yield
    finally:
        for k, v in saved.items():
            if v is None:
                os.environ.pop(k, None)
            else:
                os.environ[k] = v


def compute_job(job: Job, expected: Mapping[str, str] | None = None) -> dict[str, Any]:
    """Run one job and return its record (nothing is written: see :func:`store_record`).

    Args:
        job: The job.
        expected: On a Dask worker, the benchmark process's :func:`environment`; a worker
            whose versions differ raises :class:`ClusterError` instead of running.
    """
    import warnings

    if expected is not None and (diff := _version_diff(expected, environment())):
        import socket

        raise _mismatch(f"Dask worker on {socket.gethostname()}", diff)

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
            wall = round(time.perf_counter() - t0, 3)
            record.update(
                wall_s=wall,
                cost=costs,
                flags=flags,
                t=stamps[: len(costs)],
                best_values=result.best_values,
                best_feasible=result.feasible,
                checked=checked_results(problem, result.trials, costs, flags, job.budget),
                check_s=round(time.perf_counter() - t0 - wall, 3),
            )
    return record


CHECK_BUDGETS = (20, 50, 100, 200)
"""The budgets whose result a job checks (with the job's own budget): a result is reported
as ``servogym tune`` would write it, the cheapest safe trial within the budget that passes
the check (:func:`checked_results`)."""

MAX_CHECKS = 10
"""Trials checked at most per budget, cheapest first (``servogym tune`` checks up to 30)."""


def checked_results(
    problem: Any, trials: Sequence[Any], costs: Sequence[float | None],
    flags: Sequence[int], budget: int,
) -> dict[str, dict[str, Any] | None]:  # fmt: skip
    """For each budget of :data:`CHECK_BUDGETS` below ``budget`` and ``budget`` itself: the
    cheapest safe trial among the first ``b`` evaluations that passes the check
    (``servogym.sim.check_params`` on the problem's scenario: the reference integration,
    every loop latency, load and friction spreads), as ``{"trial": index, "cost": cost,
    "values": registers}``,
    or ``None`` when none of the :data:`MAX_CHECKS` cheapest passes; a larger budget keeps the
    smaller one's result when none of its cheaper trials passes. Each trial is checked once,
    whatever the number of budgets it is cheapest in."""
    from servogym.sim._check import check_params

    verdicts: dict[int, bool] = {}
    out: dict[str, dict[str, Any] | None] = {}
    previous: dict[str, Any] | None = None  # a larger budget never reports a worse result
    for b in sorted({x for x in CHECK_BUDGETS if x < budget} | {budget}):
        ranked = sorted(
            (c, i) for i, (c, f) in enumerate(zip(costs[:b], flags[:b], strict=True))
            if c is not None and f & (UNSAFE_FLAGS | FLAG_EXPERIMENT | FLAG_FAILED) == 0
        )  # fmt: skip
        out[str(b)] = previous
        for c, i in ranked[:MAX_CHECKS]:
            if previous is not None and c >= previous["cost"]:
                break  # the smaller budget's result is as cheap
            values = {k: int(v) for k, v in trials[i].user_attrs["registers"].items()}
            if i not in verdicts:
                params = problem.space.make_params(values)
                verdicts[i] = check_params(params, problem.scenario).passed
            if verdicts[i]:
                out[str(b)] = previous = {"trial": i, "cost": c, "values": values}
                break
    return out


def store_record(out_dir: str | Path, job: Job, record: Mapping[str, Any]) -> bool:
    """Write a finished job's record to ``out_dir/jobs/<job.key>``, once.

    The file appears whole or not at all (written aside, then linked into place). A job
    that already has a valid record (in ``runs.jsonl`` or ``jobs/``, e.g. a job that ran
    twice) keeps it: nothing is written and the answer is ``False``. A damaged record is
    replaced.

    Returns:
        Whether this call stored the record.
    """
    if load_job(out_dir, job) is not None:
        return False
    path = Path(out_dir) / "jobs" / job.key
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = path.with_suffix(f".tmp{os.getpid()}-{uuid.uuid4().hex[:8]}")
    tmp.write_text(json.dumps(record, separators=(",", ":")))
    try:
        if path.exists():  # damaged (load_job refused it): replace it
            os.replace(tmp, path)
        else:
            try:  # exclusive: of two processes storing the same job, one wins
                os.link(tmp, path)
            except FileExistsError:
                return False
            except OSError:  # a file system without hard links
                os.replace(tmp, path)
    finally:
        tmp.unlink(missing_ok=True)
    return True


def run_job(job: Job, out_dir: str) -> dict[str, Any]:
    """Run one job and store its record (:func:`store_record`); returns the record."""
    record = compute_job(job)
    store_record(out_dir, job, record)
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
    scheduler: str | Any | None = None,
    on_done: Callable[[Job, dict[str, Any] | None, bool], None] | None = None,
) -> tuple[int, int]:
    """Run the jobs that have no stored record yet, longest first, and store each record
    in this process as it arrives (:func:`store_record`: once per job).

    Args:
        jobs: The jobs.
        out_dir: Output folder (records under ``out_dir/jobs``).
        workers: Local processes (1: in this process). Must be 1 with ``scheduler``.
        scheduler: Run the jobs on this Dask cluster instead: the scheduler's address
            (``tcp://HOST:8786``) or a connected ``distributed.Client``. Every worker needs
            servogym and the versions of :data:`RESULT_PACKAGES` this process has.
        on_done: Called as ``on_done(job, record, skipped)`` for each job (``record`` is
            ``None`` for a skipped job).

    Returns:
        (jobs run and stored now, jobs skipped because already finished).

    Raises:
        ClusterError: The cluster cannot run the jobs (see :class:`ClusterError`).
    """
    if scheduler is not None and workers != 1:
        raise ValueError(
            f"workers applies to the local process pool; with a Dask scheduler the cluster's "
            f"workers run the jobs (dask worker --nworkers N); got workers={workers}."
        )
    out_dir = str(out_dir)
    todo: dict[str, Job] = {}
    n_skipped = 0
    for job in jobs:
        if load_job(out_dir, job) is not None:
            n_skipped += 1
            if on_done is not None:
                on_done(job, None, True)
        else:
            todo.setdefault(job.key, job)
    ordered = sorted(todo.values(), key=_cost_weight, reverse=True)
    counts = [0, n_skipped]

    def arrived(job: Job, rec: dict[str, Any]) -> None:
        stored = store_record(out_dir, job, rec)
        counts[0 if stored else 1] += 1
        if on_done is not None:
            on_done(job, rec if stored else None, not stored)

    if scheduler is not None:
        if ordered:
            _run_on_cluster(ordered, scheduler, arrived)
    elif workers <= 1:
        for job in ordered:
            arrived(job, compute_job(job))
    else:
        ctx = multiprocessing.get_context("spawn")
        with one_blas_thread(), cf.ProcessPoolExecutor(workers, mp_context=ctx) as pool:
            futures = {pool.submit(compute_job, job): job for job in ordered}
            taken: set[Any] = set()
            try:
                for fut in cf.as_completed(futures):
                    taken.add(fut)
                    arrived(futures[fut], fut.result())
            except BaseException:
                for fut in futures:
                    fut.cancel()
                # the running jobs finish (the pool waits for them anyway) and, with those that
                # finished meanwhile, are stored, not lost (a resume would rerun them)
                cf.wait(futures)
                for fut in futures:
                    finished = fut.done() and not fut.cancelled() and fut.exception() is None
                    if fut not in taken and finished:
                        arrived(futures[fut], fut.result())
                raise
    return counts[0], counts[1]


# ------------------------------------------------------------------------- Dask cluster

CONNECT_TIMEOUT_S = 10.0
"""Seconds to wait for the Dask scheduler to answer."""


def check_scheduler_address(address: str) -> str:
    """``address`` if it has the form of a Dask scheduler's address, ``SCHEME://HOST:PORT``
    with a scheme Dask knows (tcp, tls, ...); otherwise ``ValueError`` saying so."""
    from distributed.comm.registry import backends

    schemes = sorted(s for s in backends if s != "inproc")
    scheme, sep, loc = address.partition("://")
    host, colon, port = loc.rpartition(":")
    if (
        not sep
        or scheme not in schemes
        or not colon
        or not host
        or not port.isdigit()
        or not 1 <= int(port) <= 65535
    ):
        raise ValueError(
            "--scheduler takes the address `dask scheduler` prints, SCHEME://HOST:PORT with "
            f"SCHEME one of {', '.join(schemes)} and 1 <= PORT <= 65535 (e.g. "
            f"tcp://10.0.0.5:8786); got --scheduler {address!r}."
        )
    return address


def connect(address: str, timeout: float | None = None) -> Any:
    """A ``distributed.Client`` connected to the scheduler at ``address``.

    Args:
        address: The scheduler's address, ``SCHEME://HOST:PORT``.
        timeout: Seconds to wait for the scheduler (``None``: :data:`CONNECT_TIMEOUT_S`).

    Raises:
        ValueError: The address is malformed (:func:`check_scheduler_address`).
        ClusterError: No scheduler answered within ``timeout`` seconds.
    """
    from distributed import Client

    check_scheduler_address(address)
    timeout = CONNECT_TIMEOUT_S if timeout is None else timeout
    try:
        return Client(address, timeout=timeout, set_as_default=False)
    except (OSError, TimeoutError) as exc:
        raise ClusterError(
            f"no Dask scheduler answered at --scheduler {address!r} within {timeout:g} s "
            f"({exc}); start one with `dask scheduler` and pass the address it prints."
        ) from None


def _worker_environment() -> dict[str, str]:
    return environment()


def check_workers(client: Any) -> dict[str, int]:
    """Check that every worker now in the cluster can run the jobs (servogym importable,
    the versions of :func:`environment` equal to this process's); workers that join later
    are checked by each job they run.

    Returns:
        ``{worker address: threads}``.

    Raises:
        ClusterError: A worker cannot import servogym or has other versions.
    """
    expected = environment()
    found = client.run(_worker_environment, on_error="return")
    for addr, env in sorted(found.items()):
        if isinstance(env, BaseException):
            raise ClusterError(
                f"Dask worker {addr} cannot run servogym's jobs ({type(env).__name__}: {env}); "
                "every worker needs servogym installed, with the versions the benchmark "
                "process has (docs/benchmark.md, 'On several machines')."
            )
        diff = _version_diff(expected, env)
        if diff:
            raise _mismatch(f"Dask worker {addr}", diff)
    return dict(client.nthreads())


def _run_on_cluster(
    jobs: Sequence[Job], scheduler: str | Any, arrived: Callable[[Job, dict[str, Any]], None]
) -> None:
    """Submit ``jobs`` to the Dask cluster (highest priority first) and hand each record to
    ``arrived`` as its job completes, in this process."""
    from distributed import as_completed

    owned = isinstance(scheduler, str)
    client = connect(scheduler) if owned else scheduler
    futures: dict[Any, Job] = {}
    taken: set[Any] = set()
    try:
        check_workers(client)
        expected = environment()
        token = uuid.uuid4().hex[:8]  # this run's tasks: never shared with another client's
        for rank, job in enumerate(jobs):
            fut = client.submit(compute_job, job, expected, key=f"servogym-job-{token}-{job.key}",
                                priority=len(jobs) - rank)  # fmt: skip
            futures[fut] = job
        for fut in as_completed(list(futures), loop=client.loop):
            job = futures[fut]
            taken.add(fut)
            if fut.status != "finished":
                raise _job_error(job, fut)
            rec = fut.result()
            fut.release()
            arrived(job, rec)
    except BaseException:
        # jobs that finished meanwhile are stored, not lost (a resume would rerun them)
        for fut, job in futures.items():
            if fut not in taken and fut.status == "finished":
                arrived(job, fut.result())
        raise
    finally:
        pending = [f for f in futures if not f.done()]
        if pending:
            client.cancel(pending)
        if owned:
            client.close()


def _job_error(job: Job, fut: Any) -> ClusterError:
    if fut.status != "error":  # cancelled or lost: the scheduler or the connection went away
        return ClusterError(
            f"job {job.key} was {fut.status} on the Dask cluster (the scheduler stopped, or "
            "the connection to it was lost); the records stored so far stay: run the same "
            "command again to resume."
        )
    exc = fut.exception()
    if isinstance(exc, ClusterError):
        return exc
    text = f"job {job.key} failed on the Dask cluster: {type(exc).__name__}: {exc}"
    if isinstance(exc, ImportError):
        text += "; every worker needs servogym installed (docs/benchmark.md)"
    elif type(exc).__name__ == "KilledWorker":
        text += ("; the job's workers died in turn (distributed.scheduler.allowed-failures); "
                 "their logs say why (memory?)")  # fmt: skip
    err = ClusterError(text)
    err.__cause__ = exc
    return err
