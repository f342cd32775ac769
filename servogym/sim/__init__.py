"""The closed-loop servo runner (a compiled hot loop around mj_step), metrics and the cost."""

from servogym.sim._check import CaseResult, CheckLimits, CheckReport, check_params
from servogym.sim._contour import (
    CONTOUR_MODES,
    CirclePath,
    ContourError,
    Kinematics,
    LinePath,
    contour,
    contour_error,
    coordinated_move,
)
from servogym.sim._machine import (
    SEQUENCING,
    MultiEpisodeResult,
    MultiServoLoop,
    axis_latencies,
    check_machine,
    machine_params,
)
from servogym.sim._margins import Margins
from servogym.sim._metrics import METRIC_NAMES, EpisodeMetrics
from servogym.sim._multicheck import MachineCheckReport, check_machine_params
from servogym.sim._multieval import (
    ContourSpec,
    CoordinatedSpec,
    MultiCostWeights,
    MultiEvaluation,
    MultiEvaluator,
)
from servogym.sim._runner import (
    MAX_SUBSTEP_S,
    REFERENCE_SUBSTEPS,
    EpisodeResult,
    ServoLoop,
    Traces,
    default_substeps,
)
from servogym.sim._scenario import (
    COST_CAP,
    DEFAULT_MOVES,
    DIVERGENCE_PENALTY,
    CostWeights,
    Evaluation,
    Evaluator,
    MoveSpec,
    Scenario,
    move_cost,
    robust_cost,
)

__all__ = [
    "CONTOUR_MODES",
    "COST_CAP",
    "DEFAULT_MOVES",
    "DIVERGENCE_PENALTY",
    "MAX_SUBSTEP_S",
    "METRIC_NAMES",
    "REFERENCE_SUBSTEPS",
    "SEQUENCING",
    "CaseResult",
    "CheckLimits",
    "CheckReport",
    "CirclePath",
    "ContourError",
    "ContourSpec",
    "CoordinatedSpec",
    "CostWeights",
    "EpisodeMetrics",
    "EpisodeResult",
    "Evaluation",
    "Evaluator",
    "Kinematics",
    "LinePath",
    "MachineCheckReport",
    "Margins",
    "MoveSpec",
    "MultiCostWeights",
    "MultiEpisodeResult",
    "MultiEvaluation",
    "MultiEvaluator",
    "MultiServoLoop",
    "Scenario",
    "ServoLoop",
    "Traces",
    "axis_latencies",
    "check_machine",
    "check_machine_params",
    "check_params",
    "contour",
    "contour_error",
    "coordinated_move",
    "default_substeps",
    "machine_params",
    "move_cost",
    "robust_cost",
]
