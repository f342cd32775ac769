"""The instances of ``servobench-v0``: chip model x plant x load condition x task.

Every instance is fully determined by its id, ``servobench-v0/<chip>/<plant>/<load>/<task>``
(e.g. ``servobench-v0/mc2100/vertical-axis/heavy/fast``): the id names the chip model, the
plant family, the fixed plant values of the load condition (:data:`LOADS`) and one
point-to-point move (:data:`TASKS`). The plant is the family's nominal instance with those
values; nothing is drawn at random, so an evaluation depends on the parameter set only.

A behaviour change (another move, load, cost weight or plant) makes a new suite version;
``servobench-v0`` stays as it is.
"""

from __future__ import annotations

import dataclasses
import difflib
from collections.abc import Mapping
from typing import Any

from servogym.sim._scenario import MoveSpec, Scenario

SUITE_VERSION = "servobench-v0"

CHIPS: tuple[str, ...] = ("MC2100", "MC58000", "6250")
"""Chip models: PMD Navigator (154 us), PMD Magellan (52 us), Parker 6250 (160 us). The PMAC
family is not in the chip registry yet, so it has no instance in v0."""

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
    """

    chip_model: str
    plant: str
    load: str
    task: str
    split: str

    @property
    def id(self) -> str:
        """``servobench-v0/<chip>/<plant>/<load>/<task>`` (chip in lower case)."""
        chip = self.chip_model.lower()
        return f"{SUITE_VERSION}/{chip}/{self.plant}/{self.load}/{self.task}"

    @property
    def plant_values(self) -> dict[str, float]:
        """Fixed plant values of the load condition."""
        return dict(LOADS[self.plant][self.load])

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
            "split": self.split,
            "chip_model": self.chip_model,
            "plant": self.plant,
            "load": self.load,
            "task": self.task,
            "plant_values": self.plant_values,
            "move": dataclasses.asdict(self.move),
        }


def _build_specs() -> dict[str, InstanceSpec]:
    """Every chip x plant pair gets two (load, task) cells in train and one in held-out.

    The cells rotate over the pairs (a Latin-square pattern), so every chip, plant, load and
    task appears in both splits, and no held-out instance is a train instance.
    """
    cells = [("light", "fast"), ("heavy", "slow"), ("heavy", "fast"), ("light", "slow")]
    out: dict[str, InstanceSpec] = {}
    k = 0
    for chip in CHIPS:
        for plant in PLANTS:
            rot = [cells[(k + j) % 4] for j in range(4)]
            for j, (load, task) in enumerate(rot[:3]):
                spec = InstanceSpec(chip, plant, load, task, "train" if j < 2 else "heldout")
                out[spec.id] = spec
            k += 1
    return out


_SPECS = _build_specs()
SPLITS = ("train", "heldout", "all")


class Suite:
    """A versioned benchmark suite.

    Args:
        name: Suite name; only ``"servobench-v0"`` exists.
    """

    def __init__(self, name: str = SUITE_VERSION) -> None:
        if name != SUITE_VERSION:
            raise ValueError(f"unknown suite {name!r}; the suites are {SUITE_VERSION}.")
        self.name = name
        self._specs: Mapping[str, InstanceSpec] = _SPECS

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


def get_suite(name: str = SUITE_VERSION) -> Suite:
    """A suite by name."""
    return Suite(name)
