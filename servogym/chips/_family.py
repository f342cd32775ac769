"""What every chip family provides, so sim, envs, tuners and the CLI never special-case one.

A family (PMD, PMAC, Parker 6000) registers one :class:`ChipFamily` object. Chip models are
looked up by name across families with :func:`get_chip`.
"""

from __future__ import annotations

import abc
import dataclasses
from collections.abc import Mapping
from typing import Any

import numpy as np

from servogym.chips._space import ParameterError, ParameterSpace, resolve_name


@dataclasses.dataclass(frozen=True)
class Move:
    """A point-to-point move in encoder counts, independent of any chip's units.

    Each chip family turns it into its own profile (:meth:`ChipFamily.profile`).

    Attributes:
        distance_counts: Signed move length (counts).
        max_velocity_counts_per_s: Velocity limit (counts/s), > 0.
        max_acceleration_counts_per_s2: Acceleration and deceleration limit (counts/s^2), > 0.
        settle_s: Time at rest on the target after the move (s), >= 0.
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

    def make_params(self, model: str, values: Mapping[str, Any] | None = None) -> Any:
        """A validated parameter set: the model's defaults updated with ``values``."""
        return self.params_type.from_dict({"model": model, **(values or {})})

    def default_assumptions(self) -> Any:
        """The family's assumption switches at their defaults."""
        return self.assumptions_type()

    def kernel_arrays(self, params: Any, assumptions: Any) -> tuple[np.ndarray, np.ndarray]:
        """Register array and assumption array for the compiled loop."""
        asm = assumptions if assumptions is not None else self.assumptions_type()
        if not isinstance(asm, self.assumptions_type):
            raise TypeError(
                f"assumptions for a {self.name} chip must be {self.assumptions_type.__name__}; "
                f"got {type(asm).__name__}"
            )
        return params.to_array(), asm.to_array()

    def reference_filter(self, params: Any, assumptions: Any = None) -> Any:
        """The family's plain-Python reference filter (``step``, ``motion_error``)."""
        return self.reference_type(params, assumptions)

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

    def motor_limit(self, params: Any) -> int:
        """Largest motor-command magnitude the set allows (counts of the 16-bit output)."""
        return int(params.motor_limit)


FAMILY_CODES: dict[str, int] = {"pmd": 0, "pmac": 1, "parker6k": 2}
"""Codes the compiled servo loop dispatches on; one per family, never reused."""

_FAMILIES: dict[str, ChipFamily] = {}


def register_family(family: ChipFamily) -> ChipFamily:
    """Add a chip family to the registry (done by each family's package on import)."""
    _FAMILIES[family.name] = family
    return family


def families() -> dict[str, ChipFamily]:
    """Every registered chip family by name."""
    _load_builtin()
    return dict(_FAMILIES)


def all_models() -> dict[str, ChipFamily]:
    """Every chip model name, mapped to its family."""
    return {m: f for f in families().values() for m in f.models}


def get_chip(model: str) -> tuple[ChipFamily, str]:
    """The family and canonical name of a chip model (case-insensitive), or a clear error."""
    models = all_models()
    key = resolve_name(model, models, "chip model")
    return models[key], key


def load_params_file(text: str) -> Any:
    """Load a servogym JSON parameter file of any family (``.params``, ``.assumptions``).

    Raises:
        ParameterError: when the file is not a servogym parameter file or names no known
            chip family.
    """
    import json

    try:
        doc = json.loads(text)
    except json.JSONDecodeError as exc:
        raise ParameterError(f"not a servogym JSON parameter file: {exc}") from None
    name = doc.get("chip_family") if isinstance(doc, dict) else None
    known = families()
    if name not in known:
        raise ParameterError(
            f"chip_family must be one of {', '.join(known)}; got chip_family={name!r}."
        )
    return known[name].from_json(text)


def family_of(params: Any) -> ChipFamily:
    """The family a parameter set belongs to."""
    for fam in families().values():
        if isinstance(params, fam.params_type):
            return fam
    raise TypeError(f"{type(params).__name__} is not a parameter set of any chip family")


def _load_builtin() -> None:
    # Importing a family's package registers it.
    import servogym.chips.parker6k
    import servogym.chips.pmac
    import servogym.chips.pmd  # noqa: F401
