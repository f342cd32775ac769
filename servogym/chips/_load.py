"""One loader for every parameter file servogym writes, whatever the family and format.

Every command that takes a parameter file (``simulate --params``, ``tune --warm-start``,
``evaluate --fixed``, ``export``, ``check``) calls :func:`read_params_file`, so a set read
back from a controller can be simulated, tuned from and re-exported. The format is named
(``fmt``) or detected from the content (:func:`detect_format`).
"""

from __future__ import annotations

import re
from pathlib import Path
from typing import Any

from servogym.chips._family import ChipFamily, families, get_chip
from servogym.chips._paramfile import ParamFile, strict_json
from servogym.chips._space import ParameterError

FILE_FORMATS: dict[str, str] = {
    "json": "pmd, pmac, parker6k",
    "cmotion": "pmd",
    "host": "pmd",
    "ivar": "pmac",
    "6250": "parker6k",
    "6k": "parker6k",
}
"""Every format servogym writes, and the chip family (families) it belongs to."""

_C_CALL = re.compile(r"\bPMD[A-Z]\w*\s*\(")
_HOST = re.compile(r"(?m)^\s*0[xX][0-9a-fA-F]{1,2}\s+[A-Za-z]\w*\s+axis\s*=")
_PARKER = re.compile(r"(?im)^[^;]*?\b\d*\s*(SGP|SGSET|SSFR|SMPER|SGILIM|SOFFS)")
_PARKER_PREFIX = re.compile(
    r"(?im)^[^;]*?(?:^|:)\s*\d+\s*(SGP|SGI|SGV|SGVF|SGAF|SGILIM|SOFFS|SMPER)"
)
_PARKER_FORM = re.compile(r"(?m)^\s*;\s*form\s*:\s*(6250|6k)\s*$")
_IVAR = re.compile(r"(?i)(?<![\w$.])I\s*\d+\s*=")


def detect_format(text: str) -> str:
    """The format of a parameter file's content: a key of :data:`FILE_FORMATS`.

    Raises:
        ParameterError: when the content is empty or matches none of them.
    """
    stripped = text.lstrip("\ufeff \t\r\n")
    if not stripped:
        raise ParameterError("the parameter file is empty; it holds no parameter set.")
    if stripped.startswith("{"):
        return "json"
    if _C_CALL.search(text):
        return "cmotion"
    if _HOST.search(text):
        return "host"
    if _PARKER.search(text):
        form = _PARKER_FORM.search(text)
        if form:
            return form.group(1)
        return "6k" if _PARKER_PREFIX.search(text) else "6250"
    if _IVAR.search(text):
        return "ivar"
    raise ParameterError(
        "cannot tell the format of the parameter file: it is none of JSON, C-Motion calls, "
        "PMD host commands, PMAC I-variables or a Parker command file; name it with "
        f"--format, one of {', '.join(FILE_FORMATS)}."
    )


def _check_fmt(fmt: Any) -> str:
    name = fmt.lower() if isinstance(fmt, str) else fmt
    if name not in FILE_FORMATS:
        import difflib

        close = difflib.get_close_matches(str(fmt), list(FILE_FORMATS), n=1)
        hint = f" Did you mean {close[0]!r}?" if close else ""
        listed = ", ".join(f"{f} ({fam})" for f, fam in FILE_FORMATS.items())
        raise ParameterError(f"--format must be one of {listed}; got --format {fmt!r}.{hint}")
    return name


def _family_of_json(text: str) -> ChipFamily:
    try:
        doc = strict_json(text)
    except ValueError as exc:
        if isinstance(exc, ParameterError):
            raise
        raise ParameterError(f"a parameter file must be JSON; invalid JSON: {exc}.") from None
    name = doc.get("chip_family") if isinstance(doc, dict) else None
    known = families()
    if name not in known:
        raise ParameterError(
            f"chip_family must be one of {', '.join(known)}; got chip_family={name!r}."
        )
    return known[name]


