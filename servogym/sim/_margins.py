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

Stability is decided from the closed loop's poles, never from margins: the eigenvalues of
its state matrix (plant states, the held command ``u[k-1]``, the filter's states; the
spectral radius) or, for a filter of high order (a long PMD DerivativeTime), the number of
roots of the characteristic polynomial ``den_C den_P + num_C num_P`` outside the circle
``|z| = 1 - STABILITY_EPS``, counted by the argument principle (:func:`closed_loop_stability`).
The margins come from ``L(e^{jwT})``: every gain crossover (``|L| = 1``) and every crossing of
the negative real axis, bracketed on a grid refined until ``|L|`` and the phase change little
between points and located by Brent's method; each crossover's signed phase margin and delay
margin, each phase crossover's gain margin (negative where ``|L| > 1``: a gain reduction
margin), and the closed-loop bandwidth root-found (:class:`Margins` states the conventions;
docs/simulation.md, "Margins").
"""

from __future__ import annotations

import collections
import dataclasses
import functools
import math
import threading
from typing import Any

import mujoco
import numpy as np
import scipy.linalg
import scipy.optimize

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

    @property
    def _memo(self) -> dict[Any, Any]:
        """What :func:`analyse_loop` computes once per linear plant (read-only arrays), kept
        for the :data:`PLANT_MEMO_SIZE` plants used last (:func:`_plant_memo`)."""
        return _plant_memo(self)

    def _search_response(self, theta_lo: float) -> np.ndarray:
        """``P`` on the crossover search's base grid (``_base_grid(theta_lo)``), from the
        plant's polynomials as :func:`analyse_loop` evaluates it."""
        memo, key = self._memo, ("search", theta_lo)
        if key not in memo:
            p = self._polynomial_response(np.exp(-1j * _base_grid(theta_lo)))
            p.setflags(write=False)
            memo[key] = p
        return memo[key]

    def _polynomial_response(self, x: np.ndarray) -> np.ndarray:
        """``P`` at ``x = z^-1`` (a 1-d array) from :func:`plant_polynomials`: ``num(x) /
        den(x)``, both by Horner's rule in one pass (the float operations of ``np.polyval``,
        on a stack of the two coefficient rows, ``den`` led by zeros to ``num``'s length)."""
        memo = self._memo
        if "horner" not in memo:
            num, den = plant_polynomials(self)
            rows = np.zeros((2, max(num.size, den.size)))
            rows[0, rows.shape[1] - num.size :] = num[::-1]
            rows[1, rows.shape[1] - den.size :] = den[::-1]
            memo["horner"] = [col[:, None] for col in rows.T]
        y = np.zeros((2, x.size), dtype=complex)
        for col in memo["horner"]:
            y = y * x + col
        return y[0] / y[1]

    def _display_response(self) -> np.ndarray:
        """``P`` on the display grid :func:`frequency_grid` of the plant's period."""
        memo = self._memo
        if "display" not in memo:
            grid = _display_grid(self.dt)
            p = self.response(np.exp(1j * (2 * np.pi * grid * self.dt)))
            p.setflags(write=False)
            memo["display"] = p
        return memo["display"]


PLANT_MEMO_SIZE = 128
"""Linear plants whose gain-independent parts (polynomials, responses on the search's base
grid and on the display grid: some 110 kB each) are kept, the last used first out. An
evaluation with margins at every latency uses up to eight (four latencies, two holding
points) per plant instance."""

_plant_memos: collections.OrderedDict[int, tuple[LinearPlant, dict]] = collections.OrderedDict()
_plant_memo_lock = threading.Lock()


def _plant_memo(lin: LinearPlant) -> dict[Any, Any]:
    """The memo of ``lin`` (a new one when it is not among the last :data:`PLANT_MEMO_SIZE`
    plants used). Each entry holds its plant, so its ``id`` is not reused while it lives."""
    key = id(lin)
    with _plant_memo_lock:
        hit = _plant_memos.get(key)
        if hit is not None and hit[0] is lin:
            _plant_memos.move_to_end(key)
            return hit[1]
        memo: dict[Any, Any] = {}
        _plant_memos[key] = (lin, memo)
        while len(_plant_memos) > PLANT_MEMO_SIZE:
            _plant_memos.popitem(last=False)
        return memo


