"""Linear response of the 6000-series PIV&F feedback path: docs/chips/parker6k.md, section 10.

``C(z)`` is the motor command (signed 16-bit counts, 32768 = 10 V) per count of position
error with the commanded position held; rounding, the DAC's steps and saturation, SGILIM,
SOFFS and feed-forward are left out.
"""

from __future__ import annotations

import numpy as np

from servogym.chips.parker6k._params import Parker6kAssumptions, Parker6kParams
from servogym.chips.parker6k._reference import MICRO, scale_of


def filter_response(
    params: Parker6kParams, assumptions: Parker6kAssumptions, z: np.ndarray
) -> np.ndarray:
    """``C(z)``: motor-command counts per count of ``E = CP - AP`` with ``CP`` held.

    ``C(z) = 32768 / FS * [SGP + SGI T / 10^6 * I(z) + SGV 10^6 / T * (1 - z^-1)]`` with
    the gains as their registers (steps of 0.01 of PK-A1's unit, so one step times one
    count is one signal unit q), ``FS`` the q in 10 V (PK-A1: 10^9 for ``uV``, 10^6 for
    ``mV``) and ``T`` the servo period in us (SSFR). ``I(z) = 1 / (1 - z^-1)`` under PK-A10
    ``current`` (the integral includes this sample's error) and ``z^-1 / (1 - z^-1)`` under
    ``previous``, for every PK-A4 choice. The command is the DAC code times
    ``2^(16 - bits)``, so ``32768 / FS`` holds for either DAC width (PK-A2 changes only the
    step). The velocity term is the same under either PK-A3 choice: ``encoder`` differences
    ``-AP``, which with ``CP`` held is the error's difference; ``error_rate`` differences
    the error itself.
    The gains are those in force at sample 0 (an SGENB switch at tick 0, else
    ``sgp ... sgaf``); for stored set n, pass ``params.enable(n)``.

    Args:
        params: The settings in force.
        assumptions: The assumption switches.
        z: Points of the z-plane (any shape).
    """
    g = params.gains_at(0)
    fs, _, _ = scale_of(assumptions)
    period = params.sample_time_us
    zi = 1 / z
    integral = 0.0
    if g.sgi:
        delay = 1.0 if assumptions.integral_timing == "current" else zi
        integral = g.sgi * period / MICRO * delay / (1 - zi)
    velocity = g.sgv * MICRO / period * (1 - zi)
    return 2.0**15 / fs * (g.sgp + integral + velocity)


def filter_polynomials(
    params: Parker6kParams, assumptions: Parker6kAssumptions
) -> tuple[np.ndarray, np.ndarray]:
    """``(num, den)``, ascending powers of ``z^-1``: :func:`filter_response` as
    ``num(z^-1) / den(z^-1)``."""
    g = params.gains_at(0)
    fs, _, _ = scale_of(assumptions)
    period = params.sample_time_us
    kv = g.sgv * MICRO / period
    num = np.array([g.sgp + kv, -kv])
    den = np.array([1.0])
    if g.sgi:
        ki = g.sgi * period / MICRO
        num = np.convolve(num, [1.0, -1.0])
        integral = [ki, 0.0] if assumptions.integral_timing == "current" else [0.0, ki]
        num = num + np.array([*integral, 0.0])
        den = np.array([1.0, -1.0])
    return np.trim_zeros(2.0**15 / fs * num, "b"), den
