"""Hand-tuned nominal parameter sets: a baseline per chip family and plant family.

Each set was tuned the way an engineer tunes by hand, on the nominal plant of the scenario's
default moves (docs/cost.md) and the family's first model: starting from the chip defaults,
two passes over kp, kd, ki, kvff, kaff, integration_limit (and bias where gravity acts), one
register at a time on a coarse 1-3-10 grid, keeping a change when the cost falls. Costs on
the nominal plant (MC2100), defaults in brackets: rotary 0.80 (18.07), two-mass 0.46
(100.0), vertical-axis 1.42 (21.92), arm 0.15 (2.91). Registers not listed keep the chip's
defaults. ``tests/agents/test_agents.py`` checks each set still beats the defaults there.
"""

from __future__ import annotations

NOMINAL_SETS: dict[tuple[str, str], dict[str, int]] = {
    ("pmd", "rotary"): {"kp": 100, "kd": 300, "ki": 1000, "kaff": 10000},
    ("pmd", "two-mass"): {"kp": 1000, "kd": 0, "ki": 0, "kaff": 3000},
    ("pmd", "vertical-axis"): {"kp": 3000, "kd": 1000, "ki": 10, "kaff": 3000},
    ("pmd", "arm"): {"kp": 300, "ki": 1000, "kvff": 0, "kaff": 10000, "bias": 3000},
}
"""Hand-tuned register values per (chip family, plant family), for the nominal plant."""


def nominal_set(family: str, plant: str) -> dict[str, int] | None:
    """The hand-tuned nominal set of a chip family on a plant family, or ``None``."""
    values = NOMINAL_SETS.get((family, plant))
    return None if values is None else dict(values)
