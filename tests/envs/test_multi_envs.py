"""The envs on the multi-axis plants (issue 23, point 5): Tune and Schedule ids of every chip
family on ``two-link-arm`` and ``xy-stage``; every axis's registers in one action, the
configuration in the Schedule observation, a safe centre, finite penalties.

The ids come from the registries (chip families x :data:`servogym.plants.MULTI_PLANTS`),
never from a hand-written list.
"""

from __future__ import annotations

import math
import warnings
from pathlib import Path

import gymnasium as gym
import numpy as np
import pytest

import servogym.envs as envs
from servogym import _registration
from servogym.chips._family import families
from servogym.envs._machine import (
    MACHINE_CENTER_VERSIONS,
    MACHINE_CENTERS,
    MACHINE_CENTERS_V2,
    MACHINE_CYCLES,
    MachineScenario,
    axis_register,
    machine_fixed,
    per_axis,
)
from servogym.plants import MULTI_PLANTS, MotorFeasibilityError

MACHINE_IDS = [
    envs.env_id(kind, fam, plant, version)
    for kind in ("Tune", "Schedule")
    for fam in families().values()
    for plant in MULTI_PLANTS
    for version in _registration.MACHINE_VERSIONS
] + [
    envs.env_id("Schedule", fam, plant, version)
    for fam in families().values()
    for plant in MULTI_PLANTS
    for version in _registration.MACHINE_SCHEDULE_VERSIONS
    if version not in _registration.MACHINE_VERSIONS
]
TUNE_IDS = [i for i in MACHINE_IDS if "/Tune-" in i]
SCHEDULE_IDS = [i for i in MACHINE_IDS if "/Schedule-" in i]


def _make(eid: str, **kwargs):
    return gym.make(eid, **kwargs).unwrapped


def _rollout(eid: str, seed: int, n_episodes: int = 1, **kwargs) -> tuple[list, list]:
    env = gym.make(eid, **kwargs)
    env.action_space.seed(seed)
    observations, rewards = [], []
    for ep in range(n_episodes):
        obs, _ = env.reset(seed=seed + ep)
        observations.append(obs)
        done = False
        while not done:
            obs, r, term, trunc, _ = env.step(env.action_space.sample())
            observations.append(obs)
            rewards.append(r)
            done = term or trunc
    return observations, rewards


# --- registration -------------------------------------------------------------------------


def test_every_family_has_tune_and_schedule_ids_on_every_machine_from_v1():
    assert tuple(MULTI_PLANTS) == _registration.BUILTIN_MACHINE_PLANTS
    assert _registration.MACHINE_VERSIONS == (1,)
    ids = envs.registered_ids()
    assert set(MACHINE_IDS) <= set(ids) and len(MACHINE_IDS) == 2 * 3 * 2 + 3 * 2
    assert _registration.MACHINE_SCHEDULE_VERSIONS == (1, 2)
    assert "servogym/Schedule-PMAC-XyStage-v2" in ids and "servogym/Tune-PMAC-XyStage-v2" not in ids
    assert "servogym/Tune-PMD-TwoLinkArm-v1" in ids  # the scheme: plant_id_name
    assert "servogym/Schedule-Parker6K-XyStage-v1" in ids
    assert not any(i.endswith(("TwoLinkArm-v0", "XyStage-v0")) for i in ids)
    for eid in MACHINE_IDS:
        env = _make(eid)
        assert env.reward_scale == envs.REWARD_SCALE_V1
        assert env.axes == MULTI_PLANTS[env.scenario.plant].axes


def test_keywords_that_contradict_a_machine_id_are_refused():
    with pytest.raises(ValueError, match="plant='arm' contradicts the env id"):
        gym.make("servogym/Tune-PMD-TwoLinkArm-v1", plant="arm")
    with pytest.raises(ValueError, match="family='pmac' contradicts"):
        gym.make("servogym/Schedule-PMD-XyStage-v1", family="pmac")


# --- checkers, seeding, random steps --------------------------------------------------------