def continuous_model(
    plant: Any, qpos: Any = None
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """``(A, B, C, d)`` of the plant from motor current (A) to encoder counts, continuous time.

    ``d`` is the state derivative at the operating point with zero current (gravity).
    The operating point is at rest at ``qpos`` (every joint's position, ``model.nq``
    values; default the model's reset position ``qpos0``): a holding point under gravity.

    The state is ``(qpos, qvel)`` (plus the current, with a current-loop lag); the plant's own
    state and model settings are left as they were.
    """
    model, io = plant.model, plant.io
    nv = model.nv
    data = mujoco.MjData(model)
    mujoco.mj_resetData(model, data)
    if qpos is not None:
        data.qpos[:] = np.asarray(qpos, dtype=float)
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
    return discretize((a, b * plant.io.amp_amps_per_count, c, d), dt, latency)


def discretize(continuous: Any, dt: float, latency: float) -> LinearPlant:
    """The continuous model ``(A, B, C, d)`` (input in command counts, output in encoder
    counts) held for a period ``dt`` after a loop latency ``latency`` (s)."""
    a, b, c, d = continuous
    phi_rest, g_new = _hold_integral(a, b, dt - latency)
    phi_lat, g_lat = _hold_integral(a, b, latency)
    _, drift = _hold_integral(a, d, dt)
    return LinearPlant(
        phi=phi_rest @ phi_lat, g_new=g_new, g_old=phi_rest @ g_lat, drift=drift, c=c,
        dt=float(dt), latency=float(latency),
    )  # fmt: skip


STABILITY_EPS = 1e-9
"""A closed loop is stable when every pole has ``|z| < 1 - STABILITY_EPS``; a pole on or
within this distance of the unit circle (a marginal loop: a free rigid body, an
uncontrolled mode) is not stable. 1e-9 leaves a slow integrator's pole (``1 - 1e-7`` per
tick at the smallest integral gains) stable while rounding (1e-13 on a simple pole) cannot
move a pole on the circle inside it."""

EIGEN_MAX_ORDER = 160
"""Closed loops up to this order are decided by the eigenvalues of their state matrix
(which gives the spectral radius); higher orders (a PMD DerivativeTime in the tens and
above) by counting the characteristic polynomial's roots with the argument principle."""

ANALYSIS_LOWEST_FRACTION = 1e-6
"""Crossovers are searched from this fraction of the sample rate up to the Nyquist
frequency."""

GRID_LOG_POINTS = 4000
"""Points of the logarithmic base grid of the crossover search (before refinement)."""

REFINE_LOG_MAGNITUDE = 0.02
"""Grid intervals where ``ln |L|`` changes by more than this (0.17 dB) are split."""

REFINE_PHASE_RAD = 0.02
"""Grid intervals where the phase of ``L`` changes by more than this (1.1 degrees) are
split."""

MAX_GRID_POINTS = 400_000
"""The refinement stops adding points beyond this size."""


@dataclasses.dataclass(frozen=True)
class Stability:
    """Closed-loop stability of the linear loop, decided from its poles.

    Attributes:
        stable: Every closed-loop pole has ``|z| < 1 - STABILITY_EPS``.
        n_unstable: Closed-loop poles with ``|z| >= 1 - STABILITY_EPS``.
        spectral_radius: Largest pole magnitude (``nan`` when decided by the encirclement
            count): the factor the loop's slowest-decaying (or fastest-growing) mode is
            multiplied by per tick.
        order: Order of the closed loop (plant states, the held command, filter states).
        method: ``"eigenvalues"`` or ``"encirclement"``.
    """

    stable: bool
    n_unstable: int
    spectral_radius: float
    order: int
    method: str


@dataclasses.dataclass(frozen=True)
class Margins:
    """Stability and stability margins of a closed loop (see docs/simulation.md, "Margins").

    Conventions. ``L = C P`` at ``z = exp(j w T)``. At a gain crossover (``|L| = 1``) let
    ``phi`` be the phase, in (-180, 180] degrees, that a pure phase lag (``phi > 0``) or lead
    (``phi < 0``) needs to move ``L`` onto -1 (``phi = angle(L) + 180``, wrapped). Passing a
    crossover where ``|L|`` falls with frequency (the usual one) by lag, or one where ``|L|``
    rises (the near side of a resonance peak) by lead, adds two unstable poles; the other
    way removes two. The signed phase margin of a crossover is ``+|phi|`` when reaching it
    adds unstable poles (the Nyquist curve passes -1 on the stable side there) and
    ``-|phi|`` when it removes them (the wrong side); for a falling ``|L|`` it is the
    classical ``180 + phase``. At a phase crossover (``L = -r``, ``r > 0``) the gain margin
    is ``-20 log10 r`` dB: positive where ``r < 1`` (the gain may rise this much), negative
    where ``r > 1`` (a gain reduction of ``|gm|`` dB reaches -1: a conditionally stable loop).

    Attributes:
        gain_margin_db: Stable loop: the smallest change of the loop gain, up or down, in
            dB, that destabilises it (the smallest ``|gm|`` over the phase crossovers;
            ``inf`` when no gain does). Unstable loop: minus the smallest change that makes
            it stable (0 when none does: never ``inf``, JSON's ``None``); always <= 0.
        phase_margin_deg: Stable loop: the smallest pure phase rotation (lag or lead, deg)
            that destabilises it (the smallest ``|phi|``; ``inf`` without gain crossover).
            Unstable loop: minus the smallest rotation that stabilises it, -180 when none
            does; always <= 0.
        gain_crossover_hz: Frequency of the crossover that sets ``phase_margin_deg`` (Hz;
            ``nan`` when none).
        phase_crossover_hz: Frequency of the phase crossover that sets ``gain_margin_db``
            (Hz; ``nan`` when none).
        bandwidth_hz: Closed-loop -3 dB bandwidth: the lowest frequency where
            ``|L / (1 + L)|`` is ``1/sqrt(2)`` of its low-frequency value, root-found (Hz;
            ``nan`` when it never drops).
        stable: Closed-loop poles all strictly inside the unit circle (:class:`Stability`).
        spectral_radius: Largest closed-loop pole magnitude (``nan`` when stability was
            decided by counting encirclements).
        delay_margin_s: Stable loop: the smallest extra loop delay that destabilises it,
            ``(phi mod 360) / w`` (rad / (rad/s)) over the crossovers where ``|L|`` falls
            (``inf`` without one). Unstable loop: the most negative crossover delay margin,
            else 0.
        crossovers: Every gain crossover, ascending: ``(hz, signed phase margin deg,
            delay margin s)``, the delay margin being the signed margin (rad) over ``w``
            where ``|L|`` falls (``inf`` where it rises and the margin is positive: a delay
            never destabilises there).
        phase_crossovers: Every crossing of the negative real axis, ascending, the Nyquist
            frequency included: ``(hz, gain margin dB)``.
    """

    gain_margin_db: float
    phase_margin_deg: float
    gain_crossover_hz: float
    phase_crossover_hz: float
    bandwidth_hz: float
    stable: bool = True
    spectral_radius: float = math.nan
    delay_margin_s: float = math.inf
    crossovers: tuple[tuple[float, float, float], ...] = ()
    phase_crossovers: tuple[tuple[float, float], ...] = ()

    def to_dict(self) -> dict[str, Any]:
        """JSON-ready: ``inf`` and ``nan`` as ``None``, tuples as lists."""

        def clean(v: Any) -> Any:
            if isinstance(v, bool):
                return v
            if isinstance(v, tuple | list):
                return [clean(x) for x in v]
            v = float(v)
            return v if math.isfinite(v) else None

        return {f.name: clean(getattr(self, f.name)) for f in dataclasses.fields(self)}


@dataclasses.dataclass(frozen=True)
class LoopAnalysis:
    """The open loop of one set on one linear plant, and its margins.

    Attributes:
        freqs_hz: Display grid (Hz, ascending): :func:`frequency_grid` with every crossover
            and the bandwidth added.
        loop: ``L`` at ``freqs_hz`` (complex).
        margins: The loop's :class:`Margins`.
        stability: How stability was decided.
    """

    freqs_hz: np.ndarray
    loop: np.ndarray
    margins: Margins
    stability: Stability | None = None


def frequency_grid(dt: float, n: int = N_FREQUENCIES) -> np.ndarray:
    """Frequencies (Hz) from ``LOWEST_FREQUENCY_FRACTION / dt`` to just below Nyquist."""
    nyquist = 0.5 / dt
    return np.geomspace(LOWEST_FREQUENCY_FRACTION / dt, 0.999 * nyquist, n)


@functools.lru_cache(maxsize=64)
def _display_grid(dt: float) -> np.ndarray:
    """:func:`frequency_grid` of ``dt`` (read-only, kept)."""
    out = frequency_grid(dt)
    out.setflags(write=False)
    return out


# --- closed-loop stability ---------------------------------------------------------------


def plant_polynomials(lin: LinearPlant) -> tuple[np.ndarray, np.ndarray]:
    """``P(z) = num(z^-1) / den(z^-1)`` of a linear plant, ascending powers of ``z^-1``.

    ``den = det(I - z^-1 Phi)`` (degree ``n``, ``den[0] = 1``); ``num`` (degree ``n + 1``,
    ``num[0] = 0``) from the rank-one identity ``det(zI - Phi + s b c) = det(zI - Phi)
    (1 + s c (zI - Phi)^-1 b)`` with ``s`` scaling ``b c`` to the size of ``Phi``, so the
    difference of the two characteristic polynomials carries no cancellation. Every state
    counts, an unobservable or uncontrollable one too (its pole stays a pole of the loop).
    Computed once per plant and kept on it (read-only arrays).
    """
    memo = lin._memo if isinstance(lin, LinearPlant) else {}
    if "polynomials" not in memo:
        num, den = _plant_polynomials(lin)
        num.setflags(write=False)
        den.setflags(write=False)
        memo["polynomials"] = (num, den)
    return memo["polynomials"]


def _plant_polynomials(lin: LinearPlant) -> tuple[np.ndarray, np.ndarray]:
    """:func:`plant_polynomials`, computed."""
    phi = np.asarray(lin.phi, dtype=float)
    n = phi.shape[0]
    den = np.real(np.poly(phi))
    scale = max(1.0, float(np.max(np.abs(phi))))

    def numerator(b: np.ndarray) -> np.ndarray:
        size = float(np.linalg.norm(b) * np.linalg.norm(lin.c))
        if size == 0.0:
            return np.zeros(n + 1)
        s = scale / size
        return (np.real(np.poly(phi - s * np.outer(b, lin.c))) - den) / s

    num = np.zeros(n + 2)
    num[: n + 1] += numerator(np.asarray(lin.g_new, dtype=float))
    num[1:] += numerator(np.asarray(lin.g_old, dtype=float))
    num[0] = 0.0  # strictly proper: exactly zero
    return num, den


def characteristic_polynomial(
    filter_polys: tuple[np.ndarray, np.ndarray], lin: LinearPlant
) -> np.ndarray:
    """``den_C den_P + num_C num_P`` in ascending powers of ``x = z^-1`` (``[0] = 1``): the
    closed-loop poles are ``1 / x`` at its roots (with ``u = C E``, ``E = -y``)."""
    num_c, den_c = filter_polys
    num_p, den_p = plant_polynomials(lin)
    a = np.convolve(den_c, den_p)
    b = np.convolve(num_c, num_p)
    out = np.zeros(max(a.size, b.size))
    out[: a.size] += a
    out[: b.size] += b
    return out


def closed_loop_matrix(filter_polys: tuple[np.ndarray, np.ndarray], lin: LinearPlant) -> np.ndarray:
    """State matrix of the closed loop: state ``(x, u[k-1], w)``, ``w`` the filter's states
    in transposed direct form II (``u = w_1 + num_0 E``, ``E = -c x``)."""
    num, den = (np.asarray(v, dtype=float) for v in filter_polys)
    num, den = num / den[0], den / den[0]
    m = max(num.size, den.size) - 1
    nn = np.zeros(m + 1)
    dd = np.zeros(m + 1)
    nn[: num.size], dd[: den.size] = num, den
    n0 = nn[0]
    phi, c = np.asarray(lin.phi, dtype=float), np.asarray(lin.c, dtype=float)
    g_new, g_old = np.asarray(lin.g_new, dtype=float), np.asarray(lin.g_old, dtype=float)
    n = phi.shape[0]
    out = np.zeros((n + 1 + m, n + 1 + m))
    out[:n, :n] = phi - n0 * np.outer(g_new, c)
    out[:n, n] = g_old
    out[n, :n] = -n0 * c
    if m:
        w = n + 1
        out[:n, w] = g_new
        out[n, w] = 1.0
        out[w:, :n] = -np.outer(nn[1:] - dd[1:] * n0, c)
        out[w:, w] = -dd[1:]
        out[w : w + m - 1, w + 1 :] += np.eye(m - 1)
    return out


def count_roots_inside(coef: np.ndarray, radius: float) -> int | None:
    """Roots of the polynomial ``sum coef[k] x^k`` with ``|x| < radius``, by the argument
    principle: its winding number round the circle ``|x| = radius``.

    The polynomial is taken on the circle by an FFT (at least 8 points per degree), and
    every step whose phase change exceeds 45 degrees is split (16 points each, directly
    evaluated) until none does, so no turn is missed. ``None`` when the polynomial comes
    within rounding of zero on the circle (a root on it: neither inside nor outside).
    """
    coef = np.trim_zeros(np.asarray(coef, dtype=float), "b")
    n = coef.size - 1
    if n <= 0:
        return 0
    scaled = coef * radius ** np.arange(n + 1)
    noise = 1e-12 * float(np.sum(np.abs(scaled)))
    size = max(4096, 1 << math.ceil(math.log2(8 * (n + 1))))
    vals = np.fft.ifft(scaled, size) * size
    return winding_number(
        size, vals,
        lambda t: np.polynomial.polynomial.polyval(np.exp(1j * t), scaled),
        lambda v: bool(np.min(np.abs(v)) <= noise),
    )  # fmt: skip


def winding_number(size: int, vals: np.ndarray, at: Any, vanishes: Any) -> int | None:
    """Turns of a function round zero on the unit circle's angles ``2 pi k / size``.

    Args:
        size: Points of the first grid.
        vals: The function on them (``size`` values).
        at: ``theta`` array -> the function's values there (for the refinement).
        vanishes: values -> whether the function is (within rounding) zero there.

    Every step whose phase change exceeds 45 degrees is split (16 points each) until none
    does, so no turn is missed. ``None``: it vanishes on the circle, or 40 refinements do not
    settle.
    """
    theta = 2 * np.pi * np.arange(size + 1) / size
    vals = np.append(vals, vals[0])
    for _ in range(40):
        if vanishes(vals):
            return None
        steps = np.angle(vals[1:] / vals[:-1])
        bad = np.flatnonzero(np.abs(steps) > np.pi / 4)
        if not bad.size:
            return round(float(np.sum(steps)) / (2 * np.pi))
        frac = np.arange(1, 16) / 16
        new_t = (theta[bad, None] + (theta[bad + 1] - theta[bad])[:, None] * frac).ravel()
        theta = np.concatenate([theta, new_t])
        vals = np.concatenate([vals, at(new_t)])
        order = np.argsort(theta, kind="stable")
        theta, vals = theta[order], vals[order]
    return None


def closed_loop_stability(
    filter_polys: tuple[np.ndarray, np.ndarray], lin: LinearPlant
) -> Stability:
    """Stability of the closed loop of a filter ``(num, den)`` (``ChipFamily.filter_polynomials``)
    on a linear plant: by the eigenvalues of :func:`closed_loop_matrix` up to
    :data:`EIGEN_MAX_ORDER`, else by :func:`count_roots_inside` on
    :func:`characteristic_polynomial` (a pole ``z`` with ``|z| >= 1 - eps`` is a root ``x =
    1/z`` with ``|x| <= 1 / (1 - eps)``). See :data:`STABILITY_EPS`."""
    num, den = filter_polys
    order = lin.phi.shape[0] + 1 + max(len(num), len(den)) - 1
    limit = 1.0 - STABILITY_EPS
    if order <= EIGEN_MAX_ORDER:
        matrix = closed_loop_matrix(filter_polys, lin)
        poles = scipy.linalg.eigvals(matrix, overwrite_a=True, check_finite=False)
        radius = float(np.max(np.abs(poles)))
        n_unstable = int(np.sum(np.abs(poles) >= limit))
        return Stability(n_unstable == 0, n_unstable, radius, order, "eigenvalues")
    chi = characteristic_polynomial(filter_polys, lin)
    inside = count_roots_inside(chi, 1.0 / limit)
    if inside is None:  # a root on the circle: marginal, not stable
        return Stability(False, 1, math.nan, order, "encirclement")
    return Stability(inside == 0, inside, math.nan, order, "encirclement")


# --- crossovers --------------------------------------------------------------------------


def _wrap(angle: np.ndarray | float) -> Any:
    """An angle (rad) wrapped into (-pi, pi]."""
    return np.pi - np.mod(np.pi - np.asarray(angle, dtype=float), 2 * np.pi)


@functools.lru_cache(maxsize=8)
def _base_grid(theta_lo: float) -> np.ndarray:
    """The crossover search's base grid (sorted, distinct, read-only): :data:`GRID_LOG_POINTS`
    logarithmic and 2048 linear points from ``theta_lo`` to ``pi``."""
    base = np.concatenate(
        [np.geomspace(theta_lo, np.pi, GRID_LOG_POINTS), np.linspace(theta_lo, np.pi, 2048)]
    )
    out = np.unique(base)
    out.setflags(write=False)
    return out


def _log_abs(v: np.ndarray) -> np.ndarray:
    """``ln |v|`` (``-inf`` at 0, no warning)."""
    with np.errstate(divide="ignore"):
        return np.log(np.abs(v))


def _bad_intervals(
    t0: np.ndarray, t1: np.ndarray, v0: np.ndarray, v1: np.ndarray, m0: np.ndarray, m1: np.ndarray
) -> np.ndarray:
    """Which intervals ``[t0, t1]`` :func:`_refined_grid` splits (``L`` there ``v0``, ``v1``;
    ``ln |L|`` there ``m0``, ``m1``)."""
    with np.errstate(invalid="ignore", divide="ignore"):
        dmag = np.abs(m1 - m0)
        dphase = np.abs(np.angle(v1 / v0))
    wide = (t1 - t0) > 1e-10 * t1
    return ((dmag > REFINE_LOG_MAGNITUDE) | (dphase > REFINE_PHASE_RAD) | ~np.isfinite(dmag)) & wide


def _refined_grid(
    loop_fn: Any, theta: np.ndarray, vals: np.ndarray | None = None
) -> tuple[np.ndarray, np.ndarray]:
    """``(theta, L)``: ``theta`` with every interval split until ``ln |L|`` and the phase
    change by less than :data:`REFINE_LOG_MAGNITUDE` and :data:`REFINE_PHASE_RAD` across it
    (or the interval is below 1e-10 of its frequency, or :data:`MAX_GRID_POINTS` is met).
    ``vals``: ``loop_fn(theta)`` when already known (``theta`` then sorted and distinct)."""
    return _refine(loop_fn, theta, vals)[:2]


def _refine(
    loop_fn: Any, theta: np.ndarray, vals: np.ndarray | None = None
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """:func:`_refined_grid` and ``ln |L|`` on the grid.

    Each pass splits every interval found too wide into four and then examines only the new
    intervals (an interval once accepted stays so: its end values do not change), so the
    grid is the one that re-examining the whole grid every pass gives, in a fraction of the
    work."""
    if vals is None:
        theta = np.unique(theta)
        vals = loop_fn(theta)
    logs = _log_abs(vals)
    pieces = [(theta, vals, logs)]
    size = theta.size
    t0, t1, v0, v1, m0, m1 = theta[:-1], theta[1:], vals[:-1], vals[1:], logs[:-1], logs[1:]
    frac = np.array([0.25, 0.5, 0.75])
    for _ in range(60):
        bad = np.flatnonzero(_bad_intervals(t0, t1, v0, v1, m0, m1))
        if not bad.size or size + 3 * bad.size > MAX_GRID_POINTS:
            break
        a, b = t0[bad], t1[bad]
        new_t = (a[:, None] + (b - a)[:, None] * frac).ravel()
        new_v = loop_fn(new_t)
        new_m = _log_abs(new_v)
        pieces.append((new_t, new_v, new_m))
        size += new_t.size
        # the four new intervals of each split one: ends (a, t1, t2, t3, b)
        ts = np.column_stack([a, new_t.reshape(-1, 3), b])
        vs = np.column_stack([v0[bad], new_v.reshape(-1, 3), v1[bad]])
        ms = np.column_stack([m0[bad], new_m.reshape(-1, 3), m1[bad]])
        t0, t1 = ts[:, :-1].ravel(), ts[:, 1:].ravel()
        v0, v1 = vs[:, :-1].ravel(), vs[:, 1:].ravel()
        m0, m1 = ms[:, :-1].ravel(), ms[:, 1:].ravel()
    if len(pieces) == 1:
        return theta, vals, logs
    theta, vals, logs = (np.concatenate(p) for p in zip(*pieces, strict=True))
    order = np.argsort(theta, kind="stable")
    return theta[order], vals[order], logs[order]


ROOT_XTOL = 1e-14
"""Crossovers and the bandwidth are located by Brent's method to ``ROOT_XTOL`` of the upper
end of their bracket plus ``ROOT_RTOL`` of their frequency."""

ROOT_RTOL = 4 * np.finfo(float).eps
"""Relative tolerance of the root-finder (``scipy.optimize.brentq``'s smallest)."""

ROOT_MAXITER = 100
"""Steps of Brent's method before it gives up (``scipy.optimize.brentq``'s default)."""


class _Brent:
    """One root of Brent's method, advanced one function value at a time.

    The steps are those of ``scipy.optimize.brentq`` (Brent 1973, ch. 4: inverse quadratic
    or linear interpolation, bisection when the step is not short enough), value for value,
    so that many roots can be found in lockstep, with one vectorized evaluation of the
    function per step for all of them, and each lands on the float ``brentq`` returns.

    Args:
        xa, xb: The bracket's ends.
        fa, fb: The function there (opposite signs, or one of them 0).
        xtol, rtol: Converged when half the bracket is below ``(xtol + rtol |x|) / 2``.

    Attributes:
        x: The point whose value :meth:`tell` expects next (``root`` is ``None``).
        root: The root once converged, else ``None``.
    """

    __slots__ = ("fblk", "fcur", "fpre", "iterations", "root", "rtol", "scur", "spre",
                 "x", "xblk", "xpre", "xtol")  # fmt: skip

    def __init__(self, xa: float, xb: float, fa: float, fb: float, xtol: float, rtol: float):
        self.xpre, self.x, self.fpre, self.fcur = xa, xb, fa, fb
        self.xblk = self.fblk = self.spre = self.scur = 0.0
        self.xtol, self.rtol = xtol, rtol
        self.iterations = 0
        self.root: float | None = None
        if fa * fb > 0:
            raise ValueError(f"f(a) and f(b) must have different signs; got {fa=}, {fb=}")
        if fa == 0:
            self.root = xa
        elif fb == 0:
            self.root = xb
        else:
            self._step()

    def tell(self, f: float) -> None:
        """The function's value at :attr:`x`; then the next point, or the root."""
        self.fcur = f
        self._step()

    def _step(self) -> None:
        if self.iterations == ROOT_MAXITER:
            raise RuntimeError(f"Brent's method did not converge in {ROOT_MAXITER} steps")
        self.iterations += 1
        xpre, xcur, fpre, fcur = self.xpre, self.x, self.fpre, self.fcur
        xblk, fblk, spre, scur = self.xblk, self.fblk, self.spre, self.scur
        if fpre * fcur < 0:  # the bracket is [xpre, xcur]
            xblk, fblk = xpre, fpre
            spre = scur = xcur - xpre
        if abs(fblk) < abs(fcur):  # xcur the end with the smaller value
            xpre, xcur, xblk = xcur, xblk, xcur
            fpre, fcur, fblk = fcur, fblk, fcur
        delta = (self.xtol + self.rtol * abs(xcur)) / 2
        sbis = (xblk - xcur) / 2
        if fcur == 0 or abs(sbis) < delta:
            self.root = xcur
            return
        if abs(spre) > delta and abs(fcur) < abs(fpre):
            if xpre == xblk:  # secant
                stry = -fcur * (xcur - xpre) / (fcur - fpre)
            else:  # inverse quadratic interpolation
                dpre = (fpre - fcur) / (xpre - xcur)
                dblk = (fblk - fcur) / (xblk - xcur)
                stry = -fcur * (fblk * dblk - fpre * dpre) / (dblk * dpre * (fblk - fpre))
            bound = 3 * abs(sbis) - delta
            if 2 * abs(stry) < (abs(spre) if abs(spre) < bound else bound):
                spre, scur = scur, stry
            else:
                spre = scur = sbis
        else:
            spre = scur = sbis
        xpre, fpre = xcur, fcur
        if abs(scur) > delta:
            xcur += scur
        else:
            xcur += delta if sbis > 0 else -delta
        self.xpre, self.x, self.fpre = xpre, xcur, fpre
        self.xblk, self.fblk, self.spre, self.scur = xblk, fblk, spre, scur


def _solve_all(solvers: list[_Brent], values: Any) -> None:
    """Run every solver to its root: ``values(points, pending)`` gives the function of each
    pending solver at its point (one vectorized evaluation per step for all)."""
    pending = [s for s in solvers if s.root is None]
    while pending:
        fs = values(np.array([s.x for s in pending]), pending)
        for s, f in zip(pending, fs, strict=True):
            s.tell(f)
        pending = [s for s in pending if s.root is None]


def _sign_changes(values: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """``(k, on)``: intervals ``[k, k + 1]`` whose ends have opposite signs, and grid points
    ``on`` that are exactly zero between two values of opposite signs."""
    sign = np.sign(values)
    k = np.flatnonzero(sign[:-1] * sign[1:] < 0)
    on = np.flatnonzero(values[1:-1] == 0) + 1
    on = on[sign[on - 1] * sign[on + 1] < 0]
    return k, on


def frequency_margins(
    loop_fn: Any, dt: float, stability: Stability, theta_lo: float | None = None
) -> Margins:
    """Margins of an open loop given as a function.

    Args:
        loop_fn: ``theta -> L(exp(j theta))`` for a float array ``theta`` in (0, pi]
            (``theta = w T``), elementwise (each value depends on its own ``theta`` only).
        dt: Sample period ``T`` (s).
        stability: The closed loop's stability (:func:`closed_loop_stability`).
        theta_lo: Lowest ``theta`` searched (default ``2 pi`` :data:`ANALYSIS_LOWEST_FRACTION`).
    """
    lo = 2 * np.pi * ANALYSIS_LOWEST_FRACTION if theta_lo is None else float(theta_lo)
    base = _base_grid(lo)
    return _grid_margins(loop_fn, dt, stability, base, loop_fn(base))


def _grid_margins(
    loop_fn: Any, dt: float, stability: Stability, base: np.ndarray, base_vals: np.ndarray
) -> Margins:
    """:func:`frequency_margins` from the base grid and ``L`` on it.

    The grid is refined (:func:`_refined_grid`); every sign change of ``ln |L|`` (a gain
    crossover), of ``Im L / |L|`` below Nyquist (a crossing of the real axis) and the first
    drop of ``|L / (1 + L)|`` below ``1/sqrt(2)`` of its low-frequency value (the bandwidth)
    is bracketed by two grid points, and all are located together by Brent's method
    (:class:`_Brent`, one evaluation of ``loop_fn`` per step for all of them)."""
    theta, vals, logmag = _refine(loop_fn, base, base_vals)
    to_hz = 1.0 / (2 * np.pi * dt)
    with np.errstate(divide="ignore", invalid="ignore"):
        unit = vals / np.abs(vals)
        closed = np.abs(vals / (1 + vals))
    inner = theta < np.pi
    n_inner = int(np.count_nonzero(inner))
    sin_inner = unit.imag[:n_inner]  # theta is ascending: the points below pi come first
    level = closed[0] / math.sqrt(2)
    below = np.flatnonzero(closed < level)

    # Every root, located by Brent's method with the function brentq was given (Python
    # floats of L(theta), one theta at a time) and all of them in lockstep.
    def log_mag(v: complex) -> float:
        m = abs(v)
        return math.log(m) if m > 0 else -math.inf

    def sin_phase(v: complex) -> float:
        # L = 0 exactly (a zero of L on the unit circle, such as a notch's or a long PMD
        # derivative's, found by the root-finder): a root where Re L < 0 fails, no crossing.
        m = abs(v)
        return v.imag / m if m > 0 else 0.0

    def closed_drop(v: complex) -> float:
        return abs(v / (1 + v)) - level if v != -1 else math.inf

    eps4 = ROOT_RTOL
    # (kind, upper grid index of the bracket, solver); kind 0 gain, 1 phase, 2 bandwidth
    jobs: list[tuple[int, int, _Brent]] = []
    k_mag, on_mag = _sign_changes(logmag)
    for k in k_mag:
        a, b = float(theta[k]), float(theta[k + 1])
        fa, fb = log_mag(complex(vals[k])), log_mag(complex(vals[k + 1]))
        if fa * fb <= 0:
            jobs.append((0, k + 1, _Brent(a, b, fa, fb, ROOT_XTOL * b, eps4)))
    k_ph, on_ph = _sign_changes(sin_inner)
    for k in k_ph:
        a, b = float(theta[k]), float(theta[k + 1])
        fa, fb = sin_phase(complex(vals[k])), sin_phase(complex(vals[k + 1]))
        if fa * fb <= 0:
            jobs.append((1, k + 1, _Brent(a, b, fa, fb, ROOT_XTOL * b, eps4)))
    if below.size and below[0] > 0:
        k = int(below[0])
        fa = closed_drop(complex(vals[k - 1]))
        fb = closed_drop(complex(vals[k]))
        if fa * fb <= 0:
            solver = _Brent(theta[k - 1], theta[k], fa, fb, ROOT_XTOL * theta[k], eps4)
            jobs.append((2, k, solver))
    functions = {0: log_mag, 1: sin_phase, 2: closed_drop}
    kind_of = {id(solver): kind for kind, _, solver in jobs}

    def values(points: np.ndarray, pending: list[_Brent]) -> list[float]:
        at = loop_fn(points)
        return [functions[kind_of[id(s)]](complex(v)) for s, v in zip(pending, at, strict=True)]

    _solve_all([solver for _, _, solver in jobs], values)
    roots = np.array([float(solver.root) for _, _, solver in jobs])
    at_roots = loop_fn(roots) if roots.size else np.zeros(0, dtype=complex)

    def located(kind: int, values: np.ndarray, on: np.ndarray) -> list[tuple[float, complex, int]]:
        """``(theta, L, direction)`` of each root of one kind, ascending; direction +1 where
        ``values`` (the function on the grid) rises."""
        out = []
        for i, (kind_i, k, _) in enumerate(jobs):
            if kind_i == kind:  # the bracket [k - 1, k]
                rise = 1 if values[k] > values[k - 1] else -1
                out.append((float(roots[i]), complex(at_roots[i]), rise))
        for k in on:  # exactly on a grid point
            rise = 1 if values[k + 1] > values[k - 1] else -1
            out.append((float(theta[k]), complex(vals[k]), rise))
        return sorted(out, key=lambda r: r[0])

    # gain crossovers: ln |L| = 0
    crossovers = []
    phis = []
    for t, v, direction in located(0, logmag, on_mag):
        phi = float(_wrap(np.angle(v) + np.pi))
        signed = -direction * phi  # falling |L| (direction -1): the classical 180 + phase
        pm = math.degrees(abs(phi)) * (1.0 if signed >= 0 else -1.0)
        if direction < 0:
            delay = math.radians(pm) / t * dt
        else:
            delay = math.inf if pm >= 0 else math.radians(pm) / t * dt
        crossovers.append((t * to_hz, pm, delay))
        phis.append((t, phi, direction))
    # phase crossovers: Im L = 0 with Re L < 0 (the Nyquist point apart)
    phase_x = [
        (t, abs(v), 2 * direction) for t, v, direction in located(1, sin_inner, on_ph) if v.real < 0
    ]
    if theta[-1] == np.pi:
        v_pi = complex(vals[-1])
    else:
        v_pi = complex(loop_fn(np.array([np.pi]))[0])
    if v_pi.real < 0 and abs(v_pi.imag) <= 1e-9 * abs(v_pi):
        before = sin_inner[-1] if n_inner else 0.0
        phase_x.append((np.pi, abs(v_pi), 1 if before < 0 else -1))
    phase_crossovers = tuple((t * to_hz, -20 * math.log10(r)) for t, r, _ in phase_x)

    if stability.stable:
        gm, f_gm = math.inf, math.nan
        for hz, g in phase_crossovers:
            if abs(g) < gm:
                gm, f_gm = abs(g), hz
        pm, f_pm = math.inf, math.nan
        for (hz, _, _), (_, phi, _) in zip(crossovers, phis, strict=True):
            if math.degrees(abs(phi)) < pm:
                pm, f_pm = math.degrees(abs(phi)), hz
        delays = [float(np.mod(phi, 2 * np.pi)) / t * dt for t, phi, d in phis if d < 0]
        delay = min(delays, default=math.inf)
    else:
        z0 = stability.n_unstable
        # gain factor k: passing k = 1/r upward changes the unstable count by dz
        events = [(1.0 / r, dz, t) for t, r, dz in phase_x]
        best = (math.inf, math.nan)
        for up in (True, False):
            z = z0
            side = sorted((e for e in events if (e[0] > 1) == up), key=lambda e: e[0],
                          reverse=not up)  # fmt: skip
            for k, dz, t in side:
                z += dz if up else -dz
                if z == 0:
                    db = abs(20 * math.log10(k))
                    if db < best[0]:
                        best = (db, t * to_hz)
                    break
        gm, f_gm = (-best[0], best[1]) if math.isfinite(best[0]) else (0.0, math.nan)
        best = (180.0, math.nan)
        for lag in (True, False):
            z = z0
            side = sorted(((abs(phi), d, t) for t, phi, d in phis if (phi > 0) == lag))
            for angle, d, t in side:
                z += -2 * d if lag else 2 * d
                if z == 0:
                    if math.degrees(angle) < best[0]:
                        best = (math.degrees(angle), t * to_hz)
                    break
        pm, f_pm = -best[0], best[1]
        delay = min([c[2] for c in crossovers if c[2] < 0], default=0.0)

    bandwidth = next((s.root for kind, _, s in jobs if kind == 2), math.nan) * to_hz
    return Margins(
        gain_margin_db=float(gm),
        phase_margin_deg=float(pm),
        gain_crossover_hz=float(f_pm),
        phase_crossover_hz=float(f_gm),
        bandwidth_hz=float(bandwidth),
        stable=bool(stability.stable),
        spectral_radius=float(stability.spectral_radius),
        delay_margin_s=float(delay),
        crossovers=tuple(crossovers),
        phase_crossovers=phase_crossovers,
    )


_FILTER_CACHE_SIZE = 16
"""Parameter sets whose filter response on the base grid :func:`analyse_loop` keeps."""


@functools.lru_cache(maxsize=_FILTER_CACHE_SIZE)
def _filter_on_base(chip: Any, params: Any, assumptions: Any, theta_lo: float) -> np.ndarray:
    """``C`` on the base grid (read-only), as ``search_fn`` of :func:`analyse_loop` takes it.

    Cached: an evaluation analyses one set at every loop-latency choice and holding point,
    and ``C`` does not depend on the loop latency (``ChipFamily.filter_response``), so
    ``assumptions`` comes here with ``loop_latency`` at one fixed choice."""
    x = np.exp(-1j * _base_grid(theta_lo))
    out = chip.filter_response(params, assumptions, 1 / x)
    out.setflags(write=False)
    return out


def _latency_free(chip: Any, assumptions: Any) -> Any:
    """``assumptions`` (``None``: the defaults) with ``loop_latency`` at its first choice:
    the same filter response (:func:`_filter_on_base`)."""
    asm = assumptions if assumptions is not None else chip.default_assumptions()
    choices = getattr(type(asm), "CHOICES", {}).get("loop_latency")
    if choices and getattr(asm, "loop_latency", None) != choices[0]:
        asm = dataclasses.replace(asm, loop_latency=choices[0])
    return asm


def _search_margins(
    chip: Any, params: Any, assumptions: Any, lin: LinearPlant
) -> tuple[Margins, Stability, Any]:
    """The margins of :func:`analyse_loop` (stability and the crossover search, without the
    display grid's response), the stability and the filter's response ``z -> C(z)``."""
    polys = chip.filter_polynomials(params, assumptions)
    stability = closed_loop_stability(polys, lin)
    response = getattr(chip, "response_function", None)
    if response is not None:  # the family's own function: ChipFamily.filter_response's values
        asm = chip._assumptions(assumptions)

        def filter_at(z: np.ndarray) -> np.ndarray:
            with np.errstate(divide="ignore", invalid="ignore"):
                out = np.asarray(response(params, asm, z), dtype=complex)
            return out if out.shape == z.shape else np.broadcast_to(out, z.shape).copy()

    else:

        def filter_at(z: np.ndarray) -> np.ndarray:
            return chip.filter_response(params, assumptions, z)

    def search_fn(theta: np.ndarray) -> np.ndarray:
        # The plant as its polynomials (cheap; accurate to 1e-8 relative down to the
        # search's lowest frequency, where (1 - z^-1)^2 is 4e-11).
        x = np.exp(-1j * np.asarray(theta, dtype=float))
        return filter_at(1 / x) * lin._polynomial_response(x)

    lo = 2 * np.pi * ANALYSIS_LOWEST_FRACTION
    base = _base_grid(lo)
    try:
        c_base = _filter_on_base(chip, params, _latency_free(chip, assumptions), lo)
    except TypeError:  # an unhashable parameter set: not cached
        c_base = chip.filter_response(params, assumptions, 1 / np.exp(-1j * base))
    m = _grid_margins(search_fn, lin.dt, stability, base, c_base * lin._search_response(lo))
    return m, stability, filter_at


def margins_only(chip: Any, params: Any, assumptions: Any, lin: LinearPlant) -> Margins:
    """The :class:`Margins` of :func:`analyse_loop`, identical, without the loop's response on
    the display grid (cheaper: a tuner's prediction of a set's margins)."""
    return _search_margins(chip, params, assumptions, lin)[0]


def analyse_loop(chip: Any, params: Any, assumptions: Any, lin: LinearPlant) -> LoopAnalysis:
    """Stability, every crossover and the margins of ``params`` closing the loop on ``lin``.

    What does not depend on the gains is computed once per linear plant and kept on it
    (its polynomials, its response on the search's base grid and on the display grid), and
    the filter's response on the base grid once per set (:func:`_filter_on_base`).

    Args:
        chip: The chip family (``ChipFamily``).
        params: The parameter set.
        assumptions: The chip's assumption switches (``None``: defaults).
        lin: The plant at the set's sample period (``chip.sample_time_s(params)``) and loop
            latency (:func:`linearize`).
    """
    m, stability, filter_at = _search_margins(chip, params, assumptions, lin)
    dt = lin.dt
    extra = [hz for hz, _, _ in m.crossovers] + [hz for hz, _ in m.phase_crossovers]
    if math.isfinite(m.bandwidth_hz):
        extra.append(m.bandwidth_hz)
    # the display grid with every crossover and the bandwidth inserted in order (the plant's
    # response on the grid is kept on it)
    grid = _display_grid(dt)
    extra = np.unique(np.asarray(extra, dtype=float))
    extra = extra[(extra > 0) & (extra < 0.5 / dt)]
    pos = np.searchsorted(grid, extra)
    fresh = (pos == grid.size) | (grid[np.minimum(pos, grid.size - 1)] != extra)
    extra, pos = extra[fresh], pos[fresh]
    freqs = np.insert(grid, pos, extra)
    plant = lin._display_response()
    if extra.size:
        plant = np.insert(plant, pos, lin.response(np.exp(1j * (2 * np.pi * extra * dt))))
    loop = filter_at(np.exp(1j * (2 * np.pi * freqs * dt))) * plant
    return LoopAnalysis(freqs, loop, m, stability)


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
    for hz, pm, _ in m.crossovers:  # every gain crossover, its signed phase margin
        ax_m.axvline(hz, color="C2", ls="--", lw=1)
        ax_p.axvline(hz, color="C2", ls="--", lw=1)
        at = float(np.interp(hz, freqs_hz, phase))
        ax_p.annotate(f"PM {pm:.1f} deg at {hz:.0f} Hz", (hz, at), color="C2",
                      xytext=(5, 5), textcoords="offset points")  # fmt: skip
    for hz, gm in m.phase_crossovers:  # every crossing of the negative real axis
        ax_m.axvline(hz, color="C3", ls="--", lw=1)
        ax_m.annotate(f"GM {gm:.1f} dB at {hz:.0f} Hz", (hz, -gm), color="C3",
                      xytext=(5, -12), textcoords="offset points")  # fmt: skip
    if math.isfinite(m.bandwidth_hz):
        ax_m.axvline(m.bandwidth_hz, color="C1", ls=":", lw=1)
    note = ""
    if limits is not None:
        note = f" (minima {limits[0]:g} dB, {limits[1]:g} deg)"
    fig.suptitle(title + note)
    verdict = "stable" if m.stable else "unstable"
    if not m.stable and math.isfinite(m.spectral_radius):
        verdict += f" (spectral radius {m.spectral_radius:.3g})"
    ax_m.set_title(
        f"{verdict}: gain margin {_fmt(m.gain_margin_db, 'dB')}, phase margin "
        f"{_fmt(m.phase_margin_deg, 'deg')}, delay margin {_fmt(m.delay_margin_s * 1e3, 'ms')}, "
        f"closed-loop bandwidth {_fmt(m.bandwidth_hz, 'Hz')}",
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
