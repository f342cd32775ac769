"""Turbo PMAC commanded trajectory for a point-to-point move, in the filter's input units.

PMAC computes a jog move (speed Ixx22, acceleration time Ixx20, S-curve time Ixx21) in
floating point and hands the servo loop a commanded position with a fine fraction of a count
every servo update; the loop forms the commanded velocity and acceleration itself, as
differences of that position. This module models it simply: the time-optimal trapezoid for
the move's limits, averaged over the S-curve time for an S-curve move, evaluated at the end of
every servo update and quantized to 1/32 count. The assumptions are PMAC-P1 ... PMAC-P7 of
``docs/chips/pmac.md``, section 5.

Per entry the profile gives what :func:`~servogym.chips.pmac._kernel.pmac_step` reads:
``position`` (whole counts, what the runner compares with the encoder), ``velocity`` (the
first auxiliary input: the commanded position's fraction in 1/32 count, 0..31) and
``acceleration`` (the second auxiliary input, which the filter does not read: the commanded
acceleration in 1/32 count per update squared, for observers such as the envs).
"""

from __future__ import annotations

import dataclasses
import math

import numpy as np

from servogym.chips._profiles import TickArrays, check_arrays, int_arg, real_arg
from servogym.chips._space import ParameterError

S32_MIN, S32_MAX = -(1 << 31), (1 << 31) - 1
MAX_TICKS = 1 << 24
"""Longest profile this module builds (16,777,216 servo updates, 2 h at 442.7 us)."""
FRACTION_BITS = 5
"""The commanded position carries 5 fractional bits (1/32 count)."""


@dataclasses.dataclass(frozen=True, eq=False)
class Profile(TickArrays):
    """A commanded trajectory, one entry per servo update.

    Entry 0 is the first servo update after the move starts. All arrays are 1-D,
    C-contiguous ``np.int64`` of length ``n_ticks``; treat them as read-only.

    Attributes:
        position: Commanded position, whole counts (floor of the fine position), wrapped to
            signed 32 bits.
        velocity: First auxiliary filter input: the commanded position's fraction in 1/32
            count, 0..31 (the commanded position is ``position + velocity / 32``). The name is
            the compiled loop's slot; :attr:`fraction` is the same array.
        acceleration: Second auxiliary filter input, not read by the PMAC filter: the commanded
            acceleration CA, 1/32 count per update^2 (the second difference of the fine
            position, from rest), for observers; its sign tells accelerating from braking.
        start: Commanded (and actual) position at rest before the move, counts.
        move_ticks: Entries up to and including the first one on the target; the rest hold.
    """

    position: np.ndarray
    velocity: np.ndarray
    acceleration: np.ndarray
    start: int = 0
    move_ticks: int = 0

    def __post_init__(self) -> None:
        n = check_arrays(self)
        if not 0 <= self.move_ticks <= n:
            raise ValueError(
                f"Profile.move_ticks must satisfy 0 <= move_ticks <= n_ticks={n}; "
                f"got move_ticks={self.move_ticks}."
            )
        if n and (self.velocity.min() < 0 or self.velocity.max() > 31):
            raise ValueError("Profile.velocity holds the commanded fraction, 0..31 (1/32 count).")

    @property
    def fraction(self) -> np.ndarray:
        """The commanded position's fraction in 1/32 count (the ``velocity`` array)."""
        return self.velocity

    @property
    def fine_position(self) -> np.ndarray:
        """Commanded position in 1/32 count, unwrapped from ``start`` (int64)."""
        steps = ((np.diff(self.position, prepend=self.start) + 2**31) % 2**32) - 2**31
        return 32 * (self.start + np.cumsum(steps)) + self.velocity

    @property
    def commanded_velocity(self) -> np.ndarray:
        """CV: the fine position's change per servo update, 1/32 count/cycle (from rest)."""
        return np.diff(self.fine_position, prepend=32 * self.start)


_int_arg = int_arg
_real_arg = real_arg


def _pieces(
    distance: float, v: float, a: float, min_cruise: float = 0.0
) -> list[tuple[float, float, float, float]]:
    """The trapezoid as pieces ``(t_start, x0, v0, acc)``: x = x0 + v0 u + acc u^2 / 2.

    It cruises for at least ``min_cruise`` seconds: a move too short to do so at speed ``v``
    peaks lower (PMAC-P1, PMAC-P2).
    """
    if distance >= v * v / a + v * min_cruise:  # reaches the speed limit
        t1, peak = v / a, v
        tc = distance / v - v / a
    else:  # peak * peak / a + peak * min_cruise = distance
        peak = 0.5 * a * (math.sqrt(min_cruise * min_cruise + 4.0 * distance / a) - min_cruise)
        t1, tc = peak / a, min_cruise
    d1 = 0.5 * a * t1 * t1
    t2 = t1 + tc
    end = t2 + t1
    return [
        (-math.inf, 0.0, 0.0, 0.0),
        (0.0, 0.0, 0.0, a),
        (t1, d1, peak, 0.0),
        (t2, d1 + peak * tc, peak, -a),
        (end, distance, 0.0, 0.0),
    ]


def _trapezoid(pieces, t: np.ndarray) -> np.ndarray:
    starts = np.array([p[0] for p in pieces])
    idx = np.searchsorted(starts, t, side="right") - 1
    t0, x0, v0, acc = (np.array([p[k] for p in pieces])[idx] for k in range(4))
    u = np.where(np.isfinite(t0), t - t0, 0.0)
    return x0 + v0 * u + 0.5 * acc * u * u


