"""The tuning env: one plant instance per episode, one parameter set per episode."""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any, ClassVar

import gymnasium as gym
import numpy as np
from gymnasium import spaces

from servogym.envs._actions import make_action_map
from servogym.envs._common import (
    DEFAULT_REWARD_SCALE,
    check_reward_scale,
    make_scenario,
    markdown_table,
    options_plant_values,
)
from servogym.envs._machine import (
    axis_runs,
    evaluation_info,
    make_evaluator,
    plant_family,
    run_move,
)
from servogym.envs._observe import MOVE_FEATURES, OBS_CLIP, plant_features
from servogym.sim import MoveSpec, Scenario
from servogym.sim._multieval import CoordinatedSpec

IDENT_SCALE = (0.25, 0.5, 0.5)
"""The identification move is the scenario's first move with its distance, velocity limit and
acceleration limit scaled by these factors (a short, gentle move), and the same settle time."""


class TuneEnv(gym.Env):
    """Choose a chip's complete parameter set for an axis you have only identified.

    ## Description

    Each episode draws a plant instance from the scenario's distribution (or takes it from
    ``reset(options={"plant_values": {...}})``), runs a short, safe identification move on
    it with the chip's default parameters, and shows the agent what an engineer could measure
    on that move. The agent answers with a complete filter parameter set; the scenario's
    evaluation moves run with it and the episode ends. Components: the chip family (legal
    ranges, profile), the plant family (instance distribution), and
    :class:`servogym.sim.Evaluator` (the moves and the cost of ``docs/cost.md``).

    ## Action Space

    ``Box(-1, 1, (n,), float32)``, one entry per tuned register, mapped onto the legal
    integers by the chip's parameter space (``ParamSpec.from_unit``: log-uniform where the
    space says ``log``, the lowest 5 % giving 0 where 0 is legal). ``params=`` chooses the
    registers, ``fixed=`` holds some at given values; ``action_type="raw"`` gives the
    integers themselves as ``MultiDiscrete`` (entry ``i`` means ``low_i + action[i]``).
    Default registers of the PMD family (MC2100):

    {action_table}

    An action with a NaN, an infinity, an entry outside [-1, 1] or the wrong shape raises
    ``ValueError`` naming the index and the register; nothing is run.

    ## Observation Space

    ``Box(-10, 10, (12,), float64)``: features of the identification move, clipped to
    [-10, 10]. ``e_ref = max(4, 0.001 * |distance|)`` counts, as in the cost.

    {observation_table}

    With ``privileged=True`` the randomised plant parameters follow, each mapped to [-1, 1]
    over its legal range (log scale for log-uniform ones), in the plant family's order.

    ## Rewards

    Minus the scenario's cost of the parameter set on this plant instance (docs/cost.md),
    times ``reward_scale`` (1.0 in the ``-v0`` ids and for the class itself, 0.01 in the
    ``-v1`` ids): the mean move cost (0 .. 100) when no move
    diverged, ``-1000 * (2 - r)`` when one did (``r``: fraction of the evaluation's ticks that
    ran). Always finite. ``info["cost"]`` is the cost and ``info["raw_reward"]`` the reward
    before scaling.

    ## Starting State

    A plant instance drawn with the env's ``np_random`` (``Scenario.draw_plant``), at rest at
    its start position; the identification move (the first evaluation move scaled by
    :data:`IDENT_SCALE`) has run with the chip's defaults (or ``ident_params``: a chip whose
    defaults cannot hold the axis needs a safe set there).

    ## Episode End

    Always after one step (``terminated=True``).

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
    | `params` | tunable registers | tuple[str] | registers the action sets |
    | `fixed` | `{}` | dict (int) | registers held at a value |
    | `action_type` | `"unit"` | str or action map | `"unit"`, `"raw"` or an object |
    | `privileged` | `False` | bool | also observe the hidden plant parameters |
    | `ident_params` | chip defaults | dict (int) | registers of the identification move |
    | `render_mode` | `None` | str | `"rgb_array"`: picture of the last response |
    | `reward_scale` | 1.0 (`-v1` ids: 0.01) | float (1) | rewards are minus the cost times this |

    ## Version History

    * v1: Rewards are scaled by 0.01 by default (``reward_scale=0.01``, the factor
      ``servogym train`` applied itself before; ``info["raw_reward"]`` is the unscaled
      reward). Action and observation are those of v0.
      The multi-axis plants' ids (``two-link-arm``, ``xy-stage``) are added, from v1 on
      (docs/envs.md, "Multi-axis machines").
    * v0: Initial version: raw rewards (``reward_scale=1.0``). Added since, as keywords
      whose defaults keep v0's behaviour: ``reward_scale``, ``plant_range``,
      ``plant_file``. Changed in place, in every version, because the old defaults asked
      more than the motor can give: the plant parameters are drawn from their default
      sampling ranges (``PlantParam.sample_range``), not always their legal ranges.
    """

    metadata: ClassVar[dict[str, Any]] = {"render_modes": ["rgb_array"], "render_fps": 1}

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
        params: tuple[str, ...] | None = None,
        fixed: Mapping[str, Any] | None = None,
        action_type: str | Any = "unit",
        privileged: bool = False,
        ident_params: Mapping[str, int] | None = None,
        render_mode: str | None = None,
        family: str | None = None,
        reward_scale: float = DEFAULT_REWARD_SCALE,
    ) -> None:
        if render_mode not in (None, *self.metadata["render_modes"]):
            raise ValueError(
                f"render_mode must be None or one of {self.metadata['render_modes']}; "
                f"got render_mode={render_mode!r}."
            )
        self.render_mode = render_mode
        self.reward_scale = check_reward_scale(reward_scale)
        from servogym.calibrate._plantfile import env_plant_values

        plant_values = env_plant_values(plant_file, plant, scenario, plant_values, plant_range)
        self.scenario = make_scenario(
            chip_model, plant, scenario, plant_values, sample_scale, family, plant_range
        )
        self.chip = self.scenario.chip
        self.plant_family = plant_family(self.scenario.plant)
        self.axes: tuple[str, ...] | None = getattr(self.scenario, "axes", None)
        """A multi-axis plant's axis names; ``None`` for a single-axis plant."""
        self.evaluator = make_evaluator(self.scenario)  # compiles the plant, once
        self.defaults = self.scenario.default_params()
        self.ident_params = self.scenario.params(ident_params) if ident_params else self.defaults
        self.actions = make_action_map(
            action_type, self.chip, self.scenario.chip_model, params, fixed, axes=self.axes
        )
        self.action_space = self.actions.space
        if not isinstance(privileged, (bool, np.bool_)):
            raise ValueError(
                f"privileged must be True or False; got privileged={privileged!r} of type "
                f"{type(privileged).__name__}."
            )
        self.privileged = bool(privileged)
        n = len(MOVE_FEATURES) * (1 if self.axes is None else len(self.axes))
        if self.privileged:
            n += len(self.plant_family.randomised())
        self.observation_space = spaces.Box(-OBS_CLIP, OBS_CLIP, shape=(n,), dtype=np.float64)
        self.ident_move = identification_move(self.scenario)
        self._ident_profile = self._plan_identification()
        self._plant_values: dict[str, float] = {}
        self._last: tuple[str, Any] | None = None
        self._needs_reset = True

    def reset(
        self, *, seed: int | None = None, options: dict[str, Any] | None = None
    ) -> tuple[np.ndarray, dict[str, Any]]:
        super().reset(seed=seed)
        values = options_plant_values(self.scenario, options, self.np_random)
        plant = self.evaluator.plant
        plant.set_params(values)
        self._plant_values = dict(plant.values)
        loop = self.evaluator.loop
        loop.set_params(self.ident_params)
        r, obs = run_move(loop, self._ident_profile, reset=True, settle_s=self.ident_move.settle_s)
        if self.privileged:
            obs = np.concatenate([obs, plant_features(self.plant_family, self._plant_values)])
        self._last = ("identification", r)
        self._needs_reset = False
        return obs, {"plant_values": dict(self._plant_values)}

    def step(self, action: Any) -> tuple[np.ndarray, float, bool, bool, dict[str, Any]]:
        if self._needs_reset:
            raise RuntimeError("call reset() before step(): a tuning episode is one step")
        values = self.actions.to_values(action)
        params = self.actions.to_params(action)
        ev = self.evaluator.evaluate(params, traces=self.render_mode is not None)
        self._last = ("chosen parameters", ev)
        self._needs_reset = True
        obs = np.zeros(self.observation_space.shape)
        info = {
            "cost": ev.cost,
            "raw_reward": -float(ev.cost),
            "diverged": ev.diverged,
            "params": values,
            **evaluation_info(ev),
            "plant_values": dict(self._plant_values),
        }
        return obs, -float(ev.cost) * self.reward_scale, True, False, info

    def render(self) -> np.ndarray | None:
        if self.render_mode != "rgb_array":
            return None
        from servogym.sim._plot import response_rgb

        if self._last is None:
            raise RuntimeError("call reset() before render()")
        label, run = self._last
        title = f"{self.scenario.chip_model} on {self.scenario.plant}: {label}"
        runs = [(label, run)] if self.axes is None else axis_runs(label, run, self.axes)
        return response_rgb(runs, title=title)

    def _plan_identification(self) -> Any:
        """The identification move's chip profile (a machine: every axis's, ``Commands``)."""
        if self.axes is None:
            io = self.evaluator.plant.io
            dt = self.chip.sample_time_s(self.ident_params)
            return self.chip.profile(self.ident_move.to_move(io.counts_per_unit), dt)
        loop = self.evaluator.loop
        loop.set_params(self.ident_params)
        return self.ident_move.commands(loop)


