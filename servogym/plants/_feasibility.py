"""Can the motor move this plant instance with these moves? The peak torque the moves need.

:func:`required_peak_effort` reads the plant's joint-space inertia, gravity and friction from
the compiled MuJoCo model itself (``mj_fullM`` and ``qfrc_bias`` at the positions the moves
visit, ``dof_frictionloss``, ``dof_damping``, ``actuator_gear``), so the figure cannot drift
from the model the runner integrates, and compares the motor-shaft torque it adds up to with
the motor's peak (amplifier saturation current times torque constant). A value the motor
cannot move with the run's moves is refused (:class:`MotorFeasibilityError`) with one line
naming the parameter, the value, the torque it needs and what the motor has.

The rule (docs/plants.md, "What the motor can move"): the moves may need at most
:data:`PEAK_HEADROOM` of the motor's peak torque; the rest is the feedback's, to correct
errors, without living at the torque limit.
"""

from __future__ import annotations

import dataclasses
import itertools
import math
from collections.abc import Iterable, Mapping, Sequence
from typing import Any

import mujoco
import numpy as np

from servogym.plants._base import Plant, PlantFamily, PlantParameterError, _fmt

PEAK_HEADROOM = 0.8
"""Largest fraction of the motor's peak torque the moves may need (the feed-forward part:
inertia x acceleration + gravity + friction). The remaining 20 % is what the feedback has to
correct errors at the peak of a move; a set that needs 100 % lives at the torque limit on every
acceleration, which the tuners' saturation constraint (5 % of ticks) refuses anyway."""

GRAVITY_POINTS = 65
"""Positions per move at which the gravity torque and the inertia are evaluated."""

MAX_CORNERS = 4096
"""Most corners of a box of ranges :func:`check_motor_box` evaluates (12 ranged parameters)."""


class MotorFeasibilityError(PlantParameterError):
    """A plant instance needs more torque for the moves than the motor has (a ValueError)."""


@dataclasses.dataclass(frozen=True)
class Need:
    """The peak motor-shaft torque a plant instance needs for a sequence of moves.

    Every term is at the motor shaft, in N*m (a joint force or torque divided by the actuator
    gear: the gear ratio, or ``2*pi / screw_lead_m`` for a ball screw), and each is its worst
    over the moves; a trapezoidal move reaches nearly all of them at once at the end of its
    acceleration, so :attr:`total_nm` is the peak torque (an upper bound).

    Attributes:
        family: Plant family name.
        inertia_nm: Joint-space inertia (``mj_fullM``, rotor or armature included, largest over
            the positions visited) times the largest ``max_acceleration`` of the moves.
        gravity_nm: Largest ``|qfrc_bias|`` at rest over the positions the moves visit (the
            arm's gravity changes with its angle).
        coulomb_nm: Coulomb friction (``dof_frictionloss``).
        viscous_nm: Viscous friction (``dof_damping``) at the moves' peak velocity
            (``min(max_velocity, sqrt(|distance| * max_acceleration))``).
        peak_nm: The motor's peak torque, ``peak_current_a * torque_constant_nm_per_a``.
        headroom: Fraction of ``peak_nm`` the moves may need (:data:`PEAK_HEADROOM`).
    """

    family: str
    inertia_nm: float
    gravity_nm: float
    coulomb_nm: float
    viscous_nm: float
    peak_nm: float
    headroom: float = PEAK_HEADROOM

    @property
    def total_nm(self) -> float:
        """The peak torque the moves need, N*m at the motor shaft."""
        return self.inertia_nm + self.gravity_nm + self.coulomb_nm + self.viscous_nm

    @property
    def available_nm(self) -> float:
        """What the moves may use: ``headroom * peak_nm``, in N*m."""
        return self.headroom * self.peak_nm

    @property
    def fraction(self) -> float:
        """``total_nm / peak_nm``: the fraction of the motor's peak the moves need."""
        return self.total_nm / self.peak_nm if self.peak_nm > 0 else math.inf

    @property
    def feasible(self) -> bool:
        """Whether ``total_nm <= headroom * peak_nm``."""
        return self.total_nm <= self.available_nm

    def text(self) -> str:
        """``2.31 N*m at the motor shaft (inertia 0.86 + gravity 1.43 + ...)``."""
        return (
            f"{self.total_nm:.3g} N*m at the motor shaft (inertia {self.inertia_nm:.3g} + "
            f"gravity {self.gravity_nm:.3g} + Coulomb {self.coulomb_nm:.3g} + viscous "
            f"{self.viscous_nm:.3g}), {self.fraction:.0%} of the motor's peak"
        )

    def motor_text(self) -> str:
        """``the motor has 2 N*m peak, 1.6 N*m (80 %) for the moves``."""
        return (
            f"the motor has {self.peak_nm:.3g} N*m peak (peak_current_a x "
            f"torque_constant_nm_per_a), {self.available_nm:.3g} N*m ({self.headroom:.0%}) "
            f"of it for the moves"
        )

    def to_dict(self) -> dict[str, Any]:
        """JSON-ready, with ``total_nm`` and ``fraction``."""
        return dataclasses.asdict(self) | {
            "total_nm": self.total_nm,
            "fraction": self.fraction,
            "feasible": self.feasible,
        }


