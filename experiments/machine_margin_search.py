"""Move a multi-axis set into the check's margins: a search on the linear analysis alone.

The safe tuner cannot leave an infeasible start (``schedule_oracle.py --chain`` found no
feasible trial in 3 x 150 on the two-link arm at 2 kg, from the 0.32 kg set). This script
searches the loop gains of a set (:data:`GAINS`, every axis's, in log steps; the
feed-forward and the limits are kept) for the margins the multi-axis check asks, on the
check's own linear analysis (``servogym.sim._multicheck``): every plant of its stress set
(the machine as given, the load and the frictions at -+20 / -+50 %), every loop-latency x
sequencing choice on the machine as given, every operating configuration of the tasks, as
the check analyses them. No task is simulated in the search, so a candidate takes about a
second instead of the check's minutes. The objective is the worst slack,
``min(GM - 6 dB, (PM - 30 deg) / 5)`` over every loop and case (an unstable machine: minus
its spectral radius's excess, minus 10), plus ``--cost-weight`` times the log of the loop
gain given up (so that, of two sets with the margins, the search keeps the stiffer);
scipy's Nelder-Mead from the given set, until the slack reaches ``--target`` dB. The
following error and the saturation are not in the search (they need the tasks run): the
set found then goes through the full check.

    .venv/bin/python experiments/machine_margin_search.py \\
        --scenario TwoLinkArm --point 2 --from-label chain-150 --label margin-search

Appends one JSON line to ``experiments/results/schedule/margin_search.jsonl``: the start and
found values, their slack, the search's evaluations, and the check's verdict.
"""

from __future__ import annotations

import argparse
import contextlib
import dataclasses
import json
import sys
import time
from pathlib import Path
from typing import Any

import numpy as np

if str(Path(__file__).parent) not in sys.path:
    sys.path.insert(0, str(Path(__file__).parent))

import schedule_oracle as so

RESULTS = Path(__file__).parent / "results" / "schedule"
GAINS: dict[str, tuple[str, ...]] = {
    "pmd": ("kp", "ki", "kd", "kout"),
    "pmac": ("proportional_gain", "derivative_gain", "integral_gain"),
    "parker6k": ("sgp", "sgi", "sgv"),
}
"""Per chip family, the registers the search moves (every axis's), in log steps: the feedback
gains (PMD's with Kout); the feed-forward and the limits are kept."""


class LinearCheck:
    """The multi-axis check's linear part for one set, on a machine built once."""

    def __init__(
        self, problem: Any, limits: Any, sets: list[Any], plants: list[dict] | None = None
    ) -> None:
        from servogym.sim._multicheck import (
            _machine,
            machine_stress_cases,
            operating_configurations,
        )

        evaluator = problem.make_evaluator()
        evaluator.plant.set_params(problem.nominal_plant())
        self.limits = limits
        self.cases = []
        for k, values in enumerate(plants or [{}]):
            machine, _ = _machine(sets, evaluator.multi, None, values, None, None, None, None)
            self.machine = machine  # the same assumptions and sequencing for every plant
            for case in machine_stress_cases(machine, limits):
                if case.name.startswith(("latency", "sequencing")):
                    continue  # every timing choice is analysed on the plant as given below
                ev = machine.evaluator(case, limits)
                name = case.name if not plants else f"plant {k + 1}: {case.name}"
                self.cases.append((name, case.name == "reference", ev,
                                   operating_configurations(ev.commands())))  # fmt: skip
        self.cache: dict = {}

    def slack(self, sets: list[Any]) -> tuple[float, str]:
        """The worst slack (dB-equivalent) and where it is."""
        from servogym.sim._machine import SEQUENCING, axis_latencies
        from servogym.sim._multicheck import machine_margins

        lim = self.limits
        worst, where = np.inf, ""
        asm0 = self.machine.assumptions
        for name, everything, ev, configs in self.cases:
            chip = ev.chip
            # as the check: every timing choice on the machine as given, the stress plants
            # at the machine's own timing
            latencies = type(asm0).CHOICES["loop_latency"] if everything else [asm0.loop_latency]
            sequencings = SEQUENCING[chip.name].choices if everything else [self.machine.sequencing]
            for latency in latencies:
                asm = dataclasses.replace(asm0, loop_latency=latency)
                for seq in sequencings:
                    mm = machine_margins(chip, sets, asm, ev.plant, configs,
                                         axis_latencies(sets, asm, seq), self.cache)  # fmt: skip
                    for per in mm.analyses:
                        for k, a in enumerate(per):
                            m = a.margins
                            if not m.stable:
                                s = -10.0 - 100.0 * max(m.spectral_radius - 1.0, 0.0)
                            else:
                                s = min(
                                    m.gain_margin_db - lim.min_gain_margin_db,
                                    (m.phase_margin_deg - lim.min_phase_margin_deg) / 5.0,
                                )
                            if s < worst:
                                worst, where = s, f"{name}, {latency}/{seq}, loop {k + 1}"
        return float(worst), where


