"""Tuning a multi-axis machine: every axis's registers of one controller in one study.

A ``two-link-arm`` or an ``xy-stage`` (``servogym.plants.MULTI_PLANTS``) is driven by N axes
of one controller. :class:`MachineProblem` is a :class:`~servogym.autotune.TuneProblem` with
the same interface, so the session, the stored study, the Optuna tuners and the default
``safe`` tuner run it unchanged:

* :class:`MachineSpace` searches every axis's registers together. A per-axis register is
  named ``<register>.<axis>``, the axis being the hardware's number (PMAC: the motor
  number), 1 .. N in the plant's axis order: ``kp.1``, ``kp.2``; its Optuna parameter is
  ``u_kp.1``. A register that is one setting of the whole controller (``sample_time_us`` on
  PMD, I7000..I7002 on PMAC, ``ssfr`` on the 6000 series) has one name without an axis.
* :class:`MachineScenario` is what a set is evaluated on: the plant, its tasks (coordinated
  moves and contours, ``servogym.sim._multieval.DEFAULT_TASKS``) and the cost weights;
  :class:`MachineEvaluator` runs it through :class:`~servogym.sim._multieval.MultiEvaluator`
  (cost: the mean task cost, contouring error included, docs/cost.md).
* The constraints are the single-axis tune's, per axis: following error and saturation of
  each axis (``max_following_error.1``, ``saturation_fraction.2``), divergence, and each
  loop's gain and phase margins with the other loops closed (``gain_margin.1``,
  ``phase_margin.2``; ``servogym.sim._multicheck.machine_margins``, the worst over the
  tasks' start and end configurations) at the scenario's own loop latency and sequencing.
  The multi-axis check (``servogym.sim.check_machine_params``) then tries every latency and
  sequencing choice and the load and friction spreads before a set is written.

See docs/autotune.md, "Multi-axis machines".
"""

from __future__ import annotations

import dataclasses
import functools
import math
from collections.abc import Iterable, Mapping, Sequence
from typing import Any

import numpy as np

from servogym.autotune._problem import MARGIN_CONSTRAINT_BOUND, Outcome, TuneProblem, aggregate
from servogym.autotune._space import SearchSpace
from servogym.chips._axes import PERIOD_PER_AXIS, MultiAxisParams, max_axes
from servogym.chips._family import ChipFamily, get_chip
from servogym.chips._space import ParameterError, ParameterSpace, ParamSpec
from servogym.sim._scenario import plant_draw

AXIS_SEP = "."
"""Separator of a register and its axis number in a per-axis name (``kp.2``)."""


def axis_name(register: str, axis: int) -> str:
    """The per-axis name of a register: ``axis_name("kp", 2) == "kp.2"``."""
    return f"{register}{AXIS_SEP}{axis}"


def split_name(name: str) -> tuple[str, int | None]:
    """``"kp.2"`` -> ``("kp", 2)``; a name without an axis -> ``(name, None)``."""
    register, sep, axis = str(name).rpartition(AXIS_SEP)
    if sep and axis.isdigit():
        return register, int(axis)
    return str(name), None


def _shared(family: ChipFamily) -> tuple[str, ...]:
    return tuple(family.registers.controller_wide)


@functools.lru_cache(maxsize=64)
def machine_space(chip_model: str, n_axes: int) -> ParameterSpace:
    """Every register of ``n_axes`` axes of one chip as one :class:`ParameterSpace`.

    Per-axis registers appear once per axis (``kp.1``, ``kp.2``, axes in order, registers
    in the chip's order), controller-wide ones once, without an axis. Defaults are those of
    :func:`servogym.sim.machine_params` (a PMD period of ``n_axes`` slots); a PMD period's
    low end is ``n_axes`` times the model's per-axis slot (the time-sliced cycle).
    """
    from servogym.sim._machine import machine_params

    family, model = get_chip(chip_model)
    space = family.parameter_space(model)
    first = machine_params(model, n_axes)[0]
    shared = _shared(family)
    specs: list[ParamSpec] = []
    for axis in range(1, n_axes + 1):
        for s in space.values():
            if s.name in shared:
                continue
            specs.append(dataclasses.replace(s, name=axis_name(s.name, axis),
                                             default=int(getattr(first, s.name))))  # fmt: skip
    for name in shared:
        s = space[name]
        low = s.low
        if family.name in PERIOD_PER_AXIS and name == "sample_time_us":
            low = max(low, n_axes * family.models[model].min_sample_time_us)
        specs.append(dataclasses.replace(s, low=low, default=int(getattr(first, name))))
    return ParameterSpace(model, specs)


