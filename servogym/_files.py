"""Files an engineer loads onto a drive: atomic writes, end lines with checksums, file sets.

Rules (docs/files.md):

* Every file is written to a temporary file in the same folder, flushed to disk and renamed
  over its name (:func:`write_atomic`): a reader sees the old file or the new one, never a
  half-written one.
* Every exported text file ends with an end line carrying the SHA-256 of everything above
  it (:func:`seal`, e.g. ``; servogym-end sha256=3f1c...``); servogym's importers verify it
  (:func:`unseal`). A file that carries servogym's title line but no end line was cut short
  and is refused. A file with neither (saved by a controller, written by hand) is read as a
  hand-written file and must set every register.
* Outputs that belong together (a tuned set, its exports, its reports) are written as one
  set with a manifest (:func:`write_file_set`): every file goes to a temporary file first,
  then a pending manifest records the intent, then the renames follow and the manifest is
  committed. A run killed before the pending manifest leaves the old set (its temporary
  files are removed by :func:`recover_file_set`); killed after it, the set is completed by
  :func:`recover_file_set`. :func:`check_file_set` tells a complete set from a torn one.
"""

from __future__ import annotations

import contextlib
import datetime as _dt
import hashlib
import json
import os
import re
import secrets
import tempfile
from collections.abc import Iterable, Mapping
from pathlib import Path
from typing import Any

from servogym import __version__
from servogym.chips._space import ParameterError

END_TAG = "servogym-end"
"""The word that marks an end line."""

MANIFEST = "manifest.json"
"""Name of a file set's manifest in its folder."""

PENDING = ".manifest.pending.json"
"""Name of the manifest of a set whose renames have not all happened yet."""

SET_FORMAT = "servogym-file-set"

LOCK = ".servogym.lock"
"""Lock file of a set's folder: one writer (or recovery) at a time, across processes."""


@contextlib.contextmanager
def _folder_lock(folder: Path):
    """Hold an exclusive ``flock`` on ``folder/.servogym.lock`` (released by the OS when a
    process dies), so two runs writing sets into one folder never rename each other's
    temporary files or pending manifest."""
    try:
        import fcntl
    except ImportError:  # not POSIX: no cross-process lock
        yield
        return
    fd = os.open(folder / LOCK, os.O_RDWR | os.O_CREAT, 0o644)
    try:
        fcntl.flock(fd, fcntl.LOCK_EX)
        yield
    finally:
        os.close(fd)  # closing releases the lock


class FileSafetyError(ParameterError):
    """A file cannot be written or read safely (the message says which and why)."""


class FileWriteError(OSError):
    """The OS refused a write; the message names the file asked for, never the temporary
    file the write went through (``Permission denied (writing 'out/best_params.c')``)."""

    def __str__(self) -> str:
        return str(self.strerror)


def _write_error(exc: OSError, target: Path) -> FileWriteError:
    return FileWriteError(exc.errno, f"{exc.strerror or exc} (writing {str(target)!r})")


# --------------------------------------------------------------------------------------
# Atomic writes
# --------------------------------------------------------------------------------------


def _same_file(a: Path, b: Path) -> bool:
    try:
        return a.exists() and b.exists() and os.path.samefile(a, b)
    except OSError:
        return False


def check_target(
    path: str | Path, *, inputs: Iterable[str | Path] = (), force: bool = False, what: str = "--out"
) -> Path:
    """``path`` if a file may be written there, else a one-line :class:`FileSafetyError`.

    Args:
        path: Where the file goes.
        inputs: Files the command reads; the output never overwrites one of them.
        force: Allow overwriting another existing file.
        what: The option that named ``path``, for the message.
    """
    path = Path(path)
    for source in inputs:
        if _same_file(path, Path(source)) or Path(path).resolve() == Path(source).resolve():
            raise FileSafetyError(
                f"{what} {str(path)!r} is the input file; refusing to overwrite it. Write the "
                f"export to another file."
            )
    if path.is_dir():
        raise FileSafetyError(f"{what} {str(path)!r} is a folder; give a file name.")
    if path.exists() and not force:
        raise FileSafetyError(
            f"{what} {str(path)!r} already exists; pass --force to replace it, or choose "
            f"another name."
        )
    if not path.parent.is_dir():
        raise FileSafetyError(
            f"{what} {str(path)!r}: the folder {str(path.parent)!r} does not exist."
        )
    return path


def _fsync_dir(folder: Path) -> None:
    with contextlib.suppress(OSError):  # not every file system lets a folder be synced
        fd = os.open(folder, os.O_RDONLY)
        try:
            os.fsync(fd)
        finally:
            os.close(fd)


