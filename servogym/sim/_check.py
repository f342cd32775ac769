"""The check a parameter set passes before servogym reports, exports or stores it.

A set tuned on the default integration, the default loop latency and the nominal plant may
hold only there. :func:`check_params` re-simulates it on a stress set, each case with the fine
reference integration (RK4, :data:`~servogym.sim.REFERENCE_SUBSTEPS` substeps per period):

* the scenario itself (``reference``),
* every other choice of the chip's ``loop_latency`` assumption,
* the load (the plant family's ``load_param``) at -20 % and +20 %,
* every friction parameter at -50 % and +50 % together,
* and any extra plant instances given (a robust run's draws),

and computes the loop's stability margins from the plant linearised at its operating point
and the chip filter's linear response (``_margins``). A set fails when it diverges in any case
or when a margin falls below its minimum (defaults 6 dB and 30 degrees); each failure names
the check and by how much. docs/simulation.md, "The check", states the rules.
"""

from __future__ import annotations

import concurrent.futures as cf
import dataclasses
import math
import os
import time
from collections.abc import Mapping, Sequence
from typing import Any

from servogym.chips._space import ParameterError
from servogym.plants import get_plant
from servogym.sim._margins import (
    Margins,
    bode_plot,
    continuous_model,
    margins,
    open_loop,
    plant_response,
)
from servogym.sim._runner import REFERENCE_SUBSTEPS
from servogym.sim._scenario import Evaluator, Scenario


@dataclasses.dataclass(frozen=True)
class CheckLimits:
    """What a set must meet, and how hard the stress set pushes.

    Attributes:
        min_gain_margin_db: Smallest acceptable gain margin (dB).
        min_phase_margin_deg: Smallest acceptable phase margin (degrees).
        load_spread: Relative change of the load (inertia or payload) in the stress set.
        friction_spread: Relative change of every friction parameter in the stress set.
        reference_substeps: RK4 substeps per servo period of the reference integration.
    """

    min_gain_margin_db: float = 6.0
    min_phase_margin_deg: float = 30.0
    load_spread: float = 0.2
    friction_spread: float = 0.5
    reference_substeps: int = REFERENCE_SUBSTEPS

    def __post_init__(self) -> None:
        for name, low, high in (
            ("min_gain_margin_db", 0.0, 60.0),
            ("min_phase_margin_deg", 0.0, 90.0),
            ("load_spread", 0.0, 0.9),
            ("friction_spread", 0.0, 0.9),
        ):
            value = getattr(self, name)
            if not (isinstance(value, int | float) and low <= value <= high):
                raise ParameterError(
                    f"{name} must satisfy {low:g} <= {name} <= {high:g}; got {name}={value!r}."
                )
        n = self.reference_substeps
        if isinstance(n, bool) or not isinstance(n, int) or not 1 <= n <= 1024:
            raise ParameterError(
                f"reference_substeps must be an integer with 1 <= reference_substeps <= 1024; "
                f"got reference_substeps={n!r}."
            )


@dataclasses.dataclass(frozen=True)
class CaseResult:
    """One case of the stress set.

    Attributes:
        name: Short name (``reference``, ``latency same_tick``, ``load -20%`` ...).
        loop_latency: The latency assumption of the case.
        plant_changes: The plant values the case changes (name -> value).
        cost: The scenario cost (docs/cost.md).
        diverged: Whether an episode diverged.
        divergence_reason: Why (``none`` when it did not).
        divergence_time_s: When, from the start of the moves (s; ``nan`` when it did not).
        max_following_error: Largest following error (counts).
        saturation_fraction: Fraction of ticks at the motor limit.
    """

    name: str
    loop_latency: str
    plant_changes: dict[str, float]
    cost: float
    diverged: bool
    divergence_reason: str
    divergence_time_s: float
    max_following_error: float
    saturation_fraction: float

    def to_dict(self) -> dict[str, Any]:
        """JSON-ready."""
        d = dataclasses.asdict(self)
        if not math.isfinite(d["divergence_time_s"]):
            d["divergence_time_s"] = None
        return d


