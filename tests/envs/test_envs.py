"""Every registered servogym env: checkers, determinism, vector envs, wild actions.

The list of envs comes from Gymnasium's registry (``registered_ids``), never by hand.
"""

from __future__ import annotations

import json
import subprocess
import sys
import warnings

import gymnasium as gym
import numpy as np
import pytest

import servogym.envs as envs
from servogym.chips._family import families
from servogym.plants import PLANTS

IDS = envs.registered_ids()
"""Every registered id, every version: the checkers and determinism run on each."""
LATEST_IDS = [i for i in IDS if envs.id_version(i) == envs.VERSION]
"""The newest version's ids: the vector-env and action tests run on these (an older id is
its newer twin with other keyword defaults, ``tests/envs/test_registration.py`` checks
that the two differ only there)."""
BOX_IDS = [
    i for i in LATEST_IDS
    if not any(f"-{name}-v" in i and s.stored_sets for name, s in envs.SCENARIOS.items())
]  # fmt: skip
"""The ids whose action is a Box of register entries (not the 6250's stored-set choice)."""


def _rollout(eid: str, seed: int, n_episodes: int = 2) -> tuple[list, list]:
    env = gym.make(eid)
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


def test_registry_has_every_kind_family_plant_and_version():
    from servogym._registration import (
        MACHINE_SCHEDULE_VERSIONS,
        MACHINE_VERSIONS,
        PLANT_VERSIONS,
        SCENARIO_VERSIONS,
    )
    from servogym.plants import MULTI_PLANTS

    expected = {
        envs.env_id(kind, fam, plant, version)
        for kind in ("Tune", "Schedule")
        for fam in families().values()
        for plant in PLANTS
        for version in PLANT_VERSIONS
    }
    expected |= {
        f"servogym/Schedule-{envs.family_id_name(families()[s.family])}-{name}-v{version}"
        for name, s in envs.SCENARIOS.items()
        for version in SCENARIO_VERSIONS
    }
    expected |= {  # the multi-axis plants' ids, from -v1 (tests/envs/test_multi_envs.py)
        envs.env_id(kind, fam, plant, version)
        for kind in ("Tune", "Schedule")
        for fam in families().values()
        for plant in MULTI_PLANTS
        for version in MACHINE_VERSIONS
    }
    expected |= {  # and their Schedule ids' -v2 (checked centres)
        envs.env_id("Schedule", fam, plant, version)
        for fam in families().values()
        for plant in MULTI_PLANTS
        for version in MACHINE_SCHEDULE_VERSIONS
    }
    assert set(IDS) == expected
    assert {"servogym/Tune-PMD-VerticalAxis-v0", "servogym/Tune-PMD-VerticalAxis-v1"} <= set(IDS)
    assert "servogym/Schedule-PMD-XyStage-v2" in IDS and "servogym/Tune-PMD-XyStage-v2" not in IDS
    assert not any(i.endswith("-v2") for i in IDS if "TwoLinkArm" not in i and "XyStage" not in i)
    assert sorted(envs.VERSIONS) == [0, 1, 2] and envs.VERSION == 1
    assert PLANT_VERSIONS == (0, 1) and MACHINE_SCHEDULE_VERSIONS == (1, 2)


@pytest.mark.parametrize("eid", IDS)
def test_checkers_pass(eid):
    from gymnasium.utils.env_checker import check_env as gym_check
    from stable_baselines3.common.env_checker import check_env as sb3_check

    with warnings.catch_warnings():  # making a -v0 id warns that -v1 exists (Gymnasium)
        warnings.simplefilter("ignore", DeprecationWarning)
        rendered, plain = gym.make(eid, render_mode="rgb_array").unwrapped, gym.make(eid).unwrapped
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # a checker warning fails the test
        gym_check(rendered)
        sb3_check(plain)


@pytest.mark.parametrize("eid", IDS)
def test_same_seed_same_episodes_other_seed_other_ones(eid):
    obs_a, rew_a = _rollout(eid, 7)
    obs_b, rew_b = _rollout(eid, 7)
    np.testing.assert_array_equal(np.array(obs_a), np.array(obs_b))
    assert rew_a == rew_b
    obs_c, _ = _rollout(eid, 8)
    assert not np.array_equal(obs_a[0], obs_c[0])


def test_same_seed_same_episodes_in_a_fresh_process():
    code = (
        "import json, sys; sys.path.insert(0, '.');"
        "from tests.envs.test_envs import _rollout, IDS;"
        "print(json.dumps({i: [[o.tolist() for o in r[0]], r[1]] for i in IDS "
        "for r in [_rollout(i, 3, 1)]}))"
    )
    out = subprocess.run(
        [sys.executable, "-c", code], capture_output=True, text=True, check=True
    ).stdout
    other = json.loads(out.strip().splitlines()[-1])
    for eid in IDS:
        obs, rew = _rollout(eid, 3, 1)
        assert other[eid][0] == [o.tolist() for o in obs], eid
        assert other[eid][1] == rew, eid


