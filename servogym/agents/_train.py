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

from servogym._registration import REWARD_SCALE_V1

ALGOS = ("ppo", "sac", "td3")
"""Algorithms ``servogym train`` offers."""

DEFAULT_REWARD_SCALE = REWARD_SCALE_V1
"""``train``'s reward scale unless one is given (0.01): passed to the envs of every id as
their ``reward_scale``, so the ``-v1`` ids (whose own default it is) and the ``-v0`` ids
(raw rewards by default) train on the same scale, scaled once, by the env."""


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
    reward_scale: float | None = None,
    residual: Mapping[str, Any] | None = None,
):
    """A function building one env (picklable, for subprocess vector envs).

    ``reward_scale`` is passed to the env as its ``reward_scale`` keyword (``None``: the
    env's own, from ``env_kwargs`` or its id's default); the env scales its rewards, so
    nothing is scaled twice. ``residual`` (``{"center": ..., "scale": s}``) makes the env
    act around a set with its own residual action (:func:`residual_env_kwargs`).
    """
    kwargs = residual_env_kwargs(env_id, env_kwargs, residual)
    if reward_scale is not None:
        kwargs["reward_scale"] = reward_scale
    return _EnvFactory(env_id, kwargs)


def effective_reward_scale(
    env_kwargs: Mapping[str, Any] | None, reward_scale: float | None
) -> float:
    """The reward scale a run's envs use: ``reward_scale`` when given (it must agree with
    ``env_kwargs["reward_scale"]`` if that is given too), else the env keyword, else
    :data:`DEFAULT_REWARD_SCALE`."""
    in_env = (env_kwargs or {}).get("reward_scale")
    if reward_scale is not None and in_env is not None and in_env != reward_scale:
        raise ValueError(
            f"reward_scale={reward_scale!r} contradicts env_kwargs reward_scale={in_env!r}; "
            "give it once (the env scales its rewards)."
        )
    scale = reward_scale if reward_scale is not None else in_env
    return DEFAULT_REWARD_SCALE if scale is None else scale


def residual_env_kwargs(
    env_id: str, env_kwargs: Mapping[str, Any] | None, residual: Mapping[str, Any] | None
) -> dict[str, Any]:
    """The env keyword arguments that make it act around a set: ``train``'s ``residual``.

    ``residual`` is ``{"center": ..., "scale": s}``: the env's own residual action
    (``action_type="residual"``, ``center``, ``residual_scale``:
    :class:`servogym.envs.ResidualActions`) maps the agent's actions, so there is one
    implementation. ``center`` is the set's register values (a dict), or, as run folders
    saved before wrote it, the unit-form action of the set (a list), taken as the register
    values it stands for. ``None``: ``env_kwargs`` unchanged.

    Raises:
        ValueError: when the env already acts around a set (the scenario ids, or
            ``action_type="residual"`` in ``env_kwargs``: a residual on it would stack on
            the env's own; give ``center``/``residual_scale`` as env keywords instead), or
            when its action is not the unit box of registers (raw integers, stored sets).
    """
    kwargs = dict(env_kwargs or {})
    if residual is None:
        return kwargs
    import numpy as np

    from servogym.envs import ResidualActions, UnitActions

    shown = f"residual={dict(residual)!r:.120}"
    env = gym.make(env_id, **kwargs)
    try:
        actions = env.unwrapped.actions
        if isinstance(actions, ResidualActions):
            raise ValueError(
                f"{shown}: {env_id} already acts around a safe set (action_type='residual', "
                f"center={actions.center_values}, residual_scale={actions.scale}); a residual "
                f"on it would stack on the env's own. Give the set and the reach as env "
                f"keywords instead: env_kwargs center={{...}}, residual_scale=s."
            )
        if not isinstance(actions, UnitActions):
            raise ValueError(
                f"{shown}: acting around a set needs an env whose action is the unit box of "
                f"registers (action_type='unit'); {env_id} with env_kwargs {kwargs} has "
                f"{type(actions).__name__} ({env.action_space})."
            )
        center = residual["center"]
        if not isinstance(center, Mapping):  # the unit-form action of the set
            values = actions.to_values(np.asarray(center, dtype=np.float64))
            center = {name: values[name] for name in actions.names}
    finally:
        env.close()
    return {**kwargs, "action_type": "residual", "center": dict(center),
            "residual_scale": float(residual["scale"])}  # fmt: skip


