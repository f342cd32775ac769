"""A multi-axis machine: N axes of one controller closed around one multi-axis plant.

How a controller sequences its axes within a servo cycle is a named, switchable assumption
of its family (:data:`SEQUENCING`, ids ``PMD-M1``, ``PMAC-M1``, ``PK-M1``; docs/chips/*.md,
"Multi-axis"), and the servo period follows the number of enabled axes as each chip
documents (:func:`check_machine`): a PMD chip time-slices its cycle per enabled axis, a PMAC
servos every motor at one servo interrupt, a 6000-series controller updates every axis each
servo sample. :class:`MultiServoLoop` runs one episode of every axis in one compiled call
(``servogym.sim._multiloop``).
"""

from __future__ import annotations

import dataclasses
from collections.abc import Mapping, Sequence
from typing import Any

import mujoco
import numpy as np

from servogym.chips._axes import PERIOD_PER_AXIS, MultiAxisParams
from servogym.chips._family import family_of
from servogym.chips._space import ParameterError
from servogym.sim._loop import INTEGRATORS, REASONS
from servogym.sim._metrics import METRIC_NAMES, EpisodeMetrics, compute_metrics
from servogym.sim._multiloop import multi_closed_loop, work_size
from servogym.sim._runner import TRAVEL_MARGIN, Traces, current_loop_tau, default_substeps


@dataclasses.dataclass(frozen=True)
class Switch:
    """A named, switchable assumption of one chip family's multi-axis behaviour: how it
    sequences its axes (:data:`SEQUENCING`) or takes a contour
    (:data:`servogym.sim._contour.CONTOUR_MODES`).

    Attributes:
        ident: The assumption's id in the family's spec (``"PMD-M1"``).
        what: What is switched, for messages (``"sequencing"``, ``"contour mode"``).
        argument: The argument that picks a choice (``"sequencing"``, ``"mode"``).
        choices: The choices, the default first.
    """

    ident: str
    what: str
    argument: str
    choices: tuple[str, ...]

    @property
    def default(self) -> str:
        """The default choice."""
        return self.choices[0]

    def choose(self, choice: str | None) -> str:
        """``choice``, or the default for ``None``.

        Raises:
            ParameterError: naming the assumption, the choices and the value given.
        """
        if choice is None:
            return self.default
        if choice not in self.choices:
            raise ParameterError(
                f"assumption {self.ident} {self.what} must be one of "
                f"{', '.join(repr(c) for c in self.choices)}; got {self.argument}={choice!r}"
            )
        return choice


SEQUENCING: dict[str, Switch] = {
    name: Switch(ident, "sequencing", "sequencing", choices)
    for name, ident, choices in (
        ("pmd", "PMD-M1", ("in_turn", "simultaneous")),
        ("pmac", "PMAC-M1", ("same_interrupt", "in_turn")),
        ("parker6k", "PK-M1", ("each_sample", "in_turn")),
    )
}
"""Per chip family: the axis-sequencing assumption, default first (docs/chips/*.md):

* PMD ``in_turn``: every encoder latched at the cycle start, the axes computed in turn, so
  axis k's command goes out k per-axis slots (the model's minimum sample time) after axis
  0's; ``simultaneous``: every axis with the single-axis latency.
* PMAC ``same_interrupt``: every motor servoed at the same servo interrupt, each command
  after the single-motor latency (PMAC-A14); ``in_turn``: motor k's command k servo
  computations later, 1 % of the servo period each (the Turbo User Manual's ~1 % of the CPU
  per motor at 2.25 kHz).
* Parker ``each_sample``: both (every) axes updated each servo sample with the single-axis
  latency (PK-A9); ``in_turn``: axis k's command k / n_axes of the period later.
"""

PMAC_MOTOR_FRACTION = 0.01
"""PMAC-M1 ``in_turn``: servo computation per motor as a fraction of the servo period."""


SIMULATOR_LIMIT = (
    "the N-axis loop runs every axis at one servo period, so every axis's filter period "
    "must be equal (on a PMAC: the same Ixx60, servo_cycle_extension, on every motor); a "
    "limit of this simulator, not of the controller"
)
"""The one thing :func:`check_machine` refuses beyond what the controller refuses
(:class:`~servogym.chips.MultiAxisParams`)."""


