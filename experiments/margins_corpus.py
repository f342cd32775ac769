"""A corpus of today's loop-margin analyses, so that a faster analysis is shown to agree.

    .venv/bin/python experiments/margins_corpus.py --write    # (re)write the corpus
    .venv/bin/python experiments/margins_corpus.py --check    # recompute every case and compare

The corpus (``tests/sim/data/margins_corpus.json.xz``), written with the analysis of commit
2772d1d (before it was made faster), holds 400 random parameter sets (seed 20250611): 25 for
each pair of a chip model of servobench-v1 (PMD MC2100 and MC58000, Turbo PMAC2, Parker 6250)
and a plant family (rotary, two-mass, vertical-axis, arm), each on one of that pair's
benchmark instances (its moves, hence its holding points, and its plant values, half of them
a random draw of the plant family). A set is a point of the instance's unit cube (round the
chip model's defaults, or anywhere; two in three chosen stable at the scenario's own
latency), with every assumption switch drawn at random, a random servo period for one set in
five and, on the MC58000, a notch or a random biquad for some (:func:`draw_cases`); sets that
analysis could not handle (:func:`_analysable`: a zero of ``L`` on the unit circle) were
drawn again. Every set is analysed at every loop-latency choice of its family and at every
holding point (``servogym.sim._operating.operating_margins``): 3,000 analyses, half of them
stable, 96 decided by the encirclement count. Each case stores its inputs (register values,
assumptions, plant values, holding offsets) and each analysis's results: the closed loop's
stability (verdict, unstable-pole count, spectral radius, order, method), the margins
(``Margins.to_dict``: gain, phase and delay margins, crossover frequencies, bandwidth, every
crossover) and the open loop at 6 points of the display grid.

``--check`` recomputes every case from its stored inputs and compares (:func:`compare`),
with numpy's and OpenBLAS's kernels pinned to AVX2 (:data:`AVX2_KERNELS`; both modes run
themselves again with them):
every verdict, count, order, method and the number of crossovers exactly, every float within
``RTOL`` relative (plus ``ATOL`` absolute, for values near 0). ``tests/sim/
test_margins_corpus.py`` runs a sample of the same checks in the test suite.
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import lzma
import math
import os
import platform
import subprocess
import sys
import time
import types
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
CORPUS = ROOT / "tests" / "sim" / "data" / "margins_corpus.json.xz"
SEED = 20250611
N_PER_PAIR = 25
CHIP_MODELS = ("mc2100", "mc58000", "turbopmac2", "6250")
PLANTS = ("rotary", "two-mass", "vertical-axis", "arm")
LOOP_SAMPLES = 6
"""Points of the display grid (``frequency_grid``, evenly spaced indices) whose open-loop
value is stored."""

RTOL = 1e-9
"""Relative tolerance of every float: margins, crossover frequencies, bandwidth, spectral
radius, open-loop values. Brent's method locates a crossover to ``1e-14`` of its frequency
(``xtol``), far inside it."""

ATOL = 1e-12
"""Absolute tolerance added to ``RTOL`` (a margin or value within rounding of 0)."""

AVX2_KERNELS = {
    "NPY_DISABLE_CPU_FEATURES": "X86_V4,AVX512_ICL,AVX512_SPR",
    "OPENBLAS_CORETYPE": "Haswell",
}
"""numpy's and OpenBLAS's kernels pinned to AVX2 (x86-64) for ``--write`` and ``--check``:
the corpus was stored with them. On an AVX-512 machine their AVX-512 kernels round some
results one ulp differently; a resonant two-mass case amplifies that to 2e-6 of a
crossover, and a near-tie can move ``worst`` to another point. Seen 2026-12-03: 7 of the
test's 50 cases differed with them and none without. The analysis does not change; the
machine's arithmetic does."""

SPURIOUS_GAIN_MARGIN_DB = 200.0
"""A phase crossover with a gain margin beyond this is one at a zero of ``L`` (see
:func:`_analysable`)."""


def _instances() -> dict[tuple[str, str], list[str]]:
    from servogym.autotune.bench import get_suite

    out: dict[tuple[str, str], list[str]] = {}
    for iid in get_suite("servobench-v1").ids("all"):
        _, chip, plant, *_ = iid.split("/")
        out.setdefault((chip, plant), []).append(iid)
    return out


