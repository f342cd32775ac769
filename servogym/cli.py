"""The ``servogym`` command."""

from __future__ import annotations

import contextlib
import dataclasses
import json
import math
import sys
from pathlib import Path
from typing import Annotated, Any

import typer
from rich.console import Console
from rich.table import Table
from typer.core import TyperGroup

from servogym._cli_common import fail


class _Group(TyperGroup):
    """The app's command group: a bad option value's message also shows the value given.

    Typer's type errors name the option but not the value (``Invalid value for '--budget':
    Input should be a valid integer``); this adds ``; got --budget 'x'`` from the command
    line, so every bad-input message names the parameter and the value.
    """

    def main(self, args=None, prog_name=None, complete_var=None, standalone_mode=True, **extra):
        argv = list(sys.argv[1:] if args is None else args)
        if not standalone_mode:
            return super().main(argv, prog_name, complete_var, standalone_mode, **extra)
        try:
            rv = super().main(argv, prog_name, complete_var, False, **extra)
        except typer.BadParameter as exc:
            given = _given(argv, getattr(exc.param, "opts", []) or [])
            if given is not None and repr(given[1]) not in exc.message:
                exc.message = f"{exc.message.rstrip('.')}; got {given[0]} {given[1]!r}."
            exc.show()
            sys.exit(exc.exit_code)
        except typer.TyperException as exc:  # click's UsageError and the like
            exc.show()  # type: ignore[attr-defined]
            sys.exit(getattr(exc, "exit_code", 2))
        except typer.Abort:
            typer.echo("Aborted!", err=True)
            sys.exit(1)
        sys.exit(rv if isinstance(rv, int) else 0)


def _given(argv: list[str], opts: list[str]) -> tuple[str, str] | None:
    """The last value given on the command line for an option (``--budget x``, ``--budget=x``)."""
    found = None
    for i, arg in enumerate(argv):
        for opt in opts:
            if arg == opt and i + 1 < len(argv):
                found = (opt, argv[i + 1])
            elif opt.startswith("--") and arg.startswith(opt + "="):
                found = (opt, arg[len(opt) + 1 :])
    return found


app = typer.Typer(
    cls=_Group,
    help="Tune real motion-controller chips in simulation: exact chip filters on MuJoCo plants.",
    no_args_is_help=True,
    add_completion=True,  # --install-completion / --show-completion for bash, zsh, fish
    pretty_exceptions_enable=False,
    rich_markup_mode=None,  # usage errors as one plain line, not a wrapped rich panel
)
console = Console()
if not console.is_terminal:  # pipes and CI logs: wide enough for the parameter tables
    console.width = 130


def _version(value: bool) -> None:
    if value:
        from servogym import __version__

        typer.echo(f"servogym {__version__}")
        raise typer.Exit()


@app.callback()
def _main(
    version: Annotated[
        bool,
        typer.Option("--version", callback=_version, is_eager=True, help="Print the version."),
    ] = False,
    verbose: Annotated[
        int, typer.Option("--verbose", "-v", count=True, help="More log output (-v, -vv).")
    ] = 0,
) -> None:
    """Tune real motion-controller chips in simulation: exact chip filters on MuJoCo plants."""
    setup_logging(verbose)


def setup_logging(verbose: int = 0) -> None:
    """Render the library's ``logging`` records (logger ``servogym``) with rich on stderr:
    warnings by default, info with ``-v``, debug with ``-vv``."""
    import logging

    from rich.logging import RichHandler

    from servogym._input import SecretFilter

    logger = logging.getLogger("servogym")
    for handler in list(logger.handlers):
        if isinstance(handler, RichHandler):
            logger.removeHandler(handler)
    handler = RichHandler(console=Console(stderr=True), show_path=False, show_time=verbose > 1)
    handler.setFormatter(logging.Formatter("%(message)s"))
    handler.addFilter(SecretFilter())  # no database password in a log line
    logger.addHandler(handler)
    logger.setLevel([logging.WARNING, logging.INFO, logging.DEBUG][min(verbose, 2)])


def _fail(message: str) -> None:
    fail(message)


def _finite(text: str, option: str, name: str) -> float:
    """``text`` as a finite number, or a one-line error naming the option and the value."""
    try:
        value = float(text)
    except ValueError:
        value = math.nan
        _fail(f"{option} {name} must be a number; got {name}={text!r}.")
    if not math.isfinite(value):
        _fail(f"{option} {name} must be a finite number; got {name}={text!r}.")
    return value


