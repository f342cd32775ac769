"""One bounded, validated reader for every file and JSON text servogym is given.

Every input path (parameter files, ``--fixed`` files, ``manifest.json``, a run's
``config.json``, benchmark records, ``--env-kwargs`` / ``--algo-kwargs``) goes through
:func:`read_bytes` / :func:`read_text` and :func:`parse_json`:

* regular files only: a folder, a device (``/dev/zero``), a FIFO or a socket is refused
  before a byte is read, so nothing hangs or fills the memory;
* a size limit (:data:`MAX_FILE_BYTES`): a parameter file is a few kB;
* UTF-8 text, one error line naming the option and the byte that is not;
* JSON nested at most :data:`MAX_JSON_DEPTH` deep (checked before parsing: Python's
  parser raises ``RecursionError`` on deep nesting), strict (no key twice, no NaN or
  infinity).

Every error is an :class:`InputError` (a :class:`~servogym.chips.ParameterError`, so a
``ValueError``) whose one-line message names the option, the value and what is allowed.
:func:`mask_url` hides the password of a database URL in every message.
"""

from __future__ import annotations

import json
import os
import re
import stat
from pathlib import Path
from typing import Any

from servogym.chips._space import ParameterError

MAX_FILE_BYTES = 4 * 1024 * 1024
"""Largest input file read (4 MiB; a parameter file or a manifest is a few kB)."""

MAX_JSON_DEPTH = 32
"""Deepest nesting of arrays and objects a JSON input may have."""


class InputError(ParameterError):
    """An input file or JSON text cannot be read; the message says which and why."""


def _kind(mode: int) -> str:
    if stat.S_ISDIR(mode):
        return "a folder"
    if stat.S_ISFIFO(mode):
        return "a FIFO (named pipe)"
    if stat.S_ISCHR(mode) or stat.S_ISBLK(mode):
        return "a device"
    if stat.S_ISSOCK(mode):
        return "a socket"
    return "not a regular file"


def read_bytes(path: str | Path, what: str, *, max_bytes: int = MAX_FILE_BYTES) -> bytes:
    """The content of the regular file ``path``, at most ``max_bytes`` long.

    Args:
        path: The file.
        what: The option or file that named it, for messages (``"--params"``).
        max_bytes: Size limit.

    Raises:
        InputError: missing, a folder, a device, FIFO or socket, unreadable, or too large.
    """
    name = str(path)
    flags = os.O_RDONLY | getattr(os, "O_NONBLOCK", 0) | getattr(os, "O_NOCTTY", 0)
    try:
        fd = os.open(name, flags)  # O_NONBLOCK: opening a FIFO does not wait for a writer
    except FileNotFoundError:
        raise InputError(f"{what} {name!r} does not exist.") from None
    except IsADirectoryError:
        raise InputError(f"{what} {name!r} is a folder; give a file.") from None
    except OSError as exc:
        raise InputError(f"{what} {name!r} cannot be read: {exc.strerror or exc}.") from None
    try:
        info = os.fstat(fd)
        if not stat.S_ISREG(info.st_mode):
            raise InputError(
                f"{what} {name!r} is {_kind(info.st_mode)}; give a regular file"
                + (" (a file inside it)." if stat.S_ISDIR(info.st_mode) else ".")
            )
        if info.st_size > max_bytes:
            raise InputError(
                f"{what} {name!r} is {info.st_size} bytes; an input file is at most "
                f"{max_bytes} bytes."
            )
        chunks, size = [], 0
        while size <= max_bytes:
            chunk = os.read(fd, min(1 << 20, max_bytes + 1 - size))
            if not chunk:
                break
            chunks.append(chunk)
            size += len(chunk)
        if size > max_bytes:  # grew while being read
            raise InputError(
                f"{what} {name!r} is more than {max_bytes} bytes; an input file is at most "
                f"{max_bytes} bytes."
            )
        return b"".join(chunks)
    except OSError as exc:
        raise InputError(f"{what} {name!r} cannot be read: {exc.strerror or exc}.") from None
    finally:
        os.close(fd)


def decode(raw: bytes, what: str, name: str) -> str:
    """``raw`` as UTF-8 text, or an :class:`InputError` naming the first bad byte."""
    try:
        return raw.decode("utf-8")
    except UnicodeDecodeError as exc:
        raise InputError(
            f"{what} {name!r} is not a text file (byte {exc.start} is not UTF-8)."
        ) from None


