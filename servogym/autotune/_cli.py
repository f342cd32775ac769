"""``servogym tune``: register with ``app.command("tune")(tune_command)``.

Imports nothing heavy at module level (no torch, no stable-baselines3; Optuna, MuJoCo and
numba load when the command runs).
"""

from __future__ import annotations

from pathlib import Path
from typing import Annotated

import typer

TUNER_HELP = (
    "safe (a safe trust-region search from the model-based design), tpe, gp, cmaes, random, "
    "sobol (Optuna samplers), vendor-step, relay, model-based (classical procedures)."
)


def tune_command(
    chip: Annotated[str, typer.Option("--chip", help="Chip model, e.g. MC2100.")],
    plant: Annotated[
        str,
        typer.Option(
            "--plant",
            help="Plant family: rotary, two-mass, vertical-axis, arm; or a multi-axis machine, "
            "two-link-arm or xy-stage (every axis tuned together, names kp.1, kp.2).",
        ),
    ],
    budget: Annotated[
        int, typer.Option("--budget", help="Evaluations (trials), experiments included.")
    ],
    out: Annotated[Path, typer.Option("--out", help="Run folder for every output file.")],
    tuner: Annotated[
        str | None,
        typer.Option("--tuner", help=TUNER_HELP, show_default="safe; tpe with --multi-objective"),
    ] = None,
    plant_param: Annotated[
        list[str] | None,
        typer.Option("--plant-param", help="Fixed plant parameter NAME=VALUE (repeatable)."),
    ] = None,
    plant_file: Annotated[
        Path | None,
        typer.Option(
            "--plant-file",
            help="A plant.json from `servogym calibrate`: its values fixed, --plant-param on "
            "top, --plant-range names drawn instead.",
        ),
    ] = None,
    plant_range: Annotated[
        list[str] | None,
        typer.Option(
            "--plant-range",
            help="Draw a plant parameter from LO..HI (within its legal range) for --robust, "
            "NAME=LO:HI (repeatable); every end must be one the motor can move.",
        ),
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
        typer.Option(
            "--warm-start",
            help="Parameter file to evaluate first, in any format servogym writes (JSON, "
            "C-Motion, host commands, I-variables, 6250/6K command file).",
        ),
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
    min_gain_margin: Annotated[
        float,
        typer.Option("--min-gain-margin", help="Gain margin (dB) trials and the check need."),
    ] = 6.0,
    min_phase_margin: Annotated[
        float,
        typer.Option("--min-phase-margin", help="Phase margin (deg) trials and the check need."),
    ] = 30.0,
    check: Annotated[
        bool,
        typer.Option(
            "--check/--no-check",
            help="Check the result (reference integration, every loop latency, load and "
            "friction spreads, margins) before writing hardware files.",
        ),
    ] = True,
    check_candidates: Annotated[
        int,
        typer.Option("--check-candidates", help="Best trials the check may try in turn."),
    ] = 5,
    force: Annotated[
        bool,
        typer.Option("--force", help="Write the hardware files even when the check fails."),
    ] = False,
    as_json: Annotated[
        bool, typer.Option("--json", help="Print the run's summary.json for machines.")
    ] = False,
) -> None:
    """Tune a chip's parameters on a simulated plant and write the tuned set with reports."""
    import json

    from rich.console import Console

    from servogym._cli_common import check_choice, check_count, check_number, fail
    from servogym._files import MANIFEST, PENDING, FileSafetyError
    from servogym._input import mask_url
    from servogym.autotune._job import TuneConfig, parse_fix, parse_plant_params, tune
    from servogym.autotune._session import TuneError
    from servogym.autotune._tuners import (
        DEFAULT_MULTI_OBJECTIVE_TUNER,
        DEFAULT_TUNER,
        get_tuner,
        tuner_names,
    )
    from servogym.calibrate import plant_values
    from servogym.chips._family import get_chip
    from servogym.chips._space import ParameterError
    from servogym.plants import MULTI_PLANTS, get_plant, parse_plant_ranges

    def any_plant(name: str):  # a single-axis family or a multi-axis machine
        return MULTI_PLANTS[name] if name in MULTI_PLANTS else get_plant(name)

    console = Console()
    if tuner is None:
        tuner = DEFAULT_MULTI_OBJECTIVE_TUNER if multi_objective else DEFAULT_TUNER
    check_count("--budget", budget, high=MAX_BUDGET)
    check_count("--workers", workers, high=MAX_WORKERS)
    check_count("--robust", robust, high=MAX_ROBUST)
    check_count("--batch-size", batch_size, high=MAX_BUDGET)
    check_count("--seed", seed, low=0, high=MAX_SEED)
    check_number("--max-following-error", max_following_error, low=0, low_open=True)
    check_number("--max-saturation", max_saturation, low=0, high=1)
    check_number("--min-gain-margin", min_gain_margin, low=0, high=60)
    check_number("--min-phase-margin", min_phase_margin, low=0, high=90)
    check_count("--check-candidates", check_candidates, high=MAX_CHECK_CANDIDATES)
    check_choice("--chip", chip, get_chip)
    check_choice("--plant", plant, any_plant)
    if plant in MULTI_PLANTS and plant_file is not None:
        fail(
            f"--plant-file takes a plant.json of a single-axis plant (servogym calibrate); the "
            f"{plant} is a multi-axis machine: give its values with --plant-param."
        )
    check_choice("--tuner", tuner, get_tuner)
    if robust_mode not in ("mean", "worst"):
        fail(f"--robust-mode must be 'mean' or 'worst'; got --robust-mode {robust_mode!r}.")
    if study_name is not None and (not study_name.strip() or study_name != study_name.strip()):
        fail(
            f"--study-name must be a non-empty name without leading or trailing spaces; got "
            f"--study-name {study_name!r}."
        )
    if storage is not None and not storage.strip():
        fail(f"--storage must be a journal file path or a database URL; got --storage {storage!r}.")
    if out.exists() and not out.is_dir():
        fail(f"--out {str(out)!r} is a file; give a folder for the run's outputs.")
    # An empty study.journal (a tune stopped while it started) holds no study: the folder
    # counts as new, and the run opens that journal and starts in it.
    previous = [
        n for n in (MANIFEST, PENDING, "study.db", "study.journal")
        if (out / n).exists() and not (n == "study.journal" and _empty_file(out / n))
    ]  # fmt: skip
    if previous and not resume:
        fail(
            f"--out {str(out)!r} already holds a tune run ({', '.join(previous)}); pass "
            f"--resume to continue its study, or choose another --out."
        )
    if resume:
        own = storage is None or "://" not in storage or storage.startswith("sqlite:///")
        where = out / "study.journal" if storage is None else Path(storage).expanduser()
        if storage is not None and storage.startswith("sqlite:///"):  # no new database file
            where = Path(storage[len("sqlite:///") :].split("?", 1)[0]).expanduser()
        has_study = (storage is None and (out / "study.db").exists()) or (
            where.is_file() and where.stat().st_size > 0
        )
        name = study_name or f"servogym-{out.resolve().name}"
        if own and not has_study:
            shown = "--out " + repr(str(out)) if storage is None else "--storage " + repr(storage)
            fail(
                f"--resume: nothing to resume: {shown} holds no study {name!r} ({str(where)!r} "
                f"is missing or empty). Run the same command without --resume to start it."
            )

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
            plant_params=plant_values(
                plant_file,
                plant,
                parse_plant_params(plant_param),
                drop=tuple(r.partition("=")[0].strip() for r in plant_range or ()),
            ),
            plant_ranges=parse_plant_ranges(plant_range, any_plant(plant) if plant_range else None),
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
            min_gain_margin_db=min_gain_margin,
            min_phase_margin_deg=min_phase_margin,
            check=check,
            check_candidates=check_candidates,
            force=force,
            study_name=study_name,
        )
        problem = config.problem()  # validate everything before the progress bar
        get_tuner(tuner).check(problem, budget)
        if warm_start is not None and problem.n_axes > 1:
            from servogym.autotune._machinejob import read_warm_start

            read_warm_start(warm_start, problem)
        elif warm_start is not None:
            from servogym.autotune._job import read_param_file

            read_param_file(warm_start, problem.scenario.chip_model)
        if storage is not None:
            from servogym.autotune._session import open_storage

            if "://" not in storage and not Path(storage).expanduser().exists():
                _check_new_journal(storage)  # validated without creating the file
            else:
                try:
                    open_storage(storage)
                except TuneError as exc:
                    detail = str(exc).split("': ", 1)[-1]
                    fail(f"--storage {mask_url(storage)!r} cannot be opened as a study: {detail}")
    except (TuneError, ParameterError, KeyError, ValueError) as exc:
        fail(str(exc.args[0]) if isinstance(exc, KeyError) else str(exc), TUNE_OPTIONS)
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

    started = []

    def on_progress(done: int, total: int, best: float | None) -> None:
        if not started:  # shown once the study is open: a storage error prints one line
            progress.start()
            started.append(True)
        progress.update(
            task, completed=done, total=total, best="-" if best is None else f"{best:.4g}"
        )

    try:
        try:
            _, summary = tune(config, on_progress)
        finally:
            progress.stop()
    except KeyboardInterrupt:
        console.print(
            f"[yellow]interrupted[/yellow]: every finished trial is stored; continue with "
            f"the same command and --resume (out={out})."
        )
        raise typer.Exit(code=130) from None
    except (TuneError, ParameterError, FileSafetyError, KeyError, ValueError) as exc:
        message = str(exc.args[0]) if isinstance(exc, KeyError) else str(exc)
        if message.startswith("cannot open the study storage"):  # the default storage
            message = f"--storage (default: the run folder's study): {message}"
        fail(message, TUNE_OPTIONS)
        return
    except OSError as exc:
        fail(f"--out {str(out)!r} cannot be written: {exc.strerror or exc}.")
        return
    except Exception as exc:  # storage drivers: SQLAlchemy and Optuna errors
        if type(exc).__module__.split(".")[0] not in ("sqlalchemy", "optuna", "sqlite3"):
            raise
        where = mask_url(storage) if storage else str(out)
        first = str(exc).strip().splitlines()[0] if str(exc).strip() else type(exc).__name__
        fail(f"--storage {where!r} cannot be used as an Optuna study: {mask_url(first)[:200]}")
    report = summary.get("check")
    failed = report is not None and not report["passed"] and summary["hardware_files_withheld"]
    if as_json:
        typer.echo(json.dumps(summary, indent=2, default=str))
        if failed:
            raise typer.Exit(code=1)
        return
    console.print(summary_heading(summary), highlight=False)
    console.print(summary_table(summary))
    if summary.get("n_axes", 1) > 1:
        console.print(axes_table(summary))
    if not summary["feasible"]:
        console.print(
            "[yellow]warning:[/yellow] no trial met the constraints; the best cost is shown. "
            "Raise the budget or relax --max-following-error / --max-saturation."
        )
    if report is not None:
        console.print(
            check_table(report) if "n_axes" not in summary else machine_check_table(report)
        )
        line = fallback_line(report)
        if line:
            console.print(f"[yellow]warning:[/yellow] {line}", highlight=False)
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
    if report is not None and not report["passed"]:
        withheld = ", ".join(summary["hardware_files_withheld"]) or "none (--force)"
        console.print(
            "[red]check failed:[/red] "
            + "; ".join(report["failures"])
            + f". Hardware files withheld: {withheld}.",
            highlight=False,
        )
        if summary["hardware_files_withheld"]:
            raise typer.Exit(code=1)


