"""The closed loop of ``_loop.closed_loop`` written as a plain Python loop.

Same arithmetic, same order, the Python reference filter and ``mujoco.mj_step`` from Python.
It exists as the baseline of experiments/bench_servo_loop.py and as a check: its traces must
equal the compiled loop's bit for bit (tests/sim/test_runner.py).
"""

from __future__ import annotations

import math

import mujoco
import numpy as np

from servogym.chips.pmd._reference import PMDReferenceFilter, wrap32
from servogym.sim._loop import ERROR_BOUND, MOTION_ERROR, NON_FINITE, OK, TRAVEL


def python_closed_loop(
    model: mujoco.MjModel,
    data: mujoco.MjData,
    io,
    substeps: int,
    travel_lo: float,
    travel_hi: float,
    max_error_counts: int,
    alpha: float,
    counts_origin: int,
    chip_filter: PMDReferenceFilter,
    prof_pos: np.ndarray,
    prof_vel: np.ndarray,
    prof_acc: np.ndarray,
) -> tuple[int, int, list[int], list[int], list[float]]:
    """Run one episode; returns ``(n_run, reason, actual, command, current)``."""
    qpos, qvel, ctrl = data.qpos, data.qvel, data.ctrl
    cpu = float(io.counts_per_unit)
    current = 0.0
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
        i_ref = command * io.amp_amps_per_count
        i_ref = min(max(i_ref, -io.peak_current_a), io.peak_current_a)
        current = i_ref if alpha >= 1.0 else current + (i_ref - current) * alpha
        current_tr.append(current)
        if reason != OK:
            return k + 1, reason, actual_tr, command_tr, current_tr
        ctrl[io.ctrl_index] = io.torque_constant_nm_per_a * current
        for _ in range(substeps):
            mujoco.mj_step(model, data)
    return len(prof_pos), OK, actual_tr, command_tr, current_tr
