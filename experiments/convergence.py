"""Default integration against the fine reference, over every kind of parameter set.

    .venv/bin/python experiments/convergence.py sets    # tune the safe sets (resumable)
    .venv/bin/python experiments/convergence.py sweep   # compare (resumable)

``sets`` tunes one safe set per chip model x plant family x period (default and slowest
usable, ``servogym.sim._convergence.period_settings``) with the model-based tuner at the
default integration, and stores them in ``tests/sim/data/convergence_sets.json`` (the inputs
of tests/sim/test_convergence.py). ``sweep`` compares the default integration with the
reference (RK4, 32 substeps per period) by the rule of docs/simulation.md ("Integration") on:
those safe sets, ``--random`` random sets from the legal ranges per combination, every
best-known set of servobench-v0, the fixed set of experiments/schedule_vertical_axis, the best
sets of experiments/notch_two_mass, and ``runs/demo/best_params.json`` when present. One JSON
line per set goes to ``experiments/results/convergence.jsonl``; a summary is printed.
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import sys
import time
from pathlib import Path

import numpy as np

from servogym.autotune._job import run_study
from servogym.autotune._problem import Constraints, TuneProblem
from servogym.autotune._space import SearchSpace
from servogym.chips import load_params_file
from servogym.plants import PLANTS
from servogym.sim import Scenario
from servogym.sim._convergence import agreement, period_settings

HERE = Path(__file__).parent
SETS = HERE.parent / "tests" / "sim" / "data" / "convergence_sets.json"
RESULTS = HERE / "results" / "convergence.jsonl"
CHIPS = ("MC2100", "MC58000", "TurboPMAC2", "6250")


def tune_sets() -> None:
    doc = json.loads(SETS.read_text()) if SETS.exists() else {}
    for chip in CHIPS:
        for plant in PLANTS:
            for period, fix in period_settings(chip).items():
                key = f"{chip}/{plant}/{period}"
                if key in doc:
                    continue
                t0 = time.perf_counter()
                problem = TuneProblem(
                    scenario=Scenario(chip, plant),
                    space=SearchSpace.for_chip(chip, None, fix),
                    constraints=Constraints(min_gain_margin_db=None, min_phase_margin_deg=None),
                )
                res = run_study(problem, "model-based", 7, storage=None, n_workers=1)
                doc[key] = {
                    "chip": chip,
                    "plant": plant,
                    "period": period,
                    "values": res.best_values,
                    "tuned_cost": res.best.values[0],
                    "found_by": "model-based tuner, budget 7, default integration",
                }
                SETS.parent.mkdir(parents=True, exist_ok=True)
                SETS.write_text(json.dumps(doc, indent=1, sort_keys=True) + "\n")
                print(f"{key}: cost {res.best.values[0]:.4g} ({time.perf_counter() - t0:.0f} s)",
                      flush=True)  # fmt: skip


def shipped_sets() -> list[tuple[str, Scenario, dict]]:
    """(label, scenario, register values) of every set the repository ships."""
    out = []
    bench = json.loads((HERE.parent / "servogym/autotune/bench/data/servobench-v0.json")
                       .read_text())["instances"]  # fmt: skip
    from servogym.autotune.bench._suite import get_suite

    suite = get_suite()
    for iid, rec in bench.items():
        if "values" in rec:
            out.append((f"bench {iid}", suite.spec(iid).scenario(), rec["values"]))
    sched = json.loads((HERE / "results" / "schedule_vertical_axis.json").read_text())
    out.append(("schedule_vertical_axis fixed", Scenario("MC2100", "vertical-axis"),
                sched["fixed"]["values"]))  # fmt: skip
    sys.path.insert(0, str(HERE))
    import notch_two_mass

    for sub in ("ixx11_0", "ixx11_32000"):
        path = HERE / "results" / "notch_two_mass" / sub / "results.json"
        for run in json.loads(path.read_text())["runs"]:
            label = f"notch {sub} {run['tuner']} {run['arm']} seed {run['seed']}"
            out.append((label, notch_two_mass.scenario(), run["best_registers"]))
    demo = HERE.parent / "runs" / "demo" / "best_params.json"
    if demo.exists():
        loaded = load_params_file(demo.read_text())
        values = {k: v for k, v in dataclasses.asdict(loaded.params).items() if k != "model"}
        out.append(("demo", Scenario("MC2100", "vertical-axis"), values))
    return out


def sweep(n_random: int) -> None:
    done = set()
    if RESULTS.exists():
        done = {json.loads(line)["label"] for line in RESULTS.read_text().splitlines()}
    jobs: list[tuple[str, Scenario, dict]] = []
    sets = json.loads(SETS.read_text())
    for key, rec in sets.items():
        fix = period_settings(rec["chip"])[rec["period"]]
        jobs.append((f"safe {key}", Scenario(rec["chip"], rec["plant"]), rec["values"]))
        space = SearchSpace.for_chip(rec["chip"], None, fix)
        rng = np.random.default_rng(len(jobs))
        u0 = space.to_unit(rec["values"])
        for i in range(n_random):
            # random safe sets: near the safe one (+-0.05 of each unit interval)
            unit = {k: float(np.clip(v + rng.uniform(-0.05, 0.05), 0, 1)) for k, v in u0.items()}
            jobs.append((f"near {key} {i}", Scenario(rec["chip"], rec["plant"]),
                         space.values_from_unit(unit)))  # fmt: skip
            # and anywhere in the legal ranges (mostly unstable: the verdict is what counts)
            unit = {n: float(rng.uniform()) for n in space.unit_names}
            jobs.append((f"wild {key} {i}", Scenario(rec["chip"], rec["plant"]),
                         space.values_from_unit(unit)))  # fmt: skip
    jobs += shipped_sets()
    RESULTS.parent.mkdir(parents=True, exist_ok=True)
    for label, scenario, values in jobs:
        if label in done:
            continue
        t0 = time.perf_counter()
        params = scenario.params(values)
        a = agreement(scenario, params)
        rec = {"label": label, **dataclasses.asdict(a), "wall_s": time.perf_counter() - t0}
        with RESULTS.open("a") as fh:
            fh.write(json.dumps(rec) + "\n")
        print(f"{'ok ' if a.ok else 'BAD'} {label:60s} settled {int(a.settled)} "
              f"d {a.max_trace_difference:6d} cost {a.cost:9.4g} ref {a.reference_cost:9.4g} "
              f"{a.why}", flush=True)  # fmt: skip
    summarize()


def rejudge(r: dict) -> dict:
    """Apply the current rule (servogym.sim._convergence) to a recorded row's figures."""
    from servogym.sim._convergence import (
        COST_TOLERANCE,
        UNSETTLED_COST_TOLERANCE,
        WELL_DAMPED_COST,
    )
    from servogym.sim._scenario import COST_CAP

    settled = r["settled"] and r["reference_cost"] < WELL_DAMPED_COST
    ok = r["diverged"] == r["reference_diverged"]
    if ok and settled:
        rel, absolute = COST_TOLERANCE
        ok = (
            r["max_trace_difference"] <= r["trace_tolerance"]
            and abs(r["cost"] - r["reference_cost"]) <= rel * r["reference_cost"] + absolute
        )
    elif ok and not r["reference_diverged"]:
        ok = (min(r["cost"], r["reference_cost"]) >= COST_CAP
              or abs(r["cost"] - r["reference_cost"]) <= UNSETTLED_COST_TOLERANCE
              * r["reference_cost"])  # fmt: skip
    return {**r, "settled": settled, "ok": ok}


