"""SB3's vector-env interface on :class:`servogym.envs.GroupedAsyncVectorEnv`.

SB3 takes its own :class:`~stable_baselines3.common.vec_env.VecEnv`, not a gymnasium vector
env, so ``train`` with ``workers`` steps its envs through :class:`GroupedVecEnv`: ``n_envs``
envs in ``workers`` processes, each process stepping its group in turn (docs/envs.md,
"Speed"). What an agent sees is what :class:`~stable_baselines3.common.vec_env.DummyVecEnv`
gives on the same envs and seeds, bit for bit: an env whose episode ends is reset in the
same step, its last observation in ``info["terminal_observation"]`` and
``info["TimeLimit.truncated"]`` set as SB3 sets it.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from typing import Any

import gymnasium as gym
import numpy as np
from stable_baselines3.common.vec_env.base_vec_env import VecEnv, VecEnvIndices

from servogym.envs import GroupedAsyncVectorEnv

__all__ = ["GroupedVecEnv"]


class GroupedVecEnv(VecEnv):
    """``len(env_fns)`` envs in ``workers`` processes, as an SB3 vector env.

    Args:
        env_fns: Functions that each build one env (picklable with cloudpickle).
        workers: Worker processes, 1 to ``len(env_fns)`` (default: the smaller of
            ``len(env_fns)`` and the CPU count).
        context: The :mod:`multiprocessing` start method; default: the platform's.

    Raises:
        ValueError: as :class:`~servogym.envs.GroupedAsyncVectorEnv`.
    """

    def __init__(
        self,
        env_fns: Sequence[Callable[[], gym.Env]],
        workers: int | None = None,
        context: str | None = None,
    ) -> None:
        self.venv = GroupedAsyncVectorEnv(env_fns, workers=workers, context=context)
        super().__init__(
            len(env_fns), self.venv.single_observation_space, self.venv.single_action_space
        )
        self._actions: Any = None

    def reset(self) -> np.ndarray:
        options = [o or None for o in self._options]  # SB3 passes no options for {}
        results = self.venv.reset_each(self._seeds, options)
        self.reset_infos = [info for _, info in results]
        self._reset_seeds()  # seeds and options serve one reset only, as in SB3's envs
        self._reset_options()
        return np.stack([obs for obs, _ in results])

    def step_async(self, actions: np.ndarray) -> None:
        self._actions = actions

    def step_wait(self) -> tuple[np.ndarray, np.ndarray, np.ndarray, list[dict[str, Any]]]:
        results = self.venv.step_each(list(self._actions))
        obs, rewards, dones, infos = [], [], [], []
        for i, (o, reward, terminated, truncated, info, final) in enumerate(results):
            if final is not None:  # the env was reset: SB3's infos are the last step's
                self.reset_infos[i] = info
                info = {**final[1], "terminal_observation": final[0]}
            info["TimeLimit.truncated"] = bool(truncated and not terminated)
            obs.append(o)
            rewards.append(reward)
            dones.append(terminated or truncated)
            infos.append(info)
        return np.stack(obs), np.array(rewards, np.float32), np.array(dones, bool), infos

    def close(self) -> None:
        self.venv.close()

    def get_attr(self, attr_name: str, indices: VecEnvIndices = None) -> list[Any]:
        return self.venv.apply(
            lambda env: env.get_wrapper_attr(attr_name), self._get_indices(indices)
        )

    def set_attr(self, attr_name: str, value: Any, indices: VecEnvIndices = None) -> None:
        self.venv.apply(lambda env: setattr(env, attr_name, value), self._get_indices(indices))

    def env_method(
        self, method_name: str, *method_args: Any, indices: VecEnvIndices = None, **method_kwargs
    ) -> list[Any]:
        def call(env: gym.Env) -> Any:
            return env.get_wrapper_attr(method_name)(*method_args, **method_kwargs)

        return self.venv.apply(call, self._get_indices(indices))

    def env_is_wrapped(self, wrapper_class: type, indices: VecEnvIndices = None) -> list[bool]:
        from stable_baselines3.common.env_util import is_wrapped

        return self.venv.apply(
            lambda env: is_wrapped(env, wrapper_class), self._get_indices(indices)
        )
