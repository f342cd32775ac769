"""``servogym train`` and ``servogym evaluate`` (registered on the app in servogym/cli.py)."""

from __future__ import annotations

import json
from pathlib import Path
from typing import Annotated, Any

import typer
from rich.console import Console
from rich.table import Table

from servogym._cli_common import fail

console = Console()


def _fail(message: str) -> None:
    fail(message)


def _json_option(text: str | None, name: str) -> dict[str, Any]:
    from servogym._input import InputError, parse_json

    if not text:
        return {}
    shown = repr(text) if len(text) <= 80 else repr(text[:60] + "...")
    try:
        return parse_json(text, name)
    except InputError as e:
        _fail(f"{e} E.g. {name} '{{\"n_moves\": 8}}'; got {name} {shown}.")


def _check_env_id(env: str) -> None:
    import difflib

    from servogym.envs import registered_ids

    ids = registered_ids()
    if env not in ids:
        close = difflib.get_close_matches(env, ids, n=3)
        hint = f" Did you mean {', '.join(close)}?" if close else ""
        _fail(f"--env: unknown env id {env!r}; the servogym ids are {', '.join(ids)}.{hint}")


def train_command(
    env: Annotated[str, typer.Option(help="Env id, e.g. servogym/Tune-PMD-VerticalAxis-v1.")],
    algo: Annotated[str, typer.Option(help="ppo, sac or td3.")] = "ppo",
    timesteps: Annotated[int, typer.Option(min=1, help="Env steps to train for.")] = 100_000,
    seed: Annotated[int, typer.Option(help="Seed of the agent and the envs.")] = 0,
    out: Annotated[Path, typer.Option(help="Run directory (model, checkpoints, logs).")] = Path(
        "runs/run"
    ),
    n_envs: Annotated[int, typer.Option(min=1, help="Envs stepped in parallel.")] = 2,
    workers: Annotated[
        int | None,
        typer.Option(
            min=1,
            help="Step the --n-envs envs in this many processes, each stepping its group in "
            "turn (same results; e.g. --n-envs 8 --workers 2 on 2 cores). Default: one "
            "process per env.",
        ),
    ] = None,
    env_kwargs: Annotated[
        str | None,
        typer.Option(help="gymnasium.make keyword arguments as JSON, e.g. '{\"n_moves\": 8}'."),
    ] = None,
    algo_kwargs: Annotated[
        str | None, typer.Option(help="SB3 algorithm keyword arguments as JSON.")
    ] = None,
    minutes: Annotated[
        float | None, typer.Option(help="Stop after this much wall time (minutes).")
    ] = None,
    checkpoint_every: Annotated[int, typer.Option(min=1, help="Checkpoint interval (steps).")] = (
        10_000
    ),
    resume: Annotated[
        bool,
        typer.Option(
            "--resume",
            help="Continue the run in --out from its model.zip (saved at every checkpoint "
            "and when stopped) up to --timesteps in all; give the run's own settings.",
        ),
    ] = False,
    as_json: Annotated[
        bool, typer.Option("--json", help="Print the saved model and run folder as JSON.")
    ] = False,
) -> None:
    """Train an SB3 agent on a servogym env, with a progress bar, checkpoints and TensorBoard.

    Progress shows as a bar on a terminal and as a line on stderr every 30 s otherwise.
    Every --checkpoint-every steps, and when stopped with Ctrl-C (SIGINT) or SIGTERM, the
    model is saved as OUT/model.zip with OUT/config.json; --resume continues from it.
    """
    import sys

    from servogym._cli_common import check_count, check_number, check_writable_folder
    from servogym.agents._train import ALGOS, TrainingStopped, check_resume

    if algo.lower() not in ALGOS:
        _fail(f"--algo must be one of {', '.join(ALGOS)}; got --algo {algo!r}.")
    _check_env_id(env)
    check_count("--seed", seed, low=0, high=2**32 - 1)
    check_count("--timesteps", timesteps, high=MAX_TIMESTEPS)
    check_count("--n-envs", n_envs, high=MAX_N_ENVS)
    if workers is not None:
        check_count("--workers", workers, high=n_envs)
    check_count("--checkpoint-every", checkpoint_every, high=MAX_TIMESTEPS)
    check_number("--minutes", minutes, low=0, low_open=True, high=60 * 24 * 365)
    if out.exists() and not out.is_dir():
        _fail(f"--out {str(out)!r} is a file; give a folder for the run.")
    if not resume and (out / "model.zip").exists():
        _fail(
            f"--out {str(out)!r} already holds a trained run (model.zip); pass --resume to "
            "continue it, or choose another --out (nothing is overwritten)."
        )
    env_kw = _json_option(env_kwargs, "--env-kwargs")
    algo_kw = _json_option(algo_kwargs, "--algo-kwargs")
    if resume:
        try:
            check_resume(out, env, algo, seed, n_envs, env_kw, algo_kw)
        except ValueError as exc:
            _fail(str(exc))
    _check_env_kwargs(env, env_kw)
    _check_algo_kwargs(algo, algo_kw, env, env_kw)
    check_writable_folder("--out", out)
    bar = not as_json and sys.stdout.isatty()
    try:
        path = _train(env, algo, timesteps, seed, out, n_envs, env_kw, algo_kw, minutes,
                      checkpoint_every, bar, resume, workers)  # fmt: skip
    except TrainingStopped as stopped:
        typer.echo(
            f"stopped by {stopped.signal_name} at {stopped.timesteps} steps: saved "
            f"{stopped.path} and its config.json; continue with the same command and --resume.",
            err=True,
        )
        raise typer.Exit(code=130 if stopped.signal_name == "SIGINT" else 143) from None
    except (TypeError, ValueError) as exc:
        _fail(
            str(exc) if str(exc).startswith("--") else f"--algo-kwargs {json.dumps(algo_kw)}: {exc}"
        )
    except OSError as exc:
        _fail(f"--out {str(out)!r} cannot be written: {exc.strerror or exc}.")
    if as_json:
        doc = {"model": str(path), "out": str(out), "env": env, "algo": algo.lower(),
               "timesteps": timesteps, "seed": seed}  # fmt: skip
        typer.echo(json.dumps(doc))
        return
    console.print(f"saved {path}")