@dataclasses.dataclass(frozen=True)
class MachineSpace(SearchSpace):
    """The registers a tuner searches on a machine, and the values it holds fixed.

    The same interface as :class:`~servogym.autotune.SearchSpace` (unit names, Optuna
    distributions, the unit-cube mapping of each register), over per-axis names.

    Attributes:
        chip_model: Canonical chip model name.
        n_axes: Axes of the controller (numbered 1 .. n_axes).
        names: Searched names (``kp.1`` ...; controller-wide registers without an axis), in
            the order of :func:`machine_space`.
        fixed: Names held at a value (chip units); every other name not searched keeps
            the machine's default.
    """

    n_axes: int = 1

    @classmethod
    def for_machine(
        cls,
        chip_model: str,
        n_axes: int,
        names: Iterable[str] | None = None,
        fixed: Mapping[str, Any] | None = None,
    ) -> MachineSpace:
        """The search space of ``n_axes`` axes of a chip model.

        Args:
            chip_model: A chip model of any family (case-insensitive).
            n_axes: Number of axes, ``1 <= n_axes <= max_axes(chip_model)``.
            names: Names to search: ``kp.2`` (one axis), ``kp`` (every axis), a
                controller-wide register by itself; default every tunable register of
                every axis.
            fixed: Names held at a value, the same way (``{"bias": 0}`` on every axis,
                ``{"bias.2": 0}`` on axis 2; the one naming the axis wins).

        Raises:
            ParameterError: for an unknown register (with close matches), an axis outside
                ``1 .. n_axes``, an axis on a controller-wide register, an illegal value
                (naming ``kp.2``, the value and its legal range), or nothing to search.
        """
        family, model = get_chip(chip_model)
        most = max_axes(model)
        if isinstance(n_axes, bool) or not isinstance(n_axes, int) or not 1 <= n_axes <= most:
            raise ParameterError(
                f"n_axes must satisfy 1 <= n_axes <= {most} (the axes the {model} drives); "
                f"got n_axes={n_axes!r}."
            )
        flat = machine_space(model, n_axes)
        fixed_values: dict[str, int] = {}
        general = [(k, v) for k, v in (fixed or {}).items() if split_name(k)[1] is None]
        specific = [(k, v) for k, v in (fixed or {}).items() if split_name(k)[1] is not None]
        for key, value in general + specific:
            for name in _expand(family, model, n_axes, key):
                fixed_values[name] = flat[name].validate(value, context=model)
        if names is None:
            tunable = {s.name for s in family.parameter_space(model).tunable()}
            wanted = {n for n in flat if split_name(n)[0] in tunable}
        else:
            wanted = {n for key in names for n in _expand(family, model, n_axes, key)}
        searched = tuple(n for n in flat if n in wanted and n not in fixed_values)
        if not searched:
            raise ParameterError(
                f"the search space of {n_axes} axes of the {model} is empty: every searched "
                f"register is fixed (fixed {', '.join(fixed_values) or 'none'}). Search at "
                "least one register."
            )
        return cls(model, searched, fixed_values, n_axes=n_axes)

    @property
    def space(self) -> ParameterSpace:
        """Every name of the machine (:func:`machine_space`)."""
        return machine_space(self.chip_model, self.n_axes)

    @property
    def specs(self) -> list[ParamSpec]:
        """The searched names' specs, in order."""
        space = self.space
        return [space[n] for n in self.names]

    def base_values(self) -> dict[str, int]:
        """Every name's value when nothing is searched: the defaults and the fixed ones."""
        return {**self.space.defaults(), **self.fixed}

    def make_params(self, values: Mapping[str, Any]) -> MultiAxisParams:
        """The validated sets of the axes: the machine's defaults updated with ``values``.

        Raises:
            ParameterError: for an unknown name or an illegal value (naming it and its
                range), or anything :class:`~servogym.chips.MultiAxisParams` refuses.
        """
        space = self.space
        merged = {**space.defaults(), **dict(values)}
        per_axis: list[dict[str, int]] = [{} for _ in range(self.n_axes)]
        for name, value in merged.items():
            v = space[name].validate(value, context=self.chip_model)
            register, axis = split_name(name)
            targets = per_axis if axis is None else [per_axis[axis - 1]]
            for d in targets:
                d[register] = v
        family = self.family
        return MultiAxisParams([family.make_params(self.chip_model, d) for d in per_axis])

    def register_values(self, params: MultiAxisParams | Sequence[Any]) -> dict[str, int]:
        """Every name's value of the axes' sets (axes in order, numbered 1 .. n)."""
        sets = params.sets if isinstance(params, MultiAxisParams) else list(params)
        if len(sets) != self.n_axes:
            raise ParameterError(
                f"a set of this machine has {self.n_axes} axes; got {len(sets)} parameter sets."
            )
        out = {}
        for name in self.space:
            register, axis = split_name(name)
            out[name] = int(getattr(sets[0 if axis is None else axis - 1], register))
        return out

    def describe(self) -> dict[str, Any]:
        """JSON-ready: chip model, axes, searched names with their ranges, fixed values."""
        single = super().describe()
        return {"chip_model": single.pop("chip_model"), "n_axes": self.n_axes, **single}