def machine_axes(params: Any) -> MultiAxisParams:
    """The axes of one controller that the N-axis loop can run, in axis order.

    Args:
        params: A :class:`~servogym.chips.MultiAxisParams`, a mapping of axis (motor)
            numbers to parameter sets, or a sequence of sets (axes 1..n).

    Raises:
        ParameterError: for anything :class:`~servogym.chips.MultiAxisParams` refuses (one
            chip model, at most the axes the model drives, controller-wide registers equal,
            the PMD period for its enabled axes), and for :data:`SIMULATOR_LIMIT`.
    """
    if not isinstance(params, Mapping | Sequence) or isinstance(params, str | bytes):
        raise ParameterError(
            f"params must be parameter sets, one per axis (a sequence, a mapping of axis "
            f"numbers, or a MultiAxisParams); got params={params!r}"
        )
    axes = params if isinstance(params, MultiAxisParams) else MultiAxisParams(params)
    chip = axes.family
    (n0, first), *rest = axes.items()
    for n, p in rest:
        if chip.sample_time_s(p) != chip.sample_time_s(first):
            raise ParameterError(
                f"{SIMULATOR_LIMIT}; {axes.noun} {n0} at {chip.sample_time_s(first)!r} s, "
                f"{axes.noun} {n} at {chip.sample_time_s(p)!r} s"
            )
    return axes


def check_machine(params: Any) -> Any:
    """Check that parameter sets make one controller's axes the N-axis loop runs; returns
    the chip family.

    The controller's rules are :class:`~servogym.chips.MultiAxisParams`'s (one chip model,
    at most :func:`~servogym.chips.max_axes` axes, controller-wide registers equal, on a PMD
    chip ``sample_time_us >= n_axes * min_sample_time_us``: "4 axis * 154 us/axis" [C]);
    the simulator adds one, :data:`SIMULATOR_LIMIT`.

    Args:
        params: As for :func:`machine_axes`.

    Raises:
        ParameterError: naming the parameter, the value and the legal range.
    """
    return machine_axes(params).family


def machine_params(chip_model: str, n_axes: int, values: Any = None) -> list[Any]:
    """Default parameter sets of ``n_axes`` axes of one chip, the period set for them.

    A PMD chip's period is ``n_axes`` times the model's default per-axis sample time; the
    other families' does not depend on the number of axes. ``values`` (a mapping, or one
    mapping per axis) update the defaults.
    """
    from servogym.chips._family import get_chip

    chip, chip_model = get_chip(chip_model)
    model = chip.models[chip_model]
    per_axis = values if isinstance(values, Sequence) else [values or {}] * n_axes
    extra: dict[str, Any] = {}
    if chip.name in PERIOD_PER_AXIS:
        extra["sample_time_us"] = n_axes * model.sample_time_us
    out = [chip.make_params(chip_model, {**extra, **dict(v or {})}) for v in per_axis]
    check_machine(out)
    return out


def axis_latencies(params: Sequence[Any], assumptions: Any = None, sequencing: str | None = None):
    """Each axis's loop latency (s) under the family's sequencing assumption.

    ``min(base + k * stagger, period)`` for axis k, with ``base`` the single-axis latency of
    the ``loop_latency`` assumption and ``stagger`` the sequencing choice's (0 for
    ``simultaneous``, ``same_interrupt``, ``each_sample``).
    """
    params = machine_axes(params).sets
    chip = family_of(params[0])
    choice = SEQUENCING[chip.name].choose(sequencing)
    period = chip.sample_time_s(params[0])
    stagger = 0.0
    if choice == "in_turn":
        if chip.name == "pmd":
            stagger = chip.models[params[0].model].min_sample_time_us * 1e-6
        elif chip.name == "pmac":
            stagger = PMAC_MOTOR_FRACTION * params[0].servo_period_s
        else:
            stagger = period / len(params)
    return [min(chip.loop_latency_s(p, assumptions) + k * stagger, period)
            for k, p in enumerate(params)]  # fmt: skip


@dataclasses.dataclass(frozen=True)
class MultiEpisodeResult:
    """One episode of every axis.

    Attributes:
        metrics: Per axis, its :class:`EpisodeMetrics` (a divergence of any axis ends the
            episode of all; ``diverged`` is set on every axis).
        axis: The axis whose divergence ended the episode, -1 if none.
        traces: Per axis, its :class:`Traces` when asked for.
    """

    metrics: tuple[EpisodeMetrics, ...]
    axis: int = -1
    traces: tuple[Traces, ...] | None = None