def _biquad(rng: np.random.Generator, dt: float) -> dict[str, int]:
    """A biquad stage (q14 coefficients): a notch between 50 Hz and 0.4 of the sample rate
    (half the time), else random coefficients with poles inside the circle."""
    if rng.random() < 0.5:
        w0 = 2 * math.pi * math.exp(rng.uniform(math.log(50.0), math.log(0.4 / dt))) * dt
        r = rng.uniform(0.6, 0.98)
        b = [0.5, -math.cos(w0), 0.5]
        a = [-2 * r * math.cos(w0), r * r]
        k = 1.999 * (1 + a[0] + a[1]) / (2 * (b[0] + b[1] + b[2]) + 1e-12)
        k = min(max(k, 0.0), 1.999)
    else:
        r, w = rng.uniform(0.0, 0.95), rng.uniform(0.0, math.pi)
        b = list(rng.uniform(-1.0, 1.0, 3))
        a = [-2 * r * math.cos(w), r * r]
        k = rng.uniform(0.1, 1.999)

    def q14(x: float) -> int:
        return int(min(max(round(x * 16384), -32768), 32767))

    return {"b0": q14(b[0]), "b1": q14(b[1]), "b2": q14(b[2]), "a1": q14(a[0]),
            "a2": q14(a[1]), "k": int(min(max(round(k * 16384), 0), 32767))}  # fmt: skip


def _draw_values(inst: Any, rng: np.random.Generator) -> dict[str, int]:
    """Register values of one candidate set: the unit cube round the chip model's defaults
    (normal steps of 0.05, 0.15 or 0.4) or anywhere in it (one in five), a random servo
    period (one in five) and, on the MC58000, biquads (stage 1 two in five, stage 2 one in
    seven)."""
    scenario = inst.problem.scenario
    fam, model = scenario.chip, scenario.chip_model
    centre = inst.to_unit(inst.default_values())
    if rng.random() < 0.2:
        unit = {u: float(rng.uniform(-1.0, 1.0)) for u in centre}
    else:
        sigma = float(rng.choice([0.05, 0.15, 0.4]))
        unit = {u: float(np.clip(c + rng.normal(0.0, sigma), -1.0, 1.0)) for u, c in centre.items()}
    values = dict(inst.values_from_unit(unit))
    if rng.random() < 0.2:  # another servo period
        if fam.name == "pmd":
            low = fam.parameter_space(model)["sample_time_us"].low
            values["sample_time_us"] = int(rng.integers(low, 1000))
        elif fam.name == "pmac":
            values["servo_cycle_extension"] = int(rng.integers(0, 4))
        else:
            values["ssfr"] = int(rng.choice([1, 2, 4, 8]))
    if fam.name == "pmd" and "biquad1_enable" in fam.parameter_space(model):
        dt = fam.sample_time_s(fam.make_params(model, values))
        for stage in (1, 2):
            if rng.random() < (0.4 if stage == 1 else 0.15):
                values[f"biquad{stage}_enable"] = 1
                values.update({f"biquad{stage}_{n}": v for n, v in _biquad(rng, dt).items()})
    fam.make_params(model, values)  # legal
    return {n: int(v) for n, v in values.items()}


def draw_cases(seed: int = SEED, n_per_pair: int = N_PER_PAIR) -> Iterator[dict[str, Any]]:
    """The corpus's cases (inputs and results), drawn from ``seed``.

    Each case first draws its plant instance and assumption switches, then whether its set
    is to be stable (two in three) at the scenario's own loop latency and first holding
    point, and draws candidate sets (:func:`_draw_values`) until one is and the analysis
    handles it (:func:`_analysable`); after 40 draws any analysable set: random sets round
    the defaults are mostly unstable on some plants.
    """
    from servogym.autotune.bench import get_suite
    from servogym.plants import get_plant
    from servogym.sim._margins import closed_loop_stability, continuous_model, linearize
    from servogym.sim._operating import holding_positions

    suite = get_suite("servobench-v1")
    rng = np.random.default_rng(seed)
    by_pair = _instances()
    for chip in CHIP_MODELS:
        for plant_name in PLANTS:
            ids = by_pair[(chip, plant_name)]
            for k in range(n_per_pair):
                inst = suite.instance(ids[k % len(ids)])
                scenario = inst.problem.scenario
                fam, model = scenario.chip, scenario.chip_model
                family = get_plant(scenario.plant)
                plant_values = scenario.draw_plant(rng)
                if rng.random() < 0.5:
                    plant_values = family.sample(rng, 1.0, base=plant_values)
                    plant_values.update(scenario.plant_values)
                plant = family.build(plant_values)
                continuous = continuous_model(plant)
                asm_type = fam.assumptions_type
                asm = {n: str(rng.choice(c)) for n, c in asm_type.CHOICES.items()}
                own = (scenario.assumptions or fam.default_assumptions()).loop_latency
                assumptions = asm_type(**{**asm, "loop_latency": own})
                want = bool(rng.random() < 2 / 3)
                for attempt in range(200):
                    values = _draw_values(inst, rng)
                    params = fam.make_params(model, values)
                    dt = fam.sample_time_s(params)
                    lin = linearize(plant, dt, fam.loop_latency_s(params, assumptions), continuous)
                    polys = fam.filter_polynomials(params, assumptions)
                    if closed_loop_stability(polys, lin).stable != want and attempt < 40:
                        continue
                    case = {
                        "instance": inst.id,
                        "chip_model": model,
                        "values": values,
                        "assumptions": asm,
                        "plant": scenario.plant,
                        "plant_values": {n: _num(v) for n, v in plant_values.items()},
                        "distances": [float(m.distance) for m in scenario.moves],
                        "holding": list(holding_positions(scenario.moves)),
                        "latencies": list(asm_type.CHOICES["loop_latency"]),
                    }
                    results = _analysable(case)
                    if results is not None:
                        break
                else:
                    raise RuntimeError(f"no analysable set for {inst.id} in 200 draws")
                yield {**case, "results": results}


