"""The compiled closed loop of N axes of one controller around one multi-axis plant.

One call runs a whole episode of every axis with no Python in the loop, as ``_loop`` does for
one axis; the single-axis loop is left untouched (its results stay identical to the bit), and
this loop, given one axis, computes the same numbers in the same order
(tests/sim/test_multiloop.py compares them bit for bit).

Every axis has its own registers, filter state, profile, encoder, amplifier and loop latency;
they share the servo period ``dt``, the chip family and the plant. Per tick k:

    1. every axis's encoder is read at the tick's start (all axes are sampled together);
       a non-finite joint of any axis ends the episode.
    2. per axis, in axis order: divergence checks on its reading, the chip filter's command,
       the chip's motion error. The first axis (in axis order) with a reason ends the
       episode after this tick; every axis's filter has run.
    3. per axis, the amplifier's current reference takes over from the previous one after
       that axis's loop latency ``latency[i]`` (how the family sequences its axes within a
       servo cycle sets these: ``servogym.sim.MultiServoLoop``), through its current lag.
    4. the plant is integrated over the tick as in ``_loop``: RK4 substeps with every
       actuator's moment-matched current (or one ``mj_step`` per substep for the Euler
       integrator).
"""

from __future__ import annotations

import numpy as np
from numba import njit

from servogym.chips._fixed import wrap32 as _wrap32
from servogym.chips.parker6k._kernel import S_TRIPPED as PK_TRIPPED
from servogym.chips.parker6k._kernel import parker6k_step
from servogym.chips.pmac._kernel import S_TRIPPED as PMAC_TRIPPED
from servogym.chips.pmac._kernel import pmac_step
from servogym.chips.pmd._kernel import S_TRIPPED, pmd_step
from servogym.sim._ffi import mj_forward, mj_step
from servogym.sim._inputs import current_at, substep_input
from servogym.sim._loop import (
    AMP_CURRENT,
    AMP_REFERENCE,
    ERROR_BOUND,
    FAMILY_PARKER6K,
    FAMILY_PMAC,
    FAMILY_PMD,
    INTEGRATOR_RK4,
    MOTION_ERROR,
    NON_FINITE,
    OK,
    TRAVEL,
    WORK_EXTRA,
    _middle_stage,
    forward,
)


def work_size(nv: int, n_axes: int) -> int:
    """Entries of the ``work`` scratch array: ``4 * nv`` for RK4, ``WORK_EXTRA`` per axis
    for its substep input, and one per axis for its new current reference."""
    return 4 * nv + (WORK_EXTRA + 1) * n_axes


@njit(cache=True, nogil=True)
def _set_ctrl(ctrl, ctrl_index, kt, work, base, stage):
    """``ctrl[ctrl_index[i]] = kt[i] * u_i[stage]`` for every axis ``i``."""
    for i in range(ctrl_index.shape[0]):
        ctrl[ctrl_index[i]] = kt[i] * work[base + i * WORK_EXTRA + stage]


@njit(cache=True, nogil=True)
def multi_rk4_substep(
    m_addr, d_addr, qpos, qvel, qacc, qacc_warm, ctrl, ctrl_index, nv, kt, h, full, work
):
    """``_loop.rk4_substep`` with every axis's actuator set at each stage.

    Axis ``i``'s input ``u_i[0:3]`` (start, middle, end) sits at
    ``work[4 * nv + i * WORK_EXTRA :]``; ``kt[i]`` is its motor constant.
    """
    x0 = work[0:nv]
    v0 = work[nv : 2 * nv]
    sx = work[2 * nv : 3 * nv]
    sv = work[3 * nv : 4 * nv]
    base = 4 * nv
    half = 0.5 * h
    for i in range(nv):
        x0[i] = qpos[i]
        v0[i] = qvel[i]
    _set_ctrl(ctrl, ctrl_index, kt, work, base, 0)
    mj_forward(m_addr, d_addr)
    for i in range(nv):
        qacc_warm[i] = qacc[i]
        sx[i] = v0[i]
        sv[i] = qacc[i]
        qpos[i] = x0[i] + half * v0[i]
        qvel[i] = v0[i] + half * qacc[i]
    _set_ctrl(ctrl, ctrl_index, kt, work, base, 1)
    forward(m_addr, d_addr, full)
    _middle_stage(qpos, qvel, qacc, x0, v0, sx, sv, nv, half)
    forward(m_addr, d_addr, full)
    _middle_stage(qpos, qvel, qacc, x0, v0, sx, sv, nv, h)
    _set_ctrl(ctrl, ctrl_index, kt, work, base, 2)
    forward(m_addr, d_addr, full)
    sixth = h / 6.0
    for i in range(nv):
        sx[i] += qvel[i]
        sv[i] += qacc[i]
        qpos[i] = x0[i] + sixth * sx[i]
        qvel[i] = v0[i] + sixth * sv[i]


@njit(cache=True, nogil=True)
def _chip_step(family, state, p, a, commanded, actual, velocity, acceleration):
    """One filter update of one axis; returns ``(command, tripped)``."""
    if family == FAMILY_PMD:
        c = pmd_step(state, p, a, commanded, actual, velocity, acceleration)
        return c, state[S_TRIPPED] != 0
    if family == FAMILY_PMAC:
        c = pmac_step(state, p, a, commanded, actual, velocity, acceleration)
        return c, state[PMAC_TRIPPED] != 0
    if family == FAMILY_PARKER6K:
        c = parker6k_step(state, p, a, commanded, actual, velocity, acceleration)
        return c, state[PK_TRIPPED] != 0
    return np.int64(0), False