TUNE_OPTIONS = {
    "budget": "--budget",
    "n_workers": "--workers",
    "workers": "--workers",
    "batch_size": "--batch-size",
    "robust": "--robust",
    "robust_mode": "--robust-mode",
    "max_following_error": "--max-following-error",
    "max_saturation": "--max-saturation",
    "min_gain_margin_db": "--min-gain-margin",
    "min_phase_margin_deg": "--min-phase-margin",
    "check_candidates": "--check-candidates",
    "study_name": "--study-name",
    "seed": "--seed",
}
"""Library argument -> the tune option that sets it (for error messages)."""

MAX_BUDGET = 100_000
"""Largest ``--budget`` (and ``--batch-size``): evaluations of one run."""
MAX_WORKERS = 1024
"""Most evaluation threads."""
MAX_ROBUST = 1000
"""Most plant instances per trial (``--robust``)."""
MAX_SEED = 2**32 - 1
"""Largest ``--seed`` (the samplers' seeds are 32-bit)."""
MAX_CHECK_CANDIDATES = 1000
"""Most trials the check may try."""


def _empty_file(path: Path) -> bool:
    try:
        return path.is_file() and path.stat().st_size == 0
    except OSError:
        return False


def _check_new_journal(storage: str) -> None:
    """Refuse a journal path that cannot be created, without creating it."""
    from servogym._cli_common import fail
    from servogym.autotune._session import TuneError, open_storage

    path = Path(storage).expanduser()
    if not storage.strip() or ":" in path.name or not path.parent.is_dir():
        try:
            open_storage(storage)  # raises the one-line reason
        except TuneError as exc:
            detail = str(exc).split("': ", 1)[-1]
            fail(f"--storage {storage!r} cannot be opened as a study: {detail}")


