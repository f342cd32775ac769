"""Training SB3 agents on servogym envs: vector envs, callbacks, a saved run directory.

Torch and SB3 are imported inside the functions, so ``import servogym`` stays light.
"""

from __future__ import annotations

import json
import time
import warnings
from collections.abc import Mapping
from pathlib import Path
from typing import Any

import gymnasium as gym

ALGOS = ("ppo", "sac", "td3")
"""Algorithms ``servogym train`` offers."""

DEFAULT_REWARD_SCALE = 0.01
"""Training rewards are multiplied by this (move costs ~0.01..1, divergence 10..20)."""


def _algo_class(algo: str):
    import stable_baselines3 as sb3

    classes = {"ppo": sb3.PPO, "sac": sb3.SAC, "td3": sb3.TD3}
    try:
        return classes[algo.lower()]
    except KeyError:
        raise ValueError(f"algo must be one of {', '.join(ALGOS)}; got algo={algo!r}.") from None


def make_env(
    env_id: str,
    env_kwargs: Mapping[str, Any] | None = None,
    reward_scale: float = 1.0,
    residual: Mapping[str, Any] | None = None,
):
    """A function building one env (picklable, for subprocess vector envs).

    ``residual`` (``{"center": [...], "scale": s}``) wraps it in :class:`ResidualAction`.
    """
    return _EnvFactory(env_id, dict(env_kwargs or {}), reward_scale, residual)


def residual_to_absolute(action: Any, residual: Mapping[str, Any]) -> Any:
    """``clip(center + scale * action, -1, 1)``: a residual action in the env's own box."""
    import numpy as np

    center = np.asarray(residual["center"], dtype=np.float32)
    a = center + np.float32(residual["scale"]) * np.asarray(action, dtype=np.float32)
    return np.clip(a, -1.0, 1.0).astype(np.float32)


class ResidualAction(gym.ActionWrapper):
    """The agent acts around a fixed parameter set: ``center + scale * action``, clipped.

    Zero action is the ``center`` set (e.g. the best fixed set); an agent that starts near
    zero starts from it and learns only where scheduling pays.

    Args:
        env: An env with a Box action space in [-1, 1].
        center: The unit-form action of the fixed set (``actions.from_values(...)``).
        scale: How far the agent may move from it, in unit-form units.
    """

    def __init__(self, env: gym.Env, center: Any, scale: float) -> None:
        super().__init__(env)
        self.residual = {"center": [float(c) for c in center], "scale": float(scale)}

    def action(self, action: Any) -> Any:
        return residual_to_absolute(action, self.residual)


class _EnvFactory:
    def __init__(
        self,
        env_id: str,
        env_kwargs: dict[str, Any],
        reward_scale: float,
        residual: Mapping[str, Any] | None = None,
    ) -> None:
        self.env_id, self.env_kwargs, self.reward_scale = env_id, env_kwargs, reward_scale
        self.residual = None if residual is None else dict(residual)

    def __call__(self) -> gym.Env:
        from stable_baselines3.common.monitor import Monitor

        import servogym.envs  # noqa: F401  (registers the ids in a fresh process)

        env = Monitor(gym.make(self.env_id, **self.env_kwargs))
        if self.residual is not None:
            env = ResidualAction(env, self.residual["center"], self.residual["scale"])
        if self.reward_scale != 1.0:
            scale = self.reward_scale
            env = gym.wrappers.TransformReward(env, lambda r: r * scale)
        return env


def set_torch_threads(n: int = 1) -> None:
    """Limit torch's CPU threads (the env workers need the other cores)."""
    import torch

    torch.set_num_threads(max(1, int(n)))


class _WallClock:
    """Stops training after ``seconds`` of wall time (``None``: never)."""

    @staticmethod
    def make(seconds: float | None):
        from stable_baselines3.common.callbacks import BaseCallback

        class WallClockCallback(BaseCallback):
            def __init__(self) -> None:
                super().__init__()
                self.t0 = time.monotonic()

            def _on_step(self) -> bool:
                return seconds is None or time.monotonic() - self.t0 < seconds

        return WallClockCallback()