class _EnvFactory:
    def __init__(self, env_id: str, env_kwargs: dict[str, Any]) -> None:
        self.env_id, self.env_kwargs = env_id, env_kwargs

    def __call__(self) -> gym.Env:
        import multiprocessing
        import signal

        from stable_baselines3.common.monitor import Monitor

        import servogym.envs  # noqa: F401  (registers the ids in a fresh process)

        if multiprocessing.parent_process() is not None:
            # An env worker: Ctrl-C or SIGTERM to the group is the trainer's to handle (it
            # saves the model, then closes the workers); a worker killed first would leave
            # the trainer without its envs.
            signal.signal(signal.SIGINT, signal.SIG_IGN)
            signal.signal(signal.SIGTERM, signal.SIG_IGN)

        return Monitor(gym.make(self.env_id, **self.env_kwargs))


def set_torch_threads(n: int = 1) -> None:
    """Limit torch's CPU threads (the env workers need the other cores)."""
    import torch

    torch.set_num_threads(max(1, int(n)))


class TrainingStopped(Exception):
    """Training was stopped by SIGINT or SIGTERM; the model and its config were saved.

    Attributes:
        path: The saved ``model.zip``.
        signal_name: ``"SIGINT"`` or ``"SIGTERM"``.
        timesteps: Env steps trained so far (what ``--resume`` continues from).
    """

    def __init__(self, path: Path, signal_name: str, timesteps: int) -> None:
        super().__init__(f"stopped by {signal_name} at {timesteps} steps; saved {path}")
        self.path, self.signal_name, self.timesteps = path, signal_name, timesteps


class _Stop:
    """SIGINT / SIGTERM handlers that ask the training loop to stop (restored on exit)."""

    def __init__(self) -> None:
        self.signal_name: str | None = None
        self._old: dict[int, Any] = {}

    def __enter__(self) -> _Stop:
        import signal
        import threading

        if threading.current_thread() is threading.main_thread():
            for sig in (signal.SIGINT, signal.SIGTERM):
                self._old[sig] = signal.signal(sig, self._handle)
        return self

    def _handle(self, signum: int, _frame: Any) -> None:
        import signal

        if self.signal_name is not None:  # a second Ctrl-C: stop now, without saving
            raise KeyboardInterrupt
        self.signal_name = signal.Signals(signum).name

    def __exit__(self, *exc: Any) -> None:
        import signal

        for sig, old in self._old.items():
            signal.signal(sig, old)


def _save_run(model: Any, out: Path, config: dict[str, Any], name: str = "model.zip") -> Path:
    """``model`` as ``out/name`` and its ``config.json``, each written atomically."""
    import io

    from servogym._files import write_atomic

    buf = io.BytesIO()
    model.save(buf)
    path = write_atomic(out / name, buf.getvalue())
    config["trained_timesteps"] = int(model.num_timesteps)
    write_atomic(out / "config.json", json.dumps(config, indent=2, default=str) + "\n")
    return path