@pytest.mark.parametrize("mode", ["sync", "async"])
@pytest.mark.parametrize("eid", LATEST_IDS)
def test_gymnasium_vector_envs_step(eid, mode):
    kw = {"vector_kwargs": {"context": "fork"}} if mode == "async" else {}
    venv = gym.make_vec(eid, num_envs=2, vectorization_mode=mode, **kw)
    try:
        obs, _ = venv.reset(seed=0)
        assert obs.shape == (2, *venv.single_observation_space.shape)
        venv.action_space.seed(0)
        for _ in range(3):
            obs, rew, _term, _trunc, _ = venv.step(venv.action_space.sample())
            assert np.isfinite(obs).all() and np.isfinite(rew).all()
            assert rew.shape == (2,)
    finally:
        venv.close()


@pytest.mark.parametrize("eid", LATEST_IDS)
def test_sb3_subproc_vec_env_steps(eid):
    from stable_baselines3.common.vec_env import SubprocVecEnv

    from servogym.agents import make_env

    venv = SubprocVecEnv([make_env(eid), make_env(eid)], start_method="fork")
    try:
        venv.seed(0)
        obs = venv.reset()
        assert obs.shape == (2, *venv.observation_space.shape)
        for _ in range(3):
            actions = np.stack([venv.action_space.sample() for _ in range(2)])
            obs, rew, _done, _ = venv.step(actions)
            assert np.isfinite(obs).all() and np.isfinite(rew).all()
    finally:
        venv.close()


# --- wild actions -------------------------------------------------------------------------


@pytest.mark.parametrize("eid", BOX_IDS)
@pytest.mark.parametrize("bad", [np.nan, np.inf, -np.inf, 1.5, -1.0001])
def test_non_finite_or_out_of_range_action_names_index_and_register(eid, bad):
    env = gym.make(eid).unwrapped
    env.reset(seed=0)
    a = np.zeros(env.action_space.shape, dtype=np.float32)
    a[1] = bad
    name = env.actions.names[1]
    with pytest.raises(ValueError, match=rf"action\[1\] \({name}\) must be a finite number"):
        env.step(a)


@pytest.mark.parametrize("eid", BOX_IDS)
@pytest.mark.parametrize("shape", [(1,), (21,), (2, 9), ()])  # 20: a PMAC machine's
def test_wrong_action_shape_is_an_error(eid, shape):
    env = gym.make(eid).unwrapped
    env.reset(seed=0)
    with pytest.raises(ValueError, match="the action must have shape"):
        env.step(np.zeros(shape, dtype=np.float32))
    with pytest.raises(ValueError, match="the action must be an array"):
        env.step("kp=100")


@pytest.mark.parametrize("eid", BOX_IDS)
def test_extreme_actions_give_finite_rewards_and_observations(eid):
    env = gym.make(eid).unwrapped
    n = env.action_space.shape[0]
    rng = np.random.default_rng(0)
    corners = [np.full(n, -1.0), np.full(n, 1.0)]
    corners += [rng.choice([-1.0, 1.0], size=n) for _ in range(2)]
    for i, a in enumerate(corners):
        obs, _ = env.reset(seed=i)
        done = False
        while not done:
            obs, r, term, trunc, _info = env.step(a.astype(np.float32))
            assert np.isfinite(obs).all() and np.isfinite(r)
            assert env.observation_space.contains(obs)
            assert -2000.0 <= r <= 0.0
            done = term or trunc


# --- arguments ----------------------------------------------------------------------------


def test_raw_integer_actions_and_fixed_registers():
    env = gym.make(
        "servogym/Schedule-PMD-VerticalAxis-v1",
        action_type="raw",
        params=("kp", "kd", "bias"),
        fixed={"ki": 0},
    ).unwrapped
    assert isinstance(env.action_space, gym.spaces.MultiDiscrete)
    assert env.action_space.nvec.tolist() == [32768, 32768, 65536]
    env.reset(seed=0)
    _, r, *_, info = env.step(np.array([300, 800, 32768 + 500]))
    assert info["params"]["kp"] == 300 and info["params"]["bias"] == 500
    assert info["params"]["ki"] == 0 and np.isfinite(r)
    from gymnasium.utils.env_checker import check_env as gym_check
    from stable_baselines3.common.env_checker import check_env as sb3_check

    gym_check(env)
    sb3_check(env)
    with pytest.raises(ValueError, match=r"action\[0\] \(kp\) must satisfy 0 <= action\[0\]"):
        env.step(np.array([40000, 0, 0]))