def _write_temp(folder: Path, name: str, data: bytes, token: str | None = None) -> Path:
    """``data`` in a hidden temporary file next to ``name``, flushed to disk."""
    try:
        return _write_temp_raw(folder, name, data, token)
    except FileWriteError:
        raise
    except OSError as exc:
        raise _write_error(exc, folder / name) from None


def _write_temp_raw(folder: Path, name: str, data: bytes, token: str | None) -> Path:
    if token is None:
        fd, tmp = tempfile.mkstemp(dir=folder, prefix=f".{name}.", suffix=".tmp")
    else:
        tmp = str(folder / f".{name}.{token}.tmp")
        fd = os.open(tmp, os.O_WRONLY | os.O_CREAT | os.O_TRUNC, 0o600)
    try:
        with os.fdopen(fd, "wb") as fh:
            fh.write(data)
            fh.flush()
            os.fsync(fh.fileno())
        target = folder / name
        mode = target.stat().st_mode & 0o777 if target.exists() else 0o666 & ~_umask()
        os.chmod(tmp, mode)
    except BaseException:
        with contextlib.suppress(OSError):
            os.unlink(tmp)
        raise
    return Path(tmp)


def _umask() -> int:
    mask = os.umask(0)
    os.umask(mask)
    return mask


def _bytes(data: str | bytes) -> bytes:
    return data.encode("utf-8") if isinstance(data, str) else data


def write_atomic(path: str | Path, data: str | bytes) -> Path:
    """Write ``data`` to ``path`` through a temporary file and a rename.

    A reader (or a power cut) sees the old content or the new one, never a mix or a cut.
    Checks on the target (input, existing file) are :func:`check_target`'s.
    """
    path = Path(path)
    tmp = _write_temp(path.parent, path.name, _bytes(data))
    try:
        os.replace(tmp, path)
    except BaseException as exc:
        with contextlib.suppress(OSError):
            os.unlink(tmp)
        if isinstance(exc, OSError):
            raise _write_error(exc, path) from None
        raise
    _fsync_dir(path.parent)
    return path


# --------------------------------------------------------------------------------------
# End lines
# --------------------------------------------------------------------------------------

_END_LINE = re.compile(r"^\s*(//|#|;)\s*" + END_TAG + r"\s+sha256=([0-9a-f]{64})\s*$")
_TITLE = re.compile(r"^[\s/*#;]*servogym\b.*\bparameter set\b")


def _digest(body: str) -> str:
    return hashlib.sha256(body.encode("utf-8")).hexdigest()


def seal(text: str, comment: str) -> str:
    """``text`` with an end line: ``<comment> servogym-end sha256=<hash of text>``.

    Args:
        text: The file content (newline-terminated; a newline is added if not).
        comment: The format's line-comment marker (``//``, ``#`` or ``;``).
    """
    body = text if text.endswith("\n") else text + "\n"
    return f"{body}{comment} {END_TAG} sha256={_digest(body)}\n"


def unseal(text: str, *, verify: bool = True) -> tuple[str, bool]:
    """Verify and remove an end line; ``(body, sealed)``.

    Importers call it twice: first with ``verify=False`` (a cut-short file is refused
    before anything else), then, after reading the content, with ``verify=True``, so an
    edited value is reported with its own message (range, syntax) when it has one and as a
    checksum mismatch otherwise.

    Returns:
        The text without its end line (newlines normalised to ``\\n``) and whether it had
        one. A text without end line and without servogym's title line is returned whole,
        as a hand-written file (its importer then requires every register).

    Raises:
        FileSafetyError: if the end line does not match the content (changed or corrupted
            after export), is not the last line, is itself cut short, or if the text has
            servogym's title line but no end line (cut short).
    """
    text = text.replace("\r\n", "\n").replace("\r", "\n")
    lines = text.split("\n")
    last = len(lines) - 1
    while last >= 0 and not lines[last].strip():
        last -= 1
    for n, line in enumerate(lines[: last + 1], start=1):
        if END_TAG in line and not (n == last + 1 and _END_LINE.match(line)):
            where = "is not the last line" if _END_LINE.match(line) else "is cut short"
            raise FileSafetyError(
                f"line {n}: the end line {line.strip()!r} {where}; the file was cut short or "
                f"joined with another. Export it again."
            )
    if last >= 0 and _END_LINE.match(lines[last]):
        body = "\n".join(lines[:last]) + "\n"
        expected = _END_LINE.match(lines[last]).group(2)  # type: ignore[union-attr]
        got = _digest(body)
        if verify and got != expected:
            raise FileSafetyError(
                f"line {last + 1}: the end line's checksum sha256={expected[:12]}... does not "
                f"match the content above it (sha256={got[:12]}...): the file was changed or "
                f"corrupted after export. Export it again; to load a hand-edited copy, delete "
                f"its servogym title line and its end line (it is then read as a hand-written "
                f"file that must set every register)."
            )
        return body, True
    title = next((line for line in lines if _TITLE.match(line)), None)
    if title is not None:
        raise FileSafetyError(
            f"the file starts with servogym's title line ({title.strip()[:60]!r}) but has no "
            f"'{END_TAG}' end line: it was cut short. Export it again (a hand-written file "
            f"must not carry the servogym title line)."
        )
    return text, False


