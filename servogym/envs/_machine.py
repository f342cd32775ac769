"""The envs on a multi-axis machine: every axis of one controller around one plant.

The env classes take a single-axis plant family (:data:`servogym.plants.PLANTS`) or a
multi-axis one (:data:`servogym.plants.MULTI_PLANTS`: ``two-link-arm``, ``xy-stage``). On a
multi-axis plant their components are the ones here: a :class:`MachineScenario` (the chip,
the plant's instance distribution and the tasks of :class:`servogym.sim.MultiEvaluator`),
a :class:`MachineCycle` (the gain-scheduling env's pick and place configurations), the
per-axis safe sets the residual action acts around (:data:`MACHINE_CENTERS`), and the
action of every axis side by side (:class:`servogym.envs.AxesActions`, register names
``<register>.<axis number>``, ``kp.2``). With one axis, the envs run exactly as before.
"""

from __future__ import annotations

import dataclasses
import functools
import itertools
from collections.abc import Mapping, Sequence
from typing import Any

import numpy as np

from servogym.chips._family import get_chip
from servogym.plants import MULTI_PLANTS, PEAK_HEADROOM, MotorFeasibilityError, get_plant
from servogym.sim._multieval import DEFAULT_TASKS, MultiCostWeights
from servogym.sim._scenario import MoveSpec, plant_draw

AXIS_SEPARATOR = "."
"""Between a register's name and its axis number in the names of a multi-axis action
(``kp.1``, ``kp.2``; PMAC ``proportional_gain.2``): the hardware's axis (motor) numbers, 1
first, as ``servogym tune`` names a machine's registers (``servogym.autotune._machine``)."""


def is_machine(plant: str) -> bool:
    """Whether ``plant`` names a multi-axis plant family."""
    return isinstance(plant, str) and plant in MULTI_PLANTS


def plant_family(plant: str) -> Any:
    """The single-axis or multi-axis plant family called ``plant`` (an unknown name raises
    as :func:`servogym.plants.get_plant`)."""
    return MULTI_PLANTS[plant] if is_machine(plant) else get_plant(plant)


def axis_register(number: int, name: str) -> str:
    """A register's name on axis ``number`` (1 first) of a machine: ``axis_register(2, "kp")``
    is ``"kp.2"``."""
    return f"{name}{AXIS_SEPARATOR}{number}"


def split_register(key: str, axes: Sequence[str], what: str) -> tuple[int | None, str]:
    """``"kp.2"`` -> ``(1, "kp")`` (the axis's index, 0 first); a plain name -> ``(None, name)``.

    Raises:
        ValueError: naming ``what``, for an axis number the machine does not have.
    """
    name, sep, number = str(key).rpartition(AXIS_SEPARATOR)
    if not sep or not number.isdigit():
        return None, str(key)
    k = int(number)
    if not 1 <= k <= len(axes):
        listed = ", ".join(f"{i} ({a})" for i, a in enumerate(axes, start=1))
        raise ValueError(
            f"{what} names axis {k} in {key!r}; the axes are {listed} (names are "
            f"'<register>{AXIS_SEPARATOR}<axis number>')."
        )
    return k - 1, name


def per_axis(
    values: Mapping[str, Any] | Sequence[Mapping[str, Any] | None] | None,
    axes: Sequence[str],
    what: str,
) -> list[dict[str, Any]]:
    """``values`` split by axis.

    A sequence gives one mapping per axis; in a mapping, a name ``<register>.<axis number>``
    (``kp.2``) goes to that axis and a plain register name to every axis (an axis's own entry
    wins).

    Raises:
        ValueError: naming ``what``, for a sequence of another length or an unknown axis.
    """
    n = len(axes)
    if values is None:
        return [{} for _ in axes]
    if isinstance(values, Sequence) and not isinstance(values, str | bytes):
        if len(values) != n:
            raise ValueError(
                f"{what} must give one mapping per axis ({n}: {', '.join(axes)}); got "
                f"{len(values)}."
            )
        return [dict(v or {}) for v in values]
    if not isinstance(values, Mapping):
        raise ValueError(
            f"{what} must be a mapping of register values (a name '<register>.<axis number>' "
            f"sets one axis, a plain name every axis) or one mapping per axis; got "
            f"{what}={values!r}."
        )
    out: list[dict[str, Any]] = [{} for _ in axes]
    qualified = []
    for key, value in values.items():
        k, name = split_register(key, axes, what)
        if k is None:
            for d in out:
                d[key] = value
        else:
            qualified.append((k, name, value))
    for k, name, value in qualified:
        out[k][name] = value
    return out


