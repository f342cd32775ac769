"""The compiled closed loop: profile -> chip filter -> amplifier -> plant -> encoder -> ...

One call runs a whole episode with no Python in the loop. Everything a tick needs arrives as
an argument (numba's cache freezes module globals, so gains and scales are never globals).

Per tick k of period T (docs/simulation.md):
    1. encoder: counts = floor(qpos * counts_per_unit); the chip's actual position is
       wrap32(counts - counts_origin), with counts_origin fixed at the plant's reset.
    2. divergence checks on that reading (non-finite state, travel bound, error bound).
    3. the chip filter computes the motor command C_k (signed 16-bit).
    4. motion error latched by the chip ends the episode after this tick.
    5. amplifier: the current reference r_k = C_k * amps_per_count, saturated at +-peak, takes
       over from r_(k-1) once the loop latency L has passed; the current follows its reference
       through a first-order lag of time constant tau (0: at once), exactly (``_inputs``).
    6. the plant is integrated over [kT, (k+1)T] in ``substeps`` equal substeps: classic RK4
       on (qpos, qvel) with the accelerations of ``mj_forward`` (INTEGRATOR_RK4), or one
       ``mj_step`` of the model's own integrator per substep with the substep's mean current
       (INTEGRATOR_EULER: servogym's first tick, implicitfast, kept for comparison).
"""

from __future__ import annotations

import numpy as np
from numba import njit

from servogym.chips._family import FAMILY_CODES
from servogym.chips._fixed import wrap32 as _wrap32
from servogym.chips.parker6k._kernel import S_TRIPPED as PK_TRIPPED
from servogym.chips.parker6k._kernel import parker6k_step
from servogym.chips.pmac._kernel import S_TRIPPED as PMAC_TRIPPED
from servogym.chips.pmac._kernel import pmac_step
from servogym.chips.pmd._kernel import S_TRIPPED, pmd_step
from servogym.sim._ffi import mj_forward, mj_forwardSkip, mj_step
from servogym.sim._inputs import current_at, substep_input

FAMILY_PMD = FAMILY_CODES["pmd"]
FAMILY_PMAC = FAMILY_CODES["pmac"]
FAMILY_PARKER6K = FAMILY_CODES["parker6k"]

# Integrators (ServoLoop's ``integrator``).
INTEGRATOR_RK4, INTEGRATOR_EULER = 0, 1
INTEGRATORS = {"rk4": INTEGRATOR_RK4, "euler": INTEGRATOR_EULER}

MJ_STAGE_POS = 1
"""``mjtStage.mjSTAGE_POS``: ``mj_forwardSkip`` from the velocity stage on."""

# Divergence reasons (EpisodeMetrics.divergence_reason).
OK, ERROR_BOUND, TRAVEL, MOTION_ERROR, NON_FINITE = 0, 1, 2, 3, 4
REASONS = {
    OK: "none",
    ERROR_BOUND: "error_bound",
    TRAVEL: "travel_limit",
    MOTION_ERROR: "chip_motion_error",
    NON_FINITE: "non_finite_state",
}

AMP_CURRENT, AMP_REFERENCE = 0, 1
"""Entries of the amplifier state carried between calls: the current (A) at the end of the
last tick, and the current reference (A) in effect then (the last command's)."""

WORK_EXTRA = 6
"""Scratch entries of ``work`` beyond ``4 * nv``: the substep input (``_inputs``)."""


@njit(cache=True, nogil=True)
def forward(m_addr, d_addr, full):
    """``mj_forward``, or (``full`` false) only its velocity-dependent stages."""
    if full:
        mj_forward(m_addr, d_addr)
    else:
        mj_forwardSkip(m_addr, d_addr, MJ_STAGE_POS, 1)


@njit(cache=True, nogil=True)
def _middle_stage(qpos, qvel, qacc, x0, v0, sx, sv, nv, step):
    """RK4's stages 2 and 3: add twice the slopes, move to ``x0 + step * slope``."""
    for i in range(nv):
        kx = qvel[i]
        kv = qacc[i]
        sx[i] += 2.0 * kx
        sv[i] += 2.0 * kv
        qpos[i] = x0[i] + step * kx
        qvel[i] = v0[i] + step * kv


