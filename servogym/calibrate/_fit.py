"""Fitting a plant (and the chip's loop latency) to a trace.

For every distinct latency the chip's ``loop_latency`` choices give, the plant parameters
being fitted are found by ``scipy.optimize.least_squares`` (trust region, bounds = the legal
ranges) on three stacked residuals, each divided by its signal's size:

* the **closed-loop** replay's encoder position minus the recorded one, over the recorded
  following error's RMS;
* its motor command minus the recorded one, over the recorded command's RMS;
* the **open-loop** replay's encoder position (the recorded command into the plant) minus
  the recorded one, over the recorded following error's RMS.

Parameters are fitted in ``log(value / start)`` (all are positive, their ranges span
decades); finite differences take 10 % steps, large enough to see through the encoder's and
the filter's integer steps. The cost is rugged (counts, Coulomb friction's stick), so each
fit starts from the best Sobol points, restarts at other shares of Coulomb in the total
friction, and polishes one parameter at a time (docs/calibrate.md, "The fit"). The latency
whose fitted closed-loop replay has the lowest RMS position error wins; it is "decided" when
the runner-up's is at least :data:`LATENCY_DECIDED` times as large. Each value's uncertainty
is one standard deviation from the Jacobian at the optimum, ``s^2 (J^T J)^-1`` with ``s^2``
the residual variance, inflated by ``(1 + rho) / (1 - rho)`` for the residuals' lag-1
autocorrelation ``rho``; it covers the noise, not a model that is wrong in the way a real
axis is (a lower bound there).
"""

from __future__ import annotations

import dataclasses
import time
from collections.abc import Mapping, Sequence
from typing import Any

import numpy as np

from servogym.calibrate._replay import Replay, Replayer
from servogym.calibrate._trace import Trace, TraceError, check_trace
from servogym.chips._family import family_of

DIFF_STEP = 0.1
"""Finite-difference step of the fit in log space (10 %): smaller steps see the encoder's
and the filter's integer steps instead of the slope (3 % stalls on the vertical axis)."""

MAX_NFEV = 60
"""Most residual evaluations per latency candidate (``least_squares``'s ``max_nfev``)."""

N_STARTS = 32
"""Points of the scrambled Sobol set over the sampling ranges the fit starts from the best of."""

FRICTION_SHARES = (0.05, 0.2, 0.4, 0.6, 0.8, 0.95)
"""Shares of Coulomb friction in the total friction at the moves' top speed that a fit is
also started from (the best of them, when it is nearly as good as the fit's optimum)."""

POLISH_FACTORS = (0.25, 0.5, 0.8, 1.25, 2.0, 4.0)
"""Factors each fitted parameter is tried at, alone, after a fit (then refitted from the
best of them when it lowers the cost by 10 %)."""

POLISH_ROUNDS = 2
"""Most rounds of those trials."""

REFIT_RATIO = 10.0
"""Latency candidates whose brief fit costs at most this many times the best are fitted in
full (from their own best starts)."""

LATENCY_DECIDED = 1.5
"""The latency is reported as decided when the runner-up's replay RMS error is at least
this many times the winner's."""

N_LOCAL = 3
"""Fits run from the best of those points (and the nominal start); the best fit wins."""

TOLERANCE = 1e-3
"""``least_squares``'s ``ftol`` and ``xtol``: a trace of whole counts supports no finer."""

SCREEN_NFEV = 8
"""Iterations for each other latency candidate, from the default's fit (the best is then
fitted to convergence)."""

MAX_ERROR_RATIO = 0.05
"""A fit is poor when the closed-loop replay's RMS position error exceeds this fraction of
the recorded RMS following error (and :data:`MIN_ERROR_COUNTS`)."""

MIN_ERROR_COUNTS = 4.0
"""RMS replay errors up to this many counts always pass (quantisation, noise)."""

UNDETERMINED = 0.5
"""A fitted value whose relative uncertainty exceeds this is reported as poorly determined."""

NOT_FITTED = ("encoder_counts_per_rev",)
"""Parameters a trace never fits (integers; the trace's own units depend on them)."""


