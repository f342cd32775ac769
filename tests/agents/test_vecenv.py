"""GroupedVecEnv: SB3's vector-env interface on the grouped vector env, the same results as
SB3's DummyVecEnv on the same envs and seeds, bit for bit."""

from __future__ import annotations

from functools import partial

import gymnasium as gym
import numpy as np
import pytest
from stable_baselines3.common.monitor import Monitor
from stable_baselines3.common.vec_env import DummyVecEnv

import servogym  # noqa: F401
from servogym.agents._vecenv import GroupedVecEnv

SCHEDULE = "servogym/Schedule-PMD-RotaryInertia-v1"


def _assert_infos_equal(a: list[dict], b: list[dict], where: str) -> None:
    assert len(a) == len(b), where
    for i, (x, y) in enumerate(zip(a, b, strict=True)):
        assert set(x) == set(y), f"{where}[{i}]"
        for key in x:
            if isinstance(x[key], np.ndarray):
                np.testing.assert_array_equal(x[key], y[key], err_msg=f"{where}[{i}][{key}]")
            else:
                assert x[key] == y[key], f"{where}[{i}][{key}]"


def test_same_results_as_dummy_vec_env() -> None:
    fns = [partial(gym.make, SCHEDULE, n_moves=3)] * 5
    dummy, grouped = DummyVecEnv(fns), GroupedVecEnv(fns, workers=2)
    try:
        assert grouped.num_envs == 5 and [len(g) for g in grouped.venv.groups] == [3, 2]
        assert (grouped.observation_space, grouped.action_space) == (
            dummy.observation_space,
            dummy.action_space,
        )
        for venv in (dummy, grouped):
            venv.seed(11)
        np.testing.assert_array_equal(dummy.reset(), grouped.reset())
        _assert_infos_equal(dummy.reset_infos, grouped.reset_infos, "reset")
        rng = np.random.default_rng(0)
        ended = 0
        for t in range(10):
            # wide random actions: some sets diverge, so episodes end at different steps
            action = rng.uniform(-1, 1, (5, *dummy.action_space.shape)).astype(np.float32)
            a, b = dummy.step(action), grouped.step(action)
            for x, y in zip(a[:3], b[:3], strict=True):
                np.testing.assert_array_equal(x, y, err_msg=f"step {t}")
                assert x.dtype == y.dtype
            _assert_infos_equal(a[3], b[3], f"step {t}")
            _assert_infos_equal(dummy.reset_infos, grouped.reset_infos, f"reset infos {t}")
            ended += int(a[2].sum())
        assert ended >= 5  # episodes ended, and every one reset in the same step
    finally:
        dummy.close()
        grouped.close()


def test_attributes_methods_and_wrappers_reach_the_envs_asked() -> None:
    fns = [lambda: Monitor(gym.make(SCHEDULE, n_moves=2))] * 3
    venv = GroupedVecEnv(fns, workers=2)
    try:
        assert venv.get_attr("n_moves") == [2, 2, 2]
        venv.set_attr("n_moves", 4, indices=[2])
        assert venv.get_attr("n_moves", indices=[2, 0]) == [4, 2]
        assert venv.env_method("get_wrapper_attr", "n_moves", indices=2) == [4]
        assert venv.env_is_wrapped(Monitor) == [True] * 3
        with pytest.raises(ValueError, match=r"indices must be env numbers 0 \.\. 2; got \[3\]"):
            venv.get_attr("n_moves", indices=[3])
    finally:
        venv.close()


def test_ppo_trains_on_it() -> None:
    from stable_baselines3 import PPO

    venv = GroupedVecEnv([partial(gym.make, SCHEDULE, n_moves=2)] * 4, workers=2)
    try:
        model = PPO("MlpPolicy", venv, n_steps=16, batch_size=32, n_epochs=1, seed=0, device="cpu")
        model.learn(64)
        assert model.num_timesteps >= 64
    finally:
        venv.close()
