"""The loop-margin analysis agrees with the corpus of analyses stored before it was made faster
(experiments/margins_corpus.py): stability verdicts, counts and methods exactly, margins,
crossovers, bandwidth, spectral radius and the open loop within ``RTOL`` (1e-9 relative)."""

from __future__ import annotations

import copy
import importlib.util
import sys
from pathlib import Path

import pytest

_PATH = Path(__file__).resolve().parents[2] / "experiments" / "margins_corpus.py"

EVERY = 8
"""The test suite checks every EVERY-th case (the experiment's ``--check`` checks all)."""


@pytest.fixture(scope="module")
def corpus_module():
    spec = importlib.util.spec_from_file_location("margins_corpus", _PATH)
    module = importlib.util.module_from_spec(spec)
    sys.modules["margins_corpus"] = module
    spec.loader.exec_module(module)
    return module


@pytest.fixture(scope="module")
def corpus(corpus_module):
    return corpus_module.load()


def test_corpus_covers_every_chip_plant_latency_and_method(corpus_module, corpus):
    from servogym.chips import get_chip

    cases = corpus["cases"]
    assert len(cases) == len(corpus_module.CHIP_MODELS) * len(corpus_module.PLANTS) * 25
    pairs = {(c["instance"].split("/")[1], c["plant"]) for c in cases}
    assert pairs == {(m, p) for m in corpus_module.CHIP_MODELS for p in corpus_module.PLANTS}
    for c in cases:
        fam, _ = get_chip(c["chip_model"])
        assert list(c["results"]) == list(fam.assumptions_type.CHOICES["loop_latency"])
    points = [p for c in cases for r in c["results"].values() for p in r["points"]]
    stable = sum(p["stability"]["stable"] for p in points)
    assert 0.3 * len(points) < stable < 0.9 * len(points)
    assert {p["stability"]["method"] for p in points} == {"eigenvalues", "encirclement"}
    assert sum(len(p["margins"]["crossovers"]) > 1 for p in points) > 50
    assert sum(c["values"].get("biquad1_enable", 0) for c in cases) > 10


def test_sample_of_cases_agrees(corpus_module, corpus):
    cases = corpus["cases"][::EVERY]
    problems = {c["instance"]: d for c in cases if (d := corpus_module.check_case(c))}
    assert problems == {}


def test_a_difference_is_found(corpus_module, corpus):
    case = copy.deepcopy(next(c for c in corpus["cases"] if c["plant"] == "two-mass"))
    fresh = corpus_module.analyse_case(case)
    assert corpus_module.compare(case["results"], fresh) == []
    choice = next(iter(fresh))
    point = fresh[choice]["points"][0]
    point["margins"]["bandwidth_hz"] *= 1 + 10 * corpus_module.RTOL
    point["stability"]["order"] += 1
    point["margins"]["crossovers"].append([1.0, 2.0, 3.0])
    found = corpus_module.compare(case["results"], fresh)
    assert [d.split(":")[0] for d in found] == [
        f".{choice}.points[0].stability.order",
        f".{choice}.points[0].margins.bandwidth_hz",
        f".{choice}.points[0].margins.crossovers",
    ]