def identification_move(scenario: Any) -> MoveSpec | CoordinatedSpec:
    """The scenario's first move with its distance, velocity limit and acceleration limit
    scaled by :data:`IDENT_SCALE`, the same settle time; on a machine, every axis's first
    default move so scaled, run together from the start position (a coordinated move)."""
    s_d, s_v, s_a = IDENT_SCALE
    if isinstance(scenario, Scenario):
        first = scenario.moves[0]
        return MoveSpec(
            first.distance * s_d, first.max_velocity * s_v, first.max_acceleration * s_a,
            first.settle_s,
        )  # fmt: skip
    firsts = [axis[0] for axis in scenario.moves]
    return CoordinatedSpec(
        tuple(m.max_velocity * s_v for m in firsts),
        tuple(m.max_acceleration * s_a for m in firsts),
        targets=tuple(m.distance * s_d for m in firsts),
        settle_s=firsts[0].settle_s,
    )


def observation_table(axes: tuple[str, ...] | None = None) -> str:
    """The observation table of the tuning env, generated from :data:`MOVE_FEATURES`
    (``axes``: a machine's, every feature once per axis, named ``<axis>_<feature>``)."""
    named = [(f"`{n}`", t, doc) for n, t, doc in MOVE_FEATURES]
    if axes is not None:
        named = [(f"`{a}_{n}`", t, doc) for a in axes for n, t, doc in MOVE_FEATURES]
    rows = [(i, n, doc, t) for i, (n, t, doc) in enumerate(named)]
    return markdown_table(("Num", "Observation", "Meaning", "Type (Unit)"), rows)
