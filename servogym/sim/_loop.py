"""The compiled closed loop: profile -> chip filter -> amplifier -> mj_step -> encoder -> ...

One call runs a whole episode with no Python in the loop. Everything a tick needs arrives as
an argument (numba's cache freezes module globals, so gains and scales are never globals).

Per tick k (docs/simulation.md):
    1. encoder: counts = floor(qpos * counts_per_unit); the chip's actual position is
       wrap32(counts - counts_origin), with counts_origin fixed at the plant's reset.
    2. divergence checks on that reading (non-finite state, travel bound, error bound).
    3. the chip filter computes the motor command C_k (signed 16-bit).
    4. motion error latched by the chip ends the episode after this tick.
    5. amplifier: i_ref = C_k * amps_per_count, saturated at +-peak; with a current-loop
       bandwidth, i += (i_ref - i) * alpha, else i = i_ref. Motor torque = kt * i -> ctrl.
    6. mj_step, ``substeps`` times.
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
from servogym.sim._ffi import mj_step

FAMILY_PMD = FAMILY_CODES["pmd"]
FAMILY_PMAC = FAMILY_CODES["pmac"]
FAMILY_PARKER6K = FAMILY_CODES["parker6k"]

# Divergence reasons (EpisodeMetrics.divergence_reason).
OK, ERROR_BOUND, TRAVEL, MOTION_ERROR, NON_FINITE = 0, 1, 2, 3, 4
REASONS = {
    OK: "none",
    ERROR_BOUND: "error_bound",
    TRAVEL: "travel_limit",
    MOTION_ERROR: "chip_motion_error",
    NON_FINITE: "non_finite_state",
}


@njit(cache=True, nogil=True)
def closed_loop(
    m_addr,
    d_addr,
    qpos,
    qvel,
    ctrl,
    qpos_adr,
    qvel_adr,
    ctrl_index,
    substeps,
    counts_per_unit,
    travel_lo,
    travel_hi,
    max_error_counts,
    amps_per_count,
    peak_current,
    torque_constant,
    alpha,
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
):
    """Run one episode; returns ``(n_ticks_run, divergence_reason)``.

    Args:
        m_addr, d_addr: ``MjModel._address`` and ``MjData._address``.
        qpos, qvel, ctrl: ``MjData.qpos``, ``.qvel``, ``.ctrl`` (views of the C arrays).
        qpos_adr, qvel_adr, ctrl_index: the motor joint's addresses and the motor actuator.
        substeps: mj_step calls per servo tick.
        counts_per_unit: encoder counts per joint unit (rad or m).
        travel_lo, travel_hi: divergence bounds on qpos (joint units).
        max_error_counts: divergence bound on the magnitude of the position error (counts).
        amps_per_count: amplifier current per motor-command count (A).
        peak_current: amplifier saturation (A).
        torque_constant: motor torque per amp (N*m/A); ctrl is motor torque.
        alpha: current-loop update factor in (0, 1]; >= 1 means an ideal current loop.
        counts_origin: encoder counts at which the chip's position register reads 0.
        amp_state: float64[1], the amplifier current carried between calls (A).
        family: chip family code (``servogym.chips.FAMILY_CODES``).
        state, p, a: the chip filter's state, registers and assumption codes (int64 arrays).
        prof_pos, prof_vel, prof_acc: int64[n_ticks] profile (counts, 16.16, 16.16).
        out_actual, out_command: int64[n_ticks] traces written here.
        out_current: float64[n_ticks] amplifier current trace (A).
    """
    n_ticks = prof_pos.shape[0]
    current = amp_state[0]
    for k in range(n_ticks):
        q = qpos[qpos_adr]
        if not (np.isfinite(q) and np.isfinite(qvel[qvel_adr])):
            out_actual[k] = out_actual[k - 1] if k > 0 else 0
            out_command[k] = 0
            out_current[k] = current
            amp_state[0] = current
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

        i_ref = command * amps_per_count
        if i_ref > peak_current:
            i_ref = peak_current
        elif i_ref < -peak_current:
            i_ref = -peak_current
        if alpha >= 1.0:
            current = i_ref
        else:
            current = current + (i_ref - current) * alpha
        out_current[k] = current
        if reason != OK:
            amp_state[0] = current
            return k + 1, reason

        ctrl[ctrl_index] = torque_constant * current
        for _ in range(substeps):
            mj_step(m_addr, d_addr)
    amp_state[0] = current
    return n_ticks, OK
