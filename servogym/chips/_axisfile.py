"""What every family's multi-axis files share: the axis list of a header, and the JSON layout of
the parameter sets of several axes of one controller.

The multi-axis JSON file (``format_version`` 1)::

    {"format": "servogym-axes", "format_version": 1, "chip_family": "pmd",
     "chip_model": "MC2300", "spec_version": "...", "assumptions": {...},
     "axes": [{"axis": 1, "params": {...}}, {"axis": 2, "params": {...}}],
     "created": "...", "servogym_version": "...", "metrics": {...}, "notes": {...},
     "checksum": "sha256:..."}                  # metrics and notes optional

``params`` of each entry is the ``params`` object of the family's single-axis file
(:mod:`servogym.chips._paramfile`); a PMAC file names its entries by ``motor``.
"""

from __future__ import annotations

import datetime as _dt
import os
import re
import sys
from collections.abc import Iterable, Mapping
from typing import Any

from servogym import __version__
from servogym.chips._paramfile import (
    FILE_FORMAT,
    FILE_FORMAT_VERSION,
    FileSchema,
    ParamFile,
    _expect,
    _load,
    created_text,
    finish_json,
)
from servogym.chips._space import ParameterError

_PACKAGE_DIR = os.path.dirname(os.path.dirname(os.path.abspath(__file__))) + os.sep
"""The servogym package's folder (with the separator): frames in it are not the user's."""


def user_stacklevel() -> int:
    """The ``stacklevel`` that makes a warning raised by this function's caller point at the
    first line outside servogym (the user's call of ``import_axes``, ``load_axes``, ...),
    however many servogym functions lie between."""
    frame = sys._getframe(1)  # the function that calls warnings.warn: stacklevel 1
    level = 1
    while frame.f_back is not None and frame.f_code.co_filename.startswith(_PACKAGE_DIR):
        frame = frame.f_back
        level += 1
    return level


AXES_FORMAT = "servogym-axes"
"""Value of the ``format`` key of a multi-axis JSON parameter file."""


def plural(noun: str) -> str:
    """``"axes"`` for ``"axis"``, ``"motors"`` for ``"motor"``."""
    return "axes" if noun == "axis" else noun + "s"


def axes_text(numbers: Iterable[int]) -> str:
    """The axis list of a header: ``"1, 2"``."""
    return ", ".join(str(n) for n in numbers)


_NUMBER_LIST = re.compile(r"^\s*\d+(\s*,\s*\d+)*\s*$")


def header_axes(header: Mapping[str, Any], noun: str = "axis") -> tuple[int, ...] | None:
    """The axis numbers a file's header names (``axes: 1, 2`` or, one axis, ``axis: 2``).

    Args:
        header: The header's ``key: value`` entries.
        noun: ``"axis"`` or ``"motor"`` (PMAC): the keys are ``motor`` and ``motors``.

    Returns:
        The numbers in file order, or None when the header names none.

    Raises:
        ParameterError: for an entry that is not a list of numbers, or names one twice.
    """
    for key in (plural(noun), noun):
        text = header.get(key)
        if text is None:
            continue
        if not _NUMBER_LIST.match(str(text)):
            raise ParameterError(
                f"the header's '{key}: {text}' must list {noun} numbers such as "
                f"'{plural(noun)}: 1, 2'."
            )
        numbers = tuple(int(n) for n in str(text).split(","))
        if len(set(numbers)) != len(numbers):
            raise ParameterError(f"the header's '{key}: {text}' names an {noun} twice.")
        return numbers
    return None


def check_header_axes(
    named: tuple[int, ...] | None, found: Iterable[int], noun: str = "axis"
) -> None:
    """Refuse a file whose header names other axes than its commands set."""
    found = tuple(sorted(found))
    if named is not None and tuple(sorted(named)) != found:
        raise ParameterError(
            f"the header names {plural(noun)} {axes_text(sorted(named))} but the file sets the "
            f"registers of {plural(noun)} {axes_text(found) or 'none'}; a multi-axis file sets "
            f"every {noun} its header names, and no other."
        )


# --------------------------------------------------------------------------------------
# JSON
# --------------------------------------------------------------------------------------


def _required_keys(schema: FileSchema) -> tuple[str, ...]:
    """The single-axis file's keys with ``axes`` for ``params`` and no extra keys."""
    keys = [k for k in schema.required_keys if k not in schema.extra_keys]
    return tuple("axes" if k == "params" else k for k in keys)


