"""The closed-loop servo runner (a compiled hot loop around mj_step), metrics and the cost."""

from servogym.sim._check import CaseResult, CheckLimits, CheckReport, check_params
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
    "CostWeights",
    "EpisodeMetrics",
    "EpisodeResult",
    "Evaluation",
    "Evaluator",
    "Margins",
    "MoveSpec",
    "MultiEpisodeResult",
    "MultiServoLoop",
    "Scenario",
    "ServoLoop",
    "Traces",
    "axis_latencies",
    "check_machine",
    "check_params",
    "default_substeps",
    "machine_params",
    "move_cost",
    "robust_cost",
]
