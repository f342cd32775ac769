"""``servogym tune``: register with ``app.command("tune")(tune_command)``.

Imports nothing heavy at module level (no torch, no stable-baselines3; Optuna, MuJoCo and
numba load when the command runs).
"""

from __future__ import annotations

from pathlib import Path
from typing import Annotated

import typer

TUNER_HELP = (
    "tpe, gp, cmaes, random, sobol (Optuna samplers), vendor-step, relay, model-based "
    "(classical procedures)."
)


def tune_command(
    chip: Annotated[str, typer.Option("--chip", help="Chip model, e.g. MC2100.")],
    plant: Annotated[
        str, typer.Option("--plant", help="Plant family: rotary, two-mass, vertical-axis, arm.")
    ],
    budget: Annotated[
        int, typer.Option("--budget", help="Evaluations (trials), experiments included.")
    ],
    out: Annotated[Path, typer.Option("--out", help="Run folder for every output file.")],
    tuner: Annotated[str, typer.Option("--tuner", help=TUNER_HELP)] = "tpe",
    plant_param: Annotated[
        list[str] | None,
        typer.Option("--plant-param", help="Fixed plant parameter NAME=VALUE (repeatable)."),
    ] = None,
    seed: Annotated[int, typer.Option("--seed", help="Seed of samplers and plant draws.")] = 0,
    workers: Annotated[
        int | None,
        typer.Option("--workers", help="Evaluation threads.", show_default="all cores"),
    ] = None,
    robust: Annotated[
        int,
        typer.Option("--robust", help="Evaluate each trial on K plant instances drawn once."),
    ] = 1,
    robust_mode: Annotated[
        str, typer.Option("--robust-mode", help="Aggregate the K costs: mean or worst.")
    ] = "mean",
    constraints: Annotated[
        bool,
        typer.Option(
            "--constraints/--no-constraints",
            help="Constrain following error, saturation and divergence.",
        ),
    ] = True,
    max_following_error: Annotated[
        float | None,
        typer.Option(
            "--max-following-error",
            help="Constraint (counts).",
            show_default="1 % of the longest move",
        ),
    ] = None,
    max_saturation: Annotated[
        float,
        typer.Option("--max-saturation", help="Constraint: fraction of ticks at the limit."),
    ] = 0.05,
    multi_objective: Annotated[
        bool,
        typer.Option(
            "--multi-objective",
            help="Minimize cost and peak following error; keep the Pareto front.",
        ),
    ] = False,
    warm_start: Annotated[
        Path | None,
        typer.Option("--warm-start", help="Parameter file (JSON) to evaluate first."),
    ] = None,
    storage: Annotated[
        str | None,
        typer.Option(
            "--storage",
            help="Journal file path or Optuna RDB URL (sqlite:///..., postgresql://...).",
            show_default="OUT/study.journal",
        ),
    ] = None,
    study_name: Annotated[
        str | None,
        typer.Option(
            "--study-name",
            help="Study to create or join: several workers with the same --storage and "
            "--study-name share one study and its budget.",
            show_default="servogym-<OUT name>",
        ),
    ] = None,
    resume: Annotated[
        bool, typer.Option("--resume", help="Continue the interrupted study of this run.")
    ] = False,
    fix: Annotated[
        list[str] | None,
        typer.Option("--fix", help="Hold a register at a value, NAME=VALUE (repeatable)."),
    ] = None,
    search: Annotated[
        list[str] | None,
        typer.Option("--search", help="Search only this register (repeatable)."),
    ] = None,
    batch_size: Annotated[
        int | None,
        typer.Option("--batch-size", help="Trials a sampler asks at once.", show_default="8"),
    ] = None,
    as_json: Annotated[
        bool, typer.Option("--json", help="Print the run's summary.json for machines.")
    ] = False,
) -> None:
    """Tune a chip's parameters on a simulated plant and write the tuned set with reports."""
    import json

    from rich.console import Console

    from servogym.autotune._job import TuneConfig, parse_fix, parse_plant_params, tune
    from servogym.autotune._session import TuneError
    from servogym.autotune._tuners import tuner_names
    from servogym.chips._space import ParameterError

    console = Console()

    def fail(message: str) -> None:
        console.print(f"[red]error:[/red] {message}", highlight=False, soft_wrap=True)
        raise typer.Exit(code=2)

    try:
        if tuner not in tuner_names():
            from servogym.autotune._tuners import get_tuner

            get_tuner(tuner)  # raises with the list and close matches
        config = TuneConfig(
            chip=chip,
            plant=plant,
            out=out,
            budget=budget,
            tuner=tuner,
            plant_params=parse_plant_params(plant_param),
            seed=seed,
            workers=workers,
            robust=robust,
            robust_mode=robust_mode,
            constraints=constraints,
            max_following_error=max_following_error,
            max_saturation=max_saturation,
            multi_objective=multi_objective,
            warm_start=warm_start,
            storage=storage,
            resume=resume,
            fix=parse_fix(fix),
            search=tuple(search) if search else None,
            batch_size=batch_size,
            study_name=study_name,
        )
        config.problem()  # validate everything before the progress bar
        if storage is not None:
            from servogym.autotune._session import open_storage

            open_storage(storage)
    except (TuneError, ParameterError, KeyError, ValueError) as exc:
        fail(str(exc.args[0]) if isinstance(exc, KeyError) else str(exc))
        return

    from rich.progress import (
        BarColumn,
        MofNCompleteColumn,
        Progress,
        TextColumn,
        TimeElapsedColumn,
        TimeRemainingColumn,
    )

    progress = Progress(
        TextColumn(f"[bold]{tuner}[/bold] {chip} / {plant}"),
        BarColumn(),
        MofNCompleteColumn(),
        TextColumn("best cost {task.fields[best]}"),
        TimeElapsedColumn(),
        TimeRemainingColumn(),
        console=Console(stderr=True) if as_json else console,
    )
    task = progress.add_task("tune", total=budget, best="-")

    def on_progress(done: int, total: int, best: float | None) -> None:
        progress.update(
            task, completed=done, total=total, best="-" if best is None else f"{best:.4g}"
        )

    try:
        with progress:
            _, summary = tune(config, on_progress)
    except KeyboardInterrupt:
        console.print(
            f"[yellow]interrupted[/yellow]: every finished trial is stored; continue with "
            f"the same command and --resume (out={out})."
        )
        raise typer.Exit(code=130) from None
    except (TuneError, ParameterError, KeyError, ValueError) as exc:
        fail(str(exc.args[0]) if isinstance(exc, KeyError) else str(exc))
        return
    if as_json:
        typer.echo(json.dumps(summary, indent=2, default=str))
        return
    console.print(summary_heading(summary), highlight=False)
    console.print(summary_table(summary))
    if not summary["feasible"]:
        console.print(
            "[yellow]warning:[/yellow] no trial met the constraints; the best cost is shown. "
            "Raise the budget or relax --max-following-error / --max-saturation."
        )
    if summary["n_trials"] < budget:
        console.print(
            f"[cyan]note:[/cyan] the {tuner} procedure finished after {summary['n_trials']} of "
            f"{budget} evaluations: a classical tuner stops when its procedure is done, and "
            "the rest of the budget is not used.",
            highlight=False,
        )
    for name in summary["files"].values():
        console.print(f"wrote {out / name}", highlight=False)
    console.print(f"study: {summary['storage']} (study {summary['study_name']!r})", highlight=False)


def summary_heading(summary: dict) -> str:
    """The line above the table: what was tuned, where, how."""
    n_plants = summary["problem"]["n_plants"]
    where = (
        "nominal plant"
        if n_plants == 1
        else f"{summary['problem']['robust_mode']} over {n_plants} plant instances"
    )
    return (
        f"{summary['chip_model']} on {summary['plant']} ({where}): chip defaults vs "
        f"{summary['tuner']} after {summary['n_trials']} evaluations"
    )


def summary_table(summary: dict):
    """The default-vs-tuned table printed at the end."""
    from rich.table import Table

    from servogym.autotune._report import TABLE_METRICS

    table = Table()
    table.add_column("metric")
    table.add_column("default", justify="right")
    table.add_column("tuned", justify="right")
    for key, label in TABLE_METRICS:
        table.add_row(label, _fmt(summary["default"][key]), _fmt(summary["tuned"][key]))
    return table


def _fmt(x: float) -> str:
    if x == 0:
        return "0"
    if abs(x) >= 1000 or x == int(x):
        return f"{x:.0f}"
    return f"{x:.3g}"
