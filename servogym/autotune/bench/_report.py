"""The benchmark report, as COCO reports: targets, ECDFs, relative costs, safety, wall time.

Definitions (docs/benchmark.md):

* A run's *best-so-far* after n evaluations is the lowest cost among its *safe* trials so
  far (feasible: no divergence, following error within 1 % of the move, at most 5 % of ticks
  at the motor limit). Unsafe trials never count, whatever their cost. Every evaluation of
  the budget counts on the x axis, a classical tuner's experiments included.
* Targets are ``best_known * (1 + eps)`` for eps in :data:`TARGET_EPS`. The ECDF at n is the
  fraction of (instance, target, run) triples whose target the run has reached within n
  evaluations, each instance weighted equally.
* Anytime tuners (the Optuna samplers) give their value at budget B from the first B trials
  of one long run; classical tuners ran at each budget (markers on the ECDF plot).
* Relative final cost at budget B: best-so-far / best-known (1 = the reference's best;
  below 1: better than the reference search found; ``inf``: no safe trial at all).
* Unsafe evaluations: trials that diverged (including the chip's own position-error trip),
  exceeded the following-error limit or saturated; a classical experiment that diverged.
"""

from __future__ import annotations

import json
import math
from collections import defaultdict
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

import numpy as np

from servogym.autotune.bench._runner import (
    ANYTIME_TUNERS,
    FLAG_DIVERGED,
    FLAG_EXPERIMENT,
    FLAG_FAILED,
    FLAG_FOLLOWING_ERROR,
    FLAG_MARGINS,
    FLAG_SATURATION,
    UNSAFE_FLAGS,
)

TARGET_EPS: tuple[float, ...] = (3.0, 1.0, 0.3, 0.1, 0.03, 0.01)
"""Targets: cost <= best_known * (1 + eps). From "within 4x" (a working loop) to "within 1 %"
(as good as the reference search)."""


class Run:
    """One job's trials, ready for the report."""

    def __init__(self, rec: Mapping[str, Any]) -> None:
        self.tuner: str = rec["tuner"]
        self.instance: str = rec["instance"]
        self.seed: int = int(rec["seed"])
        self.budget: int = int(rec["budget"])
        self.anytime: bool = bool(rec.get("anytime", self.tuner in ANYTIME_TUNERS))
        self.error: str | None = rec.get("error")
        self.flags = np.asarray(rec["flags"], dtype=np.int64)
        cost = np.array([np.inf if c is None else c for c in rec["cost"]], dtype=float)
        safe = (self.flags & (UNSAFE_FLAGS | FLAG_EXPERIMENT | FLAG_FAILED)) == 0
        self.best = np.minimum.accumulate(np.where(safe, cost, np.inf)) if len(cost) else cost
        self.t = np.asarray(rec.get("t", []), dtype=float)
        self.wall_s = float(rec.get("wall_s", 0.0))
        self.checked: dict[str, Any] | None = rec.get("checked")

    @property
    def n(self) -> int:
        """Evaluations the run used."""
        return len(self.flags)

    def is_checked(self, budget: int) -> bool:
        """Whether the run's result at ``budget`` went through the check."""
        return self.checked is not None and str(min(budget, self.budget)) in self.checked

    def best_at(self, budget: int) -> float:
        """The run's result within ``budget`` evaluations: the cheapest safe trial that passed
        the check, as ``servogym tune`` would write it, where the job checked that budget
        (``CHECK_BUDGETS``); otherwise the best-so-far safe trial (inf: none)."""
        if self.is_checked(budget):
            hit = self.checked[str(min(budget, self.budget))]
            return math.inf if hit is None else float(hit["cost"])
        k = min(budget, self.n)
        return float(self.best[k - 1]) if k > 0 else math.inf

    def first_hit(self, target: float) -> int | None:
        """Evaluations needed to reach ``target`` (``None``: never)."""
        hit = np.nonzero(self.best <= target)[0]
        return int(hit[0]) + 1 if len(hit) else None

    def unsafe(self, budget: int) -> dict[str, int]:
        """Unsafe evaluations within ``budget``, by kind (one trial may have several)."""
        f = self.flags[: min(budget, self.n)]
        return {
            "unsafe": int(np.count_nonzero(f & UNSAFE_FLAGS)),
            "diverged": int(np.count_nonzero(f & FLAG_DIVERGED)),
            "following_error": int(np.count_nonzero(f & FLAG_FOLLOWING_ERROR)),
            "saturation": int(np.count_nonzero(f & FLAG_SATURATION)),
            "margins": int(np.count_nonzero(f & FLAG_MARGINS)),
        }

    def wall_at(self, budget: int) -> float:
        """Wall time of the first ``budget`` evaluations (s)."""
        if self.anytime and len(self.t):
            return float(self.t[min(budget, len(self.t)) - 1])
        return self.wall_s


