"""The ``servogym`` command."""

from __future__ import annotations

import json
from pathlib import Path
from typing import Annotated

import typer
from rich.console import Console
from rich.table import Table

app = typer.Typer(
    help="Tune real motion-controller chips in simulation: exact chip filters on MuJoCo plants.",
    no_args_is_help=True,
    add_completion=False,
    pretty_exceptions_enable=False,
)
console = Console()
if not console.is_terminal:  # pipes and CI logs: wide enough for the parameter tables
    console.width = 130


def _fail(message: str) -> None:
    console.print(f"[red]error:[/red] {message}", highlight=False)
    raise typer.Exit(code=2)


def _key_values(items: list[str] | None, option: str) -> dict[str, float]:
    out: dict[str, float] = {}
    for item in items or []:
        key, sep, value = item.partition("=")
        if not sep or not key:
            _fail(f"{option} takes NAME=VALUE; got {item!r}")
        try:
            out[key.strip()] = float(value)
        except ValueError:
            _fail(f"{option} {key}: {value!r} is not a number")
    return out


@app.command()
def chips(
    as_json: Annotated[bool, typer.Option("--json", help="Print JSON for machines.")] = False,
) -> None:
    """List chip models with every parameter's legal range and default."""
    from servogym.chips import families

    out = []
    for family in families().values():
        for model in family.models.values():
            out.append(
                {
                    "family": family.name,
                    "model": model.name,
                    "description": getattr(model, "description", ""),
                    "sample_time_s": family.sample_time_s(family.make_params(model.name)),
                    "export_formats": list(family.formats),
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
    """List plant families with every parameter, its unit, nominal value and range."""
    from servogym.plants import describe_plants

    described = describe_plants()
    if as_json:
        typer.echo(json.dumps(described, indent=2))
        return
    for fam in described:
        table = Table(title=f"{fam['name']}: {fam['description']}", title_justify="left")
        for col in ("parameter", "unit", "nominal", "range", "sampling", "randomised"):
            table.add_column(col, no_wrap=col == "parameter")
        for p in fam["params"]:
            table.add_row(
                p["name"], p["unit"], f"{p['nominal']:g}", f"{p['low']:g} .. {p['high']:g}",
                p["distribution"], "yes" if p["randomised"] else "no",
            )  # fmt: skip
        console.print(table)


@app.command()
def export(
    params_file: Annotated[Path, typer.Argument(help="A servogym JSON parameter file.")],
    fmt: Annotated[
        str, typer.Option("--format", "-f", help="Output format (see `servogym chips`).")
    ] = "cmotion",
    axis: Annotated[int | None, typer.Option(help="Axis or motor number on the chip.")] = None,
    out: Annotated[
        Path | None, typer.Option("--out", "-o", help="Write here instead of stdout.")
    ] = None,
) -> None:
    """Export a parameter file in the form the hardware takes."""
    from servogym.chips import ParameterError, family_of, load_params_file

    try:
        loaded = load_params_file(params_file.read_text())
        family = family_of(loaded.params)
        kw = {} if axis is None else {"axis": axis}
        text = family.export(loaded.params, fmt, assumptions=loaded.assumptions, **kw)
    except (ParameterError, ValueError, OSError) as exc:
        _fail(str(exc))
        return
    if out is None:
        typer.echo(text, nl=not text.endswith("\n"))
    else:
        out.write_text(text)
        console.print(f"wrote {out}")


@app.command()
def simulate(
    chip: Annotated[
        str | None, typer.Option(help="Chip model, e.g. MC2100 (default: the params file's).")
    ] = None,
    plant: Annotated[str, typer.Option(help="Plant family (see `servogym plants`).")] = "rotary",
    plant_param: Annotated[
        list[str] | None,
        typer.Option("--plant-param", help="Plant parameter NAME=VALUE (repeatable)."),
    ] = None,
    params: Annotated[
        Path | None, typer.Option(help="A servogym JSON parameter file (default: chip defaults).")
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
    from servogym.chips import ParameterError, family_of, load_params_file
    from servogym.plants import PlantParameterError
    from servogym.sim import REFERENCE_SUBSTEPS, Evaluator, MoveSpec, Scenario
    from servogym.sim._plot import plot_response

    try:
        loaded = load_params_file(params.read_text()) if params else None
        if loaded is not None and chip is not None and chip.upper() != loaded.params.model.upper():
            _fail(f"--chip {chip} differs from the params file's chip model {loaded.params.model}")
        model = loaded.params.model if loaded else (chip or "MC2100")
        moves = []
        for text in move or []:
            try:
                parts = [float(x) for x in text.split(",")]
            except ValueError:
                parts = []
            if len(parts) not in (3, 4):
                _fail(
                    f"--move takes DISTANCE,MAX_VELOCITY,MAX_ACCELERATION[,SETTLE_S]; got {text!r}"
                )
            moves.append(MoveSpec(*parts))
        scenario = Scenario(
            model, plant, plant_values=_key_values(plant_param, "--plant-param"),
            moves=tuple(moves), substeps=REFERENCE_SUBSTEPS if reference else substeps,
            assumptions=loaded.assumptions if loaded else None,
        )  # fmt: skip
        chip_params = loaded.params if loaded else scenario.default_params()
        result = Evaluator(scenario).evaluate(chip_params, traces=True)
    except (ParameterError, PlantParameterError, ValueError, KeyError, OSError) as exc:
        _fail(str(exc))
        return
    out.mkdir(parents=True, exist_ok=True)
    summary = {"chip_model": model, "chip_family": family_of(chip_params).name, "plant": plant,
               **result.summary()}  # fmt: skip
    (out / "metrics.json").write_text(json.dumps(summary, indent=2))
    plot_response([(model, result)], out / "response.png", f"{model} on {plant}")
    if as_json:
        typer.echo(json.dumps(summary, indent=2))
        return
    table = Table(title=f"{model} on {plant}: cost {result.cost:.3f}", title_justify="left")
    table.add_column("metric")
    for i in range(len(result.metrics)):
        table.add_column(f"move {i + 1}", justify="right")
    for name in result.metrics[0].to_dict():
        if name == "dt":
            continue
        row = [name] + [_fmt(m.to_dict()[name]) for m in result.metrics]
        table.add_row(*row, *[""] * (len(result.metrics) - len(row) + 1))
    console.print(table)
    console.print(f"wrote {out / 'response.png'} and {out / 'metrics.json'}")


@app.command()
def check(
    params_file: Annotated[Path, typer.Argument(metavar="PARAMS", help="A parameter file.")],
    plant: Annotated[str, typer.Option(help="Plant family (see `servogym plants`).")],
    chip: Annotated[
        str | None, typer.Option(help="Chip model (default: the file's; must agree).")
    ] = None,
    plant_param: Annotated[
        list[str] | None,
        typer.Option("--plant-param", help="Plant parameter NAME=VALUE (repeatable)."),
    ] = None,
    min_gain_margin: Annotated[
        float, typer.Option("--min-gain-margin", help="Smallest gain margin (dB).")
    ] = 6.0,
    min_phase_margin: Annotated[
        float, typer.Option("--min-phase-margin", help="Smallest phase margin (deg).")
    ] = 30.0,
    out: Annotated[
        Path | None,
        typer.Option(help="Folder for bode.png and check.json [default: PARAMS_check/]."),
    ] = None,
    as_json: Annotated[bool, typer.Option("--json", help="Print the report as JSON.")] = False,
) -> None:
    """Check a parameter set before it goes onto a drive: stress set and loop margins.

    Re-simulates the set with the fine reference integration, every loop-latency
    assumption, the load at +-20 % and friction at +-50 %, and computes gain margin, phase
    margin and closed-loop bandwidth. Exit code 0 when it passes, 1 when it fails.
    """
    from servogym.autotune._cli import check_table
    from servogym.chips import ParameterError, load_params_file
    from servogym.plants import PlantParameterError
    from servogym.sim import Scenario
    from servogym.sim._check import CheckLimits, check_params

    try:
        loaded = load_params_file(params_file.read_text())
        if chip is not None and chip.upper() != loaded.params.model.upper():
            _fail(f"--chip {chip} differs from the params file's chip model {loaded.params.model}")
        limits = CheckLimits(
            min_gain_margin_db=min_gain_margin, min_phase_margin_deg=min_phase_margin
        )
        scenario = Scenario(
            loaded.params.model, plant, plant_values=_key_values(plant_param, "--plant-param"),
            assumptions=loaded.assumptions,
        )  # fmt: skip
        folder = out or params_file.with_name(params_file.stem + "_check")
        folder.mkdir(parents=True, exist_ok=True)
        report = check_params(loaded.params, scenario, limits, bode_path=folder / "bode.png")
    except (ParameterError, PlantParameterError, ValueError, KeyError, OSError) as exc:
        _fail(str(exc.args[0]) if isinstance(exc, KeyError) else str(exc))
        return
    doc = {"params_file": str(params_file), "chip_model": loaded.params.model, "plant": plant,
           "plant_values": scenario.plant_values, **report.to_dict()}  # fmt: skip
    (folder / "check.json").write_text(json.dumps(doc, indent=2) + "\n")
    if as_json:
        typer.echo(json.dumps(doc, indent=2))
    else:
        console.print(check_table(doc))
        for line in report.failures:
            console.print(f"[red]fail:[/red] {line}", highlight=False)
        console.print(f"wrote {folder / 'bode.png'} and {folder / 'check.json'}", highlight=False)
    if not report.passed:
        raise typer.Exit(code=1)


def _fmt(value: object) -> str:
    if isinstance(value, float):
        return f"{value:.4g}"
    return str(value)


def _register_subcommands() -> None:
    from servogym.agents._cli import evaluate_command, train_command
    from servogym.autotune._cli import tune_command
    from servogym.autotune.bench._cli import benchmark_command

    app.command("tune")(tune_command)
    app.command("train")(train_command)
    app.command("evaluate")(evaluate_command)
    app.command("benchmark")(benchmark_command)


_register_subcommands()


def main() -> None:  # pragma: no cover - console entry point
    app()


if __name__ == "__main__":  # pragma: no cover
    app()
