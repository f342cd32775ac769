"""Does the default ``servogym tune`` produce sets that pass ``servogym check``?

    .venv/bin/python experiments/tune_passes_check.py [--budget 200] [--chips MC2100,...]

Runs the default tune (TPE, margin constraints, the check choosing among the best trials) for
every chip model given on every plant family, one run folder each under
``runs/tune_passes_check/<chip>/<plant>``, and appends one JSON line per run to
``experiments/results/tune_passes_check.jsonl`` (resumable: a run already recorded with the
same budget is skipped). Prints a table: cost, margins, check verdict, the first candidate that
passed. Results and discussion: experiments/tune_passes_check.md.
"""

from __future__ import annotations

import argparse
import json
import time
from pathlib import Path

from servogym.autotune._job import TuneConfig, tune
from servogym.plants import PLANTS

RESULTS = Path(__file__).parent / "results" / "tune_passes_check.jsonl"


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--budget", type=int, default=200)
    ap.add_argument("--chips", default="MC2100,MC58000,TurboPMAC2,6250")
    ap.add_argument("--plants", default=",".join(PLANTS))
    ap.add_argument("--workers", type=int, default=1)
    ap.add_argument("--out", type=Path, default=Path("runs/tune_passes_check"))
    args = ap.parse_args()
    done = set()
    if RESULTS.exists():
        for line in RESULTS.read_text().splitlines():
            r = json.loads(line)
            done.add((r["chip"], r["plant"], r["budget"]))
    RESULTS.parent.mkdir(parents=True, exist_ok=True)
    for chip in args.chips.split(","):
        for plant in args.plants.split(","):
            if (chip, plant, args.budget) in done:
                continue
            out = args.out / chip / plant
            t0 = time.perf_counter()
            config = TuneConfig(chip=chip, plant=plant, out=out, budget=args.budget,
                                workers=args.workers, storage="sqlite:///" + str(
                                    (out / f"study-{time.time_ns()}.db").resolve()))  # fmt: skip
            out.mkdir(parents=True, exist_ok=True)
            _, summary = tune(config)
            check = summary["check"]
            record = {
                "chip": chip,
                "plant": plant,
                "budget": args.budget,
                "tuner": "tpe",
                "cost": summary["tuned"]["cost"],
                "default_cost": summary["default"]["cost"],
                "feasible": summary["feasible"],
                "passed": check["passed"],
                "failures": check["failures"],
                "margins": check["margins"],
                "reference_cost": check["cases"][0]["cost"],
                "worst_case_cost": max(c["cost"] for c in check["cases"]),
                "candidates": check["candidates"],
                "wall_s": time.perf_counter() - t0,
            }
            with RESULTS.open("a") as fh:
                fh.write(json.dumps(record) + "\n")
            m = check["margins"]
            print(f"{chip:10s} {plant:14s} cost {record['cost']:8.3f} ref "
                  f"{record['reference_cost']:8.3f} worst {record['worst_case_cost']:8.3f} "
                  f"GM {m['gain_margin_db']} PM {m['phase_margin_deg']} "
                  f"{'PASS' if check['passed'] else 'FAIL'} "
                  f"(candidate {len(check['candidates'])}) {record['wall_s']:.0f}s",
                  flush=True)  # fmt: skip


if __name__ == "__main__":
    main()
