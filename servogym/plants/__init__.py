"""MuJoCo servo plants with physical parameters, edited in place between episodes.

Four single-axis families (:data:`PLANTS`): ``rotary``, ``two-mass``, ``vertical-axis``, ``arm``;
two multi-axis ones (:data:`MULTI_PLANTS`): ``two-link-arm``, ``xy-stage``. Each
has named SI parameters with a nominal value, a legal (realistic) range and a sampling
distribution; :meth:`PlantFamily.build` compiles a :class:`Plant`, whose
:meth:`Plant.set_params` changes the instance in place. :class:`AxisIO` holds what the
closed-loop runner needs; :func:`amplifier_current` and :func:`encoder_counts` are the
reference amplifier and encoder models it must match. See ``docs/plants.md``.

Example:
    >>> import numpy as np
    >>> from servogym.plants import get_plant
    >>> family = get_plant("vertical-axis")
    >>> plant = family.build()
    >>> rng = np.random.default_rng(0)
    >>> plant.set_params(family.sample(rng))  # new payload, friction: same model object
"""

from servogym.plants._amplifier import (
    amplifier_alpha,
    amplifier_current,
    encoder_counts,
    motor_torque,
)
from servogym.plants._base import (
    COMMAND_MAX,
    COMMAND_MIN,
    DEFAULT_TIMESTEP_S,
    TIMESTEP_MAX_S,
    TIMESTEP_MIN_S,
    AxisIO,
    Plant,
    PlantFamily,
    PlantParam,
    PlantParameterError,
    parse_plant_ranges,
)
from servogym.plants._families import ArmFamily, RotaryFamily, TwoMassFamily, VerticalAxisFamily
from servogym.plants._feasibility import (
    PEAK_HEADROOM,
    MotorFeasibilityError,
    Need,
    check_motor,
    feasible_range,
    required_peak_effort,
)
from servogym.plants._multi import (
    MULTI_PLANTS,
    MultiAxisPlant,
    MultiAxisPlantFamily,
    TwoLinkArmFamily,
    XYStageFamily,
    required_peak_efforts,
)
from servogym.plants._registry import (
    PLANTS,
    describe_multi_plants,
    describe_plants,
    get_plant,
    plant_table_markdown,
)

__all__ = [
    "COMMAND_MAX",
    "COMMAND_MIN",
    "DEFAULT_TIMESTEP_S",
    "MULTI_PLANTS",
    "PEAK_HEADROOM",
    "PLANTS",
    "TIMESTEP_MAX_S",
    "TIMESTEP_MIN_S",
    "ArmFamily",
    "AxisIO",
    "MotorFeasibilityError",
    "MultiAxisPlant",
    "MultiAxisPlantFamily",
    "Need",
    "Plant",
    "PlantFamily",
    "PlantParam",
    "PlantParameterError",
    "RotaryFamily",
    "TwoLinkArmFamily",
    "TwoMassFamily",
    "VerticalAxisFamily",
    "XYStageFamily",
    "amplifier_alpha",
    "amplifier_current",
    "check_motor",
    "describe_multi_plants",
    "describe_plants",
    "encoder_counts",
    "feasible_range",
    "get_plant",
    "motor_torque",
    "parse_plant_ranges",
    "plant_table_markdown",
    "required_peak_effort",
    "required_peak_efforts",
]
