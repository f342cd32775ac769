"""Reference amplifier and encoder models, in plain Python.

The closed-loop runner evaluates these in its compiled (numba) loop; it must match these
functions bit for bit. ``docs/plants.md`` ("Amplifier and encoder") states the same
arithmetic. Only IEEE double ``+ - * /``, comparisons and ``floor`` are used per step; the one
transcendental function (``exp``, in :func:`amplifier_alpha`) is evaluated once, in Python,
outside the loop.
"""

from __future__ import annotations

import math

from servogym.plants._base import COMMAND_MAX, COMMAND_MIN, AxisIO


def amplifier_alpha(current_bandwidth_hz: float, dt_s: float) -> float:
    """Per-update gain of the first-order current loop.

    ``alpha = 1.0 - math.exp(-2.0 * math.pi * current_bandwidth_hz * dt_s)``, multiplied left to
    right; ``1.0`` for an ideal current loop (``current_bandwidth_hz <= 0``).

    Args:
        current_bandwidth_hz: Current-loop bandwidth, in Hz (``AxisIO.current_bandwidth_hz``).
        dt_s: Time between two current updates, in seconds.

    Returns:
        The gain, ``0 < alpha <= 1``. Compute it once per episode (in Python) and pass it to
        the compiled loop, so that every implementation uses the same ``exp``.
    """
    if current_bandwidth_hz <= 0.0:
        return 1.0
    return 1.0 - math.exp(-2.0 * math.pi * current_bandwidth_hz * dt_s)


def amplifier_current(command: int, prev_current: float, io: AxisIO, dt_s: float) -> float:
    """The motor current after one update of the amplifier.

    1. ``c = min(max(command, -32768), 32767)``: the chip's 16-bit output range.
    2. ``i_ref = float(c) * io.amp_amps_per_count``, then clamped to
       ``-io.peak_current_a .. io.peak_current_a`` (saturation).
    3. ``alpha = amplifier_alpha(io.current_bandwidth_hz, dt_s)``. If ``alpha >= 1.0`` (an
       ideal loop, ``io.current_bandwidth_hz <= 0``, or one so fast that ``exp`` rounds to
       0): ``i = i_ref``. Otherwise ``i = prev_current + (i_ref - prev_current) * alpha``,
       evaluated as written (subtract, multiply, add; no fused multiply-add).

    The motor torque written to ``MjData.ctrl[io.ctrl_index]`` is
    ``i * io.torque_constant_nm_per_a`` in N*m.

    Args:
        command: Chip motor command, signed 16 bit (``-32768 .. 32767``; clamped).
        prev_current: Current after the previous update, in A (0 after a reset).
        io: The plant's :class:`AxisIO`.
        dt_s: Time since the previous update, in seconds.

    Returns:
        The new current, in A, within ``-io.peak_current_a .. io.peak_current_a``.
    """
    c = min(max(int(command), COMMAND_MIN), COMMAND_MAX)
    i_ref = float(c) * io.amp_amps_per_count
    if i_ref > io.peak_current_a:
        i_ref = io.peak_current_a
    elif i_ref < -io.peak_current_a:
        i_ref = -io.peak_current_a
    alpha = amplifier_alpha(io.current_bandwidth_hz, dt_s)
    if alpha >= 1.0:  # ideal loop, or a bandwidth so high that exp(-x) rounds to 0
        return i_ref
    return prev_current + (i_ref - prev_current) * alpha


def motor_torque(current_a: float, io: AxisIO) -> float:
    """Motor shaft torque for a current: ``current_a * io.torque_constant_nm_per_a``, in N*m.

    Args:
        current_a: Motor current, in A.
        io: The plant's :class:`AxisIO`.
    """
    return current_a * io.torque_constant_nm_per_a


def encoder_counts(qpos: float, io: AxisIO) -> int:
    """The encoder reading for a joint position: ``floor(qpos * io.counts_per_unit)``.

    Position 0 (the start position) reads 0 counts; counts grow with the joint coordinate.
    Over every family's legal travel the reading fits a signed 32-bit integer.

    Args:
        qpos: Position of the measured joint, ``MjData.qpos[io.qpos_adr]``, in joint units
            (rad or m).
        io: The plant's :class:`AxisIO`.

    Returns:
        The count, a Python int.
    """
    return math.floor(qpos * io.counts_per_unit)
