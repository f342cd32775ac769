"""The instances of the servobench suites: chip model x plant x load condition x task.

Every instance is fully determined by its id, ``<suite>/<chip>/<plant>/<load>/<task>``
(e.g. ``servobench-v1/mc2100/vertical-axis/heavy/fast``): the id names the suite version,
the chip model, the plant family, the fixed plant values of the load condition
(:data:`LOADS`) and one point-to-point move (:data:`TASKS`). The plant is the family's
nominal instance with those values; nothing is drawn at random, so an evaluation depends on
the parameter set only.

* ``servobench-v1`` (the default): four chip models, one of each family with PMD's two
  generations (MC2100, MC58000, TurboPMAC2, 6250), 36 train and 12 held-out instances, on
  the accurate default integration and each chip's default loop latency, with every
  constraint ``servogym tune`` sets (margins included). The Turbo PMAC instances hold two
  registers where an engineer sets them for the task: the fatal following error Ixx11 at
  four times the following-error constraint, and the output limit Ixx69 at full scale (the
  default 62.5 % is below what the heavy loads need; see :data:`PMAC_FIXED`).
* ``servobench-v0``: three chip models, 24 train and 12 held-out instances; its best-known
  costs were measured on servogym's first servo tick and are superseded (the data file
  says so), the instances stay loadable.

A behaviour change (another move, load, cost weight or plant) makes a new suite version;
published versions stay as they are.
"""

from __future__ import annotations

import dataclasses
import difflib
import functools
from collections.abc import Mapping
from typing import Any

from servogym.sim._scenario import MoveSpec, Scenario

SUITE_VERSION = "servobench-v0"
"""The first suite (superseded best-known costs); kept for the results that name it."""

DEFAULT_SUITE = "servobench-v1"
"""The suite ``servogym benchmark`` runs unless told otherwise."""

SUITES: dict[str, tuple[str, ...]] = {
    "servobench-v0": ("MC2100", "MC58000", "6250"),
    "servobench-v1": ("MC2100", "MC58000", "TurboPMAC2", "6250"),
}
"""Every suite by name, with its chip models: PMD Navigator (154 us), PMD Magellan (52 us),
Delta Tau Turbo PMAC2 (442 us), Parker 6250 (160 us). v0 predates the PMAC family."""

CHIPS: tuple[str, ...] = SUITES["servobench-v0"]
"""Chip models of servobench-v0."""

PMAC_FIXED = {"output_limit": 32767}
"""Registers the v1 Turbo PMAC instances hold at a task's value: Ixx69 at full scale. The
fatal following error Ixx11 (1/16 count) is set per instance to four times the
following-error constraint (:func:`pmac_trip_limit`)."""

TRIP_FACTOR = 4.0
"""Ixx11 of a v1 PMAC instance, as a multiple of the following-error constraint (1 % of the
move): loose enough that only a set already far outside the constraint trips, tight enough
to stop a runaway axis, as an engineer sets it for the task."""

PLANTS: tuple[str, ...] = ("rotary", "two-mass", "vertical-axis", "arm")
"""Plant families: a rigid rotary axis, a resonant two-mass axis, a vertical ball-screw axis
and a geared arm (both with a gravity bias)."""

LOADS: dict[str, dict[str, dict[str, float]]] = {
    "rotary": {"light": {"load_inertia_kgm2": 3e-5}, "heavy": {"load_inertia_kgm2": 3e-4}},
    "two-mass": {"light": {"load_inertia_kgm2": 3e-5}, "heavy": {"load_inertia_kgm2": 3e-4}},
    "vertical-axis": {"light": {"payload_kg": 0.5}, "heavy": {"payload_kg": 8.0}},
    "arm": {"light": {"payload_kg": 0.1}, "heavy": {"payload_kg": 2.0}},
}
"""Fixed plant values of each load condition (SI units, physics names of the plant family)."""

