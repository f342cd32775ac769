"""The default tuner against TPE from the same design start (docs/autotune.md, "The default
tuner").

Every cell is one chip model on one plant family with `servogym tune`'s problem (the
plant's own moves, margin constraints at every loop latency, following-error and saturation
limits): the model-based design start (`design_start`, 9 simulations, not counted) is
computed once per cell and seed, then `safe` and `tpe` each run `--budget` evaluations from
it (one evaluation thread, batches of 8, as `servogym tune --workers 1` does). Neither tuner
plans with its budget, so the smaller budgets are the prefixes of the largest run.

`--no-warm-start` runs `safe` as the benchmark runs tuners (`run_study` without a warm
start): its own model-based line search inside the budget, every evaluation counted.

Per run and budget: the best feasible cost, and the unsafe evaluations (diverged, or
violating any constraint the tune command sets). Each run is one line of
`experiments/results/safe_tuner_check/runs.jsonl`; a rerun skips the runs already there.

    nice -n 10 .venv/bin/python experiments/safe_tuner_check.py [--budgets 20,50]
        [--seeds 0,1,2] [--chips MC2100,MC58000,TurboPMAC2,6250]
        [--plants rotary,vertical-axis,two-mass,arm] [--tuners safe,tpe] [--no-warm-start]
        [--results runs.jsonl]
"""

from __future__ import annotations

import argparse
import json
import math
import statistics
import time
import warnings
from pathlib import Path

OUT = Path(__file__).parent / "results" / "safe_tuner_check"


def unsafe(trial) -> bool:
    """Diverged or violating any constraint (a refused set is not an evaluation)."""
    if trial.state.name != "COMPLETE":
        return False
    if trial.user_attrs.get("outcome", {}).get("n_diverged", 0):
        return True
    return any(v > 0 for v in trial.constraints.values())


def run_one(chip: str, plant: str, tuner: str, seed: int, budget: int, warm: dict | None,
            design_cost: float | None) -> dict:  # fmt: skip
    from servogym.autotune import TuneConfig, run_study
    from servogym.autotune._session import quiet_optuna

    cfg = TuneConfig(chip=chip, plant=plant, out=Path("unused"), budget=budget, tuner=tuner,
                     seed=seed, workers=1)  # fmt: skip
    t0 = time.perf_counter()
    c0 = time.process_time()
    with quiet_optuna(), warnings.catch_warnings():
        warnings.simplefilter("ignore")
        result = run_study(cfg.problem(), tuner, budget, storage=None, n_workers=1,
                           warm_start=warm)  # fmt: skip
    rows = []
    for t in result.trials:
        kind = t.user_attrs.get("kind")
        if kind == "experiment":
            rows.append({"kind": kind})
            continue
        ok = t.state.name == "COMPLETE"
        rows.append({
            "kind": kind,
            "cost": float(t.values[0]) if ok else None,
            "feasible": ok and not unsafe(t),
            "unsafe": unsafe(t),
        })  # fmt: skip
    return {
        "chip": chip, "plant": plant, "tuner": tuner, "seed": seed, "budget": budget,
        "warm_start": warm is not None, "design_cost": design_cost, "trials": rows,
        "wall_s": round(time.perf_counter() - t0, 2),
        "cpu_s": round(time.process_time() - c0, 2),
    }  # fmt: skip


