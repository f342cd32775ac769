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


def _fail(message: str) -> None:
    console.print(f"[red]error:[/red] {message}", highlight=False)
    raise typer.Exit(code=2)


@app.command()
def chips(
    as_json: Annotated[bool, typer.Option("--json", help="Print JSON for machines.")] = False,
) -> None:
    """List chip models with every parameter's legal range and default."""
    from servogym.chips.pmd import CHIP_MODELS, SPEC_VERSION, parameter_space

    out = []
    for model in CHIP_MODELS.values():
        out.append(
            {
                "family": model.family,
                "model": model.name,
                "line": model.line,
                "description": model.description,
                "sample_time_us": model.sample_time_us,
                "spec_version": SPEC_VERSION,
                "parameters": parameter_space(model).describe(),
            }
        )
    if as_json:
        typer.echo(json.dumps(out, indent=2))
        return
    for entry in out:
        table = Table(
            title=f"{entry['model']} ({entry['family']} {entry['line']}: {entry['description']}); "
            f"sample time {entry['sample_time_us']} us",
            title_justify="left",
        )
        for col in ("parameter", "width", "legal range", "default", "unit", "tuned", "source"):
            table.add_column(col)
        for p in entry["parameters"]:
            table.add_row(
                p["name"], p["width"], f"{p['low']} .. {p['high']}", str(p["default"]),
                p["unit"], "yes" if p["tunable"] else "no", p["source"],
            )  # fmt: skip
        console.print(table)


@app.command()
def export(
    params_file: Annotated[Path, typer.Argument(help="A servogym JSON parameter file.")],
    fmt: Annotated[
        str, typer.Option("--format", "-f", help="Output format: cmotion, host or json.")
    ] = "cmotion",
    axis: Annotated[int, typer.Option(help="Axis number on the chip (1-based).")] = 1,
    out: Annotated[
        Path | None, typer.Option("--out", "-o", help="Write here instead of stdout.")
    ] = None,
) -> None:
    """Export a parameter file in the form the hardware takes."""
    from servogym.chips import ParameterError
    from servogym.chips.pmd import export as export_params
    from servogym.chips.pmd import from_json

    try:
        loaded = from_json(params_file.read_text())
        kw = {"assumptions": loaded.assumptions} if fmt in ("json", "cmotion") else {}
        if fmt != "json":
            kw["axis"] = axis
        text = export_params(loaded.params, fmt, **kw)
    except (ParameterError, ValueError, OSError) as exc:
        _fail(str(exc))
        return
    if out is None:
        typer.echo(text, nl=not text.endswith("\n"))
    else:
        out.write_text(text)
        console.print(f"wrote {out}")


def main() -> None:  # pragma: no cover - console entry point
    app()


if __name__ == "__main__":  # pragma: no cover
    app()
