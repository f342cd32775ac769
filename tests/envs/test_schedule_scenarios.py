"""The gain-scheduling scenarios: registered, physically feasible, safe at the action's centre,
observing the condition, scaling rewards, and the 6250's stored gain sets."""

from __future__ import annotations

import math
import subprocess
import sys
from pathlib import Path

import gymnasium as gym
import numpy as np
import pytest

import servogym.envs as envs
from servogym import _registration
from servogym.envs import SCENARIOS, PickAndPlace
from servogym.envs._machine import plant_family
from servogym.plants import PEAK_HEADROOM, MotorFeasibilityError, get_plant

ROOT = Path(__file__).resolve().parents[2]
SCHEDULE_IDS = [i for i in envs.registered_ids() if i.split("/")[1].startswith("Schedule-")]
SCENARIO_IDS = {
    name: f"servogym/Schedule-{_registration.BUILTIN_FAMILIES[s.family][0]}-{name}-v1"
    for name, s in SCENARIOS.items()
}


def test_every_scenario_is_registered_as_the_import_time_table_says():
    assert set(_registration.SCENARIOS) == set(SCENARIOS)
    for name, s in SCENARIOS.items():
        assert _registration.SCENARIOS[name] == (s.family, s.chip_model, s.plant)
        assert SCENARIO_IDS[name] in envs.registered_ids()
        env = gym.make(SCENARIO_IDS[name]).unwrapped
        assert env.preset is s and env.scenario.chip_model == s.chip_model
        assert env.cycle.param == s.param and env._part == s.part and env._empty == s.empty


@pytest.mark.parametrize("eid", SCHEDULE_IDS)
def test_every_schedule_box_is_movable_by_its_motor(eid):
    env = gym.make(eid).unwrapped
    assert env.need.feasible and env.need.fraction <= PEAK_HEADROOM
    # the heaviest part the cycle can draw is inside the box the need was computed over
    assert env._part[1] <= plant_family(env.scenario.plant).param(env.cycle.param).high


def test_a_cycle_the_motor_cannot_move_is_refused_in_one_line():
    with pytest.raises(MotorFeasibilityError, match=r"load_inertia_kgm2=0\.003 .*cycle") as e:
        gym.make(
            "servogym/Schedule-PMD-Rotary-v1",
            cycle=PickAndPlace("load_inertia_kgm2", part=(1e-3, 3e-3)),
        )
    assert "\n" not in str(e.value)


def test_the_scenarios_span_what_the_issue_asks():
    arm, rotary = SCENARIOS["ArmPayload"], SCENARIOS["RotaryInertia"]
    assert arm.span >= 20
    rotor = get_plant("rotary").param("rotor_inertia_kgm2").nominal
    assert rotary.empty == pytest.approx(rotor) and rotary.part[1] == pytest.approx(30 * rotor)
    vertical = SCENARIOS["VerticalCoarseLead"]
    lead = vertical.plant_values["screw_lead_m"]
    reflected = rotor * (2 * math.pi / lead) ** 2  # kg at the carriage
    assert reflected < vertical.empty + vertical.plant_values["carriage_mass_kg"]
    assert len(SCENARIOS["StoredSets"].stored_sets) == 5  # SGSET1 .. SGSET5


@pytest.mark.parametrize("name", [n for n, s in SCENARIOS.items() if not s.stored_sets])
def test_the_centre_of_the_action_box_is_a_safe_set(name):
    env = gym.make(SCENARIO_IDS[name]).unwrapped
    assert env.action_space == gym.spaces.Box(-1, 1, env.action_space.shape, np.float32)
    zero = np.zeros(env.action_space.shape, np.float32)
    assert env.actions.to_values(zero) == env.actions.center_values
    heaviest = []
    for seed in range(6):
        env.reset(seed=seed)
        heaviest.append(env.part_value)
        for k in range(env.n_moves):
            _, _, done, _, info = env.step(zero)
            assert not info["diverged"], (name, seed, k)
            assert done == (k == env.n_moves - 1)
    assert max(heaviest) > math.sqrt(env._part[0] * env._part[1])  # a heavy part was drawn


