"""Replaying a trace through the simulator: closed loop (chip + plant) and open loop (plant).

* **Closed loop** (:meth:`Replayer.closed_loop`): the recorded commanded profile through the
  chip's filter with the registers that ran, around the plant, exactly as ``ServoLoop`` runs
  an episode. The simulated encoder and motor command are compared with the recorded ones.
* **Open loop** (:meth:`Replayer.open_loop`): the recorded motor command drives the plant
  through the same amplifier, latency and integration; no filter. Over a long trace a free
  axis would drift from the smallest error, so the motor joint is put back on the recorded
  position (the middle of its count) and velocity (the slope of a straight line through
  the samples within :data:`ANCHOR_S` each side) every :data:`WINDOW_S`; the
  plant's other joints (the two-mass twist) run on. What is compared is where the plant has
  gone within each window.
"""

from __future__ import annotations

import dataclasses
from typing import Any

import numpy as np
from numba import njit

from servogym.chips._family import family_of
from servogym.chips._fixed import wrap32 as _wrap32
from servogym.sim._inputs import current_at
from servogym.sim._loop import INTEGRATOR_RK4, WORK_EXTRA, integrate_tick
from servogym.sim._runner import ServoLoop, current_loop_tau, default_substeps

WINDOW_S = 5e-3
"""Length of an open-loop window (s): the motor joint is re-anchored on the trace at its
start (32 samples at 154 us, 11 at 442.7 us)."""

ANCHOR_S = 0.6e-3
"""Time each side of an anchor whose samples give its velocity (at least 2 samples each
side): short, so that an oscillation of the axis does not blur it."""


def window_ticks(dt: float) -> int:
    """Samples per open-loop window at a servo period ``dt`` (s)."""
    return max(8, round(WINDOW_S / dt))


def anchor_half_width(dt: float) -> int:
    """Samples each side of an anchor for its velocity at a servo period ``dt`` (s)."""
    return max(2, round(ANCHOR_S / dt))


@dataclasses.dataclass(frozen=True)
class TraceProfile:
    """The recorded commanded profile in the form ``ServoLoop.run`` takes (int64 arrays)."""

    position: np.ndarray
    velocity: np.ndarray
    acceleration: np.ndarray
    start: int

    @property
    def n_ticks(self) -> int:
        """Number of servo cycles."""
        return int(self.position.shape[0])


def trace_profile(trace: Any, family: str, period_s: float) -> TraceProfile:
    """The chip profile of a trace: its commanded positions and the auxiliary inputs.

    Auxiliary inputs the trace does not carry are derived from the commanded positions:
    PMD velocity ``65536 * (p[k] - p[k-1])`` and acceleration its difference (16.16);
    PMAC fraction 0 (whole counts); Parker velocity ``(p[k] - p[k-1]) / T`` (counts/s) and
    acceleration its difference over ``T``.
    """
    pos = np.ascontiguousarray(trace.commanded, dtype=np.int64)
    step = np.diff(pos, prepend=pos[0])
    if family == "pmd":
        vel = step * 65536
        acc = np.diff(vel, prepend=0)
    elif family == "parker6k":
        vel = np.rint(step / period_s).astype(np.int64)
        acc = np.rint(np.diff(vel, prepend=0) / period_s).astype(np.int64)
    else:
        vel = np.zeros_like(pos)
        acc = np.zeros_like(pos)
    if trace.aux1 is not None:
        vel = np.asarray(trace.aux1, dtype=np.int64)
    if trace.aux2 is not None:
        acc = np.asarray(trace.aux2, dtype=np.int64)
    return TraceProfile(pos, np.ascontiguousarray(vel), np.ascontiguousarray(acc), int(pos[0]))


@njit(cache=True, nogil=True)
def open_loop(
    m_addr, d_addr, qpos, qvel, qacc, qacc_warm, ctrl, qpos_adr, qvel_adr, ctrl_index,
    substeps, full, dt, latency, tau, counts_per_unit, amps_per_count, peak_current, kt,
    counts_origin, command, anchor_pos, anchor_vel, window, out_actual, work,
):  # fmt: skip
    """Drive the plant with recorded motor commands; the encoder reading of every tick.

    At each ``k % window == 0`` the motor joint is set to ``anchor_pos[k]``,
    ``anchor_vel[k]`` (joint units). After a non-finite state the rest reads the last
    finite value. Returns the number of ticks integrated.
    """
    n = command.shape[0]
    nv = qvel.shape[0]
    current = 0.0
    r_old = 0.0
    for k in range(n):
        if k % window == 0:
            qpos[qpos_adr] = anchor_pos[k]
            qvel[qvel_adr] = anchor_vel[k]
        q = qpos[qpos_adr]
        if not (np.isfinite(q) and np.isfinite(qvel[qvel_adr])):
            for j in range(k, n):
                out_actual[j] = out_actual[k - 1] if k > 0 else 0
            return k
        out_actual[k] = _wrap32(np.int64(np.floor(q * counts_per_unit)) - counts_origin)
        c = command[k]
        if c > 32767:
            c = 32767
        elif c < -32768:
            c = -32768
        r_new = c * amps_per_count
        if r_new > peak_current:
            r_new = peak_current
        elif r_new < -peak_current:
            r_new = -peak_current
        integrate_tick(
            m_addr, d_addr, qpos, qvel, qacc, qacc_warm, ctrl, ctrl_index, nv, INTEGRATOR_RK4,
            substeps, full, dt, latency, tau, kt, current, r_old, r_new, work,
        )  # fmt: skip
        current = current_at(dt, current, r_old, r_new, latency, tau)
        r_old = r_new
    return n