class FitError(TraceError):
    """A trace that cannot determine what was asked (one line, exit code 2)."""


@dataclasses.dataclass(frozen=True)
class FittedValue:
    """One fitted plant parameter.

    Attributes:
        name: Plant parameter name.
        value: Fitted value, in the parameter's unit.
        sigma: One-standard-deviation uncertainty, same unit.
        start: The value the fit started from.
        low, high: The legal range it was fitted in.
    """

    name: str
    value: float
    sigma: float
    start: float
    low: float
    high: float

    @property
    def relative_sigma(self) -> float:
        """``sigma / value``."""
        return self.sigma / abs(self.value) if self.value else float("inf")

    def to_dict(self) -> dict[str, Any]:
        """JSON-ready."""
        return {"value": self.value, "sigma": self.sigma, "relative_sigma": self.relative_sigma,
                "start": self.start, "range": [self.low, self.high]}  # fmt: skip


@dataclasses.dataclass(frozen=True)
class LatencyResult:
    """The fit at one latency candidate: its choices (same latency), latency and cost."""

    choices: tuple[str, ...]
    latency_s: float
    cost: float
    rms_error_counts: float


@dataclasses.dataclass(frozen=True)
class Calibration:
    """A calibrated plant and how well it replays the trace.

    Attributes:
        family: Plant family name.
        plant: Every plant parameter's value (fitted, fixed or nominal).
        fitted: The fitted parameters with their uncertainties.
        fixed: The parameters held at given values (``--fix``).
        latency: The winning ``loop_latency`` choice (the family's name for it).
        latency_choices: Every choice with the same latency (they cannot be told apart).
        latency_s: Its latency (s).
        latencies: The fit at every latency candidate, best first.
        rms_error_counts: RMS of the closed-loop replay's position error (counts).
        rms_command_error: RMS of its motor-command error (counts).
        open_loop_rms_error_counts: RMS of the open-loop replay's position error (counts).
        rms_following_error: RMS of the recorded following error (counts), the scale.
        error_ratio: ``rms_error_counts / rms_following_error``.
        poor: The fit fails (the replay does not reproduce the trace).
        poorly_determined: Fitted names whose relative uncertainty exceeds
            :data:`UNDETERMINED`.
        replay: The closed-loop replay at the fitted plant.
        open_replay: The open-loop replay at the fitted plant.
        fit_time_s: Wall time of the fit (s).
        n_evaluations: Replays run.
        max_error_ratio: The poor-fit threshold it was judged by.
    """

    family: str
    plant: dict[str, float]
    fitted: tuple[FittedValue, ...]
    fixed: dict[str, float]
    latency: str
    latency_choices: tuple[str, ...]
    latency_s: float
    latencies: tuple[LatencyResult, ...]
    rms_error_counts: float
    rms_command_error: float
    open_loop_rms_error_counts: float
    rms_following_error: float
    error_ratio: float
    poor: bool
    poorly_determined: tuple[str, ...]
    replay: Replay
    open_replay: Replay
    fit_time_s: float
    n_evaluations: int
    max_error_ratio: float = MAX_ERROR_RATIO

    @property
    def latency_margin(self) -> float:
        """The runner-up latency's replay RMS error over the winner's (``inf`` with one
        candidate, or a winner that replays the trace exactly)."""
        if len(self.latencies) < 2:
            return float("inf")
        best = self.latencies[0].rms_error_counts
        return self.latencies[1].rms_error_counts / best if best > 0 else float("inf")

    @property
    def latency_decided(self) -> bool:
        """Whether the trace tells the latency from the runner-up (margin at least
        :data:`LATENCY_DECIDED`)."""
        return self.latency_margin >= LATENCY_DECIDED

    def verdict(self) -> str:
        """One line: good or poor, and why."""
        if not self.poor:
            return (
                f"fit: the replay follows the trace within {self.rms_error_counts:.3g} counts "
                f"RMS ({100 * self.error_ratio:.2g} % of the recorded RMS following error "
                f"{self.rms_following_error:.4g} counts)"
            )
        head = (
            f"poor fit: the closed-loop replay misses the trace by {self.rms_error_counts:.4g} "
            f"counts RMS, {100 * self.error_ratio:.3g} % of the recorded RMS following error "
            f"{self.rms_following_error:.4g} counts (at most {100 * self.max_error_ratio:g} % "
            f"or {MIN_ERROR_COUNTS:g} counts)"
        )
        if self.open_loop_rms_error_counts * 5 < self.rms_error_counts:
            return (
                f"{head}; the plant does reproduce the recorded motor command's motion "
                f"(open-loop replay {self.open_loop_rms_error_counts:.3g} counts RMS), so the "
                f"register set or the chip (or one of its assumptions) differs from what ran"
            )
        return (
            f"{head}; the trace does not come from this plant family, register set and "
            f"chip, or a fixed value is wrong"
        )

    def to_dict(self) -> dict[str, Any]:
        """What ``servogym calibrate --json`` prints."""
        return {
            "plant_family": self.family,
            "plant": dict(self.plant),
            "fitted": {f.name: f.to_dict() for f in self.fitted},
            "fixed": dict(self.fixed),
            "latency": self.latency,
            "latency_choices": list(self.latency_choices),
            "latency_s": self.latency_s,
            "latency_decided": self.latency_decided,
            "latency_margin": None if self.latency_margin == float("inf") else self.latency_margin,
            "latencies": [
                dataclasses.asdict(x) | {"choices": list(x.choices)} for x in self.latencies
            ],
            "rms_error_counts": self.rms_error_counts,
            "rms_command_error": self.rms_command_error,
            "open_loop_rms_error_counts": self.open_loop_rms_error_counts,
            "rms_following_error": self.rms_following_error,
            "error_ratio": self.error_ratio,
            "poor_fit": self.poor,
            "poorly_determined": list(self.poorly_determined),
            "verdict": self.verdict(),
            "fit_time_s": self.fit_time_s,
            "n_evaluations": self.n_evaluations,
        }


