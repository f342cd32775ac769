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
        _fail(f"unknown env id {env!r}; the servogym ids are {', '.join(ids)}.{hint}")


def train_command(
    env: Annotated[str, typer.Option(help="Env id, e.g. servogym/Tune-PMD-VerticalAxis-v0.")],
    algo: Annotated[str, typer.Option(help="ppo, sac or td3.")] = "ppo",
    timesteps: Annotated[int, typer.Option(min=1, help="Env steps to train for.")] = 100_000,
    seed: Annotated[int, typer.Option(help="Seed of the agent and the envs.")] = 0,
    out: Annotated[Path, typer.Option(help="Run directory (model, checkpoints, logs).")] = Path(
        "runs/run"
    ),
    n_envs: Annotated[int, typer.Option(min=1, help="Envs stepped in parallel.")] = 2,
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
    as_json: Annotated[
        bool, typer.Option("--json", help="Print the saved model and run folder as JSON.")
    ] = False,
) -> None:
    """Train an SB3 agent on a servogym env, with a progress bar, checkpoints and TensorBoard."""
    from servogym._cli_common import check_count, check_number
    from servogym.agents._train import ALGOS

    if algo.lower() not in ALGOS:
        _fail(f"--algo must be one of {', '.join(ALGOS)}; got --algo {algo!r}.")
    _check_env_id(env)
    check_count("--seed", seed, low=0)
    check_number("--minutes", minutes, low=0, low_open=True)
    if out.exists() and not out.is_dir():
        _fail(f"--out {str(out)!r} is a file; give a folder for the run.")
    env_kw = _json_option(env_kwargs, "--env-kwargs")
    algo_kw = _json_option(algo_kwargs, "--algo-kwargs")
    _check_env_kwargs(env, env_kw)
    _check_algo_kwargs(algo, algo_kw)
    try:
        path = _train(env, algo, timesteps, seed, out, n_envs, env_kw, algo_kw, minutes,
                      checkpoint_every, as_json)  # fmt: skip
    except (TypeError, ValueError) as exc:
        _fail(f"--algo-kwargs {json.dumps(algo_kw)}: {exc}")
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


def _check_algo_kwargs(algo: str, kwargs: dict[str, Any]) -> None:
    """Refuse a keyword the SB3 algorithm does not take, before training starts."""
    import inspect

    from servogym.agents._train import _algo_class

    taken = set(inspect.signature(_algo_class(algo).__init__).parameters) - {"self", "env"}
    unknown = [k for k in kwargs if k not in taken]
    if unknown:
        _fail(
            f"--algo-kwargs names {', '.join(map(repr, unknown))}, which {algo.upper()} does not "
            f"take; got --algo-kwargs {json.dumps(kwargs)}."
        )


def _train(
    env, algo, timesteps, seed, out, n_envs, env_kw, algo_kw, minutes, checkpoint_every, as_json
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
        progress_bar=not as_json,
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

    check_count("--seed", seed, low=0)
    kwargs: dict[str, Any] = {}
    if model is not None:
        if not model.exists():
            _fail(f"--model {str(model)!r} does not exist.")
        cfg = model.parent / "config.json"
        if cfg.exists():
            from servogym.agents._train import read_config

            try:
                config = read_config(cfg, f"--model {str(model)!r}")
            except ValueError as exc:
                _fail(str(exc))
            env = env or config["env_id"]
            kwargs.update(config["env_kwargs"])
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
    policies: dict[str, Any] = {}
    if model is not None:
        from servogym.agents._train import load_policy

        try:
            policies["policy"] = load_policy(model)
        except ValueError as exc:
            _fail(str(exc))
    try:
        policies.update(baseline_policies(e, extra))
    except ValueError as exc:
        _fail(f"--fixed {str(fixed)!r}: {exc}")
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
            outcomes = run_episodes(e, p, seeds, on_episode=lambda: progress.advance(task))
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
