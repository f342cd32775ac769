"""Linear response of the PMD filter's feedback path: docs/chips/pmd.md, section 6.

``C(z)`` is the motor command (signed 16-bit counts) per count of position error with the
commanded position held; rounding, saturation, limits, bias and feed-forward are left out.
"""

from __future__ import annotations

import numpy as np

from servogym.chips.pmd._params import PMDAssumptions, PMDParams


def derivative_response(d: int, mode: str, zi: np.ndarray) -> np.ndarray:
    """The held derivative D per count of error (spec 3.3), as a linear time-invariant filter.

    With ``derivative_time = d > 1`` the derivative is sampled every ``d`` cycles and held in
    between: a periodically time-varying filter. Its output at the input's own frequency
    (the part a sinusoid of that frequency comes back with; the rest are aliases at
    ``+-f + k/d`` of the sample rate) is exactly the LTI filter used here: the difference at
    a sample instant, ``1 - z^-d`` (PMD-A8 ``sample_difference``) or ``1 - z^-1``
    (``cycle_difference``), times the hold averaged over its ``d`` phases,
    ``H(z) = (1 + z^-1 + ... + z^-(d-1)) / d`` (a mean delay of ``(d - 1)/2`` cycles).
    With ``d = 1`` both modes give ``1 - z^-1``.

    Args:
        d: DerivativeTime (cycles), >= 1.
        mode: PMD-A8, ``"sample_difference"`` or ``"cycle_difference"``.
        zi: ``z^-1`` (any shape).
    """
    zi = np.asarray(zi, dtype=complex)
    zd = zi**d
    # The hold's geometric sum in closed form, (1 - z^-d) / (d (1 - z^-1)); its limit, 1,
    # at z = 1. (A term-by-term sum cost d array powers: 50 ms per call at d ~ 1000.)
    one = zi == 1
    hold = np.where(one, 1.0, (1 - zd) / (d * np.where(one, 2.0, 1 - zi)))
    diff = 1 - zd if mode == "sample_difference" else 1 - zi
    return hold * diff


def biquad_response(params: PMDParams, stage: int, frac: int, zi: np.ndarray) -> np.ndarray:
    """One biquad stage (spec 3.7): ``k (b0 + b1 z^-1 + b2 z^-2) / (1 + a1 z^-1 + a2 z^-2)``.

    Every coefficient is its register over ``2^frac`` (PMD-A12: 14 or 15 fractional bits).
    """
    b0, b1, b2, a1, a2, k = (
        getattr(params, f"biquad{stage}_{n}") / 2.0**frac
        for n in ("b0", "b1", "b2", "a1", "a2", "k")
    )
    return k * (b0 + b1 * zi + b2 * zi**2) / (1 + a1 * zi + a2 * zi**2)


def filter_response(params: PMDParams, assumptions: PMDAssumptions, z: np.ndarray) -> np.ndarray:
    """``C(z)``: motor command (signed 16-bit counts) per count of ``E = CP - AP``.

    ``C(z) = Kout/65536 * B1(z) B2(z) * [Kp + Ki 2^-s / (1 - z^-1) + Kd D(z)]`` with ``s``
    the integral shift (PMD-A2: 8 or 0; the integral includes this cycle's error),
    ``D(z)`` from :func:`derivative_response` (PMD-A8, DerivativeTime) and ``Bi`` each
    enabled biquad stage (MC58000; PMD-A12 coefficient format). Feed-forward, bias,
    rounding (PMD-A1), the saturations (PMD-A6, A7, A9), the integration and motor limits
    are left out.

    Args:
        params: The register values.
        assumptions: The assumption switches.
        z: Points of the z-plane (any shape).
    """
    a = assumptions
    zi = 1 / z
    integral = params.ki * 2.0 ** -int(a.integral_shift) / (1 - zi) if params.ki else 0.0
    derivative = params.kd * derivative_response(params.derivative_time, a.derivative_mode, zi)
    c = params.kp + integral + derivative
    frac = 14 if a.biquad_format == "q14" else 15
    for stage in (1, 2):
        if getattr(params, f"biquad{stage}_enable"):
            c = c * biquad_response(params, stage, frac, zi)
    return params.kout / 65536 * c


def derivative_polynomial(d: int, mode: str) -> np.ndarray:
    """:func:`derivative_response` as a polynomial in ``z^-1`` (ascending powers): an FIR.

    ``sample_difference``: ``(1 + ... + z^-(d-1)) (1 - z^-d) / d``, degree ``2d - 1``;
    ``cycle_difference``: ``(1 - z^-d) / d``, degree ``d``.
    """
    if mode == "sample_difference":
        out = np.zeros(2 * d)
        out[:d] = 1.0 / d
        out[d:] = -1.0 / d
        return out
    out = np.zeros(d + 1)
    out[0], out[d] = 1.0 / d, -1.0 / d
    return out


def filter_polynomials(
    params: PMDParams, assumptions: PMDAssumptions
) -> tuple[np.ndarray, np.ndarray]:
    """``(num, den)``, ascending powers of ``z^-1``: :func:`filter_response` as
    ``num(z^-1) / den(z^-1)``. The integral term puts ``1 - z^-1`` into ``den`` (only when
    ``Ki`` is not 0); each enabled biquad multiplies both."""
    a = assumptions
    deriv = params.kd * derivative_polynomial(params.derivative_time, a.derivative_mode)
    num = np.zeros(max(deriv.size, 1) + 1)
    num[: deriv.size] += deriv
    num[0] += params.kp
    den = np.array([1.0])
    if params.ki:
        num = np.convolve(num, [1.0, -1.0])
        num[0] += params.ki * 2.0 ** -int(a.integral_shift)
        den = np.array([1.0, -1.0])
    frac = 14 if a.biquad_format == "q14" else 15
    for stage in (1, 2):
        if getattr(params, f"biquad{stage}_enable"):
            b0, b1, b2, a1, a2, k = (
                getattr(params, f"biquad{stage}_{n}") / 2.0**frac
                for n in ("b0", "b1", "b2", "a1", "a2", "k")
            )
            num = np.convolve(num, [k * b0, k * b1, k * b2])
            den = np.convolve(den, [1.0, a1, a2])
    return np.trim_zeros(params.kout / 65536 * num, "b"), den
