"""Budget accounting and feasibility-first selection (docs/autotune.md, "Budget").

Every evaluation is one trial: a sampler fills the budget exactly, whatever its remainder
after whole batches; a classical procedure never exceeds it and, at budgets below what its
procedure needs, spends all of it; an experiment or candidate beyond it is refused. The
tuned set is the cheapest *feasible* trial, however cheap an infeasible one is.
"""

from __future__ import annotations

from collections import Counter

import optuna
import pytest

from servogym.autotune import TUNERS, run_study
from servogym.autotune._session import BudgetExhausted, Session, best_trial
from servogym.autotune._space import register_values

from .helpers import short_problem


@pytest.mark.parametrize("batch_size", [4, 3])
def test_a_sampler_spends_exactly_k_batches_plus_one(batch_size):
    # budget = 2 batches + 1: two full batches, then a batch of one trial.
    budget = 2 * batch_size + 1
    r = run_study(short_problem(), "random", budget, storage=None, n_workers=2,
                  batch_size=batch_size)  # fmt: skip
    assert len(r.trials) == budget
    assert [t.number for t in r.trials] == list(range(budget))
    # (the batch a trial was asked in is no longer stored: since issue 12 every trial is
    # asked on the shared study, seeded by its number)
    assert Counter(t.user_attrs["kind"] for t in r.trials) == {"sample": budget}


def test_a_warm_start_counts_against_the_budget():
    # Trial 0 is the warm start; the sampler then asks 1..4 and 5..8: 9 trials in all.
    problem = short_problem()
    warm = register_values(problem.scenario.default_params())
    r = run_study(problem, "random", 9, storage=None, n_workers=1, batch_size=4,
                  warm_start=warm)  # fmt: skip
    assert len(r.trials) == 9
    assert r.trials[0].user_attrs["kind"] == "warm_start"
    assert [t.user_attrs["kind"] for t in r.trials[1:]] == ["sample"] * 8


@pytest.mark.parametrize("tuner", ["vendor-step", "relay", "model-based"])
def test_a_classical_tuner_spends_exactly_a_budget_it_cannot_outgrow(tuner):
    # At its minimum budget, and one above, every evaluation is used: the procedures
    # truncate their search phases to leave room for their candidates.
    low = TUNERS[tuner].min_budget
    for budget in (low, low + 1):
        r = run_study(short_problem(), tuner, budget, storage=None, n_workers=1)
        assert len(r.trials) == budget, (tuner, budget)
        kinds = Counter(t.user_attrs["kind"] for t in r.trials)
        assert kinds["experiment"] >= 1 and kinds["candidate"] >= 1
        assert set(kinds) <= {"experiment", "candidate"}


def test_an_experiment_or_candidates_beyond_the_budget_are_refused():
    problem = short_problem()
    values = register_values(problem.scenario.default_params())
    ran = []
    with Session(problem, budget=2, storage=None, study_name="b", tuner_name="t") as s:
        s.experiment(values, "first", lambda ev: ran.append(1) or {"ok": 1})
        assert s.remaining == 1
        # Two candidates with one evaluation left: refused whole, nothing evaluated.
        with pytest.raises(BudgetExhausted, match="2 candidates but 1 evaluations left"):
            s.candidates([(values, "a"), (values, "b")])
        assert s.remaining == 1 and len(s.trials()) == 1
        (outcome,) = s.candidates([(values, "last")])
        assert s.remaining == 0 and len(s.trials()) == 2
        # Nothing left: the experiment is refused before it runs.
        with pytest.raises(BudgetExhausted, match="no evaluation left for an experiment"):
            s.experiment(values, "too many", lambda ev: ran.append(2) or {})
        with pytest.raises(BudgetExhausted, match="1 candidates but 0 evaluations left"):
            s.candidates([(values, "c")])
    assert ran == [1]
    assert [t.user_attrs["kind"] for t in s.trials()] == ["experiment", "candidate"]
    assert outcome.cost == s.trials()[1].values[0]


def frozen(number: int, cost: float, fe: float, kind: str = "sample", second: float = 0.0):
    t = optuna.trial.create_trial(
        values=[cost, second], constraints={"following_error": fe}, user_attrs={"kind": kind}
    )
    t.number = number
    return t


def test_an_infeasible_trial_cheaper_than_a_feasible_one_is_not_selected():
    trials = [frozen(0, 5.0, 0.0), frozen(1, 1.0, 0.5), frozen(2, 3.0, -2.0)]
    best, feasible = best_trial(trials, multi_objective=False)
    # Trial 1 costs least but breaks its constraint; trial 0's constraint value 0 is met
    # (feasible means every value <= 0); trial 2 is the cheapest feasible one.
    assert best.number == 2 and feasible
    best, feasible = best_trial(trials[:2], multi_objective=False)
    assert best.number == 0 and feasible
    # With no feasible trial, the cheapest of all, flagged infeasible.
    best, feasible = best_trial([frozen(0, 5.0, 1.0), frozen(1, 1.0, 0.5)], False)
    assert best.number == 1 and not feasible
    # Ties in cost go to the earlier trial; experiments never count.
    best, _ = best_trial([frozen(0, 2.0, 0.0, "experiment"), frozen(3, 2.0, 0.0),
                          frozen(1, 2.0, 0.0)], False)  # fmt: skip
    assert best.number == 1