def test_the_unit_box_centre_diverges_where_the_residual_one_does_not():
    # What the residual default is for: the plain unit box's centre is not a safe set.
    costs = {}
    for action_type in ("unit", "residual"):
        env = gym.make(SCENARIO_IDS["RotaryInertia"], action_type=action_type).unwrapped
        env.reset(seed=0)
        *_, info = env.step(np.zeros(env.action_space.shape, np.float32))
        costs[action_type] = info["cost"]
    assert costs["unit"] > 10 * costs["residual"]


def test_residual_actions_reach_and_refusals():
    env = gym.make("servogym/Schedule-PMD-Arm-v1", action_type="residual").unwrapped
    from servogym.agents import nominal_set

    center = nominal_set("pmd", "arm")
    assert {k: env.actions.center_values[k] for k in center} == center
    np.testing.assert_array_equal(env.actions.from_values(center), 0.0)
    one = np.zeros(env.action_space.shape, np.float32)
    one[0] = 1.0  # kp: a quarter of its unit range above the centre
    kp = env.actions.to_values(one)["kp"]
    spec = env.actions.specs[0]
    assert spec.to_unit(kp) == pytest.approx(spec.to_unit(center["kp"]) + 0.25, abs=1e-3)
    with pytest.raises(ValueError, match=r"0 < residual_scale <= 2 .*got residual_scale=3"):
        gym.make("servogym/Schedule-PMD-Arm-v1", action_type="residual", residual_scale=3)
    with pytest.raises(ValueError, match="action_type='residual' needs center="):
        gym.make("servogym/Schedule-PMAC-Arm-v1", action_type="residual")
    with pytest.raises(ValueError, match=r"action\[1\] \(ki\) must be a finite number"):
        bad = np.zeros(env.action_space.shape, np.float32)
        bad[1] = np.nan
        env.reset(seed=0)
        env.step(bad)


def test_the_zero_residual_action_is_the_centre_to_the_count_even_on_a_31_bit_register():
    # float32 resolves a unit form to about 1e-7: 13 counts of a 1.3e8 integration limit
    center = {"kp": 701, "ki": 1937, "integration_limit": 134335376, "bias": 22683}
    env = gym.make("servogym/Schedule-PMD-Arm-v1", action_type="residual", center=center)
    actions = env.unwrapped.actions
    values = actions.to_values(np.zeros(env.action_space.shape, np.float32))
    assert {k: values[k] for k in center} == center
    spec = next(s for s in actions.specs if s.name == "integration_limit")
    assert (
        spec.from_unit(float(np.float32(spec.to_unit(center["integration_limit"]))))
        != (center["integration_limit"])
    )  # the float32 unit form would miss it


def test_the_condition_is_observed():
    env = gym.make(SCENARIO_IDS["ArmPayload"]).unwrapped
    n_move, n_state = len(envs.MOVE_FEATURES), len(envs.STATE_FEATURES)
    i_load, i_target = n_move + n_state, n_move + n_state + 1
    obs, _ = env.reset(seed=2)
    zero = np.zeros(env.action_space.shape, np.float32)
    lo, hi = math.log(env._empty), math.log(env._part[1])
    for k in range(env.n_moves):
        load = env.part_value if k % 2 else env._empty
        assert obs[i_load] == pytest.approx(2 * (math.log(load) - lo) / (hi - lo) - 1)
        assert obs[i_target] == pytest.approx(env._targets[k])
        obs, *_ = env.step(zero)
    plain = gym.make("servogym/Schedule-PMD-Arm-v1").unwrapped
    assert plain.observation_space.shape[0] == env.observation_space.shape[0] - 2