LOADS_V1: dict[str, dict[str, dict[str, float]]] = {
    **LOADS,
    "two-mass": {"light": {"load_inertia_kgm2": 1e-5}, "heavy": {"load_inertia_kgm2": 3e-5}},
}
"""servobench-v1's load conditions: v0's, but the two-mass loads are a third of the rotor's
inertia and equal to it (1e-5 and 3e-5 kg*m^2; resonance 174 and 123 Hz), not v0's 3e-5 and
3e-4 (10x the rotor, 91 Hz). With v0's heavy load no PID-only set met the tune command's
margins and following-error limit together on MC2100 or MC58000 (the reference search's
2,351 evaluations found no safe set; on MC58000 the closest missed the gain margin by 0.7 dB
and the phase margin by 1 deg), nor on MC2100 at the family's nominal 9e-5: such loads ask
for a notch, which only some chips have, so they belong in a notch benchmark, not in one
every family can solve."""


@dataclasses.dataclass(frozen=True)
class Task:
    """One point-to-point move, trapezoidal, a third of its time accelerating.

    Attributes:
        distance: Move length (rad or m, the plant's joint unit).
        move_s: Duration of the motion (s).
        settle_s: Time at rest on the target after it (s).
    """

    distance: float
    move_s: float
    settle_s: float

    def move(self) -> MoveSpec:
        """The move: peak velocity ``1.5 D/T``, acceleration ``4.5 D/T^2``."""
        d, t = self.distance, self.move_s
        return MoveSpec(d, 1.5 * d / t, 4.5 * d / (t * t), self.settle_s)


TASKS: dict[str, dict[str, Task]] = {
    # Fast moves ask for about a third to a half of the peak torque at the heavy load; slow
    # moves are short and gentle, where the error scale (4 counts) rewards precision.
    "rotary": {"fast": Task(1.5, 0.05, 0.04), "slow": Task(0.3, 0.08, 0.04)},
    "two-mass": {"fast": Task(1.0, 0.05, 0.04), "slow": Task(0.2, 0.08, 0.04)},
    "vertical-axis": {"fast": Task(0.01, 0.05, 0.04), "slow": Task(0.002, 0.08, 0.04)},
    "arm": {"fast": Task(0.05, 0.08, 0.04), "slow": Task(0.01, 0.1, 0.04)},
}
"""The move of each task, per plant family (joint units: rad or m)."""


@dataclasses.dataclass(frozen=True)
class InstanceSpec:
    """What an instance id stands for.

    Attributes:
        chip_model: Chip model (canonical name).
        plant: Plant family.
        load: ``"light"`` or ``"heavy"``.
        task: ``"fast"`` or ``"slow"``.
        split: ``"train"`` or ``"heldout"``.
        suite: Suite version the instance belongs to.
    """

    chip_model: str
    plant: str
    load: str
    task: str
    split: str
    suite: str = SUITE_VERSION

    @property
    def id(self) -> str:
        """``<suite>/<chip>/<plant>/<load>/<task>`` (chip in lower case)."""
        chip = self.chip_model.lower()
        return f"{self.suite}/{chip}/{self.plant}/{self.load}/{self.task}"

    @property
    def fixed(self) -> dict[str, int]:
        """Registers held at a task's value (v1 Turbo PMAC: Ixx69 and Ixx11); the rest are
        searched or at the chip's defaults."""
        from servogym.chips._family import get_chip

        if self.suite == SUITE_VERSION or get_chip(self.chip_model)[0].name != "pmac":
            return {}
        return {**PMAC_FIXED, "fatal_following_error_limit": pmac_trip_limit(self)}

    @property
    def plant_values(self) -> dict[str, float]:
        """Fixed plant values of the load condition."""
        loads = LOADS if self.suite == SUITE_VERSION else LOADS_V1
        return dict(loads[self.plant][self.load])

    @property
    def move(self) -> MoveSpec:
        """The task's move."""
        return TASKS[self.plant][self.task].move()

    def scenario(self) -> Scenario:
        """The scenario: nominal plant with the load's values, one move, default weights."""
        return Scenario(self.chip_model, self.plant, self.plant_values, moves=(self.move,))

    def describe(self) -> dict[str, Any]:
        """JSON-ready description."""
        return {
            "id": self.id,
            "suite": self.suite,
            "split": self.split,
            "chip_model": self.chip_model,
            "plant": self.plant,
            "load": self.load,
            "task": self.task,
            "plant_values": self.plant_values,
            "move": dataclasses.asdict(self.move),
            "fixed": self.fixed,
        }


