"""servobench-v1: the suite, the optunahub contract, the PMAC registers an engineer sets, and
the best-known sets (each one through `servogym check --instance`)."""

from __future__ import annotations

import json
import math
import warnings

import numpy as np
import optuna
import pytest
from optunahub.benchmarks import BaseProblem
from typer.testing import CliRunner

from servogym.autotune.bench import get_suite, load_best_known, load_reference
from servogym.autotune.bench._instance import CONSTRAINT_NAMES_V1
from servogym.autotune.bench._reference import ReferenceConfig
from servogym.autotune.bench._suite import DEFAULT_SUITE, SUITES, TRIP_FACTOR
from servogym.chips import ParameterError

V1 = "servobench-v1"
SUITE = get_suite(V1)
PMAC_ID = "servobench-v1/turbopmac2/rotary/light/fast"
FAMILY = {"MC2100": "pmd", "MC58000": "pmd", "TurboPMAC2": "pmac", "6250": "parker6k"}


def test_v1_is_the_default_suite_and_v0_stays_loadable():
    assert DEFAULT_SUITE == V1 == get_suite().name
    assert set(SUITES) == {"servobench-v0", V1}
    assert len(get_suite("servobench-v0").ids("all")) == 36
    with pytest.raises(ValueError, match="the suites are servobench-v0, servobench-v1"):
        get_suite("servobench-v2")


def test_v1_splits_cover_every_family_load_and_task_in_both():
    train, heldout = SUITE.ids("train"), SUITE.ids("heldout")
    assert len(train) >= 36 and len(heldout) >= 12
    assert not set(train) & set(heldout)
    assert len(set(SUITE.ids("all"))) == len(train) + len(heldout)
    for split in (train, heldout):
        specs = [SUITE.spec(i) for i in split]
        assert {FAMILY[s.chip_model] for s in specs} == {"pmd", "pmac", "parker6k"}
        assert {s.plant for s in specs} == {"rotary", "two-mass", "vertical-axis", "arm"}
        assert {s.load for s in specs} == {"light", "heavy"}
        assert {s.task for s in specs} == {"fast", "slow"}
    for i in SUITE.ids("all"):
        assert i.startswith(f"{V1}/") and SUITE.spec(i).id == i and SUITE.spec(i).suite == V1


def test_pmac_instances_hold_the_registers_an_engineer_sets_for_the_task():
    inst = SUITE.instance(PMAC_ID)
    fixed = inst.problem.space.fixed
    assert fixed["output_limit"] == 32767  # the default 62.5 % cannot move the heavy loads
    # Ixx11 (1/16 count) = TRIP_FACTOR x the following-error constraint (1 % of the move)
    assert fixed["fatal_following_error_limit"] == pytest.approx(
        16 * TRIP_FACTOR * inst.following_error_limit, abs=1
    )
    assert "output_limit" not in inst.space and "output_limit" in inst.values_from_unit(
        {k: 0.0 for k in inst.search_space}
    )
    assert inst.evaluate({"output_limit": 32767}) == inst.evaluate({})
    with pytest.raises(ParameterError, match="holds output_limit=32767; got output_limit=20480"):
        inst.evaluate({"output_limit": 20480})
    # the other families hold nothing
    assert all(not SUITE.spec(i).fixed for i in SUITE.ids("all") if "turbopmac2" not in i)


def test_instance_is_an_optunahub_problem_whose_search_space_evaluate_accepts():
    inst = SUITE.instance(PMAC_ID)
    assert isinstance(inst, BaseProblem)
    unit = {k: 0.05 for k in inst.search_space}
    cost = inst.evaluate(unit)
    assert math.isfinite(cost)
    assert cost == inst.evaluate(inst.values_from_unit(unit))  # the two views agree
    cons = inst.evaluate_constraints(unit)
    assert list(cons) == list(CONSTRAINT_NAMES_V1)
    assert all(math.isfinite(v) for v in cons.values())
    with pytest.raises(ParameterError, match="needs exactly the search_space keys"):
        inst.evaluate({k: v for k, v in list(unit.items())[:-1]})
    key = next(iter(unit))
    with pytest.raises(ParameterError, match=f"-1 <= {key} <= 1; got {key}=1.5"):
        inst.evaluate({**unit, key: 1.5})


def test_evaluate_then_evaluate_constraints_simulates_once(monkeypatch):
    inst = SUITE.instance(PMAC_ID)
    calls = []
    ev = inst.evaluator
    original = ev.evaluate
    monkeypatch.setattr(ev, "evaluate", lambda p: calls.append(1) or original(p))
    unit = {k: -0.1 for k in inst.search_space}
    inst.evaluate(unit)
    inst.evaluate_constraints(unit)
    assert len(calls) == 1
    inst.evaluate({k: 0.1 for k in inst.search_space})
    assert len(calls) == 2