def summarize() -> None:
    rows = [rejudge(json.loads(line)) for line in RESULTS.read_text().splitlines()]
    kinds: dict[str, list[dict]] = {}
    for r in rows:
        kinds.setdefault(r["label"].split()[0], []).append(r)
    print(f"{'kind':10s} {'sets':>5s} {'agree':>6s} {'settled':>8s} {'max d (settled)':>16s} "
          f"{'same verdict':>13s}")  # fmt: skip
    for r in rows:
        if not r["ok"]:
            print(f"  disagrees: {r['label']}: d {r['max_trace_difference']} cost {r['cost']:.4g} "
                  f"ref {r['reference_cost']:.4g} diverged {r['diverged']} ref "
                  f"{r['reference_diverged']}")  # fmt: skip
    for kind, rs in kinds.items():
        settled = [r for r in rs if r["settled"]]
        dmax = max((r["max_trace_difference"] for r in settled), default=0)
        same = sum(r["diverged"] == r["reference_diverged"] for r in rs)
        print(f"{kind:10s} {len(rs):5d} {sum(r['ok'] for r in rs):6d} {len(settled):8d} "
              f"{dmax:16d} {same:13d}")  # fmt: skip


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("what", choices=["sets", "sweep", "summary"])
    ap.add_argument("--random", type=int, default=3, help="random sets per combination")
    args = ap.parse_args()
    if args.what == "sets":
        tune_sets()
    elif args.what == "sweep":
        sweep(args.random)
    else:
        summarize()


if __name__ == "__main__":
    main()
