"""Bad reset options and non-real actions raise a ValueError naming them, on every env id."""

from __future__ import annotations

import gymnasium as gym
import numpy as np
import pytest

import servogym.envs  # noqa: F401
from servogym.envs import registered_ids


@pytest.mark.parametrize("env_id", registered_ids())
def test_reset_options_and_complex_actions_are_refused(env_id):
    env = gym.make(env_id)
    for options, match in (
        ({"plant_values": None}, r"plant_values'\] must be a dict.*got plant_values=None"),
        ({"plant_values": [1.0]}, r"must be a dict.*got plant_values=\[1.0\]"),
        ("fast", r"reset options must be a dict.*got options='fast'"),
    ):
        with pytest.raises(ValueError, match=match):
            env.reset(seed=0, options=options)
    env.reset(seed=0)
    action = np.asarray(env.action_space.sample())
    for bad in (action.astype(np.complex128) + 0.5j, np.full(action.shape, "x")):
        with pytest.raises(ValueError, match="action"):
            env.step(bad)
    env.close()
