"""Loop margins: the plant linearised at its operating point, closed by the chip's filter.

The open loop of one axis at sample instants is ``L(z) = C(z) * P(z)``:

* ``P(z)``: encoder counts per motor-command count. The plant is linearised at its start
  position at rest with MuJoCo's ``mjd_transitionFD`` (continuous-time derivatives recovered
  exactly from a semi-implicit Euler step, Coulomb friction off: the sliding, least damped
  case; docs/simulation.md), extended by the amplifier (``amps_per_count``) and the current
  loop's first-order lag, and discretised exactly for the hold the servo loop simulates: the
  previous command until the loop latency ``L`` has passed, the new one after it:
  ``x[k+1] = Phi x[k] + G_new u[k] + G_old u[k-1]``.
* ``C(z)``: the linear part of the chip's integer filter (``ChipFamily.filter_response``).

From ``L(e^{jwT})`` on a logarithmic grid up to the Nyquist frequency: the phase margin at
every gain crossover (the smallest): at the first (the loop's bandwidth) 180 degrees plus the
phase taken continuous from the low-frequency end, as a Bode plot shows it
(:func:`continuous_phase`; negative for a loop unstable there), at any later one (a
resonance peak or a gain rise near Nyquist) the angle between ``L`` and -1; the gain margin at
every crossing of the negative real axis with ``|L| < 1`` (the smallest: how much more gain
the loop takes), and the closed-loop bandwidth (the first frequency where ``|L / (1 + L)|``
falls 3 dB below its low-frequency value).
"""

from __future__ import annotations

import dataclasses
import math
from typing import Any

import mujoco
import numpy as np
import scipy.linalg

N_FREQUENCIES = 400
"""Points of the logarithmic frequency grid."""

LOWEST_FREQUENCY_FRACTION = 1e-4
"""The grid starts at this fraction of the sample rate."""


@dataclasses.dataclass(frozen=True)
class LinearPlant:
    """A plant discretised at one servo period with one loop latency (see the module doc).

    Attributes:
        phi, g_new, g_old: ``x[k+1] = phi x[k] + g_new u[k] + g_old u[k-1] + drift``; ``u``
            is the motor command in counts.
        c: Output row: encoder counts of the motor joint.
        drift: What the plant does in a tick at zero command from rest: the gravity force
            at the operating point (no effect on the loop's transfer function).
        dt: Servo period (s).
        latency: Loop latency (s).
    """

    phi: np.ndarray
    g_new: np.ndarray
    g_old: np.ndarray
    drift: np.ndarray
    c: np.ndarray
    dt: float
    latency: float

    def response(self, z: np.ndarray) -> np.ndarray:
        """``P(z)``, counts per command count, at each ``z`` (complex array)."""
        n = self.phi.shape[0]
        z = np.asarray(z, dtype=complex)
        lhs = z[:, None, None] * np.eye(n)[None] - self.phi[None]
        rhs = self.g_new[None, :] + self.g_old[None, :] / z[:, None]
        x = np.linalg.solve(lhs, rhs[..., None])[..., 0]
        return x @ self.c


def continuous_model(plant: Any) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """``(A, B, C, d)`` of the plant from motor current (A) to encoder counts, continuous time.

    ``d`` is the state derivative at the operating point with zero current (gravity).

    The state is ``(qpos, qvel)`` (plus the current, with a current-loop lag); the plant's own
    state and model settings are left as they were.
    """
    model, io = plant.model, plant.io
    nv = model.nv
    data = mujoco.MjData(model)
    mujoco.mj_resetData(model, data)
    saved = (model.opt.timestep, model.opt.integrator, model.opt.disableflags)
    h = 1e-4
    try:
        model.opt.timestep = h
        model.opt.integrator = mujoco.mjtIntegrator.mjINT_EULER
        model.opt.disableflags |= (
            mujoco.mjtDisableBit.mjDSBL_FRICTIONLOSS | mujoco.mjtDisableBit.mjDSBL_EULERDAMP
        )
        mujoco.mj_forward(model, data)
        qacc0 = data.qacc.copy()
        ad = np.zeros((2 * nv, 2 * nv))
        bd = np.zeros((2 * nv, model.nu))
        mujoco.mjd_transitionFD(model, data, 1e-6, True, ad, bd, None, None)
    finally:
        model.opt.timestep, model.opt.integrator, model.opt.disableflags = saved
    # Semi-implicit Euler: v' = v + h a(q, v, u), q' = q + h v'. The velocity rows give the
    # continuous derivatives exactly: a_q = Ad[v, q] / h, a_v = (Ad[v, v] - I) / h, a_u = Bd[v] / h.
    a_q = ad[nv:, :nv] / h
    a_v = (ad[nv:, nv:] - np.eye(nv)) / h
    a_u = bd[nv:, io.ctrl_index] / h * io.torque_constant_nm_per_a  # per ampere
    tau = 0.0 if io.current_bandwidth_hz <= 0 else 1.0 / (2 * math.pi * io.current_bandwidth_hz)
    n = 2 * nv + (1 if tau > 0 else 0)
    a = np.zeros((n, n))
    b = np.zeros(n)
    a[:nv, nv : 2 * nv] = np.eye(nv)
    a[nv : 2 * nv, :nv] = a_q
    a[nv : 2 * nv, nv : 2 * nv] = a_v
    if tau > 0:
        a[nv : 2 * nv, 2 * nv] = a_u
        a[2 * nv, 2 * nv] = -1.0 / tau
        b[2 * nv] = 1.0 / tau
    else:
        b[nv : 2 * nv] = a_u
    c = np.zeros(n)
    c[io.qpos_adr] = io.counts_per_unit
    d = np.zeros(n)
    d[nv : 2 * nv] = qacc0
    return a, b, c, d


