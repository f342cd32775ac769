"""The loop-margin analysis agrees with the corpus of analyses stored before it was made faster
(experiments/margins_corpus.py): stability verdicts, counts and methods exactly, margins,
crossovers, bandwidth, spectral radius and the open loop within ``RTOL`` (1e-9 relative); and
its faster parts equal the slow ones they replaced: the refinement that examines only new
intervals, and Brent's method run in lockstep (``scipy.optimize.brentq``'s floats)."""

from __future__ import annotations

import copy
import importlib.util
import math
import subprocess
import sys
from pathlib import Path

import numpy as np
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
    """Through the experiment's ``--check`` (a process with numpy's and OpenBLAS's kernels
    pinned to the AVX2 ones the corpus was stored with: ``AVX2_KERNELS``)."""
    out = subprocess.run(
        [sys.executable, str(_PATH), "--check", "--every", str(EVERY)],
        capture_output=True, text=True, timeout=600,
    )  # fmt: skip
    n = len(corpus["cases"][::EVERY])
    assert out.returncode == 0, out.stdout[-3000:] + out.stderr[-2000:]
    assert f"checked {n} cases in" in out.stdout and ": 0 differ" in out.stdout


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


def _old_refined_grid(loop_fn, theta):
    """The refinement as it was: every interval of the whole grid re-examined every pass."""
    from servogym.sim._margins import MAX_GRID_POINTS, REFINE_LOG_MAGNITUDE, REFINE_PHASE_RAD

    theta = np.unique(theta)
    vals = loop_fn(theta)
    for _ in range(60):
        with np.errstate(divide="ignore", invalid="ignore"):
            dmag = np.abs(np.diff(np.log(np.abs(vals))))
            dphase = np.abs(np.angle(vals[1:] / vals[:-1]))
        wide = np.diff(theta) > 1e-10 * theta[1:]
        bad = np.flatnonzero(
            ((dmag > REFINE_LOG_MAGNITUDE) | (dphase > REFINE_PHASE_RAD) | ~np.isfinite(dmag))
            & wide
        )
        if not bad.size or theta.size + 3 * bad.size > MAX_GRID_POINTS:
            break
        frac = np.array([0.25, 0.5, 0.75])
        new_t = (theta[bad, None] + (theta[bad + 1] - theta[bad])[:, None] * frac).ravel()
        theta = np.concatenate([theta, new_t])
        vals = np.concatenate([vals, loop_fn(new_t)])
        order = np.argsort(theta, kind="stable")
        theta, vals = theta[order], vals[order]
    return theta, vals


@pytest.mark.parametrize("q", [3.0, 300.0, 3e5])
def test_refinement_examining_new_intervals_only_gives_the_same_grid(q):
    from servogym.sim._margins import _base_grid, _refined_grid

    def loop_fn(t):  # a resonance of quality q at 0.3 rad and a zero of L at 2 rad
        s = 1j * np.asarray(t)
        return 50 * (s - 2j) / (s * (s**2 + 0.3 * s / q + 0.09))

    base = _base_grid(2 * np.pi * 1e-6)
    theta, vals = _refined_grid(loop_fn, base)
    want_t, want_v = _old_refined_grid(loop_fn, base)
    assert theta.size > base.size + 100
    np.testing.assert_array_equal(theta, want_t)
    np.testing.assert_array_equal(vals, want_v)


def _brentq_functions():
    return [
        lambda x: math.sin(3 * x) - 0.2,
        lambda x: x**3 - 2 * x - 5,
        lambda x: math.exp(x) - 1e3,
        lambda x: math.atan(1e4 * (x - 0.7071)),  # steep
        lambda x: (x - 1.3) ** 3,  # a triple root: slow, bisection steps
        lambda x: math.log(abs(math.cos(x)) + 1e-300) + 0.5,
    ]


def test_lockstep_brent_lands_on_the_floats_of_scipy_brentq():
    import scipy.optimize

    from servogym.sim._margins import ROOT_RTOL, _Brent, _solve_all

    rng = np.random.default_rng(5)
    jobs = []
    for f in _brentq_functions():
        for _ in range(40):
            a, b = sorted(rng.uniform(-3.0, 6.0, 2))
            fa, fb = f(a), f(b)
            if fa * fb < 0:
                xtol = float(rng.choice([1e-14 * b if b > 0 else 1e-14, 1e-8, 2e-12]))
                try:  # (brentq gives up on some brackets of the discontinuous last one)
                    scipy.optimize.brentq(f, a, b, xtol=xtol, rtol=ROOT_RTOL)
                except RuntimeError:
                    continue
                jobs.append((f, a, b, xtol, _Brent(a, b, fa, fb, xtol, ROOT_RTOL)))
    assert len(jobs) > 60

    def values(points, pending):
        fn = {id(s): f for f, *_, s in jobs}
        return [fn[id(s)](float(x)) for s, x in zip(pending, points, strict=True)]

    _solve_all([s for *_, s in jobs], values)
    for f, a, b, xtol, solver in jobs:
        want, info = scipy.optimize.brentq(f, a, b, xtol=xtol, rtol=ROOT_RTOL, full_output=True)
        assert solver.root == want, (a, b, xtol)
        assert solver.iterations == info.iterations


def test_brent_bracket_without_a_sign_change_is_refused():
    from servogym.sim._margins import ROOT_RTOL, _Brent

    with pytest.raises(ValueError, match="f\\(a\\) and f\\(b\\) must have different signs"):
        _Brent(0.0, 1.0, 1.0, 2.0, 1e-12, ROOT_RTOL)
    assert _Brent(0.0, 1.0, 0.0, 2.0, 1e-12, ROOT_RTOL).root == 0.0
    assert _Brent(0.0, 1.0, -1.0, 0.0, 1e-12, ROOT_RTOL).root == 1.0
