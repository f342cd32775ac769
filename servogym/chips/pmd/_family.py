"""The PMD family's entry in the chip registry."""

from __future__ import annotations

from types import MappingProxyType
from typing import Any

from servogym.chips._base import ChipFamily, Move
from servogym.chips.pmd import _export, _kernel, _profile, _response
from servogym.chips.pmd._params import CHIP_MODELS, PMDAssumptions, PMDParams
from servogym.chips.pmd._reference import PMDReferenceFilter


class PMDFamily(ChipFamily, params=PMDParams, export=_export, kernel=_kernel, response=_response):
    """PMD Navigator / Pilot / Magellan (MC2100 ... MC58000)."""

    name = "pmd"
    models = CHIP_MODELS
    assumptions_type = PMDAssumptions
    reference_type = PMDReferenceFilter
    error_trip_off = MappingProxyType(
        {"position_error_limit": 2**31 - 1}
    )  # PMD-A10: the largest limit

    def native_latency_s(self, params: Any, choice: str) -> float:
        """PMD-A13 ``"axis_slot"``: one per-axis slot, the model's minimum sample time."""
        if choice != "axis_slot":
            return super().native_latency_s(params, choice)
        return CHIP_MODELS[params.model].min_sample_time_us * 1e-6

    def profile(self, move: Move, sample_time_s: float) -> _profile.Profile:
        return _profile.move(
            move.kind,
            *move.limits,
            sample_time_s,
            jerk_counts_per_s3=move.jerk_counts_per_s3,
            settle_ticks=move.settle_ticks(sample_time_s),
        )


PMD = PMDFamily()
