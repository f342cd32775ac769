"""A plain SB3 user's view: PPO trains on the ids as registered (episodes run their moves, the
rewards are scaled once, the weights update), and the RL Zoo hyperparameters name exactly the
scenario ids and the machines' -v2 Schedule ids."""

from __future__ import annotations

from pathlib import Path

import gymnasium as gym
import numpy as np
import pytest
import yaml

import servogym  # noqa: F401  (registers the ids)
from servogym.agents import make_env, run_episodes
from servogym.agents._train import effective_reward_scale
from servogym.envs import SCENARIOS, registered_ids

SCENARIO_IDS = [i for i in registered_ids() if any(i.endswith(f"-{n}-v1") for n in SCENARIOS)]
MACHINE_V2_IDS = [
    i for i in registered_ids() if i.startswith("servogym/Schedule-") and i.endswith("-v2")
]
"""The multi-axis machines' Schedule ids of -v2 (checked centres)."""
HYPERPARAMS = Path(__file__).resolve().parents[2] / "servogym" / "agents" / "hyperparams"


@pytest.mark.parametrize("eid", SCENARIO_IDS + MACHINE_V2_IDS)
def test_plain_ppo_trains_a_few_hundred_steps_and_updates_its_weights(eid):
    # What this asserts: plain SB3 runs on the id as registered, the untrained policy's
    # episodes run their moves, the rewards are scaled and finite, and the update changes
    # the weights. Not that the policy gets better: 256 steps are too few to tell.
    from stable_baselines3 import PPO
    from stable_baselines3.common.monitor import Monitor

    env = Monitor(gym.make(eid))
    model = PPO("MlpPolicy", env, n_steps=128, batch_size=64, n_epochs=2, seed=0, device="cpu")
    before = [p.detach().clone() for p in model.policy.parameters()]
    model.learn(256)
    assert model.num_timesteps >= 256
    lengths = env.get_episode_lengths()
    n_moves = env.unwrapped.n_moves
    # Episodes do not end at the first step: an untrained policy acts around the safe set
    # (its exploration, std 1 = the box's whole reach, still diverges some moves).
    assert len(lengths) >= 256 // n_moves - 1
    assert np.mean(lengths) > 2 and max(lengths) == n_moves
    rewards = env.get_episode_rewards()
    assert all(np.isfinite(rewards)) and min(rewards) > -20.0  # scaled by 0.01
    after = list(model.policy.parameters())
    assert any(not np.array_equal(a.detach(), b) for a, b in zip(after, before, strict=True))


def test_make_env_passes_the_scale_to_the_env_once():
    eid = "servogym/Schedule-PMD-RotaryInertia-v1"
    rewards = {}
    for scale in (None, 0.5):
        env = make_env(eid, {}, scale)()
        assert not isinstance(env, gym.wrappers.TransformReward)
        env.reset(seed=0)
        _, r, *_, info = env.step(np.zeros(env.action_space.shape, np.float32))
        rewards[scale] = (r, info["raw_reward"])
    assert rewards[None][0] == pytest.approx(0.01 * rewards[None][1])
    assert rewards[0.5][0] == pytest.approx(0.5 * rewards[0.5][1])
    assert effective_reward_scale({}, None) == 0.01
    assert effective_reward_scale({"reward_scale": 0.1}, None) == 0.1
    assert effective_reward_scale({}, 0.2) == 0.2
    with pytest.raises(ValueError, match=r"reward_scale=0\.2 contradicts env_kwargs"):
        effective_reward_scale({"reward_scale": 0.1}, 0.2)


def test_run_episodes_reports_raw_returns_whatever_the_scale():
    eid = "servogym/Schedule-PMD-ArmPayload-v1"
    returns = []
    for scale in (0.01, 1.0):
        env = gym.make(eid, reward_scale=scale, n_moves=2)
        zero = np.zeros(env.action_space.shape, np.float32)
        (out,) = run_episodes(env, lambda obs, a=zero: a, [3])
        returns.append(out.episode_return)
        assert out.episode_return == pytest.approx(-2 * out.mean_cost)
    assert returns[0] == pytest.approx(returns[1])


@pytest.mark.parametrize("algo", ["sac", "ppo"])
def test_rl_zoo_hyperparameters_name_registered_ids(algo):
    conf = yaml.safe_load((HYPERPARAMS / f"{algo}.yml").read_text())
    ids = [k for k in conf if k != "default"]
    named = set(SCENARIO_IDS) | set(MACHINE_V2_IDS)
    assert set(ids) <= named and len(MACHINE_V2_IDS) == 6
    discrete = {i for i in SCENARIO_IDS if i.endswith("-StoredSets-v1")}
    assert set(ids) == (named - discrete if algo == "sac" else named)
    for eid in ids:
        assert conf[eid]["policy"] == "MlpPolicy" and conf[eid]["n_timesteps"] > 0
