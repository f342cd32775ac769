"""What both env families share: scenario set-up, plant draws, tables for docstrings."""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from typing import Any

import numpy as np

from servogym.chips._family import ChipFamily, get_chip
from servogym.plants import get_plant
from servogym.sim import Scenario

DEFAULT_REWARD_SCALE = 1.0
"""The env classes' default ``reward_scale``, and the ``-v0`` ids': rewards are minus the
cost. The ``-v1`` ids pass :data:`servogym._registration.REWARD_SCALE_V1` (0.01), so a move's
cost (about 0.01 .. 1 for a good set, 100 at the cap) gives rewards of order 0.0001 .. 1 and
a divergence (1000 .. 2000) -10 .. -20, a range SB3's default learning rates and value
networks handle. ``info["cost"]`` and ``info["raw_reward"]`` stay unscaled."""


def check_reward_scale(reward_scale: Any) -> float:
    """``reward_scale`` as a float; a ValueError unless it is a finite number > 0."""
    import math

    if (
        isinstance(reward_scale, bool)
        or not isinstance(reward_scale, int | float)
        or not math.isfinite(reward_scale)
        or reward_scale <= 0
    ):
        raise ValueError(
            f"reward_scale must be a finite number > 0 (1.0 in -v0 ids, 0.01 in -v1); got "
            f"reward_scale={reward_scale!r}."
        )
    return float(reward_scale)


def default_model(family: ChipFamily) -> str:
    """The chip model an env id of ``family`` uses unless ``chip_model=`` says otherwise."""
    return next(iter(family.models))


def make_scenario(
    chip_model: str | None,
    plant: str,
    scenario: Scenario | None,
    plant_values: Mapping[str, float] | None,
    sample_scale: float,
    family: str | None = None,
    plant_range: Mapping[str, tuple[float, float]] | None = None,
    moves: Sequence[Any] | None = None,
) -> Scenario:
    """The env's scenario: ``scenario`` itself, or one built from the other arguments.

    ``plant_range`` (``name -> (low, high)``) is the part of each parameter's legal range
    the episodes draw it from (``Scenario.plant_ranges``); validated like ``--plant-range``,
    and refused in one line when an end is more than the motor can move. ``moves``
    (``servogym.sim.MoveSpec``s) replace the plant family's default moves.
    """
    from servogym.envs._machine import MachineScenario, is_machine

    if scenario is not None:
        if not isinstance(scenario, Scenario | MachineScenario):
            raise TypeError(
                f"scenario must be a servogym.sim.Scenario (a multi-axis plant: a "
                f"servogym.envs._machine.MachineScenario); got {type(scenario).__name__}."
            )
        if plant_range:
            raise ValueError(
                "give plant_range or a scenario, not both (set Scenario.plant_ranges instead)"
            )
        if moves:
            raise ValueError("give moves or a scenario, not both (set Scenario.moves instead)")
        return scenario
    if chip_model is None:
        raise ValueError("give chip_model (e.g. 'MC2100') or a scenario")
    chip, model = get_chip(chip_model)
    if family is not None and chip.name != family:
        raise ValueError(
            f"chip_model must be a model of the {family!r} family for this env id; got "
            f"chip_model={chip_model!r} of family {chip.name!r} (its models: "
            f"{', '.join(get_chip_family_models(family))})."
        )
    if is_machine(plant):
        if moves:
            raise ValueError(
                f"moves are single-axis MoveSpecs; the {plant!r} plant runs its tasks (give a "
                f"MachineScenario with tasks instead); got moves={moves!r}."
            )
        return MachineScenario(
            model,
            plant,
            dict(plant_values or {}),
            randomise=True,
            sample_scale=sample_scale,
            plant_ranges=dict(plant_range or {}),
        )
    ranges = get_plant(plant).validate_ranges(
        plant_range, option="plant_range", fixed=plant_values or ()
    )
    return Scenario(
        model,
        plant,
        dict(plant_values or {}),
        randomise=True,
        sample_scale=sample_scale,
        plant_ranges=ranges,
        moves=tuple(moves or ()),
    )


def get_chip_family_models(family: str) -> list[str]:
    from servogym.chips._family import families

    return list(families()[family].models)


def options_plant_values(
    scenario: Scenario, options: Mapping[str, Any] | None, rng: np.random.Generator
) -> dict[str, float]:
    """A plant instance: ``options["plant_values"]`` over the scenario's fixed values and
    nominal ones when given, else a draw from the scenario's distribution."""
    options = options or {}
    if not isinstance(options, Mapping):
        raise ValueError(
            f"reset options must be a dict such as {{'plant_values': {{...}}}}; got "
            f"options={options!r}."
        )
    unknown = set(options) - {"plant_values"}
    if unknown:
        raise ValueError(f"reset options may only contain 'plant_values'; got {sorted(unknown)}.")
    if "plant_values" in options:
        if not isinstance(options["plant_values"], Mapping):
            raise ValueError(
                f"options['plant_values'] must be a dict of plant parameter values (SI); got "
                f"plant_values={options['plant_values']!r}."
            )
        from servogym.envs._machine import plant_family

        family = plant_family(scenario.plant)
        return family.validate({**scenario.plant_values, **dict(options["plant_values"])})
    return scenario.draw_plant(rng)


def markdown_table(header: Sequence[str], rows: Sequence[Sequence[str]]) -> str:
    """A Markdown table (used in env docstrings and docs/envs.md)."""
    lines = ["| " + " | ".join(header) + " |", "|" + "---|" * len(header)]
    lines += ["| " + " | ".join(str(c) for c in row) + " |" for row in rows]
    return "\n".join(lines)


def action_table(chip_model: str) -> str:
    """The action table of an env over ``chip_model`` (tunable registers), from the code."""
    chip, model = get_chip(chip_model)
    space = chip.parameter_space(model)
    rows = [
        (
            i,
            f"`{s.name}`",
            "log" if s.log else "linear",
            f"{s.low} .. {s.high}",
            s.default,
            f"int ({s.unit or '1'})",
        )
        for i, s in enumerate(space.tunable())
    ]
    return markdown_table(
        ("Num", "Parameter", "Scale", "Legal range", "Default", "Type (Unit)"), rows
    )
