"""6000-series move profiles (A, V, D trapezoid; S-curve), in whole-count integer arithmetic.

The controller computes the commanded trajectory once every SSFR servo samples (the motion
trajectory update period: 330, 370, 640 or 1200 us) [A: the APEX615n guide's SSFR table];
the servo loop runs every sample.
Here a move is a sequence of per-trajectory-period distances in micro-counts, integrated
exactly and spread over the servo samples of each period (docs/chips/parker6k.md, section 6,
assumptions PK-P1 ... PK-P6; the switchable ones are :class:`ProfileAssumptions`).

Kernel inputs per servo sample: ``position`` in whole counts (signed 32-bit, wrapped),
``velocity`` in counts/s and ``acceleration`` in counts/s^2 (integers).
"""

from __future__ import annotations

import dataclasses
import math
import numbers
from typing import Any, ClassVar

import numpy as np

from servogym.chips._assumptions import AssumptionSet
from servogym.chips._profiles import TickArrays, check_arrays, int_arg
from servogym.chips._space import ParameterError
from servogym.chips.parker6k._params import SSFR_PERIOD_US

MICRO = 1_000_000
S32_MIN, S32_MAX = -(2**31), 2**31 - 1
MAX_TICKS = 1 << 24
"""Longest profile this module builds, in servo samples (16,777,216; 45 min at 160 us)."""
MAX_VELOCITY = 1e9
"""Largest velocity limit accepted, counts/s."""
MAX_ACCELERATION = 1e12
"""Largest acceleration limit accepted, counts/s^2."""

PROFILE_ASSUMPTION_CHOICES: dict[str, tuple[str, ...]] = {
    "interpolation": ("linear", "hold"),  # PK-P2
    "position_rounding": ("floor", "nearest"),  # PK-P3
}
PROFILE_ASSUMPTION_IDS: dict[str, str] = {"interpolation": "PK-P2", "position_rounding": "PK-P3"}


@dataclasses.dataclass(frozen=True)
class ProfileAssumptions(AssumptionSet):
    """Switches for the profile behaviours no source settles (PK-P2, PK-P3).

    Attributes:
        interpolation: PK-P2. Between two trajectory updates the commanded position moves
            ``"linear"``-ly (each servo sample adds 1/SSFR of the period's distance), or is
            ``"hold"``-ed at the newest trajectory point (a staircase).
        position_rounding: PK-P3. Whole counts from micro-counts: ``"floor"`` or
            ``"nearest"`` (halves away from the start), on the distance travelled.
    """

    CHOICES: ClassVar[dict[str, tuple[str, ...]]] = PROFILE_ASSUMPTION_CHOICES
    IDS: ClassVar[dict[str, str]] = PROFILE_ASSUMPTION_IDS

    interpolation: str = "linear"
    position_rounding: str = "floor"


@dataclasses.dataclass(frozen=True, eq=False)
class Parker6kProfile(TickArrays):
    """A commanded move, one entry per servo sample.

    Entry 0 is the first servo sample after the move starts. The arrays are 1-D, C-contiguous
    ``np.int64`` of length ``n_ticks``; treat them as read-only.

    Attributes:
        position: Commanded position in counts, wrapped to signed 32 bits.
        velocity: Commanded velocity in counts/s (the trajectory period's, held over it).
        acceleration: Commanded acceleration in counts/s^2 (the change of the trajectory
            velocity at the period's update, held over it).
        start: Position at rest before the move (counts).
        move_ticks: Entries up to and including the trajectory period in which the velocity
            returns to 0 on the target; the rest hold the target.
        ssfr: Servo samples per trajectory update.
    """

    position: np.ndarray
    velocity: np.ndarray
    acceleration: np.ndarray
    start: int
    move_ticks: int
    ssfr: int = 1

    def __post_init__(self) -> None:
        check_arrays(self)


def _real(name: str, value: Any, high: float) -> float:
    if isinstance(value, bool) or not isinstance(value, numbers.Real):
        raise ParameterError(
            f"{name} must be a finite number with 0 < {name} <= {high:g}; got {name}={value!r} "
            f"of type {type(value).__name__}."
        )
    x = float(value)
    if not (math.isfinite(x) and 0 < x <= high):
        raise ParameterError(f"{name} must satisfy 0 < {name} <= {high:g}; got {name}={value!r}.")
    return x


_int = int_arg


def ssfr_of(sample_time_s: Any) -> int:
    """The SSFR whose servo period is ``sample_time_s`` (330, 185, 160 or 150 us)."""
    for ssfr, period in SSFR_PERIOD_US.items():
        if isinstance(sample_time_s, numbers.Real) and math.isclose(
            float(sample_time_s), period / MICRO, rel_tol=1e-9
        ):
            return ssfr
    raise ParameterError(
        "sample_time_s must be a 6000-series servo period, one of 330e-6 (SSFR1), 185e-6 "
        f"(SSFR2), 160e-6 (SSFR4), 150e-6 (SSFR8); got sample_time_s={sample_time_s!r}."
    )


