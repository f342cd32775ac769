"""Gain-scheduling scenarios: where the physics makes one fixed parameter set a compromise.

A :class:`ScheduleScenario` is a preset of :class:`~servogym.envs.ScheduleEnv`: a chip
family, a plant family with some parameters fixed (the motor, the screw lead), the moves, the
pick-and-place cycle of the scheduled parameter (empty value and part range), the ranges the
other randomised parameters are drawn from, the observation of the measured condition and
the action (around a safe set, or one of the 6250's stored gain sets). Each is registered as
``servogym/Schedule-<Family>-<Name>-v0`` (:data:`servogym._registration.SCENARIOS`).

Every range is physically feasible: :func:`scenario_need` adds up, from the MuJoCo model, the
peak torque the moves need at the worst corner of the scenario's box (scheduled parameter at
its empty and part ends, the other drawn parameters at theirs) and the env refuses a box that
needs more than :data:`servogym.plants.PEAK_HEADROOM` of the motor's peak
(``experiments/schedule_feasibility.py`` writes the table in docs/envs.md).
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Mapping
from typing import Any

from servogym.sim._scenario import DEFAULT_MOVES, MoveSpec


@dataclasses.dataclass(frozen=True)
class ScheduleScenario:
    """One gain-scheduling scenario (a preset of the Schedule env).

    Attributes:
        name: The id part (``RotaryInertia``: ``servogym/Schedule-PMD-RotaryInertia-v0``).
        family: Chip family name (``"pmd"``, ``"parker6k"``).
        chip_model: The chip model the id uses.
        plant: Plant family name.
        param: The scheduled plant parameter (what the part changes).
        empty: Its value without a part (SI).
        part: The range the part's value is drawn from, log-uniformly (SI).
        plant_values: Plant parameters held fixed (SI), e.g. the screw lead.
        plant_range: Ranges (SI) the other randomised parameters are drawn from, where the
            family's default sampling range would overload the motor.
        moves: The moves (the first sets the scale of the pick-and-place positions);
            ``()``: the plant family's default moves.
        center: Register values of a safe set: the zero action of ``action_type="residual"``
            (the default action of the id): a robust set tuned over the scenario that passes
            the check, or the plant family's hand-tuned nominal set (docs/envs.md).
        stored_sets: The 6250's stored gain sets (``sgp, sgi, sgv, sgvf, sgaf`` each): the
            action picks one per move (SGENB); ``()``: the action is a register set.
        why: Why the ranges are what they are (docs/envs.md).
    """

    name: str
    family: str
    chip_model: str
    plant: str
    param: str
    empty: float
    part: tuple[float, float]
    plant_values: Mapping[str, float] = dataclasses.field(default_factory=dict)
    plant_range: Mapping[str, tuple[float, float]] = dataclasses.field(default_factory=dict)
    moves: tuple[MoveSpec, ...] = ()
    center: Mapping[str, int] = dataclasses.field(default_factory=dict)
    stored_sets: tuple[Mapping[str, int], ...] = ()
    why: str = ""

    @property
    def all_moves(self) -> tuple[MoveSpec, ...]:
        """The moves, the plant family's defaults when none are given."""
        return self.moves or DEFAULT_MOVES[self.plant]

    @property
    def span(self) -> float:
        """How many times the scheduled parameter changes over the scenario (part high /
        empty)."""
        return self.part[1] / self.empty

    def operating_points(self, k: int) -> list[float]:
        """``k`` values of the scheduled parameter, log-spaced from empty to the part's high
        end (the operating points of a gain table)."""
        if isinstance(k, bool) or not isinstance(k, int) or k < 2:
            raise ValueError(f"k must be an integer >= 2; got k={k!r}.")
        lo, hi = math.log(self.empty), math.log(self.part[1])
        points = [float(math.exp(lo + (hi - lo) * i / (k - 1))) for i in range(k)]
        # the ends exactly (exp(log(10)) is 10.000000000000007: outside a legal high of 10)
        points[0], points[-1] = float(self.empty), float(self.part[1])
        return points

    def env_kwargs(self) -> dict[str, Any]:
        """The ScheduleEnv keyword arguments of the scenario (what its id passes)."""
        return {"scenario_name": self.name}


_ROTARY_MOVES = (
    MoveSpec(2 * math.pi, 50.0, 1200.0, 0.08),
    MoveSpec(-2 * math.pi, 50.0, 1200.0, 0.08),
)

