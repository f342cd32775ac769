"""Linear response of the Turbo PMAC filter's feedback path: docs/chips/pmac.md, section 10.

``C(z)`` is the DAC value (signed 16-bit counts) per count of following error with the
commanded position held, so the actual velocity AV is minus the error's difference and the
Ixx31 term damps; rounding, saturation, limits, deadband, bias and feed-forward are left out.
"""

from __future__ import annotations

import numpy as np

from servogym.chips.pmac._params import PMACAssumptions, PMACParams


def notch_transfer(params: PMACParams, zi: np.ndarray) -> np.ndarray:
    """``F(z) = (1 + n1 z^-1 + n2 z^-2) / (1 + d1 z^-1 + d2 z^-2)``, Ixx36..39 over 2^22."""
    n1, n2, d1, d2 = (
        w / 2.0**22 for w in (params.notch_n1, params.notch_n2, params.notch_d1, params.notch_d2)
    )
    return (1 + n1 * zi + n2 * zi**2) / (1 + d1 * zi + d2 * zi**2)


def filter_response(params: PMACParams, assumptions: PMACAssumptions, z: np.ndarray) -> np.ndarray:
    """``C(z)``: DAC counts per count of ``FE = CP - AP`` with ``CP`` held.

    ``C(z) = 2^-19 Ixx30 F(z) [Ixx08 (1 + Ixx33 2^-23 I(z)) + Ixx31 Ixx09 2^-7 (1 - z^-1)]``
    with ``I(z) = z^-1 / (1 - z^-1)`` under PMAC-A2 ``previous`` (update n's output uses the
    errors before n) and ``1 / (1 - z^-1)`` under ``current``. ``F`` is the notch
    (Ixx36..39), the same in either position (PMAC-A5) and form (PMAC-A6). ``z`` is taken at
    the filter period, the servo period times Ixx60 + 1 (``PMACParams.sample_time_s``).
    The deadband is taken at its slope outside the band, 1 (exact for Ixx64 = 0, the
    default; inside ``|FE| < Ixx65/16`` counts the gain is ``(16 + Ixx64)/16`` times this).
    The integrator runs (Ixx34 = 1 holds it only while the commanded position moves).

    Args:
        params: The I-variables of one motor.
        assumptions: The assumption switches.
        z: Points of the z-plane (any shape).
    """
    zi = 1 / z
    integral = 0.0
    if params.integral_gain:
        delay = zi if assumptions.integral_timing == "previous" else 1.0
        integral = params.integral_gain * 2.0**-23 * delay / (1 - zi)
    pid = params.position_loop_scale * (1 + integral) + (
        params.derivative_gain * params.velocity_loop_scale * 2.0**-7 * (1 - zi)
    )
    return 2.0**-19 * params.proportional_gain * notch_transfer(params, zi) * pid


def filter_polynomials(
    params: PMACParams, assumptions: PMACAssumptions
) -> tuple[np.ndarray, np.ndarray]:
    """``(num, den)``, ascending powers of ``z^-1`` (at the filter period, Ixx60
    included): :func:`filter_response` as ``num(z^-1) / den(z^-1)``."""
    ks = params.position_loop_scale
    kv = params.derivative_gain * params.velocity_loop_scale * 2.0**-7
    pid = np.array([ks + kv, -kv])
    den = np.array([1.0])
    if params.integral_gain:
        ki = ks * params.integral_gain * 2.0**-23
        pid = np.convolve(pid, [1.0, -1.0])
        integral = [0.0, ki] if assumptions.integral_timing == "previous" else [ki, 0.0]
        pid = pid + np.array([*integral, 0.0])
        den = np.array([1.0, -1.0])
    n1, n2, d1, d2 = (
        w / 2.0**22 for w in (params.notch_n1, params.notch_n2, params.notch_d1, params.notch_d2)
    )
    num = 2.0**-19 * params.proportional_gain * np.convolve([1.0, n1, n2], pid)
    return np.trim_zeros(num, "b"), np.trim_zeros(np.convolve(den, [1.0, d1, d2]), "b")
