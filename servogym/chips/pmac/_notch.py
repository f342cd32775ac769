"""Notch and low-pass design for Ixx36..Ixx39, and the filter's frequency response.

The design follows the Turbo PMAC User Manual ("Manual Notch Specification", "Second-Order
Filter"): a continuous second-order section is discretized with the backward difference
``s = (1 - z^-1) / Ts``, which gives, for natural frequency ``wn`` and damping ``zeta``,

    alpha = 1 + 2 zeta wn Ts + wn^2 Ts^2
    c1 = -2 (1 + zeta wn Ts) / alpha,   c2 = 1 / alpha

for the zeros (Ixx36, Ixx37) and the poles (Ixx38, Ixx39), and Ixx30 is rescaled so the
filter's DC gain does not change the loop gain. ``Ts`` is the filter's period: the servo
period times (Ixx60 + 1). The backward difference places the discrete notch below the
continuous one (at ``atan(wn Ts) / Ts`` for an undamped zero); ``prewarp=True`` scales the
frequencies handed to the manual's formulas so the notch's minimum lands where asked.

The response functions evaluate the filter with the coefficients as loaded (24-bit words with
22 fractional bits), so a plot shows what the controller runs.
"""

from __future__ import annotations

import dataclasses
import math
import numbers
from collections.abc import Sequence
from fractions import Fraction
from pathlib import Path
from typing import Any

import numpy as np

from servogym.chips._space import ParameterError
from servogym.chips.pmac._params import (
    COEFFICIENT_FIELDS,
    PMACAssumptions,
    PMACParams,
    coefficient_raw,
    parameter_space,
)

__all__ = [
    "FilterDesign",
    "FrequencyResponse",
    "controller_response",
    "design_low_pass",
    "design_notch",
    "notch_response",
    "plot_frequency_response",
]

_ONE = 1 << 22


def _positive(name: str, value: Any) -> float:
    if isinstance(value, bool) or not isinstance(value, numbers.Real):
        raise ParameterError(
            f"{name} must be a finite number > 0; got {name}={value!r} of type "
            f"{type(value).__name__}."
        )
    x = float(value)
    if not (math.isfinite(x) and x > 0):
        raise ParameterError(f"{name} must be a finite number > 0; got {name}={value!r}.")
    return x


def _damping(name: str, value: Any) -> float:
    if isinstance(value, bool) or not isinstance(value, numbers.Real):
        raise ParameterError(f"{name} must satisfy 0 <= {name} < 1; got {name}={value!r}.")
    x = float(value)
    if not 0.0 <= x < 1.0:
        raise ParameterError(f"{name} must satisfy 0 <= {name} < 1; got {name}={value!r}.")
    return x


def _frequency(name: str, value: Any, ts: float) -> float:
    f = _positive(name, value)
    nyquist = 0.5 / ts
    if not f < nyquist:
        raise ParameterError(
            f"{name} must satisfy 0 < {name} < {nyquist:.6g} Hz (half the filter's sample "
            f"rate at sample_time_s={ts!r}); got {name}={value!r}."
        )
    return f


def _response_min_hz(coeffs: tuple[float, float, float, float], ts: float) -> float:
    """Frequency of the smallest |F| over (0, Nyquist): a dense grid, then golden section."""
    n1, n2, d1, d2 = coeffs

    def mag2(theta: np.ndarray | float) -> np.ndarray | float:
        zi = np.exp(-1j * np.asarray(theta))
        return np.abs(1 + n1 * zi + n2 * zi * zi) ** 2 / np.abs(1 + d1 * zi + d2 * zi * zi) ** 2

    grid = np.linspace(0.0, math.pi, 4097)[1:-1]
    i = int(np.argmin(mag2(grid)))
    lo, hi = grid[max(i - 1, 0)], grid[min(i + 1, grid.size - 1)]
    g = (math.sqrt(5.0) - 1.0) / 2.0
    for _ in range(60):
        a, b = hi - g * (hi - lo), lo + g * (hi - lo)
        if mag2(a) < mag2(b):
            hi = b
        else:
            lo = a
    return 0.5 * (lo + hi) / (2 * math.pi * ts)


