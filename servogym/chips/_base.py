"""What every chip family provides, so sim, envs, tuners and the CLI never special-case one.

A family (PMD, PMAC, Parker 6000) defines one :class:`ChipFamily` object; the registry
(:mod:`servogym.chips._family`) lists them. Family packages import this module, never the
registry, so no import circle runs through the families.
"""

from __future__ import annotations

import abc
import dataclasses
from collections.abc import Mapping
from typing import Any

import numpy as np

from servogym.chips._space import ParameterError, ParameterSpace


@dataclasses.dataclass(frozen=True)
class Move:
    """A point-to-point move in encoder counts, independent of any chip's units.

    Each chip family turns it into its own profile (:meth:`ChipFamily.profile`).

    Attributes:
        distance_counts: Signed move length (counts).
        max_velocity_counts_per_s: Velocity limit (counts/s), > 0.
        max_acceleration_counts_per_s2: Acceleration and deceleration limit (counts/s^2), > 0.
        settle_s: Time at rest on the target after the move (s), >= 0; in servo cycles
            :meth:`settle_ticks`.
        kind: ``"trapezoidal"`` or ``"s_curve"``.
        jerk_counts_per_s3: Jerk limit for ``"s_curve"`` (counts/s^3).
        start_counts: Position at rest before the move (counts).
    """

    distance_counts: int
    max_velocity_counts_per_s: float
    max_acceleration_counts_per_s2: float
    settle_s: float = 0.1
    kind: str = "trapezoidal"
    jerk_counts_per_s3: float | None = None
    start_counts: int = 0

    def __post_init__(self) -> None:
        for name in ("max_velocity_counts_per_s", "max_acceleration_counts_per_s2"):
            value = getattr(self, name)
            if not value > 0:
                raise ParameterError(f"{name} must be > 0; got {name}={value!r}.")
        if not self.settle_s >= 0:
            raise ParameterError(f"settle_s must be >= 0; got settle_s={self.settle_s!r}.")
        if self.kind not in ("trapezoidal", "s_curve"):
            raise ParameterError(
                f"kind must be 'trapezoidal' or 's_curve'; got kind={self.kind!r}."
            )
        if self.kind == "s_curve" and not (self.jerk_counts_per_s3 or 0) > 0:
            raise ParameterError(
                "an 's_curve' move needs jerk_counts_per_s3 > 0; "
                f"got jerk_counts_per_s3={self.jerk_counts_per_s3!r}."
            )

    @property
    def limits(self) -> tuple[int, int, float, float]:
        """``(start_counts, distance_counts, max_velocity, max_acceleration)``: the leading
        arguments of every family's profile generator."""
        return (
            self.start_counts,
            self.distance_counts,
            self.max_velocity_counts_per_s,
            self.max_acceleration_counts_per_s2,
        )

    def settle_ticks(self, sample_time_s: float) -> int:
        """:attr:`settle_s` in whole servo cycles of ``sample_time_s`` (rounded)."""
        return round(self.settle_s / sample_time_s)


