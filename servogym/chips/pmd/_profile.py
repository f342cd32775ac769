"""PMD trajectory profile generator, in the chip's own units and integer arithmetic.

Positions are 32-bit signed counts; velocities and accelerations are 16.16 fixed point in
counts/cycle and counts/cycle^2 (one least significant bit, "LSB", is 2^-16 counts/cycle);
jerk is 0.32 fixed point in counts/cycle^3. Every point the public sources do not settle is
an assumption PMD-P1 ... PMD-P10 of ``docs/chips/pmd-profile.md``; the ones that change the
per-cycle numbers are switchable through :class:`ProfileAssumptions`.

The per-cycle arithmetic uses Python integers and NumPy int64 only (no floats); the unit
helpers, which convert host quantities in counts/s, use the host's double arithmetic exactly
as PMD's host code does: ``floor(0.5 + 65536 * counts_per_s * T)``.
"""

from __future__ import annotations

import dataclasses
import enum
import math
from collections.abc import Sequence
from typing import Any, ClassVar, NamedTuple

import numpy as np

from servogym.chips._assumptions import AssumptionSet
from servogym.chips._profiles import TickArrays, check_arrays, int_arg, real_arg
from servogym.chips._space import ParameterError

ONE_1616 = 1 << 16
"""One count/cycle (or count/cycle^2) in 16.16 fixed point."""
ONE_032 = 1 << 32
"""One count/cycle^3 in 0.32 fixed point."""
S32_MIN, S32_MAX = -(1 << 31), (1 << 31) - 1
U31_MAX = (1 << 31) - 1
U32_MAX = (1 << 32) - 1
MAX_TICKS = 1 << 24
"""Longest profile this module builds (16,777,216 cycles, 43 min at 154 us)."""


class ProfileMode(enum.IntEnum):
    """PMD profile modes (SetProfileMode); ElectronicGear (3) is not emulated."""

    TRAPEZOIDAL = 0
    VELOCITY_CONTOURING = 1
    S_CURVE = 2


# --------------------------------------------------------------------------------------
# Assumptions
# --------------------------------------------------------------------------------------

PROFILE_ASSUMPTION_CHOICES: dict[str, tuple[str, ...]] = {
    # field name: (default, alternatives...)
    "update_order": ("velocity_first", "position_first"),  # PMD-P2
    "position_rounding": ("floor", "round"),  # PMD-P3
    "distance": ("wrapped", "linear"),  # PMD-P4
    "deceleration": ("exact", "full_rate"),  # PMD-P5
}

PROFILE_ASSUMPTION_IDS: dict[str, str] = {
    "update_order": "PMD-P2",
    "position_rounding": "PMD-P3",
    "distance": "PMD-P4",
    "deceleration": "PMD-P5",
}


@dataclasses.dataclass(frozen=True)
class ProfileAssumptions(AssumptionSet):
    """Switches for the profile-generator behaviours no source settles.

    Each field is one assumption of ``docs/chips/pmd-profile.md``; the default is the first
    choice listed there. The assumptions that are not switchable (PMD-P1, PMD-P6 ... P10)
    are documented there too.

    Attributes:
        update_order: PMD-P2. ``"velocity_first"``: each cycle the velocity is updated and
            the position accumulator adds the new velocity; ``"position_first"``: the
            position adds the previous cycle's velocity, so the position lags one cycle.
        position_rounding: PMD-P3. The reported position from the 32.16 accumulator:
            ``"floor"`` (arithmetic shift right by 16) or ``"round"`` (add 1/2, then shift).
        distance: PMD-P4. ``"wrapped"``: the move distance is ``target - start`` wrapped to
            signed 32 bits (the shorter way round the 32-bit circle); ``"linear"``: the plain
            difference of the two signed values, so a move never crosses the wrap.
        deceleration: PMD-P5 (trapezoidal only). ``"exact"``: every cycle the largest
            velocity from which the axis can still stop exactly on the target (partial
            steps spread the leftover distance); ``"full_rate"``: the same until the first
            falling cycle, then deceleration by exactly ``deceleration`` per cycle, with the
            leftover distance as one extra cycle inserted into that ramp.
    """

    CHOICES: ClassVar[dict[str, tuple[str, ...]]] = PROFILE_ASSUMPTION_CHOICES
    IDS: ClassVar[dict[str, str]] = PROFILE_ASSUMPTION_IDS

    update_order: str = "velocity_first"
    position_rounding: str = "floor"
    distance: str = "wrapped"
    deceleration: str = "exact"


_DEFAULT_ASSUMPTIONS = ProfileAssumptions()

# --------------------------------------------------------------------------------------
# Profile
# --------------------------------------------------------------------------------------


@dataclasses.dataclass(frozen=True, eq=False)
class Profile(TickArrays):
    """A commanded trajectory, one entry per servo cycle.

    Entry 0 is the first cycle after the move starts. All arrays are 1-D, C-contiguous
    ``np.int64`` of the same length ``n_ticks``; treat them as read-only.

    Attributes:
        position: Commanded position in counts, wrapped to signed 32 bits.
        velocity: Commanded velocity, 16.16 counts/cycle (signed).
        acceleration: Commanded acceleration, 16.16 counts/cycle^2 (signed; negative while
            the velocity decreases).
        move_ticks: Number of entries up to and including the one on which the move is
            complete (velocity back to 0 on the target); the rest hold. ``None`` for
            velocity contouring, which has no end.
        start: Commanded position at rest before entry 0 (counts, signed 32-bit).
    """

    position: np.ndarray
    velocity: np.ndarray
    acceleration: np.ndarray
    move_ticks: int | None = None
    start: int = 0

    def __post_init__(self) -> None:
        n = check_arrays(self)
        if self.move_ticks is not None and not 0 <= self.move_ticks <= n:
            raise ValueError(
                f"Profile.move_ticks must satisfy 0 <= move_ticks <= n_ticks={n}; "
                f"got move_ticks={self.move_ticks}."
            )