MACHINE_REGISTERS: dict[str, dict[str, int]] = {
    "pmac": {"fatal_following_error_limit": 8388607},
}
"""Per chip family, registers the machine envs hold away from the chip's defaults on every
axis (not in the action). PMAC: Ixx11, the fatal following error limit, at its legal
maximum (524287 counts): the default 32000 (1/16 count, 2000 counts) is 2 mrad on the
two-link arm's shoulder encoder (1.04e6 counts/rad through its 50:1 gear) and 0.15 mm on
the stage's X screw (1.3e7 counts/m), so every move of either machine, whatever the gains,
killed the motors (a chip motion error) at its first few ticks."""


def machine_values(chip_model: str, values: Sequence[Mapping[str, Any]]) -> list[dict[str, Any]]:
    """Per axis, ``values`` over the family's :data:`MACHINE_REGISTERS`."""
    held = MACHINE_REGISTERS.get(get_chip(chip_model)[0].name, {})
    return [{**held, **dict(v)} for v in values]


def machine_fixed(chip_model: str, n_axes: int) -> dict[str, int]:
    """The registers a machine of ``n_axes`` holds away from the chip's defaults: a PMD
    chip's ``sample_time_us``, time-sliced per enabled axis (``servogym.sim.machine_params``),
    and the family's :data:`MACHINE_REGISTERS`."""
    from servogym.sim._machine import machine_params

    chip, model = get_chip(chip_model)
    space = chip.parameter_space(model)
    machine = machine_params(model, n_axes, machine_values(model, [{}] * n_axes))[0]
    default = chip.make_params(model)
    return {n: getattr(machine, n) for n in space if getattr(machine, n) != getattr(default, n)}


@dataclasses.dataclass(frozen=True)
class MachineScenario:
    """What a multi-axis env evaluates: the single-axis :class:`servogym.sim.Scenario`'s
    counterpart on a machine (``two-link-arm``, ``xy-stage``).

    Attributes:
        chip_model: Chip model name (any family); one controller drives every axis.
        plant: Multi-axis plant family name.
        plant_values: Fixed plant parameters; the rest are nominal or drawn.
        randomise: Whether each episode draws a plant instance.
        sample_scale: Width of the distribution (0 = nominal, 1 = the default sampling
            ranges).
        plant_ranges: ``name -> (low, high)`` the draws take a parameter from.
        tasks: The tasks of :class:`~servogym.sim.MultiEvaluator`; ``()``: the plant's
            :data:`~servogym.sim.DEFAULT_TASKS`.
        weights: The task cost's weights (docs/cost.md, "Multi-axis machines").
        integrator, substeps, assumptions: As for :class:`~servogym.sim.MultiServoLoop`.
        motor_check: Refuse, on construction, a box of instances (:meth:`box`) whose
            motors cannot run the plant's default moves (:func:`machine_need`).
    """

    chip_model: str
    plant: str
    plant_values: Mapping[str, float] = dataclasses.field(default_factory=dict)
    randomise: bool = False
    sample_scale: float = 1.0
    plant_ranges: Mapping[str, tuple[float, float]] = dataclasses.field(default_factory=dict)
    tasks: tuple[Any, ...] = ()
    weights: MultiCostWeights = dataclasses.field(default_factory=MultiCostWeights)
    integrator: str = "rk4"
    substeps: int | None = None
    assumptions: Any = None
    motor_check: bool = True

    def __post_init__(self) -> None:
        _, model = get_chip(self.chip_model)
        object.__setattr__(self, "chip_model", model)
        family = self.family
        family.validate(dict(self.plant_values))
        ranges = family.validate_ranges(
            self.plant_ranges, option="plant_range", fixed=self.plant_values
        )
        object.__setattr__(self, "plant_ranges", ranges)
        if not self.tasks:
            object.__setattr__(self, "tasks", DEFAULT_TASKS[self.plant])
        if self.motor_check:
            machine_need(self, self.box(), self.moves, "the plant's default moves")

    @property
    def chip(self) -> Any:
        """The chip family."""
        return get_chip(self.chip_model)[0]

    @property
    def family(self) -> Any:
        """The multi-axis plant family."""
        return MULTI_PLANTS[self.plant]

    @property
    def axes(self) -> tuple[str, ...]:
        """The axis names, in axis order."""
        return tuple(self.family.axes)

    @property
    def moves(self) -> tuple[tuple[MoveSpec, ...], ...]:
        """Per axis, the plant family's default moves (joint units)."""
        return self.family.default_moves()

    def default_params(self) -> list[Any]:
        """The chip's default set on every axis, the period set for the axes
        (``servogym.sim.machine_params``) and the family's :data:`MACHINE_REGISTERS`."""
        return self.params(None)

    def params(self, values: Any = None) -> list[Any]:
        """One parameter set per axis: the machine's defaults updated with ``values`` (as
        :func:`per_axis` splits them).

        Raises:
            ParameterError: for an illegal value or sets one controller cannot hold.
        """
        from servogym.sim._machine import machine_params

        split = machine_values(self.chip_model, per_axis(values, self.axes, "params"))
        return machine_params(self.chip_model, len(self.axes), split)

    def draw_plant(self, rng: np.random.Generator) -> dict[str, float]:
        """A plant instance, as :meth:`servogym.sim.Scenario.draw_plant` draws one."""
        return plant_draw(self.family, rng, self.randomise, self.sample_scale, self.plant_ranges,
                          self.plant_values)  # fmt: skip

    def box(self) -> dict[str, tuple[float, float]]:
        """The ranges a draw takes the parameters from (the fixed ones left out)."""
        if not self.randomise:
            return dict(self.plant_ranges)
        box = self.family.sample_bounds(self.sample_scale, ranges=self.plant_ranges)
        for name in self.plant_values:
            box.pop(name, None)
        return box


