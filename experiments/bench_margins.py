"""Time the loop-margin analysis before and after it was made faster, per chip family.

    OPENBLAS_NUM_THREADS=1 .venv/bin/python experiments/bench_margins.py [--points 12] [--repeats 3]

"Before" is ``servogym/sim/_margins.py`` and ``_operating.py`` as of commit ``--before``
(default :data:`BASELINE`, the commit that stored tests/sim/data/margins_corpus.json.xz),
read with ``git show`` into a temporary directory and imported from there under other names;
"after" is the working tree. For each chip family of servobench-v1 and each of its plant
families (one benchmark instance each), ``--points`` random points of the unit cube
(``u ~ U(-0.3, 0.3)``, as the benchmark's tuners start) are timed, old and new alternately:

* ``analyse_loop``: one analysis on the evaluator's own linear plant, at every loop-latency
  choice and holding point (what an evaluation runs); the new code's per-set filter cache is
  cleared before each call, so this is the cost of a lone analysis;
* ``margins``: ``Evaluator.margins`` (every latency, every holding point), the cache cleared
  before each call;
* ``evaluate``: one whole evaluation with margins (``Evaluator.evaluate``: the simulation of
  the moves and the margins).

Each time is the median of ``--repeats`` runs; the table gives, per chip family, the median
over its points (and analyses) and the ratio old/new. The margins of old and new are checked
to agree (gain/phase margins, crossover counts, stability) on every point timed. BLAS runs
on one thread (set before numpy is imported): on a shared 2-core machine more threads only
contend.
"""

from __future__ import annotations

import os

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")
os.environ.setdefault("OMP_NUM_THREADS", "1")

import argparse
import dataclasses
import importlib.util
import math
import subprocess
import sys
import tempfile
import time
from pathlib import Path
from typing import Any

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
BASELINE = "f4a51f4"
"""The commit whose margin analysis is "before"."""

CHIPS = ("mc2100", "mc58000", "turbopmac2", "6250")
PLANTS = ("rotary", "two-mass", "vertical-axis", "arm")


def old_modules(rev: str, tmp: Path) -> tuple[Any, Any]:
    """``(_margins, _operating)`` as of ``rev``, imported as ``_old_margins`` and
    ``_old_operating`` from ``tmp``."""
    out = []
    for name in ("_margins", "_operating"):
        text = subprocess.run(
            ["git", "show", f"{rev}:servogym/sim/{name}.py"],
            cwd=ROOT, check=True, capture_output=True, text=True,
        ).stdout  # fmt: skip
        text = text.replace("from servogym.sim._margins import", "from _old_margins import")
        path = tmp / f"_old{name}.py"
        path.write_text(text)
        spec = importlib.util.spec_from_file_location(f"_old{name}", path)
        module = importlib.util.module_from_spec(spec)
        sys.modules[f"_old{name}"] = module
        spec.loader.exec_module(module)
        out.append(module)
    return out[0], out[1]


def _median_time(fn: Any, repeats: int, before: Any = None) -> float:
    times = []
    for _ in range(repeats):
        if before is not None:
            before()
        t = time.perf_counter()
        fn()
        times.append(time.perf_counter() - t)
    return float(np.median(times))


def _agree(a: Any, b: Any) -> bool:
    def close(x: float, y: float) -> bool:
        if math.isnan(x) or math.isnan(y) or math.isinf(x) or math.isinf(y):
            return (x == y) or (math.isnan(x) and math.isnan(y))
        return abs(x - y) <= 1e-9 * max(abs(x), abs(y)) + 1e-12

    return (
        a.stable == b.stable
        and len(a.crossovers) == len(b.crossovers)
        and len(a.phase_crossovers) == len(b.phase_crossovers)
        and close(a.gain_margin_db, b.gain_margin_db)
        and close(a.phase_margin_deg, b.phase_margin_deg)
        and close(a.bandwidth_hz, b.bandwidth_hz)
    )


