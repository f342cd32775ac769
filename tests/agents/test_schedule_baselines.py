"""The gain-scheduling study's pieces: the observed load, the gain table, the reference twin
of an env, and experiments/schedule_policies.py's baselines and intervals (issue 21)."""

from __future__ import annotations

import importlib.util
import json
import math
import sys
from pathlib import Path

import gymnasium as gym
import numpy as np
import pytest

import servogym  # noqa: F401
from servogym.agents import ConstantPolicy, GainTablePolicy, reference_env, run_episodes
from servogym.sim import REFERENCE_SUBSTEPS

ROTARY = "servogym/Schedule-PMD-RotaryInertia-v1"
_SCRIPT = Path(__file__).parents[2] / "experiments" / "schedule_policies.py"


@pytest.fixture(scope="module")
def study():
    sys.path.insert(0, str(_SCRIPT.parent))
    spec = importlib.util.spec_from_file_location("schedule_policies", _SCRIPT)
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    return mod


def test_observed_load_reads_the_part_on_loaded_moves_and_empty_otherwise():
    env = gym.make(ROTARY, action_type="unit", n_moves=4)
    u = env.unwrapped
    obs, info = env.reset(seed=7)
    seen = [u.observed_load(obs)]
    for _ in range(3):
        obs, *_, info = env.step(u.actions.from_values({}))
        seen.append(u.observed_load(obs))
    part, empty = info["part_value"], u.scenario.plant_values.get("load_inertia_kgm2", 3e-5)
    # even moves run empty, odd ones carry the part
    assert seen[0] == pytest.approx(empty, rel=1e-9)
    assert seen[1] == pytest.approx(part, rel=1e-9)
    assert seen[2] == pytest.approx(empty, rel=1e-9)
    assert seen[3] == pytest.approx(part, rel=1e-9)
    assert part > 3 * empty


def test_observed_load_needs_the_condition():
    env = gym.make("servogym/Schedule-PMD-Rotary-v1", n_moves=2)
    with pytest.raises(ValueError, match="condition=True"):
        env.unwrapped.observed_load(np.zeros(env.observation_space.shape))
    with pytest.raises(ValueError, match="condition=True"):
        GainTablePolicy(env, [(1e-4, {"kp": 10})])


def test_gain_table_chooses_the_nearest_point_in_log_scale():
    env = gym.make(ROTARY, action_type="unit", n_moves=2)
    u = env.unwrapped
    light, heavy = {"kp": 30, "kd": 100}, {"kp": 90, "kd": 400}
    table = GainTablePolicy(env, [(3e-5, light), (9e-4, heavy)])
    obs, _ = env.reset(seed=3)
    assert u.actions.to_values(table(obs))["kp"] == 30  # empty: the light set
    obs, *_ = env.step(table(obs))
    load = u.observed_load(obs)
    want = heavy if abs(math.log(load / 9e-4)) < abs(math.log(load / 3e-5)) else light
    assert u.actions.to_values(table(obs))["kp"] == want["kp"]
    for bad in ([], [(0.0, light)], [(float("nan"), light)]):
        with pytest.raises(ValueError, match="point > 0"):
            GainTablePolicy(env, bad)


def test_reference_env_integrates_finer_and_draws_the_same_episode():
    env = gym.make(ROTARY, n_moves=2)
    ref = reference_env(env)
    assert env.unwrapped.scenario.substeps in (None, 1)
    assert ref.unwrapped.scenario.substeps == REFERENCE_SUBSTEPS
    assert ref.action_space == env.action_space
    o1, i1 = env.reset(seed=11)
    o2, i2 = ref.reset(seed=11)
    np.testing.assert_array_equal(o1, o2)
    assert i1["part_value"] == i2["part_value"]
    assert env.unwrapped.plant_values == ref.unwrapped.plant_values
    a = np.zeros(env.action_space.shape, dtype=np.float32)
    (c1,) = run_episodes(env, ConstantPolicy(a), [11])
    (c2,) = run_episodes(ref, ConstantPolicy(a), [11])
    # the same set on a finer integration: close, not identical
    assert c1.mean_cost != c2.mean_cost
    assert c2.mean_cost == pytest.approx(c1.mean_cost, rel=0.2)