@pytest.mark.slow
@pytest.mark.parametrize("eid", MACHINE_IDS)
def test_checkers_pass(eid):
    from gymnasium.utils.env_checker import check_env as gym_check
    from stable_baselines3.common.env_checker import check_env as sb3_check

    rendered = gym.make(eid, render_mode="rgb_array").unwrapped
    plain = gym.make(eid).unwrapped
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # a checker warning fails the test
        gym_check(rendered)
        sb3_check(plain)


@pytest.mark.parametrize("eid", TUNE_IDS)
def test_tune_seeding_is_reproducible_and_random_steps_finite(eid):
    obs_a, rew_a = _rollout(eid, 7, 2)
    obs_b, rew_b = _rollout(eid, 7, 2)
    np.testing.assert_array_equal(np.array(obs_a), np.array(obs_b))
    assert rew_a == rew_b
    obs_c, _ = _rollout(eid, 8)
    assert not np.array_equal(obs_a[0], obs_c[0])
    assert np.isfinite(np.array(obs_a)).all() and np.isfinite(rew_a).all()
    assert all(-20.0 <= r <= 0.0 for r in rew_a)  # -v1: minus the cost times 0.01


@pytest.mark.parametrize("eid", SCHEDULE_IDS)
def test_schedule_seeding_is_reproducible_and_random_steps_finite(eid):
    kw = {"n_moves": 3}
    obs_a, rew_a = _rollout(eid, 7, 1, **kw)
    obs_b, rew_b = _rollout(eid, 7, 1, **kw)
    np.testing.assert_array_equal(np.array(obs_a), np.array(obs_b))
    assert rew_a == rew_b
    obs_c, _ = _rollout(eid, 8, 1, **kw)
    assert not np.array_equal(obs_a[0], obs_c[0])
    env = _make(eid, **kw)
    for obs in obs_a:
        assert env.observation_space.contains(obs)
    assert np.isfinite(rew_a).all() and all(-20.0 <= r <= 0.0 for r in rew_a)


# --- the action: every axis's registers -----------------------------------------------------


@pytest.mark.parametrize("eid", TUNE_IDS)
def test_tune_action_is_every_axis_register_within_its_legal_range(eid):
    env = _make(eid)
    space = env.chip.parameter_space(env.scenario.chip_model)
    tunable = [s.name for s in space.tunable()]
    names = [axis_register(k, n) for k in range(1, len(env.axes) + 1) for n in tunable]
    assert env.actions.names == tuple(names)
    assert env.action_space == gym.spaces.Box(-1, 1, (len(names),), np.float32)
    held = machine_fixed(env.scenario.chip_model, len(env.axes))
    for u in (-1.0, 1.0):
        sets = env.actions.to_params(np.full(len(names), u, np.float32))
        assert len(sets) == len(env.axes)
        for p in sets:
            for n in tunable:
                assert getattr(p, n) == space[n].from_unit(u)
                assert space[n].low <= getattr(p, n) <= space[n].high
            for n, v in held.items():
                assert getattr(p, n) == v
    # the unit scaling is the single-axis Tune env's, register by register
    single = _make(eid.replace("TwoLinkArm", "Arm").replace("XyStage", "Rotary"))
    a = np.random.default_rng(0).uniform(-1, 1, len(names)).astype(np.float32)
    n = len(tunable)
    for k in range(len(env.axes)):
        want = single.actions.to_values(a[k * n : (k + 1) * n])
        got = env.actions.to_values(a)
        assert {r: got[axis_register(k + 1, r)] for r in tunable} == {r: want[r] for r in tunable}


def test_pmd_machine_sets_have_the_time_sliced_period():
    env = _make("servogym/Tune-PMD-TwoLinkArm-v1")
    one = env.chip.make_params(env.scenario.chip_model).sample_time_us
    assert machine_fixed("MC2100", 2) == {"sample_time_us": 2 * one}
    for p in env.actions.to_params(env.action_space.sample()):
        assert p.sample_time_us == 2 * one
    assert machine_fixed("6250", 2) == {}
    # PMAC: Ixx11 at its maximum (the default killed every move of both machines)
    assert machine_fixed("TurboPMAC2", 2) == {"fatal_following_error_limit": 8388607}
    for p in _make("servogym/Tune-PMAC-XyStage-v1").scenario.default_params():
        assert p.fatal_following_error_limit == 8388607