def test_reward_scale_is_the_envs_and_documented():
    assert envs.DEFAULT_REWARD_SCALE == 1.0  # the classes' and the -v0 ids'
    assert envs.REWARD_SCALE_V1 == 0.01
    from servogym.agents import DEFAULT_REWARD_SCALE

    assert DEFAULT_REWARD_SCALE == envs.REWARD_SCALE_V1  # what train passes to every id
    for eid in ("servogym/Schedule-PMD-Rotary-v1", "servogym/Tune-PMD-Rotary-v1"):
        rewards = {}
        for scale in (0.01, 1.0, 0.5):
            env = gym.make(eid, reward_scale=scale).unwrapped
            env.reset(seed=0)
            _, r, *_, info = env.step(env.actions.from_values({}))
            assert r == pytest.approx(scale * info["raw_reward"])
            assert info["cost"] == pytest.approx(-info["raw_reward"])
            rewards[scale] = r
        assert rewards[0.01] == gym.make(eid).unwrapped.reward_scale * rewards[1.0]
    for bad in (0, -1, float("nan"), True, "0.1"):
        with pytest.raises(ValueError, match=r"reward_scale must be a finite number > 0"):
            gym.make("servogym/Tune-PMD-Rotary-v1", reward_scale=bad)


def test_stored_sets_action_selects_sgset_per_move():
    env = gym.make(SCENARIO_IDS["StoredSets"]).unwrapped
    sets = SCENARIOS["StoredSets"].stored_sets
    assert env.action_space == gym.spaces.Discrete(5)
    env.reset(seed=0)
    costs = []
    for k in (0, 4, 2):
        *_, info = env.step(k)
        assert {g: info["params"][g] for g in sets[k]} == dict(sets[k])
        costs.append(info["cost"])
    assert len(set(costs)) == 3
    with pytest.raises(ValueError, match=r"0 <= action <= 4"):
        env.step(5)


def test_unknown_scenario_name_suggests_the_close_one():
    with pytest.raises(ValueError, match="Did you mean RotaryInertia"):
        gym.make("servogym/Schedule-PMD-Rotary-v1", scenario_name="RotaryInertie")


def test_docs_feasibility_table_is_the_scripts_output():
    run = subprocess.run(
        [sys.executable, str(ROOT / "experiments" / "schedule_feasibility.py")],
        capture_output=True, text=True, cwd=ROOT, timeout=600,
    )  # fmt: skip
    assert run.returncode == 0, run.stderr[-2000:]
    table = run.stdout.split("\nwrote")[0].strip()
    assert table in (ROOT / "docs" / "envs.md").read_text()


@pytest.mark.parametrize("k", [2, 4, 5])
def test_operating_points_end_exactly_at_empty_and_the_part_high_end(k):
    # exp(log(10)) is 10.000000000000007: the vertical axis refused its own top point
    for s in SCENARIOS.values():
        points = s.operating_points(k)
        assert points[0] == s.empty and points[-1] == s.part[1] and len(points) == k
        param = get_plant(s.plant).param(s.param)
        assert all(param.low <= p <= param.high for p in points)


@pytest.mark.parametrize("name", [n for n, s in SCENARIOS.items() if not s.stored_sets])
def test_the_centre_is_no_worse_than_the_hand_tuned_nominal_set(name):
    # The coarse-lead axis's first centre was the nominal set of the 10 mm screw: 30.7 per
    # move at the zero action, and PPO's exploration around it ended most episodes early.
    from servogym.agents import nominal_set

    s = SCENARIOS[name]
    costs = {}
    for label, centre in (("centre", s.center), ("nominal", nominal_set(s.family, s.plant))):
        env = gym.make(SCENARIO_IDS[name], center=centre, n_moves=4).unwrapped
        zero = np.zeros(env.action_space.shape, np.float32)
        per_move = []
        for seed in range(3):
            env.reset(seed=seed)
            for _ in range(env.n_moves):
                *_, info = env.step(zero)
                assert not info["diverged"], (name, label, seed)
                per_move.append(info["cost"])
        costs[label] = float(np.mean(per_move))
    assert costs["centre"] <= costs["nominal"]
    if name == "VerticalCoarseLead":
        assert costs["centre"] < 0.2 * costs["nominal"]
