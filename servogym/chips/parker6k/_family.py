"""The Parker 6000-series family's entry in the chip registry."""

from __future__ import annotations

from collections.abc import Mapping
from types import MappingProxyType
from typing import Any

import numpy as np

from servogym.chips._base import ChipFamily, Move
from servogym.chips._space import ParameterError
from servogym.chips.parker6k import _export, _kernel, _profile, _response
from servogym.chips.parker6k._params import (
    CHIP_MODELS,
    FIELDS,
    GAIN_FIELDS,
    Parker6kAssumptions,
    Parker6kParams,
    parameter_space,
)
from servogym.chips.parker6k._reference import Parker6kReferenceFilter


class Parker6kFamily(
    ChipFamily, params=Parker6kParams, export=_export, kernel=_kernel, response=_response
):
    """Parker Compumotor 6000-series servo controllers (6250, 6K): PIV&F with gain sets."""

    name = "parker6k"
    models = CHIP_MODELS
    assumptions_type = Parker6kAssumptions
    env_name = "Parker6K"
    reference_type = Parker6kReferenceFilter
    error_trip_off = MappingProxyType({"smper": 0})  # PK-A8: SMPER0 disables the check

    def formats_for(self, model: str) -> tuple[str, ...]:
        """JSON and the 6250 form for every model; the axis-prefixed 6K form for the 6K."""
        chip = CHIP_MODELS[model]
        return tuple(f for f in self.formats if f != "6k" or chip.axis_prefix)

    def native_format(self, model: str) -> str:
        """``"6k"`` for a model that takes axis-prefixed commands, else ``"6250"``."""
        return "6k" if CHIP_MODELS[model].axis_prefix else "6250"

    def profile(self, move: Move, sample_time_s: float) -> _profile.Parker6kProfile:
        ssfr = _profile.ssfr_of(sample_time_s)
        return _profile.move(
            *move.limits,
            ssfr,
            kind=move.kind,
            jerk_counts_per_s3=move.jerk_counts_per_s3,
            settle_ticks=move.settle_ticks(sample_time_s),
        )


PARKER6K = Parker6kFamily()


class StoredSetActions:
    """A discrete action that picks one stored gain set, as SGENB does: an env action map.

    It has the interface of ``servogym.envs.ActionMap`` (``space``, ``names``,
    ``to_values``, ``to_params``, ``from_values``), so the envs take it as ``action_type``.
    Action ``k`` makes stored set ``k + 1`` the gains in force (:meth:`Parker6kParams.enable`);
    every other setting, the stored sets and the SGENB schedule stay as in ``params``.

    Args:
        params: A parameter set with at least one stored gain set.

    Attributes:
        space: ``gymnasium.spaces.Discrete(len(params.sgset))``.
        names: The registers an action sets: ``sgp, sgi, sgv, sgvf, sgaf``.
    """

    def __init__(self, params: Parker6kParams) -> None:
        from gymnasium import spaces

        if not isinstance(params, Parker6kParams):
            raise ParameterError(f"params must be a Parker6kParams; got {type(params).__name__}.")
        if not params.sgset:
            raise ParameterError(
                "params must hold at least one stored gain set (sgset) to choose from; got "
                "sgset=()."
            )
        self.params = params
        self.names = GAIN_FIELDS
        self.space = spaces.Discrete(len(params.sgset))

    def _index(self, action: Any) -> int:
        a = np.asarray(action)
        n = len(self.params.sgset)
        if a.shape != () or not np.issubdtype(a.dtype, np.integer) or not 0 <= int(a) < n:
            raise ValueError(
                f"the action must be an integer with 0 <= action <= {n - 1} (stored gain set "
                f"action + 1, SGSET1 ... SGSET{n}); got {action!r}."
            )
        return int(a)

    def to_params(self, action: Any) -> Parker6kParams:
        """The parameter set with stored set ``action + 1`` in force."""
        return self.params.enable(self._index(action) + 1)

    def to_values(self, action: Any) -> dict[str, int]:
        """Every flat register of :meth:`to_params` (the fixed ones included)."""
        p = self.to_params(action)
        return {name: getattr(p, name) for name in FIELDS}

    def from_values(self, values: Mapping[str, int]) -> int:
        """The stored set closest to the gains in ``values`` (missing gains: the defaults).

        Closeness is the sum over the five gains of ``|to_unit(value) - to_unit(gain)|`` in
        the registers' own (log) scale; an exact match is always the closest.
        """
        space = parameter_space(self.params.model)
        want = [space[g].to_unit(int(values.get(g, space[g].default))) for g in GAIN_FIELDS]

        def distance(i: int) -> float:
            gains = self.params.sgset[i]
            return sum(
                abs(space[g].to_unit(getattr(gains, g)) - w)
                for g, w in zip(GAIN_FIELDS, want, strict=True)
            )

        return min(range(len(self.params.sgset)), key=distance)