def check_table(report: dict):
    """The check's stress cases, each with its margins and verdict, and the worst margins
    with their cases; printed after the default-vs-tuned table and by ``servogym check``."""
    from rich.table import Table

    worst = report.get("worst") or {}
    limits = report["limits"]
    verdict = "[green]passed[/green]" if report["passed"] else "[red]FAILED[/red]"

    def w(key: str, unit: str) -> str:
        if key not in worst:
            return "none"
        return f"{_margin(worst[key]['value'], unit)} ({worst[key]['case']})"

    title = (
        f"check {verdict}: worst gain margin {w('gain_margin_db', 'dB')}, worst phase margin "
        f"{w('phase_margin_deg', 'deg')}, lowest bandwidth {w('bandwidth_hz', 'Hz')} "
        f"(minima {limits['min_gain_margin_db']:g} dB, {limits['min_phase_margin_deg']:g} deg; "
        f"saturation at most {100 * limits['max_saturation']:g} % of ticks)"
    )
    caption = (
        "error: largest following error / its limit (counts); at limit: ticks at the motor "
        "limit; GM, PM: gain and phase margin at the worst holding point"
    )
    table = Table(title=title, title_justify="left", caption=caption, caption_justify="left")
    table.add_column("case (RK4 reference)", no_wrap=True)
    for col in ("latency", "cost", "diverged", "error", "at limit", "stable", "GM", "PM",
                "verdict"):  # fmt: skip
        table.add_column(col, justify="right", no_wrap=col in ("latency", "error"))
    for c in report["cases"]:
        m = c.get("margins") or {}
        fe = _fmt(c["max_following_error"])
        if c.get("following_error_limit") is not None:
            fe += f" / {_fmt(c['following_error_limit'])}"
        table.add_row(
            c["name"], c["loop_latency"], _fmt(c["cost"]),
            c["divergence_reason"] if c["diverged"] else "no",
            fe, f"{100 * c['saturation_fraction']:.1f} %",
            "-" if not m else ("yes" if m.get("stable") else "[red]NO[/red]"),
            _margin(m.get("gain_margin_db"), "dB") if m else "-",
            _margin(m.get("phase_margin_deg"), "deg") if m else "-",
            "[green]ok[/green]" if c.get("passed", True) else "[red]fail[/red]",
        )  # fmt: skip
    return table


