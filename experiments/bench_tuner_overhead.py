"""Tuner overhead: sampler and storage time as a share of evaluation time (docs/autotune.md).

100 TPE trials of the `make demo` problem (MC2100, vertical-axis, the plant's moves), one
evaluation thread, on each storage; the ask time (sampler + storage writes of a new trial)
and the tell time (storage writes of its result) against the summed evaluation time, all
in CPU seconds of the threads that spend them (so neither the machine's other load nor the
overlap of asking with evaluating changes the share; the wall time shows that overlap).
Memory storage is the sampler alone; the journal file is the default of `servogym tune`.
The default problem has the margin constraints on (as `servogym tune` does), so every
evaluation also linearises the plant; `--no-margins` shows the share without them. Each
storage runs `--repeat` times; the medians are printed.

    .venv/bin/python experiments/bench_tuner_overhead.py [--trials 100] [--workers 1]
        [--repeat 3] [--no-margins]
"""

from __future__ import annotations

import argparse
import statistics
import tempfile
import threading
import time
from pathlib import Path

from servogym.autotune import Constraints, SearchSpace, Session, TuneProblem, get_tuner
from servogym.autotune._session import quiet_optuna
from servogym.sim import Evaluator, Scenario

STORAGES = {
    "memory": lambda tmp: None,
    "journal file (default)": lambda tmp: str(tmp / "study.journal"),
    "sqlite": lambda tmp: f"sqlite:///{tmp / 'study.db'}",
}
"""Each storage measured, as its URL in a fresh temporary folder."""


def measure(storage: str | None, trials: int, workers: int, margins: bool) -> dict[str, float]:
    spent = [0.0]
    lock = threading.Lock()

    class TimedEvaluator(Evaluator):
        def evaluate(self, *args, **kwargs):
            t0 = time.thread_time()
            result = super().evaluate(*args, **kwargs)
            with lock:
                spent[0] += time.thread_time() - t0
            return result

    scenario = Scenario("MC2100", "vertical-axis")
    constraints = (
        Constraints()
        if margins
        else Constraints(min_gain_margin_db=None, min_phase_margin_deg=None)
    )
    problem = TuneProblem(scenario=scenario, space=SearchSpace.for_chip("MC2100"), seed=0,
                          constraints=constraints)  # fmt: skip
    with quiet_optuna():
        session = Session(problem, budget=trials, storage=storage, study_name="bench",
                          tuner_name="tpe", n_workers=workers,
                          evaluator_factory=TimedEvaluator)  # fmt: skip
        t0 = time.perf_counter()
        with session:
            get_tuner("tpe").run(session)
        wall = time.perf_counter() - t0
    over = session.overhead()
    return {"eval_s": spent[0], "wall_s": wall, **over}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--trials", type=int, default=100)
    parser.add_argument("--workers", type=int, default=1)
    parser.add_argument("--repeat", type=int, default=3)
    parser.add_argument("--no-margins", dest="margins", action="store_false")
    args = parser.parse_args()
    print(f"{args.trials} TPE trials, MC2100 vertical-axis, {args.workers} evaluation "
          f"thread(s), margin constraints {'on' if args.margins else 'off'}, median of "
          f"{args.repeat}")  # fmt: skip
    print(f"{'storage':24} {'eval s':>7} {'ask s':>7} {'tell s':>7} {'share':>7} {'wall s':>7}")
    for name, url_in in STORAGES.items():
        runs = []
        for _ in range(args.repeat):
            with tempfile.TemporaryDirectory() as tmp:
                m = measure(url_in(Path(tmp)), args.trials, args.workers, args.margins)
            m["share"] = (m["ask_s"] + m["tell_s"]) / m["eval_s"]
            runs.append(m)
        med = {k: statistics.median(r[k] for r in runs) for k in runs[0]}
        print(f"{name:24} {med['eval_s']:7.2f} {med['ask_s']:7.2f} {med['tell_s']:7.2f} "
              f"{med['share']:7.1%} {med['wall_s']:7.2f}")  # fmt: skip


if __name__ == "__main__":
    main()