def _analysable(case: dict[str, Any]) -> dict[str, Any] | None:
    """The case's results, or ``None`` where the analysis before the speed-up failed on it: it
    raised, or it reported a phase crossover at a zero of ``L`` on the unit circle (a notch
    biquad with ``b0 = b2``: the sign change of ``Im L / |L|`` there was root-found to the
    zero and, with ``|L|`` at rounding level, divided by zero or gave a gain margin of some
    300 dB)."""
    try:
        results = json.loads(json.dumps(analyse_case(case)))
    except ZeroDivisionError:
        return None
    for res in results.values():
        for point in res["points"]:
            if any(
                abs(gm) > SPURIOUS_GAIN_MARGIN_DB for _, gm in point["margins"]["phase_crossovers"]
            ):
                return None
    return results


def _num(v: Any) -> Any:
    return int(v) if isinstance(v, int | np.integer) else float(v)


def _clean(v: Any) -> Any:
    """JSON-ready: ``nan``/``inf`` as strings (kept apart, compared exactly)."""
    if isinstance(v, bool):
        return v
    if isinstance(v, tuple | list):
        return [_clean(x) for x in v]
    if isinstance(v, int | np.integer):
        return int(v)
    if isinstance(v, str):
        return v
    v = float(v)
    return v if math.isfinite(v) else repr(v)


def summarise(analysis: Any, dt: float) -> dict[str, Any]:
    """The stored results of one :class:`~servogym.sim._margins.LoopAnalysis` at period ``dt``."""
    from servogym.sim._margins import N_FREQUENCIES, frequency_grid

    m = analysis.margins
    s = analysis.stability
    idx = np.unique(np.linspace(0, N_FREQUENCIES - 1, LOOP_SAMPLES).round().astype(int))
    grid = frequency_grid(dt)[idx]  # display-grid points (crossovers are added between them)
    at = np.searchsorted(analysis.freqs_hz, grid)
    if not np.array_equal(analysis.freqs_hz[at], grid):
        raise RuntimeError("the display grid is not part of the analysis's frequencies")
    return {
        "stability": {
            "stable": bool(s.stable),
            "n_unstable": int(s.n_unstable),
            "spectral_radius": _clean(s.spectral_radius),
            "order": int(s.order),
            "method": s.method,
        },
        "margins": {f.name: _clean(getattr(m, f.name)) for f in dataclasses.fields(m)},
        "n_freqs": int(analysis.freqs_hz.size),
        "loop": [[float(v.real), float(v.imag)] for v in analysis.loop[at]],
    }


def analyse_case(case: dict[str, Any]) -> dict[str, Any]:
    """Every analysis of one case: per latency choice, per holding point."""
    from servogym.chips import get_chip
    from servogym.plants import get_plant
    from servogym.sim._operating import operating_margins

    fam, model = get_chip(case["chip_model"])
    params = fam.make_params(model, case["values"])
    plant = get_plant(case["plant"]).build(case["plant_values"])
    moves = [types.SimpleNamespace(distance=d) for d in case["distances"]]
    dt = fam.sample_time_s(params)
    cache: dict = {}
    out = {}
    for choice in case["latencies"]:
        asm = fam.assumptions_type(**{**case["assumptions"], "loop_latency": choice})
        op = operating_margins(fam, params, asm, plant, moves, cache=cache)
        if list(op.points) != case["holding"]:
            raise RuntimeError(f"holding points changed: {op.points} != {case['holding']}")
        out[choice] = {"worst": op.worst, "points": [summarise(a, dt) for a in op.analyses]}
    return out


def _close(a: Any, b: Any) -> bool:
    if isinstance(a, str) or isinstance(b, str) or isinstance(a, bool) or isinstance(b, bool):
        return a == b
    if a is None or b is None:
        return a is b
    return abs(a - b) <= RTOL * max(abs(a), abs(b)) + ATOL


