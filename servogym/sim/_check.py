"""The check a parameter set passes before servogym reports, exports or stores it.

A set tuned on the default integration, the default loop latency and the nominal plant may
hold only there. :func:`check_params` re-simulates it on a stress set, each case with the fine
reference integration (RK4, :data:`~servogym.sim.REFERENCE_SUBSTEPS` substeps per period):

* the scenario itself (``reference``),
* every other choice of the chip's ``loop_latency`` assumption,
* the load (the plant family's ``load_param``) at -20 % and +20 %,
* every friction parameter at -50 % and +50 % together,
* and any extra plant instances given (a robust run's draws),

and, for every case, the loop's stability (decided exactly, from the closed loop's poles)
and margins, from that case's plant linearised at each point where the moves hold it still
(``_operating``) and the chip filter's linear response (``_margins``).

A set passes only when every case meets every limit: no divergence, a stable loop, the
following error and the saturation within their limits (defaults: 1 % of the longest move,
5 % of ticks at the motor limit; a limit cycle saturates), the gain and phase margins above
their minima (defaults 6 dB and 30 degrees). Each failure names the case, the check and by
how much; the report gives each case's margins and the worst with its case.
docs/simulation.md, "The check", states the rules.
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
from servogym.plants import feasible_range, get_plant, required_peak_effort
from servogym.sim._margins import Margins, bode_plot
from servogym.sim._operating import OperatingMargins, operating_margins
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
        max_following_error: Largest following error in any case (counts); ``None``: 1 %
            of the longest move of the scenario (as ``servogym tune``'s constraint).
        max_saturation: Largest fraction of ticks at the motor limit in any case.
    """

    min_gain_margin_db: float = 6.0
    min_phase_margin_deg: float = 30.0
    load_spread: float = 0.2
    friction_spread: float = 0.5
    reference_substeps: int = REFERENCE_SUBSTEPS
    max_following_error: float | None = None
    max_saturation: float = 0.05

    def __post_init__(self) -> None:
        fe = self.max_following_error
        if fe is not None and not (
            isinstance(fe, int | float) and not isinstance(fe, bool) and 0 < fe < math.inf
        ):
            raise ParameterError(
                "max_following_error must be > 0 counts (or None for 1 % of the longest "
                f"move); got max_following_error={fe!r}."
            )
        for name, low, high in (
            ("min_gain_margin_db", 0.0, 60.0),
            ("min_phase_margin_deg", 0.0, 90.0),
            ("load_spread", 0.0, 0.9),
            ("friction_spread", 0.0, 0.9),
            ("max_saturation", 0.0, 1.0),
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
        following_error_limit: The case's following-error limit (counts).
        margins: The loop's margins on the case's plant at its worst holding point.
        holding_point: That point (offset from the start position, joint units).
        failures: Each limit the case misses, naming it and by how much.
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
    following_error_limit: float = math.nan
    margins: Margins | None = None
    holding_point: float = 0.0
    failures: tuple[str, ...] = ()

    @property
    def passed(self) -> bool:
        """Whether the case meets every limit."""
        return not self.failures

    def to_dict(self) -> dict[str, Any]:
        """JSON-ready."""
        d = {f.name: getattr(self, f.name) for f in dataclasses.fields(self)}
        d["plant_changes"] = dict(self.plant_changes)
        d["margins"] = None if self.margins is None else self.margins.to_dict()
        d["failures"] = list(self.failures)
        d["passed"] = self.passed
        for k in ("divergence_time_s", "following_error_limit"):
            if not math.isfinite(d[k]):
                d[k] = None
        return d


@dataclasses.dataclass(frozen=True)
class CheckReport:
    """The outcome of :func:`check_params`.

    Attributes:
        passed: Whether the set passed every check.
        failures: One line per failed check, naming the case, the check and by how much.
        cases: The stress set's results, the reference first, each with its margins.
        margins: Margins of the reference case (the scenario's own plant and latency).
        margins_by_latency: Margins at each ``loop_latency`` choice (nominal plant).
        worst: The worst of each margin over the cases, with its case:
            ``{"gain_margin_db": {"value": ..., "case": ...}, ...}`` for the gain and
            phase margins, the delay margin and the bandwidth (the lowest).
        limits: The limits applied.
        elapsed_s: Wall time of the check (s).
        candidates: When a tuner's result was chosen by checking its best trials in turn:
            each trial checked, its cost, whether it passed and why not.
        fallback: When the set written is not the tuner's best trial (which failed): the
            best trial, its cost and failures, the written trial and its cost, and their
            ratio; ``None`` otherwise.
    """

    passed: bool
    failures: tuple[str, ...]
    cases: tuple[CaseResult, ...]
    margins: Margins
    margins_by_latency: dict[str, Margins]
    limits: CheckLimits
    elapsed_s: float
    candidates: tuple[dict[str, Any], ...] = ()
    worst: dict[str, dict[str, Any]] = dataclasses.field(default_factory=dict)
    fallback: dict[str, Any] | None = None

    def to_dict(self) -> dict[str, Any]:
        """JSON-ready (for best_params.json's provenance and check.json)."""
        return {
            "passed": self.passed,
            "failures": list(self.failures),
            "margins": self.margins.to_dict(),
            "worst": {
                k: {"value": v["value"] if math.isfinite(v["value"]) else None, "case": v["case"]}
                for k, v in self.worst.items()
            },
            "margins_by_latency": {k: m.to_dict() for k, m in self.margins_by_latency.items()},
            "cases": [c.to_dict() for c in self.cases],
            "limits": dataclasses.asdict(self.limits),
            "elapsed_s": self.elapsed_s,
            "candidates": list(self.candidates),
            "fallback": self.fallback,
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
    movable = None
    if scenario.motor_check:
        movable = feasible_range(family, family.load_param, nominal, scenario.moves)
    for sign in (-1, 1):
        changes = _scaled(family, nominal, [family.load_param], 1 + sign * limits.load_spread)
        name = f"load {sign * pct:+d}%"
        x = changes[family.load_param]
        if movable is not None and not movable[0] <= x <= movable[1]:
            # The load the motor can move with the moves is the envelope the set is for:
            # a heavier load than that is refused as a plant, so it is not a stress case.
            x = min(max(x, movable[0]), movable[1])
            changes[family.load_param] = x
            name += " (motor's max)"
        cases.append(_Case(name, asm.loop_latency, changes))
    frictions = [p.name for p in family.params if "friction" in p.name]
    pct = round(100 * limits.friction_spread)
    for sign in (-1, 1):
        changes = _scaled(family, nominal, frictions, 1 + sign * limits.friction_spread)
        cases.append(_Case(f"friction {sign * pct:+d}%", asm.loop_latency, changes))
    return cases


def following_error_limit(scenario: Scenario, counts_per_unit: float, limits: CheckLimits):
    """The following-error limit in counts: the given one, or 1 % of the longest move."""
    if limits.max_following_error is not None:
        return float(limits.max_following_error)
    return 0.01 * max(abs(m.distance) for m in scenario.moves) * counts_per_unit


def _run_case(
    scenario: Scenario, params: Any, case: _Case, limits: CheckLimits
) -> tuple[CaseResult, OperatingMargins]:
    asm = scenario.assumptions or scenario.chip.default_assumptions()
    case_asm = dataclasses.replace(asm, loop_latency=case.loop_latency)
    sc = dataclasses.replace(
        scenario,
        plant_values={**scenario.plant_values, **case.plant_changes},
        plant_ranges={},  # one instance per case, no draws
        motor_check=False,  # a stress case may overload the motor on purpose
        randomise=False,
        integrator="rk4",
        substeps=limits.reference_substeps,
        assumptions=case_asm,
        margins=False,
    )
    evaluator = Evaluator(sc)
    ev = evaluator.evaluate(params)
    t_div = math.nan
    if ev.diverged:
        t_div = sum(m.n_ticks * m.dt for m in ev.metrics)
    last = ev.metrics[-1]
    op = operating_margins(
        sc.chip, params, case_asm, evaluator.plant, sc.moves,
        limits=(limits.min_gain_margin_db, limits.min_phase_margin_deg),
    )  # fmt: skip
    fe_limit = following_error_limit(sc, evaluator.plant.io.counts_per_unit, limits)
    result = CaseResult(
        name=case.name,
        loop_latency=case.loop_latency,
        plant_changes=dict(case.plant_changes),
        cost=float(ev.cost),
        diverged=bool(ev.diverged),
        divergence_reason=last.divergence_reason if ev.diverged else "none",
        divergence_time_s=t_div,
        max_following_error=float(ev.max_following_error),
        saturation_fraction=float(ev.saturation_fraction),
        following_error_limit=fe_limit,
        margins=op.margins,
        holding_point=op.points[op.worst],
    )
    family = get_plant(scenario.plant)
    failures = case_failures(result, op, limits, family.joint_unit)
    need = required_peak_effort(family, evaluator.plant.values, sc.moves, plant=evaluator.plant)
    share = float(params.motor_limit) / FULL_SCALE
    if share < need.fraction:  # the cause of what else fails: named first
        failures.insert(0, command_limit_failure(case.name, share, need))
    return dataclasses.replace(result, failures=tuple(failures)), op


FULL_SCALE = 32767
"""The chips' signed 16-bit motor command at full scale (``params.motor_limit`` counts)."""


def command_limit_failure(case: str, share: float, need: Any) -> str:
    """The set's own command limit is below what the moves need of the motor."""
    return (
        f"{case}: command limit: the set limits the motor command to {share:.1%} of full "
        f"scale (params.motor_limit; PMD motor_limit, PMAC Ixx69 output_limit), below the "
        f"{need.fraction:.1%} of the motor's peak the moves need ({need.text()})"
    )


def case_failures(
    r: CaseResult, op: OperatingMargins, limits: CheckLimits, unit: str = ""
) -> list[str]:
    """Each limit one case misses: ``"<case>: <check> <value> <relation> <limit> (<gap>)"``."""
    out = []
    if r.diverged:
        out.append(f"{r.name}: diverged ({r.divergence_reason}) at t = {r.divergence_time_s:.4g} s")
    out += run_failures(r.name, r.max_following_error, r.following_error_limit,
                        r.saturation_fraction, limits)  # fmt: skip
    where = r.name
    if op.position_dependent:
        where += f" (holding at {op.points[op.worst]:+.4g} {unit}".rstrip() + ")"
    return out + margin_failures(where, op.margins, limits)  # the worst holding point's


def run_failures(
    name: str, fe: float, fe_max: float, saturation: float, limits: CheckLimits
) -> list[str]:
    """The following error (counts) and the saturation (fraction of ticks) above their
    limits, each naming ``name`` and by how much."""
    out = []
    if fe > fe_max:
        out.append(
            f"{name}: following error: {fe:.0f} counts > {fe_max:.4g} counts "
            f"({fe - fe_max:.4g} counts over)"
        )
    sat_max = limits.max_saturation
    if saturation > sat_max:
        out.append(
            f"{name}: saturation: {100 * saturation:.1f} % of ticks at the motor limit > "
            f"{100 * sat_max:g} % ({100 * (saturation - sat_max):.1f} points over)"
        )
    return out


def margin_failures(where: str, m: Margins, limits: CheckLimits) -> list[str]:
    """An unstable loop (with its growth per tick), else each margin below its minimum."""
    if not m.stable:
        radius = m.spectral_radius
        grows = (
            f": spectral radius {radius:.4g}, grows {radius:.3g}x per tick"
            if math.isfinite(radius) and radius > 1
            else ""
        )
        return [f"{where}: unstable closed loop{grows}"]
    out = []
    gm, pm = m.gain_margin_db, m.phase_margin_deg
    if gm < limits.min_gain_margin_db:
        out.append(
            f"{where}: gain margin: {gm:.2f} dB < {limits.min_gain_margin_db:g} dB "
            f"({limits.min_gain_margin_db - gm:.2f} dB short)"
        )
    if pm < limits.min_phase_margin_deg:
        out.append(
            f"{where}: phase margin: {pm:.2f} deg < {limits.min_phase_margin_deg:g} deg "
            f"({limits.min_phase_margin_deg - pm:.2f} deg short)"
        )
    return out


def loop_margins(scenario: Scenario, params: Any, latencies: Sequence[str] | None = None):
    """``{loop_latency: OperatingMargins}`` of ``params`` on the scenario's nominal plant
    (with its fixed values), for each of ``latencies`` (``None``: the scenario's own)."""
    chip = scenario.chip
    asm = scenario.assumptions or chip.default_assumptions()
    family = get_plant(scenario.plant)
    plant = family.build({**family.nominal(), **scenario.plant_values})
    cache: dict = {}  # the continuous models are the same for every latency
    out = {}
    for choice in latencies or [asm.loop_latency]:
        a = dataclasses.replace(asm, loop_latency=choice)
        out[choice] = operating_margins(chip, params, a, plant, scenario.moves, cache=cache)
    return out


WORST_KEYS = ("gain_margin_db", "phase_margin_deg", "delay_margin_s", "bandwidth_hz")
"""The margins :attr:`CheckReport.worst` gives (each the smallest over the cases)."""


def worst_margins(cases: Sequence[CaseResult]) -> dict[str, dict[str, Any]]:
    """The smallest of each of :data:`WORST_KEYS` over the cases, with the case's name (an
    unstable case's gain and phase margins are <= 0, so it is the worst)."""
    out = {}
    for key in WORST_KEYS:
        rows = [(getattr(c.margins, key), c.name) for c in cases if c.margins is not None]
        rows = [(v, n) for v, n in rows if not math.isnan(v)]
        if rows:
            v, n = min(rows, key=lambda r: r[0])
            out[key] = {"value": float(v), "case": n}
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
        ran = list(pool.map(lambda c: _run_case(scenario, params, c, limits), cases))
    results = [r for r, _ in ran]
    failures = [line for r in results for line in r.failures]
    by_latency = {
        r.loop_latency: r.margins
        for r in results
        if r.margins is not None and (r.name == "reference" or r.name.startswith("latency "))
    }
    reference, reference_op = ran[0]
    if bode_path is not None:
        write_bode(bode_path, scenario, params, limits, reference_op)
    return CheckReport(
        passed=not failures,
        failures=tuple(failures),
        cases=tuple(results),
        margins=reference.margins,
        margins_by_latency=by_latency,
        limits=limits,
        elapsed_s=time.perf_counter() - t0,
        worst=worst_margins(results),
    )


def write_bode(path: Any, scenario: Scenario, params: Any, limits: CheckLimits, computed=None):
    """Write the Bode plot of the open loop of ``params`` on the nominal plant at its worst
    holding point (PNG); ``computed``: its :class:`OperatingMargins`, when known."""
    asm = scenario.assumptions or scenario.chip.default_assumptions()
    op = computed or loop_margins(scenario, params)[asm.loop_latency]
    a = op.analysis
    where = ""
    if op.position_dependent:
        unit = get_plant(scenario.plant).joint_unit
        where = f", holding at {op.points[op.worst]:+.4g} {unit}"
    title = (
        f"{scenario.chip_model} on {scenario.plant}: open loop (latency {asm.loop_latency}{where})"
    )
    bode_plot(path, a.freqs_hz, a.loop, a.margins, title,
              (limits.min_gain_margin_db, limits.min_phase_margin_deg))  # fmt: skip
