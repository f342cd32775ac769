"""Scenarios, the evaluator and the cost of docs/cost.md."""

from __future__ import annotations

import math

import numpy as np
import pytest

from servogym.chips import ParameterError
from servogym.plants import PLANTS, PlantParameterError
from servogym.sim._scenario import (
    COST_CAP,
    DEFAULT_MOVES,
    DIVERGENCE_PENALTY,
    CostWeights,
    Evaluator,
    MoveSpec,
    Scenario,
    move_cost,
    robust_cost,
)


def test_default_moves_cover_every_plant():
    assert set(DEFAULT_MOVES) == set(PLANTS)


@pytest.mark.parametrize("plant", list(PLANTS))
def test_default_parameters_give_a_finite_safe_cost(plant):
    sc = Scenario("MC58000", plant)
    e = Evaluator(sc).evaluate(sc.default_params())
    assert not e.diverged
    assert 0 <= e.cost <= COST_CAP
    assert len(e.move_costs) == len(sc.moves) == 2


def test_divergence_costs_more_than_any_safe_episode_and_earlier_is_worse():
    sc = Scenario("MC2100", "rotary")
    ev = Evaluator(sc)
    # Full bias, no feedback: the axis runs into its end stop.
    wild = sc.params(dict(kp=0, kd=0, ki=0, bias=32767, position_error_limit=2**31 - 1))
    e = ev.evaluate(wild)
    assert e.metrics[-1].divergence_reason == "travel_limit"
    assert e.diverged
    assert DIVERGENCE_PENALTY < e.cost < 2 * DIVERGENCE_PENALTY
    # A chip motion error after a few ticks costs nearly the full 2x penalty.
    early = ev.evaluate(sc.params(dict(kp=1, kd=0, ki=0, position_error_limit=1)))
    assert early.diverged and early.cost > e.cost
    # Maximal gains saturate into chatter on this plant: safe, but expensive.
    bang = ev.evaluate(sc.params(dict(kp=32767, kd=0, ki=0, kout=32767)))
    assert not bang.diverged and bang.saturation_fraction > 0.5
    assert bang.cost > ev.evaluate(sc.default_params()).cost


def test_cost_terms_by_hand():
    from servogym.sim._metrics import EpisodeMetrics

    m = EpisodeMetrics(
        iae=2.0, itae=0.0, max_following_error=40.0, overshoot=8.0, settling_time=0.05,
        steady_state_error=1.0, rms_command=0.5, saturation_fraction=0.25, chatter=0.001,
        settled=True, diverged=False, divergence_tick=-1, divergence_reason="none",
        n_ticks=1000, dt=0.001,
    )  # fmt: skip
    # D = 2000 counts: e_ref = max(4, 2) = 4; T = 1 s; settle window 0.1 s.
    expected = 2.0 / 1.0 / 4 + 0.1 * 40 / 4 + 0.5 * 8 / 4 + 0.05 / 0.1 + 1 / 4 + 0.1 * 0.5
    expected += 0.25 + 100 * 0.001
    assert move_cost(m, 2000, 0.1, CostWeights()) == pytest.approx(expected)
    heavy = CostWeights(mean_error=1e9)
    assert move_cost(m, 2000, 0.1, heavy) == COST_CAP


def test_plant_instances_change_the_cost_and_come_back_identical():
    sc = Scenario("MC2100", "vertical-axis", randomise=True)
    ev = Evaluator(sc)
    params = sc.params(dict(kp=200, kd=1200, ki=60, bias=1500))
    rng = np.random.default_rng(0)
    a, b = sc.draw_plant(rng), sc.draw_plant(rng)
    ca, cb, ca2 = (ev.evaluate(params, v).cost for v in (a, b, a))
    assert ca != cb and ca == ca2
    assert robust_cost([ev.evaluate(params, v) for v in (a, b)], "worst") == max(ca, cb)
    assert robust_cost([ev.evaluate(params, v) for v in (a, b)]) == pytest.approx((ca + cb) / 2)


def test_move_spec_in_counts():
    m = MoveSpec(0.5, 2.0, 20.0, 0.1).to_move(1000.0, start_counts=7)
    assert (m.distance_counts, m.max_velocity_counts_per_s, m.start_counts) == (500, 2000.0, 7)
    assert math.isclose(m.max_acceleration_counts_per_s2, 20000.0)


def test_bad_scenarios_name_the_problem():
    with pytest.raises(ParameterError, match="unknown chip model 'MC9999'"):
        Scenario("MC9999", "rotary")
    with pytest.raises(PlantParameterError, match="payload_kg"):
        Scenario("MC2100", "vertical-axis", plant_values={"payload_kg": 1e6})
    with pytest.raises(ValueError, match="mode must be 'mean' or 'worst'"):
        robust_cost([], "median")
