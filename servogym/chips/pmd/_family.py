"""The PMD family's entry in the chip registry."""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any

import numpy as np

from servogym.chips._family import FAMILY_CODES, ChipFamily, Move, register_family
from servogym.chips._space import ParameterSpace
from servogym.chips.pmd import _export, _kernel, _profile
from servogym.chips.pmd._params import CHIP_MODELS, PMDAssumptions, PMDParams, parameter_space
from servogym.chips.pmd._reference import PMDReferenceFilter


class PMDFamily(ChipFamily):
    """PMD Navigator / Pilot / Magellan (MC2100 ... MC58000)."""

    name = "pmd"
    code = FAMILY_CODES["pmd"]
    models = CHIP_MODELS
    params_type = PMDParams
    assumptions_type = PMDAssumptions
    formats = _export.FORMATS
    file_extensions = _export.FILE_EXTENSIONS

    def parameter_space(self, model: str) -> ParameterSpace:
        return parameter_space(model)

    def make_params(self, model: str, values: Mapping[str, Any] | None = None) -> PMDParams:
        return PMDParams.from_dict({"model": model, **(values or {})})

    def default_assumptions(self) -> PMDAssumptions:
        return PMDAssumptions()

    def kernel_arrays(
        self, params: PMDParams, assumptions: PMDAssumptions | None
    ) -> tuple[np.ndarray, np.ndarray]:
        asm = assumptions if assumptions is not None else PMDAssumptions()
        if not isinstance(asm, PMDAssumptions):
            raise TypeError(
                f"assumptions for a PMD chip must be PMDAssumptions; got {type(asm).__name__}"
            )
        return params.to_array(), asm.to_array()

    def reference_filter(
        self, params: PMDParams, assumptions: PMDAssumptions | None = None
    ) -> PMDReferenceFilter:
        return PMDReferenceFilter(params, assumptions)

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
            jerk_counts_per_s3=move.jerk_counts_per_s3,
            settle_ticks=round(move.settle_s / sample_time_s),
        )

    def export(self, params: PMDParams, fmt: str, **kw: Any) -> str:
        return _export.export(params, fmt, **kw)

    def import_params(self, text: str, fmt: str, model: str | None = None) -> Any:
        return _export.import_params(text, fmt, model)

    def from_json(self, text: str) -> _export.ParamFile:
        return _export.from_json(text)


PMD = register_family(PMDFamily())
