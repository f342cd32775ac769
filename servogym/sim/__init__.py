"""The closed-loop servo runner (a compiled hot loop around mj_step) and response metrics."""

from servogym.sim._metrics import METRIC_NAMES, EpisodeMetrics
from servogym.sim._runner import EpisodeResult, ServoLoop, Traces

__all__ = ["METRIC_NAMES", "EpisodeMetrics", "EpisodeResult", "ServoLoop", "Traces"]
