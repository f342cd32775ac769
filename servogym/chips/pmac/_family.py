"""The PMAC family's entry in the chip registry."""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any

import numpy as np

from servogym.chips._family import FAMILY_CODES, ChipFamily, Move, register_family
from servogym.chips._space import ParameterSpace
from servogym.chips.pmac import _export, _kernel, _profile
from servogym.chips.pmac._params import (
    CHIP_MODELS,
    PMACAssumptions,
    PMACParams,
    parameter_space,
)
from servogym.chips.pmac._reference import PMACReferenceFilter


class PMACFamily(ChipFamily):
    """Delta Tau Turbo PMAC2 and Geo Brick LV: PID + feed-forward + notch (Ixx30..Ixx39)."""

    name = "pmac"
    code = FAMILY_CODES["pmac"]
    models = CHIP_MODELS
    params_type = PMACParams
    assumptions_type = PMACAssumptions
    formats = _export.FORMATS
    file_extensions = _export.FILE_EXTENSIONS

    def parameter_space(self, model: str) -> ParameterSpace:
        return parameter_space(model)

    def make_params(self, model: str, values: Mapping[str, Any] | None = None) -> PMACParams:
        return PMACParams.from_dict({"model": model, **(values or {})})

    def default_assumptions(self) -> PMACAssumptions:
        return PMACAssumptions()

    def kernel_arrays(
        self, params: PMACParams, assumptions: PMACAssumptions | None
    ) -> tuple[np.ndarray, np.ndarray]:
        asm = assumptions if assumptions is not None else PMACAssumptions()
        if not isinstance(asm, PMACAssumptions):
            raise TypeError(
                f"assumptions for a PMAC chip must be PMACAssumptions; got {type(asm).__name__}"
            )
        return params.to_array(), asm.to_array()

    def reference_filter(
        self, params: PMACParams, assumptions: PMACAssumptions | None = None
    ) -> PMACReferenceFilter:
        return PMACReferenceFilter(params, assumptions)

    def new_state(self) -> np.ndarray:
        return _kernel.new_state()

    def profile(self, move: Move, sample_time_s: float) -> _profile.Profile:
        return _profile.move(
            move.kind,
            move.start_counts,
            move.distance_counts,
            move.max_velocity_counts_per_s,
            move.max_acceleration_counts_per_s2,
            sample_time_s,
            jerk_counts_per_s3=move.jerk_counts_per_s3 if move.kind == "s_curve" else None,
            settle_ticks=round(move.settle_s / sample_time_s),
        )

    def export(self, params: PMACParams, fmt: str, **kw: Any) -> str:
        return _export.export(params, fmt, **kw)

    def import_params(self, text: str, fmt: str, model: str | None = None) -> Any:
        return _export.import_params(text, fmt, model)

    def from_json(self, text: str) -> _export.ParamFile:
        return _export.from_json(text)


PMAC = register_family(PMACFamily())