def _family(family: PlantFamily | str) -> PlantFamily:
    if isinstance(family, PlantFamily):
        return family
    from servogym.plants._registry import get_plant

    return get_plant(family)


def default_moves(family: PlantFamily | str) -> tuple[Any, ...]:
    """The family's default evaluation moves (``servogym.sim.DEFAULT_MOVES``)."""
    from servogym.sim._scenario import DEFAULT_MOVES

    return DEFAULT_MOVES[_family(family).name]


def _moves(family: PlantFamily, moves: Sequence[Any] | None) -> tuple[Any, ...]:
    out = tuple(moves) if moves else default_moves(family)
    for m in out:
        for attr in ("distance", "max_velocity", "max_acceleration"):
            value = getattr(m, attr)
            if not math.isfinite(float(value)):
                raise ValueError(f"a move's {attr} must be finite; got {attr}={value!r}.")
    return out


def _visited(start: float, moves: Sequence[Any]) -> np.ndarray:
    """Positions (joint units) along the moves, run one after the other from ``start``."""
    points, q = [start], start
    for m in moves:
        points.append(np.linspace(q, q + float(m.distance), GRAVITY_POINTS))
        q += float(m.distance)
    return np.unique(np.hstack(points))


def _need_of(plant: Plant, moves: Sequence[Any], headroom: float) -> Need:
    """The need of the plant's current instance (its state is reset afterwards)."""
    model, data = plant.model, plant.data
    dof = plant.io.qvel_adr
    full = np.zeros((model.nv, model.nv))
    inertia = gravity = 0.0
    for q in _visited(plant.io.start_qpos, moves):
        mujoco.mj_resetData(model, data)
        data.qpos[plant.io.qpos_adr] = q
        mujoco.mj_forward(model, data)
        mujoco.mj_fullM(model, data, full)
        inertia = max(inertia, float(full[dof, dof]))
        gravity = max(gravity, abs(float(data.qfrc_bias[dof])))
    plant.reset()
    accel = max(abs(float(m.max_acceleration)) for m in moves)
    velocity = max(
        min(abs(float(m.max_velocity)), math.sqrt(abs(float(m.distance) * m.max_acceleration)))
        for m in moves
    )
    gear = float(model.actuator_gear[plant.io.ctrl_index, 0])
    return Need(
        family=plant.family.name,
        inertia_nm=inertia * accel / gear,
        gravity_nm=gravity / gear,
        coulomb_nm=float(model.dof_frictionloss[dof]) / gear,
        viscous_nm=float(model.dof_damping[dof]) * velocity / gear,
        peak_nm=plant.io.peak_torque_nm,
        headroom=headroom,
    )


def required_peak_effort(
    family: PlantFamily | str,
    values: Mapping[str, Any] | None = None,
    moves: Sequence[Any] | None = None,
    *,
    headroom: float = PEAK_HEADROOM,
    plant: Plant | None = None,
) -> Need:
    """The peak motor torque ``moves`` need on the instance ``values`` of ``family``.

    Args:
        family: A plant family or its name.
        values: Some or all parameters (missing ones nominal), validated.
        moves: Objects with ``distance``, ``max_velocity`` and ``max_acceleration`` in joint
            units (``servogym.sim.MoveSpec``), run one after the other from the start
            position; empty or ``None``: the family's default moves.
        headroom: Fraction of the motor's peak the moves may need, ``0 < headroom <= 1``.
        plant: A compiled plant of ``family`` to reuse (edited in place and reset);
            ``None`` compiles one.

    Returns:
        The :class:`Need`, each term at the motor shaft in N*m.

    Raises:
        PlantParameterError: for an unknown parameter or an illegal value.
    """
    fam = _family(family)
    mv = _moves(fam, moves)
    if plant is None:
        plant = fam.build(values)
    else:
        plant.set_params(fam.validate(values))
    return _need_of(plant, mv, headroom)