@dataclasses.dataclass(frozen=True)
class CheckReport:
    """The outcome of :func:`check_params`.

    Attributes:
        passed: Whether the set passed every check.
        failures: One line per failed check, naming it and by how much.
        cases: The stress set's results, the reference first.
        margins: Margins at the scenario's own loop latency.
        margins_by_latency: Margins at each ``loop_latency`` choice.
        limits: The limits applied.
        elapsed_s: Wall time of the check (s).
        candidates: When a tuner's result was chosen by checking its best trials in turn:
            each trial checked, whether it passed and why not.
    """

    passed: bool
    failures: tuple[str, ...]
    cases: tuple[CaseResult, ...]
    margins: Margins
    margins_by_latency: dict[str, Margins]
    limits: CheckLimits
    elapsed_s: float
    candidates: tuple[dict[str, Any], ...] = ()

    def to_dict(self) -> dict[str, Any]:
        """JSON-ready (for best_params.json's provenance and check.json)."""
        return {
            "passed": self.passed,
            "failures": list(self.failures),
            "margins": self.margins.to_dict(),
            "margins_by_latency": {k: m.to_dict() for k, m in self.margins_by_latency.items()},
            "cases": [c.to_dict() for c in self.cases],
            "limits": dataclasses.asdict(self.limits),
            "elapsed_s": self.elapsed_s,
            "candidates": list(self.candidates),
        }


@dataclasses.dataclass(frozen=True)
class _Case:
    name: str
    loop_latency: str
    plant_changes: dict[str, float]


def _scaled(family: Any, values: Mapping[str, float], names: Sequence[str], factor: float):
    """``values`` with each of ``names`` times ``factor``, kept inside its legal range."""
    out = {}
    for name in names:
        p = family.param(name)
        x = min(max(values[name] * factor, p.low), p.high)
        out[name] = round(x) if p.integer else x
    return out


def stress_cases(scenario: Scenario, limits: CheckLimits) -> list[_Case]:
    """The cases :func:`check_params` runs (see the module doc)."""
    chip = scenario.chip
    asm = scenario.assumptions or chip.default_assumptions()
    family = get_plant(scenario.plant)
    nominal = {**family.nominal(), **scenario.plant_values}
    cases = [_Case("reference", asm.loop_latency, {})]
    for choice in type(asm).CHOICES["loop_latency"]:
        if choice != asm.loop_latency:
            cases.append(_Case(f"latency {choice}", choice, {}))
    pct = round(100 * limits.load_spread)
    for sign in (-1, 1):
        changes = _scaled(family, nominal, [family.load_param], 1 + sign * limits.load_spread)
        cases.append(_Case(f"load {sign * pct:+d}%", asm.loop_latency, changes))
    frictions = [p.name for p in family.params if "friction" in p.name]
    pct = round(100 * limits.friction_spread)
    for sign in (-1, 1):
        changes = _scaled(family, nominal, frictions, 1 + sign * limits.friction_spread)
        cases.append(_Case(f"friction {sign * pct:+d}%", asm.loop_latency, changes))
    return cases


def _run_case(scenario: Scenario, params: Any, case: _Case, substeps: int) -> CaseResult:
    asm = scenario.assumptions or scenario.chip.default_assumptions()
    sc = dataclasses.replace(
        scenario,
        plant_values={**scenario.plant_values, **case.plant_changes},
        plant_ranges={},  # one instance per case, no draws
        motor_check=False,  # a stress case may overload the motor on purpose
        randomise=False,
        integrator="rk4",
        substeps=substeps,
        assumptions=dataclasses.replace(asm, loop_latency=case.loop_latency),
    )
    ev = Evaluator(sc).evaluate(params)
    t_div = math.nan
    if ev.diverged:
        t_div = sum(m.n_ticks * m.dt for m in ev.metrics)
    last = ev.metrics[-1]
    return CaseResult(
        name=case.name,
        loop_latency=case.loop_latency,
        plant_changes=dict(case.plant_changes),
        cost=float(ev.cost),
        diverged=bool(ev.diverged),
        divergence_reason=last.divergence_reason if ev.diverged else "none",
        divergence_time_s=t_div,
        max_following_error=float(ev.max_following_error),
        saturation_fraction=float(ev.saturation_fraction),
    )