def test_reference_env_needs_a_made_env():
    from servogym.envs import ScheduleEnv

    with pytest.raises(ValueError, match=r"gymnasium\.make"):
        reference_env(ScheduleEnv("MC2100", "rotary", n_moves=2))


def _oracle_lines(tmp_path: Path, passed: dict[str, bool]) -> Path:
    path = tmp_path / "oracle.jsonl"
    cross = {"0": [1.0, 9.0, 20.0], "1": [3.0, 2.0, 8.0], "2": [30.0, 6.0, 4.0],
             "robust": [2.0, 3.0, 7.0]}  # fmt: skip
    lines = []
    for i, point in enumerate(["0", "1", "2", "robust"]):
        lines.append({"kind": "set", "scenario": "RotaryInertia", "label": "t", "budget": 5,
                      "points": 3, "point": i if point != "robust" else "robust",
                      "value": [3e-5, 1.6e-4, 9e-4][i] if point != "robust" else None,
                      "values": {"kp": 10 + i}, "cross": cross[point],
                      "check_passed": passed[point]})  # fmt: skip
    path.write_text("\n".join(json.dumps(x) for x in lines) + "\n{torn")
    return path


def test_baselines_take_only_checked_sets(study, tmp_path):
    from servogym.envs._scenarios import get_scenario

    s = get_scenario("RotaryInertia")
    every = {"0": True, "1": True, "2": True, "robust": True}
    b = study.baselines(s, _oracle_lines(tmp_path, every), "t", 5)
    assert b["best_fixed"] == "robust"  # mean 4.0 against 10, 4.33, 13.3
    assert b["oracle_mean_cost"] == pytest.approx((1.0 + 2.0 + 4.0) / 3)
    assert [p for p, _ in b["table"]] == [3e-5, 1.6e-4, 9e-4]
    some = {"0": True, "1": True, "2": False, "robust": False}
    b = study.baselines(s, _oracle_lines(tmp_path, some), "t", 5)
    assert b["best_fixed"] == "1"
    assert b["table_points"] == [3e-5, 1.6e-4]
    assert b["best_fixed_checked"] and b["table_checked"]
    with pytest.raises(SystemExit, match=r"schedule_oracle\.py --scenarios RotaryInertia"):
        study.baselines(s, _oracle_lines(tmp_path, every), "other", 5)


def test_bootstrap_intervals_hold_the_estimate(study):
    rng = np.random.default_rng(0)
    a = rng.lognormal(0.0, 0.3, 100)
    b = a * 1.5 + rng.normal(0, 0.05, 100)
    lo, hi = study.bootstrap_ratio(a, b)
    assert lo < a.mean() / b.mean() < hi
    assert hi < 0.75  # paired: the ratio is tight
    lo, hi = study.bootstrap_mean(a)
    assert lo < a.mean() < hi
    assert study.bootstrap_mean(np.full(5, 2.0)) == [2.0, 2.0]


def test_hyperparameters_come_from_the_zoo_files(study):
    hp = study.hyperparameters("sac", ROTARY)
    assert hp["policy_kwargs"] == {"net_arch": [128, 128]}
    assert "n_timesteps" not in hp and "policy" not in hp
    ppo = study.hyperparameters("ppo", "servogym/Schedule-Parker6K-StoredSets-v1")
    assert ppo["n_steps"] == 256 and ppo["policy_kwargs"]["log_std_init"] == -2.0


def test_a_zero_residual_around_a_center_table_runs_the_gain_table():
    table = [(3e-5, {"kp": 34, "kd": 107, "ki": 11, "kaff": 252}),
             (9e-4, {"kp": 60, "kd": 300, "ki": 11, "kaff": 2000})]  # fmt: skip
    unit = gym.make(ROTARY, action_type="unit", n_moves=4)
    around = gym.make(ROTARY, center_table=table, residual_scale=0.5, n_moves=4)
    zero = ConstantPolicy(np.zeros(around.action_space.shape, dtype=np.float32))
    seeds = [2, 5]
    want = run_episodes(unit, GainTablePolicy(unit, table), seeds)
    got = run_episodes(around, zero, seeds)
    assert [o.episode_return for o in got] == [o.episode_return for o in want]
    # and the sets differ between the empty and the loaded moves
    around.reset(seed=2)
    kps = [around.step(zero(None))[4]["params"]["kp"] for _ in range(2)]
    assert kps == [34, 60]