def _hold_integral(a: np.ndarray, b: np.ndarray, t: float) -> tuple[np.ndarray, np.ndarray]:
    """``(exp(A t), int_0^t exp(A s) ds B)`` by one matrix exponential."""
    n = a.shape[0]
    m = np.zeros((n + 1, n + 1))
    m[:n, :n] = a * t
    m[:n, n] = b * t
    e = scipy.linalg.expm(m)
    return e[:n, :n], e[:n, n]


def linearize(plant: Any, dt: float, latency: float, continuous: Any = None) -> LinearPlant:
    """The plant at period ``dt`` with loop latency ``latency`` (s), input in command counts.

    ``continuous``: the plant's :func:`continuous_model`, when already computed (it does not
    depend on ``dt`` or ``latency``); computed here otherwise.
    """
    a, b, c, d = continuous if continuous is not None else continuous_model(plant)
    b = b * plant.io.amp_amps_per_count
    phi_rest, g_new = _hold_integral(a, b, dt - latency)
    phi_lat, g_lat = _hold_integral(a, b, latency)
    _, drift = _hold_integral(a, d, dt)
    return LinearPlant(
        phi=phi_rest @ phi_lat, g_new=g_new, g_old=phi_rest @ g_lat, drift=drift, c=c,
        dt=float(dt), latency=float(latency),
    )  # fmt: skip


@dataclasses.dataclass(frozen=True)
class Margins:
    """Stability margins of an open loop.

    Attributes:
        gain_margin_db: Smallest gain margin (dB) over the crossings of the negative real
            axis with ``|L| < 1``; ``inf`` when there is none.
        phase_margin_deg: Smallest phase margin (degrees) over the gain crossovers; ``inf``
            when ``|L|`` never crosses 1.
        gain_crossover_hz: Frequency of that phase margin (Hz; ``nan`` when none).
        phase_crossover_hz: Frequency of that gain margin (Hz; ``nan`` when none).
        bandwidth_hz: Closed-loop -3 dB bandwidth (Hz; ``nan`` when it never drops).
    """

    gain_margin_db: float
    phase_margin_deg: float
    gain_crossover_hz: float
    phase_crossover_hz: float
    bandwidth_hz: float

    def to_dict(self) -> dict[str, float | None]:
        """JSON-ready (``inf`` and ``nan`` as ``None``)."""
        return {
            k: (float(v) if math.isfinite(v) else None) for k, v in dataclasses.asdict(self).items()
        }


def frequency_grid(dt: float, n: int = N_FREQUENCIES) -> np.ndarray:
    """Frequencies (Hz) from ``LOWEST_FREQUENCY_FRACTION / dt`` to just below Nyquist."""
    nyquist = 0.5 / dt
    return np.geomspace(LOWEST_FREQUENCY_FRACTION / dt, 0.999 * nyquist, n)


def _interp_at(x0: float, x1: float, y0: float, y1: float) -> float:
    return x0 if y1 == y0 else x0 + (x1 - x0) * (0.0 - y0) / (y1 - y0)


def margins(freqs_hz: np.ndarray, loop: np.ndarray) -> Margins:
    """Margins of the open loop ``loop`` (complex) sampled at ``freqs_hz`` (ascending)."""
    mag = np.abs(loop)
    with np.errstate(divide="ignore"):
        log_mag = np.log10(np.where(mag > 0, mag, 1e-300))
    phase = continuous_phase(loop)
    pm, f_pm = math.inf, math.nan
    for i, k in enumerate(np.flatnonzero(np.diff(np.sign(log_mag)) != 0)):
        f = _interp_at(freqs_hz[k], freqs_hz[k + 1], log_mag[k], log_mag[k + 1])
        w = (f - freqs_hz[k]) / (freqs_hz[k + 1] - freqs_hz[k])
        margin = 180.0 + math.degrees(phase[k] + w * (phase[k + 1] - phase[k]))
        if i > 0:  # a later crossover (a resonance, a boost near Nyquist): distance from -1
            margin = abs((margin + 180.0) % 360.0 - 180.0)
        if margin < pm:
            pm, f_pm = margin, f
    gm, f_gm = math.inf, math.nan
    im = loop.imag
    for k in np.flatnonzero(np.diff(np.sign(im)) != 0):
        f = _interp_at(freqs_hz[k], freqs_hz[k + 1], im[k], im[k + 1])
        w = (f - freqs_hz[k]) / (freqs_hz[k + 1] - freqs_hz[k])
        re = loop.real[k] + w * (loop.real[k + 1] - loop.real[k])
        if re < 0 and -re < 1:
            g = -20 * math.log10(-re) if re != 0 else math.inf
            if g < gm:
                gm, f_gm = g, f
    closed = np.abs(loop / (1 + loop))
    bw = math.nan
    below = np.flatnonzero(closed < closed[0] / math.sqrt(2))
    if below.size:
        bw = float(freqs_hz[below[0]])
    return Margins(float(gm), float(pm), float(f_pm), float(f_gm), bw)


