"""The chip registry: every family and chip model by name.

The families' common interface is :class:`ChipFamily` (:mod:`servogym.chips._base`); each
family package defines one object of it. This module imports the family packages (lazily,
on the first look-up) and never the other way round: the family packages import
:mod:`servogym.chips._base` only, so there is no import circle through the registry.
"""

from __future__ import annotations

from typing import Any

from servogym.chips._base import FAMILY_CODES, LATENCY_FRACTIONS, ChipFamily, Move
from servogym.chips._space import resolve_name

__all__ = [
    "FAMILY_CODES",
    "LATENCY_FRACTIONS",
    "ChipFamily",
    "Move",
    "all_models",
    "families",
    "family_of",
    "get_chip",
]

_FAMILIES: dict[str, ChipFamily] = {}


def families() -> dict[str, ChipFamily]:
    """Every chip family by name (Parker 6000, PMAC, PMD: the order ``servogym chips`` lists)."""
    if not _FAMILIES:
        _load_builtin()
    return dict(_FAMILIES)


def all_models() -> dict[str, ChipFamily]:
    """Every chip model name, mapped to its family."""
    return {m: f for f in families().values() for m in f.models}


def get_chip(model: str) -> tuple[ChipFamily, str]:
    """The family and canonical name of a chip model (case-insensitive), or a clear error."""
    models = all_models()
    key = resolve_name(model, models, "chip model")
    return models[key], key


def family_of(params: Any) -> ChipFamily:
    """The family a parameter set belongs to."""
    for fam in families().values():
        if isinstance(params, fam.params_type):
            return fam
    raise TypeError(f"{type(params).__name__} is not a parameter set of any chip family")


def _load_builtin() -> None:
    # Imported here, not at the top: servogym._files imports servogym.chips, and the
    # families' exporters import servogym._files.
    from servogym.chips.parker6k import PARKER6K
    from servogym.chips.pmac import PMAC
    from servogym.chips.pmd import PMD

    _FAMILIES.update({f.name: f for f in (PARKER6K, PMAC, PMD)})