def _plan(d: int, v: int, a: int) -> tuple[int, int, int, int]:
    """``(m, cruise, n_cruise, remainder)`` of the PK-P4 trapezoid (see :func:`period_steps`)."""
    m = min(v // a, math.isqrt(d // a))
    cruise = m * a if m else v
    n_cruise, remainder = divmod(d - a * m * m, cruise)
    return m, cruise, n_cruise, remainder


def _n_periods(d: int, v: int, a: int) -> int:
    m, _, n_cruise, remainder = _plan(d, v, a)
    return m + n_cruise + max(m - 1, 0) + (1 if remainder else 0) + 1


def period_steps(distance_ucounts: int, velocity: int, acceleration: int) -> np.ndarray:
    """The trapezoid's distance per trajectory period (PK-P4), ending with one 0.

    Args:
        distance_ucounts: Move length D in micro-counts, >= 0.
        velocity: Velocity limit V in micro-counts per period, >= 1.
        acceleration: Rate A in micro-counts per period^2, >= 1.

    Returns:
        int64 distances ``A, 2A, ..., mA``, then ``mA`` (or V when m = 0) repeated, then
        ``(m-1)A, ..., A`` with the remainder inserted where it keeps the sequence falling,
        then 0. They sum to D. ``m`` is the largest integer with ``m*A <= V`` and
        ``m*m*A <= D``.
    """
    a = acceleration
    m, cruise, n_cruise, remainder = _plan(distance_ucounts, velocity, a)
    up = a * np.arange(1, m + 1, dtype=np.int64)
    down = up[-2::-1] if m > 1 else np.zeros(0, np.int64)
    if remainder:
        at = int(np.count_nonzero(down >= remainder))
        down = np.concatenate([down[:at], np.array([remainder], np.int64), down[at:]])
    return np.concatenate([up, np.full(n_cruise, cruise, np.int64), down, np.zeros(1, np.int64)])


def _smooth(steps: np.ndarray, window: int) -> np.ndarray:
    """PK-P6: the positions averaged over ``window`` periods (floor), as per-period steps."""
    if window <= 1:
        return steps
    total = int(steps.sum())
    points = np.concatenate([np.cumsum(steps), np.full(window - 1, total, np.int64)])
    if total * window < (1 << 62):
        summed = np.cumsum(points)
        summed[window:] -= summed[:-window].copy()
        averaged = summed // window
    else:  # Python integers: window * distance does not fit 63 bits
        obj = np.cumsum(points.astype(object))
        obj[window:] = obj[window:] - obj[:-window].copy()
        averaged = (obj // window).astype(np.int64)
    return np.diff(averaged, prepend=np.int64(0))


def move(
    start: int,
    distance: int,
    max_velocity_counts_per_s: float,
    max_acceleration_counts_per_s2: float,
    ssfr: int,
    *,
    kind: str = "trapezoidal",
    jerk_counts_per_s3: float | None = None,
    settle_ticks: int = 0,
    assumptions: ProfileAssumptions | None = None,
) -> Parker6kProfile:
    """A point-to-point move (``D``, ``V``, ``A`` = ``AD``) followed by a settle time at rest.

    Args:
        start: Position at rest before the move, counts, signed 32-bit.
        distance: Signed move length in counts, -2,147,483,648 .. 2,147,483,647; the target
            is ``start + distance`` wrapped to 32 bits.
        max_velocity_counts_per_s: V in counts/s, 0 < V <= 1e9; must convert to at least 1
            micro-count per trajectory period.
        max_acceleration_counts_per_s2: A (and AD) in counts/s^2, 0 < A <= 1e12; must convert
            to at least 1 micro-count per period^2.
        ssfr: Servo samples per trajectory update, one of 1, 2, 4, 8.
        kind: ``"trapezoidal"`` or ``"s_curve"``.
        jerk_counts_per_s3: Jerk for ``"s_curve"`` (counts/s^3, > 0): the trapezoid is
            averaged over ``L = max(1, floor(0.5 + A / (J * Tt)))`` trajectory periods of
            ``Tt`` seconds (PK-P6).
        settle_ticks: Servo samples at rest on the target after the move, 0 .. 16,777,216.
        assumptions: Switches PK-P2, PK-P3.

    Returns:
        The profile.

    Raises:
        ParameterError: for an illegal argument, naming it, its value and the legal range.
    """
    asm = assumptions if assumptions is not None else ProfileAssumptions()
    if not isinstance(asm, ProfileAssumptions):
        raise ParameterError(
            f"assumptions must be a ProfileAssumptions or None; got {type(asm).__name__}."
        )
    if kind not in ("trapezoidal", "s_curve"):
        raise ParameterError(f"kind must be 'trapezoidal' or 's_curve'; got kind={kind!r}.")
    start = _int("start", start, S32_MIN, S32_MAX, "s32 counts")
    distance = _int("distance", distance, S32_MIN, S32_MAX, "s32 counts")
    if isinstance(ssfr, bool) or ssfr not in SSFR_PERIOD_US:
        raise ParameterError(f"ssfr must be one of 1, 2, 4, 8; got ssfr={ssfr!r}.")
    settle_ticks = _int("settle_ticks", settle_ticks, 0, MAX_TICKS, "servo samples")
    vel = _real("max_velocity_counts_per_s", max_velocity_counts_per_s, MAX_VELOCITY)
    acc = _real("max_acceleration_counts_per_s2", max_acceleration_counts_per_s2, MAX_ACCELERATION)
    tt = ssfr * SSFR_PERIOD_US[ssfr]  # trajectory period, us

    # PK-P1: limits per trajectory period, in micro-counts, as host arithmetic rounds them.
    v = math.floor(0.5 + vel * tt)
    a = math.floor(0.5 + acc * tt * tt / MICRO)
    for name, value, got, unit in (
        ("max_velocity_counts_per_s", max_velocity_counts_per_s, v, "per period"),
        ("max_acceleration_counts_per_s2", max_acceleration_counts_per_s2, a, "per period^2"),
    ):
        if got < 1:
            raise ParameterError(
                f"{name} must convert to at least 1 micro-count {unit} at SSFR{ssfr} "
                f"(trajectory period {tt} us); got {name}={value!r}, which converts to {got}."
            )
    window = 1
    if kind == "s_curve":
        if jerk_counts_per_s3 is None:
            raise ParameterError("kind='s_curve' needs jerk_counts_per_s3 > 0; got None.")
        jerk = _real("jerk_counts_per_s3", jerk_counts_per_s3, float("inf"))
        window = max(1, math.floor(0.5 + acc * MICRO / (jerk * tt)))
        if window > MAX_TICKS:
            raise ParameterError(
                f"jerk_counts_per_s3={jerk_counts_per_s3!r} is too small: the S-curve window "
                f"would be {window} trajectory periods (at most {MAX_TICKS})."
            )
    elif jerk_counts_per_s3 is not None:
        raise ParameterError(
            f"jerk_counts_per_s3 applies to kind='s_curve' only; got "
            f"jerk_counts_per_s3={jerk_counts_per_s3!r} with kind={kind!r}."
        )
    d = abs(distance) * MICRO
    move_ticks = (_n_periods(d, v, a) + window - 1) * ssfr
    if move_ticks + settle_ticks > MAX_TICKS:
        raise ParameterError(
            f"the move needs {move_ticks + settle_ticks} servo samples, more than the "
            f"{MAX_TICKS} this module builds; raise the limits or shorten the move."
        )
    steps = _smooth(period_steps(d, v, a), window)
    return _expand(start, distance, steps, ssfr, tt, move_ticks, settle_ticks, asm)


def _round_div(x: np.ndarray, d: int) -> np.ndarray:
    """``x / d`` rounded to nearest, halves away from zero (x int64, d > 0)."""
    mag = (2 * np.abs(x) + d) // (2 * d)
    return np.sign(x) * mag


def _expand(
    start: int,
    distance: int,
    steps: np.ndarray,
    ssfr: int,
    tt: int,
    move_ticks: int,
    settle_ticks: int,
    asm: ProfileAssumptions,
) -> Parker6kProfile:
    sign = -1 if distance < 0 else 1
    points = np.cumsum(steps)  # P_j, end of period j (micro-counts)
    before = points - steps  # P_{j-1}
    i = np.tile(np.arange(1, ssfr + 1, dtype=np.int64), steps.shape[0])
    step_k = np.repeat(steps, ssfr)
    if asm.interpolation == "linear":
        x = np.repeat(before, ssfr) * ssfr + step_k * i  # micro-counts * ssfr
    else:
        x = np.repeat(points, ssfr) * ssfr
    scale = ssfr * MICRO
    if asm.position_rounding == "floor":
        travelled = x // scale
    else:
        travelled = (2 * x + scale) // (2 * scale)
    velocity = _round_div(step_k, tt)  # micro-counts per tt us = counts/s
    change = np.diff(steps, prepend=np.int64(0))
    acceleration = np.repeat(_round_div(change * MICRO, tt * tt), ssfr)
    total = abs(distance)
    position = start + sign * np.concatenate([travelled, np.full(settle_ticks, total, np.int64)])
    position = ((position - S32_MIN) & 0xFFFFFFFF) + S32_MIN
    zeros = np.zeros(settle_ticks, np.int64)
    return Parker6kProfile(
        position=position,
        velocity=sign * np.concatenate([velocity, zeros]),
        acceleration=sign * np.concatenate([acceleration, zeros]),
        start=start,
        move_ticks=move_ticks,
        ssfr=ssfr,
    )