# --------------------------------------------------------------------------------------
# Validation helpers
# --------------------------------------------------------------------------------------


_int_arg = int_arg
_real_arg = real_arg


def _assumptions(assumptions: ProfileAssumptions | None) -> ProfileAssumptions:
    if assumptions is None:
        return _DEFAULT_ASSUMPTIONS
    if not isinstance(assumptions, ProfileAssumptions):
        raise ParameterError(
            f"assumptions must be a ProfileAssumptions or None; got "
            f"assumptions={assumptions!r} of type {type(assumptions).__name__}."
        )
    return assumptions


def _wrap32(x: int) -> int:
    return ((x - S32_MIN) & U32_MAX) + S32_MIN


def _wrap32_array(x: np.ndarray) -> np.ndarray:
    return ((x - S32_MIN) & U32_MAX) + S32_MIN


class _TooLongError(Exception):
    """Internal: the profile would need more than MAX_TICKS entries."""


def _too_long(what: str, ticks: int | str) -> ParameterError:
    return ParameterError(
        f"{what} needs {ticks} ticks, more than the {MAX_TICKS} this module builds "
        f"(n_ticks <= {MAX_TICKS}); raise the velocity or acceleration limits or shorten the "
        f"move."
    )


# --------------------------------------------------------------------------------------
# Unit helpers (host side, double arithmetic as in PMD host code)
# --------------------------------------------------------------------------------------


def _to_fixed(
    name: str, value: Any, sample_time_s: Any, power: int, scale: int, low: int, high: int, fmt: str
) -> int:
    x = _real_arg(name, value)
    t = _real_arg("sample_time_s", sample_time_s, positive=True)
    raw = 0.5 + scale * x * t**power
    if not math.isfinite(raw) or not low <= math.floor(raw) <= high:
        raise ParameterError(
            f"{name} must convert to a {fmt} value in {low}..{high} "
            f"(floor(0.5 + {scale} * {name} * T^{power}) with T=sample_time_s); got "
            f"{name}={value!r} at sample_time_s={sample_time_s!r}, which converts to {raw!r}."
        )
    return math.floor(raw)


def velocity_to_1616(counts_per_s: float, sample_time_s: float) -> int:
    """Velocity register value: ``floor(0.5 + 65536 * counts_per_s * T)``.

    Args:
        counts_per_s: Velocity in counts/s (signed).
        sample_time_s: Servo period T in seconds, > 0.

    Returns:
        The velocity in 16.16 counts/cycle, a signed 32-bit value.

    Raises:
        ParameterError: if an argument is not a finite number, ``sample_time_s <= 0``, or the
            result falls outside the signed 32-bit range.
    """
    return _to_fixed(
        "counts_per_s", counts_per_s, sample_time_s, 1, ONE_1616, S32_MIN, S32_MAX, "16.16"
    )


def acceleration_to_1616(counts_per_s2: float, sample_time_s: float) -> int:
    """Acceleration register value: ``floor(0.5 + 65536 * counts_per_s2 * T^2)``.

    Args:
        counts_per_s2: Acceleration in counts/s^2 (signed).
        sample_time_s: Servo period T in seconds, > 0.

    Returns:
        The acceleration in 16.16 counts/cycle^2, a signed 32-bit value.

    Raises:
        ParameterError: as :func:`velocity_to_1616`.
    """
    return _to_fixed(
        "counts_per_s2", counts_per_s2, sample_time_s, 2, ONE_1616, S32_MIN, S32_MAX, "16.16"
    )


def jerk_to_032(counts_per_s3: float, sample_time_s: float) -> int:
    """Jerk register value: ``floor(0.5 + 2^32 * counts_per_s3 * T^3)`` (PMD-P10).

    Args:
        counts_per_s3: Jerk in counts/s^3, >= 0.
        sample_time_s: Servo period T in seconds, > 0.

    Returns:
        The jerk in 0.32 counts/cycle^3, an unsigned 32-bit value (0 .. 4,294,967,295).

    Raises:
        ParameterError: as :func:`velocity_to_1616`; also for a negative jerk.
    """
    return _to_fixed("counts_per_s3", counts_per_s3, sample_time_s, 3, ONE_032, 0, U32_MAX, "0.32")


def velocity_from_1616(velocity: int, sample_time_s: float) -> float:
    """Counts/s of a 16.16 counts/cycle velocity: ``velocity / (65536 * T)``."""
    v = _int_arg("velocity", velocity, S32_MIN, S32_MAX, "s32, 16.16 counts/cycle")
    return v / (ONE_1616 * _real_arg("sample_time_s", sample_time_s, positive=True))