def continuous_phase(loop: np.ndarray) -> np.ndarray:
    """The phase of ``loop`` (rad), continuous along the grid, its low-frequency end in
    (-2 pi, 0]: the phase a Bode plot shows (-270 degrees at low frequency for a PID on a
    rigid body), so that ``180 + phase`` at a gain crossover is the classical phase margin."""
    phase = np.unwrap(np.angle(loop))
    return phase - 2 * np.pi * math.ceil(phase[0] / (2 * np.pi))


def plant_response(
    plant: Any, dt: float, latency: float, continuous: Any = None
) -> tuple[np.ndarray, np.ndarray]:
    """``(freqs_hz, P)``: the plant's response on :func:`frequency_grid` for period ``dt``
    (``continuous`` as for :func:`linearize`)."""
    freqs = frequency_grid(dt)
    z = np.exp(2j * np.pi * freqs * dt)
    return freqs, linearize(plant, dt, latency, continuous).response(z)


def open_loop(
    family: Any, params: Any, assumptions: Any, freqs_hz: np.ndarray, plant: np.ndarray
) -> np.ndarray:
    """``L(e^{jwT}) = C(z) P(z)`` at ``freqs_hz``, ``plant`` from :func:`plant_response`."""
    z = np.exp(2j * np.pi * freqs_hz * family.sample_time_s(params))
    return family.filter_response(params, assumptions, z) * plant


def bode_plot(path: Any, freqs_hz: np.ndarray, loop: np.ndarray, m: Margins, title: str,
              limits: tuple[float, float] | None = None) -> None:  # fmt: skip
    """Write a Bode plot of the open loop with its margins marked (PNG)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, (ax_m, ax_p) = plt.subplots(2, 1, sharex=True, figsize=(8, 6.5))
    mag_db = 20 * np.log10(np.maximum(np.abs(loop), 1e-300))
    phase = np.degrees(continuous_phase(loop))
    ax_m.semilogx(freqs_hz, mag_db, color="C0")
    ax_m.axhline(0, color="0.5", lw=0.8)
    ax_m.set_ylabel("|L| (dB)")
    ax_p.semilogx(freqs_hz, phase, color="C0")
    for k in range(-4, 2):
        ax_p.axhline(-180 + 360 * k, color="0.5", lw=0.8)
    ax_p.set_ylabel("phase of L (deg)")
    ax_p.set_xlabel("frequency (Hz)")
    lo, hi = np.nanmin(phase), np.nanmax(phase)
    ax_p.set_ylim(min(lo, -200) - 20, max(hi, 0) + 20)
    if math.isfinite(m.gain_crossover_hz):
        ax_m.axvline(m.gain_crossover_hz, color="C2", ls="--", lw=1)
        ax_p.axvline(m.gain_crossover_hz, color="C2", ls="--", lw=1)
        ax_p.annotate(f"PM {m.phase_margin_deg:.1f} deg at {m.gain_crossover_hz:.0f} Hz",
                      (m.gain_crossover_hz, -180 + m.phase_margin_deg), color="C2",
                      xytext=(5, 5), textcoords="offset points")  # fmt: skip
    if math.isfinite(m.phase_crossover_hz):
        ax_m.axvline(m.phase_crossover_hz, color="C3", ls="--", lw=1)
        ax_m.annotate(f"GM {m.gain_margin_db:.1f} dB at {m.phase_crossover_hz:.0f} Hz",
                      (m.phase_crossover_hz, -m.gain_margin_db), color="C3",
                      xytext=(5, -12), textcoords="offset points")  # fmt: skip
    if math.isfinite(m.bandwidth_hz):
        ax_m.axvline(m.bandwidth_hz, color="C1", ls=":", lw=1)
    note = ""
    if limits is not None:
        note = f" (minima {limits[0]:g} dB, {limits[1]:g} deg)"
    fig.suptitle(title + note)
    ax_m.set_title(
        f"gain margin {_fmt(m.gain_margin_db, 'dB')}, phase margin "
        f"{_fmt(m.phase_margin_deg, 'deg')}, closed-loop bandwidth {_fmt(m.bandwidth_hz, 'Hz')}",
        fontsize=9,
    )
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def _fmt(x: float, unit: str) -> str:
    if math.isinf(x):
        return "unbounded"
    if math.isnan(x):
        return "none"
    return f"{x:.3g} {unit}"