SCENARIOS: dict[str, ScheduleScenario] = {
    s.name: s
    for s in (
        ScheduleScenario(
            name="ArmPayload",
            family="pmd",
            chip_model="MC2100",
            plant="arm",
            param="payload_kg",
            empty=0.05,
            part=(0.5, 2.5),
            # A robust set over the scenario's distribution (4 plant draws, payload
            # 0.05-2.5 kg, TPE budget 30 from the model-based design start; passes servogym
            # check on its draws): experiments/schedule_oracle.py --scenarios ArmPayload
            # --robust-only --budget 30 --robust 4 --label centre. At its zero action it
            # costs 1.57 per move against 7.75 for the hand-tuned nominal arm set, the first
            # centre; PPO's untrained exploration around it runs 10 of 16 episodes to the
            # end (nominal: 9 of 16): experiments/schedule_explore.py.
            center={
                "kp": 47,
                "ki": 76,
                "kd": 605,
                "kvff": 0,
                "kaff": 32767,
                "kout": 32767,
                "integration_limit": 46308,
                "derivative_time": 4,
                "bias": 3597,
            },
            why=(
                "Payload 0.05 kg (empty gripper) to 2.5 kg: 50x, and the gravity torque "
                "follows cos(angle) along every move. 2.5 kg is the default sampling range's "
                "end: with the heaviest corner of the friction ranges the default moves need "
                "76 % of the 2 N*m motor (3.1 kg would need the 80 % the feedback must keep)."
            ),
        ),
        ScheduleScenario(
            name="RotaryInertia",
            family="pmd",
            chip_model="MC2100",
            plant="rotary",
            param="load_inertia_kgm2",
            empty=3e-5,
            part=(3e-4, 9e-4),
            moves=_ROTARY_MOVES,
            center={"kp": 34, "kd": 107, "ki": 11, "kaff": 252},
            why=(
                "Load inertia 1x (3e-5 kg*m^2, the rotor's own) to 30x the rotor's. The "
                "default rotary moves (3000 rad/s^2) could move only 16x (5e-4) on the 2 N*m "
                "motor, so this scenario's moves accelerate at 1200 rad/s^2 (50 rad/s, one "
                "turn): at 30x with the most friction they need 63 % of the peak."
            ),
        ),
        ScheduleScenario(
            name="VerticalCoarseLead",
            family="pmd",
            chip_model="MC2100",
            plant="vertical-axis",
            param="payload_kg",
            empty=0.5,
            part=(3.0, 10.0),
            plant_values={"screw_lead_m": 0.04, "carriage_mass_kg": 0.5},
            plant_range={
                "viscous_friction_ns_per_m": (0.1, 200.0),
                "coulomb_friction_n": (0.5, 30.0),
            },
            # A robust set over the scenario's distribution (4 plant draws, payload 0.5-10 kg,
            # TPE budget 30 from the model-based design start; passes servogym check on its
            # draws): experiments/schedule_oracle.py --scenarios VerticalCoarseLead
            # --robust-only --budget 30 --robust 4 --label centre. At its zero action it
            # costs 0.80 per move against 30.7 for the hand-tuned nominal set of the 10 mm
            # screw that was the centre before, and PPO's untrained exploration around it
            # runs 12 of 16 episodes to the end (nominal: 3 of 16):
            # experiments/schedule_explore.py.
            center={
                "kp": 145,
                "ki": 477,
                "kd": 1890,
                "kvff": 10,
                "kaff": 32765,
                "kout": 8773,
                "integration_limit": 23391,
                "derivative_time": 2,
                "bias": 2558,
            },
            why=(
                "A 40 mm lead (the legal maximum) and a 0.5 kg carriage: the rotor reflects "
                "as 0.74 kg instead of 11.8 kg through the 10 mm screw, so the 0.5-10 kg "
                "payload is most of the moving mass (1.7 to 11.2 kg, 6.5x) and of the gravity "
                "load. Through the coarse lead the carriage friction weighs 4x more at the "
                "motor: the default ranges (up to 1000 N*s/m, 100 N) would need 135 % of the "
                "peak, so friction is drawn up to 200 N*s/m and 30 N (62 % at the worst "
                "corner)."
            ),
        ),
        ScheduleScenario(
            name="StoredSets",
            family="parker6k",
            chip_model="6250",
            plant="rotary",
            param="load_inertia_kgm2",
            empty=3e-5,
            part=(3e-4, 9e-4),
            moves=_ROTARY_MOVES,
            # Tuned at the five operating points 3e-5, 7.0e-5, 1.6e-4, 3.8e-4, 9e-4 kg*m^2
            # (TPE, budget 30 each, then servogym check: the first four pass, the 30x set
            # misses the following-error limit at load +-20 %): experiments/schedule_oracle.py
            # --scenarios StoredSets --points 5 --budget 30 --label smoke.
            stored_sets=(
                {"sgp": 252107, "sgi": 9999999, "sgv": 1049, "sgvf": 1049, "sgaf": 145},
                {"sgp": 104713, "sgi": 4195214, "sgv": 871, "sgvf": 871, "sgaf": 242},
                {"sgp": 50613, "sgi": 1013875, "sgv": 842, "sgvf": 842, "sgaf": 467},
                {"sgp": 107821, "sgi": 2159879, "sgv": 1794, "sgvf": 1794, "sgaf": 995},
                {"sgp": 60418, "sgi": 605149, "sgv": 2011, "sgvf": 2011, "sgaf": 2231},
            ),
            why=(
                "The Parker 6250's own mechanism on the RotaryInertia axis (1x-30x the "
                "rotor, the same moves): five gain sets stored with SGSET, one enabled per "
                "move with SGENB; the action is which one."
            ),
        ),
    )
}
"""Every gain-scheduling scenario by name (the ids' ``<Name>``)."""