@pytest.mark.parametrize(
    ("kwargs", "match"),
    [
        ({"center_table": [], "action_type": "residual"}, "non-empty list"),
        ({"center_table": [(-1.0, {"kp": 3})], "action_type": "residual"}, "point > 0"),
        ({"center_table": [(1e-4, {"kp": 3})], "action_type": "unit"}, "action_type='residual'"),
        ({"center_table": [(1e-4, {"kp": 3})], "center": {"kp": 4}}, "not both"),
    ],
)
def test_center_table_refuses_what_it_cannot_use(kwargs, match):
    with pytest.raises(ValueError, match=match):
        gym.make(ROTARY, **kwargs)


def test_gain_table_takes_the_nearest_point_in_log_scale_and_the_first_on_a_tie():
    from servogym.envs import GainTable

    t = GainTable([(1e-4, {"kp": 1}), (1e-2, {"kp": 2}), (1e-2, {"kp": 3})])
    assert t.row(9e-4)[1] == {"kp": 1}  # log distance 0.95 decades against 1.05
    assert t.row(1.1e-3)[1] == {"kp": 2}  # the first of the two rows at 1e-2
    assert t.index(1e-3) == 0  # equidistant in log scale: the first
    with pytest.raises(ValueError, match=r"center_table must .* point > 0.*; got center_table="):
        GainTable([(1e-4, {"kp": 1}), (0.0, {"kp": 2})], name="center_table")


@pytest.fixture(scope="module")
def oracle_script():
    path = _SCRIPT.parent / "schedule_oracle.py"
    spec = importlib.util.spec_from_file_location("schedule_oracle", path)
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    return mod


def test_the_two_link_arm_scenario_is_its_schedule_ids_cycle(oracle_script):
    """The oracle's machine scenario: the PMD id's chip, cycle and box; its centre is every
    axis's registers, which the id's chip accepts; its sets tune on the machine path."""
    from servogym.envs._machine import MACHINE_CYCLES

    s = oracle_script.get_any_scenario("TwoLinkArm")
    cycle = MACHINE_CYCLES["two-link-arm"]
    # the oracle records name the -v1 id (the -v2 id differs only in its centre)
    assert oracle_script._scenario_id(s) == "servogym/Schedule-PMD-TwoLinkArm-v1"
    assert (s.param, s.empty, s.part) == (cycle.param, cycle.empty, tuple(cycle.part))
    assert s.param not in s.plant_range and "shoulder_coulomb_friction_nm" in s.plant_range
    points = s.operating_points(3)
    assert points[0] == cycle.empty and points[-1] == cycle.part[1]
    center = oracle_script.machine_center(s)
    assert {"kp.1", "kp.2"} <= set(center)
    env = gym.make(oracle_script._scenario_id(s), action_type="unit")
    params = env.unwrapped.scenario.params(center)
    assert params[0].kp == center["kp.1"] and params[1].kp == center["kp.2"]
    args = type("A", (), dict(budget=5, tuner="safe", seed=0, workers=1, robust=3,
                              check_candidates=1))()  # fmt: skip
    point = oracle_script._config(s, args, points[1])
    assert point.plant == "two-link-arm" and point.robust == 1
    assert dict(point.plant_params) == {"payload_kg": points[1]}
    robust = oracle_script._config(s, args, None)
    assert robust.robust == 3 and robust.plant_ranges["payload_kg"] == (cycle.empty, 2.0)
    assert type(robust.problem()).__name__ == "MachineProblem"


def test_gain_table_runs_on_a_machine_action():
    """GainTablePolicy on the two-link arm: the payload row on loaded moves, the empty row on
    empty ones (every axis's registers in one row)."""
    from servogym.envs._machine import MACHINE_CENTERS, axis_register

    env = gym.make("servogym/Schedule-PMD-TwoLinkArm-v1", action_type="unit", n_moves=4)
    sets = MACHINE_CENTERS[("pmd", "two-link-arm")]
    light = {axis_register(k, n): v for k, d in enumerate(sets, 1) for n, v in d.items()}
    heavy = {**light, "kp.1": light["kp.1"] + 100}
    policy = GainTablePolicy(env, [(0.05, light), (1.0, heavy)])
    obs, _ = env.reset(seed=3)
    for k in range(4):
        obs, _, _, _, info = env.step(policy(obs))
        want = light if k % 2 == 0 else heavy
        assert int(info["params"]["kp.1"]) == want["kp.1"]
        assert (info["payload_kg"] > 0.05) == (k % 2 == 1)