def _rms(x: np.ndarray) -> float:
    return float(np.sqrt(np.mean(np.square(x, dtype=float))))


def _correlation_factor(r: np.ndarray) -> float:
    """``(1 + rho) / (1 - rho)`` for the lag-1 autocorrelation ``rho`` of the residuals:
    the variance inflation of a mean over an AR(1) series (consecutive samples of a replay
    error are far from independent)."""
    r = np.asarray(r, dtype=float)
    d = float(np.dot(r, r))
    if r.size < 3 or d == 0.0:
        return 1.0
    rho = min(max(float(np.dot(r[1:], r[:-1])) / d, 0.0), 0.999)
    return (1.0 + rho) / (1.0 - rho)


def _best_starts(cost, x0, names, start, family, n: int, k: int) -> list[np.ndarray]:
    """The ``k`` points of lowest ``cost`` among ``x0`` and ``n`` scrambled Sobol points
    (seed 0) over the parameters' sampling ranges, in the fit's coordinates
    ``log(value / start)``."""
    if n <= 0:
        return [x0]
    from scipy.stats import qmc

    lo = np.log([family.param(name).sample_low for name in names] / start)
    hi = np.log([family.param(name).sample_high for name in names] / start)
    pts = [x0] + [
        lo + u * (hi - lo) for u in qmc.Sobol(len(names), scramble=True, seed=0).random(n)
    ]
    costs = [cost(x) for x in pts]
    return [pts[i] for i in np.argsort(costs, kind="stable")[:k]]


def latency_candidates(params: Any, assumptions: Any) -> list[tuple[tuple[str, ...], float]]:
    """The chip's ``loop_latency`` choices grouped by the latency (s) they give."""
    chip = family_of(params)
    asm = assumptions or chip.default_assumptions()
    groups: dict[float, list[str]] = {}
    for choice in type(asm).CHOICES["loop_latency"]:
        lat = chip.loop_latency_s(params, dataclasses.replace(asm, loop_latency=choice))
        key = round(lat, 12)
        groups.setdefault(key, []).append(choice)
    return [(tuple(v), k) for k, v in sorted(groups.items())]