def log_registers(
    space: Any, start: dict[str, int], registers: dict[str, tuple[str, ...]]
) -> tuple[list[str], np.ndarray, Any]:
    """The entries of ``start`` whose register is one of the chip family's ``registers``
    (every axis's), their logs (a 0 as log 1), and the map from a vector of logs back to
    ``start`` with those registers rounded and held in their legal ranges (>= 1)."""
    from servogym.chips._family import get_chip

    family = get_chip(space.chip_model)[0].name
    names = [n for n in start if n.split(".")[0] in registers[family]]

    def values_of(x: np.ndarray) -> dict[str, int]:
        out = dict(start)
        for n, v in zip(names, x, strict=True):
            spec = space.space[n]
            out[n] = int(min(max(round(float(np.exp(v))), max(spec.low, 1)), spec.high))
        return out

    return names, np.log([max(start[n], 1) for n in names]), values_of


def move_into_margins(
    problem: Any,
    limits: Any,
    start: dict[str, int],
    *,
    plants: list[dict] | None = None,
    target: float = 0.5,
    cost_weight: float = 0.5,
    max_evals: int = 400,
) -> dict[str, Any]:
    """Nelder-Mead on the log loop gains of ``start`` until the worst slack on ``plants``
    (the problem's plant as given, or these plant instances: a robust run's draws) reaches
    ``target``. Returns ``{"values": the set found or None, "slack", "where",
    "start_slack", "start_where", "evaluations", "search_s"}`` (without a set found,
    ``slack`` is the best reached)."""
    import scipy.optimize

    space = problem.space
    names, x0, values_of = log_registers(space, start, GAINS)

    t0 = time.perf_counter()
    lin = LinearCheck(problem, limits, space.make_params(start).sets, plants)
    seen: dict[tuple, tuple[float, str]] = {}

    def slack_of(values: dict[str, int]) -> tuple[float, str]:
        key = tuple(values[n] for n in names)
        if key not in seen:
            seen[key] = lin.slack(space.make_params(values).sets)
        return seen[key]

    class _Done(Exception):
        pass

    best: dict[str, Any] = {}

    def objective(x: np.ndarray) -> float:
        v = values_of(x)
        sl, where = slack_of(v)
        given_up = float(np.sum(np.maximum(x0 - x, 0.0)))  # log gain below the start
        f = -min(sl, target) + cost_weight * given_up
        if sl >= target and (not best or f < best["f"]):
            best.update(f=f, values=v, slack=sl, where=where)
        if len(seen) >= max_evals:
            raise _Done
        return f

    s0, where0 = slack_of(start)
    out: dict[str, Any] = {"start_slack": s0, "start_where": where0}
    if s0 >= target:
        best.update(values=dict(start), slack=s0, where=where0)
    else:
        options = {"xatol": 0.01, "fatol": 1e-3, "maxfev": max_evals, "adaptive": True}
        with contextlib.suppress(_Done):
            scipy.optimize.minimize(objective, x0, method="Nelder-Mead", options=options)
    if best:
        out.update(values=best["values"], slack=best["slack"], where=best["where"])
    else:
        sl, where = max(seen.values())
        out.update(values=None, slack=sl, where=where)
    out.update(evaluations=len(seen), search_s=time.perf_counter() - t0)
    return out


FEED_FORWARD: dict[str, tuple[str, ...]] = {
    "pmd": ("kvff", "kaff"),
    "pmac": ("velocity_ff", "acceleration_ff"),
    "parker6k": ("sgvf", "sgaf"),
}
"""Per chip family, the feed-forward registers :func:`fit_feed_forward` moves (every axis's):
they act on the commanded trajectory outside the loop, so the loop's margins do not change."""