def _check_env_kwargs(env: str, kwargs: dict[str, Any]) -> None:
    """Build the env once in this process, so a bad keyword fails before any worker starts."""
    import gymnasium as gym

    try:
        gym.make(env, **kwargs).close()
    except (TypeError, ValueError, KeyError) as exc:
        _fail(f"--env-kwargs {json.dumps(kwargs)}: {str(exc).strip().splitlines()[0]}")


MAX_EPISODES = 1_000_000
"""Most ``evaluate --episodes``."""
MAX_TIMESTEPS = 10**9
"""Largest ``--timesteps`` (and ``--checkpoint-every``)."""
MAX_N_ENVS = 256
"""Most envs stepped in parallel."""

_ALGO_NUMBERS = {
    # keyword: (integer?, low, low open?, high)
    "learning_rate": (False, 0.0, True, 1.0),
    "gamma": (False, 0.0, True, 1.0),
    "gae_lambda": (False, 0.0, False, 1.0),
    "tau": (False, 0.0, True, 1.0),
    "clip_range": (False, 0.0, True, 10.0),
    "ent_coef": (False, 0.0, False, 10.0),
    "vf_coef": (False, 0.0, False, 10.0),
    "max_grad_norm": (False, 0.0, True, 1e6),
    "batch_size": (True, 1, False, 10**7),
    "n_steps": (True, 1, False, 10**7),
    "n_epochs": (True, 1, False, 10**4),
    "buffer_size": (True, 1, False, 10**8),
    "learning_starts": (True, 0, False, 10**9),
    "gradient_steps": (True, -1, False, 10**4),
    "policy_delay": (True, 1, False, 10**4),
}
"""Ranges of the SB3 keywords servogym checks itself (SB3 asserts some, ignores others)."""