def acceleration_from_1616(acceleration: int, sample_time_s: float) -> float:
    """Counts/s^2 of a 16.16 counts/cycle^2 acceleration: ``acceleration / (65536 * T^2)``."""
    a = _int_arg("acceleration", acceleration, S32_MIN, S32_MAX, "s32, 16.16 counts/cycle^2")
    return a / (ONE_1616 * _real_arg("sample_time_s", sample_time_s, positive=True) ** 2)


def jerk_from_032(jerk: int, sample_time_s: float) -> float:
    """Counts/s^3 of a 0.32 counts/cycle^3 jerk: ``jerk / (2^32 * T^3)``."""
    j = _int_arg("jerk", jerk, 0, U32_MAX, "u32, 0.32 counts/cycle^3")
    return j / (ONE_032 * _real_arg("sample_time_s", sample_time_s, positive=True) ** 3)


# --------------------------------------------------------------------------------------
# Integer core (all quantities in LSB = 2^-16 counts, positive direction)
# --------------------------------------------------------------------------------------


def _stop_span(u: int, d: int) -> int:
    """``u`` plus the shortest distance to rest after a cycle at velocity ``u``.

    Decelerating by at most ``d`` per cycle, the velocities after ``u`` are
    ``u - d, u - 2d, ...`` while positive, then 0; the sum of ``u`` and those is
    ``(m + 1) * u - d * m * (m + 1) / 2`` with ``m = (u - 1) // d``.
    """
    if u <= 0:
        return 0
    m = (u - 1) // d
    return (m + 1) * u - d * m * (m + 1) // 2