@njit(cache=True, nogil=True)
def multi_closed_loop(
    m_addr,
    d_addr,
    qpos,
    qvel,
    qacc,
    qacc_warm,
    ctrl,
    qpos_adr,
    qvel_adr,
    ctrl_index,
    integrator,
    substeps,
    full,
    dt,
    latency,
    tau,
    counts_per_unit,
    travel_lo,
    travel_hi,
    max_error_counts,
    amps_per_count,
    peak_current,
    torque_constant,
    counts_origin,
    amp_state,
    family,
    state,
    p,
    a,
    prof_pos,
    prof_vel,
    prof_acc,
    out_actual,
    out_command,
    out_current,
    work,
):
    """Run one episode of every axis; returns ``(n_ticks_run, divergence_reason, axis)``.

    ``axis`` is the index of the axis whose reason ended the episode (-1 if none). The
    arguments are those of ``_loop.closed_loop``, one entry (or row) per axis ``i``:

    Args:
        qpos_adr, qvel_adr, ctrl_index: int64[n_axes] joint addresses and actuators.
        latency, tau, counts_per_unit, travel_lo, travel_hi, amps_per_count, peak_current,
            torque_constant: float64[n_axes] (units as in ``closed_loop``).
        max_error_counts, counts_origin: int64[n_axes].
        amp_state: float64[n_axes, 2] (``AMP_CURRENT``, ``AMP_REFERENCE``), carried over.
        family: the controller's chip family code (one family for every axis).
        state, p, a: int64[n_axes, ...] filter states, registers, assumption codes.
        prof_pos, prof_vel, prof_acc: int64[n_axes, n_ticks] profiles.
        out_actual, out_command: int64[n_axes, n_ticks]; out_current: float64[n_axes,
            n_ticks], written here.
        work: float64[work_size(nv, n_axes)] scratch.
    """
    n_axes = qpos_adr.shape[0]
    n_ticks = prof_pos.shape[1]
    nv = qvel.shape[0]
    base = 4 * nv
    r_new = work[base + WORK_EXTRA * n_axes : base + (WORK_EXTRA + 1) * n_axes]
    for k in range(n_ticks):
        finite = True
        for i in range(n_axes):
            if not (np.isfinite(qpos[qpos_adr[i]]) and np.isfinite(qvel[qvel_adr[i]])):
                finite = False
        if not finite:
            bad = -1
            for i in range(n_axes):
                if bad < 0 and not (
                    np.isfinite(qpos[qpos_adr[i]]) and np.isfinite(qvel[qvel_adr[i]])
                ):
                    bad = i
                out_actual[i, k] = out_actual[i, k - 1] if k > 0 else 0
                out_command[i, k] = 0
                out_current[i, k] = amp_state[i, AMP_CURRENT]
            return k + 1, NON_FINITE, bad

        reason = OK
        which = -1
        for i in range(n_axes):
            q = qpos[qpos_adr[i]]
            counts = np.int64(np.floor(q * counts_per_unit[i]))
            actual = _wrap32(counts - counts_origin[i])
            out_actual[i, k] = actual
            why = OK
            if q < travel_lo[i] or q > travel_hi[i]:
                why = TRAVEL
            err = _wrap32(prof_pos[i, k] - actual)
            if err > max_error_counts[i] or -err > max_error_counts[i]:
                why = ERROR_BOUND
            command, tripped = _chip_step(
                family, state[i], p[i], a[i], prof_pos[i, k], actual, prof_vel[i, k],
                prof_acc[i, k],
            )  # fmt: skip
            if why == OK and tripped:
                why = MOTION_ERROR
            out_command[i, k] = command
            if why != OK and reason == OK:
                reason = why
                which = i
            r = command * amps_per_count[i]
            if r > peak_current[i]:
                r = peak_current[i]
            elif r < -peak_current[i]:
                r = -peak_current[i]
            r_new[i] = r
        if reason != OK:
            for i in range(n_axes):
                out_current[i, k] = amp_state[i, AMP_CURRENT]
            return k + 1, reason, which

        h = dt / substeps
        for i in range(n_axes):
            out_current[i, k] = 0.0
        for j in range(substeps):
            for i in range(n_axes):
                u = work[base + i * WORK_EXTRA : base + (i + 1) * WORK_EXTRA]
                substep_input(
                    u, j * h, h, amp_state[i, AMP_CURRENT], amp_state[i, AMP_REFERENCE],
                    r_new[i], latency[i], tau[i],
                )  # fmt: skip
                out_current[i, k] += u[3]
            if integrator == INTEGRATOR_RK4:
                multi_rk4_substep(m_addr, d_addr, qpos, qvel, qacc, qacc_warm, ctrl, ctrl_index,
                                  nv, torque_constant, h, full, work)  # fmt: skip
            else:
                _set_ctrl(ctrl, ctrl_index, torque_constant, work, base, 3)
                mj_step(m_addr, d_addr)
        for i in range(n_axes):
            out_current[i, k] = out_current[i, k] / substeps
            amp_state[i, AMP_CURRENT] = current_at(
                dt, amp_state[i, AMP_CURRENT], amp_state[i, AMP_REFERENCE], r_new[i],
                latency[i], tau[i],
            )  # fmt: skip
            amp_state[i, AMP_REFERENCE] = r_new[i]
    return n_ticks, OK, -1