def prefix(record: dict, budget: int) -> dict:
    """Best feasible cost and unsafe count among the first ``budget`` trials."""
    rows = record["trials"][:budget]
    costs = [r["cost"] for r in rows if r.get("feasible")]
    return {
        "best": min(costs) if costs else math.inf,
        "n_unsafe": sum(bool(r.get("unsafe")) for r in rows),
        "n": len(rows),
    }


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--budgets", default="20,50")
    parser.add_argument("--seeds", default="0,1,2")
    parser.add_argument("--chips", default="MC2100,MC58000,TurboPMAC2,6250")
    parser.add_argument("--plants", default="rotary,vertical-axis,two-mass,arm")
    parser.add_argument("--tuners", default="safe,tpe")
    parser.add_argument("--no-warm-start", dest="warm", action="store_false")
    parser.add_argument("--report-only", action="store_true")
    parser.add_argument("--results", default="runs.jsonl",
                        help="the runs file in results/safe_tuner_check/ (another name: a "
                             "fresh set of runs, e.g. after a change to the tuner)")  # fmt: skip
    args = parser.parse_args()
    budgets = sorted(int(b) for b in args.budgets.split(","))
    seeds = [int(s) for s in args.seeds.split(",")]
    chips, plants = args.chips.split(","), args.plants.split(",")
    tuners = args.tuners.split(",")
    OUT.mkdir(parents=True, exist_ok=True)
    path = OUT / args.results
    done = {}
    if path.exists():
        for line in path.read_text().splitlines():
            r = json.loads(line)
            done[(r["chip"], r["plant"], r["tuner"], r["seed"], r["warm_start"])] = r
    top = budgets[-1]
    if not args.report_only:
        from servogym.autotune import TuneConfig
        from servogym.autotune._job import design_start

        for chip in chips:
            for plant in plants:
                for seed in seeds:
                    todo = [
                        t
                        for t in tuners
                        if (chip, plant, t, seed, args.warm) not in done
                        or len(done[(chip, plant, t, seed, args.warm)]["trials"]) < top
                    ]
                    if not todo:
                        continue
                    warm, dcost = None, None
                    if args.warm:
                        cfg = TuneConfig(chip=chip, plant=plant, out=Path("unused"), budget=top,
                                         tuner="tpe", seed=seed, workers=1)  # fmt: skip
                        d = design_start(cfg.problem(), cfg)
                        warm, dcost = d.get("values"), d.get("cost")
                    for tuner in todo:
                        rec = run_one(chip, plant, tuner, seed, top, warm, dcost)
                        done[(chip, plant, tuner, seed, args.warm)] = rec
                        with path.open("a") as f:
                            f.write(json.dumps(rec) + "\n")
                        p = prefix(rec, top)
                        print(f"{chip:10} {plant:13} {tuner:5} seed {seed} warm {args.warm:d}: "
                              f"best {p['best']:.4g} (design {dcost}) unsafe {p['n_unsafe']}/"
                              f"{p['n']} cpu {rec['cpu_s']} s", flush=True)  # fmt: skip
    report(done, budgets, chips, plants, seeds, tuners)


def report(done, budgets, chips, plants, seeds, tuners) -> None:
    for warm in (True, False):
        recs = [r for k, r in done.items() if k[4] == warm and k[0] in chips and k[1] in plants
                and k[3] in seeds and k[2] in tuners]  # fmt: skip
        if not recs:
            continue
        print(f"\n== {'from the design start (tune)' if warm else 'no warm start (benchmark)'}")
        for b in budgets:
            print(f"-- budget {b}")
            for tuner in tuners:
                mine = [r for r in recs if r["tuner"] == tuner]
                if not mine:
                    continue
                ps = [prefix(r, b) for r in mine]
                n_unsafe = sum(p["n_unsafe"] for p in ps)
                n = sum(p["n"] for p in ps)
                rel = [p["best"] / r["design_cost"] for p, r in zip(ps, mine, strict=True)
                       if r["design_cost"]]  # fmt: skip
                none = sum(math.isinf(p["best"]) for p in ps)
                line = (
                    f"{tuner:5} runs {len(mine):3}  unsafe {n_unsafe}/{n} = "
                    f"{n_unsafe / max(n, 1):.1%}  no feasible trial: {none}"
                )
                if rel:
                    line += f"  median cost / design {statistics.median(rel):.3f}"
                print(line)
            if "safe" in tuners and "tpe" in tuners:
                ratios, wins = [], 0
                for r in recs:
                    if r["tuner"] != "safe":
                        continue
                    o = done.get((r["chip"], r["plant"], "tpe", r["seed"], warm))
                    if o is None:
                        continue
                    a, c = prefix(r, b)["best"], prefix(o, b)["best"]
                    if math.isinf(a) and math.isinf(c):
                        continue
                    ratios.append(a / c if not math.isinf(c) else 0.0)
                    wins += a < c
                if ratios:
                    print(f"safe / tpe per run: median {statistics.median(ratios):.3f}, "
                          f"safe better in {wins} of {len(ratios)}")  # fmt: skip
        print("per chip (largest budget): unsafe fraction and median cost / design")
        for chip in chips:
            for tuner in tuners:
                mine = [r for r in recs if r["tuner"] == tuner and r["chip"] == chip]
                if not mine:
                    continue
                ps = [prefix(r, budgets[-1]) for r in mine]
                rel = [p["best"] / r["design_cost"] for p, r in zip(ps, mine, strict=True)
                       if r["design_cost"]]  # fmt: skip
                n = sum(p["n"] for p in ps)
                u = sum(p["n_unsafe"] for p in ps)
                med = f"{statistics.median(rel):.3f}" if rel else "-"
                print(f"  {chip:10} {tuner:5} unsafe {u}/{n} = {u / max(n, 1):.1%}  cost/design "
                      f"{med}")  # fmt: skip


if __name__ == "__main__":
    main()