@njit(cache=True, nogil=True)
def rk4_substep(
    m_addr, d_addr, qpos, qvel, qacc, qacc_warm, ctrl, ctrl_index, nv, kt, u, h, full, work
):
    """One classic RK4 step of length ``h`` of (qpos, qvel) (hinge and slide joints: nq == nv).

    ``u[0:3]`` is the motor current (A) at the step's start, middle and end; ``ctrl`` gets
    ``kt * u``. The first stage is a full ``mj_forward``; the other three reuse its
    position-dependent quantities (mass matrix, kinematics, gravity, constraint rows) unless
    ``full`` (the plant's ``position_stages``): exact for plants whose position-dependent
    forces are joint springs (``mj_passive`` reads qpos itself) or constant. ``work`` holds
    ``4 * nv`` scratch entries.
    """
    x0 = work[0:nv]
    v0 = work[nv : 2 * nv]
    sx = work[2 * nv : 3 * nv]
    sv = work[3 * nv : 4 * nv]
    half = 0.5 * h
    for i in range(nv):
        x0[i] = qpos[i]
        v0[i] = qvel[i]
    ctrl[ctrl_index] = kt * u[0]
    mj_forward(m_addr, d_addr)
    for i in range(nv):
        qacc_warm[i] = qacc[i]
        sx[i] = v0[i]
        sv[i] = qacc[i]
        qpos[i] = x0[i] + half * v0[i]
        qvel[i] = v0[i] + half * qacc[i]
    ctrl[ctrl_index] = kt * u[1]
    forward(m_addr, d_addr, full)
    _middle_stage(qpos, qvel, qacc, x0, v0, sx, sv, nv, half)
    forward(m_addr, d_addr, full)
    _middle_stage(qpos, qvel, qacc, x0, v0, sx, sv, nv, h)
    ctrl[ctrl_index] = kt * u[2]
    forward(m_addr, d_addr, full)
    sixth = h / 6.0
    for i in range(nv):
        sx[i] += qvel[i]
        sv[i] += qacc[i]
        qpos[i] = x0[i] + sixth * sx[i]
        qvel[i] = v0[i] + sixth * sv[i]


@njit(cache=True, nogil=True)
def integrate_tick(
    m_addr, d_addr, qpos, qvel, qacc, qacc_warm, ctrl, ctrl_index, nv, integrator, substeps,
    full, dt, latency, tau, kt, i0, r_old, r_new, work,
):  # fmt: skip
    """Integrate the plant over one tick; returns the mean current over the tick (A)."""
    h = dt / substeps
    u = work[4 * nv : 4 * nv + WORK_EXTRA]
    total = 0.0
    for j in range(substeps):
        substep_input(u, j * h, h, i0, r_old, r_new, latency, tau)
        total += u[3]
        if integrator == INTEGRATOR_RK4:
            rk4_substep(m_addr, d_addr, qpos, qvel, qacc, qacc_warm, ctrl, ctrl_index, nv, kt,
                        u, h, full, work)  # fmt: skip
        else:
            ctrl[ctrl_index] = kt * u[3]
            mj_step(m_addr, d_addr)
    return total / substeps


