"""The gain-scheduling env: a parameter set per move while the operating point changes."""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Mapping
from typing import Any, ClassVar

import gymnasium as gym
import numpy as np
from gymnasium import spaces

from servogym.envs._actions import DEFAULT_RESIDUAL_SCALE, make_action_map
from servogym.envs._common import (
    DEFAULT_REWARD_SCALE,
    check_reward_scale,
    make_scenario,
    markdown_table,
    options_plant_values,
)
from servogym.envs._machine import (
    MACHINE_CENTER_VERSIONS,
    MACHINE_CYCLES,
    MachineCycle,
    axis_register,
    axis_runs,
    cycle_sweep,
    is_machine,
    machine_need,
    plant_family,
    run_move,
    worst_need,
)
from servogym.envs._observe import MOVE_FEATURES, OBS_CLIP, clip
from servogym.plants import get_plant
from servogym.sim import DIVERGENCE_PENALTY, Scenario, ServoLoop, move_cost
from servogym.sim._contour import contour_error
from servogym.sim._machine import MultiServoLoop
from servogym.sim._multieval import CoordinatedSpec, task_cost


@dataclasses.dataclass(frozen=True)
class PickAndPlace:
    """The operating-point change of a scheduling episode: a pick-and-place cycle.

    The axis starts empty at 0, moves to a pick position below (or before) 0, picks a part
    up, carries it to a place position above 0, puts it down, and goes back for the next.
    Even moves (0, 2, ...) run empty towards a pick position, odd moves carry the part. One
    part value is drawn per episode, log-uniformly over ``part``.

    Attributes:
        param: The plant parameter the part changes (``payload_kg``, ``load_inertia_kgm2``).
        empty: Its value without a part; ``None``: the parameter's legal low.
        part: Range of its value with the part; ``None``: the scenario's ``plant_ranges``
            for the parameter (the env's ``plant_range=``), else its default sampling range
            (``PlantParam.sample_range``: what the default motor can move).
        reach: Pick and place positions are drawn uniformly at ``reach[0] .. reach[1]``
            times the scenario's first move distance from 0, below and above it.
    """

    param: str
    empty: float | None = None
    part: tuple[float, float] | None = None
    reach: tuple[float, float] = (0.2, 1.2)


CYCLES: dict[str, PickAndPlace] = {
    "vertical-axis": PickAndPlace("payload_kg"),  # gravity and inertia change several-fold
    "arm": PickAndPlace("payload_kg"),  # plus angle-dependent gravity along the moves
    "rotary": PickAndPlace("load_inertia_kgm2"),  # inertia changes (a part on the table)
    "two-mass": PickAndPlace("load_inertia_kgm2"),  # inertia and resonance change
}
"""The pick-and-place cycle of each plant family; a family not listed changes its first
randomised parameter over its legal range."""

STATE_FEATURES: tuple[tuple[str, str, str], ...] = (
    ("next_distance", "float (1)", "coming move's distance / the scenario's first move distance"),
    ("position", "float (1)", "commanded position / the scenario's first move distance"),
    ("next_duration", "float (s)", "coming move's duration including settle time"),
    ("progress", "float (1)", "moves done / moves per episode"),
)
"""Features of the controller's state after the last-move features and before the last
action: name, type (unit), meaning."""

CONDITION_FEATURES: tuple[tuple[str, str, str], ...] = (
    (
        "load",
        "float (1)",
        "the scheduled parameter during the coming move, log-mapped onto [-1, 1] over empty "
        ".. the part range's high end (the gripper knows what it holds)",
    ),
    (
        "target",
        "float (rad or m)",
        "the coming move's target position in joint units (the arm's angle from horizontal)",
    ),
)
"""The measured operating condition (``condition=True``, the scenario ids' default): after
the state features, before the last action."""