def get_scenario(name: str) -> ScheduleScenario:
    """The scenario called ``name``; a ValueError naming the known ones otherwise."""
    try:
        return SCENARIOS[name]
    except (KeyError, TypeError):
        import difflib

        close = difflib.get_close_matches(str(name), SCENARIOS, n=2)
        hint = f" Did you mean {' or '.join(close)}?" if close else ""
        raise ValueError(
            f"scenario_name must be one of {', '.join(SCENARIOS)}; got "
            f"scenario_name={name!r}.{hint}"
        ) from None


def feasibility_rows() -> list[dict[str, Any]]:
    """Every Schedule id's box and the peak torque its worst corner needs (docs/envs.md).

    One row per registered Schedule id of the newest version (the plant-family ids with
    their default cycle, and the scenarios; a ``-v0`` plant id's box is its ``-v1`` twin's),
    computed by building the env (its ``need``: :func:`servogym.envs._schedule.cycle_need`;
    a multi-axis plant's: the axis nearest its motor's peak,
    :func:`servogym.envs._machine.machine_need`). ``moves``: the moves as text (a machine:
    each axis's span of targets, velocity and acceleration limits).
    """
    import gymnasium as gym

    from servogym.envs import VERSION, id_version, registered_ids

    rows = []
    for eid in registered_ids():
        if not eid.split("/")[1].startswith("Schedule-") or id_version(eid) != VERSION:
            continue
        env = gym.make(eid).unwrapped
        if env.axes is None:
            m = env.scenario.moves[0]
            moves = f"+-{m.distance:.3g}, {m.max_velocity:.3g}, {m.max_acceleration:.3g}"
        else:  # a machine: each axis's span of targets, velocity and acceleration limits
            moves = "; ".join(
                f"{axis} {lo:.3g} .. {hi:.3g}, {v:.3g}, {a:.3g}"
                for k, (axis, (v, a)) in enumerate(zip(env.axes, env._limits, strict=True))
                for lo, hi in [env.cycle.span(k)]
            )
        rows.append(
            {
                "env_id": eid,
                "param": env.cycle.param,
                "empty": env._empty,
                "part": env._part,
                "fixed": dict(env.scenario.plant_values),
                "moves": moves,
                "need": env.need,
            }
        )
        env.close()
    return rows


def feasibility_table_markdown() -> str:
    """The table of docs/envs.md, "Why each range is what it is" (see
    :func:`feasibility_rows`)."""
    from servogym.plants._base import _fmt

    lines = [
        "| Env id | Scheduled parameter: empty .. part | Fixed | Moves (distance, velocity, "
        "acceleration) | Peak torque at the worst corner (N*m) | Of the motor's peak |",
        "|---|---|---|---|---|---|",
    ]
    for r in feasibility_rows():
        n = r["need"]
        fixed = ", ".join(f"{k}={_fmt(v)}" for k, v in r["fixed"].items()) or "-"
        axis = f"{n.family.split('/')[1]}: " if "/" in n.family else ""
        lines.append(
            f"| `{r['env_id']}` | `{r['param']}` {_fmt(r['empty'])} .. "
            f"{_fmt(r['part'][0])}-{_fmt(r['part'][1])} | {fixed} | {r['moves']} | "
            f"{axis}{n.total_nm:.3g} (inertia {n.inertia_nm:.3g}, gravity {n.gravity_nm:.3g}, "
            f"Coulomb {n.coulomb_nm:.3g}, viscous {n.viscous_nm:.3g}) | {n.fraction:.0%} of "
            f"{n.peak_nm:.3g} |"
        )
    return "\n".join(lines)