def json_checksum(doc: Mapping[str, Any]) -> str:
    """``sha256:<hex>`` of a JSON document's canonical text (compact, key order kept)."""
    canonical = json.dumps(doc, separators=(",", ":"), ensure_ascii=False, allow_nan=False)
    return "sha256:" + _digest(canonical)


# --------------------------------------------------------------------------------------
# File sets with a manifest
# --------------------------------------------------------------------------------------


def _sha256_file(path: Path) -> str:
    return hashlib.sha256(path.read_bytes()).hexdigest()


_SHA256 = re.compile(r"^[0-9a-f]{64}$")


def read_manifest(path: str | Path) -> dict[str, Any]:
    """A file set's manifest (or pending manifest), read bounded and schema-checked.

    Raises:
        FileSafetyError: one line naming the file and what is wrong with it (not a regular
            file, too large or deep, not JSON, not servogym's schema) and what to do.
    """
    from servogym._input import InputError, parse_json, read_text

    path = Path(path)
    remedy = (
        f"it is not a servogym file-set manifest; if the folder holds no servogym run, "
        f"move the file away or remove {str(path)!r}, else run the command that wrote the "
        f"set again"
    )
    try:
        doc = parse_json(read_text(path, "the manifest"), f"the manifest {str(path)!r}")
    except InputError as exc:
        raise FileSafetyError(f"{str(exc).rstrip('.')}: {remedy}.") from None
    files = doc.get("files")
    why = None
    if doc.get("format") != SET_FORMAT:
        why = f"format must be {SET_FORMAT!r}; got format={doc.get('format')!r}"
    elif not isinstance(doc.get("token"), str) or not re.fullmatch(r"[0-9a-f]{12}", doc["token"]):
        why = f"token must be 12 hex digits; got token={doc.get('token')!r}"
    elif not isinstance(files, dict):
        why = f"files must be an object of file name -> entry; got files={files!r:.60}"
    else:
        for name, entry in files.items():
            if Path(name).name != name or name in ("", ".", "..", MANIFEST, PENDING):
                why = f"files names a plain file name each; got {name!r}"
            elif not isinstance(entry, dict) or not _SHA256.match(str(entry.get("sha256"))):
                why = f"files[{name!r}] must hold a 64-hex-digit sha256; got {entry!r:.80}"
            if why:
                break
    if why is not None:
        raise FileSafetyError(f"the manifest {str(path)!r}: {why}; {remedy}.")
    return doc


def write_file_set(
    folder: str | Path, files: Mapping[str, str | bytes], meta: Mapping[str, Any]
) -> dict[str, Any]:
    """Write files that belong together, then their manifest, so no reader mixes two sets.

    Order: every file to a temporary file (flushed); the pending manifest (atomic); the
    renames; the manifest (atomic rename of the pending one). See the module docstring
    for what a kill at each point leaves.

    Args:
        folder: The folder (existing).
        files: File name (no folder part) -> content.
        meta: Written into the manifest (e.g. ``{"trial": 41}``); JSON values.

    Returns:
        The manifest written.
    """
    folder = Path(folder)
    with _folder_lock(folder):
        return _write_file_set(folder, files, meta)