def _key_values(items: list[str] | None, option: str) -> dict[str, int | float]:
    """``NAME=VALUE`` items; an integer literal stays an integer (as ``tune`` reads it)."""
    out: dict[str, int | float] = {}
    for item in items or []:
        key, sep, value = item.partition("=")
        if not sep or not key.strip():
            _fail(f"{option} takes NAME=VALUE; got {option} {item!r}.")
        if key.strip() in out:
            _fail(f"{option} names {key.strip()} twice; got {option} {item!r}.")
        try:
            out[key.strip()] = int(value.strip())
        except ValueError:
            out[key.strip()] = _finite(value, option, key.strip())
    return out


def _plant_values(plant_file: Path | None, plant: str, items: list[str] | None) -> dict:
    """A --plant-file's values (servogym calibrate's plant.json) with --plant-param on top."""
    from servogym.calibrate import plant_values

    return plant_values(plant_file, plant, _key_values(items, "--plant-param"))


@app.command()
def chips(
    model_filter: Annotated[
        list[str] | None,
        typer.Option(
            "--model", help="List only this chip model (repeatable; any case, e.g. mc2100)."
        ),
    ] = None,
    as_json: Annotated[bool, typer.Option("--json", help="Print JSON for machines.")] = False,
) -> None:
    """List chip models with every parameter's legal range and default."""
    from servogym._cli_common import check_choice
    from servogym.chips import families
    from servogym.chips._family import get_chip

    wanted = None
    if model_filter:
        for name in model_filter:
            check_choice("--model", name, get_chip)
        wanted = {get_chip(name)[1] for name in model_filter}
    out = []
    for family in families().values():
        for model in family.models.values():
            if wanted is not None and model.name not in wanted:
                continue
            out.append(
                {
                    "family": family.name,
                    "model": model.name,
                    "description": getattr(model, "description", ""),
                    "sample_time_s": family.sample_time_s(family.make_params(model.name)),
                    "export_formats": list(family.formats_for(model.name)),
                    "parameters": family.parameter_space(model.name).describe(),
                }
            )
    if as_json:
        typer.echo(json.dumps(out, indent=2))
        return
    for entry in out:
        table = Table(
            title=f"{entry['model']} ({entry['family']}: {entry['description']}); "
            f"sample time {entry['sample_time_s'] * 1e6:g} us; "
            f"exports {', '.join(entry['export_formats'])}",
            title_justify="left",
        )
        for col in ("parameter", "width", "legal range", "default", "unit", "tuned", "source"):
            table.add_column(col, no_wrap=col in ("parameter", "legal range"))
        for p in entry["parameters"]:
            table.add_row(
                p["name"], p["width"], f"{p['low']} .. {p['high']}", str(p["default"]),
                p["unit"], "yes" if p["tunable"] else "no", p["source"],
            )  # fmt: skip
        console.print(table)
        for p in entry["parameters"]:
            if p["default_note"]:
                note = f"  default {p['name']}={p['default']}: {p['default_note']}"
                console.print(note, markup=False, highlight=False)


@app.command()
def plants(
    as_json: Annotated[bool, typer.Option("--json", help="Print JSON for machines.")] = False,
) -> None:
    """List plant families (single- and multi-axis, with the number of axes) with every
    parameter, its unit, nominal value and range."""
    from servogym.plants import describe_multi_plants, describe_plants

    described = describe_plants() + describe_multi_plants()
    if as_json:
        typer.echo(json.dumps(described, indent=2))
        return
    for fam in described:
        n = fam.get("n_axes", 1)
        axes = f" ({n} axes: {', '.join(fam['axes'])})" if n > 1 else " (1 axis)"
        table = Table(title=f"{fam['name']}{axes}: {fam['description']}", title_justify="left")
        for col in ("parameter", "unit", "nominal", "range", "sampling", "randomised"):
            table.add_column(col, no_wrap=col == "parameter")
        for p in fam["params"]:
            table.add_row(
                p["name"], p["unit"], _number(p["nominal"]),
                f"{_number(p['low'])} .. {_number(p['high'])}",
                p["distribution"], "yes" if p["randomised"] else "no",
            )  # fmt: skip
        console.print(table)


