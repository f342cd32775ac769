"""Switchable assumptions: the shared behaviour of every chip family's assumption dataclass.

A family declares its switches as a frozen dataclass deriving from :class:`AssumptionSet`,
with ``CHOICES`` (field -> (default, alternatives...)) and ``IDS`` (field -> "PMD-A1" ...).
The kernel reads them as an int64 array of choice indices, 0 being the default.
"""

from __future__ import annotations

import dataclasses
from typing import Any, ClassVar, Self

import numpy as np

from servogym.chips._space import ParameterError


class AssumptionSet:
    """Validation, kernel array, provenance dict and the test matrix of a family's switches."""

    CHOICES: ClassVar[dict[str, tuple[str, ...]]]
    IDS: ClassVar[dict[str, str]]

    def __post_init__(self) -> None:
        for name, choices in self.CHOICES.items():
            value = getattr(self, name)
            if value not in choices:
                raise ParameterError(
                    f"assumption {self.IDS[name]} {name} must be one of "
                    f"{', '.join(repr(c) for c in choices)}; got {name}={value!r}."
                )

    def to_array(self) -> np.ndarray:
        """The switches as an int64 array for the kernel: index of the choice, 0 = default."""
        return np.array(
            [self.CHOICES[n].index(getattr(self, n)) for n in self.CHOICES], dtype=np.int64
        )

    def to_dict(self) -> dict[str, Any]:
        """The switches by name (for provenance in exported files)."""
        return dataclasses.asdict(self)  # type: ignore[call-overload]

    @classmethod
    def all_settings(cls) -> list[Self]:
        """The default, and each single alternative switched on alone."""
        out = [cls()]
        for name, choices in cls.CHOICES.items():
            for alt in choices[1:]:
                out.append(cls(**{name: alt}))
        return out

    @classmethod
    def index(cls) -> dict[str, int]:
        """Position of each switch in :meth:`to_array`, for the kernel."""
        return {name: i for i, name in enumerate(cls.CHOICES)}
