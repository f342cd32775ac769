"""Parker 6000 scheduling with "which stored gain set" (SGENB) as a discrete action."""

import gymnasium as gym
import numpy as np
import pytest
from gymnasium.utils.env_checker import check_env
from stable_baselines3.common.env_checker import check_env as sb3_check_env

import servogym.envs  # noqa: F401  (registers the ids)
from servogym.chips import ParameterError
from servogym.chips.parker6k import Parker6kParams
from servogym.chips.parker6k._family import StoredSetActions
from servogym.chips.parker6k._params import GainSet

SETS = (
    GainSet(sgp=2000, sgi=0, sgv=100, sgvf=0, sgaf=0),
    GainSet(sgp=8500, sgi=50, sgv=230, sgvf=100, sgaf=0),
    GainSet(sgp=20000, sgi=100, sgv=400, sgvf=100, sgaf=0),
)


def make(seed_params=SETS):
    params = Parker6kParams(model="6250", sgset=seed_params)
    return gym.make("servogym/Schedule-Parker6K-Rotary-v1", action_type=StoredSetActions(params))


def test_discrete_stored_set_action_passes_both_checkers():
    env = make()
    assert env.action_space == gym.spaces.Discrete(3)
    check_env(env.unwrapped, skip_render_check=True)
    sb3_check_env(env.unwrapped)


def test_the_chosen_set_decides_the_response():
    # Three moves with each set: same seed, same episode, different gains in force.
    rewards = {}
    for k in range(3):
        env = make()
        env.reset(seed=3)
        rewards[k] = [env.step(k)[1] for _ in range(3)]
        assert np.all(np.isfinite(rewards[k]))
    assert len({tuple(r) for r in rewards.values()}) == 3


def test_a_set_index_out_of_range_is_refused():
    env = make()
    env.reset(seed=0)
    with pytest.raises((ValueError, ParameterError)):
        env.step(3)
    with pytest.raises(ParameterError, match="at least one stored gain set"):
        StoredSetActions(Parker6kParams(model="6250"))