def runs_at(runs: Sequence[Run], tuner: str, budget: int) -> list[Run]:
    """The runs that give ``tuner``'s result at ``budget`` (empty: not run at it)."""
    out = []
    for r in runs:
        if r.tuner != tuner:
            continue
        if (r.anytime and r.budget >= budget) or (not r.anytime and r.budget == budget):
            out.append(r)
    return out


def _quantiles(x: np.ndarray, qs: Sequence[float]) -> list[float]:
    """Quantiles of ratios that may be inf (no safe set): sample values, no interpolation
    (the ``inverted_cdf`` method), so a quantile is inf exactly when that run found none."""
    return [float(v) for v in np.quantile(x, qs, method="inverted_cdf")]


BOOTSTRAP_RESAMPLES = 2000
"""Resamples of the bootstrap interval of a median (seeded: the report is reproducible)."""


def median_ci(x: np.ndarray, level: float = 0.95, seed: int = 0) -> tuple[float, float]:
    """Percentile bootstrap interval of the median of ratios that may be inf (a run with no
    safe set): each resample's median is a sample value (``inverted_cdf``), so a bound is inf
    exactly when that many runs found no safe set."""
    if len(x) == 0:
        return math.nan, math.nan
    rng = np.random.default_rng(seed)
    idx = rng.integers(0, len(x), size=(BOOTSTRAP_RESAMPLES, len(x)))
    meds = np.quantile(x[idx], 0.5, axis=1, method="inverted_cdf")
    lo, hi = np.quantile(meds, [(1 - level) / 2, (1 + level) / 2], method="inverted_cdf")
    return float(lo), float(hi)


def _fmt(x: float, digits: int = 3) -> str:
    if not math.isfinite(x):
        return "inf"
    return f"{x:.{digits}g}"


def ecdf_curve(
    runs: Sequence[Run], best_known: Mapping[str, float], xs: np.ndarray, instances: set[str]
) -> np.ndarray:
    """Fraction of (instance, target, run) triples reached within each x, instances equal."""
    by_inst: dict[str, list[Run]] = defaultdict(list)
    for r in runs:
        if r.instance in instances and r.instance in best_known:
            by_inst[r.instance].append(r)
    if not by_inst:
        return np.full(len(xs), np.nan)
    total = np.zeros(len(xs))
    for inst, rs in by_inst.items():
        frac = np.zeros(len(xs))
        for eps in TARGET_EPS:
            target = best_known[inst] * (1 + eps)
            for r in rs:
                hit = r.first_hit(target)
                if hit is not None:
                    frac += (xs >= hit) & (xs <= r.n)
        total += frac / (len(TARGET_EPS) * len(rs))
    return total / len(by_inst)