def test_the_docs_table_is_the_committed_summarys(study):
    """docs/envs.md's table of policies against the baselines is the one the committed
    summary.json gives (the script writes both; a hand edit of either shows here)."""
    root = _SCRIPT.parents[1]
    doc = json.loads((root / "experiments/results/schedule/summary.json").read_text())
    page = (root / "docs/envs.md").read_text()
    start, end = (page.index(m) for m in study.TABLE_MARKERS)
    shown = page[start + len(study.TABLE_MARKERS[0]) : end].strip()
    assert shown == study.table(doc)
    for row in doc["scenarios"]:
        assert f"`{row['env_id']}`" in shown


def test_chain_starts_from_the_checked_set_before(oracle_script):
    """``--chain``: a machine point starts from the point before when its set passed the
    check, the robust set from the checked set of lowest mean cross cost, else the centre."""
    base = {"scenario": "TwoLinkArm", "budget": 60, "label": "x", "points": 3}

    def rec(point, passed, cross, kp):
        r = {"kind": "set", "point": point, **base, "check_passed": passed, "cross": cross,
             "values": {"kp.1": kp}}  # fmt: skip
        return oracle_script._key(r), r

    done = dict([rec(0, True, [1.0, 9.0, 9.0], 10), rec(1, False, [2.0, 1.0, 3.0], 20)])
    assert oracle_script.chain_start(done, base, 1) == ("0", {"kp.1": 10})
    assert oracle_script.chain_start(done, base, 2) is None  # point 1 failed the check
    assert oracle_script.chain_start(done, base, 0) is None
    done.update([rec(2, True, [3.0, 2.0, 1.0], 30)])
    assert oracle_script.chain_start(done, base, "robust") == ("2", {"kp.1": 30})
    other = {**base, "label": "y"}
    assert oracle_script.chain_start(done, other, "robust") is None


def test_the_chain_starts_where_the_set_is_feasible_then_cheapest(oracle_script, monkeypatch):
    """``pick_start``: each candidate is one trial of the set's own problem; a feasible one
    wins over a cheaper infeasible one, then the cheaper; none feasible: the cheapest."""
    import types

    from servogym.autotune import _job

    outcomes = {10: (5.0, {"margin": 1.0}), 20: (9.0, {"margin": -1.0}), 30: (7.0, {"m": -2.0})}

    def fake_run_study(problem, tuner, budget, storage, n_workers, warm_start):
        cost, constraints = outcomes[warm_start["kp.1"]]
        trial = types.SimpleNamespace(values=[cost], constraints=constraints)
        return types.SimpleNamespace(trials=[trial])

    monkeypatch.setattr(_job, "run_study", fake_run_study)
    s = oracle_script.get_any_scenario("TwoLinkArm")
    args = type("A", (), dict(budget=5, tuner="safe", seed=0, workers=1, robust=3,
                              check_candidates=1))()  # fmt: skip
    cands = [("1", {"kp.1": 10}), ("centre", {"kp.1": 20}), ("c2", {"kp.1": 30})]
    name, values, probes = oracle_script.pick_start(s, args, 2.0, cands)
    assert (name, values) == ("c2", {"kp.1": 30})  # feasible and cheaper than "centre"
    assert probes == [["1", 5.0, False], ["centre", 9.0, True], ["c2", 7.0, True]]
    name, _, _ = oracle_script.pick_start(s, args, None, cands[:1])
    assert name == "1"  # the only one, infeasible


@pytest.fixture(scope="module")
def margin_script(oracle_script):
    path = _SCRIPT.parent / "machine_margin_search.py"
    spec = importlib.util.spec_from_file_location("machine_margin_search", path)
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    return mod


