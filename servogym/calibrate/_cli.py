"""``servogym calibrate``: register with ``app.command("calibrate")(calibrate_command)``."""

from __future__ import annotations

from pathlib import Path
from typing import Annotated

import typer

PLANT_FILE = "plant.json"
REPORT_FILE = "calibration.json"
PLOT_FILE = "calibration.png"


def calibrate_command(
    trace: Annotated[
        Path,
        typer.Argument(
            metavar="TRACE",
            help="The recorded trace: a CSV with time_s, commanded, actual, command, or a "
            "Turbo PMAC data-gathering file (docs/calibrate.md).",
        ),
    ],
    chip: Annotated[str, typer.Option("--chip", help="Chip model that ran, e.g. MC2100.")],
    plant: Annotated[
        str, typer.Option("--plant", help="Plant family: rotary, two-mass, vertical-axis, arm.")
    ],
    params: Annotated[
        Path,
        typer.Option(
            "--params",
            help="The register set that ran, in any format servogym reads (JSON, C-Motion, "
            "host commands, I-variables, 6250/6K command file).",
        ),
    ],
    out: Annotated[
        Path, typer.Option("--out", help="Folder for plant.json, calibration.json and .png.")
    ],
    fmt: Annotated[
        str | None,
        typer.Option("--format", help="Trace format: csv or pmac-gather.", show_default="detected"),
    ] = None,
    params_format: Annotated[
        str | None,
        typer.Option("--params-format", help="Format of --params.", show_default="detected"),
    ] = None,
    fit: Annotated[
        list[str] | None,
        typer.Option(
            "--fit",
            help="Fit this plant parameter (repeatable).",
            show_default="the family's load, friction and coupling",
        ),
    ] = None,
    fix: Annotated[
        list[str] | None,
        typer.Option("--fix", help="Hold a plant parameter at a known value, NAME=VALUE."),
    ] = None,
    latency: Annotated[
        str | None,
        typer.Option(
            "--latency",
            help="Hold the chip's loop_latency choice instead of fitting it.",
            show_default="fitted",
        ),
    ] = None,
    max_error: Annotated[
        float,
        typer.Option(
            "--max-error",
            help="Poor fit above this RMS replay error, as a fraction of the recorded RMS "
            "following error.",
        ),
    ] = 0.05,
    force: Annotated[
        bool,
        typer.Option("--force", help="Replace OUT/plant.json; write it even for a poor fit."),
    ] = False,
    as_json: Annotated[bool, typer.Option("--json", help="Print the result as JSON.")] = False,
) -> None:
    """Fit a plant (and the chip's loop latency) to a hardware trace; write OUT/plant.json.

    Replays the recorded commanded profile through the chip's filter with the registers
    that ran around the simulated plant (closed loop), and the recorded motor command into
    the plant (open loop), and fits the plant's load, friction, coupling and the loop
    latency by least squares. Exit code 0 for a good fit, 1 for a poor one (the trace does
    not come from this plant family, register set or chip: no plant.json is written
    without --force), 2 for a malformed trace or bad options.
    """
    import json

    from rich.console import Console
    from rich.table import Table

    from servogym._cli_common import check_number, fail
    from servogym._files import FileSafetyError, check_target, write_atomic
    from servogym.calibrate._fit import calibrate
    from servogym.calibrate._plantfile import plant_document, write_plant_file
    from servogym.calibrate._plot import plot_calibration
    from servogym.calibrate._trace import read_trace
    from servogym.chips import ParameterError, family_of, read_params_file
    from servogym.plants import PlantParameterError, get_plant

    console = Console(stderr=as_json)
    check_number("--max-error", max_error, low=0, low_open=True)
    if out.exists() and not out.is_dir():
        fail(f"--out {str(out)!r} is a file; give a folder for the calibration's outputs.")
    try:
        family = get_plant(plant)
        fixed = _key_values(fix)
        if out.exists() and not force:
            check_target(out / PLANT_FILE, inputs=[trace, params])
        loaded = read_params_file(params, params_format, chip, what="--params")
        chip_family = family_of(loaded.params)
        tr = read_trace(trace, chip_family.name, fmt, params=loaded.params)
        cal = calibrate(
            tr, loaded.params, family.name, assumptions=loaded.assumptions, fit=fit,
            fix=fixed, latency=latency, max_error_ratio=max_error,
        )  # fmt: skip
    except (ParameterError, PlantParameterError, KeyError, ValueError, OSError) as exc:
        fail(str(exc.args[0]) if isinstance(exc, KeyError) else str(exc))
        return

    sources = {
        n: "fitted" if n in {f.name for f in cal.fitted} else "fixed" if n in fixed else "nominal"
        for n in cal.plant
    }
    provenance = {
        "command": "calibrate",
        "trace": str(trace),
        "trace_format": tr.fmt,
        "trace_sha256": _sha256(trace),
        "n_samples": tr.n_ticks,
        "params_file": str(params),
        "chip_model": loaded.params.model,
        "chip_family": chip_family.name,
        "loop_latency": cal.latency,
        "loop_latency_choices": list(cal.latency_choices),
        "loop_latency_s": cal.latency_s,
        "rms_error_counts": cal.rms_error_counts,
        "open_loop_rms_error_counts": cal.open_loop_rms_error_counts,
        "rms_following_error": cal.rms_following_error,
        "poor_fit": cal.poor,
    }
    fitted = {f.name: f.to_dict() for f in cal.fitted}
    motor_note = _motor_note(family, cal.plant)
    report = {
        "plant": dict(cal.plant),
        "latency": cal.latency,
        "latency_s": cal.latency_s,
        "rms_error_counts": cal.rms_error_counts,
        **{k: v for k, v in cal.to_dict().items() if k not in ("plant", "latency", "latency_s",
                                                               "rms_error_counts")},
        "chip_model": loaded.params.model,
        "trace": str(trace),
        "motor_note": motor_note,
        "files": {},
    }  # fmt: skip
    try:
        out.mkdir(parents=True, exist_ok=True)
        plot_calibration(tr, cal, out / PLOT_FILE,
                         f"{loaded.params.model} on {family.name}: {cal.verdict()}")  # fmt: skip
        report["files"]["plot"] = str(out / PLOT_FILE)
        if not cal.poor or force:
            doc = plant_document(family.name, cal.plant, sources, provenance, fitted)
            write_plant_file(out / PLANT_FILE, doc)
            report["files"]["plant"] = str(out / PLANT_FILE)
        report["files"]["report"] = str(out / REPORT_FILE)
        write_atomic(out / REPORT_FILE, json.dumps(report, indent=2, default=str) + "\n")
    except (FileSafetyError, OSError) as exc:
        fail(f"--out {str(out)!r} cannot be written: {getattr(exc, 'strerror', None) or exc}")
        return

    if as_json:
        typer.echo(json.dumps(report, indent=2, default=str))
    else:
        table = Table(
            title=f"{loaded.params.model} on {family.name}: {tr.n_ticks} samples, fitted in "
            f"{cal.fit_time_s:.1f} s ({cal.n_evaluations} replays)",
            title_justify="left",
        )
        for col in ("parameter", "value", "+- 1 sigma", "unit", "source"):
            table.add_column(col, justify="left" if col in ("parameter", "source") else "right")
        for name, value in cal.plant.items():
            f = next((x for x in cal.fitted if x.name == name), None)
            if f is None and sources[name] == "nominal":
                continue
            sig = "-" if f is None else f"{f.sigma:.3g} ({100 * f.relative_sigma:.2g} %)"
            table.add_row(name, f"{value:.5g}", sig, family.param(name).unit, sources[name])
        console.print(table)
        lat = Table(title="loop latency (chip assumption)", title_justify="left")
        for col in ("loop_latency", "latency (us)", "replay RMS error (counts)"):
            lat.add_column(col, justify="left" if col == "loop_latency" else "right")
        for x in cal.latencies:
            lat.add_row(" = ".join(x.choices), f"{x.latency_s * 1e6:.4g}",
                        f"{x.rms_error_counts:.4g}")  # fmt: skip
        console.print(lat)
        console.print(
            f"open-loop replay (recorded command into the plant): RMS error "
            f"{cal.open_loop_rms_error_counts:.3g} counts", highlight=False,
        )  # fmt: skip
        if not cal.latency_decided:
            console.print(
                f"[yellow]warning:[/yellow] the trace hardly tells the latency "
                f"{cal.latency} from {' = '.join(cal.latencies[1].choices)} (cost ratio "
                f"{cal.latency_margin:.3g}); record a faster move, or hold it with --latency",
                highlight=False,
            )
        for name in cal.poorly_determined:
            console.print(f"[yellow]warning:[/yellow] the trace determines {name} poorly "
                          f"(uncertainty above 50 %); hold it with --fix if it is known",
                          highlight=False)  # fmt: skip
        if motor_note:
            console.print(f"[yellow]note:[/yellow] {motor_note}", highlight=False)
        colour = "red" if cal.poor else "green"
        console.print(f"[{colour}]{cal.verdict()}[/{colour}]", highlight=False)
        for path in report["files"].values():
            console.print(f"wrote {path}", highlight=False)
    if cal.poor:
        if not as_json and "plant" not in report["files"]:
            console.print("plant.json not written (a poor fit); --force writes it anyway.")
        raise typer.Exit(code=1)


def _key_values(items: list[str] | None) -> dict[str, int | float]:
    from servogym._cli_common import fail

    out: dict[str, int | float] = {}
    for item in items or []:
        key, sep, value = item.partition("=")
        key = key.strip()
        if not sep or not key:
            fail(f"--fix takes NAME=VALUE; got --fix {item!r}.")
        if key in out:
            fail(f"--fix names {key} twice; got --fix {item!r}.")
        try:
            number: float = int(value)  # an integer stays one (encoder_counts_per_rev)
        except ValueError:
            try:
                number = float(value)
            except ValueError:
                number = float("nan")
        if number != number or number in (float("inf"), float("-inf")):
            fail(f"--fix {key} must be a finite number; got {key}={value!r}.")
        out[key] = number
    return out


def _sha256(path: Path) -> str:
    import hashlib

    return hashlib.sha256(path.read_bytes()).hexdigest()


def _motor_note(family, values) -> str:
    """Why ``tune`` and ``check`` with the default moves would refuse the plant, or ''."""
    from servogym.plants import MotorFeasibilityError, check_motor

    try:
        check_motor(family, values, None, None)
    except MotorFeasibilityError as exc:
        return f"with the family's default moves: {exc}"
    return ""