PARAMS_FILE_HELP = (
    "A parameter file in any format servogym writes: JSON, C-Motion, PMD host commands, "
    "PMAC I-variables, Parker 6250/6K command file (detected from the content)."
)


@app.command()
def export(
    params_file: Annotated[Path, typer.Argument(help=PARAMS_FILE_HELP)],
    fmt: Annotated[
        str | None,
        typer.Option(
            "--format",
            "-f",
            help="Output format (see `servogym chips`) [default: the chip's own: cmotion, "
            "ivar, 6250 or 6k].",
        ),
    ] = None,
    input_format: Annotated[
        str | None,
        typer.Option("--input-format", help="Format of PARAMS_FILE [default: detected]."),
    ] = None,
    chip: Annotated[
        str | None,
        typer.Option(help="Chip model, for a file that names none (a controller's file)."),
    ] = None,
    axis: Annotated[int | None, typer.Option(help="Axis or motor number on the chip.")] = None,
    out: Annotated[
        Path | None, typer.Option("--out", "-o", help="Write here instead of stdout.")
    ] = None,
    force: Annotated[
        bool, typer.Option("--force", help="Replace --out if it exists (never the input).")
    ] = False,
    as_json: Annotated[
        bool, typer.Option("--json", help="Print JSON for machines: format, chip, text, file.")
    ] = False,
) -> None:
    """Export a parameter file in the form the hardware takes (written atomically); a file of
    several axes (servogym tune on a machine) is exported with every axis, in the chip's
    multi-axis form, unless --axis picks one."""
    from servogym._cli_common import check_choice
    from servogym._files import check_target, write_atomic
    from servogym.chips import ParameterError, family_of, read_params_file
    from servogym.chips._axes import export_axes, load_axes
    from servogym.chips._family import get_chip
    from servogym.chips._load import _check_fmt

    check_choice("--chip", chip, get_chip)
    if input_format is not None:
        try:
            _check_fmt(input_format)
        except ParameterError as exc:
            _fail(str(exc).replace("--format", "--input-format"))
    try:
        if out is not None:
            check_target(out, inputs=[params_file], force=force)
        machine, machine_error = None, None
        if params_file.is_file():  # a file of several axes: all of them, or --axis
            try:
                got = load_axes(params_file, input_format, chip)
                machine = got if len(got) > 1 else None
            except (ParameterError, ValueError) as exc:
                machine_error = exc
        if machine is not None:
            family, model = machine.family, machine.model
            target = (_export_format(fmt, family, model) if fmt is not None
                      else family.native_format(model))  # fmt: skip
            if axis is None:
                text = export_axes(machine, target)
            elif axis in machine:
                text = family.export(machine[axis], target, axis=axis)
            else:
                raise ParameterError(
                    f"--axis must be one of the {machine.noun} numbers the file sets "
                    f"({', '.join(map(str, machine.numbers))}); got --axis {axis}."
                )
        else:
            try:
                loaded = read_params_file(params_file, input_format, chip, what="PARAMS_FILE")
            except ParameterError as exc:  # a damaged file of several axes: its own error
                if machine_error is not None and "import_axes" in str(exc):
                    raise machine_error from None
                raise
            family, model = family_of(loaded.params), loaded.params.model
            target = (_export_format(fmt, family, model) if fmt is not None
                      else family.native_format(model))  # fmt: skip
            kw = {} if axis is None else {"axis": axis}
            text = family.export(loaded.params, target, assumptions=loaded.assumptions, **kw)
        if out is not None:
            write_atomic(out, text)
    except (ParameterError, ValueError, OSError) as exc:
        message = str(exc).replace("name it with --format", "name it with --input-format")
        fail(message, {"axis": "--axis", "motor": "--axis", "fmt": "--format"})
        return
    if as_json:
        doc = {"format": target, "chip_model": model, "chip_family": family.name,
               "file": None if out is None else str(out), "text": text}  # fmt: skip
        if machine is not None and axis is None:
            doc["axes"] = list(machine.numbers)
        typer.echo(json.dumps(doc, indent=2))
    elif out is None:
        typer.echo(text, nl=not text.endswith("\n"))
    else:
        console.print(f"wrote {out}", highlight=False)


MAX_SUBSTEPS = 1024
"""Most RK4 substeps per servo tick ``simulate --substeps`` takes."""