class GainTable:
    """An industrial gain table: register sets tuned at K operating points of the scheduled
    parameter. :meth:`row` is the row for a load: the point nearest in log scale, the first
    on a tie. What :class:`servogym.agents.GainTablePolicy` chooses from and what
    ``center_table`` centres the residual action on.

    Args:
        table: ``(operating point, register values)`` pairs, K >= 1, points finite and > 0.
        name: The argument's name in the error message.
    """

    def __init__(self, table: Any, name: str = "table") -> None:
        try:
            rows = [(float(p), dict(v)) for p, v in table]
        except (TypeError, ValueError):
            rows = []
        if not rows or any(not math.isfinite(p) or p <= 0 for p, _ in rows):
            raise ValueError(
                f"{name} must be a non-empty list of (operating point > 0, register values) "
                f"pairs of the scheduled parameter; got {name}={table!r:.200}."
            )
        self.rows: list[tuple[float, dict[str, Any]]] = rows
        self._logs = [math.log(p) for p, _ in rows]

    def index(self, load: float) -> int:
        """The row for ``load`` (> 0): the point nearest in log scale, the first on a tie."""
        x = math.log(load)
        return min(range(len(self._logs)), key=lambda i: abs(self._logs[i] - x))

    def row(self, load: float) -> tuple[float, dict[str, Any]]:
        """``(point, register values)`` of :meth:`index`."""
        return self.rows[self.index(load)]


def cycle_for(plant: str) -> PickAndPlace:
    """The pick-and-place cycle of a plant family (:data:`CYCLES`, a machine's
    :data:`~servogym.envs._machine.MACHINE_CYCLES`, or its fallback)."""
    if is_machine(plant):
        return MACHINE_CYCLES[plant]
    if plant in CYCLES:
        return CYCLES[plant]
    return PickAndPlace(get_plant(plant).randomised()[0])


