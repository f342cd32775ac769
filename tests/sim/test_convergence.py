"""The default integration agrees with the fine reference (docs/simulation.md, "Integration").

Every chip family (and the Magellan with its biquads) on every plant family, at the chip's
default servo period and the slowest usable one, with a safe set tuned there
(tests/sim/data/convergence_sets.json, made by ``experiments/convergence.py sets``) and random
sets from the legal ranges. The sweep over every shipped set runs in experiments/convergence.py
(results in experiments/results/convergence.jsonl).
"""

from __future__ import annotations

import dataclasses
import json
from pathlib import Path

import numpy as np
import pytest

from servogym.autotune._space import SearchSpace
from servogym.plants import PLANTS
from servogym.sim import Scenario
from servogym.sim._convergence import (
    TRACE_TOLERANCE_COUNTS,
    agreement,
    compare,
    period_settings,
)
from servogym.sim._scenario import Evaluation

SETS = json.loads((Path(__file__).parent / "data" / "convergence_sets.json").read_text())
CHIPS = ("MC2100", "MC58000", "TurboPMAC2", "6250")


def test_the_safe_sets_cover_every_chip_plant_and_period():
    want = {f"{c}/{p}/{t}" for c in CHIPS for p in PLANTS for t in period_settings(c)}
    assert set(SETS) == want


@pytest.mark.parametrize("key", sorted(SETS))
def test_safe_set_agrees_with_the_reference(key):
    rec = SETS[key]
    fix = period_settings(rec["chip"])[rec["period"]]
    scenario = Scenario(rec["chip"], rec["plant"])
    params = scenario.params(rec["values"])
    for name, value in fix.items():
        assert getattr(params, name) == value  # the set runs at the period it names
    a = agreement(scenario, params)
    assert a.ok, a.why
    if a.settled:
        assert a.max_trace_difference <= TRACE_TOLERANCE_COUNTS


def random_safe_sets(key: str, n: int) -> list[dict[str, int]]:
    """Random sets near the safe set: every searched register moved by up to +-0.05 of its
    unit interval (log-scaled gains: a factor of about 1.5 to 2), seeded by the key."""
    rec = SETS[key]
    space = SearchSpace.for_chip(rec["chip"], None, period_settings(rec["chip"])[rec["period"]])
    u0 = space.to_unit(rec["values"])
    rng = np.random.default_rng(sorted(SETS).index(key))
    return [
        space.values_from_unit(
            {k: float(np.clip(v + rng.uniform(-0.05, 0.05), 0, 1)) for k, v in u0.items()}
        )
        for _ in range(n)
    ]


@pytest.mark.slow
@pytest.mark.parametrize("key", sorted(SETS))
def test_random_safe_sets_agree_with_the_reference(key):
    rec = SETS[key]
    scenario = Scenario(rec["chip"], rec["plant"])
    for values in random_safe_sets(key, 3):
        a = agreement(scenario, scenario.params(values))
        assert a.ok, a.why


def _evaluation(cost, diverged=False, trace=(0, 5, 9), settled=True, fe=10.0):
    from servogym.sim._metrics import EpisodeMetrics
    from servogym.sim._runner import EpisodeResult, Traces

    m = EpisodeMetrics(iae=0.0, itae=0.0, max_following_error=fe, overshoot=0.0,
                       settling_time=0.0, steady_state_error=0.0, rms_command=0.0,
                       saturation_fraction=0.0, chatter=0.0, settled=settled,
                       diverged=diverged, divergence_tick=-1,
                       divergence_reason="error_bound" if diverged else "none",
                       n_ticks=len(trace), dt=1e-4)  # fmt: skip
    arr = np.asarray(trace, np.int64)
    tr = Traces(arr * 0.0, arr, arr, arr * 0, arr * 0, arr * 0.0)
    return Evaluation(cost=cost, move_costs=(cost,), metrics=(m,), diverged=diverged,
                      max_following_error=fe, saturation_fraction=0.0,
                      results=(EpisodeResult(m, tr),))  # fmt: skip


def test_the_rule_by_hand():
    ref = _evaluation(1.0, trace=(0, 100, 200))
    assert compare(_evaluation(1.0, trace=(0, 108, 200)), ref).ok  # 8 counts: at the bound
    assert not compare(_evaluation(1.0, trace=(0, 109, 200)), ref).ok
    # the bound grows with the peak following error: 0.5 % of 4000 = 20 counts
    big = _evaluation(1.0, trace=(0, 100, 200), fe=4000.0)
    assert compare(_evaluation(1.0, trace=(0, 120, 200)), big).ok
    assert not compare(_evaluation(1.0, trace=(0, 121, 200)), big).ok
    # cost of a settling set: 5 % + 0.02
    assert compare(_evaluation(1.069, trace=(0, 100, 200)), ref).ok
    assert not compare(_evaluation(1.071, trace=(0, 100, 200)), ref).ok
    # a different verdict never agrees
    assert "verdict" in compare(_evaluation(1.0, diverged=True), ref).why
    # not settled: only the cost, within 10 % or both at the cap
    # settled but poorly damped (cost 10 or more): the cost rule
    slow = _evaluation(40.0, trace=(0, 100, 200))
    assert compare(_evaluation(41.0, trace=(0, 400, 200)), slow).ok
    osc = _evaluation(50.0, settled=False, trace=(0, 4000, -4000))
    assert compare(_evaluation(54.9, settled=False, trace=(0, -4000, 4000)), osc).ok
    assert not compare(_evaluation(55.1, settled=False), osc).ok
    capped = _evaluation(100.0, settled=False)
    assert compare(_evaluation(100.0, settled=False, trace=(9, 9, 9)), capped).ok


def test_the_default_is_coarser_than_the_reference():
    rec = SETS["MC2100/rotary/default"]
    scenario = Scenario(rec["chip"], rec["plant"])
    from servogym.sim._scenario import Evaluator

    loop = Evaluator(scenario).loop
    assert loop.substeps == 1 and loop.integrator == "rk4"
    ref = Evaluator(dataclasses.replace(scenario, substeps=32)).loop
    assert ref.substeps == 32