@dataclasses.dataclass(frozen=True)
class Replay:
    """A replay's simulated traces (length of the trace) and how far it ran.

    Attributes:
        actual: Simulated encoder position (counts).
        command: Simulated motor command (counts); the recorded one for an open-loop replay.
        n_run: Ticks simulated before a divergence (the trace's length when none).
        reason: The divergence reason (``"none"`` when it ran to the end).
    """

    actual: np.ndarray
    command: np.ndarray
    n_run: int
    reason: str


class Replayer:
    """Replays one trace on one compiled plant, for any plant values and latency.

    Args:
        plant: A built plant (``PlantFamily.build``); edited in place by :meth:`set_plant`.
        params: The register set that ran.
        assumptions: The chip's assumption switches (the latency is set per replay).
        trace: The :class:`~servogym.calibrate.Trace`.
    """

    def __init__(self, plant: Any, params: Any, assumptions: Any, trace: Any) -> None:
        self.plant = plant
        self.params = params
        self.chip = family_of(params)
        self.assumptions = assumptions or self.chip.default_assumptions()
        self.trace = trace
        self.dt = self.chip.sample_time_s(params)
        self.profile = trace_profile(trace, self.chip.name, self.dt)
        self.loop = ServoLoop(plant, params, self.assumptions)
        self.substeps = default_substeps(self.dt)
        self._work = np.zeros(4 * plant.model.nv + WORK_EXTRA)
        self._out = np.zeros(trace.n_ticks, np.int64)
        self._command = np.ascontiguousarray(trace.command, dtype=np.int64)

    def set_plant(self, values: dict[str, float]) -> None:
        """Set the plant instance (in place)."""
        self.plant.set_params(values)

    def closed_loop(self, latency: str) -> Replay:
        """The recorded profile through the chip and the plant at a ``loop_latency`` choice."""
        asm = dataclasses.replace(self.assumptions, loop_latency=latency)
        if asm != self.loop.assumptions:
            self.loop.assumptions = asm
            self.loop.set_params(self.params)
        start = int(self.trace.actual[0])
        r = self.loop.run(self.profile, start_counts=start, traces=True)
        n = self.trace.n_ticks
        tr = r.traces
        actual = np.empty(n, np.int64)
        command = np.zeros(n, np.int64)
        actual[: tr.actual.size] = tr.actual
        actual[tr.actual.size :] = tr.actual[-1] if tr.actual.size else start
        command[: tr.command.size] = tr.command
        return Replay(actual, command, r.metrics.n_ticks, r.metrics.divergence_reason)

    def latency_s(self, latency: str) -> float:
        """The loop latency (s) of a ``loop_latency`` choice for these registers."""
        asm = dataclasses.replace(self.assumptions, loop_latency=latency)
        return self.chip.loop_latency_s(self.params, asm)

    def open_loop(self, latency: str) -> Replay:
        """The recorded motor command through the amplifier into the plant (windowed)."""
        plant = self.plant
        io = plant.io
        plant.reset()
        plant.set_timestep(self.dt / self.substeps)
        cpu = float(io.counts_per_unit)
        meas = self.trace.actual.astype(float)
        origin = int(np.floor(plant.data.qpos[io.qpos_adr] * cpu)) - int(self.trace.actual[0])
        anchor_pos = (meas + origin + 0.5) / cpu
        h = anchor_half_width(self.dt)
        padded = np.concatenate([np.full(h, meas[0]), meas, np.full(h, meas[-1])])
        # least-squares slope over the 2h + 1 samples around each one
        k = np.arange(-h, h + 1, dtype=float)
        slope = np.zeros(meas.size)
        for j, w in enumerate(k):
            slope += w * padded[j : j + meas.size]
        anchor_vel = slope / float(np.dot(k, k)) / self.dt / cpu
        m, d = plant.model, plant.data
        n_run = open_loop(
            m._address, d._address, d.qpos, d.qvel, d.qacc, d.qacc_warmstart, d.ctrl,
            io.qpos_adr, io.qvel_adr, io.ctrl_index, self.substeps,
            bool(plant.family.position_stages), float(self.dt), float(self.latency_s(latency)),
            current_loop_tau(io.current_bandwidth_hz), cpu, float(io.amp_amps_per_count),
            float(io.peak_current_a), float(io.torque_constant_nm_per_a), origin,
            self._command, anchor_pos, anchor_vel, window_ticks(self.dt), self._out, self._work,
        )  # fmt: skip
        reason = "none" if n_run == self.trace.n_ticks else "non_finite_state"
        return Replay(self._out.copy(), self._command.copy(), int(n_run), reason)