def test_optunahub_base_call_with_a_plain_optuna_study():
    # optunahub's own BaseProblem.__call__ (not servogym's override): suggest the search
    # space, set the constraints on the trial, return evaluate(params).
    inst = SUITE.instance("servobench-v1/6250/rotary/light/fast")
    study = optuna.create_study(
        sampler=optuna.samplers.TPESampler(seed=0, constraints_func=None),
        directions=inst.directions,
    )
    study.optimize(lambda t: BaseProblem.__call__(inst, t), n_trials=4)
    for t in study.trials:
        assert set(t.params) == set(inst.search_space)
        assert list(t.constraints) == list(CONSTRAINT_NAMES_V1)
        assert t.value == inst.evaluate(t.params)
        feasible = all(v <= 0 for v in inst.evaluate_constraints(t.params).values())
        assert feasible == all(v <= 0 for v in t.constraints.values())
    # and servogym's own __call__ gives the same trial values
    study2 = optuna.create_study(sampler=optuna.samplers.TPESampler(seed=0))
    study2.optimize(inst, n_trials=4)
    assert [t.value for t in study2.trials] == [t.value for t in study.trials]


def test_scipy_minimises_an_instance_with_its_constraints():
    from scipy.optimize import NonlinearConstraint, minimize

    inst = SUITE.instance("servobench-v1/mc2100/rotary/light/fast")
    keys = list(inst.search_space)

    def point(x: np.ndarray) -> dict[str, float]:
        return dict(zip(keys, np.clip(x, -1.0, 1.0).tolist(), strict=True))

    def cons(x: np.ndarray) -> np.ndarray:
        return np.array(list(inst.evaluate_constraints(point(x)).values()))

    x0 = np.zeros(len(keys))
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        res = minimize(
            lambda x: inst.evaluate(point(x)),
            x0,
            method="COBYLA",
            constraints=[NonlinearConstraint(cons, -np.inf, 0.0)],
            options={"maxiter": 25},
        )
    assert math.isfinite(res.fun) and res.fun <= inst.evaluate(point(x0))
    assert res.fun == inst.evaluate(point(res.x))


def test_reference_search_is_over_ten_times_the_largest_budget_from_several_methods():
    config = ReferenceConfig.for_suite(V1)
    assert config.n_evaluations >= 10 * 200
    assert config.check_candidates > 0 and config.design_trials > 0


def _records() -> dict[str, dict]:
    return load_best_known(V1)


def test_best_known_file_has_provenance_and_every_record_passed_its_check():
    data = load_reference(V1)
    if not data:
        pytest.skip("servobench-v1 has no best-known data file yet")
    assert "superseded" not in data
    assert data["method"]["evaluations_per_instance"] >= 2000
    assert {"servogym", "optuna", "pmd_spec", "pmac_spec", "parker6k_spec"} <= set(data["versions"])
    for i, rec in data["instances"].items():
        assert i in SUITE.ids("all")
        assert math.isfinite(rec["cost"]) and rec["check_cost"] == rec["cost"], i
        if rec["feasible"]:  # a best-known set: it passed the check
            assert rec["check"]["passed"] and rec["check"]["n_checked"] >= 1, i
        else:  # no best-known set yet: the record says why (none safe, or none passed)
            assert rec["n_feasible"] == 0 or rec["check"]["passed"] is False, i


@pytest.mark.parametrize("instance_id", SUITE.ids("all"))
def test_every_best_known_set_reproduces_and_passes_servogym_check(instance_id, tmp_path):
    rec = _records().get(instance_id)
    if rec is None or not rec["feasible"]:
        pytest.skip(f"{instance_id} has no best-known set yet")
    from servogym.autotune._report import write_param_set
    from servogym.cli import app

    inst = SUITE.instance(instance_id)
    assert inst.evaluate(rec["values"]) == rec["cost"]  # the stored set reproduces its cost
    write_param_set(inst.problem.space.make_params(rec["values"]), tmp_path, hardware=False)
    path = tmp_path / "best_params.json"
    res = CliRunner().invoke(app, ["check", str(path), "--instance", instance_id, "--json"])
    assert res.exit_code == 0, res.output
    doc = json.loads(res.output)
    assert doc["passed"] and doc["instance"] == instance_id


def test_benchmark_list_prints_the_split_and_the_pmac_registers():
    from servogym.cli import app

    res = CliRunner().invoke(app, ["benchmark", "--list", "--split", "heldout"])
    assert res.exit_code == 0, res.output
    lines = res.output.strip().splitlines()
    assert [ln.split("\t")[0] for ln in lines] == SUITE.ids("heldout")
    pmac = next(ln for ln in lines if "/turbopmac2/" in ln)
    assert "output_limit=32767" in pmac and "fatal_following_error_limit=" in pmac
    res = CliRunner().invoke(app, ["benchmark", "--suite", V1])
    assert res.exit_code != 0 and "--out is required" in res.output


