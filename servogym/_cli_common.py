"""What every ``servogym`` command shares: the one-line error.

Errors go to stderr as one plain line, ``error: <message>``: no rich markup (a message may
hold ``[...]``), no wrapping at the terminal width, no traceback; the exit code is 2.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping
from pathlib import Path
from typing import NoReturn

import typer


def one_line(message: object) -> str:
    """``message`` with its line breaks folded into spaces."""
    return " ".join(str(message).split())


def fail(message: object, options: Mapping[str, str] | None = None) -> NoReturn:
    """Print ``error: <message>`` on one line to stderr and exit with code 2 (the password
    of any database URL in it masked; the Python argument names of ``options`` replaced by
    the command's options, see :func:`name_options`)."""
    from servogym._input import mask_secrets

    text = name_options(one_line(message), options) if options else one_line(message)
    typer.echo(f"error: {mask_secrets(text)}", err=True)
    raise typer.Exit(code=2)


def name_options(message: str, options: Mapping[str, str]) -> str:
    """``message`` with the library's argument names replaced by the options a user typed.

    ``{"min_gain_margin_db": "--min-gain-margin"}`` turns ``min_gain_margin_db must satisfy
    0 <= min_gain_margin_db; got min_gain_margin_db=-3`` into ``--min-gain-margin must
    satisfy 0 <= --min-gain-margin; got --min-gain-margin -3``. Only a message about the
    argument (one holding ``name=``) is rewritten.
    """
    import re

    for name in sorted(options, key=len, reverse=True):
        option = options[name]
        if not re.search(rf"(?<![\w.-]){re.escape(name)}=", message):
            continue
        message = re.sub(rf"(?<![\w.-]){re.escape(name)}=", f"{option} ", message)
        message = re.sub(rf"(?<![\w.-]){re.escape(name)}(?![\w=-])", option, message)
    return message


def check_choice(option: str, value: str | None, check: Callable[[str], object]) -> None:
    """Refuse a name ``check`` refuses (an unknown chip model, plant, tuner, env id) in one
    line that starts with the option: ``--chip: unknown chip model 'MC9' ...``."""
    if value is None:
        return
    try:
        check(value)
    except (KeyError, ValueError) as exc:
        text = str(exc.args[0]) if isinstance(exc, KeyError) and exc.args else str(exc)
        fail(f"{option}: {text}")


def check_count(option: str, value: int | None, low: int = 1, high: int | None = None) -> None:
    """Refuse a count below ``low`` (``--budget 0``, ``--workers -2``) or above ``high``
    in one line naming the option, the value and the legal range."""
    if value is None:
        return
    if high is not None and not low <= value <= high:
        fail(f"{option} must satisfy {low} <= {option} <= {high}; got {option} {value}.")
    if value < low:
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


def check_writable_folder(option: str, folder: Path) -> None:
    """Create ``folder`` (and its parents) and prove a file can be written in it, before any
    work: a read-only or full place fails at once, not after the run. Folders created for
    the probe are removed again when it fails."""
    import contextlib
    import os
    import tempfile

    folder = Path(folder)
    if folder.exists() and not folder.is_dir():
        fail(f"{option} {str(folder)!r} is a file; give a folder.")
    created = []
    p = folder
    while not p.exists() and p != p.parent:
        created.append(p)
        p = p.parent
    try:
        folder.mkdir(parents=True, exist_ok=True)
        fd, tmp = tempfile.mkstemp(dir=folder, prefix=".servogym-probe.", suffix=".tmp")
        os.close(fd)
        os.unlink(tmp)
    except OSError as exc:
        for c in created:
            with contextlib.suppress(OSError):
                c.rmdir()
        fail(
            f"{option} {str(folder)!r} cannot be written: {exc.strerror or exc}; give a folder "
            f"you can write to."
        )
