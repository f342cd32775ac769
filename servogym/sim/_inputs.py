"""The motor current within one servo tick, exactly, and its moments over a (sub)step.

Between two encoder samples the amplifier's current reference is piecewise constant: the
previous command's current ``r_old`` until the loop latency ``L`` has passed, then the new
command's ``r_new`` (docs/simulation.md, "Loop latency"). The current loop is a first-order lag
with time constant ``tau`` (``tau = 0``: ideal, the current equals its reference at once), so
the current is piecewise exponential and known in closed form:

    i(t) = r_old + (i0 - r_old) exp(-t / tau)              for 0 <= t < L
    i(t) = r_new + (i(L) - r_new) exp(-(t - L) / tau)      for L <= t <= T

The integrator does not sample this function at its stage times (a step in the middle of a
substep would then count as falling on a stage). It takes, per substep of length ``h``, the
quadratic ``p(s)`` (``0 <= s <= h``) with the same moments ``int s^j i ds``, ``j = 0, 1, 2``:
for a pure inertia the velocity and the position after the substep depend on ``i`` only
through its moments 0 and 1, and RK4 integrates a quadratic input on a chain of integrators
exactly, so the hold, the latency split and the lag are exact there; everywhere else the
input's error is of higher order than the integrator's own.

Every function here is compiled with numba and is also plain Python (``.py_func``): the
Python twin of the loop (``_pyloop.py``) calls the same arithmetic.
"""

from __future__ import annotations

import math

from numba import njit

_SERIES_X = 0.5
"""Below this ``w / tau`` the exponential moments are summed as a series (no cancellation)."""

_SERIES_TERMS = 18
"""Terms of that series: ``0.5**18 / 18!`` is far below a double's resolution."""


@njit(cache=True, nogil=True)
def exp_moment(m, w, tau):
    """``E_m = int_0^w u^m exp(-u / tau) du`` for ``m`` in 0, 1, 2 (``tau > 0``, ``w >= 0``)."""
    x = w / tau
    if x < _SERIES_X:
        # E_m = w^(m+1) * sum_n (-x)^n / (n! (n + m + 1))
        total = 0.0
        term = 1.0
        for n in range(_SERIES_TERMS):
            total += term / (n + m + 1)
            term *= -x / (n + 1)
        return w ** (m + 1) * total
    e = math.exp(-x)
    e0 = -tau * math.expm1(-x)
    if m == 0:
        return e0
    e1 = tau * (e0 - w * e)
    if m == 1:
        return e1
    return tau * (2.0 * e1 - w * w * e)


@njit(cache=True, nogil=True)
def piece_moments(out, s0, s1, level, start_excess, tau):
    """Add ``int_{s0}^{s1} s^j i(s) ds`` (``j = 0, 1, 2``) to ``out[0:3]``.

    On ``s0 <= s <= s1`` the current is ``level + start_excess * exp(-(s - s0) / tau)``
    (``tau = 0``: just ``level``).
    """
    w = s1 - s0
    if w <= 0.0:
        return
    out[0] += level * w
    out[1] += level * (s1 * s1 - s0 * s0) / 2.0
    out[2] += level * (s1 * s1 * s1 - s0 * s0 * s0) / 3.0
    if tau > 0.0 and start_excess != 0.0:
        e0 = exp_moment(0, w, tau)
        e1 = exp_moment(1, w, tau)
        e2 = exp_moment(2, w, tau)
        out[0] += start_excess * e0
        out[1] += start_excess * (s0 * e0 + e1)
        out[2] += start_excess * (s0 * s0 * e0 + 2.0 * s0 * e1 + e2)


@njit(cache=True, nogil=True)
def current_at(t, i0, r_old, r_new, latency, tau):
    """The exact current ``i(t)`` at ``0 <= t`` within the tick (formula in the module doc)."""
    if t < latency:
        if tau > 0.0:
            return r_old + (i0 - r_old) * math.exp(-t / tau)
        return r_old
    i_l = current_at_latency(i0, r_old, latency, tau)
    if tau > 0.0:
        return r_new + (i_l - r_new) * math.exp(-(t - latency) / tau)
    return r_new


@njit(cache=True, nogil=True)
def current_at_latency(i0, r_old, latency, tau):
    """The current when the new reference takes over, ``i(L)``."""
    if latency <= 0.0:
        return i0
    if tau > 0.0:
        return r_old + (i0 - r_old) * math.exp(-latency / tau)
    return r_old


@njit(cache=True, nogil=True)
def substep_input(out, a, h, i0, r_old, r_new, latency, tau):
    """The input of the substep ``[a, a + h]`` of a tick, as RK4 takes it.

    Writes ``out[0:3]`` = the moment-matched quadratic at the substep's start, middle and end
    (A), and ``out[3]`` = the mean current over the substep (A). ``out`` needs 6 entries; 3..5
    are scratch.

    Returns:
        True if the current is constant over the substep (then ``out[0:4]`` all hold it).
    """
    b = a + h
    ideal = tau <= 0.0
    if ideal and (b <= latency or a >= latency):
        level = r_old if b <= latency else r_new
        out[0] = level
        out[1] = level
        out[2] = level
        out[3] = level
        return True
    out[3] = 0.0
    out[4] = 0.0
    out[5] = 0.0
    m = out[3:6]
    # piece before the latency: reference r_old, starting from i0 at t = 0
    if a < latency:
        end = min(b, latency)
        excess = (i0 - r_old) * math.exp(-a / tau) if not ideal else 0.0
        piece_moments(m, 0.0, end - a, r_old, excess, tau)
    # piece after it: reference r_new, starting from i(L) at t = L
    if b > latency:
        start = max(a, latency)
        excess = 0.0
        if not ideal:
            i_l = current_at_latency(i0, r_old, latency, tau)
            excess = (i_l - r_new) * math.exp(-(start - latency) / tau)
        piece_moments(m, start - a, h, r_new, excess, tau)
    m0 = out[3] / h
    m1 = out[4] / (h * h)
    m2 = out[5] / (h * h * h)
    # quadratic c0 + c1 s/h + c2 (s/h)^2 with these moments: the inverse 3x3 Hilbert matrix
    c0 = 9.0 * m0 - 36.0 * m1 + 30.0 * m2
    c1 = -36.0 * m0 + 192.0 * m1 - 180.0 * m2
    c2 = 30.0 * m0 - 180.0 * m1 + 180.0 * m2
    out[0] = c0
    out[1] = c0 + 0.5 * c1 + 0.25 * c2
    out[2] = c0 + c1 + c2
    out[3] = m0
    return False