def test_median_ci_brackets_the_median_and_keeps_inf():
    from servogym.autotune.bench._report import median_ci

    x = np.array([1.0, 1.1, 1.2, 1.3, 5.0])
    lo, hi = median_ci(x)
    assert lo <= 1.2 <= hi and lo >= 1.0 and hi <= 5.0
    assert median_ci(x) == (lo, hi)  # seeded
    lo, hi = median_ci(np.array([1.0, np.inf, np.inf, np.inf]))
    assert hi == math.inf
    assert all(math.isnan(v) for v in median_ci(np.array([])))


def test_report_rows_have_v1_fields_per_family_and_the_default_tuner(tmp_path):
    from servogym.autotune._tuners import DEFAULT_TUNER
    from servogym.autotune.bench import load_results, plan_jobs, run_jobs, write_report

    ids = ["servobench-v1/mc2100/rotary/light/fast", "servobench-v1/turbopmac2/rotary/light/fast"]
    jobs, _ = plan_jobs([SUITE.instance(i) for i in ids], ["random"], [4], [0])
    run_jobs(jobs, tmp_path)
    records = load_results(tmp_path)
    best = {i: {"cost": 1.0, "feasible": True} for i in ids}
    summary = write_report(records, tmp_path, best_known=best, budgets=[4])
    # what `servogym tune` runs without --tuner (the tune test suite asserts the CLI uses it)
    assert summary["default_tuner"] == DEFAULT_TUNER
    row = summary["rows"][0]
    for key in ("within_5pct", "within_10pct", "unsafe_fraction", "median_rel_ci95"):
        assert key in row
    flags = [f for r in records for f in r["flags"]]
    unsafe = sum(1 for f in flags if f & 0b100111)  # diverged, FE, saturation, margins
    assert row["unsafe_fraction"] == pytest.approx(unsafe / len(flags))
    assert set(summary["rows_by_family"]) == {"PMD", "PMAC"}
    assert (tmp_path / "ecdf_pmac.png").is_file() and (tmp_path / "ecdf_pmd.png").is_file()
    assert "## Summary on the 1 PMAC instances" in (tmp_path / "report.md").read_text()


def test_benchmark_worker_processes_start_with_one_blas_thread(monkeypatch):
    import concurrent.futures as cf
    import multiprocessing
    import os

    from servogym.autotune.bench._runner import ONE_THREAD_ENV, one_blas_thread

    monkeypatch.delenv("OPENBLAS_NUM_THREADS", raising=False)
    monkeypatch.setenv("OMP_NUM_THREADS", "3")  # a user's own setting is kept
    ctx = multiprocessing.get_context("spawn")
    with one_blas_thread(), cf.ProcessPoolExecutor(1, mp_context=ctx) as pool:
        seen = pool.submit(os.getenv, "OPENBLAS_NUM_THREADS").result()
        omp = pool.submit(os.getenv, "OMP_NUM_THREADS").result()
    assert seen == ONE_THREAD_ENV["OPENBLAS_NUM_THREADS"] == "1" and omp == "3"
    assert "OPENBLAS_NUM_THREADS" not in os.environ and os.environ["OMP_NUM_THREADS"] == "3"


@pytest.mark.parametrize("tuner", ["safe", "tpe", "cmaes", "random", "sobol"])
def test_an_anytime_tuners_smaller_budget_is_the_prefix_of_its_larger_run(tuner):
    # The report takes budget b of an anytime tuner from the first b trials of its largest
    # run: that holds only if trial n never depends on the budget. (GP: the same sampler
    # code path as TPE's ask; too slow to run twice here.)
    from servogym.autotune.bench._runner import ANYTIME_TUNERS, Job, compute_job

    assert tuner in ANYTIME_TUNERS
    inst_id = "servobench-v1/6250/rotary/light/fast"
    short = compute_job(Job(tuner, inst_id, 1, 6))
    long = compute_job(Job(tuner, inst_id, 1, 14))
    assert len(short["cost"]) == 6 and len(long["cost"]) == 14
    assert long["cost"][:6] == short["cost"] and long["flags"][:6] == short["flags"]


