"""Every export is byte-identical to the corpus of exports stored before the register tables
were unified (experiments/export_corpus.py; issue 23, point 6)."""

from __future__ import annotations

import importlib.util
import json
import sys
from pathlib import Path

import pytest

_PATH = Path(__file__).resolve().parents[2] / "experiments" / "export_corpus.py"


@pytest.fixture(scope="module")
def corpus_module():
    spec = importlib.util.spec_from_file_location("export_corpus", _PATH)
    module = importlib.util.module_from_spec(spec)
    sys.modules["export_corpus"] = module
    spec.loader.exec_module(module)
    return module


@pytest.fixture(scope="module")
def corpus(corpus_module):
    return corpus_module.load()


def _stored(corpus):
    return {(e["model"], e["kind"], e["fmt"]): e["text"] for e in corpus["exports"]}


def test_corpus_covers_every_model_and_format(corpus_module, corpus):
    from servogym.chips import families

    pairs = {(e["model"], e["fmt"]) for e in corpus["exports"]}
    wanted = {(m, f) for fam in families().values() for m in fam.models for f in fam.formats_for(m)}
    assert pairs == wanted
    kinds = [c["kind"] for c in corpus["cases"]]
    assert sum(k.startswith("random") for k in kinds) == corpus_module.N_RANDOM
    assert sum(k.startswith("shipped") for k in kinds) > 0


def test_chip_descriptions_unchanged(corpus_module, corpus):
    chips = [corpus_module.describe(f, m) for f, m in corpus_module._models()]
    assert json.loads(json.dumps(chips)) == corpus["chips"]


def test_random_sets_drawn_again_from_the_seed(corpus_module, corpus):
    assert json.loads(json.dumps(corpus_module.inputs())) == corpus["cases"]


def test_every_export_byte_identical_and_read_back(corpus_module, corpus):
    problems = corpus_module.check_exports(corpus["cases"], _stored(corpus))
    assert problems == []


def test_a_changed_byte_is_found(corpus_module, corpus):
    stored = _stored(corpus)
    key = next(k for k in stored if k[2] != "json")
    stored[key] = stored[key].replace("\n", " \n", 1)
    case = next(c for c in corpus["cases"] if (c["model"], c["kind"]) == key[:2])
    problems = corpus_module.check_exports([case], stored)
    assert problems == [f"{key}: the export differs from the corpus"]