@njit(cache=True, nogil=True)
def closed_loop(
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
    """Run one episode; returns ``(n_ticks_run, divergence_reason)``.

    Args:
        m_addr, d_addr: ``MjModel._address`` and ``MjData._address``.
        qpos, qvel, qacc, qacc_warm, ctrl: ``MjData.qpos``, ``.qvel``, ``.qacc``,
            ``.qacc_warmstart``, ``.ctrl`` (views of the C arrays).
        qpos_adr, qvel_adr, ctrl_index: the motor joint's addresses and the motor actuator.
        integrator: ``INTEGRATOR_RK4`` or ``INTEGRATOR_EULER``.
        substeps: integration substeps per servo tick (>= 1).
        full: every RK4 stage recomputes the position-dependent quantities (see
            ``rk4_substep``); else only the first of each substep.
        dt: the servo period T (s).
        latency: time from the encoder sample to the new command reaching the amplifier,
            ``0 <= latency <= dt`` (s).
        tau: current-loop time constant (s); 0 means an ideal current loop.
        counts_per_unit: encoder counts per joint unit (rad or m).
        travel_lo, travel_hi: divergence bounds on qpos (joint units).
        max_error_counts: divergence bound on the magnitude of the position error (counts).
        amps_per_count: amplifier current per motor-command count (A).
        peak_current: amplifier saturation (A).
        torque_constant: motor torque per amp (N*m/A); ctrl is motor torque.
        counts_origin: encoder counts at which the chip's position register reads 0.
        amp_state: float64[2], the amplifier state carried between calls
            (``AMP_CURRENT``, ``AMP_REFERENCE``).
        family: chip family code (``servogym.chips.FAMILY_CODES``).
        state, p, a: the chip filter's state, registers and assumption codes (int64 arrays).
        prof_pos, prof_vel, prof_acc: int64[n_ticks] profile (counts, 16.16, 16.16).
        out_actual, out_command: int64[n_ticks] traces written here.
        out_current: float64[n_ticks] mean amplifier current over each tick (A).
        work: float64[4 * nv + WORK_EXTRA] scratch.
    """
    n_ticks = prof_pos.shape[0]
    nv = qvel.shape[0]
    current = amp_state[AMP_CURRENT]
    r_old = amp_state[AMP_REFERENCE]
    for k in range(n_ticks):
        q = qpos[qpos_adr]
        if not (np.isfinite(q) and np.isfinite(qvel[qvel_adr])):
            out_actual[k] = out_actual[k - 1] if k > 0 else 0
            out_command[k] = 0
            out_current[k] = current
            amp_state[AMP_CURRENT] = current
            amp_state[AMP_REFERENCE] = r_old
            return k + 1, NON_FINITE
        counts = np.int64(np.floor(q * counts_per_unit))
        actual = _wrap32(counts - counts_origin)
        out_actual[k] = actual
        reason = OK
        if q < travel_lo or q > travel_hi:
            reason = TRAVEL
        err = _wrap32(prof_pos[k] - actual)
        if err > max_error_counts or -err > max_error_counts:
            reason = ERROR_BOUND

        command = 0
        if family == FAMILY_PMD:
            command = pmd_step(state, p, a, prof_pos[k], actual, prof_vel[k], prof_acc[k])
            if reason == OK and state[S_TRIPPED] != 0:
                reason = MOTION_ERROR
        elif family == FAMILY_PMAC:
            command = pmac_step(state, p, a, prof_pos[k], actual, prof_vel[k], prof_acc[k])
            if reason == OK and state[PMAC_TRIPPED] != 0:
                reason = MOTION_ERROR
        elif family == FAMILY_PARKER6K:
            command = parker6k_step(state, p, a, prof_pos[k], actual, prof_vel[k], prof_acc[k])
            if reason == OK and state[PK_TRIPPED] != 0:
                reason = MOTION_ERROR
        out_command[k] = command

        r_new = command * amps_per_count
        if r_new > peak_current:
            r_new = peak_current
        elif r_new < -peak_current:
            r_new = -peak_current
        if reason != OK:
            out_current[k] = current
            amp_state[AMP_CURRENT] = current
            amp_state[AMP_REFERENCE] = r_old
            return k + 1, reason

        out_current[k] = integrate_tick(
            m_addr, d_addr, qpos, qvel, qacc, qacc_warm, ctrl, ctrl_index, nv, integrator,
            substeps, full, dt, latency, tau, torque_constant, current, r_old, r_new, work,
        )  # fmt: skip
        current = current_at(dt, current, r_old, r_new, latency, tau)
        r_old = r_new
    amp_state[AMP_CURRENT] = current
    amp_state[AMP_REFERENCE] = r_old
    return n_ticks, OK