@dataclasses.dataclass(frozen=True)
class MachineCycle:
    """The pick-and-place cycle of a gain-scheduling episode on a machine.

    As :class:`~servogym.envs.PickAndPlace`: even moves (0, 2, ...) run empty to a pick
    configuration, odd moves carry the part to a place configuration; one part value per
    episode, log-uniform over ``part``. Each target configuration is drawn per axis,
    uniformly over that axis's range (joint units); every move is a coordinated move
    (``servogym.sim.CoordinatedSpec``) at each axis's velocity and acceleration limits of
    the plant family's first default move.

    Attributes:
        param: The plant parameter the part changes.
        empty: Its value without a part (> 0: the observation maps it on a log scale).
        part: Range of its value with the part.
        pick: Per axis, ``(low, high)`` of the pick configurations (rad or m).
        place: Per axis, ``(low, high)`` of the place configurations (rad or m).
    """

    param: str
    empty: float
    part: tuple[float, float]
    pick: tuple[tuple[float, float], ...]
    place: tuple[tuple[float, float], ...]

    def span(self, k: int) -> tuple[float, float]:
        """Axis ``k``'s lowest and highest target."""
        return min(self.pick[k][0], self.place[k][0]), max(self.pick[k][1], self.place[k][1])


MACHINE_CYCLES: dict[str, MachineCycle] = {
    "two-link-arm": MachineCycle(
        "payload_kg",
        empty=0.05,
        part=(0.5, 2.0),
        pick=((-1.0, -0.2), (-2.0, 2.0)),
        place=((0.2, 1.0), (-2.0, 2.0)),
    ),
    "xy-stage": MachineCycle(
        "payload_kg",
        empty=0.2,
        part=(2.0, 10.0),
        pick=((-0.12, -0.02), (-0.08, 0.08)),
        place=((0.02, 0.12), (-0.08, 0.08)),
    ),
}
"""The gain-scheduling cycle of each multi-axis plant. Two-link arm: the payload from an
empty gripper (0.05 kg) to 0.5-2 kg (the default sampling range's end), the shoulder picking
on one side and placing on the other, the elbow anywhere in +-2 rad, so that the shoulder's
inertia changes several-fold with the elbow angle from move to move. X-Y stage: 0.2 kg to
2-10 kg, X picking on one side and placing on the other, Y anywhere in +-80 mm."""