def _plot_ecdf(
    runs: Sequence[Run],
    best_known: Mapping[str, float],
    tuners: Sequence[str],
    budgets: Sequence[int],
    instances: set[str],
    path: Path,
    title: str,
) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(7.5, 4.8))
    xs = np.arange(1, max(budgets) + 1)
    colors = plt.get_cmap("tab10")
    for k, tuner in enumerate(tuners):
        tr = [r for r in runs if r.tuner == tuner and r.instance in instances]
        if not tr:
            continue
        n_inst = len({r.instance for r in tr if r.instance in best_known})
        label = f"{tuner} ({n_inst} inst.)"
        if tr[0].anytime:
            top = max(r.budget for r in tr)
            x = xs[xs <= top]
            ax.step(x, ecdf_curve(tr, best_known, x, instances), where="post",
                    color=colors(k), label=label)  # fmt: skip
        else:
            pts = []
            for b in budgets:
                rb = runs_at(tr, tuner, b)
                if rb:
                    # fraction reached by the end of the budget-b run
                    pts.append((b, ecdf_curve(rb, best_known, np.array([b]), instances)[0]))
            if pts:
                x, y = zip(*pts, strict=True)
                ax.plot(x, y, "o--", color=colors(k), label=label + ", per budget")
    ax.set_xscale("log")
    ax.set_xlim(1, max(budgets))
    ax.set_ylim(0, 1)
    ax.set_xlabel("evaluations")
    ax.set_ylabel("fraction of (instance, target) pairs reached")
    eps = ", ".join(f"{e:g}" for e in TARGET_EPS)
    ax.set_title(f"{title}\ntargets: best-known x (1 + eps), eps in {{{eps}}}", fontsize=10)
    ax.grid(True, which="both", alpha=0.3)
    ax.legend(fontsize=8, loc="upper left")
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def _plot_relative(
    runs: Sequence[Run],
    best_known: Mapping[str, float],
    tuners: Sequence[str],
    budgets: Sequence[int],
    path: Path,
) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(1, len(budgets), figsize=(4.2 * len(budgets), 4.2), sharey=True)
    axes = np.atleast_1d(axes)
    for ax, b in zip(axes, budgets, strict=True):
        data, labels = [], []
        for tuner in tuners:
            rb = [r for r in runs_at(runs, tuner, b) if r.instance in best_known]
            if not rb:
                continue
            ratio = np.array([r.best_at(b) / best_known[r.instance] for r in rb])
            data.append(np.clip(ratio, 0.5, 1e3))
            labels.append(tuner)
        if data:
            ax.boxplot(data, whis=(5, 95), showfliers=False)
            ax.set_xticks(range(1, len(labels) + 1), labels, rotation=45, ha="right")
        ax.set_yscale("log")
        ax.axhline(1.0, color="k", lw=0.8)
        ax.set_title(f"budget {b}")
        ax.grid(True, axis="y", which="both", alpha=0.3)
    axes[0].set_ylabel("final cost / best-known (no safe set: 1000)")
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def summarize(
    runs: Sequence[Run],
    best_known: Mapping[str, float],
    tuners: Sequence[str],
    budgets: Sequence[int],
    instances: Sequence[str],
) -> list[dict[str, Any]]:
    """One row per (tuner, budget): relative cost, targets reached, unsafe counts, wall."""
    rows = []
    inst_set = {i for i in instances if i in best_known}
    for tuner in tuners:
        for b in budgets:
            rb = [r for r in runs_at(runs, tuner, b) if r.instance in inst_set]
            if not rb:
                rows.append({"tuner": tuner, "budget": b, "n_runs": 0})
                continue
            ratio = np.array([r.best_at(b) / best_known.get(r.instance, np.nan) for r in rb])
            ratio = ratio[~np.isnan(ratio)]
            unsafe = [r.unsafe(b) for r in rb]
            evals = np.array([min(b, r.n) for r in rb])
            wall = np.array([r.wall_at(b) for r in rb])
            reached = ecdf_curve(rb, best_known, np.array([b]), inst_set)[0]
            q = _quantiles(ratio, (0.25, 0.5, 0.75)) if len(ratio) else [math.nan] * 3
            rows.append(
                {
                    "tuner": tuner,
                    "budget": b,
                    "n_instances": len({r.instance for r in rb}),
                    "n_runs": len(rb),
                    "n_errors": sum(r.error is not None for r in rb),
                    **dict(zip(("q25_rel", "median_rel", "q75_rel"), q, strict=True)),
                    "median_rel_ci95": list(median_ci(ratio)),
                    "unchecked_runs": sum(not r.is_checked(b) for r in rb),
                    "within_5pct": float(np.mean(ratio <= 1.05)) if len(ratio) else math.nan,
                    "within_10pct": float(np.mean(ratio <= 1.1)) if len(ratio) else math.nan,
                    "no_safe_set": int(np.sum(~np.isfinite(ratio))),
                    "targets_reached": float(reached),
                    "mean_evals": float(evals.mean()),
                    "unsafe_per_run": float(np.mean([u["unsafe"] for u in unsafe])),
                    "diverged_per_run": float(np.mean([u["diverged"] for u in unsafe])),
                    "fe_per_run": float(np.mean([u["following_error"] for u in unsafe])),
                    "sat_per_run": float(np.mean([u["saturation"] for u in unsafe])),
                    "margins_per_run": float(np.mean([u["margins"] for u in unsafe])),
                    "unsafe_fraction": float(
                        sum(u["unsafe"] for u in unsafe) / max(int(evals.sum()), 1)
                    ),
                    "runs_with_unsafe": float(np.mean([u["unsafe"] > 0 for u in unsafe])),
                    "median_wall_s": float(np.median(wall)),
                    "ms_per_eval": float(1000 * wall.sum() / max(evals.sum(), 1)),
                    # costs are stored to 6 significant digits
                    "beat_best_known": int(np.sum(ratio < 1 - 1e-5)),
                }
            )
    return rows


