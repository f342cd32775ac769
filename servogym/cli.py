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
    add_completion=True,  # --install-completion / --show-completion for bash, zsh, fish
    pretty_exceptions_enable=False,
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

    logger = logging.getLogger("servogym")
    for handler in list(logger.handlers):
        if isinstance(handler, RichHandler):
            logger.removeHandler(handler)
    handler = RichHandler(console=Console(stderr=True), show_path=False, show_time=verbose > 1)
    handler.setFormatter(logging.Formatter("%(message)s"))
    logger.addHandler(handler)
    logger.setLevel([logging.WARNING, logging.INFO, logging.DEBUG][min(verbose, 2)])


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
    as_json: Annotated[
        bool, typer.Option("--json", help="Print JSON for machines: format, chip, text, file.")
    ] = False,
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
    if out is not None:
        out.write_text(text)
    if as_json:
        doc = {"format": fmt, "chip_model": loaded.params.model, "chip_family": family.name,
               "file": None if out is None else str(out), "text": text}  # fmt: skip
        typer.echo(json.dumps(doc, indent=2))
    elif out is None:
        typer.echo(text, nl=not text.endswith("\n"))
    else:
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
    substeps: Annotated[int, typer.Option(help="mj_step calls per servo tick.")] = 1,
    out: Annotated[Path, typer.Option(help="Folder for response.png and metrics.json.")] = Path(
        "runs/simulate"
    ),
    as_json: Annotated[bool, typer.Option("--json", help="Print metrics as JSON.")] = False,
) -> None:
    """Simulate a chip axis on a plant along moves; print metrics, write a response plot."""
    from servogym.chips import ParameterError, family_of, load_params_file
    from servogym.plants import PlantParameterError
    from servogym.sim import Evaluator, MoveSpec, Scenario
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
            moves=tuple(moves), substeps=substeps,
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