def _describe(
    values: Mapping[str, Any], names: Iterable[str], what: Mapping[str, str] | None = None
) -> str:
    what = what or {}
    return ", ".join(
        f"{n}={_fmt(values[n])}" + (f" ({what[n]})" if n in what else "") for n in names
    )


def _limit(
    plant: Plant, base: Mapping[str, Any], name: str, moves: Sequence[Any], headroom: float
) -> tuple[float, float] | None:
    """The sub-range of ``name``'s legal range the motor can move (bisection; None: none)."""
    fam = plant.family
    p = fam.param(name)

    def ok(x: float) -> bool:
        plant.set_params({**base, name: round(x) if p.integer else x})
        return _need_of(plant, moves, headroom).feasible

    lo, hi = p.low, p.high
    log = p.distribution == "loguniform"

    def mid(a: float, b: float) -> float:
        return math.sqrt(a * b) if log else 0.5 * (a + b)

    ok_lo, ok_hi = ok(lo), ok(hi)
    if ok_lo and ok_hi:
        return lo, hi
    anchor = next((x for x in (p.nominal, lo, hi) if ok(x)), None)
    if anchor is None:
        return None
    out = [lo, hi]
    for side, bad in ((0, lo), (1, hi)):
        if (ok_lo, ok_hi)[side]:
            continue
        good = anchor
        for _ in range(48):
            m = mid(good, bad)
            if ok(m):
                good = m
            else:
                bad = m
        out[side] = good
    return out[0], out[1]


def feasible_range(
    family: PlantFamily | str,
    name: str,
    values: Mapping[str, Any] | None = None,
    moves: Sequence[Any] | None = None,
    *,
    headroom: float = PEAK_HEADROOM,
) -> tuple[float, float] | None:
    """The part of ``name``'s legal range the motor can move with ``moves``.

    The other parameters are ``values`` (missing ones nominal). The need is monotone or
    convex in every parameter of the built-in families, so the movable values form one
    interval, found by bisection (to about 1e-12 relative).

    Returns:
        ``(low, high)`` within the legal range, or ``None`` if no value is movable.
    """
    fam = _family(family)
    mv = _moves(fam, moves)
    base = fam.validate(values)
    plant = fam.build(base)
    return _limit(plant, base, name, mv, headroom)


def check_motor(
    family: PlantFamily | str,
    base: Mapping[str, Any] | None = None,
    ranges: Mapping[str, tuple[float, float]] | None = None,
    moves: Sequence[Any] | None = None,
    *,
    what: Mapping[str, str] | None = None,
    headroom: float = PEAK_HEADROOM,
) -> Need:
    """Refuse a plant instance, or a box of them, that the motor cannot move with ``moves``.

    Every corner of the box ``ranges`` (each parameter at its low or high end, the others at
    ``base``) is evaluated: the need is monotone or convex in every parameter of the
    built-in families, so its largest value over the box is at a corner.

    Args:
        family: A plant family or its name.
        base: The instance's values (missing ones nominal).
        ranges: ``name -> (low, high)`` of the parameters that vary (drawn), or ``None``.
        moves: The run's moves (``None``: the family's default moves).
        what: Where a parameter's value comes from, by name, for the message (e.g.
            ``{"payload_kg": "--plant-range end"}``).
        headroom: Fraction of the motor's peak the moves may need.

    Returns:
        The largest need over the box.

    Raises:
        MotorFeasibilityError: naming the parameter(s), value(s), the torque needed and what
            the motor has, and the movable part of the range when there is one.
    """
    fam = _family(family)
    mv = _moves(fam, moves)
    base = fam.validate(base)
    ranges = dict(ranges or {})
    names = [p.name for p in fam.params if p.name in ranges]
    if 2 ** len(names) > MAX_CORNERS:
        raise ValueError(
            f"at most {int(math.log2(MAX_CORNERS))} plant parameters may vary at once; got "
            f"{len(names)}: {', '.join(names)}."
        )
    plant = fam.build(base)
    worst: tuple[Need, dict[str, Any]] | None = None
    corners = itertools.product(*[sorted(set(ranges[n])) for n in names]) if names else [()]
    for corner in corners:
        values = {**base, **dict(zip(names, corner, strict=True))}
        plant.set_params(values)
        need = _need_of(plant, mv, headroom)
        if worst is None or need.total_nm > worst[0].total_nm:
            worst = (need, values)
        if not need.feasible:
            raise MotorFeasibilityError(
                _refusal(plant, fam, base, values, names, need, mv, headroom, what or {})
            )
    return worst[0]  # type: ignore[index]  (the loop runs at least once)