def _expand(family: ChipFamily, model: str, n_axes: int, key: str) -> list[str]:
    """The machine names one ``--search``/``--fix`` name stands for."""
    space = family.parameter_space(model)
    register, axis = split_name(key)
    if register not in space:
        raise ParameterError(
            f"{space.unknown_message(register)} Name one axis's register as "
            f"<register>{AXIS_SEP}<axis> (axes 1 .. {n_axes}); got {key!r}."
        )
    if register in _shared(family):
        if axis is not None:
            raise ParameterError(
                f"{register} is one setting of the whole controller: name it without an axis "
                f"({register}); got {key!r}."
            )
        return [register]
    if axis is None:
        return [axis_name(register, k) for k in range(1, n_axes + 1)]
    if not 1 <= axis <= n_axes:
        raise ParameterError(
            f"{key}: the axis must satisfy 1 <= axis <= {n_axes} (the machine's axes); "
            f"got axis {axis}."
        )
    return [key]


# ------------------------------------------------------------------------------------------
# Scenario and evaluator
# ------------------------------------------------------------------------------------------


@dataclasses.dataclass(frozen=True)
class MachineScenario:
    """What a machine's parameter sets are evaluated on.

    Attributes:
        chip_model: The controller's chip model (any family; it must drive the plant's axes).
        plant: A multi-axis plant (``"two-link-arm"``, ``"xy-stage"``).
        plant_values: Fixed plant parameters; the rest nominal or drawn.
        randomise: Whether a plant instance is drawn from the family's distribution.
        sample_scale: Width of that distribution (0 .. 1).
        tasks: Coordinated moves and contours; ``()``: the plant's
            :data:`~servogym.sim._multieval.DEFAULT_TASKS`.
        weights: The task cost's weights (:class:`~servogym.sim._multieval.MultiCostWeights`).
        integrator, substeps: As for :class:`~servogym.sim.MultiServoLoop`.
        assumptions: The chip's assumption switches (every axis).
        sequencing: The family's axis-sequencing choice (``servogym.sim.SEQUENCING``).
        contour_mode: The family's contour mode (``servogym.sim._contour.CONTOUR_MODES``).
        plant_ranges: ``name -> (low, high)`` a randomised draw takes a parameter from.
        margins: Whether each evaluation also computes every loop's margins with the other
            loops closed, at the scenario's latency and sequencing (margin constraints).
    """

    chip_model: str
    plant: str
    plant_values: Mapping[str, float] = dataclasses.field(default_factory=dict)
    randomise: bool = False
    sample_scale: float = 1.0
    tasks: tuple[Any, ...] = ()
    weights: Any = None
    integrator: str = "rk4"
    substeps: int | None = None
    assumptions: Any = None
    sequencing: str | None = None
    contour_mode: str | None = None
    plant_ranges: Mapping[str, tuple[float, float]] = dataclasses.field(default_factory=dict)
    margins: bool = False

    def __post_init__(self) -> None:
        from servogym.plants import MULTI_PLANTS
        from servogym.sim._multieval import DEFAULT_TASKS, MultiCostWeights

        _, model = get_chip(self.chip_model)
        object.__setattr__(self, "chip_model", model)
        if self.plant not in MULTI_PLANTS:
            names = ", ".join(MULTI_PLANTS)
            raise ParameterError(
                f"plant must be a multi-axis plant, one of {names}; got plant={self.plant!r}."
            )
        family = MULTI_PLANTS[self.plant]
        family.validate(dict(self.plant_values))
        ranges = family.validate_ranges(
            self.plant_ranges, option="plant_ranges (--plant-range)", fixed=self.plant_values
        )
        object.__setattr__(self, "plant_ranges", ranges)
        most = max_axes(model)
        if family.n_axes > most:
            raise ParameterError(
                f"the {self.plant} has {family.n_axes} axes ({', '.join(family.axes)}) but the "
                f"{model} drives at most {most}; choose a chip model that drives at least "
                f"{family.n_axes} (1 <= axes <= {most} on the {model})."
            )
        if not self.tasks:
            object.__setattr__(self, "tasks", DEFAULT_TASKS[self.plant])
        if self.weights is None:
            object.__setattr__(self, "weights", MultiCostWeights())

    @property
    def family(self) -> Any:
        """The plant family (``servogym.plants.MULTI_PLANTS``)."""
        from servogym.plants import MULTI_PLANTS

        return MULTI_PLANTS[self.plant]

    @property
    def n_axes(self) -> int:
        """The plant's axes."""
        return int(self.family.n_axes)

    @property
    def chip(self) -> ChipFamily:
        """The chip family."""
        return get_chip(self.chip_model)[0]

    def default_params(self) -> MultiAxisParams:
        """The chip's default sets of the machine's axes (:func:`servogym.sim.machine_params`)."""
        from servogym.sim._machine import machine_params

        return MultiAxisParams(machine_params(self.chip_model, self.n_axes))

    def draw_plant(self, rng: np.random.Generator) -> dict[str, float]:
        """A plant instance: nominal (or drawn when ``randomise``), with the fixed values."""
        return plant_draw(self.family, rng, self.randomise, self.sample_scale, self.plant_ranges,
                          self.plant_values)  # fmt: skip