def calibrate(
    trace: Trace,
    params: Any,
    plant: str,
    *,
    assumptions: Any = None,
    fit: Sequence[str] | None = None,
    fix: Mapping[str, float] | None = None,
    latency: str | None = None,
    max_error_ratio: float = MAX_ERROR_RATIO,
    max_nfev: int = MAX_NFEV,
    n_starts: int = N_STARTS,
) -> Calibration:
    """Fit a plant family's parameters and the loop latency to a trace.

    Args:
        trace: The recorded trace (checked with :func:`check_trace` first).
        params: The register set that ran (any chip family).
        plant: Plant family name.
        assumptions: The chip's assumption switches (default: the family's); the latency
            is fitted unless ``latency`` names one.
        fit: Parameters to fit (default: the family's randomised ones, those a trace of a
            move determines: load, friction, the coupling).
        fix: Parameters held at known values (the motor's, the encoder's ...); the rest
            not fitted are nominal.
        latency: A ``loop_latency`` choice to hold instead of fitting it.
        max_error_ratio: The poor-fit threshold (see :data:`MAX_ERROR_RATIO`).
        max_nfev: Most iterations per latency candidate.
        n_starts: Points of the scrambled Sobol set (seed 0) the fit starts from the best
            of (with the nominal or fixed values); 0 starts from those.

    Raises:
        TraceError: a malformed trace (one line).
        FitError: a parameter the trace does not determine, or a bad ``fit``/``fix``.
        PlantParameterError: a fixed value outside its legal range.
    """
    from scipy.optimize import least_squares

    from servogym.plants import PlantParameterError, get_plant

    started = time.perf_counter()
    chip = family_of(params)
    asm = assumptions or chip.default_assumptions()
    check_trace(trace, chip.sample_time_s(params), params.model)
    family = get_plant(plant)
    fix = dict(fix or {})
    try:
        base = family.validate(fix)  # unknown names get close matches
    except PlantParameterError as exc:
        raise PlantParameterError(f"--fix: {exc}") from None
    names = list(fit) if fit else [n for n in family.randomised() if n not in fix]
    for name in names:
        try:
            p = family.param(name)
        except PlantParameterError as exc:
            raise PlantParameterError(f"--fit: {exc}") from None
        if name in fix:
            raise FitError(f"{name} is both fitted (--fit) and fixed (--fix); choose one.")
        if name in NOT_FITTED or p.type_name == "int":
            raise FitError(
                f"{name} cannot be fitted (an integer: the trace's counts depend on it); "
                f"give it with --fix {name}=VALUE."
            )
        if p.low <= 0:
            raise FitError(
                f"{name} cannot be fitted: its legal range {p.range_text} is not positive; "
                f"give it with --fix {name}=VALUE."
            )
    if not names:
        raise FitError("nothing to fit: every parameter is fixed; leave one out of --fix.")
    start = np.array([float(base[n]) for n in names])
    lows = np.array([family.param(n).low for n in names])
    highs = np.array([family.param(n).high for n in names])
    lb = np.log(lows / start)
    ub = np.log(highs / start)

    built = family.build(base)
    rp = Replayer(built, params, asm, trace)
    meas = trace.actual.astype(float)
    s_e = max(1.0, _rms(trace.commanded - trace.actual))
    s_c = max(16.0, _rms(trace.command))
    scale = 1.0 / np.sqrt(trace.n_ticks)
    counter = [0]

    def values_of(x: np.ndarray) -> dict[str, float]:
        v = dict(base)
        # clipped: exp(log(high / start)) * start can round past the legal range's end
        fitted = np.clip(start * np.exp(x), lows, highs)
        v.update({n: float(f) for n, f in zip(names, fitted, strict=True)})
        return v

    def residuals(x: np.ndarray, choice: str) -> np.ndarray:
        counter[0] += 1
        rp.set_plant(values_of(x))
        c = rp.closed_loop(choice)
        o = rp.open_loop(choice)
        return scale * np.concatenate(
            [(c.actual - meas) / s_e, (c.command - trace.command) / s_c, (o.actual - meas) / s_e]
        )

    if latency is not None:
        choices = type(asm).CHOICES["loop_latency"]
        if latency not in choices:
            raise FitError(
                f"--latency must be one of {', '.join(choices)} (the {chip.name} family's "
                f"loop_latency choices); got --latency {latency!r}."
            )
        cands = [((latency,), rp.latency_s(latency))]
    else:
        cands = latency_candidates(params, asm)

    # a parameter the replay does not depend on cannot be fitted
    x0 = np.zeros(len(names))
    r0 = residuals(x0, cands[0][0][0])
    for i, name in enumerate(names):
        x = x0.copy()
        x[i] = DIFF_STEP * 3 if ub[i] > DIFF_STEP * 3 else -DIFF_STEP * 3
        if np.array_equal(residuals(x, cands[0][0][0]), r0):
            raise FitError(
                f"the trace does not determine {name}: changing it by 9 % changes no sample "
                f"of the replay; record a longer or faster move, or hold it with --fix "
                f"{name}=VALUE."
            )

    last: dict[str, Any] = {}

    def fun(x: np.ndarray, choice: str) -> np.ndarray:
        r = residuals(x, choice)
        last.update(x=x.copy(), choice=choice, r=r)
        return r

    def jac(x: np.ndarray, choice: str) -> np.ndarray:
        # forward differences of an absolute step in log space (scipy's relative step is
        # 1.5e-8 at x = 0: below the encoder's resolution, it sees only integer jumps)
        if last.get("choice") == choice and np.array_equal(last.get("x"), x):
            r0 = last["r"]
        else:
            r0 = residuals(x, choice)
        out = np.empty((r0.size, x.size))
        for i in range(x.size):
            h = DIFF_STEP if x[i] + DIFF_STEP <= ub[i] else -DIFF_STEP
            xi = x.copy()
            xi[i] += h
            out[:, i] = (residuals(xi, choice) - r0) / h
        return out

    def solve(x_start: np.ndarray, choice: str, nfev: int) -> Any:
        return least_squares(
            fun, x_start, jac=jac, bounds=(lb, ub), args=(choice,), x_scale=1.0,
            max_nfev=nfev, method="trf", ftol=TOLERANCE, xtol=TOLERANCE,
        )  # fmt: skip

    # the best of a scrambled Sobol set over the parameters' sampling ranges (the stick
    # position at the end of a move jumps with the friction: local minima), then the plant
    # at the family's default latency (or the first candidate) to convergence, every other
    # latency from there briefly, the close ones again in full
    default = asm.loop_latency if latency is None else latency
    order = sorted(cands, key=lambda c: default not in c[0])
    # viscous and Coulomb friction trade off along the moves' speed: a fit can settle on
    # the wrong share of the same total friction (the stick at the end of a move tells
    # them apart, but only near the right share)
    visc = next((i for i, n in enumerate(names) if n.startswith("viscous_friction")), None)
    coul = next((i for i, n in enumerate(names) if n.startswith("coulomb_friction")), None)
    speed = float(np.abs(np.diff(trace.commanded)).max()) / rp.dt / rp.plant.io.counts_per_unit

    def friction_shares(x: np.ndarray) -> list[np.ndarray]:
        if visc is None or coul is None or speed <= 0:
            return []
        v = values_of(x)
        total = v[names[coul]] + v[names[visc]] * speed
        out = []
        for share in FRICTION_SHARES:
            y = x.copy()
            y[coul] = np.log(share * total / start[coul])
            y[visc] = np.log((1.0 - share) * total / speed / start[visc])
            out.append(np.clip(y, lb, ub))
        return out

    def fit_at(choice: str) -> Any:
        def cost(x: np.ndarray) -> float:
            r = residuals(x, choice)
            return float(np.dot(r, r))

        starts = _best_starts(cost, x0, names, start, family, n_starts, N_LOCAL)
        best = min((solve(x, choice, max_nfev) for x in starts), key=lambda r: r.cost)
        shares = friction_shares(best.x)
        if shares:
            costs = [cost(y) for y in shares]
            i = int(np.argmin(costs))
            if costs[i] < 2.0 * best.cost:
                other = solve(shares[i], choice, max_nfev)
                best = other if other.cost < best.cost else best
        # a trust region on a rugged cost stalls where one parameter alone could still go
        # far: try each parameter at a few factors, refit from the best if it is better
        for _ in range(POLISH_ROUNDS):
            trials = []
            for i in range(len(names)):
                for factor in POLISH_FACTORS:
                    y = best.x.copy()
                    y[i] = np.clip(y[i] + np.log(factor), lb[i], ub[i])
                    trials.append(y)
            costs = [0.5 * cost(y) for y in trials]
            i = int(np.argmin(costs))
            if not costs[i] < 0.9 * best.cost:
                break
            other = solve(trials[i], choice, max_nfev)
            if not other.cost < best.cost:
                break
            best = other
        return best

    first = fit_at(order[0][0][0])
    results = [(first.cost, order[0][0], order[0][1], first)]
    for choices, lat in order[1:]:
        sol = solve(first.x, choices[0], SCREEN_NFEV)
        results.append((sol.cost, choices, lat, sol))
    # every latency whose brief fit comes within REFIT_RATIO of the best is fitted again
    # from its own best starts: a fit from another latency's optimum can stall on the
    # count steps (the vertical axis does), and close candidates need a fair comparison
    best_cost = min(r[0] for r in results)
    for i, (c_cost, choices, lat, screened) in enumerate(results):
        if screened is first or c_cost > REFIT_RATIO * best_cost:
            continue
        sol = fit_at(choices[0])
        if sol.cost < c_cost:
            results[i] = (sol.cost, choices, lat, sol)
    results.sort(key=lambda r: r[0])
    # the latency whose fitted replay follows the recorded positions best wins: the
    # command residual, in the cost, is rugged (a count's flip kicks the derivative term)
    scored = []
    for c_cost, c_choices, c_lat, c_sol in results:
        rp.set_plant(values_of(c_sol.x))
        c_rms = _rms(rp.closed_loop(c_choices[0]).actual - meas)
        scored.append((c_rms, c_cost, c_choices, c_lat, c_sol))
    scored.sort(key=lambda r: (r[0], r[1]))
    latencies = [LatencyResult(ch, la, float(co), rm) for rm, co, ch, la, _ in scored]
    _, _, choices, lat, sol = scored[0]

    rp.set_plant(values_of(sol.x))
    closed = rp.closed_loop(choices[0])
    rp.set_plant(values_of(sol.x))
    opened = rp.open_loop(choices[0])
    rms = _rms(closed.actual - meas)

    jacobian = sol.jac
    m, k = jacobian.shape
    dof = max(1, m - k)
    s2 = 2.0 * sol.cost / dof * _correlation_factor(sol.fun)
    try:
        cov = np.linalg.pinv(jacobian.T @ jacobian) * s2
        sig_x = np.sqrt(np.clip(np.diag(cov), 0.0, None))
        sig_x[~np.any(jacobian != 0.0, axis=0)] = np.inf  # no sample depends on it
    except np.linalg.LinAlgError:
        sig_x = np.full(k, np.inf)
    values = values_of(sol.x)
    fitted = tuple(
        FittedValue(n, values[n], values[n] * float(sx) if np.isfinite(sx) else np.inf,
                    float(s), float(lo), float(hi))
        for n, sx, s, lo, hi in zip(names, sig_x, start, lows, highs, strict=True)
    )  # fmt: skip
    ratio = rms / s_e
    poor = rms > MIN_ERROR_COUNTS and ratio > max_error_ratio
    return Calibration(
        family=family.name,
        plant=values,
        fitted=fitted,
        fixed={n: float(base[n]) for n in fix},
        latency=choices[0],
        latency_choices=tuple(choices),
        latency_s=float(lat),
        latencies=tuple(latencies),
        rms_error_counts=rms,
        rms_command_error=_rms(closed.command - trace.command),
        open_loop_rms_error_counts=_rms(opened.actual - meas),
        rms_following_error=s_e,
        error_ratio=ratio,
        poor=bool(poor),
        poorly_determined=tuple(f.name for f in fitted if f.relative_sigma > UNDETERMINED),
        replay=closed,
        open_replay=opened,
        fit_time_s=time.perf_counter() - started,
        n_evaluations=counter[0],
        max_error_ratio=max_error_ratio,
    )
