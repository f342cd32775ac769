"""Compiled PMD servo filter: the same arithmetic as ``_reference.py`` in numba, on int64.

The closed-loop runner calls :func:`pmd_step` once per servo cycle from its own compiled loop.
All widths of docs/chips/pmd.md are applied explicitly; every intermediate fits in int64
(largest: a saturated 48-bit sum times a 15-bit Kout, below 2**62).

Arrays:
    state: int64[STATE_SIZE], zeroed at reset (layout in ``S_*`` below).
    p: int64[len(FIELDS)], ``PMDParams.to_array()``.
    a: int64[n_assumptions], ``PMDAssumptions.to_array()`` (0 = the default choice).
"""

from __future__ import annotations

import numpy as np
from numba import njit

from servogym.chips._fixed import clamp as _clamp
from servogym.chips._fixed import shr as _shr
from servogym.chips._fixed import wrap32 as _wrap32
from servogym.chips.pmd._params import A_INDEX, P_INDEX

# State layout.
S_INTEGRAL, S_E_SAMPLE, S_DERIVATIVE, S_E_PREV, S_CYCLE, S_TRIPPED = 0, 1, 2, 3, 4, 5
S_BQ1, S_BQ2 = 6, 10  # each [x1, x2, y1, y2]
STATE_SIZE = 14

# Register indices (numba freezes module globals at compile time; these never change).
KP, KI, KD = P_INDEX["kp"], P_INDEX["ki"], P_INDEX["kd"]
KVFF, KAFF, KOUT = P_INDEX["kvff"], P_INDEX["kaff"], P_INDEX["kout"]
ILIM, DTIME, BIAS = P_INDEX["integration_limit"], P_INDEX["derivative_time"], P_INDEX["bias"]
MLIM, PEL = P_INDEX["motor_limit"], P_INDEX["position_error_limit"]
BQ1, BQ2 = P_INDEX["biquad1_enable"], P_INDEX["biquad2_enable"]

A_ROUND, A_ISHIFT, A_FFIN = (
    A_INDEX["rounding"],
    A_INDEX["integral_shift"],
    A_INDEX["feedforward_input"],
)
A_KOUTFF, A_BIAS = A_INDEX["kout_scales_feedforward"], A_INDEX["bias_order"]
A_ESAT, A_DSAT, A_DMODE = (
    A_INDEX["error_saturation"],
    A_INDEX["derivative_saturation"],
    A_INDEX["derivative_mode"],
)
A_ACC, A_MERR, A_CMP, A_BQF = (
    A_INDEX["accumulator"],
    A_INDEX["motion_error"],
    A_INDEX["error_limit_compare"],
    A_INDEX["biquad_format"],
)

S16_LO, S16_HI = -(2**15), 2**15 - 1
S32_LO, S32_HI = -(2**31), 2**31 - 1
S48_LO, S48_HI = -(2**47), 2**47 - 1


def new_state() -> np.ndarray:
    """A zeroed filter state (power-up / reset)."""
    return np.zeros(STATE_SIZE, dtype=np.int64)


@njit(cache=True, nogil=True)
def _biquad(state, base, p, pbase, x, frac, trunc):
    x1 = state[base]
    x2 = state[base + 1]
    y1 = state[base + 2]
    y2 = state[base + 3]
    acc = (
        p[pbase + 1] * x
        + p[pbase + 2] * x1
        + p[pbase + 3] * x2
        - p[pbase + 4] * y1
        - p[pbase + 5] * y2
    )
    w = _clamp(_shr(acc, frac, trunc), S32_LO, S32_HI)
    state[base] = x
    state[base + 1] = x1
    state[base + 2] = w
    state[base + 3] = y1
    return _clamp(_shr(p[pbase + 6] * w, frac, trunc), S32_LO, S32_HI)