def _callbacks(
    out: Path, algo: str, config: dict[str, Any], n_envs: int, every: int, total: int,
    stop: _Stop, wall_time_s: float | None, log_progress: bool, t0: float,
):  # fmt: skip
    """Checkpoints (each also model.zip and config.json), the stop flag, the wall clock
    and, when no progress bar shows, a progress line on stderr."""
    import sys

    from stable_baselines3.common.callbacks import BaseCallback

    from servogym._files import write_atomic

    class _Run(BaseCallback):
        def __init__(self) -> None:
            super().__init__()
            self.next_save = (config.get("trained_timesteps", 0) // every + 1) * every
            self.next_log = 0.0
            self.start_steps: int | None = None
            self.ended = False

        def _on_step(self) -> bool:
            steps = int(self.model.num_timesteps)
            if self.start_steps is None:
                self.start_steps = steps - n_envs
            if steps >= self.next_save:
                import io

                buf = io.BytesIO()
                self.model.save(buf)
                (out / "checkpoints").mkdir(exist_ok=True)
                write_atomic(out / "checkpoints" / f"{algo}_{steps}_steps.zip", buf.getvalue())
                write_atomic(out / "model.zip", buf.getvalue())
                config["trained_timesteps"] = steps
                write_atomic(out / "config.json", json.dumps(config, indent=2, default=str) + "\n")
                self.next_save = (steps // every + 1) * every
            now = time.monotonic()
            if log_progress and (now >= self.next_log or (steps >= total and not self.ended)):
                self.ended = steps >= total
                rate = (steps - self.start_steps) / max(now - t0, 1e-9)
                left = max(total - steps, 0) / rate if rate > 0 else float("inf")
                print(
                    f"train: {steps}/{total} steps ({100 * steps / total:.0f} %), "
                    f"{rate:.1f} steps/s, about {left / 60:.1f} min left",
                    file=sys.stderr,
                    flush=True,
                )
                self.next_log = now + 30.0
            if stop.signal_name is not None:
                return False
            return wall_time_s is None or now - t0 < wall_time_s

    return _Run()


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
    reward_scale: float | None = None,
    residual: Mapping[str, Any] | None = None,
    checkpoint_every: int = 10_000,
    wall_time_s: float | None = None,
    progress_bar: bool = True,
    subprocess: bool = True,
    workers: int | None = None,
    torch_threads: int = 1,
    verbose: int = 0,
    resume: bool = False,
    log_progress: bool = False,
) -> Path:
    """Train an SB3 agent and save it; returns the path of the final model (``.zip``).

    ``out`` receives ``model.zip``, ``checkpoints/``, ``tensorboard/`` (when the
    ``tensorboard`` package is installed) and ``config.json`` (everything needed to rebuild
    the env for evaluation).

    Args:
        env_id: A registered id (``servogym/Schedule-PMD-VerticalAxis-v1``).
        algo: ``"ppo"``, ``"sac"`` or ``"td3"``.
        timesteps: Env steps to train for (over all envs).
        seed: Seed of the agent and of the envs (env ``i`` gets ``seed + i``).
        out: Run directory.
        n_envs: Envs stepped in parallel.
        env_kwargs: Keyword arguments of ``gymnasium.make``.
        algo_kwargs: Keyword arguments of the SB3 algorithm.
        reward_scale: The envs' ``reward_scale`` (they scale their own rewards; evaluation
            reports raw ones); ``None``: ``env_kwargs["reward_scale"]``, else
            :data:`DEFAULT_REWARD_SCALE` (0.01), passed to the envs of every id version.
        residual: ``{"center": {register: value}, "scale": s}``: the agent acts around a
            fixed set through the env's own residual action (:func:`residual_env_kwargs`;
            refused on an env that acts around a set already); saved in ``config.json``
            so that :func:`load_model` and ``servogym evaluate`` rebuild that env.
        checkpoint_every: Every this many env steps, save a checkpoint in
            ``checkpoints/`` and the model as ``model.zip`` with its ``config.json``.
        wall_time_s: Stop early after this much wall time (s).
        progress_bar: Show SB3's progress bar.
        resume: Continue the run in ``out`` from its ``model.zip`` (the last checkpoint,
            or the model saved when it was stopped) up to ``timesteps`` in all; the
            settings must be the run's own. Weights and optimiser state are restored (never
            unpickled); an off-policy replay buffer starts empty.
        log_progress: Print a progress line on stderr every 30 s (for logs and pipes,
            where no progress bar shows).

    Raises:
        TrainingStopped: on SIGINT or SIGTERM, after ``model.zip`` and ``config.json``
            were saved (a second signal stops at once).
        subprocess: ``SubprocVecEnv`` (one process per env) instead of ``DummyVecEnv``.
        workers: Step the ``n_envs`` envs in this many processes, each stepping its group in
            turn (:class:`servogym.agents.GroupedVecEnv`: the same results, fewer waits for
            the slowest move; docs/envs.md, "Speed"); ``None``: one process per env
            (``subprocess``). 1 to ``n_envs``.
        torch_threads: Torch CPU threads of the learner.
        verbose: SB3 verbosity.
    """
    from stable_baselines3.common.callbacks import CallbackList
    from stable_baselines3.common.vec_env import DummyVecEnv, SubprocVecEnv

    if isinstance(timesteps, bool) or not isinstance(timesteps, int) or timesteps < 1:
        raise ValueError(f"timesteps must be an integer >= 1; got timesteps={timesteps!r}.")
    cls = _algo_class(algo)
    set_torch_threads(torch_threads)
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    run_kwargs = residual_env_kwargs(env_id, env_kwargs, residual)  # refuses before any work
    if residual is not None:
        residual = {"center": run_kwargs["center"], "scale": run_kwargs["residual_scale"]}
    trained = 0
    if resume:
        trained = check_resume(out, env_id, algo, seed, n_envs, env_kwargs, algo_kwargs)
        if trained >= timesteps:
            raise ValueError(
                f"--resume: the run in {str(out)!r} has trained {trained} steps already, "
                f"--timesteps {timesteps}; give --timesteps > {trained} to train further."
            )
    scale = effective_reward_scale(env_kwargs, reward_scale)
    factories = [_EnvFactory(env_id, {**run_kwargs, "reward_scale": scale}) for _ in range(n_envs)]
    if workers is not None:
        from servogym.agents._vecenv import GroupedVecEnv

        venv = GroupedVecEnv(factories, workers=workers)  # refuses a bad workers
    else:
        venv = (SubprocVecEnv if subprocess and n_envs > 1 else DummyVecEnv)(factories)
    venv.seed(seed + trained)
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
        "reward_scale": scale,
        "residual": residual,
        "trained_timesteps": trained,
    }
    from servogym._files import write_atomic

    write_atomic(out / "config.json", json.dumps(config, indent=2, default=str) + "\n")
    kwargs = json.loads(json.dumps(dict(algo_kwargs or {})))  # SB3 edits policy_kwargs
    model = cls("MlpPolicy", venv, seed=seed, tensorboard_log=tb, verbose=verbose, **kwargs)
    if resume:  # weights and optimiser state only: nothing is unpickled
        model.set_parameters(str(out / "model.zip"), exact_match=True, device=model.device)
        model.num_timesteps = trained
    t0 = time.monotonic()
    with _Stop() as stop:
        callbacks = CallbackList(
            [_callbacks(out, algo, config, n_envs, checkpoint_every, timesteps, stop,
                        wall_time_s, log_progress, t0)]
        )  # fmt: skip
        try:
            with warnings.catch_warnings():
                warnings.filterwarnings("ignore", message="rich is experimental")
                model.learn(
                    timesteps - trained,
                    callback=callbacks,
                    progress_bar=progress_bar,
                    reset_num_timesteps=not resume,
                )
        except (EOFError, BrokenPipeError, ConnectionResetError):
            if stop.signal_name is None:  # the env workers died on their own
                raise
        finally:
            venv.close()
        config["wall_time_s"] = config.get("wall_time_s", 0.0) + time.monotonic() - t0
        if stop.signal_name is not None:
            config["stopped_by"] = stop.signal_name
        path = _save_run(model, out, config)
        if stop.signal_name is not None:
            raise TrainingStopped(path, stop.signal_name, int(model.num_timesteps))
    return path