def test_bad_actions_name_the_index_in_the_whole_action_and_the_axis():
    env = _make("servogym/Tune-PMD-XyStage-v1")
    env.reset(seed=0)
    a = np.zeros(env.action_space.shape, np.float32)
    a[10] = np.nan  # the second register of axis y
    with pytest.raises(ValueError, match=r"action\[10\] \(ki\.2\) must be a finite number"):
        env.step(a)
    with pytest.raises(ValueError, match=r"the action must have shape \(18,\)"):
        env.step(np.zeros(9, np.float32))
    raw = _make("servogym/Tune-Parker6K-TwoLinkArm-v1", action_type="raw")
    assert isinstance(raw.action_space, gym.spaces.MultiDiscrete) and raw.action_space.shape == (
        10,
    )
    raw.reset(seed=0)
    bad = np.zeros(10, np.int64)
    bad[7] = raw.action_space.nvec[7]
    with pytest.raises(ValueError, match=r"action\[7\] \(\w+\.2\) must satisfy 0 <="):
        raw.step(bad)


def test_params_fixed_and_baselines_split_by_axis():
    env = _make("servogym/Tune-PMD-TwoLinkArm-v1", params=("kp", "kd.2"), fixed={"ki": 0})
    assert env.actions.names == ("kp.1", "kp.2", "kd.2")
    values = env.actions.to_values(np.zeros(3, np.float32))
    assert values["ki.1"] == values["ki.2"] == 0
    action = env.actions.from_values({"kp": 100, "kp.2": 200})
    got = env.actions.to_values(action)
    assert (got["kp.1"], got["kp.2"]) == (100, 200)
    with pytest.raises(
        ValueError,
        match=r"params names axis 3 in 'kp\.3'; the axes are 1 \(shoulder\), 2 \(elbow\)",
    ):
        _make("servogym/Tune-PMD-TwoLinkArm-v1", params=("kp.3",))
    with pytest.raises(ValueError, match=r"params sets no register of axis 1 \(shoulder\)"):
        _make("servogym/Tune-PMD-TwoLinkArm-v1", params=("kp.2",))
    with pytest.raises(ValueError, match=r"fixed names axis 0 in 'kp\.0'"):
        _make("servogym/Tune-PMD-XyStage-v1", fixed={"kp.0": 1})
    assert per_axis([{"kp": 1}, None], ("x", "y"), "center") == [{"kp": 1}, {}]
    with pytest.raises(ValueError, match=r"center must give one mapping per axis \(2: x, y\)"):
        per_axis([{"kp": 1}], ("x", "y"), "center")


# --- the Schedule observation: configuration and condition ---------------------------------


@pytest.mark.parametrize("plant", list(MULTI_PLANTS))
def test_schedule_observes_the_configuration_at_the_move_start_and_end_and_the_load(plant):
    eid = envs.env_id("Schedule", families()["pmd"], plant)
    env = _make(eid, n_moves=4)
    n = len(env.axes)
    i_load = len(envs.MOVE_FEATURES) * n + 2 * n + 2
    obs, _ = env.reset(seed=3)
    assert obs.shape == env.observation_space.shape
    assert env.observation_space.shape[0] == i_load + 1 + 2 * n + len(env.actions.names)
    lo, hi = math.log(env._empty), math.log(env._part[1])
    zero = np.zeros(env.action_space.shape, np.float32)
    cycle = MACHINE_CYCLES[plant]
    for k in range(env.n_moves):
        start = env._start if k == 0 else env._targets[k - 1]
        np.testing.assert_allclose(obs[i_load + 1 : i_load + 1 + n], start)
        np.testing.assert_allclose(obs[i_load + 1 + n : i_load + 1 + 2 * n], env._targets[k])
        ranges = cycle.pick if k % 2 == 0 else cycle.place
        assert all(r[0] <= q <= r[1] for r, q in zip(ranges, env._targets[k], strict=True))
        load = env.part_value if k % 2 else env._empty
        assert obs[i_load] == pytest.approx(2 * (math.log(load) - lo) / (hi - lo) - 1)
        assert env.plant.values["payload_kg"] == pytest.approx(load)
        obs, _, done, _, info = env.step(zero)
        assert not info["diverged"]
        assert done == (k == env.n_moves - 1)