def machine_check_table(report: dict):
    """A machine's check (``servogym.sim.check_machine_params``): each stress case's axes,
    their following error, saturation and margins with the other loops closed, the
    contouring error and the verdict; the worst margins of each axis in the title."""
    from rich.table import Table

    limits = report["limits"]
    verdict = "[green]passed[/green]" if report["passed"] else "[red]FAILED[/red]"
    worst = []
    for axis, w in (report.get("worst") or {}).items():
        gm, pm = w.get("gain_margin_db", {}), w.get("phase_margin_deg", {})
        worst.append(f"{axis} {_margin(gm.get('value'), 'dB')} ({gm.get('case', '-')}), "
                     f"{_margin(pm.get('value'), 'deg')} ({pm.get('case', '-')})")  # fmt: skip
    title = (
        f"check {verdict}: worst margins with the other loops closed: {'; '.join(worst)} "
        f"(minima {limits['min_gain_margin_db']:g} dB, {limits['min_phase_margin_deg']:g} deg; "
        f"saturation at most {100 * limits['max_saturation']:g} % of ticks)"
    )
    table = Table(title=title, title_justify="left")
    table.add_column("case (RK4 reference)", no_wrap=True)
    for col in ("latency / sequencing", "cost", "contour (um)", "axis", "error", "at limit",
                "GM", "PM", "verdict"):  # fmt: skip
        table.add_column(col, justify="right", no_wrap=col != "case (RK4 reference)")
    for c in report["cases"]:
        for j, a in enumerate(c["axes"]):
            m = a.get("margins") or {}
            first = j == 0
            table.add_row(
                c["name"] if first else "", f"{c['loop_latency']} / {c['sequencing']}" if first
                else "", (_fmt(c["cost"]) + (" diverged" if c["diverged"] else "")) if first
                else "", _fmt(c["max_contour_error_um"]) if first else "", a["axis"],
                f"{_fmt(a['max_following_error'])} / {_fmt(a['following_error_limit'])}",
                f"{100 * a['saturation_fraction']:.1f} %",
                _margin(m.get("gain_margin_db"), "dB"), _margin(m.get("phase_margin_deg"), "deg"),
                ("[green]ok[/green]" if c["passed"] else "[red]fail[/red]") if first else "",
            )  # fmt: skip
    return table