class ScheduleEnv(gym.Env):
    """Choose the parameter set of every move while the load changes: gain scheduling.

    ## Description

    An episode is a pick-and-place sequence of ``n_moves`` moves on one plant instance
    (:class:`PickAndPlace`): empty moves to a pick position alternate with loaded moves to a
    place position, so the payload (vertical axis, arm) or load inertia (rotary, two-mass)
    changes several-fold between moves, and on the arm gravity also changes with the angle.
    Before each move the agent chooses the parameter set applied for that move; it is loaded
    the way the chip applies an Update (``ServoLoop.set_params``: the filter state, the
    integrator included, carries over), and plant, amplifier and encoder carry over too.

    ## Action Space

    As :class:`~servogym.envs.TuneEnv`: ``Box(-1, 1, (n,), float32)`` over the tuned
    registers (``params=``, ``fixed=``), or ``action_type="raw"`` (``MultiDiscrete``), or
    any action-map object with ``space``, ``names``, ``to_values``, ``to_params`` and
    ``from_values`` (``servogym.envs.ActionMap``; e.g. a discrete choice among a chip's
    stored gain sets). ``action_type="residual"``: a Box in [-1, 1] whose zero is the safe set
    ``center`` (:class:`~servogym.envs.ResidualActions`); ``"stored"``: the 6250 scenario's
    ``Discrete(5)`` choice of a stored gain set. Default registers of the PMD family (MC2100):

    {action_table}

    A NaN, an infinity, an entry outside [-1, 1] or a wrong shape raises ``ValueError``
    naming the index and the register; nothing is run.

    ## Observation Space

    ``Box(-10, 10, (12 + 4 + n,), float64)``, everything the controller can know, clipped to
    [-10, 10]: the last move's response (zeros before the first move), the state, and the
    last action in unit form (``to_unit`` of the registers applied; zeros before the first).

    {observation_table}

    With ``condition=True`` (the scenario ids' default) the measured operating condition,
    :data:`CONDITION_FEATURES` (``load``, ``target``), comes before the last action:
    ``Box(-10, 10, (12 + 4 + 2 + n,), float64)``.

    ## Rewards

    Minus the move's cost (``servogym.sim.move_cost``, 0 .. 100, docs/cost.md), times
    ``reward_scale`` (1.0 in the ``-v0`` ids and for the class itself, 0.01 in the ``-v1``
    ids). A move that diverges ends the episode with the raw
    reward ``-1000 * (2 - r)``, ``r`` the fraction of the episode's moves that ran (the
    diverging one counted by the fraction of its ticks). ``info["raw_reward"]`` is the
    reward before scaling, ``info["cost"]`` the move's cost.

    ## Starting State

    A plant instance drawn with ``np_random`` (the scenario's distribution, the cycle's
    parameter set to its empty value), the part value and the ``n_moves`` pick and place
    positions drawn with it; the axis at rest at 0, the chip's filter state zero.

    ## Episode End

    Terminated after ``n_moves`` moves, or when a move diverges. Never truncated.

    ## Arguments

    | Argument | Default | Type (Unit) | Meaning |
    |---|---|---|---|
    | `chip_model` | family's first model | str | chip model (any model of the id's family) |
    | `plant` | from the id | str | plant family |
    | `scenario` | `None` | Scenario | overrides chip_model, plant, plant_values, scale |
    | `plant_values` | `{}` | dict (SI) | plant parameters held fixed |
    | `plant_file` | `None` | path | a `servogym calibrate` plant.json; `plant_values` on top |
    | `plant_range` | `{}` | dict (SI) | name -> (low, high) the draws take a parameter from |
    | `sample_scale` | 1.0 | float (1) | width of the plant distribution (0 = nominal) |
    | `n_moves` | 8 | int (moves) | moves per episode (even: whole cycles) |
    | `cycle` | `CYCLES[plant]` | PickAndPlace | what changes between moves |
    | `params` | tunable registers | tuple[str] | registers the action sets |
    | `fixed` | `{}` | dict (int) | registers held at a value |
    | `action_type` | `"unit"` (scenarios: their own) | str or object | see Action Space |
    | `render_mode` | `None` | str | `"rgb_array"`: picture of the last move |
    | `scenario_name` | from the id | str | a gain-scheduling scenario (``SCENARIOS``) |
    | `moves` | the plant's | tuple[MoveSpec] | the moves (the first sets the positions' scale) |
    | `condition` | `False` (scenarios: `True`) | bool | observe the load and the target |
    | `reward_scale` | 1.0 (`-v1` ids: 0.01) | float (1) | rewards are minus the cost times this |
    | `center` | the scenario's or nominal set | dict (int) | zero action of `"residual"` |
    | `residual_scale` | 0.25 | float (1) | reach of a `"residual"` action (unit form) |
    | `center_table` | `None` | list of (float, dict) | gain table: centre per move (below) |
    | `machine_centers` | 1 (`-v2` ids: 2) | int | a machine's default centres (below) |

    ``center_table`` (with ``action_type="residual"``, single-axis plants): a gain table of
    ``(operating point, register values)`` rows; before each move the residual's zero action
    is the set of the point nearest, in log scale, to the coming move's load (what
    ``servogym.agents.GainTablePolicy`` runs), so a policy refines a gain table.

    ``machine_centers`` (multi-axis plants): which table the default ``center`` comes from,
    1 (``MACHINE_CENTERS``: searched on episode cost, the ``-v1`` ids) or 2
    (``MACHINE_CENTERS_V2``: sets that pass the multi-axis check at every point of the
    cycle, the ``-v2`` ids); an explicit ``center`` wins over either.

    ## Version History

    * v2: The multi-axis plants' Schedule ids only (``Schedule-<Family>-TwoLinkArm-v2``,
      ``...-XyStage-v2``): the residual action's zero is a set that passes the multi-axis
      check at every point of the cycle (``machine_centers=2``); v1's centres were searched
      on episode cost, and none passes the check everywhere.
    * v1: Rewards are scaled by 0.01 by default (``reward_scale=0.01``, the factor
      ``servogym train`` applied itself before; ``info["raw_reward"]`` is the unscaled
      reward). The gain-scheduling scenario ids (``Schedule-<Family>-<Scenario>-v1``) are
      added; by default they observe the condition (``condition=True``) and act around a
      safe set (``action_type="residual"``) or, on the 6250, choose a stored gain set
      (``"stored"``). The plant ids' action and observation are those of v0.
      The multi-axis plants' ids (``two-link-arm``, ``xy-stage``) are added, from v1 on
      (docs/envs.md, "Multi-axis machines").
    * v0: Initial version: raw rewards (``reward_scale=1.0``). Added since, as keywords
      whose defaults keep v0's behaviour: ``reward_scale``, the ``"residual"`` and
      ``"stored"`` actions, ``condition``, ``moves``, ``plant_range``, ``plant_file``,
      ``center_table``.
      Changed in place, in every version, because the old defaults asked more than the
      motor can give: the part range defaults to the parameter's default sampling range
      (was its legal range: the arm's payload to 2.5 kg, not 5 kg), the other parameters
      are drawn from their default sampling ranges (``PlantParam.sample_range``), and a
      cycle the motor cannot move is refused when the env is made.
    """

    metadata: ClassVar[dict[str, Any]] = {"render_modes": ["rgb_array"], "render_fps": 4}

    def __init__(
        self,
        chip_model: str | None = None,
        plant: str = "vertical-axis",
        *,
        scenario: Scenario | None = None,
        plant_values: Mapping[str, float] | None = None,
        plant_range: Mapping[str, tuple[float, float]] | None = None,
        plant_file: str | None = None,
        sample_scale: float = 1.0,
        n_moves: int = 8,
        cycle: PickAndPlace | None = None,
        params: tuple[str, ...] | None = None,
        fixed: Mapping[str, Any] | None = None,
        action_type: str | Any | None = None,
        render_mode: str | None = None,
        family: str | None = None,
        scenario_name: str | None = None,
        moves: tuple[Any, ...] | None = None,
        condition: bool | None = None,
        reward_scale: float = DEFAULT_REWARD_SCALE,
        center: Mapping[str, Any] | None = None,
        residual_scale: float = DEFAULT_RESIDUAL_SCALE,
        center_table: Any = None,
        machine_centers: int = 1,
    ) -> None:
        if render_mode not in (None, *self.metadata["render_modes"]):
            raise ValueError(
                f"render_mode must be None or one of {self.metadata['render_modes']}; "
                f"got render_mode={render_mode!r}."
            )
        if isinstance(n_moves, bool) or not isinstance(n_moves, int) or n_moves < 1:
            raise ValueError(f"n_moves must be an integer >= 1; got n_moves={n_moves!r}.")
        if center is not None and center_table is not None:
            raise ValueError(
                "give center (one set) or center_table (a gain table), not both; got "
                f"center={dict(center)!r:.80} and a center_table."
            )
        if isinstance(machine_centers, bool) or machine_centers not in MACHINE_CENTER_VERSIONS:
            raise ValueError(
                f"machine_centers must be one of {sorted(MACHINE_CENTER_VERSIONS)} (the table "
                f"of multi-axis centres); got machine_centers={machine_centers!r}."
            )
        self.render_mode = render_mode
        self.n_moves = n_moves
        self.reward_scale = check_reward_scale(reward_scale)
        preset = None
        if scenario_name is not None:
            from servogym.envs._scenarios import get_scenario

            preset = get_scenario(scenario_name)
            if preset.plant != plant or (family is not None and preset.family != family):
                raise ValueError(
                    f"scenario_name={scenario_name!r} is a {preset.family} scenario on the "
                    f"{preset.plant!r} plant; got plant={plant!r}, family={family!r}."
                )
            if scenario is None:
                plant_values = {**preset.plant_values, **dict(plant_values or {})}
                plant_range = dict(preset.plant_range) if plant_range is None else plant_range
                moves = preset.moves if moves is None else moves
            if cycle is None:
                cycle = PickAndPlace(preset.param, preset.empty, preset.part)
            condition = True if condition is None else condition
            if action_type is None:
                action_type = "stored" if preset.stored_sets else "residual"
            center = dict(preset.center) if center is None else center
        machine = is_machine(plant) if scenario is None else not isinstance(scenario, Scenario)
        if machine:
            # a machine's Schedule ids observe the configuration and act around a safe set
            condition = True if condition is None else condition
            action_type = "residual" if action_type is None else action_type
        self.preset = preset
        self.condition = bool(condition)
        from servogym.calibrate._plantfile import env_plant_values

        plant_values = env_plant_values(plant_file, plant, scenario, plant_values, plant_range)
        self.scenario = make_scenario(
            chip_model, plant, scenario, plant_values, sample_scale, family, plant_range, moves
        )
        self.chip = self.scenario.chip
        self.plant_family = plant_family(self.scenario.plant)
        self.axes: tuple[str, ...] | None = getattr(self.scenario, "axes", None)
        """A multi-axis plant's axis names; ``None`` for a single-axis plant."""
        self.cycle = cycle if cycle is not None else cycle_for(self.scenario.plant)
        if (self.axes is None) == isinstance(self.cycle, MachineCycle):
            want = "PickAndPlace" if self.axes is None else "MachineCycle"
            raise ValueError(
                f"cycle must be a {want} on the {self.scenario.plant!r} plant; got "
                f"cycle={self.cycle!r}."
            )
        p = self.plant_family.param(self.cycle.param)
        self._empty = p.low if self.cycle.empty is None else p.validate(self.cycle.empty)
        # The part's range: the cycle's, else the scenario's plant range for the parameter,
        # else its default sampling range (what the default motor can move).
        default_part = self.scenario.plant_ranges.get(p.name, (p.sample_low, p.sample_high))
        part = self.cycle.part if self.cycle.part is not None else default_part
        self._part = (p.validate(part[0]), p.validate(part[1]))
        if self._part[0] > self._part[1]:
            raise ValueError(
                f"the cycle's part range must have low <= high; got part={self._part!r} for "
                f"{p.name}."
            )
        self.defaults = self.scenario.default_params()
        self.plant = self.plant_family.build(self.scenario.draw_plant(np.random.default_rng(0)))
        loop_class = ServoLoop if self.axes is None else MultiServoLoop
        self.loop = loop_class(
            self.plant,
            self.defaults,
            self.scenario.assumptions,
            integrator=self.scenario.integrator,
            substeps=self.scenario.substeps,
        )
        if self.axes is None:
            self.need = cycle_need(self.scenario, self.cycle.param, self._empty, self._part)
            self._spec = self.scenario.moves[0]
            self._start = np.zeros(1)
            firsts = [self._spec]
        else:
            self._start = np.array([io.start_qpos for io in self.plant.ios], dtype=float)
            box = self.scenario.box()
            box[p.name] = (min(self._empty, self._part[0]), max(self._empty, self._part[1]))
            sweep = cycle_sweep(self._start, self.scenario.moves, self.cycle)
            self.needs = machine_need(self.scenario, box, sweep, "the cycle's moves")
            """Per axis, the worst motor need over the env's box (the cycle's sweep)."""
            self.need = worst_need(self.needs)
            firsts = [axis[0] for axis in self.scenario.moves]
            self._spec = CoordinatedSpec(
                tuple(m.max_velocity for m in firsts),
                tuple(m.max_acceleration for m in firsts),
                targets=tuple(self._start),
                settle_s=firsts[0].settle_s,
            )
        self._d_ref = np.array([abs(m.distance) for m in firsts])
        self._limits = [(m.max_velocity, m.max_acceleration) for m in firsts]
        if action_type is None:
            action_type = "unit"
        if center is None and action_type == "residual":
            center = default_center(self.chip.name, self.scenario.plant, machine_centers)
        if action_type == "stored":
            action_type = stored_set_actions(self.scenario.chip_model, preset)
        table = None
        if center_table is not None:
            table = self._check_table(center_table, action_type)
            center = table.rows[0][1]
        self.actions = make_action_map(
            action_type, self.chip, self.scenario.chip_model, params, fixed,
            center=center, residual_scale=residual_scale, axes=self.axes,
        )  # fmt: skip
        self._table = table
        self.action_space = self.actions.space
        self._space = self.chip.parameter_space(self.scenario.chip_model)
        n_axes = 1
        if self.axes is not None:
            n_axes = len(self.axes)
            self._space = {axis_register(k, n): s for k in range(1, n_axes + 1)
                           for n, s in self._space.items()}  # fmt: skip
        self._n_move = len(MOVE_FEATURES) * n_axes
        n_state = 2 * n_axes + len(STATE_FEATURES) - 2
        n_condition = (1 + n_axes * (1 if n_axes == 1 else 2)) if self.condition else 0
        n = self._n_move + n_state + n_condition + len(self.actions.names)
        self.observation_space = spaces.Box(-OBS_CLIP, OBS_CLIP, shape=(n,), dtype=np.float64)
        self._targets = np.zeros(n_moves if self.axes is None else (n_moves, n_axes))
        self._k = n_moves
        self._last: tuple[str, Any] | None = None
        self.part_value = self._empty
        self._load_index = self._n_move + n_state if self.condition else None

    def _check_table(self, table: Any, action_type: Any) -> GainTable:
        """``center_table`` validated: the gain table the residual action centres on."""
        if action_type != "residual" or self.axes is not None:
            raise ValueError(
                f"center_table needs action_type='residual' on a single-axis plant; got "
                f"action_type={action_type!r} on {self.scenario.plant!r}."
            )
        return GainTable(table, name="center_table")

    def _coming_load(self) -> float:
        """The scheduled parameter during the coming move (what the ``load`` feature shows)."""
        k = self._k
        return self.part_value if k % 2 == 1 and k < self.n_moves else self._empty

    def observed_load(self, obs: np.ndarray) -> float:
        """The scheduled parameter an observation reports for the coming move (the ``load``
        condition feature mapped back from [-1, 1] to its unit): what a gain table reads.

        Raises:
            ValueError: when the env does not observe the condition (``condition=False``).
        """
        if self._load_index is None:
            raise ValueError(
                "observed_load needs an env that observes the condition (condition=True; the "
                "scenario ids do)."
            )
        lo, hi = math.log(self._empty), math.log(max(self._part[1], self._empty))
        t = (float(np.asarray(obs)[self._load_index]) + 1.0) / 2.0
        return float(math.exp(lo + t * (hi - lo)))

    # -- the episode's plan ---------------------------------------------------------------

    def _profile(self, k: int, params: Any) -> Any:
        """Move ``k``'s chip profile; on a machine, every axis's (``Commands``: run after
        ``self.loop.set_params(params)``, which sets the period)."""
        if self.axes is not None:
            start = self._start if k == 0 else self._targets[k - 1]
            spec = dataclasses.replace(
                self._spec, targets=tuple(self._targets[k]), start_qpos=tuple(start)
            )
            return spec.commands(self.loop)
        io = self.plant.io
        start = 0.0 if k == 0 else self._targets[k - 1]
        start_counts = round(start * io.counts_per_unit)
        spec = dataclasses.replace(self._spec, distance=self._targets[k] - start)
        move = spec.to_move(io.counts_per_unit, start_counts)
        return self.chip.profile(move, self.chip.sample_time_s(params))

    def _observation(self, features: np.ndarray, values: Mapping[str, int] | None) -> np.ndarray:
        k = self._k
        if k < self.n_moves:
            prev = self._start if k == 0 else np.atleast_1d(self._targets[k - 1])
            nxt = np.atleast_1d(self._targets[k]) - prev
            times = [
                _trapezoid_time(abs(d), v, a) for d, (v, a) in zip(nxt, self._limits, strict=True)
            ]
            duration = max(times) + self._spec.settle_s
        else:
            prev, duration = np.atleast_1d(self._targets[-1]), 0.0
            nxt = np.zeros_like(prev)
        # per axis: next distance and position over the axis's scale; then duration, progress
        state = list(np.column_stack([nxt / self._d_ref, prev / self._d_ref]).ravel())
        state += [duration, k / self.n_moves]
        if self.condition:
            lo, hi = math.log(self._empty), math.log(max(self._part[1], self._empty))
            t = (math.log(self._coming_load()) - lo) / (hi - lo) if hi > lo else 0.0
            state.append(2.0 * t - 1.0)
            if self.axes is not None:
                state += list(prev)  # the configuration at the move's start ...
            state += list(prev + nxt)  # ... and at its end (one axis: the target)
        if values is None:
            last = np.zeros(len(self.actions.names))
        else:
            last = [self._space[n].to_unit(values[n]) for n in self.actions.names]
        return clip(np.concatenate([features, state, last]))

    def reset(
        self, *, seed: int | None = None, options: dict[str, Any] | None = None
    ) -> tuple[np.ndarray, dict[str, Any]]:
        super().reset(seed=seed)
        rng = self.np_random
        values = options_plant_values(self.scenario, options, rng)
        lo, hi = self._part
        self.part_value = float(math.exp(rng.uniform(math.log(lo), math.log(hi))))
        even = (np.arange(self.n_moves) % 2 == 0)[:, None]
        if self.axes is None:
            r0, r1 = self.cycle.reach
            reach = rng.uniform(r0, r1, size=self.n_moves) * self._d_ref[0]
            sign = math.copysign(1.0, self._spec.distance)
            # even moves go to a pick position (below 0), odd ones to a place position (above)
            self._targets = np.where(even[:, 0], -reach, reach) * sign
        else:
            # even moves go to a pick configuration, odd ones to a place configuration
            lows = np.where(even, [r[0] for r in self.cycle.pick], [r[0] for r in self.cycle.place])
            highs = np.where(even, [r[1] for r in self.cycle.pick],
                             [r[1] for r in self.cycle.place])  # fmt: skip
            self._targets = rng.uniform(lows, highs)
        values[self.cycle.param] = self._empty
        self.plant.set_params(values)
        self.plant_values = dict(self.plant.values)
        self.loop.set_params(self.defaults)
        self._k = 0
        self._last = None
        obs = self._observation(np.zeros(self._n_move), None)
        return obs, self._info()

    def _info(self) -> dict[str, Any]:
        return {
            "move": self._k,
            self.cycle.param: float(self.plant.values[self.cycle.param]),
            "part_value": self.part_value,
        }

    def step(self, action: Any) -> tuple[np.ndarray, float, bool, bool, dict[str, Any]]:
        if self._k >= self.n_moves:
            raise RuntimeError("the episode has ended; call reset() before step()")
        if self._table is not None:  # act around the gain table's set for this load
            self.actions.set_center(self._table.row(self._coming_load())[1])
        values = self.actions.to_values(action)
        params = self.actions.to_params(action)
        k = self._k
        self.loop.set_params(params)  # the chip's Update: filter state carries over
        profile = self._profile(k, params)
        r, feats = run_move(self.loop, profile, reset=k == 0, settle_s=self._spec.settle_s)
        self._last = (f"move {k}", r)
        metrics = (r.metrics,) if self.axes is None else r.metrics
        m = metrics[0]
        diverged = any(x.diverged for x in metrics)
        info = self._info()
        if diverged:
            done = (k + m.n_ticks / profile.n_ticks) / self.n_moves
            raw = -DIVERGENCE_PENALTY * (2.0 - done)
            terminated = True
            self._k = self.n_moves
        else:
            raw = -self._move_cost(r, profile)
            self._k = k + 1
            terminated = self._k >= self.n_moves
            if not terminated:
                # at rest on the target: pick the part up (after an even move) or put it down
                value = self.part_value if k % 2 == 0 else self._empty
                self.plant.set_params({self.cycle.param: value}, keep_state=True)
        obs = self._observation(feats, values)
        info.update(cost=-raw, raw_reward=raw, diverged=diverged, params=values)
        return obs, float(raw * self.reward_scale), terminated, False, info

    def _move_cost(self, r: Any, profile: Any) -> float:
        """A move's cost (it did not diverge): ``servogym.sim.move_cost``; on a machine the
        coordinated move's task cost (``servogym.sim.task_cost``: the axes' mean move cost
        plus the contouring error's terms, docs/cost.md)."""
        if self.axes is None:
            distance = int(profile.position[-1]) - int(profile.start)
            return move_cost(r.metrics, distance, self._spec.settle_s, self.scenario.weights)
        actual = np.stack([tr.actual for tr in r.traces])
        error = contour_error(profile, actual, r.metrics[0].n_ticks)
        return task_cost(r.metrics, profile, error, self.scenario.weights)

    def render(self) -> np.ndarray | None:
        if self.render_mode != "rgb_array":
            return None
        from servogym.sim._plot import response_rgb

        if self._last is None:
            return np.zeros((64, 64, 3), dtype=np.uint8)
        label, run = self._last
        title = f"{self.scenario.chip_model} on {self.scenario.plant}: {label}"
        runs = [(label, run)] if self.axes is None else axis_runs(label, run, self.axes)
        return response_rgb(runs, title=title)