SUMMARY_COLUMNS = (
    ("tuner", "tuner"),
    ("budget", "budget"),
    ("inst.", "n_instances"),
    ("runs", "n_runs"),
    ("median rel. cost [IQR]", None),
    ("median 95 % CI", None),
    ("within 5 %", "within_5pct"),
    ("within 10 %", "within_10pct"),
    ("targets reached", "targets_reached"),
    ("no safe set", "no_safe_set"),
    ("unsafe evals/run (div/FE/sat/margin)", None),
    ("unsafe share", "unsafe_fraction"),
    ("runs with unsafe", "runs_with_unsafe"),
    ("median wall (s)", "median_wall_s"),
    ("ms/eval", "ms_per_eval"),
)
"""Columns of the summary table (the report's first table)."""


def _summary_table(rows: Sequence[Mapping[str, Any]]) -> list[str]:
    head = [c for c, _ in SUMMARY_COLUMNS]
    lines = ["| " + " | ".join(head) + " |", "|" + "---|" * len(head)]
    for r in rows:
        if not r.get("n_runs"):
            na = " | ".join(["n/a"] * (len(head) - 2))
            lines.append(f"| {r['tuner']} | {r['budget']} | {na} |")
            continue
        cells = [
            r["tuner"], str(r["budget"]), str(r["n_instances"]), str(r["n_runs"]),
            f"{_fmt(r['median_rel'])} [{_fmt(r['q25_rel'])}, {_fmt(r['q75_rel'])}]",
            f"{_fmt(r['median_rel_ci95'][0])}-{_fmt(r['median_rel_ci95'][1])}",
            f"{r['within_5pct']:.0%}", f"{r['within_10pct']:.0%}", f"{r['targets_reached']:.0%}",
            str(r["no_safe_set"]),
            f"{r['unsafe_per_run']:.1f} ({r['diverged_per_run']:.1f}/{r['fe_per_run']:.1f}/"
            f"{r['sat_per_run']:.1f}/{r['margins_per_run']:.1f})",
            f"{r['unsafe_fraction']:.1%}", f"{r['runs_with_unsafe']:.0%}",
            f"{r['median_wall_s']:.1f}", f"{r['ms_per_eval']:.0f}",
        ]  # fmt: skip
        lines.append("| " + " | ".join(cells) + " |")
    return lines


def _instance_table(
    runs: Sequence[Run],
    best_known: Mapping[str, float],
    tuners: Sequence[str],
    budget: int,
    instances: Sequence[str],
) -> list[str]:
    lines = [
        "| instance | best-known | " + " | ".join(tuners) + " |",
        "|---|---|" + "---|" * len(tuners),
    ]
    for inst in instances:
        cells = [inst.split("/", 1)[1], _fmt(best_known.get(inst, math.nan), 4)]
        for tuner in tuners:
            rb = [r for r in runs_at(runs, tuner, budget) if r.instance == inst]
            if not rb or inst not in best_known:
                cells.append("n/a")
                continue
            ratio = np.array([r.best_at(budget) / best_known[inst] for r in rb])
            if len(rb) == 1:
                cells.append(_fmt(ratio[0]))
            else:
                q = _quantiles(ratio, [0.25, 0.5, 0.75])
                cells.append(f"{_fmt(q[1])} [{_fmt(q[0])}-{_fmt(q[2])}]")
        lines.append("| " + " | ".join(cells) + " |")
    return lines