@dataclasses.dataclass(frozen=True)
class MachineEvaluation:
    """One machine's sets on one plant instance, in the figures a tuner reads.

    The fields of :class:`~servogym.sim.Evaluation` a session aggregates, over every axis,
    plus the per-axis safety figures and the contouring error.

    Attributes:
        cost: The mean task cost, or the divergence penalty (finite).
        metrics: Every axis's metrics of every task run.
        diverged: Whether a task's episode ended early.
        max_following_error: Largest following error of any axis (counts).
        saturation_fraction: Largest fraction of ticks at the motor limit of any axis.
        axis_following_error: Per axis, its largest following error (counts).
        axis_saturation: Per axis, its fraction of ticks at the limit over the tasks run.
        max_contour_error_um, rms_contour_error_um: Largest and RMS (worst task)
            contouring error (um).
        run: The :class:`~servogym.sim._multieval.MultiEvaluation`.
        axis_gain_margin_db, axis_phase_margin_deg: Per axis, its loop's smallest margins
            with the other loops closed over the operating configurations (``inf``: not
            computed or unbounded; <= 0 when the machine's loop is unstable).
        stable: Whether the machine's closed loop is stable at every configuration.
        margins: ``None`` (the single-axis margins; the per-axis ones above instead).
    """

    cost: float
    metrics: tuple[Any, ...]
    diverged: bool
    max_following_error: float
    saturation_fraction: float
    axis_following_error: tuple[float, ...]
    axis_saturation: tuple[float, ...]
    max_contour_error_um: float
    rms_contour_error_um: float
    run: Any = None
    axis_gain_margin_db: tuple[float, ...] = ()
    axis_phase_margin_deg: tuple[float, ...] = ()
    stable: bool = True
    margins: Any = None