def test_the_margin_search_reproduces_its_recorded_slacks(margin_script, oracle_script):
    """The committed search (margin_search.jsonl): the start's slack recomputed is the
    recorded one, and the set found (which passed the full check) has the slack recorded,
    at least the target, so the search returns it unchanged after one evaluation."""
    path = _SCRIPT.parent / "results" / "schedule" / "margin_search.jsonl"
    rec = next(r for r in map(json.loads, path.read_text().splitlines()) if r.get("check_passed"))
    s = oracle_script.get_any_scenario(rec["scenario"])
    args = type("A", (), dict(budget=1, tuner="safe", seed=0, workers=1, robust=1,
                              check_candidates=1))()  # fmt: skip
    config = oracle_script._config(s, args, rec["value"])
    problem, limits = config.problem(), config.check_limits()
    out = margin_script.move_into_margins(problem, limits, rec["found"], target=rec["target"])
    assert out["values"] == rec["found"] and out["evaluations"] == 1
    assert out["slack"] == pytest.approx(rec["slack"], rel=1e-6) and out["slack"] >= rec["target"]
    lin = margin_script.LinearCheck(problem, limits, problem.space.make_params(rec["start"]).sets)
    slack, where = lin.slack(problem.space.make_params(rec["start"]).sets)
    assert slack == pytest.approx(rec["start_slack"], rel=1e-6) and where == rec["start_where"]
    assert slack < 0  # the start failed the margins: the search moved it


def test_the_pooled_oracle_takes_the_cheapest_checked_set_at_each_point(oracle_script):
    s = oracle_script.get_any_scenario("TwoLinkArm")
    points = s.operating_points(3)

    def rec(label, point, cross, passed=True, **kw):
        return {"kind": "set", "scenario": "TwoLinkArm", "points": 3, "label": label,
                "point": point, "cross": cross, "check_passed": passed, **kw}  # fmt: skip

    records = [
        rec("a", 0, [1.0, 3.0, 9.0]),
        rec("a", 1, [0.5, 2.0, 9.0]),  # cheapest at 0.05 kg, but checked at 0.32 kg only
        rec("a", 2, [0.1, 0.1, 0.1], passed=False),  # unchecked: never the oracle
        rec("b", "robust", [3.5, 3.5, 3.5]),  # no point-wise check: counts nowhere
    ]
    assert oracle_script.summarize_pooled(records, s, points) is None  # nothing at 2 kg
    records.append(rec("c", 2, [5.0, 5.0, 6.0]))
    # no set checked at every point: no best fixed set, so no gap
    assert oracle_script.summarize_pooled(records, s, points) is None
    records.append(rec("d", "cycle", [4.0, 4.5, 6.5], checked_at=list(points)))
    out = oracle_script.summarize_pooled(records, s, points, {"a:1": {1, 2}, "b:robust": {0}})
    assert out["oracle_from"] == ["a:0", "a:1", "c:2"]
    assert out["oracle_costs"] == [1.0, 2.0, 6.0]
    assert out["checked_everywhere"] == ["d:cycle"]  # a:1 failed at 0.05 kg
    assert out["checked_at"]["a:1"] == [1, 2] and out["checked_at"]["b:robust"] == [0]
    assert out["best_fixed"] == "d:cycle" and out["best_fixed_mean_cost"] == pytest.approx(5.0)
    assert out["oracle_gap"] == pytest.approx(5.0 / 3.0)
    assert out["oracle_gap_worst_point"] == pytest.approx(4.0)
    assert "a:2" not in out["pool"]


def test_start_from_reads_a_recorded_set_by_label_and_point(oracle_script):
    s = oracle_script.get_any_scenario("TwoLinkArm")
    rec = {"kind": "set", "scenario": "TwoLinkArm", "label": "margins:oracle:x:2",
           "point": "cycle", "values": {"kp.1": 7}}  # fmt: skip
    done = {("set", "TwoLinkArm", "cycle", None, rec["label"], 3): rec}
    assert oracle_script.recorded_set(done, s, "margins:oracle:x:2:cycle") == {"kp.1": 7}
    with pytest.raises(SystemExit, match="no set 'robust' of label 'margins:oracle:x:2'"):
        oracle_script.recorded_set(done, s, "margins:oracle:x:2:robust")