def pmac_trip_limit(spec: InstanceSpec) -> int:
    """Ixx11 (1/16 count) for an instance: :data:`TRIP_FACTOR` times its following-error
    constraint, 1 % of the move in encoder counts."""
    from servogym.plants import get_plant

    counts = get_plant(spec.plant).counts_per_unit(spec.plant_values)
    return round(16 * TRIP_FACTOR * 0.01 * abs(spec.move.distance) * counts)


def _build_specs(suite: str) -> dict[str, InstanceSpec]:
    """Every chip x plant pair gets three (load, task) cells: two in train and one in
    held-out (v0); in v1 the pairs on one diagonal of the chip x plant square (one pair of
    each chip and of each plant) keep all three in train, so 36 train and 12 held-out.

    The cells rotate over the pairs (a Latin-square pattern), so every chip, plant, load and
    task appears in both splits, and no held-out instance is a train instance.
    """
    cells = [("light", "fast"), ("heavy", "slow"), ("heavy", "fast"), ("light", "slow")]
    out: dict[str, InstanceSpec] = {}
    k = 0
    for c, chip in enumerate(SUITES[suite]):
        for p, plant in enumerate(PLANTS):
            rot = [cells[(k + j) % 4] for j in range(4)]
            all_train = suite != SUITE_VERSION and p == (c + 3) % len(PLANTS)
            for j, (load, task) in enumerate(rot[:3]):
                split = "train" if j < 2 or all_train else "heldout"
                spec = InstanceSpec(chip, plant, load, task, split, suite)
                out[spec.id] = spec
            k += 1
    return out


SPLITS = ("train", "heldout", "all")


class Suite:
    """A versioned benchmark suite.

    Args:
        name: Suite name, one of :data:`SUITES`.
    """

    def __init__(self, name: str = DEFAULT_SUITE) -> None:
        if name not in SUITES:
            raise ValueError(f"unknown suite {name!r}; the suites are {', '.join(SUITES)}.")
        self.name = name
        self._specs: Mapping[str, InstanceSpec] = _specs(name)

    def ids(self, split: str = "train") -> list[str]:
        """Instance ids of a split (``"train"``, ``"heldout"`` or ``"all"``), in suite order."""
        if split not in SPLITS:
            raise ValueError(f"split must be one of {', '.join(SPLITS)}; got split={split!r}.")
        return [i for i, s in self._specs.items() if split == "all" or s.split == split]

    def spec(self, instance_id: str) -> InstanceSpec:
        """The spec of an id, with close matches in the error for a mistyped one."""
        try:
            return self._specs[instance_id]
        except KeyError:
            close = difflib.get_close_matches(instance_id, list(self._specs), n=3)
            hint = f" Did you mean {', '.join(close)}?" if close else ""
            raise KeyError(
                f"unknown instance {instance_id!r} in {self.name} "
                f"({len(self._specs)} instances).{hint}"
            ) from None

    def instance(self, instance_id: str) -> Any:
        """The :class:`~servogym.autotune.bench.BenchmarkInstance` of an id."""
        from servogym.autotune.bench._instance import BenchmarkInstance

        return BenchmarkInstance(self.spec(instance_id))

    def instances(self, split: str = "train") -> list[Any]:
        """The instances of a split."""
        return [self.instance(i) for i in self.ids(split)]


@functools.cache
def _specs(suite: str) -> dict[str, InstanceSpec]:
    return _build_specs(suite)


def get_suite(name: str = DEFAULT_SUITE) -> Suite:
    """A suite by name (:data:`SUITES`)."""
    return Suite(name)
