"""Parker Compumotor 6000-series servo (6250, 6K) PIV&F filter, per docs/chips/parker6k.md."""

from servogym.chips._paramfile import ParamFile
from servogym.chips.parker6k._export import (
    FORMATS,
    export,
    from_command_file,
    from_json,
    import_params,
    read_header,
    to_command_file,
    to_json,
)
from servogym.chips.parker6k._kernel import (
    S_TRIPPED,
    STATE_SIZE,
    new_state,
    parker6k_run,
    parker6k_step,
)
from servogym.chips.parker6k._params import (
    CHIP_MODELS,
    FIELDS,
    GAIN_FIELDS,
    MAX_GAIN_SETS,
    SPEC_VERSION,
    SSFR_PERIOD_US,
    TABLE,
    GainSet,
    Parker6kAssumptions,
    Parker6kModel,
    Parker6kParams,
    get_model,
    parameter_space,
)
from servogym.chips.parker6k._profile import Parker6kProfile, ProfileAssumptions
from servogym.chips.parker6k._profile import move as profile_move
from servogym.chips.parker6k._reference import Parker6kReferenceFilter

__all__ = [
    "CHIP_MODELS",
    "FIELDS",
    "FORMATS",
    "GAIN_FIELDS",
    "MAX_GAIN_SETS",
    "SPEC_VERSION",
    "SSFR_PERIOD_US",
    "STATE_SIZE",
    "S_TRIPPED",
    "TABLE",
    "GainSet",
    "ParamFile",
    "Parker6kAssumptions",
    "Parker6kModel",
    "Parker6kParams",
    "Parker6kProfile",
    "Parker6kReferenceFilter",
    "ProfileAssumptions",
    "export",
    "from_command_file",
    "from_json",
    "get_model",
    "import_params",
    "new_state",
    "parameter_space",
    "parker6k_run",
    "parker6k_step",
    "profile_move",
    "read_header",
    "to_command_file",
    "to_json",
]

from servogym.chips.parker6k._family import PARKER6K, StoredSetActions  # listed by the registry

__all__ += ["PARKER6K", "StoredSetActions"]
