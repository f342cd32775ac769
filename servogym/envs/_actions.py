"""How an env's action becomes a chip parameter set: pluggable action maps.

An action map owns the action space and turns an action into a validated parameter set of
the chip. Envs take any object with this interface (:class:`ActionMap`), so a chip family
can add its own kind of action (for example a discrete choice among stored gain sets)
without touching the envs.
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Mapping, Sequence
from typing import Any, Protocol

import numpy as np
from gymnasium import spaces

from servogym.chips._family import ChipFamily
from servogym.chips._space import ParameterError, ParamSpec


class ActionMap(Protocol):
    """What an env needs from an action map.

    Attributes:
        space: The Gymnasium action space.
        names: Names of the registers the action sets, in action order.
    """

    space: spaces.Space
    names: tuple[str, ...]

    def to_values(self, action: Any) -> dict[str, int]:
        """The complete register values (fixed ones included) an action stands for."""

    def to_params(self, action: Any) -> Any:
        """The chip parameter set an action stands for; raises ValueError for a bad action."""

    def from_values(self, values: Mapping[str, int]) -> Any:
        """An action that gives ``values`` (as closely as the map can); for baselines."""


def _baseline_values(amap: Any, values: Mapping[str, Any]) -> dict[str, int]:
    """Check a baseline's register values against an action map; return every action entry.

    Unknown names and illegal values raise (naming them). A register the action does not set
    must equal what the env uses for it (its fixed value, else the chip default): a baseline
    is never run silently with other values than it names.
    """
    space = amap.family.parameter_space(amap.chip_model)
    checked = space.validate({k: v for k, v in values.items() if k != "model"})
    for name, value in checked.items():
        if name in amap.names:
            continue
        used = amap.fixed.get(name, space[name].default)
        if value != used:
            raise ValueError(
                f"the baseline sets {name}={value}, a register this env's action does not set "
                f"(the env uses {name}={used}); fix it with fixed={{{name!r}: {value}}} or "
                f"leave it out."
            )
    return {s.name: checked.get(s.name, space[s.name].default) for s in amap.specs}


def _resolve(
    family: ChipFamily, chip_model: str, params: tuple[str, ...] | None, fixed: Mapping[str, Any]
) -> tuple[tuple[ParamSpec, ...], dict[str, int]]:
    space = family.parameter_space(chip_model)
    fixed_values = space.validate(dict(fixed))
    if params is None:
        names = [s.name for s in space.tunable() if s.name not in fixed_values]
    else:
        if isinstance(params, str) or not all(isinstance(n, str) for n in params):
            raise ValueError(
                f"params must be a sequence of register names, e.g. ('kp', 'kd'); got "
                f"params={params!r}."
            )
        names = list(params)
        twice = sorted({n for n in names if names.count(n) > 1})
        if twice:
            raise ValueError(
                f"params names {', '.join(map(repr, twice))} twice; each register is one "
                f"action entry; got params={tuple(params)!r}."
            )
        for name in names:
            space[name]  # unknown names raise with close matches
            if name in fixed_values:
                raise ValueError(
                    f"a parameter is either set by the action or fixed, not both; "
                    f"got {name!r} in params and in fixed={dict(fixed)!r}."
                )
    if not names:
        raise ValueError(
            f"the action must set at least one parameter; every tunable parameter of "
            f"{chip_model} is fixed ({', '.join(fixed_values)})."
        )
    return tuple(space[n] for n in names), fixed_values


def check_box_action(action: Any, specs: Sequence[ParamSpec], shape: tuple[int, ...]) -> np.ndarray:
    """``action`` as a float64 array of ``shape``, one entry per spec in [-1, 1].

    Raises:
        ValueError: for a wrong shape or a non-numeric action, or an entry that is NaN,
            infinite or outside [-1, 1]; the message names the index, the parameter and the
            value.
    """
    names = [s.name for s in specs]
    kind = np.asarray(action).dtype.kind
    if kind not in "iuf":  # complex (its imaginary part would be dropped), bool, text
        raise ValueError(
            f"the action must be an array of {len(names)} real numbers in [-1, 1] "
            f"({', '.join(names)}); got {action!r} of dtype {np.asarray(action).dtype}."
        )
    try:
        a = np.asarray(action, dtype=np.float64)
    except (TypeError, ValueError):
        raise ValueError(
            f"the action must be an array of {len(names)} numbers in [-1, 1] "
            f"({', '.join(names)}); got {action!r}."
        ) from None
    if a.shape != shape:
        raise ValueError(
            f"the action must have shape {shape} (one entry per parameter: "
            f"{', '.join(names)}); got shape {a.shape}."
        )
    for i, (spec, u) in enumerate(zip(specs, a, strict=True)):
        if not (math.isfinite(u) and -1.0 <= u <= 1.0):
            raise ValueError(
                f"action[{i}] ({spec.name}) must be a finite number in [-1, 1]; "
                f"got action[{i}]={u!r}."
            )
    return a


def check_raw_action(action: Any, specs: Sequence[ParamSpec], nvec: np.ndarray) -> np.ndarray:
    """``action`` as an integer array, entry ``i`` in ``0 .. nvec[i] - 1``.

    Raises:
        ValueError: for a wrong shape, a non-integer entry or one outside its range.
    """
    a = np.asarray(action)
    if a.shape != nvec.shape or not np.issubdtype(a.dtype, np.integer):
        raise ValueError(
            f"the action must be an integer array of shape {nvec.shape} "
            f"({', '.join(s.name for s in specs)}); got {a.dtype} of shape {a.shape}."
        )
    for i, spec in enumerate(specs):
        n = int(nvec[i])
        if not 0 <= int(a[i]) < n:
            raise ValueError(
                f"action[{i}] ({spec.name}) must satisfy 0 <= action[{i}] <= {n - 1} "
                f"(meaning {spec.range_text}); got action[{i}]={int(a[i])}."
            )
    return a


class UnitActions:
    """A Box in [-1, 1], one entry per register, mapped by :meth:`ParamSpec.from_unit`.

    Log-scaled registers map log-uniformly (0 stays reachable where it is legal), linear ones
    evenly. Registers not in the action keep the chip's default or the value in ``fixed``.

    Args:
        family: The chip family.
        chip_model: The chip model.
        params: Registers the action sets, in order; ``None``: every tunable register of the
            model that is not fixed.
        fixed: Registers held at a given value for the whole env.
    """

    def __init__(
        self,
        family: ChipFamily,
        chip_model: str,
        params: tuple[str, ...] | None = None,
        fixed: Mapping[str, Any] | None = None,
    ) -> None:
        self.family, self.chip_model = family, chip_model
        self.specs, self.fixed = _resolve(family, chip_model, params, fixed or {})
        self.names = tuple(s.name for s in self.specs)
        self.space = spaces.Box(-1.0, 1.0, shape=(len(self.specs),), dtype=np.float32)

    def checked(self, action: Any) -> np.ndarray:
        """``action`` as a float64 array, after checking it (the one check of every Box
        action map: unit, residual, and the axes of :class:`AxesActions`).

        Raises:
            ValueError: for a wrong shape or a non-numeric action, or an entry that is NaN,
                infinite or outside [-1, 1]; the message names the index, the parameter and
                the value.
        """
        return check_box_action(action, self.specs, self.space.shape)

    def to_values(self, action: Any) -> dict[str, int]:
        """Register values of ``action``: the fixed ones, then one per action entry.

        Raises:
            ValueError: as :meth:`checked`.
        """
        a = self.checked(action)
        values = dict(self.fixed)
        for spec, u in zip(self.specs, a, strict=True):
            values[spec.name] = spec.from_unit(float(u))
        return values

    def to_params(self, action: Any) -> Any:
        """The chip parameter set of ``action`` (see :meth:`to_values`)."""
        return _make(self.family, self.chip_model, self.to_values(action))

    def from_values(self, values: Mapping[str, int]) -> np.ndarray:
        """The action closest to ``values`` (registers missing take the chip default).

        Raises:
            ParameterError: for an unknown register or an illegal value.
            ValueError: for a register the action does not set, with another value than the
                env uses for it.
        """
        return self.unit_form(values).astype(np.float32)

    def unit_form(self, values: Mapping[str, int]) -> np.ndarray:
        """:meth:`from_values` in float64: the unit form that maps back to ``values`` exactly
        where float32 cannot resolve it (a 31-bit integration limit); raises as
        :meth:`from_values`."""
        full = _baseline_values(self, values)
        return np.array([s.to_unit(full[s.name]) for s in self.specs], dtype=np.float64)


class RawActions:
    """The registers' own integers: ``MultiDiscrete``, entry ``i`` meaning ``low_i + a[i]``.

    For agents that want the legal integers themselves. Arguments as :class:`UnitActions`.
    """

    def __init__(
        self,
        family: ChipFamily,
        chip_model: str,
        params: tuple[str, ...] | None = None,
        fixed: Mapping[str, Any] | None = None,
    ) -> None:
        self.family, self.chip_model = family, chip_model
        self.specs, self.fixed = _resolve(family, chip_model, params, fixed or {})
        self.names = tuple(s.name for s in self.specs)
        self.lows = np.array([s.low for s in self.specs], dtype=np.int64)
        self.space = spaces.MultiDiscrete(
            np.array([s.high - s.low + 1 for s in self.specs], dtype=np.int64)
        )

    def to_values(self, action: Any) -> dict[str, int]:
        """Register values of ``action`` (``low + action[i]`` for entry ``i``).

        Raises:
            ValueError: for a wrong shape, a non-integer entry or one outside its range.
        """
        a = check_raw_action(action, self.specs, self.space.nvec)
        values = dict(self.fixed)
        for i, spec in enumerate(self.specs):
            values[spec.name] = spec.low + int(a[i])
        return values

    def to_params(self, action: Any) -> Any:
        """The chip parameter set of ``action``."""
        return _make(self.family, self.chip_model, self.to_values(action))

    def from_values(self, values: Mapping[str, int]) -> np.ndarray:
        """The action giving ``values`` (registers missing take the chip default); raises as
        :meth:`UnitActions.from_values` does."""
        full = _baseline_values(self, values)
        return np.array([full[s.name] - s.low for s in self.specs], dtype=np.int64)


DEFAULT_RESIDUAL_SCALE = 0.25
"""How far a residual action reaches from its centre, in unit-form units (see
:class:`ResidualActions`)."""


class ResidualActions:
    """A Box in [-1, 1] around a safe set: unit form ``clip(center + scale * action, -1, 1)``.

    The zero action is the ``center`` set (e.g. a robust fixed set that never diverges on the
    scenario), so an agent whose policy starts near zero starts from a safe set, and learns
    only where scheduling pays. ``scale`` bounds how far it reaches (0.25: a quarter of each
    register's unit range, a factor of about 6 on a log-scaled 16-bit gain either way).

    Args:
        family: The chip family.
        chip_model: The chip model.
        params: Registers the action sets (as :class:`UnitActions`).
        fixed: Registers held at a value.
        center: Register values of the centre set; registers missing take the chip default
            (or their ``fixed`` value).
        scale: Reach in unit-form units, ``0 < scale <= 2``.
    """

    def __init__(
        self,
        family: ChipFamily,
        chip_model: str,
        params: tuple[str, ...] | None = None,
        fixed: Mapping[str, Any] | None = None,
        center: Mapping[str, Any] | None = None,
        scale: float = DEFAULT_RESIDUAL_SCALE,
    ) -> None:
        if (
            isinstance(scale, bool)
            or not isinstance(scale, int | float)
            or not (math.isfinite(scale) and 0 < scale <= 2)
        ):
            raise ValueError(
                f"residual_scale must satisfy 0 < residual_scale <= 2 (unit-form units); got "
                f"residual_scale={scale!r}."
            )
        if center is None:
            raise ValueError(
                "action_type='residual' needs center= (register values of a safe set, e.g. "
                "{'kp': 34, 'kd': 107}); this chip family and plant have no default one."
            )
        self.unit = UnitActions(family, chip_model, params, fixed)
        self.family, self.chip_model = family, chip_model
        self.specs, self.fixed, self.names = self.unit.specs, self.unit.fixed, self.unit.names
        self.space = self.unit.space
        # float64: the zero action is the centre to the count, even a 31-bit register's
        self.center = self.unit.unit_form(center)
        self.center_values = self.unit.to_values(self.center)
        self.scale = float(scale)

    def set_center(self, center: Mapping[str, Any]) -> None:
        """Act around another set from now on (a gain table's row: ``center_table``)."""
        self.center = self.unit.unit_form(center)
        self.center_values = self.unit.to_values(self.center)

    def absolute(self, action: Any) -> np.ndarray:
        """The unit-form action of the underlying :class:`UnitActions` (validated, clipped).

        Raises:
            ValueError: as :meth:`UnitActions.checked` (shape, NaN, outside [-1, 1]).
        """
        a = self.unit.checked(action)
        return np.clip(self.center + self.scale * a, -1.0, 1.0)

    def to_values(self, action: Any) -> dict[str, int]:
        """Register values of ``action`` (see :meth:`absolute`)."""
        return self.unit.to_values(self.absolute(action))

    def to_params(self, action: Any) -> Any:
        """The chip parameter set of ``action``."""
        return _make(self.family, self.chip_model, self.to_values(action))

    def from_values(self, values: Mapping[str, int]) -> np.ndarray:
        """The action closest to ``values`` (clipped to the box: a set further than
        ``scale`` from the centre is out of reach); raises as :meth:`UnitActions.from_values`."""
        u = self.unit.unit_form(values)
        return np.clip((u - self.center) / self.scale, -1.0, 1.0).astype(np.float32)


class AxesActions:
    """The actions of every axis of one controller side by side: one action for a machine.

    Each axis has its own action map (:class:`UnitActions`, :class:`RawActions` or
    :class:`ResidualActions` of the one chip model); the action is theirs concatenated in
    axis order, and its entries are named ``<register>.<axis number>`` (``kp.1`` ... for axis
    1, then ``kp.2`` ...). Checks name the entry's index in the whole action.

    Args:
        axes: The axis names, in axis order.
        maps: One action map per axis, all Box or all MultiDiscrete.
    """

    def __init__(self, axes: tuple[str, ...], maps: tuple[Any, ...]) -> None:
        from servogym.envs._machine import axis_register

        if len(axes) != len(maps) or not maps:
            raise ValueError(f"give one action map per axis ({len(axes)}); got {len(maps)}.")
        self.axes, self.maps = tuple(axes), tuple(maps)
        self.family, self.chip_model = maps[0].family, maps[0].chip_model
        self.specs = tuple(
            dataclasses.replace(s, name=axis_register(k, s.name))
            for k, m in enumerate(self.maps, start=1)
            for s in m.specs
        )
        self.names = tuple(s.name for s in self.specs)
        self.fixed = {
            axis_register(i, k): v
            for i, m in enumerate(self.maps, start=1)
            for k, v in m.fixed.items()
        }
        self._cuts = np.cumsum([len(m.names) for m in self.maps])[:-1]
        if all(isinstance(m.space, spaces.Box) for m in self.maps):
            self.space = spaces.Box(-1.0, 1.0, shape=(len(self.specs),), dtype=np.float32)
        elif all(isinstance(m.space, spaces.MultiDiscrete) for m in self.maps):
            self.space = spaces.MultiDiscrete(np.concatenate([m.space.nvec for m in self.maps]))
        else:
            raise ValueError("the axes' action maps must be all Box or all MultiDiscrete")

    def _parts(self, action: Any) -> list[np.ndarray]:
        if isinstance(self.space, spaces.Box):
            a = check_box_action(action, self.specs, self.space.shape)
        else:
            a = check_raw_action(action, self.specs, self.space.nvec)
        return np.split(a, self._cuts)

    def axis_values(self, action: Any) -> list[dict[str, int]]:
        """Per axis, its complete register values (the map's ``to_values``).

        Raises:
            ValueError: for a wrong shape or type, or an entry outside its range, naming the
                index in the whole action and the entry's ``<register>.<axis number>`` name.
        """
        return [m.to_values(p) for m, p in zip(self.maps, self._parts(action), strict=True)]

    def to_values(self, action: Any) -> dict[str, int]:
        """Every axis's register values, named ``<register>.<axis number>``."""
        from servogym.envs._machine import axis_register

        return {
            axis_register(i, k): v
            for i, values in enumerate(self.axis_values(action), start=1)
            for k, v in values.items()
        }

    def to_params(self, action: Any) -> list[Any]:
        """One chip parameter set per axis, in axis order."""
        return [m.to_params(p) for m, p in zip(self.maps, self._parts(action), strict=True)]

    def from_values(self, values: Any) -> np.ndarray:
        """The action closest to ``values``: a mapping (``<register>.<axis number>`` for one axis, a
        plain register name for every axis) or one mapping per axis; raises as the axes'
        maps do."""
        from servogym.envs._machine import per_axis

        split = per_axis(values, self.axes, "values")
        return np.concatenate([m.from_values(v) for m, v in zip(self.maps, split, strict=True)])

    @property
    def center_values(self) -> dict[str, int]:
        """The residual maps' centre sets, named ``<register>.<axis number>``."""
        from servogym.envs._machine import axis_register

        return {
            axis_register(i, k): v
            for i, m in enumerate(self.maps, start=1)
            for k, v in m.center_values.items()
        }


ACTION_TYPES = {"unit": UnitActions, "raw": RawActions, "residual": ResidualActions}
"""Built-in action maps by name: ``"unit"`` (Box in [-1, 1]), ``"raw"`` (MultiDiscrete) and
``"residual"`` (Box in [-1, 1] around a safe set, :class:`ResidualActions`)."""


def make_action_map(
    action_type: str | Any,
    family: ChipFamily,
    chip_model: str,
    params: tuple[str, ...] | None,
    fixed: Mapping[str, Any] | None,
    *,
    center: Any = None,
    residual_scale: float = DEFAULT_RESIDUAL_SCALE,
    axes: tuple[str, ...] | None = None,
) -> Any:
    """An action map by name, or ``action_type`` itself when it is already one.

    ``center`` and ``residual_scale`` are those of ``"residual"`` (:class:`ResidualActions`).
    With ``axes`` (a machine's axis names), one map per axis side by side
    (:class:`AxesActions`): ``params``, ``fixed`` and ``center`` are then split by axis
    (``servogym.envs._machine.per_axis``: ``<register>.<axis number>`` for one axis, a plain name
    for every axis), and registers the machine holds for its axes (a PMD chip's time-sliced
    ``sample_time_us``) are fixed on every axis.
    """
    if not isinstance(action_type, str):
        return action_type
    try:
        cls = ACTION_TYPES[action_type]
    except KeyError:
        raise ValueError(
            f"action_type must be one of {', '.join(map(repr, ACTION_TYPES))} or an action "
            f"map object; got action_type={action_type!r}."
        ) from None
    if axes is not None:
        from servogym.envs._machine import machine_fixed, per_axis

        held = machine_fixed(chip_model, len(axes))
        fixes = per_axis(fixed, axes, "fixed")
        names = _axis_params(params, axes)
        centers = per_axis(center, axes, "center") if center is not None else [None] * len(axes)
        maps = tuple(
            _one_map(cls, family, chip_model, p, {**held, **f}, c, residual_scale)
            for p, f, c in zip(names, fixes, centers, strict=True)
        )
        return AxesActions(axes, maps)
    return _one_map(cls, family, chip_model, params, fixed, center, residual_scale)


def _one_map(cls, family, chip_model, params, fixed, center, residual_scale) -> Any:
    if cls is ResidualActions:
        return cls(family, chip_model, params, fixed, center, residual_scale)
    return cls(family, chip_model, params, fixed)


def _axis_params(
    params: tuple[str, ...] | None, axes: tuple[str, ...]
) -> list[tuple[str, ...] | None]:
    """Per axis, the registers its action sets: a plain name on every axis, an
    ``<register>.<axis number>`` name on its own; ``None``: every tunable one."""
    from servogym.envs._machine import split_register

    if params is None:
        return [None] * len(axes)
    if isinstance(params, str) or not all(isinstance(n, str) for n in params):
        raise ValueError(
            f"params must be a sequence of register names, e.g. ('kp', 'kd.2'); got "
            f"params={params!r}."
        )
    out: list[list[str]] = [[] for _ in axes]
    for name in params:
        k, register = split_register(name, axes, "params")
        for names in out if k is None else [out[k]]:
            names.append(register)
    for axis, names in zip(axes, out, strict=True):
        if not names:
            raise ValueError(
                f"params sets no register of axis {axes.index(axis) + 1} ({axis}); name one on "
                f"every axis (a plain name such as 'kp' sets it on all); got "
                f"params={tuple(params)!r}."
            )
    return [tuple(n) for n in out]


def _make(family: ChipFamily, chip_model: str, values: Mapping[str, int]) -> Any:
    try:
        return family.make_params(chip_model, values)
    except ParameterError as e:  # a combination the chip model rejects
        raise ValueError(f"the action gives an illegal parameter set: {e}") from e