def bench_instance(inst: Any, old: tuple[Any, Any], n_points: int, repeats: int,
                   rng: np.random.Generator) -> dict[str, list[tuple[float, float]]]:  # fmt: skip
    """``{"analyse_loop" | "margins" | "evaluate": [(old s, new s), ...]}`` for one instance."""
    import servogym.sim._scenario as scenario_module
    from servogym.sim import _margins as new_margins
    from servogym.sim._scenario import Evaluator

    old_margins, old_operating = old
    new_operating = scenario_module.operating_margins
    scenario = inst.problem.scenario
    chip = scenario.chip
    ev_old, ev_new = Evaluator(scenario), Evaluator(scenario)
    clear = new_margins._filter_on_base.cache_clear
    out: dict[str, list[tuple[float, float]]] = {"analyse_loop": [], "margins": [], "evaluate": []}
    asm0 = scenario.assumptions or chip.default_assumptions()
    choices = type(asm0).CHOICES["loop_latency"]

    def with_old(fn: Any) -> Any:
        def run() -> Any:
            scenario_module.operating_margins = old_operating.operating_margins
            try:
                return fn()
            finally:
                scenario_module.operating_margins = new_operating

        return run

    for _ in range(n_points):
        unit = {k: float(rng.uniform(-0.3, 0.3)) for k in inst.search_space}
        params = inst.problem.space.make_params(inst.values_from_unit(unit))
        m_old = with_old(lambda p=params: ev_old.margins(p))()
        m_new = ev_new.margins(params)
        if not _agree(m_old, m_new):
            raise RuntimeError(f"{inst.id}: margins differ for {unit}: {m_old} != {m_new}")
        out["margins"].append((
            _median_time(with_old(lambda p=params: ev_old.margins(p)), repeats),
            _median_time(lambda p=params: ev_new.margins(p), repeats, clear),
        ))  # fmt: skip
        out["evaluate"].append((
            _median_time(with_old(lambda p=params: ev_old.evaluate(p)), repeats),
            _median_time(lambda p=params: ev_new.evaluate(p), repeats, clear),
        ))  # fmt: skip
        # every analysis the evaluation ran, on the evaluators' own linear plants
        old_lins = {k: v for k, v in ev_old._linear.items() if len(k) == 4}
        new_lins = {k: v for k, v in ev_new._linear.items() if len(k) == 4}
        dt = chip.sample_time_s(params)
        for choice in choices:
            asm = dataclasses.replace(asm0, loop_latency=choice)
            latency = chip.loop_latency_s(params, asm)
            for key in [k for k in new_lins if k[2] == dt and k[3] == latency]:
                lin_old, lin_new = old_lins[key], new_lins[key]
                out["analyse_loop"].append((
                    _median_time(lambda a=asm, lo=lin_old, p=params:
                                 old_margins.analyse_loop(chip, p, a, lo), repeats),
                    _median_time(lambda a=asm, ln=lin_new, p=params:
                                 new_margins.analyse_loop(chip, p, a, ln), repeats, clear),
                ))  # fmt: skip
    return out


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--before", default=BASELINE, help="git revision of the old analysis")
    ap.add_argument("--points", type=int, default=12, help="random sets per instance")
    ap.add_argument("--repeats", type=int, default=3, help="runs per timing (median)")
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--chips", default=",".join(CHIPS), help="comma-separated chip models")
    args = ap.parse_args(argv)
    for name in ("points", "repeats"):
        if getattr(args, name) < 1:
            ap.error(f"--{name} must be >= 1; got --{name}={getattr(args, name)}")
    chips = args.chips.split(",")
    unknown = [c for c in chips if c not in CHIPS]
    if unknown:
        ap.error(f"--chips must name some of {', '.join(CHIPS)}; got {', '.join(unknown)}")

    from servogym.autotune.bench import get_suite

    suite = get_suite("servobench-v1")
    rng = np.random.default_rng(args.seed)
    rev = subprocess.run(["git", "rev-parse", "--short", args.before], cwd=ROOT, check=True,
                         capture_output=True, text=True).stdout.strip()  # fmt: skip
    print(f"before: {args.before} ({rev}); after: the working tree; "
          f"OPENBLAS_NUM_THREADS={os.environ.get('OPENBLAS_NUM_THREADS')}; "
          f"{args.points} sets per instance, median of {args.repeats} runs each")  # fmt: skip
    header = f"{'chip':<11} {'what':<13} {'n':>4} {'before ms':>10} {'after ms':>9} {'ratio':>6}"
    print(header)
    print("-" * len(header))
    with tempfile.TemporaryDirectory() as tmp:
        old = old_modules(args.before, Path(tmp))
        for chip in chips:
            rows: dict[str, list[tuple[float, float]]] = {}
            for plant in PLANTS:
                iid = next(i for i in suite.ids("all") if i.split("/")[1:3] == [chip, plant])
                for k, v in bench_instance(suite.instance(iid), old, args.points, args.repeats,
                                           rng).items():  # fmt: skip
                    rows.setdefault(k, []).extend(v)
            for what, pairs in rows.items():
                before = float(np.median([p[0] for p in pairs])) * 1e3
                after = float(np.median([p[1] for p in pairs])) * 1e3
                print(f"{chip:<11} {what:<13} {len(pairs):>4} {before:>10.2f} {after:>9.2f} "
                      f"{before / after:>6.2f}")  # fmt: skip
            sys.stdout.flush()
    return 0


if __name__ == "__main__":
    sys.exit(main())
