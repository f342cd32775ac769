"""GP on a capped history (issue 20: GP's per-trial overhead): what the GP sees, and that the
same seed still gives the same study."""

from __future__ import annotations

import optuna
import pytest
from optuna.distributions import FloatDistribution
from optuna.trial import TrialState, create_trial

from servogym.autotune import _gp, get_tuner, run_study
from servogym.autotune._gp import (
    GP_KEEP_BEST,
    GP_KEEP_RECENT,
    CappedGPSampler,
    capped_history,
    capped_view,
)

from .helpers import short_problem, trial_table

MIN = [optuna.study.StudyDirection.MINIMIZE]
DIST = {"x": FloatDistribution(-1.0, 1.0)}


def done(number: int, value: float, violation: float | None = None, values=None):
    t = create_trial(
        params={"x": value / 100},
        distributions=DIST,
        values=values or [value],
        system_attrs={} if violation is None else {"constraints": [violation, -1.0]},
    )
    t.number = number
    return t


def running(number: int):
    t = create_trial(state=TrialState.RUNNING, params={"x": 0.0}, distributions=DIST)
    t.number = number
    return t


def numbers(trials) -> list[int]:
    return [t.number for t in trials]


# ---------------------------------------------------------------- which trials the GP sees


def test_capped_history_keeps_the_best_then_the_most_recent_and_every_unfinished_trial():
    costs = [5.0, 1.0, 7.0, 3.0, 9.0, 2.0, 8.0, 6.0, 4.0, 10.0]
    trials = [done(i, c) for i, c in enumerate(costs)] + [running(10), running(11)]
    kept = capped_history(trials, MIN, keep_best=3, keep_recent=2)
    # best three: trials 1 (1.0), 5 (2.0), 3 (3.0); most recent two of the rest: 8, 9.
    assert numbers(kept) == [1, 3, 5, 8, 9, 10, 11]
    # Under the cap nothing is dropped.
    assert capped_history(trials, MIN, keep_best=8, keep_recent=2) == trials
    # Maximized: the best are the largest.
    up = [optuna.study.StudyDirection.MAXIMIZE]
    assert numbers(capped_history(trials, up, keep_best=2, keep_recent=0)) == [4, 9, 10, 11]


def test_capped_history_puts_feasible_trials_first_then_the_least_violating():
    # trial 0 has the lowest cost but breaks a constraint: the feasible 2 and 3 come first,
    # then the least violating infeasible trial (4, violation 0.1, over 0 with 5.0).
    trials = [done(0, 0.5, violation=5.0), done(1, 9.0, violation=0.3),
              done(2, 4.0, -1.0), done(3, 2.0, 0.0), done(4, 8.0, violation=0.1),
              done(5, 1.0, violation=0.2)]  # fmt: skip
    assert numbers(capped_history(trials, MIN, keep_best=3, keep_recent=0)) == [2, 3, 4]
    assert numbers(capped_history(trials, MIN, keep_best=2, keep_recent=1)) == [2, 3, 5]


def test_capped_history_ranks_multi_objective_trials_by_pareto_front():
    both = MIN * 2
    trials = [done(0, 0, values=[3.0, 3.0]), done(1, 0, values=[1.0, 4.0]),
              done(2, 0, values=[4.0, 1.0]), done(3, 0, values=[2.0, 2.0]),
              done(4, 0, values=[5.0, 5.0])]  # fmt: skip
    # Front {1, 2, 3}, then {0}, then {4}.
    assert numbers(capped_history(trials, both, keep_best=3, keep_recent=0)) == [1, 2, 3]
    assert numbers(capped_history(trials, both, keep_best=4, keep_recent=0)) == [0, 1, 2, 3]


@pytest.mark.parametrize(
    ("kw", "match"),
    [
        ({"keep_best": 0, "keep_recent": 30},
         r"keep_best must be an integer >= 1; got keep_best=0"),
        ({"keep_best": 20, "keep_recent": -1},
         r"keep_recent must be an integer >= 0; got keep_recent=-1"),
        ({"keep_best": 2.5, "keep_recent": 30},
         r"keep_best must be an integer >= 1; got keep_best=2.5"),
        ({"keep_best": 4, "keep_recent": 5},
         r"keep_best \+ keep_recent must be >= 10 .*keep_best=4, keep_recent=5"),
    ],
)  # fmt: skip
def test_a_cap_that_is_not_a_count_or_too_small_for_the_random_start_is_refused(kw, match):
    with pytest.raises(ValueError, match=match):
        CappedGPSampler(seed=0, **kw)
    with pytest.raises(ValueError, match=match):
        get_tuner("gp", **kw)


