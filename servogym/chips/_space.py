"""Legal ranges of chip registers, shared by every chip family.

A :class:`ParamSpec` describes one integer register: its legal range, its default, whether
an optimizer should search it on a log scale, and whether tuners should touch it at all.
A :class:`ParameterSpace` is the ordered collection for one chip model; envs and tuners read
ranges from it instead of hard-coding them.
"""

from __future__ import annotations

import dataclasses
import difflib
import math
import numbers
from collections.abc import Iterator, Mapping
from typing import Any


class ParameterError(ValueError):
    """A parameter value is illegal for the chip: wrong type, out of range, or unknown."""


def resolve_name(name: str, known: Any, what: str, *, n: int = 3) -> str:
    """The key of ``known`` that is ``name`` up to case, or a :class:`ParameterError`.

    The error reads ``unknown <what> <name>; known models are ...`` and suggests up to ``n``
    close matches.
    """
    by_upper = {k.upper(): k for k in known}
    key = by_upper.get(str(name).upper())
    if key is not None:
        return key
    close = difflib.get_close_matches(str(name).upper(), list(by_upper), n=n)
    hint = f" Did you mean {', '.join(by_upper[c] for c in close)}?" if close else ""
    raise ParameterError(f"unknown {what} {name!r}; known models are {', '.join(known)}.{hint}")


ZERO_FRACTION = 0.05
"""Share of the unit interval that maps to 0 for a log-scaled register whose low is 0."""
_ZERO_BELOW = 2.0 * ZERO_FRACTION - 1.0  # u below this maps to 0


@dataclasses.dataclass(frozen=True)
class ParamSpec:
    """One integer register of a chip.

    Attributes:
        name: The register's name in the vendor's own terms (``kp``, ``integration_limit``).
        low: Smallest legal value (inclusive).
        high: Largest legal value (inclusive).
        default: Value used when none is given.
        width: Storage format on the chip, e.g. ``"u16"``, ``"s16"``, ``"u32 (31 used)"``.
        log: Whether an optimizer should search this register on a log scale. A log-scaled
            register whose ``low`` is 0 keeps 0 reachable (0 switches the term off).
        tunable: Whether tuners and envs search it by default. Axis configuration such as
            the sample time or the motor limit is legal to set but not tuned by default.
        unit: Unit of the register, e.g. ``"counts"``, ``"us"``, ``"1/65536"``.
        doc: One line saying what the register does.
        source: How sure the range is: ``"M"`` manual, ``"C"`` public code, ``"A"`` assumption.
        default_note: Where the default comes from when it is not the controller's own
            power-up value (a manual's worked example, say); empty when it is.
    """

    name: str
    low: int
    high: int
    default: int
    width: str
    log: bool = False
    tunable: bool = True
    unit: str = ""
    doc: str = ""
    source: str = "M"
    default_note: str = ""

    def __post_init__(self) -> None:
        if not self.low <= self.default <= self.high:
            raise ValueError(
                f"ParamSpec {self.name}: default must satisfy low <= default <= high; "
                f"got {self.low=}, {self.default=}, {self.high=}."
            )

    @property
    def range_text(self) -> str:
        """The legal range as it appears in error messages, e.g. ``0 <= kp <= 32767``."""
        return f"{self.low} <= {self.name} <= {self.high}"

    def from_unit(self, u: float) -> int:
        """Map ``u`` in [-1, 1] onto a legal value (what envs' Box actions and tuners use).

        Linear registers map ``u`` evenly onto ``low..high``. Log-scaled registers map it
        log-uniformly onto ``max(low, 1)..high``; when ``low`` is 0 or negative, the lowest
        :data:`ZERO_FRACTION` of the interval gives 0 (the term switched off), so 0 stays
        reachable (a signed log-scaled gain is searched over 0 and its positive values
        only). The result is rounded to the nearest integer, and is always legal.

        Raises:
            ParameterError: when ``u`` is not a finite number in [-1, 1].
        """
        if not isinstance(u, numbers.Real) or not (math.isfinite(u) and -1.0 <= u <= 1.0):
            raise ParameterError(
                f"the action for {self.name} must be a finite number in [-1, 1]; got {u!r}."
            )
        u = float(u)
        t = (u + 1.0) / 2.0
        if not self.log:
            return min(self.high, max(self.low, round(self.low + t * (self.high - self.low))))
        lo = max(self.low, 1)
        if self.low <= 0:
            if u < _ZERO_BELOW:
                return min(max(self.low, 0), self.high)
            t = (u - _ZERO_BELOW) / (1.0 - _ZERO_BELOW)
        value = round(math.exp(math.log(lo) + t * (math.log(self.high) - math.log(lo))))
        return min(self.high, max(lo, value))

    def to_unit(self, value: int) -> float:
        """The ``u`` in [-1, 1] that :meth:`from_unit` maps back to ``value`` (a warm start).

        ``from_unit(to_unit(v)) == v`` for every legal ``v`` a log scale can resolve (on a
        log scale, neighbouring large values may share one ``u``).
        """
        v = self.validate(value)
        if self.high == self.low:
            return -1.0
        if not self.log:
            t = (v - self.low) / (self.high - self.low)
        else:
            lo = max(self.low, 1)
            if self.low <= 0 and v <= 0:
                return (_ZERO_BELOW - 1.0) / 2.0
            t = (math.log(v) - math.log(lo)) / (math.log(self.high) - math.log(lo))
            if self.low <= 0:
                return min(1.0, _ZERO_BELOW + t * (1.0 - _ZERO_BELOW))
        return min(1.0, max(-1.0, 2.0 * t - 1.0))

    def validate(self, value: Any, *, context: str = "") -> int:
        """Return ``value`` as a Python int, or raise :class:`ParameterError`.

        Only integers are accepted (Python or NumPy integers, not bools, not floats): a chip
        register holds an integer and a float would have to be rounded silently.
        """
        where = f" ({context})" if context else ""
        if isinstance(value, bool) or not isinstance(value, numbers.Integral):
            raise ParameterError(
                f"{self.name} must be an integer with {self.range_text} ({self.width}){where}; "
                f"got {self.name}={value!r} of type {type(value).__name__}."
            )
        ivalue = int(value)
        if not self.low <= ivalue <= self.high:
            raise ParameterError(
                f"{self.name} must satisfy {self.range_text} ({self.width}){where}; "
                f"got {self.name}={ivalue}."
            )
        return ivalue