MOVE_LIMITS = {
    "DISTANCE": (0.0, 1e4),
    "MAX_VELOCITY": (0.0, 1e5),
    "MAX_ACCELERATION": (0.0, 1e8),
    "SETTLE_S": (0.0, 60.0),
}
"""Legal ranges of ``simulate --move``'s fields (joint units: rad or m; s)."""


def _export_format(fmt: str, family, model: str) -> str:
    """``export --format`` checked (any case) against the formats the chip model takes."""
    import difflib

    from servogym.chips import ParameterError

    allowed = family.formats_for(model)
    if fmt.lower() in allowed:
        return fmt.lower()
    close = difflib.get_close_matches(fmt.lower(), list(allowed), n=1)
    hint = f" Did you mean {close[0]!r}?" if close else ""
    listed = ", ".join(f"{f} ({family.file_extensions.get(f, '')})" for f in allowed)
    raise ParameterError(
        f"--format must be one of {listed} for the {model}; got --format {fmt!r}.{hint}"
    )


PlantParamOption = Annotated[
    list[str] | None,
    typer.Option("--plant-param", help="Plant parameter NAME=VALUE (repeatable)."),
]
"""``--plant-param`` of ``simulate`` and ``check``."""

PlantFileOption = Annotated[
    Path | None,
    typer.Option(
        "--plant-file",
        help="A plant.json from `servogym calibrate`: its values, --plant-param on top.",
    ),
]
"""``--plant-file`` of ``simulate`` and ``check``."""


@app.command()
def simulate(
    chip: Annotated[
        str | None, typer.Option(help="Chip model, e.g. MC2100 (default: the params file's).")
    ] = None,
    plant: Annotated[str, typer.Option(help="Plant family (see `servogym plants`).")] = "rotary",
    plant_param: PlantParamOption = None,
    plant_file: PlantFileOption = None,
    params: Annotated[
        Path | None,
        typer.Option(help=PARAMS_FILE_HELP + " Default: the chip's defaults."),
    ] = None,
    params_format: Annotated[
        str | None, typer.Option("--format", help="Format of --params [default: detected].")
    ] = None,
    move: Annotated[
        list[str] | None,
        typer.Option(
            help="DISTANCE,MAX_VELOCITY,MAX_ACCELERATION[,SETTLE_S] in the plant's joint units "
            "(rad or m); repeatable, run in sequence. Default: the plant's out-and-back moves."
        ),
    ] = None,
    substeps: Annotated[
        int | None,
        typer.Option(help="RK4 substeps per servo tick [default: ceil(period / 160 us)]."),
    ] = None,
    reference: Annotated[
        bool,
        typer.Option("--reference", help="Use the fine reference integration (RK4 x 32)."),
    ] = False,
    out: Annotated[Path, typer.Option(help="Folder for response.png and metrics.json.")] = Path(
        "runs/simulate"
    ),
    as_json: Annotated[bool, typer.Option("--json", help="Print metrics as JSON.")] = False,
) -> None:
    """Simulate a chip axis on a plant along moves; print metrics, write a response plot."""
    from servogym._cli_common import check_choice, check_writable_folder
    from servogym._files import write_atomic
    from servogym.chips import ParameterError, family_of, read_params_file
    from servogym.chips._family import get_chip
    from servogym.plants import PlantParameterError, get_plant
    from servogym.sim import REFERENCE_SUBSTEPS, Evaluator, MoveSpec, Scenario
    from servogym.sim._plot import plot_response

    if substeps is not None and not 1 <= substeps <= MAX_SUBSTEPS:
        _fail(
            f"--substeps must satisfy 1 <= --substeps <= {MAX_SUBSTEPS}; got --substeps {substeps}."
        )
    if substeps is not None and reference:
        _fail(
            f"--substeps {substeps} contradicts --reference (the reference integration is RK4 x "
            f"{REFERENCE_SUBSTEPS}); give one of them."
        )
    if params_format is not None and params is None:
        _fail(f"--format {params_format!r} names the format of --params; give --params too.")
    check_choice("--chip", chip, get_chip)
    check_choice("--plant", plant, get_plant)
    try:
        loaded = read_params_file(params, params_format, chip, what="--params") if params else None
        model = loaded.params.model if loaded else (chip if chip is not None else "MC2100")
        moves = []
        for text in move or []:
            fields = text.split(",")
            if len(fields) not in (3, 4):
                _fail(
                    f"--move takes DISTANCE,MAX_VELOCITY,MAX_ACCELERATION[,SETTLE_S]; got "
                    f"--move {text!r}."
                )
            names = ("DISTANCE", "MAX_VELOCITY", "MAX_ACCELERATION", "SETTLE_S")
            parts = [_finite(x, "--move", n) for x, n in zip(fields, names, strict=False)]
            for n, value in zip(names, parts, strict=False):
                low, high = MOVE_LIMITS[n]
                ok = (abs(value) <= high if n == "DISTANCE" else value <= high) and (
                    n == "DISTANCE" or (value >= low if n == "SETTLE_S" else value > low)
                )
                if not ok:
                    rule = (
                        f"|{n}| <= {high:g}" if n == "DISTANCE"
                        else f"{low:g} {'<=' if n == 'SETTLE_S' else '<'} {n} <= {high:g}"
                    )  # fmt: skip
                    _fail(f"--move {n} must satisfy {rule}; got {n}={value:g} in --move {text!r}.")
            moves.append(MoveSpec(*parts))
        scenario = Scenario(
            model, plant, plant_values=_plant_values(plant_file, plant, plant_param),
            moves=tuple(moves), substeps=REFERENCE_SUBSTEPS if reference else substeps,
            assumptions=loaded.assumptions if loaded else None,
        )  # fmt: skip
        chip_params = loaded.params if loaded else scenario.default_params()
        check_writable_folder("--out", out)  # before the work, not after it
        with _working(f"simulating {model} on {plant} ({len(scenario.moves)} moves)", as_json):
            result = Evaluator(scenario).evaluate(chip_params, traces=True)
    except (ParameterError, PlantParameterError, ValueError, KeyError, OSError) as exc:
        _fail(str(exc.args[0]) if isinstance(exc, KeyError) and exc.args else str(exc))
        return
    summary = {"chip_model": model, "chip_family": family_of(chip_params).name, "plant": plant,
               **result.summary()}  # fmt: skip
    try:
        write_atomic(out / "metrics.json", json.dumps(summary, indent=2) + "\n")
        plot_response([(model, result)], out / "response.png", f"{model} on {plant}")
    except OSError as exc:
        _fail(f"--out {str(out)!r} cannot be written: {exc.strerror or exc}.")
    if as_json:
        typer.echo(json.dumps(summary, indent=2))
        return
    table = Table(title=f"{model} on {plant}: cost {result.cost:.3f}", title_justify="left")
    table.add_column("metric")
    table.add_column("unit")
    for i in range(len(result.metrics)):
        table.add_column(f"move {i + 1}", justify="right")
    for name in result.metrics[0].to_dict():
        if name == "dt":
            continue
        row = [name, METRIC_UNITS.get(name, "")] + [_fmt(m.to_dict()[name]) for m in result.metrics]
        table.add_row(*row)
    console.print(table)
    console.print(f"wrote {out / 'response.png'} and {out / 'metrics.json'}")


