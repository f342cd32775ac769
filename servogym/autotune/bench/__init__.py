"""servobench: a versioned benchmark suite for autotuners (docs/benchmark.md).

Instances (chip model x plant x load x task, each determined by its id) are tuning problems
any optimizer can use through :class:`BenchmarkInstance` (``evaluate``, an Optuna
``__call__``, constraints); the runner benchmarks servogym's tuners on them in a process
pool, resumably; the report gives COCO-style ECDFs, relative costs, unsafe evaluations and
wall time against the best-known costs stored in ``data/<suite>.json``.

Example:
    >>> from servogym.autotune.bench import get_suite
    >>> inst = get_suite("servobench-v0").instance("servobench-v0/mc2100/rotary/light/fast")
    >>> cost = inst.evaluate({"kp": 2000, "kd": 12000})  # doctest: +SKIP
"""

from servogym.autotune.bench._instance import CONSTRAINT_NAMES, BenchmarkInstance
from servogym.autotune.bench._reference import (
    ReferenceConfig,
    data_path,
    load_best_known,
    load_reference,
    reference_search,
    refine_from_runs,
    run_reference,
    superseded_note,
)
from servogym.autotune.bench._report import TARGET_EPS, Run, summarize, write_report
from servogym.autotune.bench._runner import (
    ANYTIME_TUNERS,
    DETERMINISTIC_TUNERS,
    Job,
    TunerLimit,
    load_results,
    pack_results,
    plan_jobs,
    run_job,
    run_jobs,
)
from servogym.autotune.bench._suite import (
    LOADS,
    SUITE_VERSION,
    TASKS,
    InstanceSpec,
    Suite,
    Task,
    get_suite,
)

__all__ = [
    "ANYTIME_TUNERS",
    "CONSTRAINT_NAMES",
    "DETERMINISTIC_TUNERS",
    "LOADS",
    "SUITE_VERSION",
    "TARGET_EPS",
    "TASKS",
    "BenchmarkInstance",
    "InstanceSpec",
    "Job",
    "ReferenceConfig",
    "Run",
    "Suite",
    "Task",
    "TunerLimit",
    "data_path",
    "get_suite",
    "load_best_known",
    "load_reference",
    "load_results",
    "pack_results",
    "plan_jobs",
    "reference_search",
    "refine_from_runs",
    "run_job",
    "run_jobs",
    "run_reference",
    "summarize",
    "superseded_note",
    "write_report",
]
