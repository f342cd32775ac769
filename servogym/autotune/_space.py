"""The search space of a tuner: some registers of a chip model, each on u in [-1, 1].

Every searched register is one Optuna float parameter ``u_<name>`` in [-1, 1] and becomes a
legal integer through :meth:`servogym.chips.ParamSpec.from_unit`, the mapping the envs'
actions use: linear registers map evenly onto their range, log-scaled gains log-uniformly,
with 0 (a term switched off) reachable at the bottom of the interval.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Iterable, Mapping
from typing import Any

from servogym.chips._family import ChipFamily, get_chip
from servogym.chips._space import ParameterError, ParamSpec

UNIT_PREFIX = "u_"
"""Prefix of the Optuna parameter that searches a register (``u_kp`` searches ``kp``)."""


@dataclasses.dataclass(frozen=True)
class SearchSpace:
    """The registers a tuner searches and the values it holds fixed.

    Attributes:
        chip_model: Canonical chip model name (any family of the chip registry).
        names: Searched registers, in the chip's register order.
        fixed: Registers held at a given value (chip units); every other register not
            searched keeps the chip model's default.
    """

    chip_model: str
    names: tuple[str, ...]
    fixed: Mapping[str, int] = dataclasses.field(default_factory=dict)

    @classmethod
    def for_chip(
        cls,
        chip_model: str,
        names: Iterable[str] | None = None,
        fixed: Mapping[str, Any] | None = None,
    ) -> SearchSpace:
        """The search space of a chip model.

        Args:
            chip_model: A chip model of any registered family (case-insensitive).
            names: Registers to search; default every register with ``tunable=True``.
                A register that is not tunable by default may be named explicitly.
            fixed: Registers to hold at a value (chip units), e.g. ``{"bias": 0}``; they are
                removed from the searched ones.

        Raises:
            ParameterError: for an unknown chip model or register (with close matches), an
                illegal fixed value (naming the legal range), or an empty search space.
        """
        family, model = get_chip(chip_model)
        space = family.parameter_space(model)
        fixed_values = space.validate(dict(fixed or {}))
        if names is None:
            wanted = [s.name for s in space.tunable()]
        else:
            wanted = list(names)
            for name in wanted:
                space[name]  # raises with close matches for an unknown register
        searched = tuple(n for n in space if n in wanted and n not in fixed_values)
        if not searched:
            raise ParameterError(
                f"the search space of {model} is empty: every searched register is fixed "
                f"(searched {', '.join(wanted) or 'none'}; fixed {', '.join(fixed_values)}). "
                "Search at least one register."
            )
        return cls(model, searched, fixed_values)

    @property
    def family(self) -> ChipFamily:
        """The chip family."""
        return get_chip(self.chip_model)[0]

    @property
    def specs(self) -> list[ParamSpec]:
        """The searched registers' specs, in order."""
        space = self.family.parameter_space(self.chip_model)
        return [space[n] for n in self.names]

    @property
    def unit_names(self) -> tuple[str, ...]:
        """The Optuna parameter names, ``u_<register>``."""
        return tuple(UNIT_PREFIX + n for n in self.names)

    def distributions(self) -> dict[str, Any]:
        """Optuna distributions: one ``FloatDistribution(-1, 1)`` per searched register."""
        from optuna.distributions import FloatDistribution

        return {u: FloatDistribution(-1.0, 1.0) for u in self.unit_names}

    def values_from_unit(self, unit: Mapping[str, float]) -> dict[str, int]:
        """Chip values of the searched registers plus the fixed ones, from ``u_<name>``."""
        out = {s.name: s.from_unit(float(unit[UNIT_PREFIX + s.name])) for s in self.specs}
        out.update(self.fixed)
        return out

    def to_unit(self, values: Mapping[str, Any]) -> dict[str, float]:
        """The ``u_<name>`` coordinates of a set's searched registers (a warm start)."""
        return {UNIT_PREFIX + s.name: s.to_unit(values[s.name]) for s in self.specs}

    def make_params(self, values: Mapping[str, Any]) -> Any:
        """A validated parameter set: the chip defaults updated with ``values``."""
        return self.family.make_params(self.chip_model, dict(values))

    def base_values(self) -> dict[str, int]:
        """Every register's value when nothing is searched: the defaults and the fixed ones."""
        return {**self.family.parameter_space(self.chip_model).defaults(), **self.fixed}

    def register_values(self, params: Any) -> dict[str, int]:
        """Every register of a set this space makes, by name (:func:`register_values`)."""
        return register_values(params)

    def params_from_unit(self, unit: Mapping[str, float]) -> Any:
        """The parameter set a point of the unit cube stands for."""
        return self.make_params(self.values_from_unit(unit))

    def describe(self) -> dict[str, Any]:
        """JSON-ready: chip model, searched registers with their ranges, fixed values."""
        return {
            "chip_model": self.chip_model,
            "searched": {
                s.name: {"low": s.low, "high": s.high, "log": s.log, "default": s.default}
                for s in self.specs
            },
            "fixed": dict(self.fixed),
        }


def register_values(params: Any) -> dict[str, int]:
    """Every register of a parameter set by name (chip units), for any chip family."""
    family, model = get_chip(params.model)
    return {name: int(getattr(params, name)) for name in family.parameter_space(model)}
