"""Autotuners for chip parameters: Optuna samplers and classical procedures (docs/autotune.md).

A :class:`TuneProblem` (scenario, search space, plant instances, constraints, objectives) is
tuned by a registered tuner within a budget of evaluations; every trial is stored in an
Optuna study. :func:`tune` is the main job behind ``servogym tune``.

Example:
    >>> from servogym.autotune import TuneConfig, tune
    >>> result, summary = tune(TuneConfig(chip="MC2100", plant="rotary", out="runs/r",
    ...                                   budget=200, tuner="tpe"))  # doctest: +SKIP
"""

from servogym.autotune._classical import (
    ModelBasedTuner,
    RelayTuner,
    VendorStepTuner,
    astrom_hagglund,
    identify_rigid_axis,
)
from servogym.autotune._gains import (
    GAIN_MAPS,
    GainMap,
    Parker6kGainMap,
    PMACGainMap,
    PMDGainMap,
    ServoDesign,
    design_registers,
    gain_map_for,
    register_gain_map,
)
from servogym.autotune._job import (
    StudyResult,
    TuneConfig,
    read_param_file,
    run_study,
    tune,
)
from servogym.autotune._problem import (
    DEFAULT_MULTI_OBJECTIVES,
    OBJECTIVES,
    Constraints,
    Outcome,
    TuneProblem,
)
from servogym.autotune._session import (
    DEFAULT_BATCH_SIZE,
    BudgetExhausted,
    Session,
    TuneError,
    best_trial,
    counts_toward_budget,
    default_storage_url,
    open_storage,
    trial_seed,
)
from servogym.autotune._space import UNIT_PREFIX, SearchSpace, register_values
from servogym.autotune._tuners import (
    TUNERS,
    CMAESTuner,
    GPTuner,
    OptunaTuner,
    RandomTuner,
    SobolTuner,
    TPETuner,
    Tuner,
    get_tuner,
    register_tuner,
    tuner_names,
)

__all__ = [
    "DEFAULT_BATCH_SIZE",
    "DEFAULT_MULTI_OBJECTIVES",
    "GAIN_MAPS",
    "OBJECTIVES",
    "TUNERS",
    "UNIT_PREFIX",
    "BudgetExhausted",
    "CMAESTuner",
    "Constraints",
    "GPTuner",
    "GainMap",
    "ModelBasedTuner",
    "OptunaTuner",
    "Outcome",
    "PMACGainMap",
    "PMDGainMap",
    "Parker6kGainMap",
    "RandomTuner",
    "RelayTuner",
    "SearchSpace",
    "ServoDesign",
    "Session",
    "SobolTuner",
    "StudyResult",
    "TPETuner",
    "TuneConfig",
    "TuneError",
    "TuneProblem",
    "Tuner",
    "VendorStepTuner",
    "astrom_hagglund",
    "best_trial",
    "counts_toward_budget",
    "default_storage_url",
    "design_registers",
    "gain_map_for",
    "get_tuner",
    "identify_rigid_axis",
    "open_storage",
    "read_param_file",
    "register_gain_map",
    "register_tuner",
    "register_values",
    "run_study",
    "trial_seed",
    "tune",
    "tuner_names",
]