METRIC_UNITS = {
    "iae": "counts*s",
    "itae": "counts*s^2",
    "max_following_error": "counts",
    "overshoot": "counts",
    "settling_time": "s",
    "steady_state_error": "counts",
    "rms_command": "of full scale",
    "saturation_fraction": "of ticks",
    "chatter": "full scale/tick",
    "settled": "",
    "diverged": "",
    "divergence_tick": "tick",
    "divergence_reason": "",
    "n_ticks": "ticks",
}
"""Unit of every per-move metric in ``simulate``'s table (``EpisodeMetrics``; docs/cost.md)."""


@app.command()
def check(
    params_file: Annotated[Path, typer.Argument(metavar="PARAMS", help="A parameter file.")],
    plant: Annotated[
        str | None,
        typer.Option(help="Plant family (see `servogym plants`); required without --instance."),
    ] = None,
    chip: Annotated[
        str | None, typer.Option(help="Chip model (default: the file's; must agree).")
    ] = None,
    instance: Annotated[
        str | None,
        typer.Option(
            "--instance",
            help="A benchmark instance id (`servogym benchmark --list`): its chip, plant, "
            "plant values and move.",
        ),
    ] = None,
    plant_param: PlantParamOption = None,
    plant_file: PlantFileOption = None,
    min_gain_margin: Annotated[
        float, typer.Option("--min-gain-margin", help="Smallest gain margin (dB).")
    ] = 6.0,
    min_phase_margin: Annotated[
        float, typer.Option("--min-phase-margin", help="Smallest phase margin (deg).")
    ] = 30.0,
    max_following_error: Annotated[
        float | None,
        typer.Option(
            "--max-following-error",
            help="Largest following error in any case (counts) [default: 1 % of the longest move].",
        ),
    ] = None,
    max_saturation: Annotated[
        float,
        typer.Option(
            "--max-saturation", help="Largest fraction of ticks at the motor limit in any case."
        ),
    ] = 0.05,
    out: Annotated[
        Path | None,
        typer.Option(help="Folder for bode.png and check.json [default: PARAMS_check/]."),
    ] = None,
    as_json: Annotated[bool, typer.Option("--json", help="Print the report as JSON.")] = False,
) -> None:
    """Check a parameter set before it goes onto a drive: stress set and loop margins.

    Re-simulates the set with the fine reference integration, every loop-latency
    assumption, the load at +-20 % and friction at +-50 %; in every case, decides the
    loop's stability from its closed-loop poles and computes gain margin, phase margin and
    closed-loop bandwidth at each holding point. The set passes when every case is stable,
    within the following-error and saturation limits and above the margin minima. Exit
    code 0 when it passes, 1 when it fails.
    """
    from servogym._cli_common import check_choice, check_number, check_writable_folder
    from servogym._files import write_atomic
    from servogym.autotune._cli import check_table
    from servogym.chips import ParameterError, read_params_file
    from servogym.chips._family import get_chip
    from servogym.plants import PlantParameterError, get_plant
    from servogym.sim import Scenario
    from servogym.sim._check import CheckLimits, check_params

    check_number("--min-gain-margin", min_gain_margin, low=0, high=60)
    check_number("--min-phase-margin", min_phase_margin, low=0, high=90)
    check_number("--max-following-error", max_following_error, low=0, low_open=True)
    check_number("--max-saturation", max_saturation, low=0, high=1)
    check_choice("--chip", chip, get_chip)
    bench = None
    if instance is not None:
        from servogym.autotune.bench import get_suite

        if plant_param or plant_file is not None:
            _fail("--instance fixes the plant: give neither --plant-param nor --plant-file")
        try:
            bench = get_suite(instance.split("/")[0]).spec(instance)
        except (KeyError, ValueError) as exc:
            _fail(f"--instance: {exc.args[0]}")
            return
        if plant is not None and plant != bench.plant:
            _fail(f"--plant {plant} differs from --instance {instance}'s plant {bench.plant}")
        plant = bench.plant
        chip = chip or bench.chip_model
        if chip.upper() != bench.chip_model.upper():
            _fail(f"--chip {chip} differs from --instance {instance}'s chip {bench.chip_model}")
    if plant is None:
        _fail("--plant is required (or --instance, a benchmark instance id)")
        return
    from servogym.plants import MULTI_PLANTS

    if plant in MULTI_PLANTS:  # a machine: PARAMS is a multi-axis file
        limits_kw = dict(
            min_gain_margin_db=min_gain_margin,
            min_phase_margin_deg=min_phase_margin,
            max_following_error=max_following_error,
            max_saturation=max_saturation,
        )
        _check_machine(params_file, plant, chip, limits_kw, plant_param, plant_file, out, as_json)
        return
    check_choice("--plant", plant, get_plant)
    try:
        loaded = read_params_file(params_file, model=chip, what="PARAMS")
        if chip is not None and chip.upper() != loaded.params.model.upper():
            _fail(f"--chip {chip} differs from the params file's chip model {loaded.params.model}")
        limits = CheckLimits(
            min_gain_margin_db=min_gain_margin,
            min_phase_margin_deg=min_phase_margin,
            max_following_error=max_following_error,
            max_saturation=max_saturation,
        )
        if bench is not None:
            from servogym.autotune._space import register_values

            values = register_values(loaded.params)
            held = {k: v for k, v in bench.fixed.items() if values.get(k) != v}
            if held:
                _fail(
                    f"--instance {instance} holds "
                    + ", ".join(f"{k}={v} (the file has {values.get(k)})" for k, v in held.items())
                    + "; the set is not one of the instance's"
                )
            scenario = dataclasses.replace(bench.scenario(), assumptions=loaded.assumptions)
        else:
            scenario = Scenario(
                loaded.params.model, plant,
                plant_values=_plant_values(plant_file, plant, plant_param),
                assumptions=loaded.assumptions,
            )  # fmt: skip
        folder = out or params_file.with_name(params_file.stem + "_check")
        check_writable_folder("--out", folder)  # before the check, not after it
        with _working(
            f"checking {loaded.params.model} on {plant}: the stress set on the reference "
            f"integration and the loop margins (tens of seconds)",
            as_json,
        ):
            report = check_params(loaded.params, scenario, limits, bode_path=folder / "bode.png")
    except (ParameterError, PlantParameterError, ValueError, KeyError, OSError) as exc:
        _fail(str(exc.args[0]) if isinstance(exc, KeyError) else str(exc))
        return
    doc = {"params_file": str(params_file), "chip_model": loaded.params.model, "plant": plant,
           "plant_values": scenario.plant_values, **report.to_dict()}  # fmt: skip
    if instance is not None:
        doc["instance"] = instance
    write_atomic(folder / "check.json", json.dumps(doc, indent=2) + "\n")
    if as_json:
        typer.echo(json.dumps(doc, indent=2))
    else:
        console.print(check_table(doc))
        for line in report.failures:
            console.print(f"[red]fail:[/red] {line}", highlight=False)
        console.print(f"wrote {folder / 'bode.png'} and {folder / 'check.json'}", highlight=False)
    if not report.passed:
        raise typer.Exit(code=1)


