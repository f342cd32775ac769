"""Response metrics of one episode, computed from its traces in compiled code.

Every metric is finite for every episode, including one that diverged (it then covers the
ticks that ran; the cost functions of envs and tuners add the divergence penalty).
"""

from __future__ import annotations

import dataclasses
import math

import numpy as np
from numba import njit

FULL_SCALE = 32768.0  # motor command counts at 100 % [C]

METRIC_NAMES = (
    "iae",
    "itae",
    "max_following_error",
    "overshoot",
    "settling_time",
    "steady_state_error",
    "rms_command",
    "saturation_fraction",
    "chatter",
)


@dataclasses.dataclass(frozen=True)
class EpisodeMetrics:
    """What one episode's response measured. Errors are in encoder counts.

    Attributes:
        iae: Integral of absolute error, ``dt * sum |e_k|`` over the ticks run (counts*s).
        itae: Integral of time-weighted absolute error, ``dt * sum (k dt) |e_k|`` (counts*s^2).
        max_following_error: Largest ``|e_k|`` while the profile moves (counts); over the
            whole episode when the profile never moves.
        overshoot: Largest excursion of the actual position past the target, in the
            direction of the move, after the profile has stopped (counts, >= 0).
        settling_time: Time from the end of the profile's move until ``|e|`` enters the band
            ``settle_band`` and stays there to the end of the episode (s). When it never
            settles: the time from the end of the move to the end of the episode.
        steady_state_error: Mean ``|e_k|`` over the last 10 % of the ticks run (counts).
        rms_command: Root mean square motor command as a fraction of full scale (32768).
        saturation_fraction: Fraction of ticks whose command magnitude reached the chip's
            motor limit (a limit of 0 counts every tick).
        chatter: Mean magnitude of the tick-to-tick change of the motor command, as a
            fraction of full scale per tick.
        settled: Whether ``|e|`` stayed inside the band over the whole steady-state
            window (the last 10 % of the ticks, after the move): a response that only
            passes through the band at its last tick has not settled.
        diverged: Whether the episode ended early (error bound, travel bound, the chip's
            motion error, or a non-finite simulation state).
        divergence_tick: Tick at which it ended early, or -1.
        divergence_reason: ``"none"``, ``"error_bound"``, ``"travel_limit"``,
            ``"chip_motion_error"`` or ``"non_finite_state"``.
        n_ticks: Ticks run.
        dt: Servo period (s).
    """

    iae: float
    itae: float
    max_following_error: float
    overshoot: float
    settling_time: float
    steady_state_error: float
    rms_command: float
    saturation_fraction: float
    chatter: float
    settled: bool
    diverged: bool
    divergence_tick: int
    divergence_reason: str
    n_ticks: int
    dt: float

    def to_dict(self) -> dict:
        """Every field, JSON-ready."""
        return dataclasses.asdict(self)

    def __post_init__(self) -> None:
        for name in METRIC_NAMES:
            if not math.isfinite(getattr(self, name)):
                raise ValueError(f"metric {name} is not finite: {getattr(self, name)}")


@njit(cache=True, nogil=True)
def compute_metrics(commanded, actual, command, n, move_end, target, direction, dt, band, limit):
    """Metric values in METRIC_NAMES order, plus the settled flag as a last entry.

    Args:
        commanded, actual, command: int64 traces; the first ``n`` entries are used.
        n: ticks run (>= 1).
        move_end: index of the last tick at which the commanded position changes (-1: none).
        target: the commanded position at the end of the profile (counts).
        direction: +1 or -1 for the move's direction, 0 when there is no move.
        dt: servo period (s).
        band: settling band (counts).
        limit: the chip's motor limit (counts).
    """
    out = np.zeros(len(METRIC_NAMES) + 1)
    iae = 0.0
    itae = 0.0
    max_fe = 0.0
    over = 0.0
    sq = 0.0
    sat = 0
    chat = 0.0
    last_out = -1  # last tick outside the band after the move
    moving_end = move_end if move_end >= 0 else n - 1
    for k in range(n):
        e = commanded[k] - actual[k]
        e = ((e + 2**31) & 0xFFFFFFFF) - 2**31
        ae = abs(e)
        iae += ae
        itae += k * ae
        if k <= moving_end and ae > max_fe:
            max_fe = ae
        if k > move_end:
            past = actual[k] - target
            past = (((past + 2**31) & 0xFFFFFFFF) - 2**31) * direction
            if past > over:
                over = past
            if ae > band:
                last_out = k
        c = command[k]
        sq += c * c
        if abs(c) >= limit:
            sat += 1
        if k > 0:
            chat += abs(c - command[k - 1])
    tail = max(1, n // 10)
    sse = 0.0
    for k in range(n - tail, n):
        e = commanded[k] - actual[k]
        sse += abs(((e + 2**31) & 0xFFFFFFFF) - 2**31)
    end = max(move_end, 0)
    ends_inside = last_out < n - 1 and n - 1 > move_end
    # settled: inside the band over the whole steady-state window (the last tenth, the
    # window steady_state_error is taken over), which starts after the move; a response
    # that only passes through the band at the last tick has not settled.
    settled = last_out < n - tail and n - tail > move_end
    if ends_inside:
        settle = (max(last_out + 1, end) - end) * dt
    else:
        settle = max(n - end, 0) * dt
    out[0] = iae * dt
    out[1] = itae * dt * dt
    out[2] = max_fe
    out[3] = over
    out[4] = settle
    out[5] = sse / tail
    out[6] = np.sqrt(sq / n) / 32768.0
    out[7] = sat / n
    out[8] = chat / max(n - 1, 1) / 32768.0
    out[9] = 1.0 if settled else 0.0
    return out