def test_multi_objective_selection_is_feasible_pareto_first():
    # Trial 1 dominates both others but is infeasible; of the feasible front {0, 2}, the
    # one best in the first objective is 2.
    trials = [frozen(0, 4.0, -1.0, second=1.0), frozen(1, 1.0, 1.0, second=0.5),
              frozen(2, 3.0, 0.0, second=2.0), frozen(3, 5.0, 0.0, second=3.0)]  # fmt: skip
    best, feasible = best_trial(trials, multi_objective=True)
    assert best.number == 2 and feasible


def test_batch_of_one_and_illegal_counts():
    from servogym.autotune import TuneError

    # batch_size = 1 (the smallest legal): one trial per batch.
    r = run_study(short_problem(), "random", 2, storage=None, n_workers=1, batch_size=1)
    assert [t.number for t in r.trials] == [0, 1]
    for name in ("budget", "n_workers", "batch_size"):
        for bad in (0, True, 2.0):
            kw = {"budget": 2, "n_workers": 1, "batch_size": 1, name: bad}
            with pytest.raises(TuneError, match=f"{name} must be an integer >= 1; got {name}="):
                Session(short_problem(), storage=None, study_name="b", tuner_name="t", **kw)


def test_a_resume_may_ask_for_exactly_the_budget_already_spent(tmp_path):
    from servogym.autotune import TuneError

    url = f"sqlite:///{tmp_path / 'study.db'}"
    run_study(short_problem(), "random", 3, storage=url, n_workers=1, batch_size=2)
    # Budget 3 = the 3 stored trials: nothing left to do, nothing refused.
    r = run_study(short_problem(), "random", 3, storage=url, n_workers=1, resume=True)
    assert len(r.trials) == 3
    with pytest.raises(TuneError, match="already holds 3 trials, more than budget=2"):
        run_study(short_problem(), "random", 2, storage=url, n_workers=1, resume=True)


def test_every_trial_carries_its_constraints():
    problem = short_problem()
    r = run_study(problem, "random", 9, storage=None, n_workers=2)
    assert len(r.trials) == 9
    # Constraints on (the default): every scored trial stores the problem's constraint
    # values, so feasibility-first selection can see them (margins since issue 13).
    names = {"max_following_error", "saturation_fraction", "diverged", "gain_margin",
             "phase_margin"}  # fmt: skip
    for t in r.trials:
        assert set(t.constraints) == names, t.number


def test_progress_reports_the_best_feasible_cost():
    # The running best of the progress callback skips infeasible trials, however cheap,
    # and counts a constraint value of exactly 0 as feasible.
    seen = []
    with Session(short_problem(), budget=5, storage=None, study_name="b", tuner_name="t",
                 progress=lambda done, budget, best: seen.append(best)) as s:  # fmt: skip
        for cost, fe in ((5.0, 0.5), (4.0, 0.0), (1.0, 0.5), (3.0, -1.0)):
            s._add(optuna.trial.create_trial(
                values=[cost], constraints={"following_error": fe}, user_attrs={"kind": "sample"}
            ))  # fmt: skip
    assert seen == [None, 4.0, 4.0, 3.0]


def test_default_storage_is_a_journal_in_the_run_folder(tmp_path):
    from servogym.autotune._session import default_storage_url

    assert default_storage_url(tmp_path) == f"{tmp_path.resolve()}/study.journal"
    (tmp_path / "study.db").write_bytes(b"")  # a run folder from before issue 12
    assert default_storage_url(tmp_path) == f"sqlite:///{tmp_path.resolve()}/study.db"


def test_a_resumed_study_does_not_repeat_its_warm_start(tmp_path):
    url = f"sqlite:///{tmp_path / 'study.db'}"
    problem = short_problem()
    warm = register_values(problem.scenario.default_params())
    run_study(problem, "random", 1, storage=url, n_workers=1, warm_start=warm)
    r = run_study(problem, "random", 3, storage=url, n_workers=1, resume=True)
    assert [t.user_attrs["kind"] for t in r.trials] == ["warm_start", "sample", "sample"]


@pytest.mark.parametrize("storage", ["memory", "journal"])
def test_a_budget_of_one_with_a_warm_start_scores_the_warm_start(tmp_path, storage):
    # The queued warm start counts toward the budget before it is evaluated: a budget of 1
    # leaves nothing "remaining", yet the warm start itself must still be run and scored.
    problem = short_problem()
    warm = register_values(problem.scenario.default_params())
    url = None if storage == "memory" else str(tmp_path / "study.journal")
    r = run_study(problem, "tpe", 1, storage=url, n_workers=1, warm_start=warm)
    assert [(t.state.name, t.user_attrs["kind"]) for t in r.trials] == [("COMPLETE", "warm_start")]
    assert r.best_values == warm
