"""The closed loop of ``_loop.closed_loop`` written as a plain Python loop.

Same arithmetic, same order: the chip family's Python reference filter, the plain-Python
versions of the current model (``_inputs``, ``.py_func``), and ``mujoco.mj_forward`` /
``mujoco.mj_step`` called from Python. It exists as the baseline of
experiments/bench_servo_loop.py and as a check: its traces must equal the compiled loop's bit
for bit, for every integrator and loop latency (tests/sim/test_runner.py).
"""

from __future__ import annotations

import math

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

_substep_input = _inputs.substep_input.py_func
_current_at = _inputs.current_at.py_func


def _forward(model, data, full: bool) -> None:
    if full:
        mujoco.mj_forward(model, data)
    else:
        mujoco.mj_forwardSkip(model, data, mujoco.mjtStage.mjSTAGE_POS, 1)


def _rk4_substep(model, data, ctrl_index: int, kt: float, u, h: float, full: bool) -> None:
    """``_loop.rk4_substep`` in Python, operation for operation."""
    qpos, qvel, qacc = data.qpos, data.qvel, data.qacc
    nv = model.nv
    x0 = [float(qpos[i]) for i in range(nv)]
    v0 = [float(qvel[i]) for i in range(nv)]
    half = 0.5 * h
    data.ctrl[ctrl_index] = kt * u[0]
    mujoco.mj_forward(model, data)
    data.qacc_warmstart[:] = qacc
    sx = [v0[i] for i in range(nv)]
    sv = [float(qacc[i]) for i in range(nv)]
    for i in range(nv):
        qpos[i] = x0[i] + half * v0[i]
        qvel[i] = v0[i] + half * float(qacc[i])
    data.ctrl[ctrl_index] = kt * u[1]
    for frac in (half, h):
        _forward(model, data, full)
        for i in range(nv):
            kx, kv = float(qvel[i]), float(qacc[i])
            sx[i] += 2.0 * kx
            sv[i] += 2.0 * kv
            qpos[i] = x0[i] + frac * kx
            qvel[i] = v0[i] + frac * kv
    data.ctrl[ctrl_index] = kt * u[2]
    _forward(model, data, full)
    sixth = h / 6.0
    for i in range(nv):
        sx[i] += float(qvel[i])
        sv[i] += float(qacc[i])
        qpos[i] = x0[i] + sixth * sx[i]
        qvel[i] = v0[i] + sixth * sv[i]


def python_closed_loop(
    model: mujoco.MjModel,
    data: mujoco.MjData,
    io,
    integrator: int,
    substeps: int,
    full: bool,
    dt: float,
    latency: float,
    tau: float,
    travel_lo: float,
    travel_hi: float,
    max_error_counts: int,
    counts_origin: int,
    chip_filter,
    prof_pos: np.ndarray,
    prof_vel: np.ndarray,
    prof_acc: np.ndarray,
) -> tuple[int, int, list[int], list[int], list[float]]:
    """Run one episode from rest; returns ``(n_run, reason, actual, command, current)``."""
    qpos, qvel = data.qpos, data.qvel
    cpu = float(io.counts_per_unit)
    kt = io.torque_constant_nm_per_a
    h = dt / substeps
    u = np.zeros(WORK_EXTRA)
    current = 0.0
    r_old = 0.0
    actual_tr: list[int] = []
    command_tr: list[int] = []
    current_tr: list[float] = []
    for k in range(len(prof_pos)):
        q = float(qpos[io.qpos_adr])
        if not (math.isfinite(q) and math.isfinite(qvel[io.qvel_adr])):
            actual_tr.append(actual_tr[-1] if actual_tr else 0)
            command_tr.append(0)
            current_tr.append(current)
            return k + 1, NON_FINITE, actual_tr, command_tr, current_tr
        actual = wrap32(math.floor(q * cpu) - counts_origin)
        actual_tr.append(actual)
        reason = OK
        if q < travel_lo or q > travel_hi:
            reason = TRAVEL
        if abs(wrap32(int(prof_pos[k]) - actual)) > max_error_counts:
            reason = ERROR_BOUND
        command = chip_filter.step(int(prof_pos[k]), actual, int(prof_vel[k]), int(prof_acc[k]))
        if reason == OK and chip_filter.motion_error:
            reason = MOTION_ERROR
        command_tr.append(command)
        r_new = command * io.amp_amps_per_count
        r_new = min(max(r_new, -io.peak_current_a), io.peak_current_a)
        if reason != OK:
            current_tr.append(current)
            return k + 1, reason, actual_tr, command_tr, current_tr
        total = 0.0
        for j in range(substeps):
            _substep_input(u, j * h, h, current, r_old, r_new, latency, tau)
            total += u[3]
            if integrator == INTEGRATOR_RK4:
                _rk4_substep(model, data, io.ctrl_index, kt, u, h, full)
            else:
                data.ctrl[io.ctrl_index] = kt * u[3]
                mujoco.mj_step(model, data)
        current_tr.append(total / substeps)
        current = _current_at(dt, current, r_old, r_new, latency, tau)
        r_old = r_new
    return len(prof_pos), OK, actual_tr, command_tr, current_tr
