"""The classical tuners against TPE: the figures of docs/autotune.md, "Measured".

    .venv/bin/python experiments/classical_tuners.py [--tpe-budget 200] [--rows all]

Runs ``servogym tune`` (the function the command calls, the check included) for each row:
TurboPMAC2 and the 6250 on the nominal rotary plant with ``vendor-step``, ``relay``,
``model-based`` and TPE, and MC2100 on the nominal vertical axis with the three classical
tuners; prints one markdown row per run (cost on the default integration, evaluations, the
check's verdict). Run folders under ``runs/classical_tuners/`` (a fresh folder per run).
"""

from __future__ import annotations

import argparse
import time
from pathlib import Path

from servogym.autotune._job import TuneConfig, tune

CLASSICAL = ("vendor-step", "relay", "model-based")
ROWS = {
    "TurboPMAC2/rotary": (*CLASSICAL, "tpe"),
    "6250/rotary": (*CLASSICAL, "tpe"),
    "MC2100/vertical-axis": CLASSICAL,
}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--tpe-budget", type=int, default=200)
    ap.add_argument("--rows", default="all", help="comma-separated CHIP/PLANT, or all")
    ap.add_argument("--workers", type=int, default=2)
    ap.add_argument("--out", type=Path, default=Path("runs/classical_tuners"))
    args = ap.parse_args()
    rows = ROWS if args.rows == "all" else {k: ROWS[k] for k in args.rows.split(",")}
    print("| chip | plant | tuner | cost | evaluations | feasible | check | wall (s) |")
    print("|---|---|---|---:|---:|---|---|---:|")
    for key, tuners in rows.items():
        chip, plant = key.split("/")
        for tuner in tuners:
            budget = args.tpe_budget if tuner == "tpe" else 40
            out = args.out / chip / plant / f"{tuner}-{time.time_ns()}"
            t0 = time.perf_counter()
            cfg = TuneConfig(chip=chip, plant=plant, out=out, budget=budget, tuner=tuner,
                             workers=args.workers)  # fmt: skip
            _, s = tune(cfg)
            check = s["check"]
            verdict = "pass" if check["passed"] else "FAIL: " + "; ".join(check["failures"][:2])
            if check.get("fallback"):
                verdict += f" (fallback, {check['fallback']['cost_ratio']:.3g}x)"
            print(f"| {chip} | {plant} | {tuner} | {s['tuned']['cost']:.4g} | {s['n_trials']} | "
                  f"{'yes' if s['feasible'] else 'no'} | {verdict} | "
                  f"{time.perf_counter() - t0:.0f} |", flush=True)  # fmt: skip


if __name__ == "__main__":
    main()