class ChipFamily(abc.ABC):
    """One chip family: its models, parameter sets, compiled filter and profile generator.

    A family sets the class attributes below and implements :meth:`profile`; everything
    else is derived from them.

    Attributes:
        name: Family id (``"pmd"``).
        code: Chip family code the compiled loop dispatches on (:data:`FAMILY_CODES`).
        models: Chip model records by name.
        params_type: The family's parameter-set class (``from_dict``, ``to_array``,
            ``model``, ``sample_time_s``, ``motor_limit``).
        assumptions_type: The family's assumption-switch class (an ``AssumptionSet``).
        reference_type: The plain-Python reference filter class, ``(params, assumptions)``.
        export_module: The module with ``export``, ``import_params``, ``from_json``.
        formats: Export formats; every one takes ``assumptions`` and ``axis`` (JSON ignores
            ``axis``).
        file_extensions: Suggested file extension per format.
        env_name: The family's name in env ids (``Tune-<env_name>-...``); empty: the name
            in capitals.
        error_trip_off: Register values that switch off the chip's own following-error trip
            (for identification experiments that must not be cut short by it).
        response_function: ``(params, assumptions, z) -> complex array``: the linear part of
            the filter's feedback path (:meth:`filter_response`), in the family's
            ``_response`` module.
        polynomial_function: ``(params, assumptions) -> (num, den)``: the same as
            polynomials in ``z^-1`` (:meth:`filter_polynomials`), in the same module.
    """

    name: str
    code: int
    models: Mapping[str, Any]
    params_type: type
    assumptions_type: type
    reference_type: type
    export_module: Any
    formats: tuple[str, ...] = ("json",)
    file_extensions: Mapping[str, str] = {"json": ".json"}
    env_name: str = ""
    error_trip_off: Mapping[str, int] = {}
    response_function: Any = None
    polynomial_function: Any = None

    def __init_subclass__(
        cls,
        *,
        params: Any = None,
        export: Any = None,
        kernel: Any = None,
        response: Any = None,
        **kw: Any,
    ) -> None:
        """Take a family's modules: ``class PMDFamily(ChipFamily, export=..., kernel=...,
        response=...)`` sets :attr:`export_module`, :attr:`formats` and
        :attr:`file_extensions` (from the export module's ``FORMATS`` and
        ``FILE_EXTENSIONS``), :meth:`new_state` (the kernel module's), and
        :attr:`response_function` / :attr:`polynomial_function` (the response module's
        ``filter_response`` / ``filter_polynomials``); ``params=``, the parameter-set class
        (a ``RegisterSet``), sets :attr:`params_type` and :meth:`parameter_space`; and
        :attr:`code` comes from :attr:`name`."""
        super().__init_subclass__(**kw)
        if params is not None:
            cls.params_type = params
            cls.parameter_space = staticmethod(params._space_of)  # type: ignore[method-assign]
        if export is not None:
            cls.export_module = export
            cls.formats = export.FORMATS
            cls.file_extensions = export.FILE_EXTENSIONS
        if kernel is not None:
            cls.new_state = staticmethod(kernel.new_state)  # type: ignore[method-assign]
        if response is not None:
            cls.response_function = staticmethod(response.filter_response)
            cls.polynomial_function = staticmethod(response.filter_polynomials)
        if "name" in cls.__dict__:
            cls.code = FAMILY_CODES[cls.name]

    @staticmethod
    @abc.abstractmethod
    def parameter_space(model: str) -> ParameterSpace:
        """Legal registers of a chip model."""

    @staticmethod
    @abc.abstractmethod
    def new_state() -> np.ndarray:
        """A zeroed filter state for the compiled loop."""

    @abc.abstractmethod
    def profile(self, move: Move, sample_time_s: float) -> Any:
        """The chip's own profile for ``move``: int64 ``position``/``velocity``/
        ``acceleration`` arrays, one entry per servo cycle, and ``start``."""

    @property
    def registers(self) -> Any:
        """The family's register table (:class:`~servogym.chips._registers.RegisterTable`):
        every register with its range, default, unit, source and file spellings."""
        return self.params_type.TABLE

    def make_params(self, model: str, values: Mapping[str, Any] | None = None) -> Any:
        """A validated parameter set: the model's defaults updated with ``values``."""
        return self.params_type.from_dict({"model": model, **(values or {})})

    def default_assumptions(self) -> Any:
        """The family's assumption switches at their defaults."""
        return self.assumptions_type()

    def _assumptions(self, assumptions: Any) -> Any:
        """``assumptions``, or the defaults for ``None``; a wrong type is a TypeError."""
        asm = assumptions if assumptions is not None else self.assumptions_type()
        if not isinstance(asm, self.assumptions_type):
            raise TypeError(
                f"assumptions for a {self.name} chip must be {self.assumptions_type.__name__}; "
                f"got {type(asm).__name__}"
            )
        return asm

    def kernel_arrays(self, params: Any, assumptions: Any) -> tuple[np.ndarray, np.ndarray]:
        """Register array and assumption array for the compiled loop."""
        return params.to_array(), self._assumptions(assumptions).to_array()

    def filter_response(self, params: Any, assumptions: Any, z: Any) -> np.ndarray:
        """Transfer function of the linear part of the filter's feedback path, at ``z``.

        ``C(z)`` is the motor command (counts of the signed 16-bit command the servo loop
        applies, 32768 = 100 %) per count of position error ``E = commanded - actual``,
        with the commanded position held fixed: the loop's transfer from ``-actual``. So a
        term on the encoder's velocity (PMAC Ixx31, Parker SGV) enters with the sign that
        makes it damping. Feed-forward (it acts on the commanded profile), bias and offset,
        saturation, limits, deadband and rounding are left out; every gain scaling and
        every assumption switch that changes the linear response is in. The loop latency
        is not (it belongs to the loop: ``loop_latency_s``). Each family's spec states
        its formula ("Linear response (for margins)").

        Args:
            params: A parameter set of this family.
            assumptions: The family's assumption switches; ``None`` for the defaults.
            z: Points of the z-plane (any shape), ``z = exp(1j * omega * T)`` on the unit
                circle, with ``T`` the filter period :meth:`sample_time_s` (PMAC: the
                servo period times Ixx60 + 1).

        Returns:
            Complex array of ``z``'s shape. At ``z = 1`` with an integral gain the
            response is not finite.
        """
        if not isinstance(params, self.params_type):
            raise TypeError(
                f"params for a {self.name} chip must be {self.params_type.__name__}; "
                f"got {type(params).__name__}"
            )
        asm = self._assumptions(assumptions)
        zz = np.asarray(z, dtype=complex)
        with np.errstate(divide="ignore", invalid="ignore"):
            out = np.asarray(self.response_function(params, asm, zz), dtype=complex)
        return np.broadcast_to(out, zz.shape).copy()

    def filter_polynomials(self, params: Any, assumptions: Any) -> tuple[np.ndarray, np.ndarray]:
        """:meth:`filter_response` as a ratio of polynomials in ``z^-1``.

        ``C(z) = num(z^-1) / den(z^-1)`` exactly (to rounding), coefficients in ascending
        powers of ``z^-1``, ``den[0] = 1``; the closed loop's characteristic polynomial and
        state matrix are built from them (``servogym.sim._margins``). An integral gain puts
        ``1 - z^-1`` into ``den``; a PMD DerivativeTime ``d`` makes ``num`` an FIR of degree
        up to ``2d - 1`` (plus the biquads' and the integral's).

        Args:
            params: A parameter set of this family.
            assumptions: The family's assumption switches; ``None`` for the defaults.

        Returns:
            Two float arrays ``(num, den)``, neither empty (``num = [0.0]`` for a zero
            filter).
        """
        if not isinstance(params, self.params_type):
            raise TypeError(
                f"params for a {self.name} chip must be {self.params_type.__name__}; "
                f"got {type(params).__name__}"
            )
        num, den = self.polynomial_function(params, self._assumptions(assumptions))
        num = np.asarray(num, dtype=float)
        den = np.asarray(den, dtype=float)
        return (num if num.size else np.zeros(1)), den

    def filter_frequency_response(self, params: Any, assumptions: Any, freqs_hz: Any) -> np.ndarray:
        """:meth:`filter_response` at ``z = exp(2j pi f T)``, ``T`` = :meth:`sample_time_s`.

        Args:
            params: A parameter set of this family.
            assumptions: The family's assumption switches; ``None`` for the defaults.
            freqs_hz: Frequencies (Hz), any shape.

        Returns:
            Complex array of ``freqs_hz``'s shape: motor-command counts per count of error.
        """
        f = np.asarray(freqs_hz, dtype=float)
        return self.filter_response(
            params, assumptions, np.exp(2j * np.pi * f * self.sample_time_s(params))
        )

    def reference_filter(self, params: Any, assumptions: Any = None) -> Any:
        """The family's plain-Python reference filter (``step``, ``motion_error``)."""
        return self.reference_type(params, assumptions)

    def formats_for(self, model: str) -> tuple[str, ...]:
        """The export formats a chip model takes (every one of :attr:`formats` by default)."""
        return tuple(self.formats)

    def native_format(self, model: str) -> str:
        """The format the model's own controller takes (``servogym export``'s default)."""
        return next(f for f in self.formats_for(model) if f != "json")

    def export(self, params: Any, fmt: str, **kw: Any) -> str:
        """The parameter set in one of ``formats``."""
        return self.export_module.export(params, fmt, **kw)

    def import_params(self, text: str, fmt: str, model: str | None = None) -> Any:
        """A parameter set read back from one of ``formats`` (identical to what was exported)."""
        return self.export_module.import_params(text, fmt, model)

    def from_json(self, text: str) -> Any:
        """Load a servogym JSON parameter file of this family (``.params``, ``.assumptions``)."""
        return self.export_module.from_json(text)

    def sample_time_s(self, params: Any) -> float:
        """Servo period of a parameter set (s)."""
        return float(params.sample_time_s)

    def loop_latency_s(self, params: Any, assumptions: Any = None) -> float:
        """Time from the encoder sample to the new command reaching the amplifier (s).

        The family's ``loop_latency`` assumption: ``"same_tick"`` (0), ``"half_period"``,
        ``"full_period"`` of the servo period, or the family's own reasoned default
        (:meth:`native_latency_s`), never more than the period.
        """
        asm = assumptions if assumptions is not None else self.assumptions_type()
        period = self.sample_time_s(params)
        fraction = LATENCY_FRACTIONS.get(asm.loop_latency)
        if fraction is not None:
            return fraction * period
        return min(self.native_latency_s(params, asm.loop_latency), period)

    def native_latency_s(self, params: Any, choice: str) -> float:
        """The latency (s) of a family-specific ``loop_latency`` choice (none by default)."""
        raise ParameterError(f"loop_latency={choice!r} is not a latency of the {self.name} family")

    def motor_limit(self, params: Any) -> int:
        """Largest motor-command magnitude the set allows (counts of the 16-bit output)."""
        return int(params.motor_limit)


LATENCY_FRACTIONS: dict[str, float] = {"same_tick": 0.0, "half_period": 0.5, "full_period": 1.0}
"""``loop_latency`` choices every family offers, as fractions of the servo period."""

FAMILY_CODES: dict[str, int] = {"pmd": 0, "pmac": 1, "parker6k": 2}
"""Codes the compiled servo loop dispatches on; one per family, never reused."""