class MultiServoLoop:
    """N axes of one controller closed around a multi-axis plant, one compiled call per episode.

    Args:
        plant: A built multi-axis plant (``servogym.plants.MULTI_PLANTS[...].build()``),
            or a single-axis plant (then one axis).
        params: One parameter set per axis, in the plant's axis order: a sequence, a
            mapping of axis numbers or a :class:`~servogym.chips.MultiAxisParams`
            (:func:`check_machine`; :func:`machine_params` gives defaults).
        assumptions: The chip's assumption switches (every axis), ``None``: defaults.
        sequencing: The family's axis-sequencing choice (:data:`SEQUENCING`); ``None``:
            its default.
        integrator, substeps, max_error_counts, settle_band_counts: As for
            :class:`~servogym.sim.ServoLoop` (``max_error_counts`` for every axis).
    """

    def __init__(
        self,
        plant: Any,
        params: Any,
        assumptions: Any = None,
        *,
        sequencing: str | None = None,
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
            raise ValueError(f"the servo loop integrates hinge and slide joints only (nq == nv); "
                             f"got nq={model.nq}, nv={model.nv}")  # fmt: skip
        self.plant = plant
        self.integrator = integrator
        self.full_stages = bool(plant.family.position_stages)
        self.assumptions = assumptions
        self.sequencing = sequencing
        self.max_error_counts = max_error_counts
        self.settle_band_counts = settle_band_counts
        self._substeps = substeps
        n = self.n_axes
        self._work = np.zeros(work_size(model.nv, n))
        self._amp = np.zeros((n, 2))
        self._origin = np.zeros(n, np.int64)
        self.chip: Any = None
        self.set_params(params)
        self._state = np.stack([self.chip.new_state() for _ in range(n)])

    @property
    def ios(self) -> tuple[Any, ...]:
        """The plant's axes as they are now (``plant.ios``, or ``(plant.io,)`` for a
        single-axis plant): read on every episode, so that a plant edited in place
        (``plant.set_params``: a screw lead, a gear ratio, an amplifier) is run as it is."""
        plant = self.plant
        return tuple(plant.ios) if hasattr(plant, "ios") else (plant.io,)

    @property
    def n_axes(self) -> int:
        """Number of axes."""
        return len(self.ios)

    def set_params(self, params: Any) -> None:
        """Load new parameter sets (one per axis, as for :func:`machine_axes`: a sequence,
        a mapping of axis numbers or a :class:`~servogym.chips.MultiAxisParams`, in the
        plant's axis order); the filter states stay.

        Raises:
            ParameterError: for a count of sets other than the plant's axes, or sets that
                :func:`check_machine` refuses; the loop is left unchanged.
        """
        axes = machine_axes(params)
        params = axes.sets
        if len(params) != self.n_axes:
            raise ParameterError(
                f"the {self.plant.family.name!r} plant has {self.n_axes} axes; give one "
                f"parameter set per axis, got {len(params)}"
            )
        chip = axes.family
        if self.chip is not None and chip is not self.chip:
            self._state = np.stack([chip.new_state() for _ in self.ios])
        self.chip = chip
        arrays = [chip.kernel_arrays(p, self.assumptions) for p in params]
        self._p = np.ascontiguousarray(np.stack([x[0] for x in arrays]))
        self._a = np.ascontiguousarray(np.stack([x[1] for x in arrays]))
        self.params = list(params)
        self.dt = chip.sample_time_s(params[0])
        self.latencies_s = axis_latencies(self.params, self.assumptions, self.sequencing)
        if self._substeps is not None:
            self.substeps = self._substeps
        elif self.integrator == "rk4":
            self.substeps = default_substeps(self.dt)
        else:
            self.substeps = 1
        self.plant.set_timestep(self.dt / self.substeps)

    def run(
        self,
        profiles: Sequence[Any],
        *,
        start_counts: Sequence[int] | None = None,
        traces: bool = False,
        reset: bool = True,
        start_qpos: Sequence[float] | None = None,
    ) -> MultiEpisodeResult:
        """Run one episode of every axis along its profile.

        A profile shorter than the longest holds its last position (velocity and
        acceleration 0) to the episode's end.

        Args:
            profiles: One chip profile per axis (``position``, ``velocity``,
                ``acceleration``, ``start``).
            start_counts, traces, reset: As for :meth:`ServoLoop.run`, per axis.
            start_qpos: With ``reset``, each axis's joint position at rest at the start
                (rad or m) instead of the plant's ``io.start_qpos`` (a contour starts on
                its path: ``servogym.sim._contour``).
        """
        ios = self.ios
        n = len(ios)
        if len(profiles) != n:
            raise ValueError(f"give one profile per axis ({n}); got {len(profiles)}")
        if start_counts is not None and len(start_counts) != n:
            raise ValueError(f"give one start_counts per axis ({n}); got {len(start_counts)}")
        ticks = max(len(p.position) for p in profiles)
        if ticks == 0:
            raise ValueError("profiles have no ticks; an episode needs at least one")
        pos = np.zeros((n, ticks), np.int64)
        vel = np.zeros((n, ticks), np.int64)
        acc = np.zeros((n, ticks), np.int64)
        for i, p in enumerate(profiles):
            m = len(p.position)
            pos[i, :m] = p.position
            pos[i, m:] = p.position[-1] if m else int(p.start)
            vel[i, :m] = p.velocity
            acc[i, :m] = p.acceleration
        if reset:
            self.plant.reset()
            if start_qpos is not None:
                if len(start_qpos) != n:
                    raise ValueError(f"give one start_qpos per axis ({n}); got {len(start_qpos)}")
                for io, q in zip(ios, start_qpos, strict=True):
                    self.plant.data.qpos[io.qpos_adr] = float(q)
                mujoco.mj_forward(self.plant.model, self.plant.data)
            self._state[:] = 0
            self._amp[:] = 0.0
            for i, io in enumerate(ios):
                start = int(profiles[i].start if start_counts is None else start_counts[i])
                q0 = self.plant.data.qpos[io.qpos_adr]
                self._origin[i] = int(np.floor(q0 * io.counts_per_unit)) - start
        f = np.array
        lo, hi, max_err = [], [], []
        for io in ios:
            span = io.travel_max - io.travel_min
            lo.append(io.travel_min + TRAVEL_MARGIN * span)
            hi.append(io.travel_max - TRAVEL_MARGIN * span)
            me = self.max_error_counts
            max_err.append(min(int(span * io.counts_per_unit), 2**31 - 1) if me is None else me)
        out_actual = np.zeros((n, ticks), np.int64)
        out_command = np.zeros((n, ticks), np.int64)
        out_current = np.zeros((n, ticks))
        m, d = self.plant.model, self.plant.data
        n_run, reason, axis = multi_closed_loop(
            m._address, d._address, d.qpos, d.qvel, d.qacc, d.qacc_warmstart, d.ctrl,
            f([io.qpos_adr for io in ios], np.int64), f([io.qvel_adr for io in ios], np.int64),
            f([io.ctrl_index for io in ios], np.int64), INTEGRATORS[self.integrator],
            self.substeps, self.full_stages, float(self.dt), f(self.latencies_s, float),
            f([current_loop_tau(io.current_bandwidth_hz) for io in ios], float),
            f([io.counts_per_unit for io in ios], float), f(lo, float), f(hi, float),
            f(max_err, np.int64), f([io.amp_amps_per_count for io in ios], float),
            f([io.peak_current_a for io in ios], float),
            f([io.torque_constant_nm_per_a for io in ios], float), self._origin, self._amp,
            self.chip.code, self._state, self._p, self._a, pos, vel, acc, out_actual,
            out_command, out_current, self._work,
        )  # fmt: skip
        metrics = tuple(
            self._metrics(
                i, pos[i], int(profiles[i].start), out_actual[i], out_command[i], n_run, reason
            )
            for i in range(n)
        )
        tr = None
        if traces:
            tr = tuple(
                Traces(
                    time_s=np.arange(n_run) * self.dt,
                    commanded=pos[i, :n_run].copy(),
                    actual=out_actual[i, :n_run].copy(),
                    error=((pos[i, :n_run] - out_actual[i, :n_run] + 2**31) % 2**32) - 2**31,
                    command=out_command[i, :n_run].copy(),
                    current_a=out_current[i, :n_run].copy(),
                )
                for i in range(n)
            )
        return MultiEpisodeResult(metrics=metrics, axis=int(axis), traces=tr)

    def _metrics(self, i, pos, start, actual, command, n_run, reason) -> EpisodeMetrics:
        changes = np.flatnonzero(np.diff(pos, prepend=start) != 0)
        move_end = int(changes[-1]) if changes.size else -1
        target = int(pos[-1])
        distance = ((target - start + 2**31) % 2**32) - 2**31
        direction = int(np.sign(distance)) if move_end >= 0 else 0
        band = self.settle_band_counts
        if band is None:
            band = max(4.0, 0.002 * abs(distance))
        limit = self.chip.motor_limit(self.params[i])
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


__all__ = [
    "SEQUENCING",
    "SIMULATOR_LIMIT",
    "MultiEpisodeResult",
    "MultiServoLoop",
    "Switch",
    "axis_latencies",
    "check_machine",
    "machine_axes",
    "machine_params",
]
