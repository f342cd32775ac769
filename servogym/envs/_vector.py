"""A vector env that steps several envs in each worker process.

gymnasium's :class:`~gymnasium.vector.AsyncVectorEnv` gives every env its own process and
steps them in lockstep, so each vector step waits for the slowest move of all. A servo
move's wall time varies with its length and the episode's plant (a coefficient of
variation near 0.2 on the Schedule ids), which costs about a tenth of the second core with
two envs (docs/envs.md, "Speed"). :class:`GroupedAsyncVectorEnv` puts ``num_envs / workers``
envs in each of ``workers`` processes; a worker steps its group in turn, so it waits for a
sum of moves, whose relative spread shrinks as the square root of the group's size.

Example:
    >>> import gymnasium as gym
    >>> import servogym
    >>> from servogym.envs import GroupedAsyncVectorEnv
    >>> envs = GroupedAsyncVectorEnv(
    ...     [lambda: gym.make("servogym/Schedule-PMD-RotaryInertia-v1")] * 8, workers=2
    ... )
"""

from __future__ import annotations

import contextlib
import multiprocessing as mp
import os
import traceback
from collections.abc import Callable, Sequence
from typing import Any

import gymnasium as gym
import numpy as np
from gymnasium.vector import AutoresetMode, VectorEnv
from gymnasium.vector.utils import (
    CloudpickleWrapper,
    batch_space,
    concatenate,
    create_empty_array,
    iterate,
)

__all__ = ["GroupedAsyncVectorEnv"]


def _step_group(envs: list[gym.Env], actions: list[Any]) -> list[tuple]:
    """One step of each env, resetting an env whose episode ended in the same step."""
    out = []
    for env, action in zip(envs, actions, strict=True):
        obs, reward, terminated, truncated, info = env.step(action)
        final = None
        if terminated or truncated:
            final = (obs, info)
            obs, info = env.reset()
        out.append((obs, reward, terminated, truncated, info, final))
    return out


def _worker(remote: Any, parent_remote: Any, env_fns: CloudpickleWrapper) -> None:
    parent_remote.close()
    envs: list[gym.Env] = []
    try:
        envs = [fn() for fn in env_fns.fn]
        remote.send(("ok", (envs[0].observation_space, envs[0].action_space)))
        while True:
            cmd, data = remote.recv()
            if cmd == "step":
                remote.send(("ok", _step_group(envs, data)))
            elif cmd == "reset":
                seeds, options = data
                results = [
                    env.reset(seed=s, options=o)
                    for env, s, o in zip(envs, seeds, options, strict=True)
                ]
                remote.send(("ok", results))
            elif cmd == "apply":
                fn, local = data
                remote.send(("ok", [fn.fn(envs[i]) for i in local]))
            elif cmd == "close":
                break
            else:
                raise ValueError(f"unknown command {cmd!r}")
    except (KeyboardInterrupt, EOFError):
        pass
    except Exception:  # the parent raises it, with the worker's traceback
        with contextlib.suppress(BrokenPipeError, EOFError):
            remote.send(("error", traceback.format_exc()))
    finally:
        for env in envs:
            env.close()
        remote.close()


