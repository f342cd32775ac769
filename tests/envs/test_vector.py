"""GroupedAsyncVectorEnv: the same results as SyncVectorEnv (same-step autoreset), bit for bit."""

from __future__ import annotations

from functools import partial

import gymnasium as gym
import numpy as np
import pytest
from gymnasium.vector import AutoresetMode, SyncVectorEnv

import servogym  # noqa: F401
from servogym.envs import GroupedAsyncVectorEnv

SCHEDULE = "servogym/Schedule-PMD-RotaryInertia-v1"
TUNE = "servogym/Tune-PMD-VerticalAxis-v1"


def _assert_info_equal(a: dict, b: dict, where: str) -> None:
    assert set(a) == set(b), where
    for key in a:
        if isinstance(a[key], dict):
            _assert_info_equal(a[key], b[key], f"{where}[{key}]")
        elif a[key].dtype == object:
            mask = a.get("_" + key, np.ones(len(a[key]), bool))
            for i in np.flatnonzero(mask):
                x, y = a[key][i], b[key][i]
                if isinstance(x, np.ndarray):
                    np.testing.assert_array_equal(x, y, err_msg=f"{where}[{key}][{i}]")
                else:
                    assert x == y, f"{where}[{key}][{i}]"
        else:
            np.testing.assert_array_equal(a[key], b[key], err_msg=f"{where}[{key}]")


@pytest.mark.parametrize(("env_id", "n", "workers"), [(SCHEDULE, 5, 2), (TUNE, 3, 3)])
def test_same_results_as_sync_vector_env(env_id: str, n: int, workers: int) -> None:
    fns = [partial(gym.make, env_id)] * n
    sync = SyncVectorEnv(fns, autoreset_mode=AutoresetMode.SAME_STEP)
    grouped = GroupedAsyncVectorEnv(fns, workers=workers)
    try:
        assert grouped.metadata["autoreset_mode"] == AutoresetMode.SAME_STEP
        assert grouped.single_action_space == sync.single_action_space
        assert grouped.observation_space == sync.observation_space
        sizes = [len(g) for g in np.array_split(range(n), workers)]
        assert [len(g) for g in grouped.groups] == sizes
        obs_a, info_a = sync.reset(seed=7)
        obs_b, info_b = grouped.reset(seed=7)
        np.testing.assert_array_equal(obs_a, obs_b)
        _assert_info_equal(info_a, info_b, "reset")
        rng = np.random.default_rng(0)
        ended = 0
        for t in range(12):
            # wide random actions: some sets diverge, so episodes end at different steps
            action = rng.uniform(-1, 1, sync.action_space.shape).astype(np.float32)
            a = sync.step(action)
            b = grouped.step(action)
            for x, y in zip(a[:4], b[:4], strict=True):
                np.testing.assert_array_equal(x, y, err_msg=f"step {t}")
            _assert_info_equal(a[4], b[4], f"step {t}")
            ended += int(np.sum(a[2] | a[3]))
        assert ended > 0  # the same-step resets were exercised
        assert grouped.get_attr("spec")[0].id == env_id
    finally:
        sync.close()
        grouped.close()


def test_different_seeds_differ_and_seed_lists() -> None:
    fns = [partial(gym.make, SCHEDULE)] * 2
    with GroupedAsyncVectorEnv(fns, workers=2) as envs:
        a, _ = envs.reset(seed=1)
        b, _ = envs.reset(seed=[1, 2])
        np.testing.assert_array_equal(a, b)
        c, _ = envs.reset(seed=[3, 4])
        assert not np.array_equal(a, c)
        with pytest.raises(ValueError, match=r"one seed per env \(2\); got 3 seeds"):
            envs.reset(seed=[1, 2, 3])


@pytest.mark.parametrize("workers", [0, 3, 1.5, True])
def test_bad_workers(workers: object) -> None:
    fns = [partial(gym.make, SCHEDULE)] * 2
    with pytest.raises(ValueError, match=r"1 <= workers <= len\(env_fns\) = 2; got workers="):
        GroupedAsyncVectorEnv(fns, workers=workers)  # type: ignore[arg-type]


def test_no_envs() -> None:
    with pytest.raises(ValueError, match="at least one env builder; got 0"):
        GroupedAsyncVectorEnv([])


def _broken_env() -> gym.Env:
    raise RuntimeError("this plant cannot be built")


def test_a_worker_error_is_raised_with_its_traceback() -> None:
    with pytest.raises(RuntimeError, match=r"(?s)worker 1.*this plant cannot be built"):
        GroupedAsyncVectorEnv([partial(gym.make, SCHEDULE), _broken_env], workers=2)


def test_different_spaces_are_refused() -> None:
    fns = [partial(gym.make, SCHEDULE), partial(gym.make, TUNE)]
    with pytest.raises(ValueError, match="every env must have the same spaces"):
        GroupedAsyncVectorEnv(fns, workers=2)


def test_closed_env_refuses_steps() -> None:
    envs = GroupedAsyncVectorEnv([partial(gym.make, SCHEDULE)], workers=1)
    envs.close()
    with pytest.raises(RuntimeError, match="closed"):
        envs.reset(seed=0)


def test_spawned_workers_take_lambdas() -> None:
    envs = GroupedAsyncVectorEnv([lambda: gym.make(SCHEDULE)] * 2, workers=1, context="spawn")
    try:
        obs, _ = envs.reset(seed=0)
        out = envs.step(np.zeros(envs.action_space.shape, np.float32))
        assert obs.shape == out[0].shape == (2, *envs.single_observation_space.shape)
        assert np.all(np.isfinite(out[1]))
    finally:
        envs.close()