def loop_margins(scenario: Scenario, params: Any, latencies: Sequence[str] | None = None):
    """``{loop_latency: (freqs_hz, L, Margins)}`` of ``params`` on the scenario's nominal
    plant, for each of ``latencies`` (``None``: the scenario's own); one plant build."""
    chip = scenario.chip
    asm = scenario.assumptions or chip.default_assumptions()
    family = get_plant(scenario.plant)
    plant = family.build({**family.nominal(), **scenario.plant_values})
    dt = chip.sample_time_s(params)
    continuous = continuous_model(plant)  # the same for every latency
    out = {}
    for choice in latencies or [asm.loop_latency]:
        a = dataclasses.replace(asm, loop_latency=choice)
        freqs, response = plant_response(plant, dt, chip.loop_latency_s(params, a), continuous)
        loop = open_loop(chip, params, a, freqs, response)
        out[choice] = (freqs, loop, margins(freqs, loop))
    return out


def check_params(
    params: Any,
    scenario: Scenario,
    limits: CheckLimits | None = None,
    *,
    extra_plants: Sequence[Mapping[str, float]] = (),
    workers: int | None = None,
    bode_path: Any = None,
) -> CheckReport:
    """Check a parameter set on the stress set and its margins (see the module doc).

    Args:
        params: The chip parameter set.
        scenario: Chip, plant (with its fixed values), moves, weights and assumptions.
        limits: The minima and spreads (defaults: :class:`CheckLimits`).
        extra_plants: More plant instances (complete values) to run at the reference.
        workers: Threads for the cases (default: every core).
        bode_path: Where to write the Bode plot of the open loop (PNG), if anywhere.
    """
    limits = limits or CheckLimits()
    t0 = time.perf_counter()
    asm = scenario.assumptions or scenario.chip.default_assumptions()
    cases = stress_cases(scenario, limits)
    for i, values in enumerate(extra_plants):
        changes = {k: v for k, v in values.items() if scenario.plant_values.get(k) != v}
        cases.append(_Case(f"plant draw {i + 1}", asm.loop_latency, changes))
    n_workers = workers or os.cpu_count() or 1
    with cf.ThreadPoolExecutor(n_workers) as pool:
        results = list(
            pool.map(lambda c: _run_case(scenario, params, c, limits.reference_substeps), cases)
        )
    computed = loop_margins(scenario, params, type(asm).CHOICES["loop_latency"])
    by_latency = {choice: m for choice, (_, _, m) in computed.items()}
    main = computed[asm.loop_latency]
    failures = []
    for r in results:
        if r.diverged:
            failures.append(
                f"{r.name}: diverged ({r.divergence_reason}) at t = {r.divergence_time_s:.4g} s"
            )
    m = main[2]
    if m.gain_margin_db < limits.min_gain_margin_db:
        failures.append(
            f"gain margin: {m.gain_margin_db:.2f} dB < {limits.min_gain_margin_db:g} dB "
            f"({limits.min_gain_margin_db - m.gain_margin_db:.2f} dB short)"
        )
    if m.phase_margin_deg < limits.min_phase_margin_deg:
        failures.append(
            f"phase margin: {m.phase_margin_deg:.2f} deg < {limits.min_phase_margin_deg:g} deg "
            f"({limits.min_phase_margin_deg - m.phase_margin_deg:.2f} deg short)"
        )
    if bode_path is not None:
        write_bode(bode_path, scenario, params, limits, main)
    return CheckReport(
        passed=not failures,
        failures=tuple(failures),
        cases=tuple(results),
        margins=m,
        margins_by_latency=by_latency,
        limits=limits,
        elapsed_s=time.perf_counter() - t0,
    )


def write_bode(path: Any, scenario: Scenario, params: Any, limits: CheckLimits, computed=None):
    """Write the Bode plot of the open loop of ``params`` on the nominal plant (PNG)."""
    asm = scenario.assumptions or scenario.chip.default_assumptions()
    freqs, loop, m = computed or loop_margins(scenario, params)[asm.loop_latency]
    title = f"{scenario.chip_model} on {scenario.plant}: open loop (latency {asm.loop_latency})"
    bode_plot(path, freqs, loop, m, title,
              (limits.min_gain_margin_db, limits.min_phase_margin_deg))  # fmt: skip