def _prewarp_scale(fz: float, zz: float, fp: float, zp: float, ts: float) -> float:
    """The factor k so that zeros at k*fz and poles at k*fp put the minimum of |F| at fz."""

    def miss(k: float) -> float:
        coeffs = (*_section(k * fz, zz, ts), *_section(k * fp, zp, ts))
        return _response_min_hz(coeffs, ts) - fz

    lo, hi = 1.0, 1.0
    if miss(lo) >= 0:
        return lo
    while miss(hi) < 0:
        lo, hi = hi, hi * 1.1
        if hi > 100.0:
            raise ParameterError(
                f"prewarp cannot place the notch minimum at {fz!r} Hz with "
                f"sample_time_s={ts!r}: no scaling of the backward-difference design up to "
                f"100x puts it there; lower zero_hz or pass prewarp=False."
            )
    for _ in range(50):
        mid = 0.5 * (lo + hi)
        if miss(mid) < 0:
            lo = mid
        else:
            hi = mid
    return 0.5 * (lo + hi)


def _section(f_hz: float, zeta: float, ts: float) -> tuple[float, float]:
    """The manual's backward-difference coefficients (c1, c2) of one second-order section."""
    wt = 2 * math.pi * f_hz * ts
    alpha = 1.0 + 2.0 * zeta * wt + wt * wt
    return -2.0 * (1.0 + zeta * wt) / alpha, 1.0 / alpha


def _raw(name: str, value: float) -> int:
    raw = coefficient_raw(value)
    spec = parameter_space("TurboPMAC2")[name]
    if not spec.low <= raw <= spec.high:
        raise ParameterError(
            f"the design needs {name}={value!r}, outside the coefficient range -2.0 <= "
            f"{name} < 2.0 ({spec.range_text} as a 24-bit word); change the frequency or "
            f"damping."
        )
    return raw


@dataclasses.dataclass(frozen=True)
class FilterDesign:
    """Ixx36..Ixx39 from a design helper, as the 24-bit words the controller stores.

    Attributes:
        notch_n1, notch_n2, notch_d1, notch_d2: Ixx36..Ixx39, raw (value * 2^22).
        sample_time_s: The filter period the design is for (servo period times Ixx60+1).
        marks_hz: Frequencies the design placed (zeros first), for plots.
        proportional_gain: Ixx30 rescaled for the DC gain, when a gain was given.
    """

    notch_n1: int
    notch_n2: int
    notch_d1: int
    notch_d2: int
    sample_time_s: float
    marks_hz: tuple[float, ...] = ()
    proportional_gain: int | None = None

    @property
    def coefficients(self) -> tuple[float, float, float, float]:
        """Ixx36..Ixx39 as the values the controller holds (raw / 2^22)."""
        return (
            self.notch_n1 / _ONE,
            self.notch_n2 / _ONE,
            self.notch_d1 / _ONE,
            self.notch_d2 / _ONE,
        )

    @property
    def dc_gain(self) -> Fraction:
        """F(1) = (1 + n1 + n2) / (1 + d1 + d2) of the stored coefficients, exactly."""
        num = _ONE + self.notch_n1 + self.notch_n2
        den = _ONE + self.notch_d1 + self.notch_d2
        if den == 0:
            raise ParameterError(
                "the filter has a pole at z = 1 (1 + d1 + d2 = 0): its DC gain is infinite."
            )
        return Fraction(num, den)

    def rescaled_gain(self, proportional_gain: int) -> int:
        """Ixx30 that keeps the loop's DC gain: ``round(Ixx30 / F(1))``.

        This is the manual's ``Ixx30_new = Ixx30_old * wnp^2 alpha_z / (wnz^2 alpha_p)``
        (``* wn^2 Ts^2 / alpha`` for the low-pass), evaluated with the coefficients as stored.

        Raises:
            ParameterError: if the result falls outside Ixx30's range.
        """
        gain = Fraction(int(proportional_gain)) / self.dc_gain
        new = math.floor(gain + Fraction(1, 2))
        return parameter_space("TurboPMAC2")["proportional_gain"].validate(
            new, context="rescaled by the filter design"
        )

    def registers(self) -> dict[str, int]:
        """The registers the design sets: Ixx36..Ixx39, and Ixx30 if it was rescaled."""
        out = {f: getattr(self, f) for f in COEFFICIENT_FIELDS}
        if self.proportional_gain is not None:
            out["proportional_gain"] = self.proportional_gain
        return out

    def apply(self, params: PMACParams) -> PMACParams:
        """``params`` with these coefficients and its own Ixx30 rescaled for the DC gain.

        Raises:
            ParameterError: if ``params`` runs at another filter period than the design's.
        """
        if not math.isclose(params.sample_time_s, self.sample_time_s, rel_tol=1e-9):
            raise ParameterError(
                f"the filter was designed for sample_time_s={self.sample_time_s!r} but the "
                f"parameter set runs at sample_time_s={params.sample_time_s!r} (servo period "
                f"times Ixx60+1); design it again for that period."
            )
        changes = {f: getattr(self, f) for f in COEFFICIENT_FIELDS}
        changes["proportional_gain"] = self.rescaled_gain(params.proportional_gain)
        return params.replace(**changes)


