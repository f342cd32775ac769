"""Observation features: what an engineer or the controller can measure on a move.

Everything here is cheap (a few NumPy reductions over one move's traces) and every feature
is finite and clipped to ``[-OBS_CLIP, OBS_CLIP]``.
"""

from __future__ import annotations

import math
from collections.abc import Mapping

import numpy as np

from servogym.plants import PlantFamily
from servogym.sim import EpisodeResult

OBS_CLIP = 10.0
"""Every observation entry is clipped to ``[-OBS_CLIP, OBS_CLIP]``."""

FULL_SCALE = 32768.0
"""Motor command counts at 100 %."""

MOVE_FEATURES: tuple[tuple[str, str, str], ...] = (
    ("mean_error", "float (1)", "log(1 + IAE / T / e_ref): mean absolute error"),
    ("peak_error", "float (1)", "log(1 + max_following_error / e_ref)"),
    ("overshoot", "float (1)", "log(1 + overshoot / e_ref)"),
    ("settling", "float (1)", "settling_time / settle_s (1 = never settled), clipped"),
    ("steady_state_error", "float (1)", "log(1 + steady_state_error / e_ref)"),
    ("rms_command", "float (1)", "RMS motor command, fraction of full scale"),
    ("mean_command", "float (1)", "mean motor command, signed fraction of full scale"),
    ("holding_command", "float (1)", "mean command over the last 10 % of ticks (load torque)"),
    (
        "acceleration_command",
        "float (1)",
        "mean command while accelerating minus while decelerating, times the move's sign: "
        "what the inertia takes (fraction of full scale)",
    ),
    ("saturation", "float (1)", "fraction of ticks at the motor limit"),
    ("chatter", "float (1)", "100 * mean tick-to-tick command change (fraction of full scale)"),
    ("diverged", "float (flag)", "1 if the move diverged, else 0"),
)
"""Features of one move's response: name, type (unit) and meaning. ``e_ref`` is
``max(4, 0.001 * |distance|)`` counts, as in the cost (docs/cost.md)."""


def move_features(
    result: EpisodeResult, profile, distance_counts: int, settle_s: float
) -> np.ndarray:
    """The :data:`MOVE_FEATURES` of one move run with ``traces=True`` (float64, finite)."""
    m = result.metrics
    e_ref = max(4.0, 0.001 * abs(distance_counts))
    duration = max(m.n_ticks * m.dt, m.dt)
    u = result.traces.command.astype(np.float64) / FULL_SCALE
    n = u.shape[0]
    tail = u[max(0, n - max(1, n // 10)) :]
    acc = np.asarray(profile.acceleration[:n])
    up, down = acc > 0, acc < 0
    a_up = float(u[up].mean()) if up.any() else 0.0
    a_down = float(u[down].mean()) if down.any() else 0.0
    sign = 1.0 if distance_counts >= 0 else -1.0
    out = np.array(
        [
            math.log1p(m.iae / duration / e_ref),
            math.log1p(m.max_following_error / e_ref),
            math.log1p(m.overshoot / e_ref),
            m.settling_time / max(settle_s, m.dt),
            math.log1p(m.steady_state_error / e_ref),
            m.rms_command,
            float(u.mean()) if n else 0.0,
            float(tail.mean()) if n else 0.0,
            sign * (a_up - a_down) / 2.0,
            m.saturation_fraction,
            100.0 * m.chatter,
            1.0 if m.diverged else 0.0,
        ]
    )
    return clip(out)


def clip(x: np.ndarray) -> np.ndarray:
    """Replace non-finite entries by the clip bound of their sign (NaN by 0) and clip."""
    x = np.nan_to_num(np.asarray(x, dtype=np.float64), nan=0.0, posinf=OBS_CLIP, neginf=-OBS_CLIP)
    return np.clip(x, -OBS_CLIP, OBS_CLIP)


def plant_features(family: PlantFamily, values: Mapping[str, float]) -> np.ndarray:
    """The randomised plant parameters, each mapped onto [-1, 1] over its legal range
    (log scale for log-uniform ones): the privileged observation."""
    out = []
    for name in family.randomised():
        p = family.param(name)
        v = float(values[name])
        if p.distribution == "loguniform" and p.low > 0:
            t = (math.log(v) - math.log(p.low)) / (math.log(p.high) - math.log(p.low))
        else:
            t = (v - p.low) / (p.high - p.low) if p.high > p.low else 0.5
        out.append(2.0 * t - 1.0)
    return clip(np.array(out))
