"""The tuner case every registered tuner must pass: legal sets, the budget, improvement."""

from __future__ import annotations

from typing import ClassVar

import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from servogym.autotune import GAIN_MAPS, TUNERS, TuneError, get_tuner, run_study, tuner_names
from servogym.chips._family import all_models
from servogym.sim import Evaluator

from .helpers import short_problem

TUNER_NAMES = tuner_names()
OPTUNA = ["tpe", "gp", "cmaes", "random", "sobol"]
CLASSICAL = ["vendor-step", "relay", "model-based"]
DEFAULT = ["safe"]  # the default tuner (test_safe_tuner.py)


def test_the_registry_holds_every_tuner_of_the_issue():
    assert set(TUNER_NAMES) == set(OPTUNA + CLASSICAL + DEFAULT)


class Recorder:
    """An Evaluator that keeps every parameter set it is asked to run."""

    seen: ClassVar[list] = []

    def __init__(self, scenario):
        self.inner = Evaluator(scenario)
        self.plant, self.loop = self.inner.plant, self.inner.loop

    def evaluate(self, params, plant_values=None, *, traces=False):
        Recorder.seen.append(params)
        return self.inner.evaluate(params, plant_values, traces=traces)


def assert_legal(problem, values):
    space = problem.space.family.parameter_space(problem.space.chip_model)
    for name in space:
        value = values[name] if isinstance(values, dict) else getattr(values, name)
        assert space[name].validate(value) == value, (name, value)


@pytest.mark.parametrize("tuner", TUNER_NAMES)
@settings(
    max_examples=2,
    deadline=None,
    suppress_health_check=[HealthCheck.too_slow, HealthCheck.function_scoped_fixture],
)
@given(
    seed=st.integers(0, 2**16),
    model=st.sampled_from(sorted(all_models())),
    n_fixed=st.integers(0, 2),
)
def test_every_tuner_proposes_only_legal_sets_within_the_budget(tuner, seed, model, n_fixed):
    # Hold the last n_fixed tunable registers at their "off" value: 0 where legal, else the
    # lowest (the lowest PMAC notch coefficient, -2.0, would make an unstable filter).
    tunable = all_models()[model].parameter_space(model).tunable()
    fixed = {s.name: min(max(s.low, 0), s.high) for s in tunable[len(tunable) - n_fixed :]}
    problem = short_problem(model, seed=seed, fixed=fixed)
    budget = max(TUNERS[tuner].min_budget, 10)
    Recorder.seen = []
    if tuner in CLASSICAL and problem.space.family.name not in GAIN_MAPS:
        with pytest.raises(TuneError, match="register_gain_map"):
            run_study(problem, tuner, budget, storage=None)
        return
    result = run_study(
        problem, tuner, budget, storage=None, n_workers=2, batch_size=4,
        evaluator_factory=Recorder,
    )  # fmt: skip
    assert Recorder.seen, "nothing was evaluated"
    for params in Recorder.seen:
        assert_legal(problem, params)
    for t in result.trials:
        assert_legal(problem, t.user_attrs["registers"])
        if t.user_attrs["kind"] != "experiment":
            for name, value in (fixed or {}).items():
                assert t.user_attrs["registers"][name] == value
    assert len(result.trials) <= budget
    if tuner in OPTUNA:
        assert len(result.trials) == budget
    assert_legal(problem, result.best_params)


IMPROVE_BUDGET = {"gp": 40, "cmaes": 100, "random": 150, "vendor-step": 40, "relay": 40,
                  "model-based": 40}  # fmt: skip


@pytest.mark.parametrize("tuner", TUNER_NAMES)
def test_every_tuner_improves_on_the_chip_defaults_on_the_nominal_rotary_plant(tuner):
    # GP fits one model per constraint: without them it asks twice as fast. The derivative is
    # sampled every cycle: with the loop latency (PMD-A13) a derivative held over 10 or more
    # cycles leaves this plant no stable set, and finding the one value near 1 in 1..32767
    # would be most of the search. No margin constraints here: whether each tuner improves
    # on the defaults at these budgets is the question (tune's margins and check are tested
    # in test_tune_check.py; blind search rarely meets them in 60 trials).
    problem = short_problem("MC2100", "rotary", seed=1, constraints=tuner != "gp",
                            fixed={"derivative_time": 1}, margins=False)  # fmt: skip
    default = Evaluator(problem.scenario).evaluate(problem.scenario.default_params()).cost
    budget = IMPROVE_BUDGET.get(tuner, 60)
    result = run_study(problem, tuner, budget, storage=None, n_workers=2, batch_size=4)
    assert result.feasible
    if tuner == "gp":
        # GP at 40 evaluations reaches 61.5 against the defaults' 69.6 on the issue-13 loop
        # (measured 2026-12-01); half the defaults needs more than this test can afford.
        assert result.best.values[0] < default
    else:
        assert result.best.values[0] < 0.5 * default
    assert len(result.trials) <= budget
    # The stored cost is the cost of the stored registers.
    again = Evaluator(problem.scenario).evaluate(result.best_params).cost
    assert again == result.best.values[0]


def test_budgets_below_a_procedures_minimum_and_multi_objective_misuse_are_refused():
    problem = short_problem()
    with pytest.raises(TuneError, match="'vendor-step' tuner needs a budget of at least 8"):
        run_study(problem, "vendor-step", 3, storage=None)
    mo = short_problem(objectives=("cost", "max_following_error"))
    with pytest.raises(TuneError, match="'cmaes' tuner minimizes one objective"):
        run_study(mo, "cmaes", 10, storage=None)
    with pytest.raises(TuneError, match=r"unknown tuner 'tpee'.*Did you mean tpe"):
        get_tuner("tpee")
