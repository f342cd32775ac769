"""Same seed, same study: whatever the number of workers, and in a fresh process."""

from __future__ import annotations

import json
import subprocess
import sys

import pytest

from servogym.autotune import run_study

from .helpers import short_problem, trial_table


@pytest.mark.parametrize("tuner", ["tpe", "cmaes", "sobol", "model-based"])
def test_same_seed_gives_the_same_study_with_one_or_two_workers(tuner):
    problem = short_problem(seed=3)
    runs = [run_study(problem, tuner, 20, storage=None, n_workers=w, batch_size=4) for w in (1, 2)]
    assert trial_table(runs[0].trials) == trial_table(runs[1].trials)
    assert runs[0].best_values == runs[1].best_values


def test_a_different_seed_gives_a_different_study():
    a = run_study(short_problem(seed=3), "tpe", 12, storage=None, batch_size=4)
    b = run_study(short_problem(seed=4), "tpe", 12, storage=None, batch_size=4)
    assert trial_table(a.trials) != trial_table(b.trials)


def test_robust_tuning_draws_the_same_plants_and_aggregates_them():
    problem = short_problem(seed=5, n_plants=3, robust_mode="worst")
    plants = problem.plant_instances()
    assert plants == short_problem(seed=5, n_plants=3).plant_instances()
    assert plants != short_problem(seed=6, n_plants=3).plant_instances()
    assert len({p["load_inertia_kgm2"] for p in plants}) == 3
    runs = [run_study(problem, "random", 8, storage=None, n_workers=w) for w in (1, 2)]
    assert trial_table(runs[0].trials) == trial_table(runs[1].trials)
    for t in runs[0].trials:
        outcome = t.user_attrs["outcome"]
        assert len(outcome["costs"]) == 3
        assert t.values[0] == max(outcome["costs"])


SCRIPT = """
import json, sys
sys.path.insert(0, {root!r})
from tests.autotune.helpers import short_problem
from servogym.autotune import run_study
r = run_study(short_problem(seed=3), "tpe", 12, storage=None, batch_size=4)
print(json.dumps([[t.number, list(t.values), t.user_attrs["registers"]] for t in r.trials]))
"""


def test_same_seed_gives_the_same_study_in_a_fresh_process():
    import pathlib

    root = str(pathlib.Path(__file__).resolve().parents[2])
    out = subprocess.run(
        [sys.executable, "-c", SCRIPT.format(root=root)],
        capture_output=True, text=True, check=True, timeout=300,
    )  # fmt: skip
    there = json.loads(out.stdout.strip().splitlines()[-1])
    here = run_study(short_problem(seed=3), "tpe", 12, storage=None, batch_size=4)
    assert there == [[t.number, list(t.values), t.user_attrs["registers"]] for t in here.trials]