def test_fixing_a_register_removes_it_from_the_action():
    env = gym.make("servogym/Tune-PMD-Rotary-v1", fixed={"kout": 20000, "bias": 0}).unwrapped
    assert "kout" not in env.actions.names and env.action_space.shape == (7,)
    env.reset(seed=0)
    *_, info = env.step(env.action_space.sample())
    assert info["params"]["kout"] == 20000
    with pytest.raises(ValueError, match="either set by the action or fixed"):
        gym.make("servogym/Tune-PMD-Rotary-v1", params=("kp",), fixed={"kp": 1})


def test_other_model_of_the_family_and_a_wrong_family():
    env = gym.make("servogym/Tune-PMD-VerticalAxis-v1", chip_model="MC58000").unwrapped
    assert env.scenario.chip_model == "MC58000"
    with pytest.raises(Exception, match="unknown chip model 'MC9999'"):
        gym.make("servogym/Tune-PMD-VerticalAxis-v1", chip_model="MC9999")


def test_reset_options_set_the_plant_and_privileged_observation_shows_it():
    env = gym.make("servogym/Tune-PMD-VerticalAxis-v1", privileged=True).unwrapped
    assert env.observation_space.shape == (12 + len(PLANTS["vertical-axis"].randomised()),)
    obs, info = env.reset(seed=0, options={"plant_values": {"payload_kg": 10.0}})
    assert info["plant_values"]["payload_kg"] == 10.0
    assert obs[12] == pytest.approx(1.0)  # payload at the top of its range
    light, _ = env.reset(seed=0, options={"plant_values": {"payload_kg": 0.5}})
    assert light[7] < obs[7]  # a lighter payload needs less holding command
    with pytest.raises(ValueError, match="only contain 'plant_values'"):
        env.reset(options={"payload_kg": 1.0})


def test_schedule_payload_follows_the_pick_and_place_cycle():
    env = gym.make("servogym/Schedule-PMD-VerticalAxis-v1").unwrapped
    _obs, info = env.reset(seed=1)
    payloads = [info["payload_kg"]]
    defaults = env.actions.from_values({})
    for _ in range(env.n_moves - 1):
        *_, info = env.step(defaults)
        payloads.append(env.plant.values["payload_kg"])
    part = env.part_value
    assert payloads == [0.5 if k % 2 == 0 else part for k in range(env.n_moves)]
    assert np.diff(env._targets[::2] > 0).sum() == 0  # picks all below, places all above


def test_render_gives_a_picture_of_the_last_response():
    for eid in ("servogym/Tune-PMD-Arm-v1", "servogym/Schedule-PMD-Arm-v1"):
        env = gym.make(eid, render_mode="rgb_array")
        env.reset(seed=0)
        env.step(env.unwrapped.actions.from_values({}))
        img = env.render()
        assert img.dtype == np.uint8 and img.ndim == 3 and img.shape[2] == 3
        assert img.shape[0] > 100


def test_make_in_a_fresh_process_by_module_prefix():
    code = (
        "import gymnasium as gym;"
        "e = gym.make('servogym.envs:servogym/Tune-PMD-Rotary-v1'); print(e.reset(seed=0)[0][0])"
    )
    subprocess.run([sys.executable, "-c", code], check=True, capture_output=True)


# --- docs match the code ------------------------------------------------------------------


def test_docstring_tables_are_generated_from_the_code():
    from servogym.envs._common import action_table
    from servogym.envs._schedule import observation_table as schedule_table
    from servogym.envs._tune import observation_table as tune_table

    for cls, obs_table in ((envs.TuneEnv, tune_table()), (envs.ScheduleEnv, schedule_table())):
        doc = " ".join(cls.__doc__.split())
        for table in (action_table("MC2100"), obs_table):
            assert " ".join(table.split()) in doc
        assert "Type (Unit)" in doc


def test_docs_envs_md_has_the_code_tables():
    from pathlib import Path

    from servogym.envs._common import action_table
    from servogym.envs._schedule import observation_table as schedule_table
    from servogym.envs._tune import observation_table as tune_table

    text = (Path(__file__).parents[2] / "docs" / "envs.md").read_text()
    for table in (action_table("MC2100"), tune_table(), schedule_table()):
        assert table in text


def test_identification_with_a_given_parameter_set():
    from servogym.agents import nominal_set

    tuned = nominal_set("pmd", "vertical-axis")
    env = gym.make("servogym/Tune-PMD-VerticalAxis-v1", ident_params=tuned).unwrapped
    default = gym.make("servogym/Tune-PMD-VerticalAxis-v1").unwrapped
    obs, _ = env.reset(seed=0)
    obs_default, _ = default.reset(seed=0)
    assert env.ident_params.kp == tuned["kp"]
    assert obs[0] < obs_default[0]  # the tuned set follows the identification move better
