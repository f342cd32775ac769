"""A corpus of today's exports, so that a change to the register tables is shown byte-identical.

    .venv/bin/python experiments/export_corpus.py --write    # (re)write the corpus
    .venv/bin/python experiments/export_corpus.py --check    # compare every case (about 1 min)

The corpus (``tests/chips/data/export_corpus.json.xz``) holds, for every chip model and every
export format the model takes: the model's default set, the shipped sets of
``tests/sim/data/convergence_sets.json`` for that model, and its share of 1,000 random legal
sets (seed 20250123; 100 per model): each case's inputs (parameter values, assumption
switches, axis) and the exported text. It also holds each model's ``servogym chips --json``
entry (every register's width, range, default, unit, source) and the random sets' inputs.

``--check`` draws the random sets again from the seed (they depend on every register's range
and order, so a changed table shows here), exports every case again and compares the text
byte for byte, and reads each export back to the identical set. ``tests/chips/
test_export_corpus.py`` runs a sample of the same checks in the test suite.
"""

from __future__ import annotations

import argparse
import json
import lzma
import sys
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
CORPUS = ROOT / "tests" / "chips" / "data" / "export_corpus.json.xz"
SHIPPED = ROOT / "tests" / "sim" / "data" / "convergence_sets.json"
SEED = 20250123
N_RANDOM = 1000
CREATED = "2025-01-23T12:00:00+00:00"
"""The fixed ``created`` entry of every JSON export (reproducible files)."""


def _models() -> list[tuple[Any, str]]:
    from servogym.chips import families

    return [(fam, name) for fam in families().values() for name in fam.models]


def describe(fam: Any, model: str) -> dict[str, Any]:
    """A model's entry as ``servogym chips --json`` prints it (cli.chips)."""
    return {
        "family": fam.name,
        "model": model,
        "sample_time_s": fam.sample_time_s(fam.make_params(model)),
        "export_formats": list(fam.formats_for(model)),
        "native_format": fam.native_format(model),
        "parameters": fam.parameter_space(model).describe(),
    }


def _random_value(spec: Any, rng: np.random.Generator) -> int:
    """A legal value: uniform over the range, or (half the time) log-uniform for a log register."""
    if spec.log and rng.random() < 0.5:
        return spec.from_unit(float(rng.uniform(-1.0, 1.0)))
    return int(rng.integers(spec.low, spec.high, endpoint=True))


def random_case(fam: Any, model: str, rng: np.random.Generator) -> dict[str, Any]:
    """One random legal set of ``model``: values, assumptions and an axis, JSON-ready."""
    space = fam.parameter_space(model)
    values: dict[str, Any] = {name: _random_value(space[name], rng) for name in space}
    if fam.name == "parker6k":
        values["ssfr"] = int(rng.choice([1, 2, 4, 8]))
        gains = ("sgp", "sgi", "sgv", "sgvf", "sgaf")
        n_sets = int(rng.integers(0, 5, endpoint=True))
        values["sgset"] = [{g: _random_value(space[g], rng) for g in gains} for _ in range(n_sets)]
        n_switches = int(rng.integers(0, 4, endpoint=True)) if n_sets else 0
        ticks = sorted(rng.choice(100_000, size=n_switches, replace=False).tolist())
        values["sgenb"] = [[int(t), int(rng.integers(1, n_sets, endpoint=True))] for t in ticks]
    asm_type = fam.assumptions_type
    assumptions = {name: str(rng.choice(choices)) for name, choices in asm_type.CHOICES.items()}
    chip = fam.models[model]
    n_axes = getattr(chip, "n_axes", None) or chip.n_motors
    axis = int(rng.integers(1, n_axes, endpoint=True))
    return {"values": values, "assumptions": assumptions, "axis": axis}