def _check_algo_kwargs(
    algo: str, kwargs: dict[str, Any], env: str | None = None, env_kw: dict | None = None
) -> None:
    """Refuse a keyword the SB3 algorithm does not take, a value outside its range, a device
    this machine lacks, and anything else the algorithm refuses when it is built once here
    (before any worker starts)."""
    import inspect
    import math

    from servogym.agents._train import _algo_class

    shown = f"--algo-kwargs {json.dumps(kwargs)}"
    taken = set(inspect.signature(_algo_class(algo).__init__).parameters) - {"self", "env"}
    unknown = [k for k in kwargs if k not in taken]
    if unknown:
        _fail(
            f"--algo-kwargs names {', '.join(map(repr, unknown))}, which {algo.upper()} does not "
            f"take; got {shown}."
        )
    for key, value in kwargs.items():
        if key not in _ALGO_NUMBERS or (key == "gradient_steps" and value == -1):
            continue
        if key == "ent_coef" and isinstance(value, str) and value.startswith("auto"):
            continue  # SAC's learned entropy coefficient ("auto", "auto_0.1")
        integer, low, low_open, high = _ALGO_NUMBERS[key]
        kind_ok = isinstance(value, int) if integer else isinstance(value, (int, float))
        rule = f"{low} {'<' if low_open else '<='} {key} <= {high}"
        if (
            isinstance(value, bool)
            or not kind_ok
            or not math.isfinite(value)
            or not ((value > low if low_open else value >= low) and value <= high)
        ):
            what = "an integer" if integer else "a number"
            _fail(f"--algo-kwargs {key} must be {what} with {rule}; got {key}={value!r}.")
    if algo.lower() == "ppo" and "batch_size" in kwargs and kwargs["batch_size"] < 2:
        _fail(
            f"--algo-kwargs batch_size must be >= 2 for PPO; got "
            f"batch_size={kwargs['batch_size']!r}."
        )
    if "device" in kwargs:
        _check_device(kwargs["device"])
    if env is None:
        return
    import gymnasium as gym

    kw = {k: v for k, v in kwargs.items() if k not in ("buffer_size", "learning_starts")}
    e = gym.make(env, **(env_kw or {}))
    try:
        extra = {"buffer_size": 1} if algo.lower() in ("sac", "td3") else {}
        _algo_class(algo)("MlpPolicy", e, **{"device": "cpu", **kw, **extra})
    except (AssertionError, TypeError, ValueError, KeyError, RuntimeError) as exc:
        first = str(exc).strip().splitlines()[0] if str(exc).strip() else type(exc).__name__
        _fail(f"{shown}: {algo.upper()} refuses them: {first[:200]}")
    finally:
        e.close()


def _check_device(device: Any) -> None:
    """Refuse a torch device this machine does not have (SB3 would fall back to the CPU
    without a word)."""
    import torch

    try:
        dev = torch.device(device)
    except (RuntimeError, TypeError) as exc:
        if device == "auto":
            return
        _fail(
            f"--algo-kwargs device must be 'cpu', 'auto' or a torch device; got "
            f"device={device!r} ({exc})."
        )
    if dev.type == "cuda" and not torch.cuda.is_available():
        _fail(
            f"--algo-kwargs device={device!r}: no CUDA device is available here "
            f"(torch.cuda.is_available() is False); use 'cpu', or 'auto' for the best there is."
        )
    if dev.type == "mps" and not torch.backends.mps.is_available():
        _fail(f"--algo-kwargs device={device!r}: no MPS device is available here; use 'cpu'.")


def _train(
    env,
    algo,
    timesteps,
    seed,
    out,
    n_envs,
    env_kw,
    algo_kw,
    minutes,
    checkpoint_every,
    bar,
    resume=False,
    workers=None,
):
    from servogym.agents._train import train

    return train(
        env,
        algo,
        timesteps,
        seed,
        out,
        n_envs=n_envs,
        env_kwargs=env_kw,
        algo_kwargs=algo_kw,
        wall_time_s=None if minutes is None else minutes * 60.0,
        checkpoint_every=checkpoint_every,
        progress_bar=bar,
        log_progress=not bar,
        resume=resume,
        workers=workers,
    )


