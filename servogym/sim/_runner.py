"""The servo loop: one chip axis closed around one plant, an episode per call."""

from __future__ import annotations

import dataclasses
import math
from typing import Any

import numpy as np

from servogym.chips._family import family_of
from servogym.sim._loop import INTEGRATORS, REASONS, WORK_EXTRA, closed_loop
from servogym.sim._metrics import METRIC_NAMES, EpisodeMetrics, compute_metrics

TRAVEL_MARGIN = 0.01
"""Fraction of the travel span, inside each hard stop, whose crossing counts as divergence."""

MAX_SUBSTEP_S = 160e-6
"""Longest RK4 substep of the default integration (s): a servo period T is integrated in
``ceil(T / MAX_SUBSTEP_S)`` equal substeps (docs/simulation.md, "Integration")."""

REFERENCE_SUBSTEPS = 32
"""Substeps per servo period of the fine reference integration (RK4), the most of which the
default must agree with (``servogym check``, tests/sim/test_convergence.py)."""


def default_substeps(dt_s: float) -> int:
    """Substeps per servo period of the default integration: ``ceil(dt_s / MAX_SUBSTEP_S)``."""
    return max(1, math.ceil(dt_s / MAX_SUBSTEP_S - 1e-9))


@dataclasses.dataclass(frozen=True)
class Traces:
    """Per-tick traces of one episode, all of length ``n_ticks`` run.

    Attributes:
        time_s: Time at the start of each tick (s).
        commanded: Commanded position from the profile (counts).
        actual: Encoder position the chip read (counts).
        error: Position error the chip saw, ``wrap32(commanded - actual)`` (counts).
        command: Motor command (signed 16-bit counts, 32768 = 100 %).
        current_a: Mean amplifier output current over each tick (A).
    """

    time_s: np.ndarray
    commanded: np.ndarray
    actual: np.ndarray
    error: np.ndarray
    command: np.ndarray
    current_a: np.ndarray


@dataclasses.dataclass(frozen=True)
class EpisodeResult:
    """Metrics, always; traces when asked for."""

    metrics: EpisodeMetrics
    traces: Traces | None = None


def current_loop_tau(bandwidth_hz: float) -> float:
    """Time constant (s) of the first-order current loop of a bandwidth; 0 = ideal."""
    if bandwidth_hz <= 0:
        return 0.0
    return 1.0 / (2.0 * math.pi * bandwidth_hz)