def default_center(family: str, plant: str, machine_centers: int = 1) -> Any:
    """The safe set a residual action acts around by default: the hand-tuned nominal set of
    a single-axis plant (``servogym.agents.nominal_set``), a machine's per-axis sets
    (:data:`~servogym.envs._machine.MACHINE_CENTER_VERSIONS`, table ``machine_centers``);
    ``None`` when there is none."""
    if is_machine(plant):
        return MACHINE_CENTER_VERSIONS[machine_centers].get((family, plant))
    from servogym.agents._baselines import nominal_set

    return nominal_set(family, plant)


def cycle_need(scenario: Scenario, param: str, empty: float, part: tuple[float, float]) -> Any:
    """The worst motor need over a scheduling env's box (a :class:`~servogym.plants.Need`).

    The box: ``param`` from ``min(empty, part low)`` to ``max(empty, part high)``, every
    other parameter the env draws over its range (the scenario's ``plant_ranges``, else the
    default sampling range at ``sample_scale``), the fixed ones as given.

    Raises:
        MotorFeasibilityError: when a corner needs more than the motor may give, naming it.
    """
    from servogym.plants import check_motor

    family = get_plant(scenario.plant)
    box = (
        family.sample_bounds(scenario.sample_scale, ranges=scenario.plant_ranges)
        if scenario.randomise
        else dict(scenario.plant_ranges)
    )
    for name in scenario.plant_values:
        box.pop(name, None)
    box[param] = (min(empty, part[0]), max(empty, part[1]))
    what = {param: "the cycle's empty value or part range"}
    return check_motor(family, scenario.plant_values, box, scenario.moves, what=what)