def test_pooled_baselines_take_the_pooled_oracles_sets(study, tmp_path, monkeypatch):
    import schedule_oracle  # the module schedule_policies imports (its folder is on sys.path)

    monkeypatch.setattr(schedule_oracle, "checked_at_points", lambda s, n: {"a:1": {0}})
    s = schedule_oracle.get_any_scenario("TwoLinkArm")
    points = s.operating_points(3)

    def rec(label, point, cross, values, **kw):
        return {"kind": "set", "scenario": "TwoLinkArm", "points": 3, "label": label,
                "point": point, "budget": 150, "cross": cross, "check_passed": True,
                "values": values, **kw}  # fmt: skip

    lines = [
        rec("a", 0, [2.0, 3.0, 9.0], {"kp.1": 1}),
        rec("a", 1, [1.0, 2.0, 9.0], {"kp.1": 2}),  # checked at 0.05 kg too (the patched file)
        rec("c", 2, [5.0, 5.0, 6.0], {"kp.1": 3}),
        rec("d", "cycle", [4.0, 4.5, 6.5], {"kp.1": 4}, checked_at=list(points)),
    ]
    path = tmp_path / "oracle.jsonl"
    path.write_text("\n".join(json.dumps(x) for x in lines) + "\n")
    b = study.baselines(s, path, "pooled", 150)  # the budget is not used
    assert b["best_fixed"] == "d:cycle" and b["best_fixed_values"] == {"kp.1": 4}
    assert b["oracle_from"] == ["a:1", "a:1", "c:2"]
    assert b["table"] == [(points[0], {"kp.1": 2}), (points[1], {"kp.1": 2}),
                          (points[2], {"kp.1": 3})]  # fmt: skip
    assert b["oracle_mean_cost"] == pytest.approx((1.0 + 2.0 + 6.0) / 3)
    assert b["robust_values"] is None
    assert study._policies(None, b) == ["best_fixed", "gain_table"]  # no robust set to run
    args = study._parse(["--oracle-label", "pooled"])
    key = study._block_key("TwoLinkArm", "best_fixed", "default", None, args, b)
    assert key.endswith("|pooled|150|d:cycle|a:1,a:1,c:2")  # a grown pool is run again
    path.write_text(json.dumps(lines[0]) + "\n")
    with pytest.raises(SystemExit, match="no pooled oracle of TwoLinkArm at 3 points"):
        study.baselines(s, path, "pooled", 150)


def test_the_feed_forward_fit_reproduces_its_recorded_ratios(margin_script, oracle_script):
    """The committed fit of the PMAC X-Y stage's checked set (``--sets ff:held:margins`` in
    machine_centre_checks.jsonl): the start's worst following error / limit recomputed on
    the check's tasks is the recorded one (over the limit), the set found has the recorded
    ratio (under 0.85), and the fit changed only the feed-forward registers."""
    path = _SCRIPT.parent / "results" / "schedule" / "machine_centre_checks.jsonl"
    eid = "servogym/Schedule-PMAC-XyStage-v1"
    lines = [json.loads(x) for x in path.read_text().splitlines()]
    found = next(r for r in lines if r["env_id"] == eid and r["sets"] == "ff:held:margins")
    start = next(r for r in lines if r["env_id"] == eid and r["sets"] == "held:margins")
    fit = found["feed_forward"]
    s = oracle_script.machine_scenario(eid)
    points = s.operating_points(3)
    config = oracle_script._config(s, oracle_script.point_args(2), points[0])
    problem, limits = config.problem(), config.check_limits()
    plants = [{s.param: float(p)} for p in points]
    errors = margin_script.TaskErrors(
        problem, limits, problem.space.make_params(start["values"]).sets, plants
    )
    for values, ratio, where in ((start["values"], fit["start_ratio"], fit["start_where"]),
                                 (found["values"], fit["ratio"], fit["where"])):  # fmt: skip
        got, at = errors.ratio(problem.space.make_params(values).sets, workers=2)
        assert got == pytest.approx(ratio, rel=1e-9) and at == where
    assert fit["start_ratio"] > 1.0 > 0.85 >= fit["ratio"]
    changed = {k for k in start["values"] if start["values"][k] != found["values"][k]}
    assert changed and {k.split(".")[0] for k in changed} <= {"velocity_ff", "acceleration_ff"}