def _unsolved_table(runs: Sequence[Run], tuners: Sequence[str], ids: Sequence[str]) -> list[str]:
    lines = ["| instance | " + " | ".join(tuners) + " |", "|---|" + "---|" * len(tuners)]
    for inst in ids:
        cells = [inst.split("/", 1)[1]]
        for tuner in tuners:
            rs = [r for r in runs if r.tuner == tuner and r.instance == inst]
            if not rs:
                cells.append("n/a")
                continue
            top = max(r.budget for r in rs)
            rs = [r for r in rs if r.budget == top]
            found = [r.best_at(top) for r in rs if math.isfinite(r.best_at(top))]
            best = f" ({_fmt(min(found))})" if found else ""
            cells.append(f"{len(found)}/{len(rs)}{best}")
        lines.append("| " + " | ".join(cells) + " |")
    return lines


FAMILY_NAMES = {"pmd": "PMD", "pmac": "PMAC", "parker6k": "Parker 6000"}
"""How the report names each chip family of the registry."""


def instance_family(instance_id: str) -> str:
    """``"PMD"``, ``"PMAC"`` or ``"Parker 6000"``: the chip family of an instance id's chip
    model, from the chip registry."""
    from servogym.chips._family import get_chip

    family = get_chip(instance_id.split("/")[1])[0].name
    return FAMILY_NAMES.get(family, family)


def default_tuner() -> str:
    """The tuner ``servogym tune`` runs when ``--tuner`` is not given (single objective)."""
    from servogym.autotune._tuners import DEFAULT_TUNER

    return DEFAULT_TUNER


