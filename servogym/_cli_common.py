"""What every ``servogym`` command shares: the one-line error.

Errors go to stderr as one plain line, ``error: <message>``: no rich markup (a message may
hold ``[...]``), no wrapping at the terminal width, no traceback; the exit code is 2.
"""

from __future__ import annotations

from typing import NoReturn

import typer


def one_line(message: object) -> str:
    """``message`` with its line breaks folded into spaces."""
    return " ".join(str(message).split())


def fail(message: object) -> NoReturn:
    """Print ``error: <message>`` on one line to stderr and exit with code 2."""
    typer.echo(f"error: {one_line(message)}", err=True)
    raise typer.Exit(code=2)


def check_count(option: str, value: int | None, low: int = 1) -> None:
    """Refuse a count below ``low`` (``--budget 0``, ``--workers -2``) in one line."""
    if value is not None and value < low:
        fail(f"{option} must be an integer >= {low}; got {option} {value}.")


def check_number(
    option: str,
    value: float | None,
    *,
    low: float | None = None,
    high: float | None = None,
    low_open: bool = False,
) -> None:
    """Refuse NaN, an infinity or a value outside ``[low, high]`` (``(low, high]`` when
    ``low_open``) in one line naming the option, the value and the legal range."""
    if value is None:
        return
    import math

    lo = "" if low is None else f"{low:g} {'<' if low_open else '<='} "
    hi = "" if high is None else f" <= {high:g}"
    rule = f"{lo}{option}{hi}" if (lo or hi) else f"{option} finite"
    if not math.isfinite(value):
        fail(f"{option} must be a finite number ({rule}); got {option} {value}.")
    if low is not None and (value <= low if low_open else value < low):
        fail(f"{option} must satisfy {rule}; got {option} {value:g}.")
    if high is not None and value > high:
        fail(f"{option} must satisfy {rule}; got {option} {value:g}.")