def read_text(path: str | Path, what: str, *, max_bytes: int = MAX_FILE_BYTES) -> str:
    """:func:`read_bytes` decoded as UTF-8 (one error line naming the bad byte)."""
    return decode(read_bytes(path, what, max_bytes=max_bytes), what, str(path))


_TOKEN = re.compile(r'"(?:[^"\\]|\\.)*"|[\[\]{}]', re.DOTALL)


def json_depth_error(text: str | bytes, max_depth: int = MAX_JSON_DEPTH) -> str | None:
    """Why ``text`` nests deeper than ``max_depth`` (``None`` if it does not)."""
    if isinstance(text, bytes):
        text = text.decode("utf-8", "replace")
    if text.count("[") + text.count("{") <= max_depth:
        return None
    depth = 0
    for match in _TOKEN.finditer(text):
        token = match.group()
        if token in "[{":
            depth += 1
            if depth > max_depth:
                return f"JSON nested more than {max_depth} deep (at character {match.start()})"
        elif token in "]}":
            depth -= 1
    return None


def _no_duplicates(pairs: list[tuple[str, Any]]) -> dict[str, Any]:
    out: dict[str, Any] = {}
    for key, value in pairs:
        if key in out:
            raise InputError(f"the key {key!r} appears twice in one JSON object")
        out[key] = value
    return out


def _no_constant(name: str) -> Any:
    raise InputError(f"the non-JSON number {name} (NaN and infinities are not JSON)")


def parse_json(
    text: str | bytes, what: str, *, expect: type | None = dict, max_depth: int = MAX_JSON_DEPTH
) -> Any:
    """``text`` as strict JSON, bounded in depth; ``expect`` the type of the top value.

    Args:
        text: The JSON text.
        what: What it is, for messages (``"--env-kwargs '{...}'"`` or a file's name).
        expect: Type the document must have (``None``: any).
        max_depth: Deepest nesting allowed.

    Raises:
        InputError: one line naming ``what`` and what is wrong.
    """
    why = json_depth_error(text, max_depth)
    if why is not None:
        raise InputError(f"{what} must be JSON nested at most {max_depth} deep; got {why}.")
    try:
        doc = json.loads(text, object_pairs_hook=_no_duplicates, parse_constant=_no_constant)
    except InputError as exc:
        raise InputError(f"{what} must be strict JSON; got {exc}.") from None
    except json.JSONDecodeError as exc:
        raise InputError(
            f"{what} must be JSON; invalid JSON at line {exc.lineno} column {exc.colno}: {exc.msg}."
        ) from None
    except (ValueError, RecursionError) as exc:
        raise InputError(f"{what} must be JSON; got {type(exc).__name__}: {exc}.") from None
    if expect is not None and not isinstance(doc, expect):
        raise InputError(
            f"{what} must be a JSON {'object' if expect is dict else expect.__name__}; got a "
            f"JSON {_json_type(doc)}."
        )
    return doc


def _json_type(value: Any) -> str:
    return {dict: "object", list: "array", str: "string", bool: "boolean", int: "number",
            float: "number", type(None): "null"}.get(type(value), type(value).__name__)  # fmt: skip


def read_json(
    path: str | Path, what: str, *, expect: type | None = dict, max_bytes: int = MAX_FILE_BYTES
) -> Any:
    """A JSON file through :func:`read_text` and :func:`parse_json`."""
    text = read_text(path, what, max_bytes=max_bytes)
    return parse_json(text, f"{what} {str(path)!r}", expect=expect)


# --------------------------------------------------------------------------------------
# Secrets
# --------------------------------------------------------------------------------------

# scheme://user:password@host: the password runs to the last "@" before the path
_URL_PASSWORD = re.compile(r"(?P<head>\b[a-zA-Z][\w+.-]*://[^:/@\s'\"]*:)[^\s'\"/]*(?=@)")


def mask_url(url: str) -> str:
    """``url`` with its password replaced by ``***`` (``postgresql://bob:***@host/db``).

    The password runs from the first ``:`` after the user to the last ``@`` before the
    host, so one holding ``:`` or ``@`` is hidden whole (SQLAlchemy's ``make_url`` splits at
    the first ``@`` and would show the rest).
    """
    return mask_secrets(url)


def mask_secrets(text: str) -> str:
    """``text`` with the password of every ``scheme://user:password@host`` in it masked."""
    return _URL_PASSWORD.sub(r"\g<head>***", text)


class SecretFilter:
    """A ``logging`` filter that masks database passwords in every record it passes."""

    def filter(self, record: Any) -> bool:
        message = record.getMessage()
        masked = mask_secrets(message)
        if masked != message:
            record.msg, record.args = masked, None
        return True