def write_axes_json(
    schema: FileSchema,
    axes: Mapping[int, Any],
    assumptions: Any = None,
    *,
    noun: str = "axis",
    metrics: Mapping[str, Any] | None = None,
    notes: Mapping[str, Any] | None = None,
    created: str | _dt.datetime | None = None,
) -> str:
    """The multi-axis JSON file of the sets of several axes (validated each, in axis order).

    Args:
        schema: The family's JSON file schema.
        axes: Axis (PMAC: motor) number -> parameter set, one chip model.
        assumptions: The switches the sets were tuned under; default all defaults.
        noun: ``"axis"`` or ``"motor"``: the key that numbers each entry.
        metrics: Optional results to keep with the sets.
        notes: Optional free-form notes.
        created: Creation time; default now (UTC).
    """
    sets = {n: schema.legal_params(p) for n, p in sorted(axes.items())}
    a = schema.legal_assumptions(assumptions)
    model = next(iter(sets.values())).model
    doc: dict[str, Any] = {
        "format": AXES_FORMAT,
        "format_version": FILE_FORMAT_VERSION,
        "chip_family": schema.family,
        "chip_model": model,
        "spec_version": schema.spec_version,
        "assumptions": a.to_dict(),
        "axes": [{noun: n, "params": p.to_dict()} for n, p in sets.items()],
        "created": created_text(created),
        "servogym_version": __version__,
    }
    return finish_json(doc, metrics, notes)


def read_axes_json(
    schema: FileSchema, text: str | bytes, model: Any = None, *, noun: str = "axis"
) -> tuple[dict[int, Any], ParamFile[Any, Any]]:
    """Read a multi-axis JSON file (or a single-axis one, as axis 1).

    Args:
        schema: The family's JSON file schema.
        text: The file content.
        model: Chip model; if given it must be the file's ``chip_model``.
        noun: ``"axis"`` or ``"motor"``: the key that numbers each entry.

    Returns:
        Axis number -> parameter set, and a :class:`ParamFile` whose ``params`` is the
        first axis's set, with the file's assumptions and provenance.

    Raises:
        ParameterError: for anything :meth:`FileSchema.read` refuses, an entry without its
            number or with another key, a number given twice, or a model that disagrees.
    """
    doc = _load(text)
    if doc.get("format") == FILE_FORMAT:  # a single-axis file: axis 1
        loaded = schema.read(text)
        sets = {1: loaded.params}
    else:
        loaded, sets = _read_axes_doc(schema, doc, noun)
    schema.same_model(model, loaded.params.model)
    return sets, loaded


def _read_axes_doc(
    schema: FileSchema, doc: dict[str, Any], noun: str
) -> tuple[ParamFile[Any, Any], dict[int, Any]]:
    schema.check_header(
        doc,
        fmt=AXES_FORMAT,
        expected=f"{AXES_FORMAT!r} (a servogym multi-axis parameter file) or {FILE_FORMAT!r} "
        f"(one axis)",
        required=_required_keys(schema),
    )
    chip = schema.get_model(_expect(doc, "chip_model", str, f"a {schema.title} chip model name"))
    entries = _expect(doc, "axes", list, f"a non-empty JSON list of {{{noun!r}: n, 'params'}}")
    if not entries:
        raise ParameterError(f"axes must list at least one {noun}; got axes=[].")
    sets: dict[int, Any] = {}
    for i, entry in enumerate(entries):
        where = f"axes[{i}]"
        if not isinstance(entry, dict) or set(entry) != {noun, "params"}:
            got = sorted(entry) if isinstance(entry, dict) else type(entry).__name__
            raise ParameterError(
                f"{where} must be a JSON object with exactly the keys {noun!r} and 'params'; "
                f"got {got}."
            )
        number = entry[noun]
        if type(number) is not int:
            raise ParameterError(f"{where}.{noun} must be an integer; got {noun}={number!r}.")
        if number in sets:
            raise ParameterError(
                f"{where}: {noun} {number} is listed twice; a file gives each {noun} once."
            )
        values = schema.complete_values(entry["params"], chip, f"{where}.params")
        try:
            sets[number] = schema.params_type.from_dict(values)
        except ParameterError as exc:
            raise ParameterError(f"{where} ({noun} {number}): {exc}") from None
    # import_axes, load_axes: the warning points at the caller's line
    assumptions = schema.check_tail(doc, stacklevel=user_stacklevel() + 1)
    provenance = {k: v for k, v in doc.items() if k not in ("axes", "assumptions", "checksum")}
    first = sets[min(sets)]
    return ParamFile(params=first, assumptions=assumptions, provenance=provenance), sets
