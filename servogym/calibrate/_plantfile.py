"""``plant.json``: a plant instance with provenance, as ``servogym calibrate`` writes it.

Every command that takes a plant (``tune``, ``simulate``, ``check``) reads it with
``--plant-file``, the envs with ``plant_file=``; its values are the plant's fixed values
(``--plant-param`` on top). The file holds every parameter of its family, where each value
came from (``fitted``, ``fixed``, ``nominal``), the fit's figures, and a checksum over the
rest, as servogym's JSON parameter files do (docs/files.md): an edited or cut file is refused.
"""

from __future__ import annotations

import dataclasses
import datetime as _dt
import json
from collections.abc import Mapping
from pathlib import Path
from typing import Any

from servogym.chips._space import ParameterError

PLANT_FILE_FORMAT = "servogym-plant"
"""The ``format`` entry of a plant file."""

PLANT_FILE_VERSION = 1
"""The ``version`` entry this servogym writes and reads."""


class PlantFileError(ParameterError):
    """A plant file that cannot be read (the message names the file and the rule)."""


@dataclasses.dataclass(frozen=True)
class PlantFile:
    """A plant instance read from a plant file.

    Attributes:
        family: Plant family name.
        values: Every parameter's value, validated against the family's legal ranges.
        sources: ``name -> "fitted" | "fixed" | "nominal"``.
        provenance: What produced the file (trace, register set, chip, fit figures).
    """

    family: str
    values: dict[str, float]
    sources: dict[str, str]
    provenance: dict[str, Any]


def plant_document(
    family: str,
    values: Mapping[str, float],
    sources: Mapping[str, str],
    provenance: Mapping[str, Any],
    fitted: Mapping[str, Any] | None = None,
) -> dict[str, Any]:
    """The JSON document of a plant file, checksum last."""
    from servogym import __version__
    from servogym._files import json_checksum

    doc: dict[str, Any] = {
        "format": PLANT_FILE_FORMAT,
        "version": PLANT_FILE_VERSION,
        "plant_family": family,
        "values": {k: float(v) if not isinstance(v, int) else v for k, v in values.items()},
        "sources": dict(sources),
        "fitted": dict(fitted or {}),
        "provenance": {
            "servogym_version": __version__,
            "created": _dt.datetime.now(_dt.UTC).isoformat(timespec="seconds"),
            **provenance,
        },
    }
    doc["checksum"] = json_checksum(doc)
    return doc


def write_plant_file(path: str | Path, doc: Mapping[str, Any]) -> Path:
    """Write a plant document atomically (``servogym._files.write_atomic``)."""
    from servogym._files import write_atomic

    return write_atomic(path, json.dumps(doc, indent=2, allow_nan=False) + "\n")


def read_plant_file(
    path: str | Path, family: str | None = None, *, what: str = "--plant-file"
) -> PlantFile:
    """A plant file, checked: format, version, checksum, family and every value's range.

    Args:
        path: The file.
        family: The plant family the command runs (``--plant``); the file's must agree.
        what: The option that named the file, for messages.

    Raises:
        PlantFileError: one line naming the file and what is wrong.
    """
    from servogym._files import json_checksum
    from servogym._input import InputError, read_json
    from servogym.plants import PlantParameterError, get_plant

    path = Path(path)
    name = f"{what} {str(path)!r}"
    try:
        doc = read_json(path, what)
    except InputError as exc:
        raise PlantFileError(str(exc)) from None
    if not isinstance(doc, dict) or doc.get("format") != PLANT_FILE_FORMAT:
        got = doc.get("format") if isinstance(doc, dict) else type(doc).__name__
        raise PlantFileError(
            f"{name} is not a plant file: its format must be {PLANT_FILE_FORMAT!r} (written "
            f"by servogym calibrate); got format={got!r}."
        )
    if doc.get("version") != PLANT_FILE_VERSION:
        raise PlantFileError(
            f"{name}: version must be {PLANT_FILE_VERSION}; got version={doc.get('version')!r}."
        )
    body = {k: v for k, v in doc.items() if k != "checksum"}
    if "checksum" not in doc or json_checksum(body) != doc["checksum"]:
        what_wrong = "has no checksum" if "checksum" not in doc else "checksum does not match"
        raise PlantFileError(
            f"{name}: the file {what_wrong} its content: it was edited or cut after it was "
            f"written. Calibrate again, or give changed values with --plant-param."
        )
    fam_name = doc.get("plant_family")
    try:
        fam = get_plant(str(fam_name))
    except (KeyError, PlantParameterError, ValueError) as exc:
        raise PlantFileError(f"{name}: {exc.args[0] if exc.args else exc}") from None
    if family is not None and get_plant(family).name != fam.name:
        raise PlantFileError(
            f"{name} is a {fam.name!r} plant, but the command runs --plant {family}; pass "
            f"--plant {fam.name} or calibrate a {family!r} plant."
        )
    values = doc.get("values")
    if not isinstance(values, dict):
        raise PlantFileError(f"{name}: 'values' must be an object of parameter values.")
    try:
        checked = fam.validate(values)
    except PlantParameterError as exc:
        raise PlantFileError(f"{name}: {exc}") from None
    return PlantFile(fam.name, dict(checked), dict(doc.get("sources") or {}),
                     dict(doc.get("provenance") or {}))  # fmt: skip


def plant_values(
    path: str | Path | None,
    family: str,
    plant_params: Mapping[str, float] | None = None,
    *,
    drop: tuple[str, ...] = (),
) -> dict[str, float]:
    """The fixed plant values of a command: a plant file's, then ``plant_params`` on top.

    Args:
        path: The plant file, or ``None`` (then only ``plant_params``).
        family: The command's plant family (``--plant``).
        plant_params: ``--plant-param`` values, which override the file's.
        drop: Names the command draws instead (``--plant-range``): left out.
    """
    out: dict[str, float] = {}
    if path is not None:
        out.update(read_plant_file(path, family).values)
    out.update(plant_params or {})
    for name in drop:
        out.pop(name, None)
    return out


_merged = plant_values


def env_plant_values(
    plant_file: str | Path | None,
    plant: str,
    scenario: Any,
    plant_values: Mapping[str, float] | None,
    plant_range: Mapping[str, Any] | None,
) -> Mapping[str, float] | None:
    """The envs' ``plant_values``: a ``plant_file``'s values, ``plant_values`` on top, the
    names in ``plant_range`` left out (drawn); ``plant_values`` itself without a file.

    Raises:
        ValueError: a ``plant_file`` together with a ``scenario`` (which fixes the plant).
        PlantFileError: a file that cannot be read (:func:`read_plant_file`).
    """
    if plant_file is None:
        return plant_values
    if scenario is not None:
        raise ValueError(
            "give plant_file or a scenario, not both (put the file's values into "
            "Scenario.plant_values: servogym.calibrate.read_plant_file(path).values)"
        )
    return _merged(plant_file, plant, plant_values, drop=tuple(plant_range or ()))
