"""Exact emulations of servo-chip filters, their legal parameter ranges, profiles and exports.

Every chip family is one :class:`ChipFamily` object, listed by :func:`families`; its registers
are one declarative table (:mod:`servogym.chips._registers`); :func:`get_chip` finds a model
by name.
"""

from servogym.chips._axes import (
    MultiAxisParams,
    export_axes,
    import_axes,
    load_axes,
    max_axes,
    save_axes,
)
from servogym.chips._family import (
    FAMILY_CODES,
    ChipFamily,
    Move,
    all_models,
    families,
    family_of,
    get_chip,
)
from servogym.chips._load import FILE_FORMATS, detect_format, load_params_file, read_params_file
from servogym.chips._space import ParameterError, ParameterSpace, ParamSpec

__all__ = [
    "FAMILY_CODES",
    "FILE_FORMATS",
    "ChipFamily",
    "Move",
    "MultiAxisParams",
    "ParamSpec",
    "ParameterError",
    "ParameterSpace",
    "all_models",
    "detect_format",
    "export_axes",
    "families",
    "family_of",
    "get_chip",
    "import_axes",
    "load_axes",
    "load_params_file",
    "max_axes",
    "read_params_file",
    "save_axes",
]