class GroupedAsyncVectorEnv(VectorEnv):
    """``len(env_fns)`` envs stepped in ``workers`` processes, each holding a group of them.

    The envs are split into ``workers`` contiguous groups (sizes differ by at most one, as
    :func:`numpy.array_split`). Results are those of
    :class:`~gymnasium.vector.SyncVectorEnv` with ``autoreset_mode=AutoresetMode.SAME_STEP``
    on the same envs and seeds, bit for bit: an env whose episode ends is reset in the same
    step, its last observation and info in ``info["final_obs"]`` and ``info["final_info"]``
    (as SB3's vector envs do, every step is a step of every env).

    Args:
        env_fns: Functions that each build one env (picklable with cloudpickle, so lambdas
            work). Every env has the same observation and action space.
        workers: Worker processes, 1 to ``len(env_fns)``. Default: the smaller of
            ``len(env_fns)`` and ``os.cpu_count()``.
        context: The :mod:`multiprocessing` start method (``"spawn"``, ``"fork"``,
            ``"forkserver"``); default: the platform's.

    Raises:
        ValueError: ``env_fns`` is empty or ``workers`` is outside ``1 <= workers <= len(env_fns)``.
    """

    def __init__(
        self,
        env_fns: Sequence[Callable[[], gym.Env]],
        workers: int | None = None,
        context: str | None = None,
    ) -> None:
        n = len(env_fns)
        if n < 1:
            raise ValueError(f"env_fns must hold at least one env builder; got {n}.")
        if workers is None:
            workers = min(n, os.cpu_count() or 1)
        if isinstance(workers, bool) or not isinstance(workers, int) or not 1 <= workers <= n:
            raise ValueError(
                f"workers must be an integer with 1 <= workers <= len(env_fns) = {n}; "
                f"got workers={workers!r}."
            )
        self.num_envs = n
        self.workers = workers
        self.groups = [list(g) for g in np.array_split(np.arange(n), workers)]
        self.metadata = {"autoreset_mode": AutoresetMode.SAME_STEP}
        self._closed = True
        ctx = mp.get_context(context)
        self._remotes, self._processes = [], []
        for group in self.groups:
            parent, child = ctx.Pipe()
            fns = CloudpickleWrapper([env_fns[i] for i in group])
            p = ctx.Process(target=_worker, args=(child, parent, fns), daemon=True)
            p.start()
            child.close()
            self._remotes.append(parent)
            self._processes.append(p)
        self._closed = False
        spaces = self._receive_all()
        self.single_observation_space, self.single_action_space = spaces[0]
        for k, (obs_space, act_space) in enumerate(spaces[1:], start=1):
            if obs_space != self.single_observation_space or act_space != self.single_action_space:
                self.close()
                raise ValueError(
                    f"every env must have the same spaces; worker {k}'s envs have "
                    f"{obs_space} and {act_space}, worker 0's {self.single_observation_space} "
                    f"and {self.single_action_space}."
                )
        self.observation_space = batch_space(self.single_observation_space, n)
        self.action_space = batch_space(self.single_action_space, n)
        self._obs = create_empty_array(self.single_observation_space, n, fn=np.zeros)

    def _receive_all(self) -> list[Any]:
        out = []
        errors = []
        for k, remote in enumerate(self._remotes):
            try:
                status, payload = remote.recv()
            except EOFError:
                status, payload = "error", f"worker {k} exited without a reply"
            if status == "error":
                errors.append(f"worker {k}:\n{payload}")
            out.append(payload)
        if errors:
            self.close(terminate=True)
            raise RuntimeError("a GroupedAsyncVectorEnv worker failed:\n" + "\n".join(errors))
        return out

    def _check_open(self) -> None:
        if self._closed:
            raise RuntimeError("this GroupedAsyncVectorEnv is closed; make a new one.")

    def reset_each(
        self, seeds: Sequence[int | None], options: Sequence[dict[str, Any] | None]
    ) -> list[tuple[Any, dict[str, Any]]]:
        """Reset env ``i`` with ``seeds[i]`` and ``options[i]``; its ``(obs, info)`` in env
        order (what :meth:`reset` batches, and an SB3 vector env reads one by one)."""
        self._check_open()
        for remote, group in zip(self._remotes, self.groups, strict=True):
            remote.send(("reset", ([seeds[i] for i in group], [options[i] for i in group])))
        return [r for part in self._receive_all() for r in part]

    def step_each(self, actions: Sequence[Any]) -> list[tuple]:
        """Step env ``i`` with ``actions[i]``; per env in env order ``(obs, reward,
        terminated, truncated, info, final)``, ``final`` the ended episode's last ``(obs,
        info)`` (the env was then reset: ``obs`` and ``info`` are the reset's) or ``None``."""
        self._check_open()
        for remote, group in zip(self._remotes, self.groups, strict=True):
            remote.send(("step", [actions[i] for i in group]))
        return [r for part in self._receive_all() for r in part]

    def apply(self, fn: Callable[[gym.Env], Any], indices: Sequence[int] | None = None) -> list:
        """``fn(env)`` in the worker of each env of ``indices`` (default: every one), in the
        order given; ``fn`` is sent with cloudpickle, so a lambda works."""
        self._check_open()
        indices = list(range(self.num_envs)) if indices is None else [int(i) for i in indices]
        where = {i: (k, j) for k, group in enumerate(self.groups) for j, i in enumerate(group)}
        bad = [i for i in indices if i not in where]
        if bad:
            raise ValueError(f"indices must be env numbers 0 .. {self.num_envs - 1}; got {bad}.")
        asked = [[where[i][1] for i in indices if where[i][0] == k] for k in range(self.workers)]
        for remote, local in zip(self._remotes, asked, strict=True):
            remote.send(("apply", (CloudpickleWrapper(fn), local)))
        parts = [iter(part) for part in self._receive_all()]
        return [next(parts[where[i][0]]) for i in indices]

    def reset(
        self, *, seed: int | list[int | None] | None = None, options: dict[str, Any] | None = None
    ) -> tuple[Any, dict[str, Any]]:
        """Reset every env; ``seed`` an int (env ``i`` gets ``seed + i``) or one per env."""
        self._check_open()
        if seed is None:
            seeds: list[int | None] = [None] * self.num_envs
        elif isinstance(seed, int):
            seeds = [seed + i for i in range(self.num_envs)]
        else:
            seeds = list(seed)
            if len(seeds) != self.num_envs:
                raise ValueError(
                    f"seed must be None, an int or one seed per env ({self.num_envs}); "
                    f"got {len(seeds)} seeds."
                )
        results = self.reset_each(seeds, [options] * self.num_envs)
        infos: dict[str, Any] = {}
        for i, (_, info) in enumerate(results):
            infos = self._add_info(infos, info, i)
        obs = concatenate(self.single_observation_space, [o for o, _ in results], self._obs)
        return obs.copy(), infos

    def step(self, actions: Any) -> tuple[Any, np.ndarray, np.ndarray, np.ndarray, dict]:
        """Step every env with its row of ``actions`` (an env whose episode ends is reset)."""
        results = self.step_each(list(iterate(self.action_space, actions)))
        rewards = np.array([r[1] for r in results], dtype=np.float64)
        terminated = np.array([r[2] for r in results], dtype=np.bool_)
        truncated = np.array([r[3] for r in results], dtype=np.bool_)
        infos: dict[str, Any] = {}
        for i, (_, _, _, _, info, final) in enumerate(results):
            if final is not None:
                infos = self._add_info(infos, {"final_obs": final[0], "final_info": final[1]}, i)
            infos = self._add_info(infos, info, i)
        obs = concatenate(self.single_observation_space, [r[0] for r in results], self._obs)
        return obs.copy(), rewards, terminated, truncated, infos

    def call(self, name: str, *args: Any, **kwargs: Any) -> tuple[Any, ...]:
        """Call method ``name`` of every env (or read attribute ``name``), one result per env."""

        def call(env: gym.Env) -> Any:
            attr = env.get_wrapper_attr(name)
            return attr(*args, **kwargs) if callable(attr) else attr

        return tuple(self.apply(call))

    def get_attr(self, name: str) -> tuple[Any, ...]:
        """Attribute ``name`` of every env."""
        return self.call(name)

    def close_extras(self, terminate: bool = False, **kwargs: Any) -> None:
        """Stop the workers (``terminate``: at once, without closing their envs)."""
        if self._closed:
            return
        self._closed = True
        for remote, p in zip(self._remotes, self._processes, strict=True):
            if terminate:
                p.terminate()
            else:
                with contextlib.suppress(BrokenPipeError, EOFError):
                    remote.send(("close", None))
        for remote, p in zip(self._remotes, self._processes, strict=True):
            p.join(timeout=10)
            if p.is_alive():
                p.terminate()
                p.join()
            remote.close()

    def close(self, **kwargs: Any) -> None:
        """Close the envs and stop the workers."""
        if not self._closed:
            self.close_extras(**kwargs)
        self.closed = True

    def __enter__(self) -> GroupedAsyncVectorEnv:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close(terminate=exc[0] is not None)

    def __del__(self) -> None:
        if not getattr(self, "_closed", True):
            self.close(terminate=True)