def test_schedule_table_names_the_observation_entries():
    from servogym.envs._schedule import observation_table

    env = _make("servogym/Schedule-PMD-TwoLinkArm-v1")
    table = observation_table(True, env.axes)
    assert "`shoulder_start`" in table and "`elbow_end`" in table
    rows = table.splitlines()[2:]
    assert rows[-1].startswith(f"| {len(rows) - 1} .. ")  # then the last action
    assert len(rows) - 1 + len(env.actions.names) == env.observation_space.shape[0]


# --- the residual action and its safe centre ------------------------------------------------


@pytest.mark.parametrize("eid", SCHEDULE_IDS)
def test_schedule_acts_around_a_safe_centre(eid):
    env = _make(eid, n_moves=4)
    centre = MACHINE_CENTER_VERSIONS[envs.id_version(eid)][(env.chip.name, env.scenario.plant)]
    assert len(centre) == len(env.axes)
    zero = np.zeros(env.action_space.shape, np.float32)
    for k, values in enumerate(env.actions.axis_values(zero)):
        assert {r: values[r] for r in centre[k]} == centre[k]
    for seed in range(2):
        env.reset(seed=seed)
        done = False
        while not done:
            _, _, done, _, info = env.step(zero)
            assert not info["diverged"], (eid, seed)
            assert info["cost"] < 100.0
    unit = _make(eid, action_type="unit", n_moves=4)
    assert unit.action_space == env.action_space


EXPERIMENTS = Path(__file__).parents[2] / "experiments"


@pytest.fixture(scope="module")
def centre_checks():
    """``experiments/machine_centre_check.py`` (its lines are the checks of the centres)."""
    import importlib.util

    spec = importlib.util.spec_from_file_location(
        "machine_centre_check", EXPERIMENTS / "machine_centre_check.py"
    )
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    return mod


@pytest.mark.parametrize("key", sorted(MACHINE_CENTERS_V2))
def test_every_v2_centre_is_a_set_that_passed_the_check_at_every_point(key, centre_checks):
    """The set a -v2 id runs at the zero action, every register of every axis (the action's,
    the held ones, the chip defaults), is one the multi-axis check passed at every operating
    point of the id's cycle (the lines in CHECKS, of the -v1 id the checks ran on)."""
    family, plant = key
    fam = families()[family]
    v2 = _make(envs.env_id("Schedule", fam, plant, 2))
    zero = np.zeros(v2.action_space.shape, np.float32)
    sets = v2.actions.to_params(zero)  # one parameter set per axis

    def runs(values: dict) -> bool:
        for name, value in values.items():
            register, _, axis = name.rpartition(".")
            axes = [int(axis) - 1] if axis.isdigit() else range(len(sets))
            register = register if axis.isdigit() else name
            if any(getattr(sets[k], register) != value for k in axes):
                return False
        return True

    done = centre_checks.load_done(centre_checks.RESULTS / "machine_centre_checks.jsonl")
    checked = centre_checks.passed_everywhere(done, envs.env_id("Schedule", fam, plant, 1), 3)
    assert any(runs(r["values"]) and len(r["values"]) >= 5 * len(sets) for r in checked.values())
    assert (
        not runs(
            {f"{n}.{k}": v for k, d in enumerate(MACHINE_CENTERS[key], 1) for n, v in d.items()}
        )
        or MACHINE_CENTERS[key] == MACHINE_CENTERS_V2[key]
    )  # the test tells the sets apart


