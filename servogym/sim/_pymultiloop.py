"""The N-axis closed loop of ``_multiloop.multi_closed_loop`` as a plain Python loop.

Same arithmetic, same order: each axis's plain-Python reference filter, the plain-Python
current model (``_inputs``, ``.py_func``), and ``mujoco.mj_forward`` / ``mujoco.mj_step``
called from Python. Its traces must equal the compiled loop's bit for bit
(tests/sim/test_multiloop.py, a hypothesis property test over families, latencies,
integrators and current loops).
"""

from __future__ import annotations

import math
from collections.abc import Sequence

import mujoco
import numpy as np

from servogym.chips._fixed import wrap32
from servogym.sim import _inputs
from servogym.sim._loop import (
    ERROR_BOUND,
    INTEGRATOR_RK4,
    MOTION_ERROR,
    NON_FINITE,
    OK,
    TRAVEL,
    WORK_EXTRA,
)
from servogym.sim._pyloop import _forward

_substep_input = _inputs.substep_input.py_func
_current_at = _inputs.current_at.py_func


def _multi_rk4_substep(model, data, ios, us, h: float, full: bool) -> None:
    """``_multiloop.multi_rk4_substep`` in Python, operation for operation."""
    qpos, qvel, qacc = data.qpos, data.qvel, data.qacc
    nv = model.nv
    x0 = [float(qpos[i]) for i in range(nv)]
    v0 = [float(qvel[i]) for i in range(nv)]
    half = 0.5 * h

    def set_ctrl(stage: int) -> None:
        for io, u in zip(ios, us, strict=True):
            data.ctrl[io.ctrl_index] = io.torque_constant_nm_per_a * u[stage]

    set_ctrl(0)
    mujoco.mj_forward(model, data)
    data.qacc_warmstart[:] = qacc
    sx = [v0[i] for i in range(nv)]
    sv = [float(qacc[i]) for i in range(nv)]
    for i in range(nv):
        qpos[i] = x0[i] + half * v0[i]
        qvel[i] = v0[i] + half * float(qacc[i])
    set_ctrl(1)
    for frac in (half, h):
        _forward(model, data, full)
        for i in range(nv):
            kx, kv = float(qvel[i]), float(qacc[i])
            sx[i] += 2.0 * kx
            sv[i] += 2.0 * kv
            qpos[i] = x0[i] + frac * kx
            qvel[i] = v0[i] + frac * kv
    set_ctrl(2)
    _forward(model, data, full)
    sixth = h / 6.0
    for i in range(nv):
        sx[i] += float(qvel[i])
        sv[i] += float(qacc[i])
        qpos[i] = x0[i] + sixth * sx[i]
        qvel[i] = v0[i] + sixth * sv[i]


def python_multi_closed_loop(
    model: mujoco.MjModel,
    data: mujoco.MjData,
    ios: Sequence,
    integrator: int,
    substeps: int,
    full: bool,
    dt: float,
    latency: Sequence[float],
    tau: Sequence[float],
    travel_lo: Sequence[float],
    travel_hi: Sequence[float],
    max_error_counts: Sequence[int],
    counts_origin: Sequence[int],
    chip_filters: Sequence,
    prof_pos: np.ndarray,
    prof_vel: np.ndarray,
    prof_acc: np.ndarray,
) -> tuple[int, int, int, list[list[int]], list[list[int]], list[list[float]]]:
    """Run one episode of every axis from rest.

    Returns:
        ``(n_run, reason, axis, actual, command, current)``: the traces one list per axis.
    """
    n = len(ios)
    qpos, qvel = data.qpos, data.qvel
    h = dt / substeps
    us = [np.zeros(WORK_EXTRA) for _ in range(n)]
    current = [0.0] * n
    r_old = [0.0] * n
    r_new = [0.0] * n
    actual_tr: list[list[int]] = [[] for _ in range(n)]
    command_tr: list[list[int]] = [[] for _ in range(n)]
    current_tr: list[list[float]] = [[] for _ in range(n)]
    for k in range(prof_pos.shape[1]):
        finite = [
            math.isfinite(qpos[io.qpos_adr]) and math.isfinite(qvel[io.qvel_adr]) for io in ios
        ]
        if not all(finite):
            for i in range(n):
                actual_tr[i].append(actual_tr[i][-1] if actual_tr[i] else 0)
                command_tr[i].append(0)
                current_tr[i].append(current[i])
            return k + 1, NON_FINITE, finite.index(False), actual_tr, command_tr, current_tr
        reason, which = OK, -1
        for i, io in enumerate(ios):
            q = float(qpos[io.qpos_adr])
            actual = wrap32(math.floor(q * float(io.counts_per_unit)) - int(counts_origin[i]))
            actual_tr[i].append(actual)
            why = OK
            if q < travel_lo[i] or q > travel_hi[i]:
                why = TRAVEL
            if abs(wrap32(int(prof_pos[i, k]) - actual)) > max_error_counts[i]:
                why = ERROR_BOUND
            command = chip_filters[i].step(
                int(prof_pos[i, k]), actual, int(prof_vel[i, k]), int(prof_acc[i, k])
            )
            if why == OK and chip_filters[i].motion_error:
                why = MOTION_ERROR
            command_tr[i].append(command)
            if why != OK and reason == OK:
                reason, which = why, i
            r_new[i] = min(
                max(command * io.amp_amps_per_count, -io.peak_current_a), io.peak_current_a
            )
        if reason != OK:
            for i in range(n):
                current_tr[i].append(current[i])
            return k + 1, reason, which, actual_tr, command_tr, current_tr
        totals = [0.0] * n
        for j in range(substeps):
            for i in range(n):
                _substep_input(us[i], j * h, h, current[i], r_old[i], r_new[i], latency[i], tau[i])
                totals[i] += us[i][3]
            if integrator == INTEGRATOR_RK4:
                _multi_rk4_substep(model, data, ios, us, h, full)
            else:
                for io, u in zip(ios, us, strict=True):
                    data.ctrl[io.ctrl_index] = io.torque_constant_nm_per_a * u[3]
                mujoco.mj_step(model, data)
        for i in range(n):
            current_tr[i].append(totals[i] / substeps)
            current[i] = _current_at(dt, current[i], r_old[i], r_new[i], latency[i], tau[i])
            r_old[i] = r_new[i]
    return prof_pos.shape[1], OK, -1, actual_tr, command_tr, current_tr