def train(
    env_id: str,
    algo: str = "sac",
    timesteps: int = 100_000,
    seed: int = 0,
    out: str | Path = "runs/run",
    *,
    n_envs: int = 2,
    env_kwargs: Mapping[str, Any] | None = None,
    algo_kwargs: Mapping[str, Any] | None = None,
    reward_scale: float = DEFAULT_REWARD_SCALE,
    residual: Mapping[str, Any] | None = None,
    checkpoint_every: int = 10_000,
    wall_time_s: float | None = None,
    progress_bar: bool = True,
    subprocess: bool = True,
    torch_threads: int = 1,
    verbose: int = 0,
) -> Path:
    """Train an SB3 agent and save it; returns the path of the final model (``.zip``).

    ``out`` receives ``model.zip``, ``checkpoints/``, ``tensorboard/`` (when the
    ``tensorboard`` package is installed) and ``config.json`` (everything needed to rebuild
    the env for evaluation).

    Args:
        env_id: A registered id (``servogym/Schedule-PMD-VerticalAxis-v0``).
        algo: ``"ppo"``, ``"sac"`` or ``"td3"``.
        timesteps: Env steps to train for (over all envs).
        seed: Seed of the agent and of the envs (env ``i`` gets ``seed + i``).
        out: Run directory.
        n_envs: Envs stepped in parallel.
        env_kwargs: Keyword arguments of ``gymnasium.make``.
        algo_kwargs: Keyword arguments of the SB3 algorithm.
        reward_scale: Training rewards are multiplied by it (evaluation reports raw ones).
        residual: ``{"center": [...], "scale": s}``: the agent acts around a fixed set
            (:class:`ResidualAction`); saved in ``config.json`` so :func:`load_policy` maps
            the model's actions back.
        checkpoint_every: Save a checkpoint every this many env steps.
        wall_time_s: Stop early after this much wall time (s).
        progress_bar: Show SB3's progress bar.
        subprocess: ``SubprocVecEnv`` (one process per env) instead of ``DummyVecEnv``.
        torch_threads: Torch CPU threads of the learner.
        verbose: SB3 verbosity.
    """
    from stable_baselines3.common.callbacks import CallbackList, CheckpointCallback
    from stable_baselines3.common.vec_env import DummyVecEnv, SubprocVecEnv

    if isinstance(timesteps, bool) or not isinstance(timesteps, int) or timesteps < 1:
        raise ValueError(f"timesteps must be an integer >= 1; got timesteps={timesteps!r}.")
    cls = _algo_class(algo)
    set_torch_threads(torch_threads)
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    if residual is not None:
        residual = {
            "center": [float(c) for c in residual["center"]],
            "scale": float(residual["scale"]),
        }
    factories = [make_env(env_id, env_kwargs, reward_scale, residual) for _ in range(n_envs)]
    vec_cls = SubprocVecEnv if subprocess and n_envs > 1 else DummyVecEnv
    venv = vec_cls(factories)
    venv.seed(seed)
    tb = None
    try:
        import tensorboard  # noqa: F401

        tb = str(out / "tensorboard")
    except ImportError:
        warnings.warn(
            "the tensorboard package is not installed, so no TensorBoard logs are written; "
            "pip install tensorboard to get them",
            stacklevel=2,
        )
    config = {
        "env_id": env_id,
        "algo": algo.lower(),
        "timesteps": timesteps,
        "seed": seed,
        "n_envs": n_envs,
        "env_kwargs": dict(env_kwargs or {}),
        "algo_kwargs": dict(algo_kwargs or {}),
        "reward_scale": reward_scale,
        "residual": residual,
    }
    (out / "config.json").write_text(json.dumps(config, indent=2, default=str))
    kwargs = json.loads(json.dumps(dict(algo_kwargs or {})))  # SB3 edits policy_kwargs
    model = cls("MlpPolicy", venv, seed=seed, tensorboard_log=tb, verbose=verbose, **kwargs)
    callbacks = CallbackList(
        [
            CheckpointCallback(
                max(checkpoint_every // n_envs, 1), str(out / "checkpoints"), name_prefix=algo
            ),
            _WallClock.make(wall_time_s),
        ]
    )
    t0 = time.monotonic()
    try:
        with warnings.catch_warnings():
            warnings.filterwarnings("ignore", message="rich is experimental")
            model.learn(timesteps, callback=callbacks, progress_bar=progress_bar)
    finally:
        venv.close()
    path = out / "model.zip"
    model.save(path)
    config.update(trained_timesteps=int(model.num_timesteps), wall_time_s=time.monotonic() - t0)
    (out / "config.json").write_text(json.dumps(config, indent=2, default=str))
    return path


class UnsafeModelError(ValueError):
    """A saved model cannot be loaded without running code from the file (or is damaged)."""


def read_config(path: str | Path, what: str = "--model") -> dict[str, Any]:
    """A run's ``config.json``, read bounded and schema-checked (an :class:`UnsafeModelError`
    naming the file and the entry otherwise)."""
    from servogym._input import InputError, read_json

    try:
        config = read_json(path, f"{what}: the run's config.json")
    except InputError as exc:
        raise UnsafeModelError(str(exc)) from None
    config.setdefault("env_kwargs", {})
    config.setdefault("algo_kwargs", {})
    config.setdefault("residual", None)
    checks = (
        ("algo", lambda v: isinstance(v, str) and v.lower() in ALGOS, f"one of {', '.join(ALGOS)}"),
        ("env_id", lambda v: isinstance(v, str) and bool(v), "an env id"),
        ("env_kwargs", lambda v: isinstance(v, dict), "a JSON object"),
        ("algo_kwargs", lambda v: isinstance(v, dict), "a JSON object"),
        ("residual", lambda v: v is None or (isinstance(v, dict) and {"center", "scale"} <= set(v)),
         "null or an object with center and scale"),
    )  # fmt: skip
    for key, ok, rule in checks:
        if key not in config or not ok(config[key]):
            got = f"{key}={config[key]!r:.60}" if key in config else f"no {key}"
            raise UnsafeModelError(
                f"{what}: {str(path)!r} is not a servogym train config.json: {key} must be "
                f"{rule}; got {got}."
            )
    return config


def load_model(path: str | Path):
    """Load a model saved by :func:`train` without unpickling anything from the file.

    SB3's own ``load`` unpickles the ``data`` entry of the zip (spaces, schedules, the policy
    class), so a crafted ``model.zip`` runs code. Here only the weights are read, with
    ``torch.load(weights_only=True)`` (tensors and plain containers, nothing else); the
    model is rebuilt from the run's ``config.json`` (algorithm, env id and keyword
    arguments, residual map: JSON), and the env gives the spaces.

    Raises:
        UnsafeModelError: if the run folder has no ``config.json``, the zip holds no
            ``policy.pth`` or holds objects other than tensors, or the weights do not fit
            the policy the configuration builds.
    """
    import io
    import zipfile

    import torch

    path = Path(path)
    cfg = path.parent / "config.json"
    if not cfg.exists():
        raise UnsafeModelError(
            f"--model {str(path)!r} has no config.json next to it; servogym rebuilds a policy "
            f"from its run's config.json and loads only the weights, so it never unpickles a "
            f"model file. Evaluate the run folder `servogym train` wrote."
        )
    config = read_config(cfg, f"--model {str(path)!r}")
    algo, env_id = config["algo"].lower(), config["env_id"]
    try:
        with zipfile.ZipFile(path) as zf:
            raw = zf.read("policy.pth")
    except (OSError, zipfile.BadZipFile, KeyError) as exc:
        raise UnsafeModelError(
            f"--model {str(path)!r} is not a saved SB3 model (a zip with policy.pth): {exc}."
        ) from None
    try:
        state = torch.load(io.BytesIO(raw), map_location="cpu", weights_only=True)
    except Exception as exc:  # torch raises UnpicklingError, RuntimeError, ...
        first = str(exc).strip().splitlines()[0] if str(exc).strip() else type(exc).__name__
        raise UnsafeModelError(
            f"--model {str(path)!r}: policy.pth holds more than weights (refused unread: "
            f"{first[:160]})."
        ) from None
    kwargs = json.loads(json.dumps(dict(config.get("algo_kwargs") or {})))
    for key in ("learning_starts", "n_steps", "batch_size", "buffer_size"):
        kwargs.pop(key, None)  # training-only; keep the buffer small
    env = make_env(env_id, config.get("env_kwargs"), 1.0, config.get("residual"))()
    try:
        model = (
            _algo_class(algo)("MlpPolicy", env, device="cpu", buffer_size=1, **kwargs)
            if algo in ("sac", "td3")
            else _algo_class(algo)("MlpPolicy", env, device="cpu", **kwargs)
        )
        model.policy.load_state_dict(state)
    except (RuntimeError, TypeError, ValueError) as exc:
        first = str(exc).strip().splitlines()[0]
        raise UnsafeModelError(
            f"--model {str(path)!r}: its weights do not fit the {algo} policy its config.json "
            f"describes ({first[:160]})."
        ) from None
    finally:
        env.close()
    return model


def load_policy(path: str | Path):
    """A saved model as a policy of the plain env (residual actions mapped back)."""
    from servogym.agents._evaluate import ModelPolicy

    path = Path(path)
    cfg = path.parent / "config.json"
    residual = read_config(cfg)["residual"] if cfg.exists() else None
    return ModelPolicy(load_model(path), residual)