MACHINE_CENTERS: dict[tuple[str, str], tuple[dict[str, int], ...]] = {
    # servogym/Schedule-PMAC-TwoLinkArm-v1: 4.74 per move at the zero action (defaults: 81.7)
    ("pmac", "two-link-arm"): (
        {
            "notch_n1": 0,
            "notch_n2": 0,
            "notch_d1": 0,
            "notch_d2": 0,
            "proportional_gain": 28152,
            "derivative_gain": 1664,
            "velocity_ff": 1673,
            "integral_gain": 215092,
            "acceleration_ff": 7211,
            "friction_ff": 0,
        },
        {
            "notch_n1": 0,
            "notch_n2": 0,
            "notch_d1": 0,
            "notch_d2": 0,
            "proportional_gain": 28152,
            "derivative_gain": 1664,
            "velocity_ff": 1673,
            "integral_gain": 215092,
            "acceleration_ff": 7211,
            "friction_ff": 0,
        },
    ),
    # servogym/Schedule-PMAC-XyStage-v1: 20.5 per move at the zero action (defaults: 100)
    ("pmac", "xy-stage"): (
        {
            "notch_n1": 0,
            "notch_n2": 0,
            "notch_d1": 0,
            "notch_d2": 0,
            "proportional_gain": 118153,
            "derivative_gain": 1664,
            "velocity_ff": 1665,
            "integral_gain": 215093,
            "acceleration_ff": 7211,
            "friction_ff": 0,
        },
        {
            "notch_n1": 0,
            "notch_n2": 0,
            "notch_d1": 0,
            "notch_d2": 0,
            "proportional_gain": 118153,
            "derivative_gain": 1664,
            "velocity_ff": 1665,
            "integral_gain": 215093,
            "acceleration_ff": 7211,
            "friction_ff": 0,
        },
    ),
    # servogym/Schedule-PMD-TwoLinkArm-v1: 16 per move at the zero action (defaults: 100)
    ("pmd", "two-link-arm"): (
        {
            "kp": 721,
            "ki": 1213,
            "kd": 1134,
            "kvff": 2,
            "kaff": 3883,
            "kout": 558,
            "integration_limit": 398918242,
            "derivative_time": 8,
            "bias": 18283,
        },
        {
            "kp": 960,
            "ki": 1840,
            "kd": 2251,
            "kvff": 20,
            "kaff": 14646,
            "kout": 587,
            "integration_limit": 2569,
            "derivative_time": 3,
            "bias": -1082,
        },
    ),
    # servogym/Schedule-PMD-XyStage-v1: 3.58 per move at the zero action (defaults: 83.3)
    ("pmd", "xy-stage"): (
        {
            "kp": 954,
            "ki": 4423,
            "kd": 14490,
            "kvff": 0,
            "kaff": 3229,
            "kout": 1305,
            "integration_limit": 11042,
            "derivative_time": 1,
            "bias": 296,
        },
        {
            "kp": 954,
            "ki": 4423,
            "kd": 14490,
            "kvff": 0,
            "kaff": 3229,
            "kout": 1305,
            "integration_limit": 11042,
            "derivative_time": 1,
            "bias": 296,
        },
    ),
    # servogym/Schedule-Parker6K-TwoLinkArm-v1: 0.779 per move at the zero action (defaults: 90.3)
    ("parker6k", "two-link-arm"): (
        {"sgp": 852624, "sgi": 8598642, "sgv": 1161, "sgvf": 1188, "sgaf": 155},
        {"sgp": 852624, "sgi": 8598642, "sgv": 1161, "sgvf": 1188, "sgaf": 155},
    ),
    # servogym/Schedule-Parker6K-XyStage-v1: 4.32 per move at the zero action (defaults: 100)
    ("parker6k", "xy-stage"): (
        {"sgp": 1147826, "sgi": 9999999, "sgv": 2387, "sgvf": 2387, "sgaf": 166},
        {"sgp": 1147826, "sgi": 9999999, "sgv": 2387, "sgvf": 2387, "sgaf": 166},
    ),
}
"""(chip family, multi-axis plant) -> per axis, the register values of a safe set: the zero
action of the Schedule ids' residual action. Each is the best fixed set of a search on the
id's own episodes (``experiments/machine_schedule_centres.py``: TPE from the chip defaults and
the family's servobench-v1 best-known sets put on every axis; the mean cost per move of two
seeded 4-move episodes; results in ``experiments/results/schedule/machine_centres.jsonl``).
Where both axes hold one set, a servobench set put on both axes was the best found."""

