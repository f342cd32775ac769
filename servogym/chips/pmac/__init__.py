"""Delta Tau Turbo PMAC2 / Geo Brick LV PID + feed-forward + notch filter, per docs/chips/pmac.md.

The family object :data:`PMAC` is what the chip registry lists as ``"pmac"``.
"""

from servogym.chips._paramfile import ParamFile
from servogym.chips.pmac._export import (
    FILE_EXTENSIONS,
    FORMATS,
    export,
    from_ivar,
    from_json,
    import_params,
    read_header,
    to_ivar,
    to_json,
)
from servogym.chips.pmac._kernel import S_TRIPPED, STATE_SIZE, new_state, pmac_run, pmac_step
from servogym.chips.pmac._notch import (
    FilterDesign,
    FrequencyResponse,
    controller_response,
    design_low_pass,
    design_notch,
    notch_response,
    plot_frequency_response,
)
from servogym.chips.pmac._params import (
    ASSUMPTION_CHOICES,
    ASSUMPTION_IDS,
    CHIP_MODELS,
    FIELDS,
    I_VARIABLES,
    MASTER_CLOCK_HZ,
    SPEC_VERSION,
    TABLE,
    PMACAssumptions,
    PMACChipModel,
    PMACParams,
    coefficient_raw,
    coefficient_value,
    get_model,
    ivar_name,
    parameter_space,
)
from servogym.chips.pmac._profile import Profile, move
from servogym.chips.pmac._reference import PMACReferenceFilter

__all__ = [
    "ASSUMPTION_CHOICES",
    "ASSUMPTION_IDS",
    "CHIP_MODELS",
    "FIELDS",
    "FILE_EXTENSIONS",
    "FORMATS",
    "I_VARIABLES",
    "MASTER_CLOCK_HZ",
    "SPEC_VERSION",
    "STATE_SIZE",
    "S_TRIPPED",
    "TABLE",
    "FilterDesign",
    "FrequencyResponse",
    "PMACAssumptions",
    "PMACChipModel",
    "PMACParams",
    "PMACReferenceFilter",
    "ParamFile",
    "Profile",
    "coefficient_raw",
    "coefficient_value",
    "controller_response",
    "design_low_pass",
    "design_notch",
    "export",
    "from_ivar",
    "from_json",
    "get_model",
    "import_params",
    "ivar_name",
    "move",
    "new_state",
    "notch_response",
    "parameter_space",
    "plot_frequency_response",
    "pmac_run",
    "pmac_step",
    "read_header",
    "to_ivar",
    "to_json",
]

from servogym.chips.pmac._family import PMAC  # the family object the registry lists

__all__ += ["PMAC"]