def design_notch(
    zero_hz: float,
    sample_time_s: float,
    *,
    zero_damping: float = 0.05,
    pole_hz: float | None = None,
    pole_damping: float = 0.7,
    proportional_gain: int | None = None,
    prewarp: bool = False,
) -> FilterDesign:
    """A notch: lightly damped zeros (band reject) over heavily damped poles (band pass).

    The manual recommends the zeros at about 90 % of the resonance and the poles somewhat
    above it; by default the poles sit at the zeros' frequency, which gives a symmetric notch
    with unity gain far from it.

    Args:
        zero_hz: Natural frequency of the zeros (the notch), Hz, below half the sample rate.
        sample_time_s: The filter's period (``PMACParams.sample_time_s``), s.
        zero_damping: Damping ratio of the zeros, 0 <= zeta < 1 (0 = deepest notch).
        pole_hz: Natural frequency of the poles, Hz; default ``zero_hz``.
        pole_damping: Damping ratio of the poles, 0 <= zeta < 1.
        proportional_gain: Ixx30 before the filter; if given, the design carries it rescaled.
        prewarp: Scale both frequencies (keeping their ratio) so the minimum of |F| lands on
            ``zero_hz``; without it the backward difference puts it lower (about 2 % at 100
            Hz, 5 % at 200 Hz with the default 442.7 us period). The depth does not change.

    Returns:
        The coefficients as 24-bit words (and the rescaled Ixx30).

    Raises:
        ParameterError: for an illegal argument, or a coefficient or Ixx30 out of range.
    """
    ts = _positive("sample_time_s", sample_time_s)
    fz = _frequency("zero_hz", zero_hz, ts)
    fp = fz if pole_hz is None else _frequency("pole_hz", pole_hz, ts)
    zz = _damping("zero_damping", zero_damping)
    zp = _damping("pole_damping", pole_damping)
    if prewarp:
        k = _prewarp_scale(fz, zz, fp, zp, ts)
        fz, fp = k * fz, k * fp
    n1, n2 = _section(fz, zz, ts)
    d1, d2 = _section(fp, zp, ts)
    design = FilterDesign(
        _raw("notch_n1", n1),
        _raw("notch_n2", n2),
        _raw("notch_d1", d1),
        _raw("notch_d2", d2),
        ts,
        (float(zero_hz), float(pole_hz if pole_hz is not None else zero_hz)),
    )
    if proportional_gain is not None:
        design = dataclasses.replace(
            design, proportional_gain=design.rescaled_gain(proportional_gain)
        )
    return design