def _refusal(
    plant: Plant,
    fam: PlantFamily,
    base: Mapping[str, Any],
    values: Mapping[str, Any],
    names: Sequence[str],
    need: Need,
    moves: Sequence[Any],
    headroom: float,
    what: Mapping[str, str],
) -> str:
    """The one-line refusal (see :func:`check_motor`)."""
    nominal = fam.nominal()
    named = [n for n in names if values[n] != nominal[n]] or list(names)
    named += [n for n in what if n not in named and n in values]
    if not named:
        named = [n for n in fam.randomised()]
    hint = ""
    if len(named) == 1:
        movable = _limit(plant, {**values}, named[0], moves, headroom)
        p = fam.param(named[0])
        if movable is not None:
            hint = (
                f"; the motor can move {_fmt_range(p.name, movable)} ({p.unit}) with these "
                "moves, the other parameters as here"
            )
        else:
            hint = f"; no value of {p.name} in its legal range {p.range_text} is movable"
    return (
        f"the motor cannot move the {fam.name!r} plant with {_describe(values, named, what)} "
        f"through the moves: it needs {need.text()}; {need.motor_text()}{hint}."
    )


def round_inward(low: float, high: float, digits: int = 4) -> tuple[float, float]:
    """``low`` rounded up and ``high`` rounded down to ``digits`` significant digits.

    A movable range printed this way stays movable: every value it shows is inside.
    """

    def step(x: float) -> float:
        return 10.0 ** (math.floor(math.log10(abs(x))) - digits + 1) if x else 1.0

    lo = math.ceil(round(low / step(low), 6)) * step(low) if low else 0.0
    hi = math.floor(round(high / step(high), 6)) * step(high) if high else 0.0
    lo, hi = float(f"{lo:.{digits}g}"), float(f"{hi:.{digits}g}")
    return (min(lo, hi), hi) if lo <= high else (low, high)


def _fmt_range(name: str, r: tuple[float, float]) -> str:
    lo, hi = round_inward(*r)
    return f"{lo:.4g} <= {name} <= {hi:.4g}"


def feasibility_rows(headroom: float = PEAK_HEADROOM) -> list[dict[str, Any]]:
    """What the default motor moves with the default moves, for every registered family.

    One row per family and parameter whose movable part (the other parameters nominal) is
    not its whole legal range, plus one ``"nominal"`` and one ``"sampled box"`` row per
    family (the nominal plant; the worst corner of the default sampling ranges of the
    randomised parameters). Computed with :func:`required_peak_effort` from the models.
    """
    from servogym.plants._registry import PLANTS

    rows: list[dict[str, Any]] = []
    for fam in PLANTS.values():
        moves = default_moves(fam)
        rows.append({"family": fam.name, "what": "nominal", "need": required_peak_effort(fam)})
        box = fam.sample_bounds()
        worst = check_motor(fam, None, box, moves, headroom=1e9)  # the need, never refused
        rows.append({"family": fam.name, "what": "sampled box", "need": worst})
        nominal = fam.nominal()
        for p in fam.params:
            movable = feasible_range(fam, p.name, nominal, moves, headroom=headroom)
            if movable != (p.low, p.high):
                rows.append({"family": fam.name, "what": p.name, "movable": movable, "param": p})
    return rows


def feasibility_table_markdown(headroom: float = PEAK_HEADROOM) -> str:
    """The table of docs/plants.md, "What the motor can move" (see :func:`feasibility_rows`)."""
    lines = [
        "| Family | Case | Peak torque needed (N*m) | Of the 2 N*m peak | Movable part of the "
        "legal range (others nominal) |",
        "|---|---|---|---|---|",
    ]
    for row in feasibility_rows(headroom):
        if "need" in row:
            n = row["need"]
            case = (
                "nominal plant"
                if row["what"] == "nominal"
                else "worst corner of the sampled ranges"
            )
            lines.append(
                f"| {row['family']} | {case} | {n.total_nm:.3g} (inertia {n.inertia_nm:.3g}, "
                f"gravity {n.gravity_nm:.3g}, Coulomb {n.coulomb_nm:.3g}, viscous "
                f"{n.viscous_nm:.3g}) | {n.fraction:.0%} | |"
            )
        else:
            p = row["param"]
            movable = row["movable"]
            text = "none" if movable is None else f"{_fmt_range(p.name, movable)} ({p.unit})"
            lines.append(
                f"| {row['family']} | `{p.name}` (legal {_fmt(p.low)} .. {_fmt(p.high)}) | "
                f"| | {text} |"
            )
    return "\n".join(lines)