MACHINE_CENTERS_V2: dict[tuple[str, str], tuple[dict[str, int], ...]] = {
    # servogym/Schedule-PMAC-TwoLinkArm-v1: --sets ff-t0.05:held:margins
    ("pmac", "two-link-arm"): (
        {
            "notch_n1": 0,
            "notch_n2": 0,
            "notch_d1": 0,
            "notch_d2": 0,
            "proportional_gain": 25512,
            "derivative_gain": 2725,
            "velocity_ff": 2737,
            "integral_gain": 147889,
            "acceleration_ff": 9707,
            "friction_ff": 0,
        },
        {
            "notch_n1": 0,
            "notch_n2": 0,
            "notch_d1": 0,
            "notch_d2": 0,
            "proportional_gain": 20452,
            "derivative_gain": 1664,
            "velocity_ff": 1638,
            "integral_gain": 191915,
            "acceleration_ff": 6151,
            "friction_ff": 0,
        },
    ),
    # servogym/Schedule-PMAC-XyStage-v1: --sets ff-t0.05:held:margins
    ("pmac", "xy-stage"): (
        {
            "notch_n1": 0,
            "notch_n2": 0,
            "notch_d1": 0,
            "notch_d2": 0,
            "proportional_gain": 36306,
            "derivative_gain": 1274,
            "velocity_ff": 1193,
            "integral_gain": 661407,
            "acceleration_ff": 5796,
            "friction_ff": 0,
        },
        {
            "notch_n1": 0,
            "notch_n2": 0,
            "notch_d1": 0,
            "notch_d2": 0,
            "proportional_gain": 134896,
            "derivative_gain": 2293,
            "velocity_ff": 2344,
            "integral_gain": 215985,
            "acceleration_ff": 10468,
            "friction_ff": 0,
        },
    ),
    # servogym/Schedule-PMD-TwoLinkArm-v1: --sets margins:oracle:cycle-robust-150:robust
    ("pmd", "two-link-arm"): (
        {
            "kp": 701,
            "ki": 1937,
            "kd": 3160,
            "kvff": 0,
            "kaff": 2828,
            "kout": 639,
            "integration_limit": 134335376,
            "derivative_time": 3,
            "bias": 22683,
        },
        {
            "kp": 597,
            "ki": 768,
            "kd": 5481,
            "kvff": 27,
            "kaff": 19037,
            "kout": 415,
            "integration_limit": 150,
            "derivative_time": 2,
            "bias": 0,
        },
    ),
    # servogym/Schedule-PMD-XyStage-v1: --sets margins
    ("pmd", "xy-stage"): (
        {
            "kp": 956,
            "ki": 4789,
            "kd": 14421,
            "kvff": 0,
            "kaff": 3229,
            "kout": 647,
            "integration_limit": 11042,
            "derivative_time": 1,
            "bias": 296,
        },
        {
            "kp": 1241,
            "ki": 4507,
            "kd": 26812,
            "kvff": 0,
            "kaff": 3229,
            "kout": 1787,
            "integration_limit": 11042,
            "derivative_time": 1,
            "bias": 296,
        },
    ),
    # servogym/Schedule-Parker6K-TwoLinkArm-v1: --sets ff-t0.05:margins
    ("parker6k", "two-link-arm"): (
        {"sgp": 906028, "sgi": 9999999, "sgv": 1976, "sgvf": 1665, "sgaf": 217},
        {"sgp": 869590, "sgi": 9999999, "sgv": 1453, "sgvf": 1144, "sgaf": 124},
    ),
    # servogym/Schedule-Parker6K-XyStage-v1: --sets ff-t0.05:margins-t0.1-w5
    ("parker6k", "xy-stage"): (
        {"sgp": 1408774, "sgi": 9999999, "sgv": 2608, "sgvf": 2676, "sgaf": 145},
        {"sgp": 1187463, "sgi": 9999999, "sgv": 5180, "sgvf": 5151, "sgaf": 114},
    ),
}
"""(chip family, multi-axis plant) -> per axis, the register values of the ``-v2`` Schedule
ids' safe centre (``ScheduleEnv(machine_centers=2)``): a set that passes the multi-axis
check (``servogym check``'s cases: the reference integration, every loop-latency and
sequencing choice, the load at +-20 % and the friction at +-50 %, each with its closed-loop
stability, margins, following error and saturation) at three operating points of the id's
cycle (the payload at the empty gripper, the log-middle and the part range's high end,
the other parameters nominal). Each comment names the ``--sets`` of
``experiments/machine_centre_check.py`` whose lines in
``experiments/results/schedule/machine_centre_checks.jsonl`` hold the check
(``tests/envs/test_multi_envs.py`` holds every centre to those lines): ``margins``, the
``-v1`` centre moved into the check's margins at the three points at once by a search on
the check's linear analysis; ``held:``, checked with the machine's held registers
(:data:`MACHINE_REGISTERS`); ``ff:``, with the feed-forward registers then fitted on the
check's tasks until the following error cleared its limit (the loop gains, and so the
margins, kept); ``margins:oracle:cycle-robust-150:robust``, the two-link arm's robust set
of ``experiments/schedule_oracle.py`` tuned over the cycle and moved into the margins."""