def design_low_pass(
    cutoff_hz: float,
    sample_time_s: float,
    *,
    damping: float = 0.707,
    proportional_gain: int | None = None,
) -> FilterDesign:
    """A second-order low-pass in the poles (Ixx38, Ixx39); Ixx36 = Ixx37 = 0.

    Its DC gain is ``alpha / (wn Ts)^2`` (about 129 for 60 Hz at 250 us), so Ixx30 drops by
    the same factor (the manual's example: ``Ixx30_new = 0.00774 * Ixx30_old``).

    Args:
        cutoff_hz: Cutoff (natural) frequency, Hz, below half the sample rate.
        sample_time_s: The filter's period (``PMACParams.sample_time_s``), s.
        damping: Damping ratio, 0 <= zeta < 1 (0.707: Butterworth).
        proportional_gain: Ixx30 before the filter; if given, the design carries it rescaled.

    Returns:
        The coefficients as 24-bit words (and the rescaled Ixx30).

    Raises:
        ParameterError: for an illegal argument, or a coefficient or Ixx30 out of range.
    """
    ts = _positive("sample_time_s", sample_time_s)
    fc = _frequency("cutoff_hz", cutoff_hz, ts)
    z = _damping("damping", damping)
    d1, d2 = _section(fc, z, ts)
    design = FilterDesign(0, 0, _raw("notch_d1", d1), _raw("notch_d2", d2), ts, (float(cutoff_hz),))
    if proportional_gain is not None:
        design = dataclasses.replace(
            design, proportional_gain=design.rescaled_gain(proportional_gain)
        )
    return design


# --------------------------------------------------------------------------------------
# Frequency response
# --------------------------------------------------------------------------------------


@dataclasses.dataclass(frozen=True)
class FrequencyResponse:
    """A complex frequency response.

    Attributes:
        freqs_hz: Frequencies, Hz (1-D float array).
        response: Complex response at each frequency.
        unit: Unit of ``|response|``.
    """

    freqs_hz: np.ndarray
    response: np.ndarray
    unit: str

    @property
    def magnitude(self) -> np.ndarray:
        """|response|."""
        return np.abs(self.response)

    @property
    def magnitude_db(self) -> np.ndarray:
        """20 log10 |response| (dB; -inf where it is 0)."""
        with np.errstate(divide="ignore"):
            return 20.0 * np.log10(self.magnitude)

    @property
    def phase_deg(self) -> np.ndarray:
        """Phase in degrees, unwrapped along frequency."""
        return np.degrees(np.unwrap(np.angle(self.response)))


def _design_or_params(source: PMACParams | FilterDesign) -> tuple[tuple[float, ...], float]:
    if isinstance(source, FilterDesign):
        return source.coefficients, source.sample_time_s
    if isinstance(source, PMACParams):
        return tuple(float(c) for c in source.coefficients()), source.sample_time_s
    raise ParameterError(
        f"source must be a PMACParams or a FilterDesign; got {type(source).__name__}."
    )


def _freqs(freqs_hz: Any, ts: float) -> np.ndarray:
    if freqs_hz is None:
        return np.geomspace(1.0, 0.5 / ts, 2000)
    f = np.asarray(freqs_hz, dtype=float)
    if f.ndim != 1 or f.size == 0 or not np.all(np.isfinite(f)) or np.any(f < 0):
        raise ParameterError("freqs_hz must be a non-empty 1-D sequence of finite values >= 0.")
    return f


def notch_response(
    source: PMACParams | FilterDesign, freqs_hz: Sequence[float] | np.ndarray | None = None
) -> FrequencyResponse:
    """F(z) = (1 + n1 z^-1 + n2 z^-2) / (1 + d1 z^-1 + d2 z^-2) on the unit circle.

    Args:
        source: A parameter set or a design (its stored coefficients and filter period).
        freqs_hz: Frequencies, Hz; default 2000 log-spaced from 1 Hz to half the sample rate.

    Returns:
        The response (dimensionless).
    """
    (n1, n2, d1, d2), ts = _design_or_params(source)
    f = _freqs(freqs_hz, ts)
    zi = np.exp(-2j * np.pi * f * ts)
    return FrequencyResponse(f, (1 + n1 * zi + n2 * zi**2) / (1 + d1 * zi + d2 * zi**2), "1")