def evaluate_command(
    env: Annotated[
        str | None, typer.Option(help="Env id; default: the one in the model's config.json.")
    ] = None,
    model: Annotated[
        Path | None, typer.Option(help="A saved model (model.zip); omit for baselines only.")
    ] = None,
    episodes: Annotated[int, typer.Option(min=1, help="Seeded episodes per policy.")] = 100,
    seed: Annotated[int, typer.Option(help="First seed; episodes use seed .. seed+n-1.")] = (
        100_000
    ),
    env_kwargs: Annotated[
        str | None, typer.Option(help="gymnasium.make keyword arguments as JSON.")
    ] = None,
    fixed: Annotated[
        Path | None,
        typer.Option(
            help="A 'best fixed set' baseline: a parameter file in any format servogym writes "
            "(JSON, C-Motion, host commands, I-variables, 6250/6K command file) or a JSON "
            "object of register values."
        ),
    ] = None,
    as_json: Annotated[bool, typer.Option("--json", help="Print JSON for machines.")] = False,
) -> None:
    """Run a saved policy and the baselines on the same seeded episodes; print a table."""
    import gymnasium as gym

    import servogym.envs  # noqa: F401
    from servogym._cli_common import check_count
    from servogym.agents._evaluate import (
        baseline_policies,
        run_episodes,
        summarize,
    )

    check_count("--seed", seed, low=0, high=2**32 - 1)
    check_count("--episodes", episodes, high=MAX_EPISODES)
    kwargs: dict[str, Any] = {}
    if model is not None:
        if not model.exists():
            _fail(f"--model {str(model)!r} does not exist.")
        if not model.is_file():  # a folder, FIFO or device: never opened (a FIFO would wait)
            _fail(f"--model {str(model)!r} is not a regular file; give a run's model.zip.")
        cfg = model.parent / "config.json"
        if cfg.exists():
            from servogym.agents._train import read_config, run_env_kwargs

            try:
                config = read_config(cfg, f"--model {str(model)!r}")
                env = env or config["env_id"]
                # the run's env: its keywords and, if it acted around a set, that action
                kwargs.update(run_env_kwargs({**config, "env_id": env}))
            except ValueError as exc:
                _fail(str(exc))
    if env is None:
        _fail("give --env, or a --model whose run directory has a config.json")
    _check_env_id(env)
    kwargs.update(_json_option(env_kwargs, "--env-kwargs"))
    try:
        e = gym.make(env, **kwargs)
    except (ValueError, TypeError, KeyError) as exc:
        _fail(f"--env-kwargs {json.dumps(kwargs)}: {exc}")
    extra = {}
    if fixed is not None:
        extra["best fixed set"] = _fixed_values(fixed, e.unwrapped.scenario.chip_model)
    base_env = _baseline_env(env, kwargs, e)
    policies: dict[str, Any] = {}
    if model is not None:
        from servogym.agents._train import load_policy

        try:
            policies["policy"] = load_policy(model)
        except ValueError as exc:
            _fail(str(exc))
    try:
        baselines = baseline_policies(base_env, extra)
    except ValueError as exc:
        _fail(f"--fixed {str(fixed)!r}: {exc}")
    policies.update(baselines)
    seeds = range(seed, seed + episodes)
    from rich.progress import BarColumn, MofNCompleteColumn, Progress, TextColumn, TimeElapsedColumn

    progress = Progress(
        TextColumn("{task.description}"), BarColumn(), MofNCompleteColumn(), TimeElapsedColumn(),
        console=Console(stderr=True), transient=True,
    )  # fmt: skip
    results = {}
    with progress:
        task = progress.add_task("episodes", total=len(policies) * episodes)
        for name, p in policies.items():
            progress.update(task, description=f"evaluate {name}")
            run_env = base_env if name in baselines else e
            outcomes = run_episodes(run_env, p, seeds, on_episode=lambda: progress.advance(task))
            results[name] = summarize(outcomes)
    if as_json:
        typer.echo(json.dumps({"env": env, "seeds": [seed, seed + episodes - 1], **results}))
        return
    table = Table(title=f"{env}: {episodes} episodes, seeds {seed}..{seed + episodes - 1}")
    for col in ("policy", "mean return", "± s.e.", "median", "worst", "diverged", "step cost"):
        table.add_column(col)
    for name, s in results.items():
        table.add_row(
            name, f"{s['mean_return']:.2f}", f"{s['sem_return']:.2f}",
            f"{s['median_return']:.2f}", f"{s['worst_return']:.2f}", str(s["n_diverged"]),
            f"{s['mean_step_cost']:.2f}",
        )  # fmt: skip
    console.print(table)


def _baseline_env(env_id: str, kwargs: dict[str, Any], env: Any) -> Any:
    """The env the constant baselines run on: ``env`` itself, or, when its action is a
    residual around a set (which reaches only sets near it), the same env with the unit box
    of registers, so a baseline runs exactly the registers it names. The action map draws
    nothing, so both give the same episodes for a seed."""
    import gymnasium as gym

    from servogym.envs import ResidualActions

    if not isinstance(env.unwrapped.actions, ResidualActions):
        return env
    unit = {k: v for k, v in kwargs.items() if k not in ("center", "residual_scale")}
    return gym.make(env_id, **{**unit, "action_type": "unit"})


def _fixed_values(path: Path, chip_model: str) -> dict[str, Any]:
    """Register values of a --fixed file: a parameter file in any format servogym writes,
    or a plain JSON object of register values."""
    from servogym._input import read_text
    from servogym.chips import ParameterError, read_params_file
    from servogym.chips._paramfile import strict_json

    try:
        text = read_text(path, "--fixed")  # regular files only, bounded
        doc = strict_json(text) if text.lstrip().startswith("{") else None
    except ValueError as exc:
        _fail(f"--fixed {str(path)!r}: {exc}" if str(path) not in str(exc) else str(exc))
    if isinstance(doc, dict) and "format" not in doc:
        return doc  # register values only; the env validates them
    try:
        params = read_params_file(path, what="--fixed").params
    except ParameterError as exc:
        _fail(str(exc))
    if params.model != chip_model:
        _fail(
            f"--fixed {str(path)!r} is a {params.model} parameter set; the env runs "
            f'{chip_model} (pass --env-kwargs \'{{"chip_model": "{params.model}"}}\').'
        )
    return {k: v for k, v in params.to_dict().items() if k != "model"}