def _check_machine(
    params_file: Path,
    plant: str,
    chip: str | None,
    limits_kw: dict[str, Any],
    plant_param: list[str] | None,
    plant_file: Path | None,
    out: Path | None,
    as_json: bool,
) -> None:
    """``servogym check`` of a multi-axis parameter file on a multi-axis plant
    (:func:`servogym.sim.check_machine_params`): the per-axis table, the cases, the verdict;
    exit code 1 when the sets fail."""
    from servogym._cli_common import check_writable_folder
    from servogym._files import write_atomic
    from servogym.chips import ParameterError
    from servogym.chips._axes import load_axes
    from servogym.plants import PlantParameterError
    from servogym.sim._check import CheckLimits
    from servogym.sim._multicheck import check_machine_params

    try:
        axes = load_axes(params_file, model=chip)
        if chip is not None and chip.upper() != axes.model.upper():
            _fail(f"--chip {chip} differs from the params file's chip model {axes.model}")
        assumptions = _axes_assumptions(params_file, axes.family)
        limits = CheckLimits(**limits_kw)
        values = _plant_values(plant_file, plant, plant_param)
        folder = out or params_file.with_name(params_file.stem + "_check")
        check_writable_folder("--out", folder)  # before the check, not after it
        with _working(
            f"checking {axes.model} on {plant}: {len(axes)} axes, the stress set on the "
            f"reference integration and every loop's margins with the others closed (a minute "
            f"or more)",
            as_json,
        ):
            report = check_machine_params(axes, plant, limits, plant_values=values,
                                          assumptions=assumptions)  # fmt: skip
    except (ParameterError, PlantParameterError, ValueError, KeyError, OSError) as exc:
        _fail(str(exc.args[0]) if isinstance(exc, KeyError) else str(exc))
        return
    doc = {"params_file": str(params_file), "axis_numbers": list(axes.numbers),
           "plant_values": values, **report.to_dict()}  # fmt: skip
    write_atomic(folder / "check.json", json.dumps(doc, indent=2) + "\n")
    if as_json:
        typer.echo(json.dumps(doc, indent=2))
    else:
        for table in _machine_check_tables(doc):
            console.print(table)
        for line in report.failures:
            console.print(f"[red]fail:[/red] {line}", highlight=False)
        console.print(f"wrote {folder / 'check.json'}", highlight=False)
    if not report.passed:
        raise typer.Exit(code=1)


