"""The default tuner: a safe trust-region search that starts from the model-based design.

A tuner an engineer would let run on a real axis must not spend its budget on sets that
make the axis diverge, saturate, lose its following error or its stability margins. Blind
samplers do (TPE spent 17 of 20 evaluations on unsafe sets at budget 20 in servobench-v0).
:class:`SafeTuner` searches only where the evidence of earlier evaluations says it is safe:

1. **Start from a design.** Without a warm start it runs the model-based procedure
   (:class:`~servogym.autotune.ModelBasedTuner`: two identification moves and seven
   candidate bandwidths) inside its budget; every one of those runs counts, as it would on
   a machine. With a warm start (``--warm-start``) it starts from that set.
2. **A trust region around the best safe set** (TuRBO's rule, Eriksson et al., 2019): a box
   centred on the best feasible trial, with one half-width per register in the unit cube.
   The registers an unsafe trial moved have theirs halved; those an improving trial moved
   grow (two improvements double them); every half-width halves after
   :attr:`SafeTuner.failure_tolerance` trials without improvement. So a register found
   sensitive (a derivative interval, a feed-forward pair) keeps small steps while the
   others open up. The half-widths are a function of the study's trials in number order
   (each trial records the trial it moved from, ``safe_centre``), never stored.
3. **A safety model on the constraints** (SafeOpt's rule, Sui et al., 2015): one Gaussian
   process per constraint, on the constraint values of the trials near the centre scaled to
   their limit (a gain margin 3 dB short of 6 dB reads 0.5); a candidate is proposed only
   when every constraint's upper confidence bound ``mean + beta * std`` is below its limit.
   The prior mean is the limit itself, so far from the evidence nothing is safe and the
   safe set grows only as evaluations show slack.
4. **Cheap proposals.** 256 random perturbations of the centre inside the box (each
   register perturbed with probability ``max(0.5, 2/d)``), scored by the same Gaussian
   process on the log cost: the safe candidate with the lowest lower confidence bound is
   proposed. Pending trials of the batch are added to the model, the cost at its predicted
   value (the kriging believer, so a batch spreads out) and every constraint at its upper
   bound (a running trial is no evidence of safety). All in NumPy on at most
   :attr:`SafeTuner.n_local` trials: a fraction of a millisecond per trial, against an
   evaluation of 4 to 20 ms.

The Gaussian processes share one Matern-5/2 kernel on the unit cube; its length scale is
the maximum of the marginal likelihood of the cost and margin values over a grid. Seeded:
trial ``n`` is asked with the seed of :func:`~servogym.autotune.trial_seed`, so the same
seed gives the same study (docs/autotune.md, "The default tuner").
"""

from __future__ import annotations

import logging
import math
from collections.abc import Mapping
from typing import Any

import numpy as np

from servogym.autotune._predict import MarginPredictor, predictor_from_fit
from servogym.autotune._session import Session, TuneError
from servogym.autotune._tuners import OptunaTuner, register_tuner

logger = logging.getLogger(__name__)

_SQRT5 = math.sqrt(5.0)

LENGTH_SCALES = (0.05, 0.1, 0.2, 0.4)
"""Kernel length scales (unit-cube units, a cube of side 2) the likelihood chooses from."""

CENTRE_KEY = "safe_centre"
"""User attribute of a trial the safe tuner asked: the number of the trial it moved from."""

FIT_KEY = "safe_identified_model"
"""Study user attribute: the rigid axis the design identified (``accel_gain``, ...), from
which the margin predictor is rebuilt (the same on a resumed study)."""

BINARY_CONSTRAINTS = ("diverged",)
"""Constraints that are counts (0 when met): modelled as -1 (met) or +1 (violated)."""


def compressed(v: float) -> float:
    """A scaled constraint value as the Gaussian processes see it: itself within one limit
    either side, beyond that ``1 + ln |v|`` with its sign (continuous, with slope 1 at 1).

    Clipping (at 2, formerly) made every far violation look the same: a following error 10x
    its limit read like one 2x, so while nothing was safe the search had no slope to follow
    (servobench-v1, budget 50: 15 of 36 train instances spent 48 of 48 samples unsafe). The
    logarithm keeps the order and a slope without letting one far trial dominate the fit."""
    if not math.isfinite(v):
        return math.copysign(1.0 + math.log(1e6), v) if not math.isnan(v) else 1.0 + math.log(1e6)
    a = abs(v)
    return v if a <= 1.0 else math.copysign(1.0 + math.log(a), v)