def _averaged(pieces, t: np.ndarray, window: float) -> np.ndarray:
    """Mean of the trapezoid over ``[t - window, t]``, piece by piece (numerically stable)."""
    total = np.zeros_like(t)
    ends = [p[0] for p in pieces[1:]] + [math.inf]
    for (t0, x0, v0, acc), t_end in zip(pieces, ends, strict=True):
        lo = np.maximum(t - window, t0)
        hi = np.minimum(t, t_end)
        dt = np.maximum(hi - lo, 0.0)
        if math.isfinite(t0):
            u0 = np.where(dt > 0, lo - t0, 0.0)
            u1 = np.where(dt > 0, hi - t0, 0.0)
        else:
            u0 = u1 = np.zeros_like(t)
        mean = x0 + v0 * (u0 + u1) / 2 + acc * (u0 * u0 + u0 * u1 + u1 * u1) / 6
        total += dt * mean
    return total / window


def move(
    kind: str,
    start: int,
    distance: int,
    max_velocity_counts_per_s: float,
    max_acceleration_counts_per_s2: float,
    sample_time_s: float,
    *,
    jerk_counts_per_s3: float | None = None,
    settle_ticks: int = 100,
) -> Profile:
    """A point-to-point move from rest at ``start``, then ``settle_ticks`` at rest on target.

    Args:
        kind: ``"trapezoidal"`` or ``"s_curve"``.
        start: Position at rest before the move, counts, signed 32-bit.
        distance: Move length in counts, signed 32-bit; the target wraps at 32 bits.
        max_velocity_counts_per_s: Speed limit (jog speed Ixx22), counts/s, > 0.
        max_acceleration_counts_per_s2: Acceleration limit, counts/s^2, > 0 (the
            acceleration time Ixx20 is speed / acceleration).
        sample_time_s: The filter's period (servo period times Ixx60+1), seconds, > 0.
        jerk_counts_per_s3: ``"s_curve"`` only (required there): jerk limit, counts/s^3;
            the S-curve time Ixx21 is acceleration / jerk.
        settle_ticks: Entries at rest on the target after the move, 0 .. 16,777,216.

    Returns:
        The profile, ``max(1, move_ticks + settle_ticks)`` entries long.

    Raises:
        ParameterError: for an illegal argument, naming it, its value and the legal range,
            or a move longer than 16,777,216 servo updates.
    """
    if kind not in ("trapezoidal", "s_curve"):
        raise ParameterError(f"kind must be one of 'trapezoidal', 's_curve'; got kind={kind!r}.")
    start = _int_arg("start", start, S32_MIN, S32_MAX, "s32 counts")
    distance = _int_arg("distance", distance, S32_MIN, S32_MAX, "s32 counts")
    v = _real_arg("max_velocity_counts_per_s", max_velocity_counts_per_s, positive=True)
    a = _real_arg("max_acceleration_counts_per_s2", max_acceleration_counts_per_s2, positive=True)
    t = _real_arg("sample_time_s", sample_time_s, positive=True)
    settle_ticks = _int_arg("settle_ticks", settle_ticks, 0, MAX_TICKS, "servo updates")
    window = 0.0
    if kind == "s_curve":
        if jerk_counts_per_s3 is None:
            raise ParameterError(
                "jerk_counts_per_s3 is required for kind='s_curve': a jerk limit in "
                "counts/s^3 > 0; got jerk_counts_per_s3=None."
            )
        window = a / _real_arg("jerk_counts_per_s3", jerk_counts_per_s3, positive=True)
    elif jerk_counts_per_s3 is not None:
        raise ParameterError(
            f"jerk_counts_per_s3 applies to kind='s_curve' only; got "
            f"jerk_counts_per_s3={jerk_counts_per_s3!r} with kind={kind!r}."
        )

    length = abs(distance)
    if length == 0:
        move_ticks, rel = 0, np.zeros(0, np.int64)
    else:
        pieces = _pieces(float(length), v, a, window)
        duration = pieces[-1][0] + window
        ticks = math.ceil(duration / t - 1e-9)
        if not math.isfinite(duration) or ticks + settle_ticks > MAX_TICKS:
            raise ParameterError(
                f"the move of {distance} counts needs about {duration / t:.4g} servo updates, "
                f"more than the {MAX_TICKS} this module builds (n_ticks <= {MAX_TICKS}); "
                f"raise the velocity or acceleration limits or shorten the move."
            )
        move_ticks = max(ticks, 1)
        times = (np.arange(move_ticks) + 1) * t
        x = _averaged(pieces, times, window) if window > 0 else _trapezoid(pieces, times)
        rel = np.floor(32.0 * np.minimum(x, length) + 0.5).astype(np.int64)
        rel = np.maximum.accumulate(np.clip(rel, 0, 32 * length))
        rel[-1] = 32 * length  # PMAC-P5: the move ends exactly on the target
        if distance < 0:
            rel = -rel
    n = max(1, move_ticks + settle_ticks)
    fine = np.full(n, 32 * distance, np.int64)
    fine[:move_ticks] = rel
    whole = fine >> FRACTION_BITS
    position = ((start + whole + 2**31) % 2**32) - 2**31
    fraction = fine & 31
    acceleration = np.diff(np.diff(fine, prepend=0), prepend=0)
    return Profile(position, fraction, acceleration, start, move_ticks)
