"""Does the default ``servogym tune`` write only sets that pass ``servogym check``?

    .venv/bin/python experiments/tune_passes_check.py [--budget 200] [--chips MC2100,...]
        [--points ends | all-plants | PLANT:NAME=VALUE,...]

Runs the default tune (the safe tuner from the model-based design, margin constraints, the check
choosing) through the command a user runs, ``servogym tune ... --json``, for every chip model
given at every plant point, one run folder each under ``runs/tune_passes_check/``; then, for
a run that wrote its hardware files, checks the written ``best_params.json`` again with
``servogym check`` (a separate process, the same limits). Appends one JSON line per run to
``experiments/results/tune_passes_check.jsonl`` (resumable: a run already recorded with the
same chip, point and budget is skipped) and prints a table.

Points: ``ends`` (the default, issue 18) is each end of the feasible range of the arm's payload
and the rotary axis's load inertia (from 1x the rotor's inertia to the largest load its motor
moves with the default moves, ``servogym.plants.feasible_range``); ``all-plants`` is every
plant family at its nominal values. Every run must either write a set that passes the check
everywhere (exit 0, and the separate check passes) or exit 1 naming why.
Results and discussion: experiments/tune_passes_check.md.
"""

from __future__ import annotations

import argparse
import json
import subprocess
import sys
import time
from pathlib import Path

RESULTS = Path(__file__).parent / "results" / "tune_passes_check.jsonl"
SERVOGYM = [sys.executable, "-m", "servogym.cli"]


def end_points() -> list[tuple[str, dict[str, float]]]:
    """The arm's lightest and heaviest payload, the rotary axis at 1x and its largest load."""
    from servogym.plants import get_plant
    from servogym.plants._feasibility import feasible_range

    arm_lo, arm_hi = feasible_range("arm", "payload_kg")
    rotary = get_plant("rotary")
    one_x = rotary.nominal()["rotor_inertia_kgm2"]
    _, rot_hi = feasible_range("rotary", "load_inertia_kgm2")
    return [
        ("arm", {"payload_kg": arm_lo}),
        ("arm", {"payload_kg": arm_hi}),
        ("rotary", {"load_inertia_kgm2": one_x}),
        ("rotary", {"load_inertia_kgm2": rot_hi}),
    ]


def parse_points(text: str) -> list[tuple[str, dict[str, float]]]:
    if text == "ends":
        return end_points()
    if text == "all-plants":
        from servogym.plants import PLANTS

        return [(p, {}) for p in PLANTS]
    out = []
    for item in text.split(","):
        plant, _, rest = item.partition(":")
        values = {}
        for kv in filter(None, rest.split(";")):
            k, _, v = kv.partition("=")
            values[k] = float(v)
        out.append((plant, values))
    return out


def key_of(chip: str, plant: str, values: dict[str, float], budget: int) -> str:
    vals = ",".join(f"{k}={v:.6g}" for k, v in sorted(values.items()))
    return f"{chip}|{plant}|{vals}|{budget}"


def plant_args(values: dict[str, float]) -> list[str]:
    return [a for k, v in values.items() for a in ("--plant-param", f"{k}={v!r}")]


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--budget", type=int, default=200)
    ap.add_argument("--chips", default="MC2100,MC58000,TurboPMAC2,6250")
    ap.add_argument("--points", default="ends")
    ap.add_argument("--workers", type=int, default=1)
    ap.add_argument("--out", type=Path, default=Path("runs/tune_passes_check"))
    ap.add_argument(
        "--tune-args", default="", help="more tune options, e.g. '--fix output_limit=32767'"
    )
    args = ap.parse_args()
    extra = args.tune_args.split()
    done = set()
    if RESULTS.exists():
        for line in RESULTS.read_text().splitlines():
            r = json.loads(line)
            if "key" in r:
                done.add(r["key"])
    RESULTS.parent.mkdir(parents=True, exist_ok=True)
    for plant, values in parse_points(args.points):
        for chip in args.chips.split(","):
            key = key_of(chip, plant, values, args.budget) + (f"|{args.tune_args}" if extra else "")
            if key in done:
                continue
            tag = "-".join(f"{k}{v:.3g}" for k, v in values.items()) or "nominal"
            out = args.out / chip / plant / f"{tag}-{time.time_ns()}"
            t0 = time.perf_counter()
            cmd = [*SERVOGYM, "tune", "--chip", chip, "--plant", plant, *plant_args(values),
                   "--budget", str(args.budget), "--workers", str(args.workers),
                   "--out", str(out), "--json", *extra]  # fmt: skip
            run = subprocess.run(cmd, capture_output=True, text=True)
            wall = time.perf_counter() - t0
            record = {
                "key": key, "chip": chip, "plant": plant, "plant_values": values,
                "budget": args.budget, "exit_code": run.returncode, "wall_s": wall,
                "tune_args": args.tune_args,
            }  # fmt: skip
            if run.returncode not in (0, 1) or not (out / "summary.json").exists():
                record["error"] = (run.stderr or run.stdout).strip().splitlines()[-3:]
            else:
                summary = json.loads((out / "summary.json").read_text())
                check = summary["check"]
                record.update(
                    cost=summary["tuned"]["cost"],
                    default_cost=summary["default"]["cost"],
                    feasible=summary["feasible"],
                    design=summary.get("design_start", {}).get("cost"),
                    passed=check["passed"],
                    failures=check["failures"],
                    worst=check["worst"],
                    fallback=check["fallback"],
                    worst_case_cost=max(c["cost"] for c in check["cases"]),
                    candidates=len(check["candidates"]),
                    withheld=summary["hardware_files_withheld"],
                )
                if run.returncode == 0:
                    again = subprocess.run(
                        [*SERVOGYM, "check", str(out / "best_params.json"), "--plant", plant,
                         *plant_args(values), "--out", str(out / "recheck"), "--json"],
                        capture_output=True, text=True,
                    )  # fmt: skip
                    record["recheck_exit_code"] = again.returncode
            with RESULTS.open("a") as fh:
                fh.write(json.dumps(record) + "\n")
            print(row(record), flush=True)


def row(r: dict) -> str:
    vals = ", ".join(f"{k}={v:.3g}" for k, v in r["plant_values"].items()) or "nominal"
    if r.get("tune_args"):
        vals += f" ({r['tune_args']})"
    if "error" in r:
        crash = f"crashed (exit {r['exit_code']})"
        return f"| {r['chip']} | {r['plant']} {vals} | {crash} | {r['error']} |"
    w = r["worst"]

    def worst(k: str, unit: str) -> str:
        return f"{w[k]['value']:.3g} {unit} ({w[k]['case']})" if k in w else "-"

    verdict = "pass, written" if r["exit_code"] == 0 else "exit 1"
    if r["exit_code"] == 0:
        verdict += ", re-check " + ("pass" if r.get("recheck_exit_code") == 0 else "FAIL")
    first = sorted(r["failures"], key=lambda f: ": command limit: " not in f)  # the cause first
    why = "; ".join(first[:2]) if r["exit_code"] else ""
    design = "-" if r["design"] is None else f"{r['design']:.3g}"
    return (
        f"| {r['chip']} | {r['plant']} {vals} | {r['default_cost']:.3g} | {design} | "
        f"{r['cost']:.3g} | {r['worst_case_cost']:.3g} | {worst('gain_margin_db', 'dB')} | "
        f"{worst('phase_margin_deg', 'deg')} | {verdict} | {why} | {r['wall_s']:.0f} |"
    )


if __name__ == "__main__":
    main()
