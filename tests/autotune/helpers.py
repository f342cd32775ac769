"""Small problems the autotune tests share (a short move keeps one evaluation ~1 ms)."""

from __future__ import annotations

from servogym.autotune import Constraints, SearchSpace, TuneProblem
from servogym.sim import MoveSpec, Scenario

SHORT_MOVES = {
    "rotary": (MoveSpec(1.0, 40.0, 3000.0, 0.03), MoveSpec(-1.0, 40.0, 3000.0, 0.03)),
    "vertical-axis": (MoveSpec(0.01, 0.2, 4.0, 0.03), MoveSpec(-0.01, 0.2, 4.0, 0.03)),
}
"""Out-and-back moves of about 0.1 s in all."""


def short_problem(
    chip: str = "MC2100",
    plant: str = "rotary",
    *,
    seed: int = 0,
    n_plants: int = 1,
    robust_mode: str = "mean",
    fixed: dict | None = None,
    names: tuple[str, ...] | None = None,
    objectives: tuple[str, ...] = ("cost",),
    constraints: bool = True,
    margins: bool = True,
) -> TuneProblem:
    """A tuning problem on short moves (``margins=False``: no margin constraints)."""
    scenario = Scenario(chip, plant, moves=SHORT_MOVES[plant])
    return TuneProblem(
        scenario=scenario,
        space=SearchSpace.for_chip(scenario.chip_model, names, fixed),
        n_plants=n_plants,
        robust_mode=robust_mode,
        objectives=objectives,
        constraints=Constraints(enabled=constraints)
        if margins
        else Constraints(enabled=constraints, min_gain_margin_db=None, min_phase_margin_deg=None),
        seed=seed,
    )


def trial_table(trials) -> list[tuple]:
    """What must be identical between two runs: number, kind, state, values, registers."""
    return [
        (
            t.number,
            t.user_attrs.get("kind"),
            t.state.name,
            None if t.values is None else tuple(t.values),
            tuple(sorted(t.user_attrs.get("registers", {}).items())),
            tuple(sorted(t.params.items())),
        )
        for t in trials
    ]