def test_the_view_reads_the_capped_trials_and_writes_to_the_real_study(tmp_path):
    # A journal file: the view works on the default storage of servogym tune, not only memory.
    storage = optuna.storages.JournalStorage(
        optuna.storages.journal.JournalFileBackend(str(tmp_path / "s.journal"))
    )
    study = optuna.create_study(storage=storage, study_name="s")
    for i in range(30):
        t = study.ask(DIST)
        t.set_constraint("c", float(i % 3) - 1.0)
        study.tell(t, float((i * 7) % 30))
    pending = study.ask(DIST)
    view = capped_view(study, 5, 7)
    complete = view.get_trials(deepcopy=False, states=(TrialState.COMPLETE,))
    assert len(complete) == 12
    assert numbers(view.get_trials(deepcopy=False)) == numbers(
        capped_history(study.get_trials(deepcopy=False), study.directions, 5, 7)
    )
    assert pending.number in numbers(view.get_trials(deepcopy=False))
    real = {t.number: t for t in study.get_trials(deepcopy=False)}
    for t in complete:  # constraints and values are the study's own
        assert t.constraints == real[t.number].constraints
        assert t.values == real[t.number].values
    view._storage.set_trial_system_attr(pending._trial_id, "written", 1)
    assert study.trials[pending.number].system_attrs["written"] == 1


def test_the_gp_is_fitted_on_the_capped_history_and_proposes_from_it(monkeypatch):
    seen = []
    real_sample = optuna.samplers.GPSampler.sample_relative

    def spy(self, study, trial, space):
        seen.append(len(study.get_trials(deepcopy=False, states=(TrialState.COMPLETE,))))
        return real_sample(self, study, trial, space)

    monkeypatch.setattr(optuna.samplers.GPSampler, "sample_relative", spy)
    study = optuna.create_study(sampler=optuna.samplers.RandomSampler(seed=1))
    two = {"x": FloatDistribution(-1.0, 1.0), "y": FloatDistribution(-1.0, 1.0)}
    for _ in range(25):
        t = study.ask(two)
        t.set_constraint("c", t.params["x"] - 0.5)
        study.tell(t, (t.params["x"] - 0.2) ** 2 + t.params["y"] ** 2)
    study.sampler = CappedGPSampler(seed=3, keep_best=6, keep_recent=6)
    t = study.ask(two)
    assert seen == [12]
    # The GP proposed the point (Optuna stores a relative sample on the trial), not the
    # random start; and it is a point the GP alone gives: a fresh sampler with the seed too.
    assert any(k.startswith("gp:relative_params") for k in study.trials[-1].system_attrs)
    study.tell(t, state=TrialState.FAIL)
    study.sampler = CappedGPSampler(seed=3, keep_best=6, keep_recent=6)
    assert study.ask(two).params == t.params


def test_the_tuner_asks_every_trial_with_a_new_sampler_of_that_trials_seed():
    tuner = get_tuner("gp")
    assert (tuner.keep_best, tuner.keep_recent) == (GP_KEEP_BEST, GP_KEEP_RECENT)
    a, b = tuner.make_sampler(1, object()), tuner.make_sampler(1, object())
    assert a is not b and isinstance(a, CappedGPSampler)


# ---------------------------------------------------------------- reproducibility


def test_gp_with_an_active_cap_gives_the_same_study_for_the_same_seed_and_another_for_another(
    monkeypatch,
):
    # keep 4 + 6 of 16: from trial 11 on the cap drops trials, so this exercises the view.
    monkeypatch.setattr(_gp, "GP_KEEP_BEST", 4)
    monkeypatch.setattr(_gp, "GP_KEEP_RECENT", 6)
    assert get_tuner("gp").keep_best == 4
    problem = short_problem("MC2100", "rotary", seed=6, margins=False)
    kw = {"storage": None, "batch_size": 2}
    r1 = run_study(problem, "gp", 16, n_workers=1, **kw)
    r2 = run_study(problem, "gp", 16, n_workers=2, **kw)
    assert trial_table(r1.trials) == trial_table(r2.trials)
    other = short_problem("MC2100", "rotary", seed=7, margins=False)
    r3 = run_study(other, "gp", 16, n_workers=1, **kw)
    assert trial_table(r3.trials)[12:] != trial_table(r1.trials)[12:]


# ---------------------------------------------------------------- Optuna internals pinned


def test_optuna_gp_sampler_still_reads_the_acquisition_budget_servogym_sets():
    # Optuna has no public argument for the acquisition optimizer's budget; servogym sets
    # two private attributes. This fails if Optuna renames them or stops reading them.
    import inspect

    fresh = optuna.samplers.GPSampler(seed=0)
    for attr, optuna_value in _gp._OPTUNA_ACQF_ATTRS.items():
        assert getattr(fresh, attr) == optuna_value
    source = inspect.getsource(optuna.samplers.GPSampler._optimize_acqf)
    assert "n_preliminary_samples=self._n_preliminary_samples" in source
    assert "n_local_search=self._n_local_search" in source
    ours = CappedGPSampler(seed=0)._gp
    assert ours._n_preliminary_samples == _gp.GP_PRELIMINARY_SAMPLES
    assert ours._n_local_search == _gp.GP_LOCAL_SEARCHES


def test_a_gp_sampler_without_the_private_attributes_is_refused_with_the_reason():
    class Changed:
        _n_local_search = 10

    with pytest.raises(RuntimeError, match=r"no integer _n_preliminary_samples.*update"):
        _gp._set_acqf_budget(Changed(), 512, 4)