def check_resume(
    out: Path,
    env_id: str,
    algo: str,
    seed: int,
    n_envs: int,
    env_kwargs: Mapping[str, Any] | None,
    algo_kwargs: Mapping[str, Any] | None,
) -> int:
    """Steps the run in ``out`` has trained, after checking that it is a run of the same
    settings (a :class:`ValueError` naming the option that differs otherwise)."""
    cfg, model = out / "config.json", out / "model.zip"
    if not cfg.is_file() or not model.is_file():
        missing = "config.json" if not cfg.is_file() else "model.zip"
        raise ValueError(
            f"--resume: --out {str(out)!r} holds no {missing}, so there is no run to continue "
            f"(a run saves model.zip at every checkpoint and when stopped). Run without "
            f"--resume to start one."
        )
    config = read_config(cfg, "--resume")
    given = {
        "--env": env_id,
        "--algo": algo.lower(),
        "--seed": seed,
        "--n-envs": n_envs,
        "--env-kwargs": dict(env_kwargs or {}),
        "--algo-kwargs": dict(algo_kwargs or {}),
    }
    stored = {"--env": config["env_id"], "--algo": config["algo"], "--seed": config.get("seed"),
              "--n-envs": config.get("n_envs"), "--env-kwargs": config["env_kwargs"],
              "--algo-kwargs": config["algo_kwargs"]}  # fmt: skip
    for option, value in given.items():
        if stored[option] != value:
            raise ValueError(
                f"--resume: {option} {json.dumps(value)} differs from the run's own "
                f"{json.dumps(stored[option])} ({str(cfg)!r}); repeat the run's settings."
            )
    trained = config.get("trained_timesteps", 0)
    if isinstance(trained, bool) or not isinstance(trained, int) or trained < 0:
        raise ValueError(
            f"--resume: {str(cfg)!r} has trained_timesteps={trained!r}; expected an integer >= 0."
        )
    return trained


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
        ("residual", lambda v: v is None or (isinstance(v, dict) and {"center", "scale"} <= set(v)
         and isinstance(v["center"], dict | list)),
         "null or an object with center (register values, or a unit-form list) and scale"),
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
    arguments, residual set: JSON), and the env gives the spaces.

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
    env = make_env(env_id, config.get("env_kwargs"), None, config.get("residual"))()
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


def run_env_kwargs(config: Mapping[str, Any]) -> dict[str, Any]:
    """The env keyword arguments a run trained with: its ``env_kwargs`` and, when it acted
    around a set, the residual action's (:func:`residual_env_kwargs`). What
    ``servogym evaluate`` builds the policy's env with."""
    return residual_env_kwargs(config["env_id"], config.get("env_kwargs"), config.get("residual"))


def load_policy(path: str | Path):
    """A saved model as a policy of its run's env (:func:`run_env_kwargs`)."""
    from servogym.agents._evaluate import ModelPolicy

    return ModelPolicy(load_model(path))