def _matern52(a: np.ndarray, b: np.ndarray, ell: float) -> np.ndarray:
    """Matern-5/2 correlation between the rows of ``a`` (n x d) and ``b`` (m x d)."""
    d2 = np.maximum((a * a).sum(1)[:, None] + (b * b).sum(1)[None, :] - 2.0 * a @ b.T, 0.0)
    r = _SQRT5 * np.sqrt(d2) / ell
    return (1.0 + r + r * r / 3.0) * np.exp(-r)


class _GP:
    """Gaussian processes with one kernel for several outputs (columns of ``y``).

    Args:
        x: Inputs, n x d.
        y: Outputs, n x k.
        prior_mean: Prior mean of each output (k).
        min_amplitude: Smallest prior standard deviation of each output (k); the amplitude
            is otherwise the maximum-likelihood one.
        ell: Length scale.
    """

    jitter = 1e-6

    def __init__(
        self,
        x: np.ndarray,
        y: np.ndarray,
        prior_mean: np.ndarray,
        min_amplitude: np.ndarray,
        ell: float,
    ) -> None:
        # NumPy only: at these sizes (n <= 56) SciPy's triangular solves cost more in
        # thread start-up than in arithmetic, and so would a threaded BLAS call.
        self.x, self.y, self.ell = x, y, ell
        self.mean, self.min_amplitude = prior_mean, min_amplitude
        n = len(x)
        chol = np.linalg.cholesky(_matern52(x, x, ell) + self.jitter * np.eye(n))
        self.linv = np.linalg.inv(chol)
        resid = y - prior_mean
        self.alpha = self.linv.T @ (self.linv @ resid)
        ml_var = (resid * self.alpha).sum(0) / n
        self.amplitude = np.maximum(np.sqrt(np.maximum(ml_var, 0.0)), min_amplitude)
        self.log_likelihood = (
            -0.5 * n * np.log(np.maximum(ml_var, 1e-12)) - np.log(np.diag(chol)).sum()
        )

    def predict(self, xs: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Mean (m x k) and standard deviation (m x k) at the rows of ``xs``."""
        ks = _matern52(xs, self.x, self.ell)
        mean = self.mean + ks @ self.alpha
        v = self.linv @ ks.T
        var = np.clip(1.0 - (v * v).sum(0), 0.0, 1.0)
        return mean, np.sqrt(var)[:, None] * self.amplitude[None, :]

    def with_points(self, xs: np.ndarray, pessimism: np.ndarray | None = None) -> _GP:
        """The same GP given the points ``xs`` at its predicted means (kriging believer),
        plus ``pessimism`` (k) standard deviations per output."""
        mean, std = self.predict(xs)
        if pessimism is not None:
            mean = mean + pessimism[None, :] * std
        y = np.vstack([self.y, mean])
        return _GP(np.vstack([self.x, xs]), y, self.mean, self.min_amplitude, self.ell)


class _Row:
    """One finished trial as the model sees it."""

    __slots__ = ("centre", "cons", "kind", "log_cost", "margins", "number", "registers", "safe",
                 "sample", "x")  # fmt: skip

    def __init__(self, number: int, kind: str, x: np.ndarray, log_cost: float,
                 cons: np.ndarray, safe: bool, centre: int | None,
                 registers: Mapping[str, int] | None = None,
                 margins: tuple[float, float] | None = None) -> None:  # fmt: skip
        self.number, self.kind, self.x = number, kind, x
        self.log_cost, self.cons, self.safe = log_cost, cons, safe
        self.sample = kind == "sample"
        self.centre = centre
        self.registers = registers
        self.margins = margins
        """The evaluation's gain and phase margins (dB, degrees), when constrained."""


class _Model:
    """What the safe sampler knows: the study's finished trials, scaled, and the rules.

    Shared by the per-trial samplers of one session (it caches each finished trial's row;
    everything it proposes is a function of the finished trials, the pending ones and the
    trial's seed only).
    """

    def __init__(self, tuner: SafeTuner, session: Session) -> None:
        problem = session.problem
        self.tuner = tuner
        self.space = problem.space
        self.unit_names = list(problem.space.unit_names)
        self._specs = list(problem.space.specs)  # in the order of unit_names
        self.dim = len(self.unit_names)
        c = problem.constraints
        self.constraints_on = bool(c.enabled)
        self.scales = problem.constraint_scales(session.fe_limit)
        self.names: list[str] | None = None
        self.rows: dict[int, _Row] = {}
        self._first_error: str | None = None  # the first refused set's error, for the log
        self._fit_cache: tuple[Any, _GP] | None = None
        start = session.warm_start or self.space.base_values()
        self.start = self._unit(self.space.to_unit(start))
        self.limits = (c.min_gain_margin_db, c.min_phase_margin_deg)
        fit = session.study.user_attrs.get(FIT_KEY)
        self.predictor = predictor_from_fit(session, fit) if fit else None
        self._keys: dict[int, tuple[int, ...]] = {}  # a row's searched register values
        self._taken: set[tuple[int, ...]] = set()  # the register sets asked (rows, pending)
        # the rigid model's raw margins of a set (by _key): a proposal's are computed when it
        # is screened and reused when its evaluation calibrates the model
        self._raw: dict[tuple[int, ...], tuple[float, float]] = {}

    def _unit(self, params: Mapping[str, float]) -> np.ndarray:
        return np.array([float(params[u]) for u in self.unit_names])

    def _key(self, x: np.ndarray) -> tuple[int, ...]:
        """The searched registers' chip values of a unit-cube point: two points with one key
        are one set (a register's integer steps are coarser than a small trust region)."""
        return tuple(s.from_unit(float(v)) for s, v in zip(self._specs, x, strict=True))

    def _note_taken(self, rows: list[_Row], pending: list[np.ndarray]) -> None:
        for r in rows:
            if r.number not in self._keys:
                self._keys[r.number] = self._key(r.x)
        self._taken = set(self._keys.values()) | {self._key(p) for p in pending}

    def _constraint_names(self, trial: Any) -> list[str]:
        if self.names is None:
            self.names = sorted(trial.constraints) if self.constraints_on else ["diverged"]
        return self.names

    def _row(self, t: Any) -> _Row | None:
        kind = t.user_attrs.get("kind", "sample")
        if kind == "experiment" or not all(u in t.params for u in self.unit_names):
            return None
        x = self._unit(t.params)
        if t.state.name == "COMPLETE":
            outcome = t.user_attrs.get("outcome", {})
            diverged = float(outcome.get("n_diverged", 0))
            values = dict(t.constraints) if self.constraints_on else {}
            values.setdefault("diverged", diverged)
            names = self._constraint_names(t)
            cons = np.array([self._scaled(n, values.get(n, 0.0)) for n in names])
            safe = diverged == 0 and all(v <= 0 for v in t.constraints.values())
            cost = float(t.values[0])
            log_cost = math.log(max(cost, 1e-12)) if math.isfinite(cost) else math.nan
            margins = None
            if "gain_margin" in values and "phase_margin" in values:
                margins = (self.limits[0] - values["gain_margin"],
                           self.limits[1] - values["phase_margin"])  # fmt: skip
            return _Row(t.number, kind, x, log_cost, cons, safe, t.user_attrs.get(CENTRE_KEY),
                        t.user_attrs.get("registers"), margins)  # fmt: skip
        if t.state.name == "FAIL" and "error" in t.user_attrs:
            # A set a family's cross-register rule refuses: never proposed again.
            self._first_error = self._first_error or str(t.user_attrs["error"])
            return _Row(t.number, kind, x, math.nan, np.array([]), False,
                        t.user_attrs.get(CENTRE_KEY))  # fmt: skip
        return None

    def _scaled(self, name: str, value: float) -> float:
        if name in BINARY_CONSTRAINTS:
            return 1.0 if value > 0 else -1.0
        return compressed(value / self.scales.get(name, 1.0))

    def update(self, trials: list[Any]) -> tuple[list[_Row], list[np.ndarray]]:
        """The finished trials' rows in number order and the pending trials' points."""
        pending = []
        for t in trials:
            if t.number in self.rows:
                continue
            if t.state.is_finished():
                row = self._row(t)
                if row is not None:
                    self.rows[t.number] = row
            elif t.state.name == "RUNNING" and all(u in t.params for u in self.unit_names):
                pending.append(self._unit(t.params))
        return [self.rows[n] for n in sorted(self.rows)], pending

    # ---------------------------------------------------------------- the trust region

    def trust_region(self, rows: list[_Row]) -> tuple[np.ndarray, _Row | None]:
        """Replay the trials in number order: each register's half-width and the centre
        (the best safe row).

        A trial changes the half-widths of the registers it moved away from its centre
        (the trial it was proposed around): halved when it is unsafe, grown by
        ``2 ** (1 / success_tolerance)`` when it improves (so
        :attr:`SafeTuner.success_tolerance` improvements double them); after
        :attr:`SafeTuner.failure_tolerance` trials without improvement every one halves.
        """
        tuner = self.tuner
        r = np.full(self.dim, tuner.initial_radius)
        fail_tol = max(tuner.failure_tolerance, self.dim // 2)
        best: _Row | None = None
        least = math.inf  # the smallest violation while nothing is safe
        wins = losses = 0
        for row in rows:
            better = (
                row.safe
                and not math.isnan(row.log_cost)
                and (best is None or row.log_cost < best.log_cost - tuner.min_improvement)
            )
            violation = float(row.cons.max()) if len(row.cons) else math.inf
            if row.sample and best is None and not row.safe:
                # No safe set yet: every trial is unsafe; progress is a smaller violation.
                if violation < least - tuner.min_improvement:
                    wins, losses = wins + 1, 0
                    if wins >= tuner.success_tolerance:
                        r, wins = np.minimum(2 * r, tuner.max_radius), 0
                else:
                    wins, losses = 0, losses + 1
                    if losses >= fail_tol:
                        r, losses = np.maximum(r / 2, tuner.min_radius), 0
            elif row.sample:
                centre = self.rows.get(row.centre) if row.centre is not None else best
                moved = (
                    np.abs(row.x - centre.x) > 1e-12
                    if centre is not None
                    else np.ones(self.dim, bool)
                )
                if not row.safe:
                    r[moved] = np.maximum(r[moved] / 2, tuner.min_radius)
                    wins, losses = 0, 0
                elif better:
                    # Only the registers that moved grow: one found sensitive stays small.
                    grow = 2.0 ** (1.0 / tuner.success_tolerance)
                    r[moved] = np.minimum(r[moved] * grow, tuner.max_radius)
                    wins, losses = wins + 1, 0
                else:
                    wins, losses = 0, losses + 1
                    if losses >= fail_tol:
                        r, losses = np.maximum(r / 2, tuner.min_radius), 0
            if better:
                best = row
            least = min(least, violation)
        return r, best

    # ---------------------------------------------------------------- proposals

    def propose(self, trials: list[Any], rng: np.random.Generator) -> tuple[np.ndarray, Any]:
        """The unit-cube point of the next trial and the number of its centre trial."""
        rows, pending = self.update(trials)
        self._note_taken(rows, pending)
        radius, best = self.trust_region(rows)
        scored = [r for r in rows if not math.isnan(r.log_cost)]
        if best is None and not scored:
            if not rows and not pending:
                # Nothing asked yet: the start (the chip's defaults or the warm start).
                return self.start.copy(), None
            # Nothing scored: the start (and any set since) refused by a cross-register
            # rule, or still running. Proposing the start again would be refused again.
            return self._near_start(rows, pending, rng), None
        if best is None:  # nothing safe yet: head for the least violation
            centre_row = min(scored, key=lambda r: (float(r.cons.max()), r.log_cost))
        else:
            centre_row = best
        centre = centre_row.x
        # The kernel sees each register in units of its half-width (the registers found
        # sensitive, with small half-widths, are far apart for the safety model).
        scale = float(np.exp(np.log(radius).mean())) / radius
        local = self._local(rows, centre)
        self._calibrate(local)
        gp = self._fitted(local, scale)
        if pending:
            # The cost at its predicted mean (the batch spreads out); every constraint at its
            # upper bound: a pending trial is no evidence of safety, so the batch's later
            # trials are not proposed on the strength of the earlier ones' predictions.
            beta = np.concatenate([[0.0], np.full(gp.y.shape[1] - 1, self.tuner.beta)])
            gp = gp.with_points(np.array(pending) * scale, beta)
        fallback: tuple[float, np.ndarray] | None = None
        for attempt in range(4):
            cands = self._candidates(centre, radius / 2**attempt, rng)
            pick, least = self._choose(gp, cands, scale, feasible=best is not None)
            if pick is not None:
                return pick, centre_row.number
            if fallback is None or least[0] < fallback[0]:
                fallback = least
        # Nothing predicted safe even at 1/8 of the radius: the likeliest safe candidate, or
        # the centre again when the rigid model says the margins of that one are short.
        if fallback is None or (best is not None and not self._model_safe(fallback[1])):
            return centre.copy(), centre_row.number
        return fallback[1], centre_row.number

    def _near_start(
        self, rows: list[_Row], pending: list[np.ndarray], rng: np.random.Generator
    ) -> np.ndarray:
        """A point near the start while no set is scored: the candidate farthest from every
        point asked so far (refused or pending, so never one of them), in a box around the
        start whose half-width, :attr:`SafeTuner.initial_radius` at first, doubles with each
        refused set (a rule refuses a region, not a point) up to the whole cube."""
        if rows:
            logger.info(
                "safe: %d set(s) refused and none evaluated (first refusal: %s); moving away "
                "from the start", len(rows), self._first_error,
            )  # fmt: skip
        taken = np.array([r.x for r in rows] + list(pending))
        radius = np.full(self.dim, min(self.tuner.initial_radius * 2.0 ** len(rows), 2.0))
        cands = self._candidates(self.start, radius, rng)
        gap = ((cands[:, None, :] - taken[None, :, :]) ** 2).sum(-1).min(1)
        return cands[int(np.argmax(gap))]

    def _local(self, rows: list[_Row], centre: np.ndarray) -> list[_Row]:
        """The :attr:`SafeTuner.n_local` rows nearest the centre (unique points)."""
        seen: dict[bytes, _Row] = {}
        for r in rows:
            seen.setdefault(r.x.tobytes(), r)
        uniq = list(seen.values())
        if len(uniq) > self.tuner.n_local:
            d = np.array([float(((r.x - centre) ** 2).sum()) for r in uniq])
            keep = np.argsort(d, kind="stable")[: self.tuner.n_local]
            uniq = [uniq[i] for i in sorted(keep)]
        return uniq

    def _candidates(
        self, centre: np.ndarray, radius: np.ndarray, rng: np.random.Generator
    ) -> np.ndarray:
        n, d = self.tuner.n_candidates, self.dim
        mask = rng.random((n, d)) < self.tuner.move_probability(d)
        mask[np.arange(n), rng.integers(0, d, n)] = True  # at least one register moves
        step = rng.uniform(-1.0, 1.0, (n, d)) * radius
        return np.clip(centre + mask * step, -1.0, 1.0)

    def _fitted(self, data: list[_Row], scale: np.ndarray) -> _GP:
        """The GP of the data rows, inputs times ``scale`` (cached: the asks of one batch
        share both)."""
        key = (tuple(r.number for r in data), scale.tobytes())
        if self._fit_cache is not None and self._fit_cache[0] == key:
            return self._fit_cache[1]
        tuner = self.tuner
        x = np.array([r.x for r in data]) * scale
        names = self.names or []
        n_cons = len(names)
        costs = np.array([r.log_cost for r in data])
        worst = np.nanmax(costs) if np.isfinite(costs).any() else 0.0
        costs = np.where(np.isnan(costs), worst, costs)  # a refused set: the worst cost
        cons = np.array(
            [r.cons if len(r.cons) == n_cons else np.ones(n_cons) for r in data]
        ).reshape(len(data), n_cons)
        y = np.column_stack([costs, cons])
        binary = np.array([n in BINARY_CONSTRAINTS for n in names], bool)
        prior = np.concatenate([[float(costs.mean())], np.zeros(n_cons)])
        min_amp = np.concatenate(
            [[1e-3], np.where(binary, tuner.binary_amplitude, tuner.min_amplitude)]
        )
        if len(x) < 3:
            gp = _GP(x, y, prior, min_amp, tuner.default_length_scale)
        else:  # the length scale of the largest likelihood of the continuous outputs
            fits = [_GP(x, y, prior, min_amp, ell) for ell in LENGTH_SCALES]
            keep = np.concatenate([[True], ~binary])
            gp = max(fits, key=lambda g: float(g.log_likelihood[keep].sum()))
        self._fit_cache = (key, gp)
        return gp

    def _choose(
        self, gp: _GP, cands: np.ndarray, scale: np.ndarray, feasible: bool
    ) -> tuple[np.ndarray | None, tuple[float, np.ndarray]]:
        """The safe candidate with the lowest cost bound (``None``: none is safe), and the
        candidate likeliest to be safe with its largest constraint bound."""
        tuner = self.tuner
        mean, std = gp.predict(cands * scale)
        n_cons = mean.shape[1] - 1
        if not n_cons:
            return cands[int(np.argmin(mean[:, 0] - tuner.kappa * std[:, 0]))], (0.0, cands[0])
        upper = (mean[:, 1:] + tuner.beta * std[:, 1:]).max(1)
        i = int(np.argmin(upper))
        least = (float(upper[i]), cands[i])
        if not feasible:  # nothing safe known: the least predicted violation not yet asked
            order = np.argsort(mean[:, 1:].max(1), kind="stable")
            fresh = [
                j for j in order[: tuner.max_repeats] if self._key(cands[j]) not in self._taken
            ]
            return cands[fresh[0] if fresh else order[0]], least
        safe = upper <= 0.0
        if not safe.any():
            return None, least
        lcb = mean[:, 0] - tuner.kappa * std[:, 0]
        lcb[~safe] = np.inf
        order = np.argsort(lcb, kind="stable")[: min(int(safe.sum()), tuner.max_repeats)]
        tried = 0
        for i in order:  # the lowest bound not asked yet whose margins the rigid model keeps
            if self._key(cands[i]) in self._taken:
                continue
            if self._model_safe(cands[i]):
                return cands[i], least
            tried += 1
            if tried >= tuner.max_predictions:
                break
        return None, least

    # ---------------------------------------------------------------- the rigid model

    def _calibrate(self, rows: list[_Row]) -> None:
        """Learn how far the model overstates the margins on the rows' evaluated sets."""
        if self.predictor is None:
            return
        pairs = []
        for r in rows:
            if r.margins is None or r.registers is None:
                continue
            key = self._keys[r.number]  # a proposal's margins were predicted when screened
            if key not in self._raw:
                self._raw[key] = self.predictor.raw(r.registers)
            pairs.append((self._raw[key], r.margins))
        if pairs:
            self.predictor.calibrate(np.array([p for p, _ in pairs]),
                                     np.array([m for _, m in pairs]))  # fmt: skip

    def _model_safe(self, x: np.ndarray) -> bool:
        """Whether the rigid model's margins of the point (less the learnt bias) are at
        least the limits plus :attr:`SafeTuner.model_buffer` (always, without a model)."""
        if self.predictor is None:
            return True
        key = self._key(x)
        if key not in self._raw:
            unit = dict(zip(self.unit_names, (float(v) for v in x), strict=True))
            try:
                self._raw[key] = self.predictor.raw(self.space.values_from_unit(unit))
            except ValueError:  # a set the chip refuses: the session records the refusal
                return True
        gm, pm = np.subtract(self._raw[key], self.predictor.bias)
        return self.predictor.clears(float(gm), float(pm), self.tuner.model_buffer)


def _sampler_class() -> type:
    import optuna

    class _SafeSampler(optuna.samplers.BaseSampler):
        """Asks one trial: the model's proposal with this trial's seed."""

        def __init__(self, model: _Model, seed: int) -> None:
            self._model = model
            self._seed = seed
            self.trial_user_attrs: dict[str, Any] = {}
            """What the session stores on the trial this sampler asked (its centre), with
            ``Trial.set_user_attr`` after the ask."""

        def infer_relative_search_space(self, study: Any, trial: Any) -> dict[str, Any]:
            return self._model.space.distributions()

        def sample_relative(self, study: Any, trial: Any, search_space: Any) -> dict[str, Any]:
            if not search_space:
                return {}
            trials = study.get_trials(deepcopy=False)
            x, centre = self._model.propose(trials, np.random.default_rng(self._seed))
            if centre is not None:  # the trust region's replay needs it
                self.trial_user_attrs[CENTRE_KEY] = centre
            return {u: float(v) for u, v in zip(self._model.unit_names, x, strict=True)}

        def sample_independent(self, study: Any, trial: Any, name: str, dist: Any) -> Any:
            # Only reached for a parameter outside the space (never in a servogym study).
            return float(np.random.default_rng(self._seed).uniform(dist.low, dist.high))

    return _SafeSampler


@register_tuner
class SafeTuner(OptunaTuner):
    """The default tuner of ``servogym tune``: a safe trust-region search from the
    model-based design (module docstring; docs/autotune.md, "The default tuner").

    Single objective. Every evaluation goes through the session (the design's experiments
    and candidates too), so the budget counts every run of the axis.
    """

    name = "safe"
    supports_multi_objective = False

    initial_radius = 0.03
    """Half-width of the first trust region (the unit cube has side 2)."""
    max_radius = 0.4
    """Largest half-width."""
    min_radius = 1.0 / 256
    """Smallest half-width."""
    success_tolerance = 2
    """Improvements that double the half-widths of the registers they moved."""
    failure_tolerance = 4
    """Trials without improvement that halve the radius (at least half the dimension)."""
    min_improvement = 1e-3
    """Relative improvement of the cost (in log) that counts as one."""
    beta = 2.0
    """Safety: every constraint's mean + beta * std must be within its limit."""
    kappa = 1.0
    """Exploration of the cost: the lowest mean - kappa * std among safe candidates."""
    n_candidates = 256
    """Random candidates scored per trial."""

    @staticmethod
    def move_probability(dim: int) -> float:
        """Probability that a candidate moves a register (one more is always moved)."""
        return max(0.5, 2.0 / dim)

    n_local = 48
    """Trials nearest the centre the Gaussian processes see."""
    min_amplitude = 0.5
    """Smallest prior std of a scaled constraint (0.5: 3 dB of a 6 dB gain margin)."""
    binary_amplitude = 0.5
    """Prior std of a count constraint (divergence) read as -1 / +1."""
    default_length_scale = 0.2
    """Length scale while fewer than three trials are known."""
    design_first = 3
    """The model-based candidate scored first (0: the fastest of seven bandwidths)."""
    model_buffer = (0.25, 2.0)
    """dB and degrees by which a proposal's margins on the identified rigid model, less the
    bias learnt from the evaluated sets, must clear the limits."""
    design_buffer = (2.0, 10.0)
    """The same for the design's candidates, before any set is evaluated (the bias is not
    known yet: the servobench-v1 instances measured up to 1.5 dB and 10 degrees)."""
    max_predictions = 8
    """Candidates per proposal round whose margins the rigid model computes at most."""
    max_repeats = 64
    """Candidates per proposal round looked at, best first, for one whose register values
    no trial has asked yet (a small trust region on an integer register rounds many points
    to one set; evaluating a set again teaches nothing)."""

    def run(self, session: Session) -> None:
        if session.warm_start is None:
            self._design(session)
        else:
            session.evaluate_warm_start()
        session.run_sampler(lambda seed: self.make_sampler(seed, session))

    def make_sampler(self, seed: int, session: Session) -> Any:
        # One model per session, shared by its per-trial samplers (it caches the rows).
        cached = getattr(self, "_model", None)
        if cached is None or cached[0] is not session:
            cached = self._model = (session, _Model(self, session))
        return _sampler_class()(cached[1], seed)

    def _design(self, session: Session) -> None:
        """The model-based design inside the budget, unless the study is past it."""
        from servogym.autotune._classical import ModelBasedTuner

        if any(t.user_attrs.get("kind") == "sample" for t in session.trials()):
            return  # the study went on without a design (a smaller budget before)
        if session.problem.n_axes > 1:  # identifies one axis; servogym tune designs a machine's
            logger.info("safe: no model-based design of a machine; starting from its defaults")
            return
        if session.budget < ModelBasedTuner.min_budget:
            return
        try:
            ModelBasedTuner().run(_LineSearchSession(session, self))
        except TuneError as exc:  # no gain map for the family, or no identification
            logger.info("safe: no model-based design (%s); starting from the chip defaults", exc)


class _LineSearchSession:
    """The session as the model-based procedure sees it inside :class:`SafeTuner`: its
    candidate bandwidths (fastest first) are scored one at a time, a safe line search.

    It starts at the middle bandwidth :attr:`SafeTuner.design_first` and walks towards
    faster loops while each step is safe and better, else towards slower ones; it stops at
    the first unsafe or worse step, and does not take a step whose constraints, extrapolated
    linearly from the last two steps, would be violated. Every other attribute is the
    session's own.
    """

    def __init__(self, session: Session, tuner: SafeTuner) -> None:
        self._session = session
        self._tuner = tuner

    def __getattr__(self, name: str) -> Any:
        return getattr(self._session, name)

    _predictor: MarginPredictor | None = None

    def on_identified(self, fit: Mapping[str, float]) -> None:
        """The design's rigid model: stored with the study, and kept to screen the
        candidates (:meth:`candidates`)."""
        fit = {k: float(v) for k, v in fit.items()}
        self._session.study.set_user_attr(FIT_KEY, fit)
        self._predictor = predictor_from_fit(self._session, fit)

    def _screened(self, sets: list[tuple[Mapping[str, int], str]]) -> tuple[list[Any], int]:
        """The candidates whose margins on the rigid model clear the limits by
        :attr:`SafeTuner.design_buffer` (fastest first), and the index to start from: the
        candidate :attr:`SafeTuner.design_first` if kept, else the fastest kept. None clears
        them: the one with the largest margins, alone."""
        first = min(self._tuner.design_first, len(sets) - 1)
        pred = self._predictor
        if pred is None:
            return sets, first
        margins = []
        for values, _ in sets:
            try:
                margins.append(pred.margins(values))
            except ValueError:  # a set the chip refuses: kept, the session records the refusal
                margins.append(None)
        buffer = self._tuner.design_buffer
        keep = [i for i, m in enumerate(margins) if m is None or pred.clears(*pred.pair(m), buffer)]
        if not keep:
            return [sets[max(range(len(sets)), key=lambda i: pred.severity(margins[i]))]], 0
        return [sets[i] for i in keep], keep.index(first) if first in keep else 0

    def candidates(self, sets: list[tuple[Mapping[str, int], str]]) -> list[Any]:
        session, problem = self._session, self._session.problem
        if not sets:
            return []
        sets, mid = self._screened(list(sets))
        n = len(sets)
        done: dict[int, Any] = {}

        def score(i: int) -> Any:
            if session.remaining < 1:
                return None
            done[i] = session.candidates([sets[i]])[0]
            return done[i]

        def values(o: Any) -> dict[str, float]:
            if not problem.constraints.enabled:
                return {}
            return problem.constraint_values(o, session.fe_limit)

        def safe(o: Any) -> bool:
            return o.n_diverged == 0 and all(v <= 0 for v in values(o).values())

        def walk(start: int, step: int) -> None:
            i = start
            while 0 <= i + step < n and session.remaining >= 1:
                prev, prev2 = done.get(i), done.get(i - step)
                if prev is None or not safe(prev):
                    return
                if prev2 is not None:  # extrapolate the constraints one step on
                    # (violated when 2a - b > 0: the same answer in any units, so raw values)
                    a, b = values(prev), values(prev2)
                    if any(2 * a[k] - b[k] > 0 for k in a if k in b):
                        return
                o = score(i + step)
                if o is None or not safe(o) or o.cost >= prev.cost:
                    return
                i += step

        first = score(mid)
        if first is None:
            return []
        if safe(first):
            walk(mid, -1)  # faster loops (the candidates come fastest first)
            if mid - 1 not in done or not safe(done[mid - 1]) or done[mid - 1].cost >= first.cost:
                walk(mid, +1)
        else:
            # A loop short of margin or unstable: slower; following error or saturation
            # only: faster. An episode stopped with a stable loop and its margins met (a
            # following-error trip such as PMAC's Ixx11) is the following error's case.
            c = values(first)
            measured = "gain_margin" in c or "phase_margin" in c
            loop = (
                getattr(first, "n_unstable", 0) > 0
                or any(c.get(k, 0) > 0 for k in ("gain_margin", "phase_margin"))
                or (first.n_diverged > 0 and not measured)
            )
            step = +1 if loop else -1
            i = mid
            while 0 <= i + step < n and (o := score(i + step)) is not None:
                i += step
                if safe(o):
                    walk(i, step)
                    break
        return [done[i] for i in sorted(done)]
