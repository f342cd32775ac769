"""Every plant family, registered in one place, and their JSON and Markdown descriptions."""

from __future__ import annotations

import dataclasses
import difflib
from typing import Any

from servogym.plants._base import PlantFamily, PlantParam, _fmt
from servogym.plants._families import ArmFamily, RotaryFamily, TwoMassFamily, VerticalAxisFamily
from servogym.plants._multi import MULTI_PLANTS

PLANTS: dict[str, PlantFamily] = {
    f.name: f for f in (RotaryFamily(), TwoMassFamily(), VerticalAxisFamily(), ArmFamily())
}
"""The plant families by name: ``"rotary"``, ``"two-mass"``, ``"vertical-axis"``, ``"arm"``."""


def get_plant(name: str) -> PlantFamily:
    """The plant family called ``name``.

    Raises:
        KeyError: if there is no such family; the message lists the families and the
            closest names.
    """
    try:
        return PLANTS[name]
    except (KeyError, TypeError):
        if isinstance(name, str) and name in MULTI_PLANTS:
            multi = MULTI_PLANTS[name]
            raise KeyError(
                f"{name!r} is a multi-axis plant ({multi.n_axes} axes: {', '.join(multi.axes)}); "
                f"this takes a single-axis plant family: {', '.join(PLANTS)} (multi-axis plants "
                "run today in servogym.sim.MultiServoLoop; docs/plants.md, Multi-axis plants)"
            ) from None
        close = difflib.get_close_matches(str(name), list(PLANTS), n=3)
        hint = f" Did you mean {', '.join(close)}?" if close else ""
        raise KeyError(
            f"no plant family {name!r}; the plant families are {', '.join(PLANTS)}.{hint}"
        ) from None


def describe_plants() -> list[dict[str, Any]]:
    """A JSON-ready description of every family and parameter (for ``servogym plants``).

    Returns:
        One dict per family, in registry order: ``name``, ``description``, ``joint_unit`` and
        ``params``, a list of dicts with the :class:`PlantParam` fields plus ``type``
        (``"float"`` or ``"int"``).
    """
    return [
        {
            "name": family.name,
            "description": family.description,
            "joint_unit": family.joint_unit,
            "params": [{**dataclasses.asdict(p), "type": p.type_name} for p in family.params],
        }
        for family in PLANTS.values()
    ]


def describe_multi_plants() -> list[dict[str, Any]]:
    """As :func:`describe_plants`, for the multi-axis families (:data:`MULTI_PLANTS`), each
    with ``n_axes``, ``axes`` (the axis names, in axis order) and ``joint_units``."""
    return [
        {
            "name": family.name,
            "description": family.description,
            "joint_unit": family.joint_unit,
            "n_axes": family.n_axes,
            "axes": list(family.axes),
            "joint_units": list(family.joint_units),
            "params": [{**dataclasses.asdict(p), "type": p.type_name} for p in family.params],
        }
        for family in MULTI_PLANTS.values()
    ]


TABLE_HEADER = (
    "| Parameter | Type (Unit) | Nominal | Range | Sampled | Distribution | Randomised "
    "| Description |"
)


def param_row(p: PlantParam) -> str:
    """The Markdown table row ``docs/plants.md`` has for a parameter."""
    cells = [
        f"`{p.name}`",
        f"{p.type_name} ({p.unit})",
        _fmt(p.nominal),
        f"{_fmt(p.low)} .. {_fmt(p.high)}",
        f"{_fmt(p.sample_low)} .. {_fmt(p.sample_high)}",
        p.distribution,
        "yes" if p.randomised else "no",
        p.doc,
    ]
    return "| " + " | ".join(cells) + " |"


def plant_table_markdown(family: PlantFamily) -> str:
    """The parameter table of a family, as in ``docs/plants.md``."""
    lines = [TABLE_HEADER, "|" + "---|" * 8]
    lines += [param_row(p) for p in family.params]
    return "\n".join(lines)
