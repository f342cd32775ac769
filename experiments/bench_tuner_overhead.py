"""Tuner overhead: sampler and storage time as a share of evaluation time (docs/autotune.md).

`--trials` trials of a tuner (`--tuner`, default TPE) on the `make demo` problem (MC2100,
vertical-axis, the plant's moves), one evaluation thread, on each storage; the ask time
(sampler + storage writes of a new trial), the sampler's own part of it, and the tell time
(storage writes of its result) against the evaluation time, all in CPU seconds of the
threads that spend them (so neither the machine's other load nor the overlap of asking with
evaluating changes the share; the wall time shows that overlap). Memory storage is the
sampler and Optuna's ask/tell alone; the journal file is the default of `servogym tune`.
The default problem has the margin constraints on (as `servogym tune` does), so every
evaluation also linearises the plant; `--no-margins` shows the share without them. Each
storage runs `--repeat` times; the medians are printed.

The shares are per sampled trial against the mean evaluation: a tuner that also runs
experiments or scores candidates itself (the model-based design of `safe`) has those
evaluations in the evaluation mean and its sampled trials in the ask and tell columns.

`--batch-size` is the trials asked before any is told (default 8, `servogym tune`'s): with
more than one, GP and TPE ask with the batch's pending trials (GP: the q-batch acquisition);
the benchmark (`servogym benchmark`) runs every study with a batch of 1.

    .venv/bin/python experiments/bench_tuner_overhead.py [--tuner tpe] [--trials 100]
        [--workers 1] [--batch-size 8] [--repeat 3] [--storages memory,journal,sqlite]
        [--no-margins]
"""

from __future__ import annotations

import argparse
import statistics
import tempfile
import threading
import time
from pathlib import Path

from servogym.autotune import Constraints, SearchSpace, Session, TuneProblem, get_tuner
from servogym.autotune._session import DEFAULT_BATCH_SIZE, quiet_optuna
from servogym.sim import Evaluator, Scenario

STORAGES = {
    "memory": lambda tmp: None,
    "journal": lambda tmp: str(tmp / "study.journal"),
    "sqlite": lambda tmp: f"sqlite:///{tmp / 'study.db'}",
}
"""Each storage measured, as its URL in a fresh temporary folder (journal: the default)."""


def measure(
    tuner: str,
    storage: str | None,
    trials: int,
    workers: int,
    margins: bool,
    batch_size: int | None = None,
) -> dict[str, float]:
    spent = [0.0, 0]
    lock = threading.Lock()

    class TimedEvaluator(Evaluator):
        def evaluate(self, *args, **kwargs):
            t0 = time.thread_time()
            result = super().evaluate(*args, **kwargs)
            with lock:
                spent[0] += time.thread_time() - t0
                spent[1] += 1
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
                          tuner_name=tuner, n_workers=workers,
                          evaluator_factory=TimedEvaluator, batch_size=batch_size)  # fmt: skip
        t0 = time.perf_counter()
        with session:
            get_tuner(tuner).run(session)
        wall = time.perf_counter() - t0
    over = session.overhead()
    sampled = sum(t.user_attrs.get("kind") == "sample" for t in session.trials())
    return {"eval_s": spent[0], "n_eval": spent[1], "n_sampled": sampled, "wall_s": wall, **over}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--tuner", default="tpe")
    parser.add_argument("--trials", type=int, default=100)
    parser.add_argument("--workers", type=int, default=1)
    parser.add_argument("--batch-size", type=int, default=None)
    parser.add_argument("--repeat", type=int, default=3)
    parser.add_argument("--storages", default=",".join(STORAGES))
    parser.add_argument("--no-margins", dest="margins", action="store_false")
    args = parser.parse_args()
    storages = [s.strip() for s in args.storages.split(",") if s.strip()]
    for name in storages:
        if name not in STORAGES:
            parser.error(f"--storages takes names from {', '.join(STORAGES)}; got {name!r}")
    if args.batch_size is not None and args.batch_size < 1:
        parser.error(f"--batch-size must be >= 1; got {args.batch_size}")
    get_tuner(args.tuner)  # an unknown name fails here, with close matches
    batch = args.batch_size or DEFAULT_BATCH_SIZE
    print(f"{args.trials} {args.tuner} trials, MC2100 vertical-axis, {args.workers} evaluation "
          f"thread(s), batches of {batch}, margin constraints {'on' if args.margins else 'off'}, "
          f"median of "
          f"{args.repeat}; per sampled trial, in ms of CPU")  # fmt: skip
    print(f"{'storage':10} {'eval ms':>8} {'sampler':>8} {'ask ms':>8} {'tell ms':>8} "
          f"{'sampler share':>14} {'(ask+tell) share':>17} {'wall s':>7}")  # fmt: skip
    for name in storages:
        runs = []
        for _ in range(args.repeat):
            with tempfile.TemporaryDirectory() as tmp:
                m = measure(args.tuner, STORAGES[name](Path(tmp)), args.trials, args.workers,
                            args.margins, args.batch_size)  # fmt: skip
            n = max(m["n_sampled"], 1)
            per_eval = m["eval_s"] / max(m["n_eval"], 1)
            m = {
                "eval_ms": 1e3 * per_eval,
                "sampler_ms": 1e3 * m["sampler_s"] / n,
                "ask_ms": 1e3 * m["ask_s"] / n,
                "tell_ms": 1e3 * m["tell_s"] / n,
                "sampler_share": m["sampler_s"] / n / per_eval,
                "share": (m["ask_s"] + m["tell_s"]) / n / per_eval,
                "wall_s": m["wall_s"],
            }
            runs.append(m)
        med = {k: statistics.median(r[k] for r in runs) for k in runs[0]}
        print(f"{name:10} {med['eval_ms']:8.2f} {med['sampler_ms']:8.2f} {med['ask_ms']:8.2f} "
              f"{med['tell_ms']:8.2f} {med['sampler_share']:14.1%} {med['share']:17.1%} "
              f"{med['wall_s']:7.1f}")  # fmt: skip


if __name__ == "__main__":
    main()