def _axes_assumptions(path: Path, family: Any) -> Any:
    """The assumption switches a multi-axis file records (its header, or its JSON
    ``assumptions``), else the family's defaults."""
    from servogym._input import read_text
    from servogym.chips._axisfile import read_axes_json
    from servogym.chips._load import detect_format

    text = read_text(path, "PARAMS")
    if detect_format(text) == "json":
        table = family.export_module.FORMAT_TABLE
        return read_axes_json(table.schema, text, noun=table.index)[1].assumptions
    return family.export_module.read_header(text).get("assumptions") or (
        family.default_assumptions()
    )


def _machine_check_tables(doc: dict[str, Any]) -> list[Any]:
    """Per axis: its loop's margins with the others closed (worst over the cases and every
    latency x sequencing choice), its following error and saturation; then the cases."""
    from rich.table import Table

    from servogym.autotune._cli import _fmt, _margin

    limits = doc["limits"]
    verdict = "[green]passed[/green]" if doc["passed"] else "[red]FAILED[/red]"
    stable = "stable" if doc["stable"] else "[red]UNSTABLE[/red]"
    title = (
        f"check {verdict}: {doc['chip_model']} on {doc['plant']}, the machine's closed loop "
        f"{stable} (minima {limits['min_gain_margin_db']:g} dB, "
        f"{limits['min_phase_margin_deg']:g} deg; saturation at most "
        f"{100 * limits['max_saturation']:g} % of ticks)"
    )
    caption = (
        "GM, PM: each loop's gain and phase margin with the other loops closed, the worst "
        "over the cases, operating configurations and latency/sequencing choices, with where; "
        "error: largest following error over the cases / its limit (counts)"
    )
    axes = Table(title=title, title_justify="left", caption=caption, caption_justify="left")
    for col in ("axis", "latency", "GM (reference)", "PM (reference)", "worst GM", "worst PM",
                "error", "at limit"):  # fmt: skip
        axes.add_column(col, justify="left" if col == "axis" else "right")
    for k, loop in enumerate(doc["loops"]):
        name = loop["axis"]
        worst = doc["worst"].get(name, {})
        rows = [c["axes"][k] for c in doc["cases"]]
        fe = max(rows, key=lambda r: r["max_following_error"] / r["following_error_limit"])

        def w(key: str, unit: str, worst=worst) -> str:
            if key not in worst:
                return "none"
            return f"{_margin(worst[key]['value'], unit)} ({worst[key]['case']})"

        axes.add_row(
            name, f"{1e6 * loop['latency_s']:.4g} us",
            _margin(loop["margins"]["gain_margin_db"], "dB"),
            _margin(loop["margins"]["phase_margin_deg"], "deg"),
            w("gain_margin_db", "dB"), w("phase_margin_deg", "deg"),
            f"{_fmt(fe['max_following_error'])} / {_fmt(fe['following_error_limit'])}",
            f"{100 * max(r['saturation_fraction'] for r in rows):.1f} %",
        )  # fmt: skip
    cases = Table(title="stress cases (RK4 reference)", title_justify="left")
    for col in ("case", "latency", "sequencing", "cost", "contour max", "diverged", "stable",
                "verdict"):  # fmt: skip
        cases.add_column(col, justify="left" if col == "case" else "right")
    for c in doc["cases"]:
        cases.add_row(
            c["name"], c["loop_latency"], c["sequencing"], _fmt(c["cost"]),
            f"{c['max_contour_error_um']:.3g} um", c["divergence"] or "no",
            "yes" if c["stable"] else "[red]NO[/red]",
            "[green]ok[/green]" if c["passed"] else "[red]fail[/red]",
        )  # fmt: skip
    return [axes, cases]


