"""Compiled 6000-series PIV&F filter: the arithmetic of ``_reference.py`` in numba, on int64.

The closed-loop runner calls :func:`parker6k_step` once per servo sample from its compiled
loop. Every width of docs/chips/parker6k.md is applied explicitly. Where a product could leave
int64 before the spec's saturation at +-2^47 q, the factor is clamped first to a bound beyond
which the saturated result is the same (spec 4.0), so the result is bit-identical to the
reference's unbounded integers.

Arrays:
    state: int64[STATE_SIZE], zeroed at reset (layout in ``S_*`` below; ``S_TRIPPED`` is at
        the same index as in the PMD kernel).
    p: int64, ``Parker6kParams.to_array()`` (variable length: the SGENB schedule is at its
        end).
    a: int64, ``Parker6kAssumptions.to_array()`` (0 = the default choice; indices in
        ``A_INDEX``).
"""

from __future__ import annotations

import numpy as np
from numba import njit

from servogym.chips._fixed import clamp as _clamp
from servogym.chips._fixed import wrap32 as _wrap32
from servogym.chips.parker6k._params import (
    A_INDEX,
    P_GAINS,
    P_N_SWITCHES,
    P_PERIOD_US,
    P_SGILIM,
    P_SMPER,
    P_SOFFS,
    P_SWITCHES,
)

# State layout.
S_INTEGRAL, S_PREV_ACTUAL, S_PREV_ERROR, S_ACTIVE_SET, S_CYCLE, S_TRIPPED = 0, 1, 2, 3, 4, 5
STATE_SIZE = 6

# Assumption indices (numba freezes module globals at compile time; these never change).
A_UNIT, A_DAC, A_VFB = A_INDEX["gain_unit"], A_INDEX["dac_bits"], A_INDEX["velocity_feedback"]
A_ILIM, A_OFFS, A_ROUND = (
    A_INDEX["integral_limit"],
    A_INDEX["offset_order"],
    A_INDEX["rounding"],
)
A_CMP, A_ZERO = A_INDEX["smper_compare"], A_INDEX["smper_zero"]
A_ITIME = A_INDEX["integral_timing"]

W = 2**47
MICRO = 1_000_000
S32_LO, S32_HI = -(2**31), 2**31 - 1


def new_state() -> np.ndarray:
    """A zeroed filter state (power-up / reset)."""
    return np.zeros(STATE_SIZE, dtype=np.int64)