def machine_evaluation(run: Any, margins: Any = None) -> MachineEvaluation:
    """The figures of a :class:`~servogym.sim._multieval.MultiEvaluation` (and of its
    :class:`~servogym.sim._multicheck.MachineMargins`, when computed)."""
    n = len(run.tasks[0].metrics)
    fe = tuple(float(max(t.metrics[k].max_following_error for t in run.tasks)) for k in range(n))
    sat = []
    for k in range(n):
        ticks = sum(t.metrics[k].n_ticks for t in run.tasks)
        hit = sum(t.metrics[k].saturation_fraction * t.metrics[k].n_ticks for t in run.tasks)
        sat.append(float(hit / ticks) if ticks else 0.0)
    return MachineEvaluation(
        cost=float(run.cost),
        metrics=tuple(m for t in run.tasks for m in t.metrics),
        diverged=bool(run.diverged),
        max_following_error=max(fe),
        saturation_fraction=max(sat),
        axis_following_error=fe,
        axis_saturation=tuple(sat),
        max_contour_error_um=float(max(t.contour.max_um for t in run.tasks)),
        rms_contour_error_um=float(max(t.contour.rms_um for t in run.tasks)),
        run=run,
        axis_gain_margin_db=_worst(margins, "gain_margin_db", n),
        axis_phase_margin_deg=_worst(margins, "phase_margin_deg", n),
        stable=True if margins is None else bool(margins.stable),
    )


def _worst(margins: Any, name: str, n: int) -> tuple[float, ...]:
    if margins is None:
        return (math.inf,) * n
    return tuple(float(min(getattr(per[k].margins, name) for per in margins.analyses))
                 for k in range(n))  # fmt: skip


class MachineEvaluator:
    """Runs a :class:`MachineScenario`'s tasks for any sets on any plant instance of it.

    Args:
        scenario: The scenario (its nominal plant is compiled once, here).
    """

    def __init__(self, scenario: MachineScenario) -> None:
        from servogym.sim._multieval import MultiEvaluator

        self.scenario = scenario
        self.multi = MultiEvaluator(
            scenario.plant, scenario.chip_model, scenario.tasks,
            plant_values=scenario.draw_plant(np.random.default_rng(0)),
            weights=scenario.weights, assumptions=scenario.assumptions,
            sequencing=scenario.sequencing, contour_mode=scenario.contour_mode,
            integrator=scenario.integrator, substeps=scenario.substeps,
        )  # fmt: skip
        self._linear: dict = {}  # continuous models per plant instance and configuration

    @property
    def plant(self) -> Any:
        """The compiled plant (edited in place by each evaluation's plant values)."""
        return self.multi.plant

    def evaluate(
        self, params: Any, plant_values: Mapping[str, float] | None = None, *, traces: bool = False
    ) -> MachineEvaluation:
        """The sets ``params`` (one per axis) on one plant instance (the current one when
        ``None``); with ``scenario.margins``, every loop's margins too."""
        run = self.multi.evaluate(params, plant_values, traces=traces)
        return machine_evaluation(run, self.margins() if self.scenario.margins else None)

    def margins(self) -> Any:
        """Every loop's margins with the others closed, of the sets last evaluated, at the
        tasks' start and end configurations (``servogym.sim._multicheck.machine_margins``,
        at the loop's own latencies)."""
        from servogym.sim._multicheck import machine_margins, operating_configurations

        loop = self.multi.loop
        return machine_margins(
            self.multi.chip, loop.params, loop.assumptions, self.plant,
            operating_configurations(self.multi.commands()), loop.latencies_s,
            cache=self._linear,
        )  # fmt: skip

    def axis_spans(self) -> tuple[int, ...]:
        """Per axis, the largest span of its commanded position over the tasks (counts)."""
        every = self.multi.commands()
        n = len(every[0].distances_counts)
        return tuple(int(max(abs(c.distances_counts[k]) for c in every)) for k in range(n))


# ------------------------------------------------------------------------------------------
# Outcome and problem
# ------------------------------------------------------------------------------------------