def controller_response(
    params: PMACParams,
    freqs_hz: Sequence[float] | np.ndarray | None = None,
    assumptions: PMACAssumptions | None = None,
) -> FrequencyResponse:
    """The whole linear filter from following error to DAC value, at rest (CV = 0).

    ``C(z) = 2^-19 Ixx30 F(z) [Ixx08 (1 + Ixx33 2^-23 z^-1 / (1 - z^-1))
    + Ixx31 Ixx09 2^-7 (1 - z^-1)]``: the manual's PID equation with the commanded position
    held (so the actual velocity is minus the error's difference), in DAC bits per count
    (``PMAC.filter_response``; under PMAC-A2 ``current`` the integral has no ``z^-1``).
    Limits, deadband, big-step limit and rounding are left out.

    Args:
        params: The parameter set.
        freqs_hz: Frequencies, Hz; default 2000 log-spaced from 1 Hz to half the sample rate.
        assumptions: The assumption switches; default the defaults.
    """
    from servogym.chips.pmac._family import PMAC

    if not isinstance(params, PMACParams):
        raise ParameterError(f"params must be a PMACParams; got {type(params).__name__}.")
    f = _freqs(freqs_hz, params.sample_time_s)
    return FrequencyResponse(
        f, PMAC.filter_frequency_response(params, assumptions, f), "DAC bits/count"
    )


def plot_frequency_response(
    params: PMACParams | FilterDesign,
    path: str | Path,
    *,
    freqs_hz: Sequence[float] | np.ndarray | None = None,
    controller: bool = True,
    mark_hz: Sequence[float] | None = None,
    title: str | None = None,
) -> Path:
    """Plot magnitude and phase to a PNG: the notch F(z), and the whole filter C(z).

    Args:
        params: A parameter set, or a design (then only F(z) is drawn).
        path: Output file (``.png``).
        freqs_hz: Frequencies, Hz; default 2000 log-spaced from 1 Hz to half the sample rate.
        controller: Also draw C(z) (needs a parameter set).
        mark_hz: Frequencies to mark with dashed lines; default a design's ``marks_hz``.
        title: Figure title.

    Returns:
        The path written.
    """
    from matplotlib.figure import Figure

    curves = [("notch F(z)", notch_response(params, freqs_hz))]
    if controller and isinstance(params, PMACParams):
        curves.append(("controller C(z)", controller_response(params, freqs_hz)))
    if mark_hz is None:
        mark_hz = params.marks_hz if isinstance(params, FilterDesign) else ()
    fig = Figure(figsize=(6.0 * len(curves), 6.0), constrained_layout=True)
    axes = fig.subplots(2, len(curves), sharex=True, squeeze=False)
    for col, (label, resp) in enumerate(curves):
        mag, ph = axes[0, col], axes[1, col]
        mag.semilogx(resp.freqs_hz, resp.magnitude_db, color="C0")
        ph.semilogx(resp.freqs_hz, resp.phase_deg, color="C1")
        mag.set_title(label)
        unit = "" if resp.unit == "1" else f" re 1 {resp.unit}"
        mag.set_ylabel(f"magnitude (dB{unit})")
        ph.set_ylabel("phase (deg)")
        ph.set_xlabel("frequency (Hz)")
        for ax in (mag, ph):
            ax.grid(True, which="both", alpha=0.3)
            for f in mark_hz:
                ax.axvline(float(f), color="0.4", linestyle="--", linewidth=1)
    if title:
        fig.suptitle(title)
    out = Path(path)
    fig.savefig(out, dpi=100)
    return out
