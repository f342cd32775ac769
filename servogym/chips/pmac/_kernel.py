"""Compiled Turbo PMAC servo filter: the arithmetic of ``_reference.py`` in numba, on int64.

The closed-loop runner calls :func:`pmac_step` once per servo update from its own compiled
loop. Every width of docs/chips/pmac.md is applied explicitly and every intermediate fits in
int64 (largest: Ixx08 times a commanded velocity of 2^36/32 count, below 2^60), except the
Ixx30 product of a 48-bit servo sum; see :func:`pmac_step` for how that one stays exact.

Arrays:
    state: int64[STATE_SIZE], zeroed at reset (layout in ``S_*`` below).
    p: int64[len(FIELDS)], ``PMACParams.to_array()``.
    a: int64[n_assumptions], ``PMACAssumptions.to_array()`` (0 = the default choice).
"""

from __future__ import annotations

import numpy as np
from numba import njit

from servogym.chips._fixed import clamp as _clamp
from servogym.chips._fixed import shr as _shr
from servogym.chips._fixed import wrap32 as _wrap32
from servogym.chips.pmac._params import A_INDEX, P_INDEX

# State layout.
S_CYCLE, S_TRIPPED, S_INTEGRAL, S_SATURATED = 0, 1, 2, 3
S_CP_PREV, S_F_PREV, S_AP_PREV, S_CV_PREV = 4, 5, 6, 7
S_NOTCH = 8  # [x1, x2, w1, w2] (direct form I) or [v1, v2, 0, 0] (direct form II)
STATE_SIZE = 12
"""Length of the state array; ``state[S_TRIPPED]`` is 1 once a fatal following error has
latched (the compiled loop ends the episode on it)."""

# Register indices (numba freezes module globals at compile time; these never change).
IX08, IX09, IX11 = (
    P_INDEX["position_loop_scale"],
    P_INDEX["velocity_loop_scale"],
    P_INDEX["fatal_following_error_limit"],
)
IX29, IX30, IX31 = P_INDEX["output_bias"], P_INDEX["proportional_gain"], P_INDEX["derivative_gain"]
IX32, IX33, IX34 = P_INDEX["velocity_ff"], P_INDEX["integral_gain"], P_INDEX["integration_mode"]
IX35, IX36 = P_INDEX["acceleration_ff"], P_INDEX["notch_n1"]
IX37, IX38, IX39 = P_INDEX["notch_n2"], P_INDEX["notch_d1"], P_INDEX["notch_d2"]
IX63, IX64, IX65 = (
    P_INDEX["integration_limit"],
    P_INDEX["deadband_gain"],
    P_INDEX["deadband_size"],
)
IX67, IX68, IX69 = P_INDEX["big_step_limit"], P_INDEX["friction_ff"], P_INDEX["output_limit"]

A_ROUND, A_ITIME, A_IINPUT = (
    A_INDEX["rounding"],
    A_INDEX["integral_timing"],
    A_INDEX["integrator_input"],
)
A_WINDUP, A_NPOS, A_NFORM = (
    A_INDEX["anti_windup"],
    A_INDEX["notch_position"],
    A_INDEX["notch_form"],
)
A_DBOUT, A_FRIC, A_BIAS = (
    A_INDEX["deadband_outside"],
    A_INDEX["friction_order"],
    A_INDEX["bias_order"],
)
A_VWORD, A_TRIP, A_TCMP, A_FIRST = (
    A_INDEX["velocity_words"],
    A_INDEX["trip_action"],
    A_INDEX["trip_compare"],
    A_INDEX["first_cycle"],
)

S16_LO, S16_HI = -(2**15), 2**15 - 1
S24_LO, S24_HI = -(2**23), 2**23 - 1
S32_LO, S32_HI = -(2**31), 2**31 - 1
S48_LO, S48_HI = -(2**47), 2**47 - 1
Y_CLAMP = 2**39  # |Y| >= 2^39 saturates the 24-bit output word for every Ixx30 != 0


def new_state() -> np.ndarray:
    """A zeroed filter state (loop closed, nothing integrated)."""
    return np.zeros(STATE_SIZE, dtype=np.int64)


