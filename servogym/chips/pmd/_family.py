"""The PMD family's entry in the chip registry."""

from __future__ import annotations

from types import MappingProxyType
from typing import Any

from servogym.chips._base import FAMILY_CODES, ChipFamily, Move
from servogym.chips.pmd import _export, _kernel, _profile, _response
from servogym.chips.pmd._params import CHIP_MODELS, PMDAssumptions, PMDParams, parameter_space
from servogym.chips.pmd._reference import PMDReferenceFilter


class PMDFamily(ChipFamily):
    """PMD Navigator / Pilot / Magellan (MC2100 ... MC58000)."""

    name = "pmd"
    code = FAMILY_CODES["pmd"]
    models = CHIP_MODELS
    params_type = PMDParams
    assumptions_type = PMDAssumptions
    reference_type = PMDReferenceFilter
    export_module = _export
    formats = _export.FORMATS
    file_extensions = _export.FILE_EXTENSIONS
    error_trip_off = MappingProxyType(
        {"position_error_limit": 2**31 - 1}
    )  # PMD-A10: the largest limit
    parameter_space = staticmethod(parameter_space)
    new_state = staticmethod(_kernel.new_state)
    response_function = staticmethod(_response.filter_response)
    polynomial_function = staticmethod(_response.filter_polynomials)

    def native_latency_s(self, params: Any, choice: str) -> float:
        """PMD-A13 ``"axis_slot"``: one per-axis slot, the model's minimum sample time."""
        if choice != "axis_slot":
            return super().native_latency_s(params, choice)
        return CHIP_MODELS[params.model].min_sample_time_us * 1e-6

    def profile(self, move: Move, sample_time_s: float) -> _profile.Profile:
        return _profile.move(
            move.kind,
            move.start_counts,
            move.distance_counts,
            move.max_velocity_counts_per_s,
            move.max_acceleration_counts_per_s2,
            sample_time_s,
            jerk_counts_per_s3=move.jerk_counts_per_s3,
            settle_ticks=round(move.settle_s / sample_time_s),
        )


PMD = PMDFamily()