@njit(cache=True, nogil=True, inline="always")
def _div(x, d, trunc):
    if trunc != 0 and x < 0:
        return -((-x) // d)
    return x // d


@njit(cache=True, nogil=True)
def _active_set(p, n):
    """The set of the last SGENB switch with tick <= n (0 if none): a binary search."""
    count = p[P_N_SWITCHES]
    lo = 0
    hi = count
    while lo < hi:
        mid = (lo + hi) // 2
        if p[P_SWITCHES + mid] <= n:
            lo = mid + 1
        else:
            hi = mid
    if lo == 0:
        return 0
    return p[P_SWITCHES + count + lo - 1]


@njit(cache=True, nogil=True)
def parker6k_step(state, p, a, commanded, actual, velocity, acceleration):
    """One servo sample; returns the signed 16-bit motor command (as int64).

    Args:
        state: int64[STATE_SIZE] filter state, updated in place.
        p: int64 settings (``Parker6kParams.to_array()``).
        a: int64 assumption codes (``Parker6kAssumptions.to_array()``).
        commanded: Commanded position, signed 32-bit counts.
        actual: Encoder position, signed 32-bit counts.
        velocity: Commanded velocity, counts/s.
        acceleration: Commanded acceleration, counts/s^2.
    """
    trunc = a[A_ROUND]
    n = state[S_CYCLE]
    fs = 1_000_000_000 if a[A_UNIT] == 0 else 1_000_000
    mv = fs // 10_000
    half = 2048 if a[A_DAC] == 0 else 32768
    period = p[P_PERIOD_US]

    # 4.1 error and SMPER
    e = _wrap32(commanded - actual)
    smper = p[P_SMPER]
    if smper > 0 or a[A_ZERO] == 1:
        mag = e if e >= 0 else -e
        if (a[A_CMP] == 0 and mag > smper) or (a[A_CMP] == 1 and mag >= smper):
            state[S_TRIPPED] = 1

    # 4.2 gain set in force
    active = _active_set(p, n)
    state[S_ACTIVE_SET] = active
    g = P_GAINS + 5 * active
    sgp = p[g]
    sgi = p[g + 1]
    sgv = p[g + 2]
    sgvf = p[g + 3]
    sgaf = p[g + 4]

    # 4.3 velocity input (counts/sample)
    encoder = a[A_VFB] == 0
    if n == 0:
        x = 0
    elif encoder:
        x = _wrap32(actual - state[S_PREV_ACTUAL])
    else:
        x = e - state[S_PREV_ERROR]
    state[S_PREV_ACTUAL] = actual
    state[S_PREV_ERROR] = e

    # 4.4 proportional
    t_p = _clamp(sgp * e, -W, W)

    # 4.5 velocity: beyond +-xc the saturated term is +-W either way
    y = sgv * x
    if encoder:
        y = -y
    xc = (W * period) // MICRO + 1
    y = _clamp(y, -xc, xc)
    t_v = _clamp(_div(y * MICRO, period, trunc), -W, W)

    # 4.6 integral; PK-A10 "previous" (1) reads the term before this sample's update
    lim = p[P_SGILIM] * mv * MICRO
    before = a[A_ITIME] == 1
    t_i = 0
    if a[A_ILIM] == 0:
        if before:
            t_i = _div(state[S_INTEGRAL], MICRO, trunc)
        state[S_INTEGRAL] = _clamp(state[S_INTEGRAL] + sgi * e * period, -lim, lim)
        if not before:
            t_i = _div(state[S_INTEGRAL], MICRO, trunc)
    else:
        if before:
            t_i = _div(_clamp(sgi * state[S_INTEGRAL] * period, -lim, lim), MICRO, trunc)
        candidate = _clamp(state[S_INTEGRAL] + e, S32_LO, S32_HI)
        if a[A_ILIM] == 1:
            state[S_INTEGRAL] = candidate
        else:
            z = sgi * candidate * period
            if z < 0:
                z = -z
            if z <= lim:
                state[S_INTEGRAL] = candidate
        if not before:
            t_i = _div(_clamp(sgi * state[S_INTEGRAL] * period, -lim, lim), MICRO, trunc)

    # 4.7 feed-forward
    t_vf = 0
    if sgvf != 0:
        vc = W // sgvf + 1
        t_vf = _clamp(sgvf * _clamp(velocity, -vc, vc), -W, W)
    t_af = 0
    if sgaf != 0:
        ac = (100 * W) // sgaf + 1
        t_af = _clamp(_div(sgaf * _clamp(acceleration, -ac, ac), 100, trunc), -W, W)

    # 4.8 control signal, offset, DAC
    u = _clamp(t_p + t_v + t_i + t_vf + t_af, -W, W)
    offset = p[P_SOFFS] * mv
    if a[A_OFFS] == 0:
        yv = u + offset
    else:
        yv = _clamp(u, -fs, fs) + offset
    code = _clamp(_div(yv * half, fs, trunc), -half, half - 1)

    # 4.9 shutdown
    if state[S_TRIPPED] != 0:
        code = 0
    state[S_CYCLE] = n + 1
    return code * (32768 // half)


@njit(cache=True, nogil=True)
def parker6k_run(state, p, a, commanded, actual, velocity, acceleration, out):
    """Run :func:`parker6k_step` over whole input arrays (open loop); writes ``out``."""
    for i in range(commanded.shape[0]):
        out[i] = parker6k_step(state, p, a, commanded[i], actual[i], velocity[i], acceleration[i])
    return out
