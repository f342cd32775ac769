"""PMD Navigator / Pilot / Magellan servo filter (MC2100 ... MC58000), per docs/chips/pmd.md."""

from servogym.chips._paramfile import ParamFile
from servogym.chips.pmd import _params
from servogym.chips.pmd._export import (
    FORMATS,
    export,
    from_json,
    import_params,
    to_json,
)
from servogym.chips.pmd._params import (
    CHIP_MODELS,
    FIELDS,
    SPEC_VERSION,
    PMDAssumptions,
    PMDChipModel,
    PMDParams,
    get_model,
    parameter_space,
)
from servogym.chips.pmd._profile import (
    Profile,
    ProfileAssumptions,
    move,
    s_curve,
    trapezoidal,
    velocity_contouring,
)

__all__ = [
    "CHIP_MODELS",
    "FIELDS",
    "FORMATS",
    "SPEC_VERSION",
    "TABLE",
    "PMDAssumptions",
    "PMDChipModel",
    "PMDParams",
    "ParamFile",
    "Profile",
    "ProfileAssumptions",
    "export",
    "from_json",
    "get_model",
    "import_params",
    "move",
    "parameter_space",
    "s_curve",
    "to_json",
    "trapezoidal",
    "velocity_contouring",
]

from servogym.chips.pmd._family import PMD  # the family object the registry lists

__all__ += ["PMD"]

TABLE = _params.TABLE
"""The PMD register table (:mod:`servogym.chips._registers`)."""