def compare(stored: Any, new: Any, path: str = "") -> list[str]:
    """Differences between two results (empty when they agree): strings, booleans, counts and
    lengths exactly, floats within ``RTOL`` (+ ``ATOL``)."""
    if isinstance(stored, dict):
        if set(stored) != set(new):
            return [f"{path}: keys {sorted(stored)} != {sorted(new)}"]
        return [d for k in stored for d in compare(stored[k], new[k], f"{path}.{k}")]
    if isinstance(stored, list):
        if not isinstance(new, list) or len(stored) != len(new):
            return [f"{path}: {stored!r} != {new!r} (length)"]
        pairs = enumerate(zip(stored, new, strict=True))
        return [d for i, (s, n) in pairs for d in compare(s, n, f"{path}[{i}]")]
    if (
        isinstance(stored, int)
        and not isinstance(stored, bool)
        and path.endswith(("n_unstable", "order", "worst", "n_freqs"))
    ):
        return [] if stored == new else [f"{path}: {stored} != {new}"]
    return [] if _close(stored, new) else [f"{path}: {stored!r} != {new!r}"]


def write(path: Path = CORPUS) -> dict[str, Any]:
    cases = []
    t0 = time.perf_counter()
    for k, case in enumerate(draw_cases()):
        cases.append(case)
        if k % 25 == 24:
            print(f"{k + 1} cases, {time.perf_counter() - t0:.0f} s", file=sys.stderr)
    corpus = {"seed": SEED, "n_per_pair": N_PER_PAIR, "rtol": RTOL, "atol": ATOL, "cases": cases}
    path.parent.mkdir(parents=True, exist_ok=True)
    with lzma.open(path, "wt") as fh:
        json.dump(corpus, fh, separators=(",", ":"))
    return corpus


def load(path: Path = CORPUS) -> dict[str, Any]:
    with lzma.open(path, "rt") as fh:
        return json.load(fh)


def check_case(case: dict[str, Any]) -> list[str]:
    """Differences between a stored case's results and today's (JSON round trip included)."""
    new = json.loads(json.dumps(analyse_case(case)))
    return compare(case["results"], new, case["instance"])


def describe(corpus: dict[str, Any]) -> str:
    n = {"analyses": 0, "stable": 0, "encirclement": 0, "crossovers": 0, "phase_crossovers": 0}
    for case in corpus["cases"]:
        for res in case["results"].values():
            for pt in res["points"]:
                n["analyses"] += 1
                n["stable"] += pt["stability"]["stable"]
                n["encirclement"] += pt["stability"]["method"] == "encirclement"
                n["crossovers"] += len(pt["margins"]["crossovers"])
                n["phase_crossovers"] += len(pt["margins"]["phase_crossovers"])
    return f"{len(corpus['cases'])} cases: " + ", ".join(f"{v} {k}" for k, v in n.items())


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    mode = ap.add_mutually_exclusive_group(required=True)
    mode.add_argument("--write", action="store_true", help="compute and store the corpus")
    mode.add_argument("--check", action="store_true", help="recompute every case and compare")
    ap.add_argument("--every", type=int, default=1, help="check every n-th case only")
    args = ap.parse_args(argv)
    pinned = all(os.environ.get(k) == v for k, v in AVX2_KERNELS.items())
    if platform.machine() in ("x86_64", "AMD64") and not pinned:  # run again, pinned
        cmd = [sys.executable, str(Path(__file__).resolve()), *(sys.argv[1:] if argv is None
                                                                  else argv)]  # fmt: skip
        return subprocess.call(cmd, env={**os.environ, **AVX2_KERNELS})
    if args.write:
        corpus = write()
        print(f"wrote {CORPUS.relative_to(ROOT)}: {describe(corpus)}")
        return 0
    if args.every < 1:
        ap.error(f"--every must be >= 1; got --every={args.every}")
    corpus = load()
    print(describe(corpus))
    bad = identical = 0
    t0 = time.perf_counter()
    cases = corpus["cases"][:: args.every]
    for case in cases:
        new = json.loads(json.dumps(analyse_case(case)))
        identical += new == case["results"]
        diffs = compare(case["results"], new, case["instance"])
        if diffs:
            bad += 1
            print("\n".join(diffs[:10]))
    dt = time.perf_counter() - t0
    print(
        f"checked {len(cases)} cases in {dt:.1f} s: {bad} differ (rtol {RTOL:g}, atol {ATOL:g}); "
        f"{identical} identical to the last bit"
    )
    return 1 if bad else 0


if __name__ == "__main__":
    sys.exit(main())