@contextlib.contextmanager
def _working(text: str, quiet: bool = False):
    """Show that a long step runs: a spinner on a terminal, one line on stderr otherwise
    (nothing with ``--json``)."""
    if quiet:
        yield
        return
    err = Console(stderr=True)
    if err.is_terminal:
        with err.status(text + " ..."):
            yield
    else:
        typer.echo(f"{text} ...", err=True)
        yield


def _number(x: float) -> str:
    """A plant value as a person writes it: ``1048576``, ``0.0002``, ``1.5e-07``."""
    if float(x).is_integer() and abs(x) < 1e15:
        return str(int(x))
    return f"{x:.6g}"


def _fmt(value: object) -> str:
    if isinstance(value, float):
        return f"{value:.4g}"
    return str(value)


def _register_subcommands() -> None:
    from servogym.agents._cli import evaluate_command, train_command
    from servogym.autotune._cli import tune_command
    from servogym.autotune.bench._cli import benchmark_command
    from servogym.calibrate._cli import calibrate_command

    app.command("tune")(tune_command)
    app.command("train")(train_command)
    app.command("evaluate")(evaluate_command)
    app.command("benchmark")(benchmark_command)
    app.command("calibrate")(calibrate_command)


_register_subcommands()


def main() -> None:  # pragma: no cover - console entry point
    app()


if __name__ == "__main__":  # pragma: no cover
    app()