def write_report(
    records: Sequence[Mapping[str, Any]],
    out_dir: str | Path,
    *,
    best_known: Mapping[str, Mapping[str, Any]],
    budgets: Sequence[int],
    tuners: Sequence[str] | None = None,
    instances: Sequence[str] | None = None,
    skipped: Sequence[tuple[str, str, str]] = (),
    notes: Sequence[str] = (),
) -> dict[str, Any]:
    """Write ``report.md``, ``instances.md``, ``summary.json`` and the PNG plots.

    Args:
        records: Job records (:func:`servogym.autotune.bench.load_results`).
        out_dir: Folder for the report.
        best_known: Best-known records by instance id (``cost`` and ``feasible``).
        budgets: Budgets reported.
        tuners: Tuner order (default: as found).
        instances: Instance ids, in order (default: as found).
        skipped: ``(tuner, instance, reason)`` pairs that could not run ("n/a").
        notes: Lines added under the title (e.g. reduced seeds of a tuner).

    Returns:
        The summary written to ``summary.json``.
    """
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    runs = [Run(r) for r in records]
    tuners = list(tuners or dict.fromkeys(r.tuner for r in runs))
    instances = list(instances or dict.fromkeys(r.instance for r in runs))
    infeasible_bk = [i for i in instances if i in best_known and not best_known[i]["feasible"]]
    # A target derived from an unsafe set means nothing: such instances leave the figures
    # and get their own table (did any run find a safe set at all?).
    bk = {
        i: float(v["cost"])
        for i, v in best_known.items()
        if i in instances and i not in infeasible_bk
    }
    missing_bk = [i for i in instances if i not in best_known]
    budgets = sorted(budgets)
    inst_all = set(instances)
    plots = {"ecdf.png": ("all instances", inst_all)}
    title = f"ECDF over {len(inst_all)} instances (each tuner on the instances it ran)"
    _plot_ecdf(runs, bk, tuners, budgets, inst_all, out / "ecdf.png", title)
    # Subsets on which every tuner of a group ran: comparisons on equal terms.
    subsets: dict[str, set[str]] = {}
    for tuner in tuners:
        ran = {r.instance for r in runs if r.tuner == tuner}
        if ran and ran != inst_all:
            subsets.setdefault(f"instances {tuner} ran", ran)
    extra: list[str] = []
    for k, (label, subset) in enumerate(subsets.items()):
        name = f"ecdf_subset{k + 1}.png"
        _plot_ecdf(runs, bk, tuners, budgets, subset, out / name,
                   f"ECDF on the {len(subset)} {label}")  # fmt: skip
        plots[name] = (label, subset)
        extra.append(label)
    _plot_relative(runs, bk, tuners, budgets, out / "relative_cost.png")

    rows = summarize(runs, bk, tuners, budgets, instances)
    families: dict[str, list[str]] = defaultdict(list)
    for i in instances:
        families[instance_family(i)].append(i)
    by_family = {}
    for fam, ids in families.items():
        by_family[fam] = summarize(runs, bk, tuners, budgets, ids)
        name = "ecdf_" + fam.lower().replace(" ", "") + ".png"
        _plot_ecdf(runs, bk, tuners, budgets, set(ids), out / name,
                   f"ECDF on the {len(ids)} {fam} instances")  # fmt: skip
        plots[name] = (f"{fam} instances", set(ids))
    md = [
        "# servobench report",
        "",
        f"{len(instances)} instances, tuners {', '.join(tuners)}, budgets "
        f"{', '.join(map(str, budgets))}. Costs per docs/cost.md; relative cost = the run's "
        "best *safe* cost / best-known; targets best-known x (1 + eps), eps in "
        f"{{{', '.join(f'{e:g}' for e in TARGET_EPS)}}}. Definitions: docs/benchmark.md.",
        "",
    ]
    md += [f"- {n}" for n in notes]
    if infeasible_bk:
        md.append(f"- {len(infeasible_bk)} instance(s) without a known safe set (the reference "
                  "search found none) are left out of every figure and summary; see "
                  "'Instances without a known safe set' below.")  # fmt: skip
    if missing_bk:
        md.append(f"- No best-known record (left out of every figure): {', '.join(missing_bk)}.")
    if skipped:
        by_tuner: dict[str, int] = defaultdict(int)
        for t, _, _ in skipped:
            by_tuner[t] += 1
        md.append("- n/a (cannot run): " + ", ".join(
            f"{t} on {n} instance(s) ({next(r for tt, _, r in skipped if tt == t)})"
            for t, n in by_tuner.items()) + ".")  # fmt: skip
    md += ["", "## Summary (all instances each tuner ran)", ""]
    md += _summary_table(rows)
    for label, subset in ((lbl, s) for lbl, s in subsets.items()):
        md += ["", f"## Summary on the {len(subset)} {label}", ""]
        md += _summary_table(summarize(runs, bk, tuners, budgets, sorted(subset)))
    if len(by_family) > 1:
        for fam, fam_rows in by_family.items():
            md += ["", f"## Summary on the {len(families[fam])} {fam} instances", ""]
            md += _summary_table(fam_rows)
    if infeasible_bk:
        md += ["", "## Instances without a known safe set", "",
               "Runs (at the largest budget each tuner ran) that found at least one safe set, "
               "and the best safe cost any of them found.", ""]  # fmt: skip
        md += _unsolved_table(runs, tuners, infeasible_bk)
    md += ["", "## Plots", ""]
    for name, (label, _subset) in plots.items():
        md.append(f"![ECDF, {label}]({name})")
        md.append("")
    md += ["![relative final cost](relative_cost.png)", ""]
    beat = sum(r.get("beat_best_known", 0) for r in rows if r.get("n_runs"))
    md += [
        f"Runs whose final cost beat the best-known (relative cost < 1), summed over the rows "
        f"above: {beat}.",
        "",
        "Per-instance results (median [IQR] of relative cost over seeds): instances.md.",
        "",
    ]
    (out / "report.md").write_text("\n".join(md))
    inst_md = ["# Per-instance relative final cost", "",
               "Median [25 %-75 %] over seeds of best safe cost / best-known; one number: one "
               "run (deterministic tuner); inf: no safe set; n/a: not run.", ""]  # fmt: skip
    for b in budgets:
        inst_md += [f"## Budget {b}", ""]
        inst_md += _instance_table(runs, bk, tuners, b, instances)
        inst_md.append("")
    (out / "instances.md").write_text("\n".join(inst_md))
    summary = {
        "targets_eps": list(TARGET_EPS),
        "budgets": budgets,
        "tuners": tuners,
        "instances": instances,
        "rows": rows,
        "rows_by_family": by_family,
        "default_tuner": default_tuner(),
        "subsets": {k: sorted(v) for k, v in subsets.items()},
        "skipped": [list(s) for s in skipped],
    }
    (out / "summary.json").write_text(json.dumps(summary, indent=1, default=_json_num) + "\n")
    return summary


def _json_num(x: Any) -> Any:
    if isinstance(x, np.generic):
        return x.item()
    raise TypeError(type(x).__name__)