@dataclasses.dataclass(frozen=True)
class MachineOutcome(Outcome):
    """An :class:`~servogym.autotune.Outcome` with each axis's safety figures.

    Attributes:
        axis_following_error: Per axis, its largest following error over the tasks and
            the plant instances (counts).
        axis_saturation: Per axis, its largest fraction of ticks at the limit over the
            plant instances.
        max_contour_error_um: Largest contouring error over tasks and instances (um).
        rms_contour_error_um: Largest RMS contouring error of a task (um).
    """

    axis_following_error: tuple[float, ...] = ()
    axis_saturation: tuple[float, ...] = ()
    max_contour_error_um: float = math.nan
    rms_contour_error_um: float = math.nan
    axis_gain_margin_db: tuple[float | None, ...] = ()
    axis_phase_margin_deg: tuple[float | None, ...] = ()

    def to_attrs(self) -> dict[str, Any]:
        """JSON-ready (an unbounded margin as ``None``)."""
        out = super().to_attrs()
        for name in ("axis_gain_margin_db", "axis_phase_margin_deg"):
            out[name] = [x if x is not None and math.isfinite(x) else None for x in out[name]]
        return out

    @classmethod
    def from_attrs(cls, attrs: Mapping[str, Any]) -> MachineOutcome:
        """Inverse of :meth:`to_attrs`."""
        out = super().from_attrs(attrs)

        def floats(xs: Any) -> tuple[float, ...]:
            return tuple(math.inf if x is None else float(x) for x in xs)

        return dataclasses.replace(
            out,
            axis_following_error=floats(out.axis_following_error),
            axis_saturation=floats(out.axis_saturation),
            axis_gain_margin_db=floats(out.axis_gain_margin_db),
            axis_phase_margin_deg=floats(out.axis_phase_margin_deg),
        )


def aggregate_machine(
    values: Mapping[str, int], evaluations: Sequence[MachineEvaluation], mode: str
) -> MachineOutcome:
    """:func:`~servogym.autotune._problem.aggregate` plus each axis's worst figures."""
    base = aggregate(values, evaluations, mode)
    n = len(evaluations[0].axis_following_error)
    gm = tuple(min(e.axis_gain_margin_db[k] for e in evaluations) for k in range(n))
    pm = tuple(min(e.axis_phase_margin_deg[k] for e in evaluations) for k in range(n))
    base = dataclasses.replace(
        base, gain_margin_db=min(gm), phase_margin_deg=min(pm),
        n_unstable=sum(not e.stable for e in evaluations),
    )  # fmt: skip
    return MachineOutcome(
        **{f.name: getattr(base, f.name) for f in dataclasses.fields(Outcome)},
        axis_gain_margin_db=gm,
        axis_phase_margin_deg=pm,
        axis_following_error=tuple(
            max(e.axis_following_error[k] for e in evaluations) for k in range(n)
        ),
        axis_saturation=tuple(max(e.axis_saturation[k] for e in evaluations) for k in range(n)),
        max_contour_error_um=max(e.max_contour_error_um for e in evaluations),
        rms_contour_error_um=max(e.rms_contour_error_um for e in evaluations),
    )