@njit(cache=True, nogil=True)
def pmd_step(state, p, a, commanded, actual, velocity, acceleration):
    """One servo cycle; returns the signed 16-bit motor command (as int64).

    Args:
        state: int64[STATE_SIZE] filter state, updated in place.
        p: int64 registers (``PMDParams.to_array()``).
        a: int64 assumption codes (``PMDAssumptions.to_array()``).
        commanded: Commanded position, signed 32-bit counts.
        actual: Encoder position, signed 32-bit counts.
        velocity: Commanded velocity, 16.16 counts/cycle.
        acceleration: Commanded acceleration, 16.16 counts/cycle^2.
    """
    trunc = a[A_ROUND]
    n = state[S_CYCLE]

    # 3.1 error and motion error
    e32 = _wrap32(commanded - actual)
    mag = e32 if e32 >= 0 else -e32
    if a[A_CMP] == 0:
        exceeded = mag > p[PEL]
    else:
        exceeded = mag >= p[PEL]
    if exceeded:
        state[S_TRIPPED] = 1
    e = _clamp(e32, S16_LO, S16_HI) if a[A_ESAT] == 1 else e32

    # 3.2 integral
    ilim = p[ILIM]
    state[S_INTEGRAL] = _clamp(state[S_INTEGRAL] + e, -ilim, ilim)

    # 3.3 derivative
    if n % p[DTIME] == 0:
        if a[A_DMODE] == 0:
            d = e - state[S_E_SAMPLE]
        else:
            d = e - state[S_E_PREV]
        state[S_E_SAMPLE] = e
        if a[A_DSAT] == 0:
            d = _clamp(d, S16_LO, S16_HI)
        state[S_DERIVATIVE] = d
    state[S_E_PREV] = e

    # 3.4 feed-forward
    if a[A_FFIN] == 0:
        ff = p[KVFF] * _shr(velocity, 16, trunc) + p[KAFF] * _shr(acceleration, 16, trunc)
    else:
        ff = _shr(p[KVFF] * velocity, 16, trunc) + _shr(p[KAFF] * acceleration, 16, trunc)

    # 3.5 PID sum
    ishift = 8 if a[A_ISHIFT] == 0 else 0
    u = p[KP] * e + p[KD] * state[S_DERIVATIVE] + _shr(p[KI] * state[S_INTEGRAL], ishift, trunc)
    if a[A_KOUTFF] == 0:
        u += ff

    # 3.6 accumulator
    if a[A_ACC] == 0:
        u = _clamp(u, S32_LO, S32_HI)
    else:
        u = _clamp(u, S48_LO, S48_HI)

    # 3.7 biquads
    frac = 14 if a[A_BQF] == 0 else 15
    if p[BQ1] != 0:
        u = _biquad(state, S_BQ1, p, BQ1, _clamp(u, S32_LO, S32_HI), frac, trunc)
    if p[BQ2] != 0:
        u = _biquad(state, S_BQ2, p, BQ2, _clamp(u, S32_LO, S32_HI), frac, trunc)

    # 3.8 Kout
    y = _shr(u * p[KOUT], 16, trunc)
    if a[A_KOUTFF] == 1:
        y += ff

    # 3.9 bias and limit
    mlim = p[MLIM]
    if a[A_BIAS] == 0:
        command = _clamp(y + p[BIAS], -mlim, mlim)
    else:
        command = _clamp(_clamp(y, -mlim, mlim) + p[BIAS], S16_LO, S16_HI)

    # 3.10 motion error
    if state[S_TRIPPED] != 0 and a[A_MERR] == 0:
        command = 0

    state[S_CYCLE] = n + 1
    return command


@njit(cache=True, nogil=True)
def pmd_run(state, p, a, commanded, actual, velocity, acceleration, out):
    """Run :func:`pmd_step` over whole input arrays (open loop); writes commands to ``out``."""
    for i in range(commanded.shape[0]):
        out[i] = pmd_step(state, p, a, commanded[i], actual[i], velocity[i], acceleration[i])
    return out