def stored_set_actions(chip_model: str, preset: Any) -> Any:
    """The 6250's "which stored gain set" action over the scenario's stored sets."""
    from servogym.chips.parker6k import GainSet, Parker6kParams, StoredSetActions

    sets = tuple(getattr(preset, "stored_sets", ()) or ())
    if not sets:
        raise ValueError(
            "action_type='stored' needs a scenario with stored gain sets "
            "(scenario_name='StoredSets'), or pass StoredSetActions(params) as action_type."
        )
    params = Parker6kParams(model=chip_model, sgset=tuple(GainSet(**g) for g in sets))
    return StoredSetActions(params)


def _trapezoid_time(distance: float, v: float, a: float) -> float:
    """Duration of a trapezoidal (or triangular) move (s)."""
    if distance <= 0:
        return 0.0
    if distance <= v * v / a:
        return 2.0 * math.sqrt(distance / a)
    return distance / v + v / a


def observation_table(condition: bool = False, axes: tuple[str, ...] | None = None) -> str:
    """The observation table of the scheduling env, generated from the feature lists
    (``condition``: with :data:`CONDITION_FEATURES`; ``axes``: a machine's, every per-axis
    feature once per axis, named ``<axis>_<feature>``)."""
    if axes is None:
        rows = [(i, f"`last_{n}`", doc, t) for i, (n, t, doc) in enumerate(MOVE_FEATURES)]
        state = list(STATE_FEATURES)
        cond = list(CONDITION_FEATURES)
    else:
        rows = [(0, f"`last_{a}_{n}`", doc, t) for a in axes for n, t, doc in MOVE_FEATURES]
        state = [(f"{a}_{n}", t, d) for a in axes for n, t, d in STATE_FEATURES[:2]]
        state += STATE_FEATURES[2:]
        cond = [CONDITION_FEATURES[0]] + [
            (f"{a}_{end}", "float (rad or m)", f"axis {a}'s joint position at the coming "
             f"move's {end}")
            for end in ("start", "end") for a in axes
        ]  # fmt: skip
    rows = [(i, *r[1:]) for i, r in enumerate(rows)]
    base = len(rows)
    rows += [(base + i, f"`{n}`", doc, t) for i, (n, t, doc) in enumerate(state)]
    base = len(rows)
    if condition:
        rows += [(base + i, f"`{n}`", d, t) for i, (n, t, d) in enumerate(cond)]
        base = len(rows)
    rows.append(
        (
            f"{base} .. {base} + n - 1",
            "`last_action`",
            "unit form of the registers last applied",
            "float (1)",
        )
    )
    return markdown_table(("Num", "Observation", "Meaning", "Type (Unit)"), rows)