def load_params_file(
    text: str,
    fmt: str | None = None,
    model: str | None = None,
    axis: int | None = None,
) -> ParamFile[Any, Any]:
    """A parameter set from the text of any file servogym writes.

    Args:
        text: The file content.
        fmt: One of :data:`FILE_FORMATS`; default detected from the content.
        model: Chip model, for files that do not name one (a controller's I-variable file,
            a host-command list without header); if both name one they must agree.
        axis: Axis (PMAC: motor) to read from a file that sets several; default the
            header's, else the only one. Not for JSON and PMD files (one axis each).

    Returns:
        A :class:`ParamFile`: the validated set, the assumptions (the file's, else the
        family's defaults) and the provenance (a JSON file's entries, or the header's
        ``key: value`` lines), with ``"file_format"`` added.

    Raises:
        ParameterError: naming what is wrong, for anything the format's importer refuses.
    """
    fmt = detect_format(text) if fmt is None else _check_fmt(fmt)
    if fmt == "json":
        family = _family_of_json(text)
    else:
        family = families()[FILE_FORMATS[fmt]]
    if model is not None:
        owner, model = get_chip(model)
        if owner.name != family.name:
            raise ParameterError(
                f"--chip {model} is a {owner.name} model, but the file is a {family.name} "
                f"file ({fmt}); pass a {family.name} model or leave --chip out."
            )
    if fmt == "json":
        if axis is not None:
            raise ParameterError(
                f"--axis applies to files that set several axes; a JSON file holds one set "
                f"(got --axis {axis})."
            )
        loaded = family.from_json(text)
        if model is not None and loaded.params.model != model:
            raise ParameterError(
                f"--chip {model} disagrees with the file's chip_model {loaded.params.model}; "
                f"pass --chip {loaded.params.model} or leave --chip out."
            )
        return ParamFile(
            loaded.params, loaded.assumptions, {**loaded.provenance, "file_format": fmt}
        )
    module = family.export_module
    header = module.read_header(text)
    kw: dict[str, Any] = {}
    if axis is not None:
        if family.name == "pmd":
            raise ParameterError(
                f"--axis does not apply to a PMD file: it loads the one axis its calls "
                f"address (got --axis {axis})."
            )
        kw["motor" if family.name == "pmac" else "axis"] = axis
    params = module.import_params(text, fmt, model, **kw)
    assumptions = header.get("assumptions") or family.default_assumptions()
    provenance = {k: v for k, v in header.items() if isinstance(v, str)}
    provenance.update(file_format=fmt, chip_family=family.name, chip_model=params.model)
    return ParamFile(params, assumptions, provenance)


def read_params_file(
    path: str | Path,
    fmt: str | None = None,
    model: str | None = None,
    axis: int | None = None,
    *,
    what: str = "the parameter file",
) -> ParamFile[Any, Any]:
    """:func:`load_params_file` of a file on disk, with one-line errors naming it.

    A file listed in its folder's ``manifest.json`` (the outputs of ``servogym tune``) must
    match it: a torn or half-replaced set is refused.

    Args:
        path: The file.
        fmt: As for :func:`load_params_file`.
        model: As for :func:`load_params_file`.
        axis: As for :func:`load_params_file`.
        what: The option that named the file, for messages (``"--params"``).
    """
    from servogym._files import check_against_manifest
    from servogym._input import read_text

    path = Path(path)
    if path.is_dir():
        raise ParameterError(f"{what} {str(path)!r} is a folder; give a parameter file.")
    text = read_text(path, what)  # regular files only, bounded
    try:
        check_against_manifest(path)
        return load_params_file(text, fmt, model, axis)
    except ParameterError as exc:
        message = str(exc)
        if model is not None and (what.startswith("--") or what.isupper()):  # a command's --chip
            message = re.sub(
                r"\bor model=None( to use the header)?", "or leave --chip out", message
            )
            message = re.sub(r"(?<![\w-])model=", "--chip ", message)
        raise type(exc)(f"{what} {str(path)!r}: {message}") from None