class TaskErrors:
    """The check's following-error and saturation tests on its reference case, at each plant
    of ``plants``, for one set: the tasks run as the check runs them (RK4 reference)."""

    def __init__(self, problem: Any, limits: Any, sets: list[Any], plants: list[dict]) -> None:
        from servogym.sim._multicheck import _machine, machine_stress_cases

        evaluator = problem.make_evaluator()
        evaluator.plant.set_params(problem.nominal_plant())
        self.limits = limits
        self.evaluators = []
        for values in plants:
            machine, _ = _machine(sets, evaluator.multi, None, values, None, None, None, None)
            reference = machine_stress_cases(machine, limits)[0]
            self.evaluators.append(machine.evaluator(reference, limits))
        self.fe_limits = [self._fe_limits(ev) for ev in self.evaluators]

    def _fe_limits(self, ev: Any) -> np.ndarray:
        from servogym.sim._multicheck import _spans

        spans = _spans(ev.commands())
        if self.limits.max_following_error is not None:
            return np.full(len(spans), float(self.limits.max_following_error))
        return 0.01 * np.where(spans > 0, spans, np.max(spans))

    def ratio(self, sets: list[Any], workers: int = 1) -> tuple[float, str]:
        """The worst of (following error / its limit) and (saturation / its maximum) over
        every plant and axis (a divergence: 10), and where it is."""
        from concurrent.futures import ThreadPoolExecutor

        with ThreadPoolExecutor(max(1, workers)) as pool:  # the loop releases the GIL
            runs = list(pool.map(lambda ev: ev.evaluate(sets), self.evaluators))
        worst, where = -np.inf, ""
        for k, (e, fe_max) in enumerate(zip(runs, self.fe_limits, strict=True)):
            if e.diverged:
                return 10.0, f"plant {k + 1}: diverged"
            for a in range(len(fe_max)):
                ms = [t.metrics[a] for t in e.tasks]
                fe = max(m.max_following_error for m in ms)
                ticks = max(sum(m.n_ticks for m in ms), 1)
                sat = sum(m.saturation_fraction * m.n_ticks for m in ms) / ticks
                for r, what in (
                    (fe / fe_max[a], f"following error {fe:.0f} / {fe_max[a]:.0f}"),
                    (sat / self.limits.max_saturation, f"saturation {sat:.3f}"),
                ):
                    if r > worst:
                        worst, where = float(r), f"plant {k + 1}, axis {a + 1}: {what}"
        return worst, where


def fit_feed_forward(
    problem: Any,
    limits: Any,
    start: dict[str, int],
    *,
    plants: list[dict],
    target: float = 0.85,
    accept: float | None = None,
    max_evals: int = 80,
    workers: int = 1,
) -> dict[str, Any]:
    """Nelder-Mead on the log feed-forward registers (:data:`FEED_FORWARD`, every axis's) of
    ``start`` until the worst of following error / limit and saturation / maximum over the
    check's tasks at every plant of ``plants`` (:class:`TaskErrors`) is at most ``target``.
    The feedback gains are kept, so the margins are those of ``start``. When ``target`` is
    not reached in ``max_evals`` candidates, the best is kept if its ratio is at most
    ``accept`` (default: ``target``). Returns ``{"values": the set found or None, "ratio",
    "where", "start_ratio", "start_where", "evaluations", "search_s", "best"}`` (``best``:
    the set of the best ratio reached, found or not)."""
    import scipy.optimize

    space = problem.space
    names, x0, values_of = log_registers(space, start, FEED_FORWARD)

    t0 = time.perf_counter()
    errors = TaskErrors(problem, limits, space.make_params(start).sets, plants)
    seen: dict[tuple, tuple[float, str]] = {}

    def ratio_of(values: dict[str, int]) -> tuple[float, str]:
        key = tuple(values[n] for n in names)
        if key not in seen:
            seen[key] = errors.ratio(space.make_params(values).sets, workers)
            print(f"  ff {dict(zip(names, key, strict=True))}: {seen[key][0]:.3f} "
                  f"({seen[key][1]})", flush=True)  # fmt: skip
        return seen[key]

    class _Done(Exception):
        pass

    best: dict[str, Any] = {}

    def objective(x: np.ndarray) -> float:
        v = values_of(x)
        r, where = ratio_of(v)
        if not best or r < best["ratio"]:
            best.update(values=v, ratio=r, where=where)
        if r <= target or len(seen) >= max_evals:
            raise _Done
        return r

    r0, where0 = ratio_of(start)
    out: dict[str, Any] = {"start_ratio": r0, "start_where": where0}
    best.update(values=dict(start), ratio=r0, where=where0)
    if r0 > target:
        # steps of about 20 % in every register (Nelder-Mead's own first steps are 5 %)
        simplex = np.vstack([x0] + [x0 + 0.2 * np.eye(len(x0))[i] for i in range(len(x0))])
        options = {"xatol": 0.005, "fatol": 1e-3, "maxfev": max_evals, "initial_simplex": simplex}
        with contextlib.suppress(_Done):
            scipy.optimize.minimize(objective, x0, method="Nelder-Mead", options=options)
    found = best["ratio"] <= (target if accept is None else max(target, accept))
    out.update(values=best["values"] if found else None, best=best["values"],
               ratio=best["ratio"], where=best["where"], evaluations=len(seen),
               search_s=time.perf_counter() - t0)  # fmt: skip
    return out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--scenario", default="TwoLinkArm")
    ap.add_argument("--point", type=int, default=2, help="operating point index (of --points)")
    ap.add_argument("--points", type=int, default=3)
    ap.add_argument("--from-label", default="chain-150", help="schedule_oracle label to start from")
    ap.add_argument("--label", default="margin-search")
    ap.add_argument("--target", type=float, default=0.5, help="slack to reach (dB-equivalent)")
    ap.add_argument("--cost-weight", type=float, default=0.5)
    ap.add_argument("--max-evals", type=int, default=400)
    ap.add_argument("--workers", type=int, default=2)
    ap.add_argument("--out", type=Path, default=RESULTS / "margin_search.jsonl")
    args = ap.parse_args()

    s = so.get_any_scenario(args.scenario)
    point = float(s.operating_points(args.points)[args.point])
    start = so.recorded_set(so._done(RESULTS / "oracle.jsonl"), s,
                            f"{args.from_label}:{args.point}", "--from-label/--point")  # fmt: skip
    config = so._config(s, so.point_args(args.workers), point)
    problem = config.problem()
    limits = config.check_limits()
    earlier = (
        [json.loads(x) for x in args.out.read_text().splitlines()] if args.out.exists() else []
    )
    rec = next((r for r in earlier if r["label"] == args.label and r["scenario"] == args.scenario
                and r["point"] == args.point), None)  # fmt: skip
    if rec is None:
        rec = search_and_check(args, problem, limits, start, point)
        with args.out.open("a") as f:
            f.write(json.dumps(rec) + "\n")
    else:
        print(f"{args.label}: the search is in {args.out}; not run again")
    if rec.get("check_passed"):
        record_for_oracle(args, s, rec)