@njit(cache=True, nogil=True, inline="always")
def _sign(x):
    if x > 0:
        return 1
    if x < 0:
        return -1
    return 0


@njit(cache=True, nogil=True)
def _notch(state, p, x, lo, hi, form, trunc):
    n1 = p[IX36]
    n2 = p[IX37]
    d1 = p[IX38]
    d2 = p[IX39]
    if form == 0:
        x1 = state[S_NOTCH]
        x2 = state[S_NOTCH + 1]
        w1 = state[S_NOTCH + 2]
        w2 = state[S_NOTCH + 3]
        acc = x * 4194304 + n1 * x1 + n2 * x2 - d1 * w1 - d2 * w2
        w = _clamp(_shr(acc, 22, trunc), lo, hi)
        state[S_NOTCH] = x
        state[S_NOTCH + 1] = x1
        state[S_NOTCH + 2] = w
        state[S_NOTCH + 3] = w1
        return w
    v1 = state[S_NOTCH]
    v2 = state[S_NOTCH + 1]
    v = _clamp(_shr(x * 4194304 - d1 * v1 - d2 * v2, 22, trunc), lo, hi)
    w = _clamp(_shr(v * 4194304 + n1 * v1 + n2 * v2, 22, trunc), lo, hi)
    state[S_NOTCH] = v
    state[S_NOTCH + 1] = v1
    return w


@njit(cache=True, nogil=True)
def _integrate(state, p, a, e_int, cv32, saturated):
    if p[IX34] == 1 and cv32 != 0:
        return
    ilim = p[IX63]
    if ilim < 0:
        ilim = -ilim
    limit = ilim * 16777216
    old = state[S_INTEGRAL]
    new = _clamp(old + p[IX33] * e_int, -limit, limit)
    if saturated != 0:
        if a[A_WINDUP] == 1:
            return
        if (new if new >= 0 else -new) > (old if old >= 0 else -old):
            return
    state[S_INTEGRAL] = new