def _max_stoppable(r: int, d: int) -> int:
    """Largest velocity ``u >= 0`` with ``_stop_span(u, d) <= r``.

    With ``u = m*d + s`` (``1 <= s <= d``), ``_stop_span(u) = (m+1)*s + d*m*(m+1)/2``:
    first the largest ``m`` with ``_stop_span(m*d + 1) <= r``, then the largest ``s``.
    """
    if r <= 0:
        return 0
    m = math.isqrt(2 * r // d)
    while m > 0 and (m + 1) + d * m * (m + 1) // 2 > r:
        m -= 1
    while (m + 2) + d * (m + 1) * (m + 2) // 2 <= r:
        m += 1
    s = min(d, (r - d * m * (m + 1) // 2) // (m + 1))
    return m * d + s


@dataclasses.dataclass
class _Plan:
    """A move from rest over ``distance`` LSB: velocities ``a, 2a, ..., k*a`` (the full
    acceleration ramp), then ``runs`` of ``(velocity, count)``, then one entry at 0."""

    ramp_steps: int
    ramp_acceleration: int
    runs: list[tuple[int, int]]
    last_increase: int  # index of the last cycle whose velocity rose (-1 if none)
    first_decrease: int  # index of the first cycle whose velocity fell
    move_ticks: int  # entries including the final one at velocity 0 (when complete)

    def velocities(self) -> np.ndarray:
        """Per-cycle velocities in LSB/cycle, ending with the entry at 0."""
        ramp = np.arange(1, self.ramp_steps + 1, dtype=np.int64) * self.ramp_acceleration
        if self.runs:
            vals = np.array([u for u, _ in self.runs], dtype=np.int64)
            counts = np.array([c for _, c in self.runs], dtype=np.int64)
            rest = np.repeat(vals, counts)
        else:
            rest = np.zeros(0, dtype=np.int64)
        return np.concatenate([ramp, rest, np.zeros(1, dtype=np.int64)])


def _plan_move(
    distance: int,
    v_max: int,
    acc: int,
    dec: int,
    rule: str,
    *,
    stop_at_decrease: bool = False,
    limit_ticks: bool = True,
) -> _Plan:
    """The trapezoidal velocity sequence of PMD-P5 for ``distance > 0`` LSB from rest.

    Every cycle the velocity becomes the largest one in ``[v - dec, min(v_max, v + acc)]``
    from which the axis can still stop exactly on the target (``_stop_span(u) <= remaining``;
    ``v - dec`` always can). With ``rule="full_rate"``, from the first cycle where that
    velocity would fall, the axis instead decelerates by exactly ``dec`` per cycle and the
    leftover distance (less than ``v``) is one extra cycle inserted into that ramp.

    With ``stop_at_decrease`` the plan stops at the first falling cycle (only the indices
    ``last_increase`` and ``first_decrease`` are meaningful); holds are fast-forwarded, so
    that costs O(log) steps whatever the length.

    Raises:
        _TooLongError: if ``limit_ticks`` and the move needs more than MAX_TICKS cycles.
    """

    # Full acceleration steps from rest: j*acc for j = 1..k, while j*acc <= v_max and the
    # axis can still stop from j*acc; the condition is monotone in j, so bisect.
    def full_step_ok(j: int) -> bool:
        return j * acc <= v_max and _stop_span(j * acc, dec) <= distance - acc * j * (j - 1) // 2

    lo, hi = 0, min(v_max // acc, math.isqrt(2 * distance // acc) + 1) + 1
    while hi - lo > 1:
        mid = (lo + hi) // 2
        if full_step_ok(mid):
            lo = mid
        else:
            hi = mid
    k = lo
    if limit_ticks and k > MAX_TICKS:
        raise _TooLongError
    v = k * acc
    r = distance - acc * k * (k + 1) // 2
    n = k
    runs: list[tuple[int, int]] = []
    last_increase = k - 1
    first_decrease = -1
    while r > 0:
        # Stopping from v takes at least (v - 1) // dec more moving cycles and the entry at 0.
        if limit_ticks and n + (v - 1) // dec + 2 > MAX_TICKS:
            raise _TooLongError
        u = min(v_max, v + acc, _max_stoppable(r, dec))
        if u < v and rule == "full_rate" and not stop_at_decrease:
            # Full-rate ramp v - dec, v - 2*dec, ... > 0 and one cycle at the leftover
            # distance, placed after every ramp velocity >= it (all changes stay <= dec).
            ramp = list(range(v - dec, 0, -dec))
            left = r - sum(ramp)
            if left > 0:
                ramp.insert(sum(1 for w in ramp if w >= left), left)
            if first_decrease < 0:
                first_decrease = n
            runs.extend((w, 1) for w in ramp)
            n += len(ramp)
            if limit_ticks and n >= MAX_TICKS:
                raise _TooLongError
            break
        if u == v:
            # Hold: the same choice repeats while the axis can still stop from u.
            count = (r - _stop_span(u, dec)) // u + 1
            runs.append((u, count))
            r -= count * u
            n += count
        else:
            if u > v:
                last_increase = n
            elif first_decrease < 0:
                first_decrease = n
                if stop_at_decrease:
                    break
            runs.append((u, 1))
            r -= u
            n += 1
            v = u
        if limit_ticks and n >= MAX_TICKS:
            raise _TooLongError
    if first_decrease < 0:
        first_decrease = n
    return _Plan(k, acc, runs, last_increase, first_decrease, n + 1)


def _icbrt(n: int) -> int:
    """Largest integer x with x**3 <= n (n >= 0)."""
    x = 0
    for bit in range(max(n.bit_length() // 3 + 1, 1), -1, -1):
        cand = x | (1 << bit)
        if cand**3 <= n:
            x = cand
    return x


def _finish(
    start: int,
    sign: int,
    speed: np.ndarray,
    accel: np.ndarray,
    assumptions: ProfileAssumptions,
    n_ticks: int | None,
    move_ticks: int | None,
    what: str,
) -> Profile:
    """Positions from per-cycle velocities (LSB/cycle, positive frame) and hold padding."""
    if n_ticks is not None and n_ticks < speed.shape[0]:
        raise ParameterError(
            f"n_ticks is too short: {what} needs {speed.shape[0]} ticks; n_ticks must "
            f"satisfy {speed.shape[0]} <= n_ticks <= {MAX_TICKS}; got n_ticks={n_ticks}."
        )
    if n_ticks is not None and n_ticks > speed.shape[0]:
        pad = np.zeros(n_ticks - speed.shape[0], dtype=np.int64)
        speed = np.concatenate([speed, pad])
        accel = np.concatenate([accel, pad])
    velocity = sign * speed
    acceleration = sign * accel
    travelled = np.cumsum(velocity)
    if assumptions.update_order == "position_first":
        travelled = np.concatenate([np.zeros(1, dtype=np.int64), travelled[:-1]])
    acc32_16 = np.int64(start) * ONE_1616 + travelled
    if assumptions.position_rounding == "round":
        acc32_16 = acc32_16 + (ONE_1616 >> 1)
    position = _wrap32_array(acc32_16 >> 16)
    return Profile(position, velocity, acceleration, move_ticks, start)


def _move_distance(start: int, target: int, assumptions: ProfileAssumptions) -> int:
    if assumptions.distance == "wrapped":
        return _wrap32(target - start)
    return target - start


def _check_ticks(n_ticks: int | None) -> int | None:
    if n_ticks is None:
        return None
    return _int_arg("n_ticks", n_ticks, 1, MAX_TICKS, "servo cycles")


def _check_limit(
    name: str, value: Any, high: int, width: str, distance: int, start: int, target: int
) -> int:
    value = _int_arg(name, value, 0, high, width)
    if value == 0 and distance != 0:
        raise ParameterError(
            f"{name} must satisfy 1 <= {name} <= {high} ({width}) for a move of nonzero "
            f"distance, which would otherwise never finish; got {name}=0 with "
            f"start={start}, target={target}."
        )
    return value


# --------------------------------------------------------------------------------------
# Public generators
# --------------------------------------------------------------------------------------


def trapezoidal(
    start: int,
    target: int,
    velocity: int,
    acceleration: int,
    deceleration: int | None = None,
    n_ticks: int | None = None,
    *,
    assumptions: ProfileAssumptions | None = None,
) -> Profile:
    """Trapezoidal point-to-point move (profile mode 0) from rest at ``start``.

    Each cycle the velocity rises by at most ``acceleration``, falls by at most
    ``deceleration``, never exceeds ``velocity`` in magnitude, and the move lands exactly on
    ``target`` (PMD-P5). Velocity and acceleration outputs are exact: the 32.16 position
    accumulator adds the velocity each cycle and the acceleration is the velocity change.

    Args:
        start: Position at rest before the move, counts, -2,147,483,648 .. 2,147,483,647.
        target: Destination, counts, same range. The distance is the 32-bit wrapped
            difference by default (PMD-P4).
        velocity: Velocity limit, 16.16 counts/cycle, 0 .. 2,147,483,647 (>= 1 if the
            distance is nonzero).
        acceleration: Acceleration limit, 16.16 counts/cycle^2, 0 .. 2,147,483,647 (>= 1 if
            the distance is nonzero).
        deceleration: Deceleration limit in the same format and range; ``None`` uses
            ``acceleration``.
        n_ticks: Length of the profile in cycles, 1 .. 16,777,216, at least the move's own
            length; the axis holds on the target after the move. ``None``: the profile ends
            on the first cycle at rest on the target.
        assumptions: Switches of the unsettled behaviours; ``None`` is the default set.

    Returns:
        The profile.

    Raises:
        ParameterError: for an illegal argument (the message names it, its value and the
            legal range), an ``n_ticks`` shorter than the move, or a move longer than
            ``MAX_TICKS`` cycles.
    """
    assumptions = _assumptions(assumptions)
    start = _int_arg("start", start, S32_MIN, S32_MAX, "s32 counts")
    target = _int_arg("target", target, S32_MIN, S32_MAX, "s32 counts")
    distance = _move_distance(start, target, assumptions)
    velocity = _check_limit(
        "velocity", velocity, U31_MAX, "16.16 counts/cycle", distance, start, target
    )
    acceleration = _check_limit(
        "acceleration", acceleration, U31_MAX, "16.16 counts/cycle^2", distance, start, target
    )
    if deceleration is None:
        deceleration = acceleration
    else:
        deceleration = _check_limit(
            "deceleration", deceleration, U31_MAX, "16.16 counts/cycle^2", distance, start, target
        )
    n_ticks = _check_ticks(n_ticks)
    what = f"the move from start={start} to target={target}"
    speed = _trapezoid_speed(
        abs(distance) * ONE_1616,
        velocity,
        acceleration,
        deceleration,
        assumptions.deceleration,
        what,
    )
    accel = np.diff(speed, prepend=np.int64(0))
    sign = -1 if distance < 0 else 1
    return _finish(start, sign, speed, accel, assumptions, n_ticks, speed.shape[0], what)


def _trapezoid_speed(
    distance: int, v_max: int, acc: int, dec: int, rule: str, what: str
) -> np.ndarray:
    """Per-cycle velocities (LSB/cycle) of a move of ``distance`` LSB, ending at 0."""
    if distance == 0:
        return np.zeros(1, dtype=np.int64)
    # Lower bound on the length: the cruise (distance / v_max) and the ramps.
    bound = max(-(-distance // v_max), math.isqrt(distance // max(acc, dec)))
    if bound > MAX_TICKS:
        raise _too_long(what, f"at least {bound}")
    try:
        plan = _plan_move(distance, v_max, acc, dec, rule)
    except _TooLongError:
        raise _too_long(what, f"more than {MAX_TICKS}") from None
    return plan.velocities()


def s_curve(
    start: int,
    target: int,
    velocity: int,
    acceleration: int,
    jerk: int,
    n_ticks: int | None = None,
    *,
    assumptions: ProfileAssumptions | None = None,
) -> Profile:
    """Jerk-limited point-to-point move (profile mode 2) from rest at ``start`` (PMD-P8).

    A symmetric seven-segment S-curve (acceleration = deceleration), built as a trapezoidal
    profile with acceleration ``a'`` and peak velocity ``v'`` averaged over a window of
    ``L`` cycles, so the acceleration ramps in ``L`` cycles at a jerk ``a'/L <= jerk``. The
    position lands exactly on ``target``; ``|velocity| <= velocity``,
    ``|acceleration| <= acceleration`` every cycle, and the reported acceleration (the
    internal one floored to 16.16) changes by at most ``ceil(jerk / 2^16)`` per cycle.

    Args:
        start: Position at rest before the move, counts, -2,147,483,648 .. 2,147,483,647.
        target: Destination, counts, same range (distance as PMD-P4).
        velocity: Velocity limit, 16.16 counts/cycle, 0 .. 2,147,483,647 (>= 1 if the
            distance is nonzero).
        acceleration: Acceleration and deceleration limit, 16.16 counts/cycle^2,
            0 .. 2,147,483,647 (>= 1 if the distance is nonzero).
        jerk: Jerk limit, 0.32 counts/cycle^3, 0 .. 4,294,967,295 (>= 1 if the distance is
            nonzero).
        n_ticks: Length of the profile in cycles, as in :func:`trapezoidal`.
        assumptions: Switches of the unsettled behaviours; ``deceleration`` is ignored (the
            underlying trapezoid always uses the ``"exact"`` rule).

    Returns:
        The profile.

    Raises:
        ParameterError: as :func:`trapezoidal`; also when the jerk is too small to move
            the distance with velocities of at least one 16.16 LSB.
    """
    assumptions = _assumptions(assumptions)
    start = _int_arg("start", start, S32_MIN, S32_MAX, "s32 counts")
    target = _int_arg("target", target, S32_MIN, S32_MAX, "s32 counts")
    distance = _move_distance(start, target, assumptions)
    velocity = _check_limit(
        "velocity", velocity, U31_MAX, "16.16 counts/cycle", distance, start, target
    )
    acceleration = _check_limit(
        "acceleration", acceleration, U31_MAX, "16.16 counts/cycle^2", distance, start, target
    )
    jerk = _check_limit("jerk", jerk, U32_MAX, "0.32 counts/cycle^3", distance, start, target)
    n_ticks = _check_ticks(n_ticks)
    what = f"the S-curve move from start={start} to target={target}"
    lsb = abs(distance) * ONE_1616
    if lsb == 0:
        zero = np.zeros(1, dtype=np.int64)
        return _finish(start, 1, zero, zero.copy(), assumptions, n_ticks, 1, what)
    window, acc_used, v_used = _s_curve_plan(lsb, velocity, acceleration, jerk, what)
    speed_trap = _trapezoid_speed(lsb, v_used, acc_used, acc_used, "exact", what)
    ticks = speed_trap.shape[0] + window - 1
    if ticks > MAX_TICKS:
        raise _too_long(what, ticks)
    speed, accel = _smooth(speed_trap, window, ticks)
    sign = -1 if distance < 0 else 1
    return _finish(start, sign, speed, accel, assumptions, n_ticks, ticks, what)


def _s_curve_plan(
    distance: int, v_max: int, a_max: int, jerk: int, what: str
) -> tuple[int, int, int]:
    """Window ``L``, trapezoid acceleration ``a'`` and peak velocity ``v'`` (PMD-P8)."""
    # Peak acceleration of the continuous S-curve: limited by a_max, by reaching v_max at
    # the end of the jerk phase (a^2 = v*j) and by the distance (a^3 = distance*j^2/2), with
    # j = jerk / 2^16 in LSB/cycle^3.
    peak = min(a_max, math.isqrt((v_max * jerk) >> 16), _icbrt((distance * jerk * jerk) >> 33))
    peak = max(peak, 1)
    window = -(-(peak << 16) // jerk)
    if window > MAX_TICKS:
        raise _too_long(what, f"at least {window}")
    acc = min(a_max, (window * jerk) >> 16)

    def wide_enough(v: int) -> bool:
        # No cycle may see a rising and a falling trapezoid velocity inside one window.
        plan = _plan_move(distance, v, acc, acc, "exact", stop_at_decrease=True, limit_ticks=False)
        return plan.first_decrease - plan.last_increase > window

    if wide_enough(v_max):
        return window, acc, v_max
    lo, hi = 1, v_max
    if not wide_enough(lo):
        raise ParameterError(
            f"jerk={jerk} is too small for {what}: its {window}-cycle jerk phase does not "
            f"fit even at the slowest velocity (1 LSB); raise jerk (0.32 counts/cycle^3, "
            f"1 <= jerk <= {U32_MAX})."
        )
    # Largest velocity found by bisection that keeps the window; the length limit is checked
    # on the final profile.
    while hi - lo > 1:
        mid = (lo + hi) // 2
        if wide_enough(mid):
            lo = mid
        else:
            hi = mid
    return window, acc, lo


def _smooth(speed_trap: np.ndarray, window: int, ticks: int) -> tuple[np.ndarray, np.ndarray]:
    """Average a trapezoid over ``window`` cycles; velocities and accelerations in LSB.

    With ``P`` the trapezoid's accumulated distance, the smoothed accumulator is
    ``X_n / L`` with ``X_n = sum_{i<L} P_{n-i}``; the reported accumulator is its floor,
    the reported velocity the floor's increment (exact, PMD-P8) and the reported
    acceleration ``floor((v_n - v_{n-L}) / L)`` of the trapezoid's velocities ``v``.
    """
    speed = np.zeros(ticks, dtype=np.int64)
    speed[: speed_trap.shape[0]] = speed_trap
    travelled = np.cumsum(speed)
    lagged = np.zeros(ticks, dtype=np.int64)
    lagged[window:] = travelled[:-window] if window < ticks else lagged[window:]
    span = travelled - lagged  # X_n - X_{n-1}, at most window * v' and at most the distance
    speed_lag = np.zeros(ticks, dtype=np.int64)
    speed_lag[window:] = speed[:-window] if window < ticks else speed_lag[window:]
    accel = (speed - speed_lag) // window
    total = int(travelled[-1]) * window
    if total < (1 << 62):
        smoothed = np.cumsum(span) // window
    else:  # Python integers: window * distance does not fit 63 bits
        smoothed = (np.cumsum(span.astype(object)) // window).astype(np.int64)
    velocity = np.diff(smoothed, prepend=np.int64(0))
    return velocity, accel


class VelocitySegment(NamedTuple):
    """One segment of a velocity-contouring profile.

    Attributes:
        velocity: Target velocity, 16.16 counts/cycle, signed 32-bit.
        acceleration: Rate while the speed grows, 16.16 counts/cycle^2, 0 .. 2,147,483,647.
        duration: Cycles until the next segment starts, 0 .. 16,777,216.
        deceleration: Rate while the speed falls, same format; ``None`` uses
            ``acceleration``.
    """

    velocity: int
    acceleration: int
    duration: int
    deceleration: int | None = None


def _contour_step(v: int, target: int, acc: int, dec: int) -> int:
    """One cycle of velocity mode (PMD-P9): toward ``target``, never through zero."""
    if v == target:
        return v
    if v >= 0 and target > v:
        return v + min(acc, target - v)
    if v <= 0 and target < v:
        return v - min(acc, v - target)
    if v > 0:  # falling toward target < v
        return max(v - min(dec, v - target), 0)
    return min(v + min(dec, target - v), 0)


def velocity_contouring(
    start: int,
    segments: Sequence[VelocitySegment | tuple[int, ...]],
    n_ticks: int | None = None,
    *,
    assumptions: ProfileAssumptions | None = None,
) -> Profile:
    """Velocity mode (profile mode 1): ramp to each segment's velocity, from rest at ``start``.

    Each segment sets a new target velocity; every cycle the velocity moves toward it by at
    most the acceleration while the speed grows and at most the deceleration while it
    falls, and stops at zero for one cycle when the target has the other sign (PMD-P9).
    The position wraps at 32 bits.

    Args:
        start: Position before the first cycle, counts, -2,147,483,648 .. 2,147,483,647.
        segments: At least one ``(velocity, acceleration, duration[, deceleration])``, see
            :class:`VelocitySegment`.
        n_ticks: Length in cycles, 1 .. 16,777,216, at least the sum of the durations; the
            last segment continues after its duration. ``None``: the sum of the durations.
        assumptions: Switches; ``update_order`` and ``position_rounding`` apply.

    Returns:
        The profile (``move_ticks`` is ``None``).

    Raises:
        ParameterError: for an illegal argument, naming it, its value and the legal range.
    """
    assumptions = _assumptions(assumptions)
    start = _int_arg("start", start, S32_MIN, S32_MAX, "s32 counts")
    if (
        isinstance(segments, (str, bytes))
        or not isinstance(segments, Sequence)
        or (len(segments) == 0)
    ):
        raise ParameterError(
            "segments must be a non-empty sequence of (velocity, acceleration, duration"
            f"[, deceleration]) tuples; got segments={segments!r}."
        )
    checked: list[VelocitySegment] = []
    for i, seg in enumerate(segments):
        if (
            isinstance(seg, (str, bytes))
            or not isinstance(seg, Sequence)
            or len(seg)
            not in (
                3,
                4,
            )
        ):
            raise ParameterError(
                f"segments[{i}] must be (velocity, acceleration, duration) or (velocity, "
                f"acceleration, duration, deceleration); got segments[{i}]={seg!r}."
            )
        vel, acc, dur = seg[0], seg[1], seg[2]
        dec = seg[3] if len(seg) == 4 else None
        p = f"segments[{i}]."
        vel = _int_arg(p + "velocity", vel, S32_MIN, S32_MAX, "s32, 16.16 counts/cycle")
        acc = _int_arg(p + "acceleration", acc, 0, U31_MAX, "16.16 counts/cycle^2")
        dur = _int_arg(p + "duration", dur, 0, MAX_TICKS, "cycles")
        dec = (
            acc
            if dec is None
            else _int_arg(p + "deceleration", dec, 0, U31_MAX, "16.16 counts/cycle^2")
        )
        checked.append(VelocitySegment(vel, acc, dur, dec))
    n_ticks = _check_ticks(n_ticks)
    total = sum(s.duration for s in checked)
    if total > MAX_TICKS:
        raise _too_long("the segments", total)
    if n_ticks is None:
        if total == 0:
            raise ParameterError(
                "segments must last at least one cycle in total when n_ticks is None; got "
                "a total duration of 0."
            )
        n_ticks = total
    elif n_ticks < total:
        raise ParameterError(
            f"n_ticks is too short: the segments last {total} ticks; n_ticks must satisfy "
            f"{total} <= n_ticks <= {MAX_TICKS}; got n_ticks={n_ticks}."
        )
    durations = [s.duration for s in checked]
    durations[-1] += n_ticks - total
    chunks: list[np.ndarray] = []
    v = 0
    for seg, dur in zip(checked, durations, strict=True):
        ramp: list[int] = []
        while len(ramp) < dur and v != seg.velocity:
            nxt = _contour_step(v, seg.velocity, seg.acceleration, seg.deceleration)
            if nxt == v:  # zero rate: the velocity stays
                break
            v = nxt
            ramp.append(v)
        chunks.append(np.array(ramp, dtype=np.int64))
        chunks.append(np.full(dur - len(ramp), v, dtype=np.int64))
    velocity = np.concatenate(chunks)
    accel = np.diff(velocity, prepend=np.int64(0))
    return _finish(start, 1, velocity, accel, assumptions, None, None, "velocity contouring")


_MOVE_KINDS = ("trapezoidal", "s_curve")


def move(
    kind: str,
    start: int,
    distance: int,
    max_velocity_counts_per_s: float,
    max_acceleration_counts_per_s2: float,
    sample_time_s: float,
    *,
    jerk_counts_per_s3: float | None = None,
    max_deceleration_counts_per_s2: float | None = None,
    settle_ticks: int = 100,
    assumptions: ProfileAssumptions | None = None,
) -> Profile:
    """A point-to-point move from limits in counts/s, followed by a settle time at rest.

    The limits are converted with :func:`velocity_to_1616`, :func:`acceleration_to_1616` and
    :func:`jerk_to_032` at the servo period, then the profile is built by
    :func:`trapezoidal` or :func:`s_curve` and held on the target for ``settle_ticks``
    cycles after the move completes.

    Args:
        kind: ``"trapezoidal"`` or ``"s_curve"``.
        start: Position at rest before the move, counts, signed 32-bit.
        distance: Move length in counts (signed). With PMD-P4 ``"wrapped"`` (the default)
            -2,147,483,648 .. 2,147,483,647 and the target is ``start + distance`` wrapped
            to 32 bits; with ``"linear"`` the target ``start + distance`` must be a signed
            32-bit value.
        max_velocity_counts_per_s: Velocity limit in counts/s, > 0; must convert to a 16.16
            value 1 .. 2,147,483,647.
        max_acceleration_counts_per_s2: Acceleration limit in counts/s^2, > 0; must convert
            to a 16.16 value 1 .. 2,147,483,647.
        sample_time_s: Servo period in seconds, > 0.
        jerk_counts_per_s3: Jerk limit in counts/s^3 (``"s_curve"`` only, required there);
            must convert to a 0.32 value 1 .. 4,294,967,295.
        max_deceleration_counts_per_s2: Deceleration limit (``"trapezoidal"`` only);
            ``None`` uses the acceleration limit.
        settle_ticks: Cycles at rest on the target after the move, 0 .. 16,777,216.
        assumptions: Switches of the unsettled behaviours.

    Returns:
        The profile, ``move_ticks + settle_ticks`` entries long.

    Raises:
        ParameterError: for an illegal argument or a limit that converts outside its
            register range, naming it, its value and the legal range.
    """
    assumptions = _assumptions(assumptions)
    if kind not in _MOVE_KINDS:
        raise ParameterError(
            f"kind must be one of {', '.join(repr(k) for k in _MOVE_KINDS)}; got kind={kind!r}."
        )
    start = _int_arg("start", start, S32_MIN, S32_MAX, "s32 counts")
    if assumptions.distance == "wrapped":
        distance = _int_arg("distance", distance, S32_MIN, S32_MAX, "s32 counts")
        target = _wrap32(start + distance)
    else:
        distance = _int_arg(
            "distance",
            distance,
            S32_MIN - start,
            S32_MAX - start,
            f"counts, so that start + distance fits s32 (start={start})",
        )
        target = start + distance
    settle_ticks = _int_arg("settle_ticks", settle_ticks, 0, MAX_TICKS, "servo cycles")
    t = _real_arg("sample_time_s", sample_time_s, positive=True)
    v = _limit_1616(
        "max_velocity_counts_per_s", max_velocity_counts_per_s, t, 1, "velocity", U31_MAX, ONE_1616
    )
    a = _limit_1616(
        "max_acceleration_counts_per_s2",
        max_acceleration_counts_per_s2,
        t,
        2,
        "acceleration",
        U31_MAX,
        ONE_1616,
    )
    if kind == "trapezoidal":
        if jerk_counts_per_s3 is not None:
            raise ParameterError(
                f"jerk_counts_per_s3 applies to kind='s_curve' only; got "
                f"jerk_counts_per_s3={jerk_counts_per_s3!r} with kind={kind!r}."
            )
        d = None
        if max_deceleration_counts_per_s2 is not None:
            d = _limit_1616(
                "max_deceleration_counts_per_s2",
                max_deceleration_counts_per_s2,
                t,
                2,
                "deceleration",
                U31_MAX,
                ONE_1616,
            )
        profile = trapezoidal(start, target, v, a, d, assumptions=assumptions)
    else:
        if max_deceleration_counts_per_s2 is not None:
            raise ParameterError(
                "max_deceleration_counts_per_s2 applies to kind='trapezoidal' only (the "
                "S-curve is symmetric, PMD-P8); got max_deceleration_counts_per_s2="
                f"{max_deceleration_counts_per_s2!r} with kind={kind!r}."
            )
        if jerk_counts_per_s3 is None:
            raise ParameterError(
                "jerk_counts_per_s3 is required for kind='s_curve': a jerk limit in "
                "counts/s^3 > 0; got jerk_counts_per_s3=None."
            )
        j = _limit_1616("jerk_counts_per_s3", jerk_counts_per_s3, t, 3, "jerk", U32_MAX, ONE_032)
        profile = s_curve(start, target, v, a, j, assumptions=assumptions)
    n = profile.n_ticks + settle_ticks
    if n > MAX_TICKS:
        raise _too_long("the move with its settle time", n)
    return _hold(profile, n)


def _limit_1616(
    name: str, value: Any, t: float, power: int, register: str, high: int, scale: int
) -> int:
    """Convert an SI limit; it must land in 1..high so the move can finish."""
    x = _real_arg(name, value, positive=True)
    raw = math.floor(0.5 + scale * x * t**power)
    if not 1 <= raw <= high:
        low_si = 0.5 / (scale * t**power)
        high_si = (high + 0.5) / (scale * t**power)
        raise ParameterError(
            f"{name} must convert to a {register} register value 1 <= {register} <= {high} "
            f"at sample_time_s={t!r}, i.e. about {low_si:.6g} <= {name} < {high_si:.6g}; "
            f"got {name}={value!r}, which converts to {register}={raw}."
        )
    return raw


def _hold(profile: Profile, n_ticks: int) -> Profile:
    """Extend a profile by holding its last position at rest up to ``n_ticks`` entries."""
    extra = n_ticks - profile.n_ticks
    if extra <= 0:
        return profile
    return Profile(
        np.concatenate([profile.position, np.full(extra, profile.position[-1], np.int64)]),
        np.concatenate([profile.velocity, np.zeros(extra, np.int64)]),
        np.concatenate([profile.acceleration, np.zeros(extra, np.int64)]),
        profile.move_ticks,
        profile.start,
    )
