"""The PMAC family's entry in the chip registry."""

from __future__ import annotations

from types import MappingProxyType
from typing import Any

from servogym.chips._base import ChipFamily, Move
from servogym.chips.pmac import _export, _kernel, _profile, _response
from servogym.chips.pmac._params import CHIP_MODELS, PMACAssumptions, PMACParams
from servogym.chips.pmac._reference import PMACReferenceFilter


class PMACFamily(ChipFamily, params=PMACParams, export=_export, kernel=_kernel, response=_response):
    """Delta Tau Turbo PMAC2 and Geo Brick LV: PID + feed-forward + notch (Ixx30..Ixx39)."""

    name = "pmac"
    models = CHIP_MODELS
    assumptions_type = PMACAssumptions
    reference_type = PMACReferenceFilter
    error_trip_off = MappingProxyType({"fatal_following_error_limit": 0})  # Ixx11 = 0 disables it

    def native_latency_s(self, params: Any, choice: str) -> float:
        """PMAC-A14 ``"phase_edge"``: one phase period, servo period / (I7002 + 1)."""
        if choice != "phase_edge":
            return super().native_latency_s(params, choice)
        return params.servo_period_s / (params.servo_clock_divider + 1)

    def profile(self, move: Move, sample_time_s: float) -> _profile.Profile:
        return _profile.move(
            move.kind,
            *move.limits,
            sample_time_s,
            jerk_counts_per_s3=move.jerk_counts_per_s3 if move.kind == "s_curve" else None,
            settle_ticks=move.settle_ticks(sample_time_s),
        )


PMAC = PMACFamily()