@njit(cache=True, nogil=True)
def pmac_step(state, p, a, commanded, actual, velocity, acceleration):
    """One servo update; returns the signed 16-bit output command (DAC value, as int64).

    Args:
        state: int64[STATE_SIZE] filter state, updated in place.
        p: int64 registers (``PMACParams.to_array()``).
        a: int64 assumption codes (``PMACAssumptions.to_array()``).
        commanded: Commanded position, whole counts, signed 32-bit (wrapped).
        actual: Encoder position, counts, signed 32-bit (wrapped).
        velocity: The profile's first auxiliary input: the commanded position's fraction in
            1/32 count (0..31; only the low 5 bits are read). The commanded velocity and
            acceleration are differences of the commanded position, taken here as PMAC does.
        acceleration: The profile's second auxiliary input; not read.
    """
    trunc = a[A_ROUND]
    wide = a[A_VWORD] == 1
    wlo = S32_LO if wide else S24_LO
    whi = S32_HI if wide else S24_HI
    f = velocity & 31

    # 3.1 following error in 1/32 count
    fe = 32 * _wrap32(commanded - actual) + f
    if state[S_CYCLE] == 0:
        if a[A_FIRST] == 0:
            state[S_CP_PREV] = actual
            state[S_F_PREV] = 0
        else:
            state[S_CP_PREV] = commanded
            state[S_F_PREV] = f
        state[S_AP_PREV] = actual
        state[S_CV_PREV] = 0

    # 3.2 safety
    ffl = p[IX11]
    if ffl > 0:
        mag = fe if fe >= 0 else -fe
        if a[A_TCMP] == 0:
            if mag > 2 * ffl:
                state[S_TRIPPED] = 1
        elif mag >= 2 * ffl:
            state[S_TRIPPED] = 1
    if p[IX63] < 0:
        imag = state[S_INTEGRAL]
        if imag < 0:
            imag = -imag
        if imag >= -p[IX63] * 16777216:
            state[S_TRIPPED] = 1

    # 3.3 big step
    big = 2 * p[IX67]
    fe_b = _clamp(fe, -big, big)

    # 3.4 deadband
    band = 2 * p[IX65]
    g = p[IX64]
    if (fe_b if fe_b >= 0 else -fe_b) < band:
        fe_d = _shr(fe_b * (16 + g), 4, trunc)
    elif a[A_DBOUT] == 0:
        offset = _shr(g * band, 4, trunc)
        fe_d = fe_b + offset if fe_b >= 0 else fe_b - offset
    else:
        fe_d = fe_b

    # 3.5 velocities
    cv32 = 32 * _wrap32(commanded - state[S_CP_PREV]) + (f - state[S_F_PREV])
    cv = _clamp(p[IX08] * cv32, wlo, whi)
    ca = _clamp(cv - state[S_CV_PREV], wlo, whi)
    av = _clamp(p[IX09] * 32 * _wrap32(actual - state[S_AP_PREV]), wlo, whi)

    # 3.6 integrator before the output (PMAC-A2 "current")
    e_int = fe_d if a[A_IINPUT] == 0 else fe_b
    if a[A_ITIME] == 1:
        _integrate(state, p, a, e_int, cv32, state[S_SATURATED])

    # 3.7 servo sum
    ff = _shr(p[IX32] * cv + p[IX35] * ca, 7, trunc)
    io = _shr(state[S_INTEGRAL], 23, trunc)
    pos = _clamp(p[IX08] * fe_d + ff + p[IX08] * io, S48_LO, S48_HI)
    y = _clamp(pos - _shr(p[IX31] * av, 7, trunc), S48_LO, S48_HI)

    # 3.8 Ixx30 and notch -> 24-bit output word
    if a[A_NPOS] == 0:
        # Ixx30 * y can exceed int64. Any |y| >= 2^39 saturates the 24-bit word for every
        # nonzero Ixx30 (|Ixx30 * y| / 2^16 >= 2^23), so clamping y there first is exact.
        yc = _clamp(y, -Y_CLAMP, Y_CLAMP)
        o = _clamp(_shr(p[IX30] * yc, 16, trunc), S24_LO, S24_HI)
        o = _notch(state, p, o, S24_LO, S24_HI, a[A_NFORM], trunc)
    else:
        w = _notch(state, p, _clamp(y, S32_LO, S32_HI), S32_LO, S32_HI, a[A_NFORM], trunc)
        o = _clamp(_shr(p[IX30] * w, 16, trunc), S24_LO, S24_HI)

    # 3.9 DAC value, friction, limit, bias
    x = o >> 8
    friction = p[IX68] * _sign(cv32)
    if a[A_FRIC] == 0:
        x += friction
    if a[A_BIAS] == 1:
        x += p[IX29]
    olim = p[IX69]
    limited = _clamp(x, -olim, olim)
    saturated = 0
    if limited != x:
        saturated = _sign(x)
    if a[A_FRIC] == 1:
        limited += friction
    if a[A_BIAS] == 0:
        limited += p[IX29]
    command = _clamp(limited, S16_LO, S16_HI)

    # 3.6 integrator after the output (PMAC-A2 "previous")
    if a[A_ITIME] == 0:
        _integrate(state, p, a, e_int, cv32, saturated)
    state[S_SATURATED] = saturated

    # 3.10 killed motor
    if state[S_TRIPPED] != 0:
        if a[A_TRIP] == 0:
            command = 0
        elif a[A_TRIP] == 1:
            command = p[IX29]

    # 3.11 state
    state[S_CP_PREV] = commanded
    state[S_F_PREV] = f
    state[S_AP_PREV] = actual
    state[S_CV_PREV] = cv
    state[S_CYCLE] += 1
    return command


@njit(cache=True, nogil=True)
def pmac_run(state, p, a, commanded, actual, velocity, acceleration, out):
    """Run :func:`pmac_step` over whole input arrays (open loop); writes outputs to ``out``."""
    for i in range(commanded.shape[0]):
        out[i] = pmac_step(state, p, a, commanded[i], actual[i], velocity[i], acceleration[i])
    return out