@dataclasses.dataclass(frozen=True)
class MachineProblem(TuneProblem):
    """A machine's tuning problem: a :class:`~servogym.autotune.TuneProblem` whose scenario
    is a :class:`MachineScenario` and whose space is a :class:`MachineSpace`.

    The constraints, per axis: ``max_following_error.<axis>`` (counts over the axis's
    limit: ``constraints.max_following_error``, or 1 % of the axis's largest commanded span
    over the tasks, of the largest axis's for an axis that does not move: the multi-axis
    check's rule), ``saturation_fraction.<axis>``, ``gain_margin.<axis>`` and
    ``phase_margin.<axis>`` (the loop's margins with the others closed, at the scenario's
    own timing, when the constraints have minima), and ``diverged``.
    """

    scenario: MachineScenario
    space: MachineSpace

    def __post_init__(self) -> None:
        if self.space.n_axes != self.scenario.n_axes:
            raise ParameterError(
                f"the search space has {self.space.n_axes} axes but the {self.scenario.plant} "
                f"has {self.scenario.n_axes}; build both for the same machine."
            )
        super().__post_init__()

    @property
    def n_axes(self) -> int:
        """The machine's axes."""
        return self.scenario.n_axes

    def margin_scenario(self) -> MachineScenario:
        """The scenario with every loop's margins computed in each evaluation."""
        return dataclasses.replace(self.scenario, margins=True)

    def make_evaluator(self) -> MachineEvaluator:
        """A new :class:`MachineEvaluator` of the scenario."""
        return MachineEvaluator(self.scenario)

    def aggregate(
        self, values: Mapping[str, int], evaluations: Sequence[MachineEvaluation]
    ) -> MachineOutcome:
        """One set's evaluations on the plant instances as one :class:`MachineOutcome`."""
        return aggregate_machine(values, evaluations, self.robust_mode)

    def following_error_limit(self, evaluator: MachineEvaluator) -> tuple[float, ...]:
        """Per axis, its following-error limit (counts)."""
        if self.constraints.max_following_error is not None:
            return (float(self.constraints.max_following_error),) * self.n_axes
        spans = evaluator.axis_spans()
        return tuple(0.01 * (s if s > 0 else max(spans)) for s in spans)

    def constraint_values(
        self, outcome: MachineOutcome, fe_limit: Sequence[float]
    ) -> dict[str, float]:
        """Optuna constraint values (feasible when every value is <= 0), per axis."""
        c = self.constraints
        out = {}
        for k, limit in enumerate(fe_limit):
            out[axis_name("max_following_error", k + 1)] = outcome.axis_following_error[k] - limit
        for k in range(len(fe_limit)):
            out[axis_name("saturation_fraction", k + 1)] = (
                outcome.axis_saturation[k] - c.max_saturation
            )
        if c.no_divergence:
            out["diverged"] = float(outcome.n_diverged)
        bound = MARGIN_CONSTRAINT_BOUND
        for name, low, got in (
            ("gain_margin", c.min_gain_margin_db, outcome.axis_gain_margin_db),
            ("phase_margin", c.min_phase_margin_deg, outcome.axis_phase_margin_deg),
        ):
            if low is not None:
                for k, v in enumerate(got):
                    out[axis_name(name, k + 1)] = min(max(low - v, -bound), bound)
        return out

    def constraint_scales(self, fe_limit: Sequence[float]) -> dict[str, float]:
        """What the safe tuner divides each constraint value by: each axis's limits."""
        one = super().constraint_scales(1.0)
        out = {}
        for k, limit in enumerate(fe_limit):
            out[axis_name("max_following_error", k + 1)] = max(float(limit), 1.0)
            for name in ("saturation_fraction", "gain_margin", "phase_margin"):
                out[axis_name(name, k + 1)] = one[name]
        return out

    def check(self, params: Any, limits: Any, **kw: Any) -> Any:
        """The multi-axis check of a result before it is written
        (``servogym.sim._multicheck.check_machine_params``)."""
        from servogym.autotune._machinejob import check_machine

        return check_machine(self, params, limits, **kw)

    def describe(self) -> dict[str, Any]:
        """JSON-ready description (stored with the study and in summary.json)."""
        sc = self.scenario
        return {
            "chip_model": sc.chip_model,
            "plant": sc.plant,
            "n_axes": sc.n_axes,
            "axes": list(sc.family.axes),
            "plant_values": dict(sc.plant_values),
            "plant_ranges": {k: list(v) for k, v in sc.plant_ranges.items()},
            "tasks": [describe_task(t) for t in sc.tasks],
            "weights": dataclasses.asdict(sc.weights),
            "integrator": sc.integrator,
            "substeps": sc.substeps,
            "sequencing": sc.sequencing,
            "contour_mode": sc.contour_mode,
            "space": self.space.describe(),
            "n_plants": self.n_plants,
            "robust_mode": self.robust_mode,
            "sample_scale": self.sample_scale,
            "constraints": dataclasses.asdict(self.constraints),
            "objectives": list(self.objectives),
            "seed": self.seed,
        }


def describe_task(task: Any) -> dict[str, Any]:
    """JSON-ready: a task's type and fields (a contour's path with its type)."""
    out: dict[str, Any] = {"type": type(task).__name__}
    for f in dataclasses.fields(task):
        out[f.name] = _plain(getattr(task, f.name))
    return out


def _plain(value: Any) -> Any:
    if dataclasses.is_dataclass(value) and not isinstance(value, type):
        fields = {f.name: _plain(getattr(value, f.name)) for f in dataclasses.fields(value)}
        return {"type": type(value).__name__, **fields}
    if isinstance(value, np.ndarray | tuple | list):
        return [_plain(v) for v in value]
    if isinstance(value, np.generic):
        return value.item()
    return value


__all__ = [
    "AXIS_SEP",
    "MachineEvaluation",
    "MachineEvaluator",
    "MachineOutcome",
    "MachineProblem",
    "MachineScenario",
    "MachineSpace",
    "aggregate_machine",
    "axis_name",
    "machine_space",
    "split_name",
]