def test_dry_run_estimate_times_real_evaluations_not_the_kept_one(tmp_path):
    # The instance keeps its last evaluation; the estimate must time the simulation itself
    # (an evaluation with margins at every latency takes milliseconds on any machine).
    import re

    from servogym.cli import app

    inst = "servobench-v1/mc2100/rotary/light/fast"
    args = ["benchmark", "--instance", inst, "--tuners", "tpe", "--budget", "20",
            "--seeds", "1", "--dry-run", "--out", str(tmp_path)]  # fmt: skip
    res = CliRunner().invoke(app, args)
    assert res.exit_code == 0, res.output
    ms = float(re.search(r"mean\s+evaluation\s+([\d.]+) ms", res.output).group(1))
    assert ms > 2.0
    # and a dry run leaves the folder's config.json (the last real run's) alone
    assert not (tmp_path / "config.json").exists()


def test_a_failing_job_in_the_process_pool_loses_no_finished_record(tmp_path):
    from servogym.autotune.bench._runner import Job, load_job, run_jobs

    ok = [Job("random", "servobench-v1/6250/rotary/light/fast", s, 2) for s in range(3)]
    bad = Job("random", "servobench-v1/6250/rotary/light/nope", 0, 2)  # fails on its worker
    with pytest.raises(KeyError, match="unknown instance"):
        run_jobs([*ok, bad], tmp_path, workers=2)
    assert all(load_job(tmp_path, j) is not None for j in ok)


def test_check_instance_refuses_a_set_without_the_instances_held_registers(tmp_path):
    from servogym.autotune._report import write_param_set
    from servogym.cli import app

    inst = SUITE.instance(PMAC_ID)
    params = inst.problem.space.make_params({**inst.default_values(), "output_limit": 32767})
    write_param_set(params, tmp_path, hardware=False)  # Ixx11 at the chip default, not held
    res = CliRunner().invoke(
        app, ["check", str(tmp_path / "best_params.json"), "--instance", PMAC_ID]
    )
    assert res.exit_code != 0
    limit = inst.problem.space.fixed["fatal_following_error_limit"]
    assert f"holds fatal_following_error_limit={limit} (the file has 32000)" in res.output


def test_a_jobs_result_is_the_cheapest_safe_trial_that_passes_the_check(monkeypatch):
    from servogym.autotune.bench import _runner
    from servogym.autotune.bench._report import Run
    from servogym.sim import _check

    job = _runner.Job("safe", "servobench-v1/6250/rotary/light/fast", 0, 24)
    rec = _runner.compute_job(job)
    assert set(rec["checked"]) == {"20", "24"}
    safe = [(c, i) for i, (c, f) in enumerate(zip(rec["cost"], rec["flags"], strict=True))
            if c is not None and f == 0]  # fmt: skip
    assert safe, "the safe tuner found no safe trial: nothing to check"
    hit = rec["checked"]["24"]
    inst = SUITE.instance(job.instance)
    if hit is not None:  # it passes the check, and no cheaper safe trial does
        assert hit["cost"] == rec["cost"][hit["trial"]] and rec["flags"][hit["trial"]] == 0
        report = _check.check_params(
            inst.problem.space.make_params(hit["values"]), inst.problem.scenario
        )
        assert report.passed
        assert Run(rec).best_at(24) == hit["cost"] >= min(c for c, _ in safe)
    # a check that fails every set: no result, whatever the costs
    monkeypatch.setattr(_check, "check_params", lambda *a, **k: type("R", (), {"passed": False}))
    problem = inst.problem
    trials = [type("T", (), {"user_attrs": {"registers": inst.default_values()}})] * 3
    none = _runner.checked_results(problem, trials, [1.0, 2.0, None], [0, 0, 1], 3)
    assert none == {"3": None}
    assert Run({**rec, "checked": none, "budget": 3}).best_at(3) == math.inf


def test_a_larger_budget_never_reports_a_worse_checked_result(monkeypatch):
    from servogym.autotune.bench import _runner
    from servogym.sim import _check

    passing = {1}  # only trial 1 passes the check
    trials = [type("T", (), {"user_attrs": {"registers": {"sgp": n}}}) for n in range(40)]
    space = type("S", (), {"make_params": staticmethod(lambda values: values)})()
    problem = type("P", (), {"space": space, "scenario": None})()
    monkeypatch.setattr(_check, "check_params", lambda params, scenario: type(
        "R", (), {"passed": params["sgp"] in passing}))  # fmt: skip
    # within 20 trials, trial 1 is the cheapest; the next 20 are cheaper and fail the check
    costs = [5.0, 4.0] + [6.0] * 18 + [3.0 - 0.01 * k for k in range(20)]
    got = _runner.checked_results(problem, trials, costs, [0] * 40, 40)
    assert got["20"]["trial"] == 1 and got["40"]["trial"] == 1  # kept, not None
    passing.add(39)  # a cheaper passing trial in the larger budget replaces it
    got = _runner.checked_results(problem, trials, costs, [0] * 40, 40)
    assert got["20"]["trial"] == 1 and got["40"]["trial"] == 39
