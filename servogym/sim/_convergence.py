"""Does the default integration agree with the fine reference? The rule and its inputs.

docs/simulation.md ("Integration") states the rule this module implements:

* both runs reach the same divergence verdict;
* a set whose reference response settles and is well damped (every move settled, cost
  below :data:`WELL_DAMPED_COST`) keeps its encoder trace within
  :data:`TRACE_TOLERANCE_COUNTS` counts of the reference, or :data:`TRACE_TOLERANCE_FRACTION`
  of the reference's peak following error if that is more, and its cost within
  :data:`COST_TOLERANCE`;
* any other set (a slowly decaying or sustained oscillation, a limit cycle) keeps its cost
  within :data:`UNSETTLED_COST_TOLERANCE` (both at the cap counts as agreement): its
  trajectory is chaotic at the count level, the reference itself at 32 and 128 substeps
  disagrees there by thousands of counts, so no trace tolerance can be stated for it.

The sets it is applied to: per chip model and plant family, at the chip's default servo period
and the slowest one its docs call usable (:func:`period_settings`), a safe set tuned there (the
model-based tuner), random sets from the legal ranges, and every set the repository ships.
"""

from __future__ import annotations

import dataclasses
from typing import Any

import numpy as np

from servogym.chips._family import get_chip
from servogym.sim._runner import REFERENCE_SUBSTEPS
from servogym.sim._scenario import COST_CAP, Evaluation, Evaluator, Scenario

TRACE_TOLERANCE_COUNTS = 8
"""Largest encoder-trace difference (counts) of a settling set."""

TRACE_TOLERANCE_FRACTION = 0.005
"""... or this fraction of the reference's peak following error, if that is more."""

COST_TOLERANCE = (0.05, 0.02)
"""Relative and absolute cost tolerance of a settling set: ``|d| <= 0.05 * ref + 0.02``."""

UNSETTLED_COST_TOLERANCE = 0.10
"""Relative cost tolerance of a set that does not settle."""

WELL_DAMPED_COST = 10.0
"""Below this cost a settled response counts as well damped (docs/cost.md: a mean error of
about ten error scales, or a long oscillating transient, costs more)."""


def period_settings(chip_model: str) -> dict[str, dict[str, int]]:
    """Register values giving the chip's default and slowest usable servo period.

    PMD: the model's default, and one slot per axis for every axis the chip drives
    (``n_axes * minimum``: 616 us on a 4-axis Navigator, 208 us on a Magellan; docs/chips/pmd.md
    section 1). PMAC: the factory clocks, and the filter run every second servo interrupt
    (Ixx60 = 1, 885 us). Parker: SSFR4 (160 us, the 6250's default) and SSFR1 (330 us, the
    slowest of the SSFR table).
    """
    family, model = get_chip(chip_model)
    if family.name == "pmd":
        from servogym.chips.pmd._params import CHIP_MODELS

        rec = CHIP_MODELS[model]
        return {"default": {}, "slowest": {"sample_time_us": rec.n_axes * rec.min_sample_time_us}}
    if family.name == "pmac":
        return {"default": {}, "slowest": {"servo_cycle_extension": 1}}
    return {"default": {}, "slowest": {"ssfr": 1}}


def encoder_trace(ev: Evaluation) -> np.ndarray:
    """The encoder counts of every tick run, the moves joined."""
    return np.concatenate([r.traces.actual for r in ev.results])


def settled(ev: Evaluation) -> bool:
    """Whether every move settled, nothing diverged and the cost shows a well-damped loop."""
    return not ev.diverged and ev.cost < WELL_DAMPED_COST and all(m.settled for m in ev.metrics)


@dataclasses.dataclass(frozen=True)
class Agreement:
    """Default integration against the reference for one set.

    Attributes:
        ok: Whether the rule holds.
        settled: Whether the reference response settles (which rule applies).
        max_trace_difference: Largest encoder-trace difference over the common ticks (counts).
        trace_tolerance: The trace tolerance applied (counts; 0 for an unsettled set).
        cost, reference_cost: The two costs.
        diverged, reference_diverged: The two verdicts.
        why: What failed ("" when ``ok``).
    """

    ok: bool
    settled: bool
    max_trace_difference: int
    trace_tolerance: float
    cost: float
    reference_cost: float
    diverged: bool
    reference_diverged: bool
    why: str


def compare(default: Evaluation, reference: Evaluation) -> Agreement:
    """Apply the rule of the module doc to two evaluations of one set (traces needed)."""
    a, b = encoder_trace(default), encoder_trace(reference)
    n = min(a.size, b.size)
    diff = int(np.max(np.abs(a[:n] - b[:n]))) if n else 0
    is_settled = settled(reference)
    why = ""
    tol = 0.0
    if default.diverged != reference.diverged:
        why = f"verdict: diverged={default.diverged} vs reference {reference.diverged}"
    elif is_settled:
        tol = max(TRACE_TOLERANCE_COUNTS, TRACE_TOLERANCE_FRACTION * reference.max_following_error)
        rel, absolute = COST_TOLERANCE
        if diff > tol:
            why = f"trace differs by {diff} counts > {tol:g}"
        elif abs(default.cost - reference.cost) > rel * reference.cost + absolute:
            why = f"cost {default.cost:.4g} vs reference {reference.cost:.4g}"
    elif not reference.diverged:
        both_capped = default.cost >= COST_CAP and reference.cost >= COST_CAP
        close = abs(default.cost - reference.cost) <= UNSETTLED_COST_TOLERANCE * reference.cost
        if not (both_capped or close):
            why = f"cost {default.cost:.4g} vs reference {reference.cost:.4g} (not settled)"
    return Agreement(
        ok=not why,
        settled=is_settled,
        max_trace_difference=diff,
        trace_tolerance=tol,
        cost=float(default.cost),
        reference_cost=float(reference.cost),
        diverged=bool(default.diverged),
        reference_diverged=bool(reference.diverged),
        why=why,
    )


def agreement(scenario: Scenario, params: Any, substeps: int = REFERENCE_SUBSTEPS) -> Agreement:
    """Evaluate ``params`` at the default integration and the reference; compare them."""
    default = Evaluator(scenario).evaluate(params, traces=True)
    ref_sc = dataclasses.replace(scenario, integrator="rk4", substeps=substeps)
    reference = Evaluator(ref_sc).evaluate(params, traces=True)
    return compare(default, reference)