def _write_file_set(
    folder: Path, files: Mapping[str, str | bytes], meta: Mapping[str, Any]
) -> dict[str, Any]:
    _recover(folder)
    token = secrets.token_hex(6)
    entries: dict[str, dict[str, Any]] = {}
    for name, data in files.items():
        if Path(name).name != name or name in (MANIFEST, PENDING):
            raise FileSafetyError(f"file set entries are plain file names; got {name!r}.")
        raw = _bytes(data)
        _write_temp(folder, name, raw, token)
        entries[name] = {"sha256": hashlib.sha256(raw).hexdigest(), "bytes": len(raw)}
    manifest = {
        "format": SET_FORMAT,
        "format_version": 1,
        **json.loads(json.dumps(dict(meta), allow_nan=False)),
        "created": _dt.datetime.now(_dt.UTC).isoformat(timespec="seconds"),
        "servogym_version": __version__,
        "token": token,
        "files": entries,
    }
    text = json.dumps(manifest, indent=2) + "\n"
    write_atomic(folder / PENDING, text)
    _commit(folder, manifest)
    return manifest


def _commit(folder: Path, manifest: Mapping[str, Any]) -> None:
    token = manifest["token"]
    for name, entry in manifest["files"].items():
        tmp = folder / f".{name}.{token}.tmp"
        if tmp.exists():
            os.replace(tmp, folder / name)
        elif not ((folder / name).exists() and _sha256_file(folder / name) == entry["sha256"]):
            raise FileSafetyError(
                f"the pending file set in {str(folder)!r} cannot be completed: {name} is "
                f"neither in its temporary file nor already in place. Run the command again."
            )
    _fsync_dir(folder)
    os.replace(folder / PENDING, folder / MANIFEST)
    _fsync_dir(folder)


_TEMP = re.compile(r"^\..+\.(?:[0-9a-f]{12}|[a-z0-9_]{8})\.tmp$")  # ours and mkstemp's
_OURS = re.compile(r"^\..+\.[0-9a-f]{12}\.tmp$")


def recover_file_set(folder: str | Path) -> str:
    """Finish or undo a set a killed writer left; ``"complete"``, ``"rolled forward"`` or
    ``"cleaned"`` (temporary files of a set that never got its pending manifest removed)."""
    folder = Path(folder)
    if not folder.is_dir():
        return "complete"
    with _folder_lock(folder):
        return _recover(folder)


def _recover(folder: Path) -> str:
    state = "complete"
    pending = folder / PENDING
    if pending.exists():
        manifest = read_manifest(pending)  # written atomically: a bad one is not ours
        _commit(folder, manifest)
        state = "rolled forward"
    now = _dt.datetime.now().timestamp()
    for stray in folder.iterdir():
        if not _TEMP.match(stray.name):
            continue
        # A set's temporary files (and its pending manifest's) are written under the folder
        # lock held here: left over. Another writer's (write_atomic of trials.csv) may be in
        # use by a live process: removed only once it is a minute old.
        ours = _OURS.match(stray.name) or stray.name.startswith(f".{PENDING}.")
        with contextlib.suppress(OSError):
            if ours or now - stray.stat().st_mtime > 60:
                stray.unlink(missing_ok=True)
                state = "cleaned" if state == "complete" else state
    return state


def check_file_set(folder: str | Path, names: Iterable[str] | None = None) -> dict[str, Any]:
    """The manifest of a complete set, or a :class:`FileSafetyError` naming what is torn.

    Args:
        folder: The set's folder.
        names: Check only these files (default every file of the manifest).
    """
    folder = Path(folder)
    if (folder / PENDING).exists():
        raise FileSafetyError(
            f"the outputs in {str(folder)!r} were being replaced when their writer stopped "
            f"({PENDING} is there); run the same `servogym tune` with --resume to finish them."
        )
    if not (folder / MANIFEST).exists():
        raise FileSafetyError(f"{str(folder)!r} has no {MANIFEST}.")
    manifest = read_manifest(folder / MANIFEST)
    files = manifest["files"]
    for name in files if names is None else names:
        entry = files.get(name)
        if entry is None:
            raise FileSafetyError(f"{name} is not listed in {str(folder / MANIFEST)!r}.")
        path = folder / name
        if not path.exists():
            raise FileSafetyError(f"{name}, listed in {MANIFEST}, is missing.")
        if _sha256_file(path) != entry["sha256"]:
            raise FileSafetyError(
                f"{name} does not match {MANIFEST} (trial {manifest.get('trial')!r}): the "
                f"set is torn or the file was changed after it was written."
            )
    return manifest


def check_against_manifest(path: str | Path) -> None:
    """Refuse a file whose folder's manifest lists it with another hash (or is pending)."""
    path = Path(path)
    folder = path.parent
    if (folder / PENDING).exists() and path.name in read_manifest(folder / PENDING)["files"]:
        check_file_set(folder)  # raises the pending message
    if (folder / MANIFEST).exists() and path.name in read_manifest(folder / MANIFEST)["files"]:
        check_file_set(folder, [path.name])