def _margin(x: float | None, unit: str) -> str:
    return "unbounded" if x is None else f"{x:.3g} {unit}"


def fallback_line(report: dict) -> str | None:
    """The warning printed when the written set is not the tuner's best trial."""
    fb = report.get("fallback")
    if not fb:
        return None
    ratio = fb.get("cost_ratio")
    worse = f", {ratio:.3g}x the best trial's cost" if ratio is not None else ""
    return (
        f"the best trial {fb['best_trial']} (cost {fb['best_cost']:.4g}) failed the check "
        f"({'; '.join(fb['best_failures'])}); the set written is trial {fb['written_trial']}, "
        f"cost {fb['written_cost']:.4g}{worse}, which passed."
    )


def summary_heading(summary: dict) -> str:
    """The line above the table: what was tuned, where, how."""
    from servogym.autotune._report import plant_description

    where = plant_description(summary["problem"])
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


def axes_table(summary: dict):
    """A machine's per-axis figures and contouring error, chip defaults vs tuned."""
    from rich.table import Table

    table = Table()
    table.add_column(f"{summary['plant']} ({summary['axis_noun']} numbers)")
    table.add_column("default", justify="right")
    table.add_column("tuned", justify="right")
    d, t = summary["default"], summary["tuned"]
    for k, (name, number) in enumerate(zip(summary["axes"], summary["axis_numbers"], strict=True)):
        label = f"{name} ({summary['axis_noun']} {number})"
        table.add_row(
            f"{label}: max following error (counts)",
            _fmt(d["axis_following_error"][k]),
            _fmt(t["axis_following_error"][k]),
        )
        table.add_row(f"{label}: saturation (fraction of ticks)",
                      _fmt(d["axis_saturation"][k]), _fmt(t["axis_saturation"][k]))  # fmt: skip
    for key, label in (
        ("max_contour_error_um", "max contouring error (um)"),
        ("rms_contour_error_um", "RMS contouring error, worst task (um)"),
    ):
        table.add_row(label, _fmt(d[key]), _fmt(t[key]))  # fmt: skip
    return table


def _fmt(x: float) -> str:
    if x == 0:
        return "0"
    if abs(x) >= 1000 or x == int(x):
        return f"{x:.0f}"
    return f"{x:.3g}"