def search_and_check(args, problem, limits, start: dict[str, int], point: float) -> dict:
    """Search from ``start``; the full check of the set found."""
    found = move_into_margins(problem, limits, start, target=args.target,
                              cost_weight=args.cost_weight, max_evals=args.max_evals)  # fmt: skip
    print(f"start: slack {found['start_slack']:.3f} at {found['start_where']}")
    rec: dict[str, Any] = {"scenario": args.scenario, "point": args.point, "value": point,
                           "label": args.label, "from_label": args.from_label, "start": start,
                           "target": args.target, "cost_weight": args.cost_weight,
                           **{k: v for k, v in found.items() if k != "values"},
                           "found": found["values"]}  # fmt: skip
    if found["values"] is None:
        print(f"no set reached slack {args.target} in {found['evaluations']} evaluations; "
              f"best {found['slack']:.3f} at {found['where']}")  # fmt: skip
        return rec
    print(f"found slack {found['slack']:.3f} after {found['evaluations']} evaluations "
          f"({found['search_s']:.0f} s): {found['values']}", flush=True)  # fmt: skip
    report = problem.check(problem.space.make_params(found["values"]), limits,
                           workers=args.workers)  # fmt: skip
    rec.update(check_passed=bool(report.passed), check_failures=list(report.failures)[:6],
               check_s=float(report.elapsed_s))  # fmt: skip
    print(f"check: {'passed' if report.passed else 'failed'} {list(report.failures)[:3]}")
    return rec


def record_for_oracle(args, s, rec: dict[str, Any]) -> None:
    """Append the checked set found to the oracle study's records (tuner ``margin-search``,
    with its cross-evaluation at every point), so that ``schedule_oracle.py --pooled`` counts
    it among the checked sets known."""
    path = RESULTS / "oracle.jsonl"
    margin_start = {k: rec.get(k) for k in ("start_slack", "slack", "where", "evaluations",
                                            "search_s")}  # fmt: skip
    cross = so.append_checked_set(path, s, args.label, args.point, rec["found"],
                                  s.operating_points(args.points), args.workers,
                                  value=rec["value"], warm_start=rec["from_label"],
                                  margin_start=margin_start)  # fmt: skip
    if cross is not None:
        print(f"recorded in {path}: cross {[round(c, 3) for c in cross]}")


if __name__ == "__main__":
    main()
