"""N worker processes on one study vs one (docs/autotune.md, "Many workers, one study").

Each configuration runs the `make demo` problem (MC2100, vertical-axis, TPE, seed 0) with
the same budget on a fresh journal file: 1 process with 1 evaluation thread, N processes
with 1 thread each (`servogym tune --storage FILE --study-name NAME` started N times), and
1 process with N threads. Throughput is evaluations per second between the first trial's
start and the last trial's end in the study (start-up of each process excluded).

    .venv/bin/python experiments/bench_shared_study.py [--budget 300] [--workers 2] [--repeat 3]

Each configuration runs `--repeat` times, interleaved; the median rate is printed, with the
ratio to 1 process x 1 thread measured in the same run.
"""

from __future__ import annotations

import argparse
import pathlib
import statistics
import subprocess
import sys
import tempfile

import optuna

from servogym.autotune._session import counts_toward_budget, open_storage

ROOT = str(pathlib.Path(__file__).resolve().parents[1])
WORKER = """
import sys
sys.path.insert(0, {root!r})
from servogym.autotune import SearchSpace, TuneProblem, run_study
from servogym.sim import Scenario
problem = TuneProblem(scenario=Scenario("MC2100", "vertical-axis"),
                      space=SearchSpace.for_chip("MC2100"), seed=0)
run_study(problem, "tpe", {budget}, storage={url!r}, study_name="bench", n_workers={threads},
          load_if_exists=True)
"""


def run(budget: int, processes: int, threads: int) -> tuple[float, int]:
    with tempfile.TemporaryDirectory() as tmp:
        url = str(pathlib.Path(tmp) / "study.journal")
        code = WORKER.format(root=ROOT, budget=budget, url=url, threads=threads)
        procs = [subprocess.Popen([sys.executable, "-c", code]) for _ in range(processes)]
        for p in procs:
            if p.wait() != 0:
                raise SystemExit(f"a worker failed (exit {p.returncode})")
        trials = optuna.load_study(study_name="bench", storage=open_storage(url)).get_trials()
        counted = [t for t in trials if counts_toward_budget(t)]
        start = min(t.datetime_start for t in counted)
        end = max(t.datetime_complete for t in counted)
        return len(counted) / (end - start).total_seconds(), len(counted)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--budget", type=int, default=300)
    parser.add_argument("--workers", type=int, default=2)
    parser.add_argument("--repeat", type=int, default=3)
    args = parser.parse_args()
    n = args.workers
    configs = [
        ("1 process x 1 thread", 1, 1),
        (f"{n} processes x 1 thread", n, 1),
        (f"1 process x {n} threads", 1, n),
    ]
    rates: dict[str, list[float]] = {label: [] for label, _, _ in configs}
    counts: dict[str, set[int]] = {label: set() for label, _, _ in configs}
    for _ in range(args.repeat):
        for label, processes, threads in configs:
            rate, count = run(args.budget, processes, threads)
            rates[label].append(rate)
            counts[label].add(count)
    print(f"budget {args.budget}, TPE, MC2100 vertical-axis, one journal file, "
          f"median of {args.repeat}")  # fmt: skip
    base = statistics.median(rates[configs[0][0]])
    for label, _, _ in configs:
        med = statistics.median(rates[label])
        print(f"{label:26} {med:7.1f} evaluations/s  x{med / base:4.2f}  "
              f"(trials per study: {sorted(counts[label])})")  # fmt: skip


if __name__ == "__main__":
    main()