MACHINE_CENTER_VERSIONS: dict[int, dict[tuple[str, str], tuple[dict[str, int], ...]]] = {
    1: MACHINE_CENTERS,
    2: MACHINE_CENTERS_V2,
}
"""``machine_centers`` of :class:`~servogym.envs.ScheduleEnv` -> the table of machine
centres it takes: 1, :data:`MACHINE_CENTERS` (the ``-v1`` ids); 2, :data:`MACHINE_CENTERS_V2`
(the ``-v2`` ids)."""


def cycle_sweep(
    starts: Sequence[float], moves: Sequence[Sequence[MoveSpec]], cycle: MachineCycle
) -> tuple[tuple[MoveSpec, ...], ...]:
    """Per axis, two moves from its start position (``starts``, rad or m) over the cycle's
    whole span, at the limits of the axis's first move in ``moves``: what
    :func:`machine_need` evaluates the plant along."""
    out = []
    for k, (start, axis_moves) in enumerate(zip(starts, moves, strict=True)):
        lo, hi = cycle.span(k)
        v, a = axis_moves[0].max_velocity, axis_moves[0].max_acceleration
        out.append((MoveSpec(lo - start, v, a), MoveSpec(hi - lo, v, a)))
    return tuple(out)


def machine_need(
    scenario: MachineScenario,
    box: Mapping[str, tuple[float, float]],
    moves: tuple[tuple[MoveSpec, ...], ...],
    what: str,
) -> tuple[Any, ...]:
    """Per axis, the largest motor need over every corner of ``box`` (the other parameters
    at the scenario's fixed or nominal values) along ``moves``
    (``servogym.plants._multi.required_peak_efforts``); computed once per process for a
    plant, box and moves.

    Raises:
        MotorFeasibilityError: in one line, naming the axis, the corner, the need and the
            motor's peak, when an axis needs more than :data:`PEAK_HEADROOM` of its peak.
    """
    base = scenario.family.validate(dict(scenario.plant_values))
    needs, corners = _worst_needs(
        scenario.plant,
        tuple(sorted(base.items())),
        tuple(sorted((k, tuple(v)) for k, v in box.items())),
        moves,
    )
    for need, corner in zip(needs, corners, strict=True):
        if not need.feasible:
            at = ", ".join(f"{k}={v:.6g}" for k, v in corner.items()) or "its nominal values"
            raise MotorFeasibilityError(
                f"the {need.family} motor cannot move {what} at {at}: it needs "
                f"{need.total_nm:.3g} of its {need.peak_nm:.3g} peak (N*m; N on a linear "
                f"motor), {need.fraction:.0%}, where at most {PEAK_HEADROOM:.0%} leaves the "
                f"feedback its share; narrow the ranges or fix the heavy values."
            )
    return needs


@functools.lru_cache(maxsize=64)
def _worst_needs(plant: str, base: tuple, box: tuple, moves: tuple) -> tuple[tuple, tuple]:
    from servogym.plants._multi import required_peak_efforts

    family = MULTI_PLANTS[plant]
    values = dict(base)
    built = family.build(values)
    names = [n for n, _ in box]
    worst: list[Any] = [None] * family.n_axes
    corners: list[dict[str, float]] = [{} for _ in range(family.n_axes)]
    for corner in itertools.product(*[sorted(set(r)) for _, r in box]):
        at = dict(zip(names, corner, strict=True))
        needs = required_peak_efforts(family, {**values, **at}, moves, plant=built)
        for k, need in enumerate(needs):
            if worst[k] is None or need.fraction > worst[k].fraction:
                worst[k], corners[k] = need, at
    return tuple(worst), tuple(corners)