class ParameterSpace(Mapping[str, ParamSpec]):
    """The registers of one chip model, in a fixed order.

    Args:
        chip_model: Name of the chip model the ranges belong to (used in messages).
        specs: The registers, in the order they are stored and exported.
    """

    def __init__(self, chip_model: str, specs: list[ParamSpec]) -> None:
        self.chip_model = chip_model
        self._specs = {s.name: s for s in specs}
        if len(self._specs) != len(specs):
            raise ValueError(f"duplicate register names in the space of {chip_model}")

    def __getitem__(self, name: str) -> ParamSpec:
        try:
            return self._specs[name]
        except KeyError:
            raise ParameterError(self.unknown_message(name)) from None

    def __contains__(self, name: object) -> bool:
        return name in self._specs

    def __iter__(self) -> Iterator[str]:
        return iter(self._specs)

    def __len__(self) -> int:
        return len(self._specs)

    def __repr__(self) -> str:
        return f"ParameterSpace({self.chip_model!r}, {list(self._specs)})"

    def unknown_message(self, name: str) -> str:
        """An error message for a register this chip model does not have."""
        close = difflib.get_close_matches(name, list(self._specs), n=3)
        hint = f" Did you mean {', '.join(close)}?" if close else ""
        return (
            f"{self.chip_model} has no parameter {name!r}; its parameters are "
            f"{', '.join(self._specs)}.{hint}"
        )

    def defaults(self) -> dict[str, int]:
        """Every register's default value."""
        return {name: spec.default for name, spec in self._specs.items()}

    def tunable(self) -> list[ParamSpec]:
        """The registers tuners search by default."""
        return [s for s in self._specs.values() if s.tunable]

    def validate(self, values: Mapping[str, Any]) -> dict[str, int]:
        """Check a complete or partial mapping of register values; return them as ints.

        Raises:
            ParameterError: for an unknown name or an illegal value; the message names the
                parameter, the value and the legal range.
        """
        out = {}
        for name, value in values.items():
            out[name] = self[name].validate(value, context=self.chip_model)
        return out

    def describe(self) -> list[dict[str, Any]]:
        """A JSON-ready description of every register (for ``servogym chips --json``)."""
        return [dataclasses.asdict(s) for s in self._specs.values()]
