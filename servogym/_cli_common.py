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