def test_machine_centers_keyword_is_checked_and_an_explicit_centre_wins():
    with pytest.raises(
        ValueError, match=r"machine_centers must be one of \[1, 2\].*got machine_centers=3"
    ):
        _make("servogym/Schedule-PMD-XyStage-v2", machine_centers=3)
    v1 = _make("servogym/Schedule-PMD-XyStage-v1", machine_centers=2)
    v2 = _make("servogym/Schedule-PMD-XyStage-v2")
    zero = np.zeros(v1.action_space.shape, np.float32)
    assert v1.actions.to_values(zero) == v2.actions.to_values(zero)
    given = {"kp": 900}
    v2c = _make("servogym/Schedule-PMD-XyStage-v2", center=given)
    assert all(v["kp"] == 900 for v in v2c.actions.axis_values(zero))


# --- unstable gains: a finite, documented penalty --------------------------------------------


@pytest.mark.parametrize("eid", TUNE_IDS)
def test_tune_divergence_is_a_finite_documented_penalty(eid):
    env = _make(eid)
    diverged = []
    n = env.action_space.shape[0]
    corners = [np.full(n, 1.0), np.full(n, -1.0), np.random.default_rng(0).choice([-1, 1], n)]
    for u in corners:  # corners of the action box: one of them diverges on each id
        env.reset(seed=0)
        obs, r, term, trunc, info = env.step(u.astype(np.float32))
        assert term and not trunc and np.isfinite(obs).all() and np.isfinite(r)
        assert np.isfinite(info["max_contour_error_um"])
        assert r == pytest.approx(-0.01 * info["cost"])
        if info["diverged"]:
            assert 1000.0 <= info["cost"] <= 2000.0
            diverged.append(u.tolist())
        else:
            assert 0.0 <= info["cost"] <= 100.0
    assert diverged, eid


def test_schedule_divergence_ends_the_episode_with_a_finite_penalty():
    env = _make("servogym/Schedule-PMD-TwoLinkArm-v1", action_type="unit", n_moves=4)
    env.reset(seed=0)
    obs, r, term, _, info = env.step(np.ones(env.action_space.shape, np.float32))
    assert info["diverged"] and term
    assert 1000.0 * (2 - 1 / 4) <= info["cost"] <= 2000.0
    assert r == pytest.approx(-0.01 * info["cost"]) and np.isfinite(obs).all()
    with pytest.raises(RuntimeError, match="the episode has ended"):
        env.step(np.zeros(env.action_space.shape, np.float32))


# --- refusals ----------------------------------------------------------------------------------


def test_a_box_the_motors_cannot_move_is_refused_in_one_line():
    with pytest.raises(MotorFeasibilityError, match=r"two-link-arm/\w+ motor cannot move") as e:
        MachineScenario("MC2100", "two-link-arm", {"shoulder_gear_ratio": 5.0}, randomise=True)
    assert "\n" not in str(e.value)


def test_a_single_axis_cycle_on_a_machine_is_refused():
    from servogym.envs import PickAndPlace

    with pytest.raises(ValueError, match="cycle must be a MachineCycle on the 'xy-stage'"):
        _make("servogym/Schedule-PMD-XyStage-v1", cycle=PickAndPlace("payload_kg"))
    with pytest.raises(ValueError, match="moves are single-axis MoveSpecs"):
        from servogym.sim import MoveSpec

        _make("servogym/Schedule-PMD-XyStage-v1", moves=(MoveSpec(0.1, 0.5, 5.0),))


def test_render_draws_every_axis():
    for eid in ("servogym/Tune-PMD-XyStage-v1", "servogym/Schedule-PMD-XyStage-v1"):
        env = gym.make(eid, render_mode="rgb_array")
        env.reset(seed=0)
        env.step(np.zeros(env.action_space.shape, np.float32))
        img = env.render()
        assert img.dtype == np.uint8 and img.ndim == 3 and img.shape[0] > 100


def test_docs_envs_md_has_the_machine_tables():
    from pathlib import Path

    from servogym.envs._schedule import observation_table as schedule_table
    from servogym.envs._tune import observation_table as tune_table

    text = (Path(__file__).parents[2] / "docs" / "envs.md").read_text()
    axes = MULTI_PLANTS["two-link-arm"].axes
    assert "\n".join(tune_table(axes).splitlines()[1:]) in text
    assert schedule_table(True, axes) in text
    for eid in SCHEDULE_IDS:
        assert f"| `{eid}` |" in text  # the centres' and the feasibility tables