class ServoLoop:
    """A chip axis closed around a plant; :meth:`run` runs one episode in compiled code.

    Between two servo ticks the plant is integrated with the motor current held by the
    amplifier (the previous command's until the loop latency has passed, then the new one's,
    through the current loop's lag), in ``substeps`` RK4 substeps (docs/simulation.md). The
    plant is edited in place between episodes (``plant.set_params``); nothing is recompiled.

    Args:
        plant: A built :class:`servogym.plants.Plant` (hinge and slide joints only).
        params: The chip's parameter set (e.g. :class:`servogym.chips.pmd.PMDParams`).
        assumptions: The chip's assumption switches; ``None`` for the defaults. The loop
            latency is one of them (``loop_latency``).
        integrator: ``"rk4"`` (default) or ``"euler"`` (one ``mj_step`` of the plant's
            implicitfast integrator per substep: servogym's first tick, half a substep ahead
            of the continuous plant; kept for comparison).
        substeps: Integration substeps per servo tick (>= 1); ``None``:
            :func:`default_substeps` of the chip's servo period (``"rk4"``) or 1 (``"euler"``).
        max_error_counts: Divergence bound on the position error (counts). ``None``: the
            plant's whole travel in counts.
        settle_band_counts: Band for the settling time (counts). ``None``: 0.2 % of the
            move's distance, at least 4 counts.
    """

    def __init__(
        self,
        plant: Any,
        params: Any,
        assumptions: Any = None,
        *,
        integrator: str = "rk4",
        substeps: int | None = None,
        max_error_counts: int | None = None,
        settle_band_counts: float | None = None,
    ) -> None:
        if integrator not in INTEGRATORS:
            raise ValueError(
                f"integrator must be one of {', '.join(map(repr, INTEGRATORS))}; "
                f"got integrator={integrator!r}"
            )
        if substeps is not None and (
            isinstance(substeps, bool) or not isinstance(substeps, int) or substeps < 1
        ):
            raise ValueError(f"substeps must be an integer >= 1; got substeps={substeps!r}")
        model = plant.model
        if model.nq != model.nv:
            raise ValueError(
                "the servo loop integrates hinge and slide joints only (nq == nv); "
                f"got nq={model.nq}, nv={model.nv} for plant {plant.family.name!r}"
            )
        self.plant = plant
        self.integrator = integrator
        self.full_stages = bool(plant.family.position_stages)
        self._substeps = substeps
        self.max_error_counts = max_error_counts
        self.settle_band_counts = settle_band_counts
        self.assumptions = assumptions
        self._work = np.zeros(4 * model.nv + WORK_EXTRA)
        self.set_params(params)
        self._buffers: tuple[np.ndarray, np.ndarray, np.ndarray] | None = None
        self._state = self.chip.new_state()
        self._amp = np.zeros(2)
        self._origin = 0

    def set_params(self, params: Any) -> None:
        """Load a new chip parameter set, as the chip's Update does: the filter state stays.

        A set of another chip family, or another servo period, also resets the state at the
        next :meth:`run` with ``reset=True`` (the only way to change them on hardware).
        """
        chip = family_of(params)
        if getattr(self, "chip", chip) is not chip:
            self._state = chip.new_state()
        self.chip = chip
        self._p, self._a = self.chip.kernel_arrays(params, self.assumptions)
        self.params = params
        self.dt = self.chip.sample_time_s(params)
        self.latency_s = self.chip.loop_latency_s(params, self.assumptions)
        if self._substeps is not None:
            self.substeps = self._substeps
        elif self.integrator == "rk4":
            self.substeps = default_substeps(self.dt)
        else:
            self.substeps = 1
        self.plant.set_timestep(self.dt / self.substeps)

    def _buffers_for(self, n: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        if self._buffers is None or self._buffers[0].shape[0] < n:
            self._buffers = (np.zeros(n, np.int64), np.zeros(n, np.int64), np.zeros(n))
        return self._buffers

    def run(
        self,
        profile: Any,
        *,
        params: Any = None,
        start_counts: int | None = None,
        traces: bool = False,
        reset: bool = True,
    ) -> EpisodeResult:
        """Run one episode along ``profile``.

        Args:
            profile: A chip profile (``position``, ``velocity``, ``acceleration`` int64 arrays
                of one entry per tick).
            params: A parameter set to use from this episode on (optional).
            start_counts: With ``reset``, the value the chip's position register takes at
                the plant's start position; defaults to the profile's ``start``.
            traces: Also return the per-tick traces.
            reset: Reset the plant (``mj_resetData`` at its start position), the filter
                state and the amplifier first. ``False`` continues from where the last
                episode ended (the next move of a sequence): plant, filter, amplifier and the
                encoder's origin all carry over.
        """
        if params is not None:
            self.set_params(params)
        io = self.plant.io
        if reset:
            self.plant.reset()
            self._state[:] = 0
            self._amp[:] = 0.0
            start = int(profile.start if start_counts is None else start_counts)
            q0 = self.plant.data.qpos[io.qpos_adr]
            self._origin = int(np.floor(q0 * io.counts_per_unit)) - start
        pos = np.ascontiguousarray(profile.position, dtype=np.int64)
        vel = np.ascontiguousarray(profile.velocity, dtype=np.int64)
        acc = np.ascontiguousarray(profile.acceleration, dtype=np.int64)
        n = pos.shape[0]
        if n == 0:
            raise ValueError("profile has no ticks; an episode needs at least one")
        start = int(profile.start)
        span = io.travel_max - io.travel_min
        lo = io.travel_min + TRAVEL_MARGIN * span
        hi = io.travel_max - TRAVEL_MARGIN * span
        max_err = self.max_error_counts
        if max_err is None:
            max_err = min(int(span * io.counts_per_unit), 2**31 - 1)
        out_actual, out_command, out_current = self._buffers_for(n)
        m, d = self.plant.model, self.plant.data
        n_run, reason = closed_loop(
            m._address, d._address, d.qpos, d.qvel, d.qacc, d.qacc_warmstart, d.ctrl,
            io.qpos_adr, io.qvel_adr, io.ctrl_index, INTEGRATORS[self.integrator],
            self.substeps, self.full_stages, float(self.dt), float(self.latency_s),
            current_loop_tau(io.current_bandwidth_hz),
            float(io.counts_per_unit), float(lo), float(hi), int(max_err),
            float(io.amp_amps_per_count), float(io.peak_current_a),
            float(io.torque_constant_nm_per_a),
            self._origin, self._amp, self.chip.code, self._state, self._p, self._a,
            pos, vel, acc, out_actual, out_command, out_current, self._work,
        )  # fmt: skip
        metrics = self._metrics(pos, start, out_actual, out_command, n_run, reason)
        tr = None
        if traces:
            commanded = pos[:n_run].copy()
            actual = out_actual[:n_run].copy()
            err = ((commanded - actual + 2**31) % 2**32) - 2**31
            tr = Traces(
                time_s=np.arange(n_run) * self.dt,
                commanded=commanded,
                actual=actual,
                error=err,
                command=out_command[:n_run].copy(),
                current_a=out_current[:n_run].copy(),
            )
        return EpisodeResult(metrics=metrics, traces=tr)

    def _metrics(self, pos, start, actual, command, n_run, reason) -> EpisodeMetrics:
        changes = np.flatnonzero(np.diff(pos, prepend=start) != 0)
        move_end = int(changes[-1]) if changes.size else -1
        target = int(pos[-1])
        distance = ((target - start + 2**31) % 2**32) - 2**31
        direction = int(np.sign(distance)) if move_end >= 0 else 0
        band = self.settle_band_counts
        if band is None:
            band = max(4.0, 0.002 * abs(distance))
        limit = self.chip.motor_limit(self.params)
        vals = compute_metrics(
            pos, actual, command, n_run, move_end, target, direction, self.dt, float(band), limit
        )
        return EpisodeMetrics(
            **{name: float(v) for name, v in zip(METRIC_NAMES, vals, strict=False)},
            settled=bool(vals[-1]),
            diverged=reason != 0,
            divergence_tick=n_run - 1 if reason != 0 else -1,
            divergence_reason=REASONS[int(reason)],
            n_ticks=int(n_run),
            dt=self.dt,
        )