def inputs() -> list[dict[str, Any]]:
    """Every case's inputs: defaults, shipped sets, then the seeded random sets, per model."""
    shipped = json.loads(SHIPPED.read_text())
    rng = np.random.default_rng(SEED)
    models = _models()
    per_model = N_RANDOM // len(models)
    out = []
    for fam, model in models:
        default = fam.make_params(model).to_dict()
        default.pop("model")
        out.append({"model": model, "kind": "default", "values": default, "assumptions": None})
        for key, entry in sorted(shipped.items()):
            if entry["chip"] == model:
                out.append(
                    {"model": model, "kind": f"shipped {key}", "values": entry["values"],
                     "assumptions": None}
                )  # fmt: skip
        for i in range(per_model):
            case = random_case(fam, model, rng)
            out.append({"model": model, "kind": f"random {i}", **case})
    return out


def export_all(cases: list[dict[str, Any]]) -> Iterator[tuple[dict[str, Any], str, str]]:
    """``(case, fmt, text)`` for every case and every format its model takes."""
    from servogym.chips import get_chip

    for case in cases:
        fam, model = get_chip(case["model"])
        params = fam.make_params(model, case["values"])
        for fmt in fam.formats_for(model):
            kw: dict[str, Any] = {"assumptions": case["assumptions"]}
            if fmt == "json":
                kw["created"] = CREATED
            elif "axis" in case:
                kw["axis"] = case["axis"]
            yield case, fmt, fam.export(params, fmt, **kw)


def write() -> None:
    cases = inputs()
    texts = [
        {"model": c["model"], "kind": c["kind"], "fmt": fmt, "text": text}
        for c, fmt, text in export_all(cases)
    ]
    doc = {
        "seed": SEED,
        "created": CREATED,
        "chips": [describe(fam, model) for fam, model in _models()],
        "cases": cases,
        "exports": texts,
    }
    CORPUS.parent.mkdir(parents=True, exist_ok=True)
    data = json.dumps(doc, sort_keys=True, separators=(",", ":")).encode()
    CORPUS.write_bytes(lzma.compress(data, preset=9 | lzma.PRESET_EXTREME))
    print(f"wrote {CORPUS.relative_to(ROOT)}: {len(texts)} exports of {len(cases)} sets, "
          f"{CORPUS.stat().st_size / 1e6:.2f} MB")  # fmt: skip


def load() -> dict[str, Any]:
    """The stored corpus."""
    return json.loads(lzma.decompress(CORPUS.read_bytes()))


def check_exports(
    cases: list[dict[str, Any]], stored: dict[tuple[str, str, str], str]
) -> list[str]:
    """Re-export ``cases``; the differences from ``stored`` and failed read-backs, as messages."""
    from servogym.chips import get_chip

    problems = []
    seen = 0
    for case, fmt, text in export_all(cases):
        key = (case["model"], case["kind"], fmt)
        seen += 1
        if stored.get(key) != text:
            problems.append(f"{key}: the export differs from the corpus")
            continue
        fam, model = get_chip(case["model"])
        back = fam.import_params(text, fmt, model)
        if back != fam.make_params(model, case["values"]):
            problems.append(f"{key}: the export does not read back to the same set")
    expected = {(c["model"], c["kind"]) for c in cases}
    wanted = sum(1 for (m, k, _f) in stored if (m, k) in expected)
    if seen != wanted:
        problems.append(f"{seen} exports made, the corpus has {wanted} for these cases")
    return problems


def check() -> int:
    corpus = load()
    problems = []
    chips = [describe(fam, model) for fam, model in _models()]
    if json.loads(json.dumps(chips)) != corpus["chips"]:
        problems.append("the chip descriptions (servogym chips --json) differ from the corpus")
    cases = inputs()
    if json.loads(json.dumps(cases)) != corpus["cases"]:
        problems.append("the seeded random sets differ: a register's range or order changed")
    stored = {(e["model"], e["kind"], e["fmt"]): e["text"] for e in corpus["exports"]}
    problems += check_exports(corpus["cases"], stored)
    for p in problems[:20]:
        print(p)
    n = len(corpus["exports"])
    print(f"{n} exports of {len(corpus['cases'])} sets: {len(problems)} problems")
    return 1 if problems else 0


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    group = parser.add_mutually_exclusive_group(required=True)
    group.add_argument("--write", action="store_true", help="write the corpus")
    group.add_argument("--check", action="store_true", help="compare every case with it")
    args = parser.parse_args(argv)
    if args.write:
        write()
        return 0
    return check()


if __name__ == "__main__":
    sys.exit(main())