def worst_need(needs: Sequence[Any]) -> Any:
    """The axis need with the largest share of its motor's peak."""
    return max(needs, key=lambda n: n.fraction)


def axis_runs(label: str, run: Any, axes: Sequence[str]) -> list[tuple[str, Any]]:
    """Per axis, a labelled run that ``servogym.sim._plot.response_rgb`` draws: from a
    :class:`~servogym.sim.MultiEpisodeResult` (one move) or a
    :class:`~servogym.sim.MultiEvaluation` (its tasks one after the other)."""
    from types import SimpleNamespace

    from servogym.sim._runner import EpisodeResult

    episodes = [t for t in getattr(run, "tasks", ())] or [run]
    return [
        (
            f"{label}, {axis}",
            SimpleNamespace(results=[EpisodeResult(e.metrics[k], e.traces[k]) for e in episodes]),
        )
        for k, axis in enumerate(axes)
    ]


def make_evaluator(scenario: Any) -> Any:
    """The evaluator of an env's scenario: :class:`servogym.sim.Evaluator` of a
    :class:`~servogym.sim.Scenario`, :class:`servogym.sim.MultiEvaluator` of a
    :class:`MachineScenario` (its plant compiled once, at the instance of seed 0)."""
    from servogym.sim import Evaluator
    from servogym.sim._multieval import MultiEvaluator

    if not isinstance(scenario, MachineScenario):
        return Evaluator(scenario)
    return MultiEvaluator(
        scenario.plant,
        scenario.chip_model,
        scenario.tasks,
        plant_values=scenario.draw_plant(np.random.default_rng(0)),
        weights=scenario.weights,
        assumptions=scenario.assumptions,
        integrator=scenario.integrator,
        substeps=scenario.substeps,
    )


def evaluation_info(ev: Any) -> dict[str, float]:
    """What a Tune step's ``info`` reports of an evaluation beyond its cost: the largest
    following error (counts) and the share of ticks at the motor limit; of a
    :class:`~servogym.sim.MultiEvaluation`, over every task and axis, and its largest
    contouring error (``max_contour_error_um``)."""
    if not hasattr(ev, "tasks"):
        return {
            "max_following_error": ev.max_following_error,
            "saturation_fraction": ev.saturation_fraction,
        }
    metrics = [m for t in ev.tasks for m in t.metrics]
    ticks = sum(m.n_ticks for m in metrics)
    return {
        "max_following_error": max(m.max_following_error for m in metrics),
        "saturation_fraction": sum(m.saturation_fraction * m.n_ticks for m in metrics)
        / max(ticks, 1),
        "max_contour_error_um": float(ev.max_contour_error_um),
    }


def run_move(loop: Any, planned: Any, *, reset: bool, settle_s: float) -> tuple[Any, np.ndarray]:
    """Run one move with traces; return the run and its observed features.

    ``planned`` is a chip profile on a :class:`~servogym.sim.ServoLoop` (the features are
    :data:`~servogym.envs.MOVE_FEATURES`), or a machine's
    :class:`~servogym.sim._contour.Commands` on a :class:`~servogym.sim.MultiServoLoop`
    (every axis's features, in axis order; with ``reset`` the machine starts at rest at the
    commands' start positions).
    """
    from servogym.envs._observe import move_features
    from servogym.sim._runner import EpisodeResult

    if not hasattr(planned, "profiles"):
        r = loop.run(planned, traces=True, reset=reset)
        distance = int(planned.position[-1]) - int(planned.start)
        return r, move_features(r, planned, distance, settle_s)
    r = loop.run(
        list(planned.profiles), start_counts=planned.start_counts,
        start_qpos=planned.start_qpos if reset else None, traces=True, reset=reset,
    )  # fmt: skip
    feats = [
        move_features(EpisodeResult(m, tr), p, int(p.position[-1]) - int(p.start), settle_s)
        for m, tr, p in zip(r.metrics, r.traces, planned.profiles, strict=True)
    ]
    return r, np.concatenate(feats)
