"""Output files of ``servogym tune``: tuned set, exports, trials, plots and summary."""

from __future__ import annotations

import csv
import dataclasses
import io
import json
import math
from pathlib import Path
from typing import Any

import numpy as np

from servogym import __version__
from servogym._files import write_atomic, write_file_set
from servogym.autotune._problem import TuneProblem
from servogym.autotune._session import (
    counts_toward_budget,
    is_feasible,
    pareto_front,
    scored_trials,
)
from servogym.autotune._space import UNIT_PREFIX
from servogym.chips._family import family_of, get_chip
from servogym.sim._scenario import Evaluation, Evaluator

TABLE_METRICS = (
    ("cost", "cost"),
    ("diverged", "diverged"),
    ("max_following_error", "max following error (counts)"),
    ("saturation_fraction", "saturation (fraction of ticks)"),
    ("overshoot", "overshoot (counts)"),
    ("settling_time", "settling time (s)"),
    ("steady_state_error", "steady-state error (counts)"),
    ("rms_command", "RMS command (fraction)"),
    ("chatter", "chatter (fraction/tick)"),
)
"""Rows of the default-vs-tuned table: (key of :func:`evaluation_metrics`, label)."""


def _n_counted(trials: list[Any]) -> int:
    """Trials that used the budget (not a dead worker's re-queued or an over-budget one)."""
    return sum(map(counts_toward_budget, trials))


def export_names(family: Any, model: str | None = None) -> dict[str, str]:
    """File name of each export format of a chip family (of one model, when given: the
    formats it takes, :meth:`ChipFamily.formats_for`): ``best_params.json``, ...

    A format whose extension (``family.file_extensions``) is unique and not ``.txt`` gets
    ``best_params<ext>``; the others ``best_params_<format><ext>`` (``best_params_host.txt``).
    """
    formats = family.formats if model is None else family.formats_for(model)
    exts = {f: family.file_extensions.get(f, ".txt") for f in formats}
    out = {}
    for fmt, ext in exts.items():
        unique = list(exts.values()).count(ext) == 1 and ext != ".txt"
        out[fmt] = f"best_params{ext}" if unique else f"best_params_{fmt}{ext}"
    return out


def plant_description(problem: dict) -> str:
    """The plant a run used: ``nominal plant``, its fixed values, or the robust draws."""
    fixed = ", ".join(f"{k}={v:g}" for k, v in problem.get("plant_values", {}).items())
    ranges = problem.get("plant_ranges") or {}
    if problem["n_plants"] == 1:
        return f"plant {fixed}" if fixed else "nominal plant"
    where = f"{problem['robust_mode']} over {problem['n_plants']} plant instances"
    if ranges:
        where += " with " + ", ".join(f"{k} in [{lo:g}, {hi:g}]" for k, (lo, hi) in ranges.items())
    return where + (f", {fixed}" if fixed else "")


def evaluation_metrics(evaluations: list[Evaluation], mode: str) -> dict[str, float]:
    """Figures of a set over the plant instances: the aggregated cost, worst of the rest."""
    from servogym.sim._scenario import robust_cost

    metrics = [m for e in evaluations for m in e.metrics]
    return {
        "cost": robust_cost(evaluations, mode),
        "diverged": float(sum(e.diverged for e in evaluations)),
        "max_following_error": max(e.max_following_error for e in evaluations),
        "saturation_fraction": max(e.saturation_fraction for e in evaluations),
        "overshoot": max(m.overshoot for m in metrics),
        "settling_time": max(m.settling_time for m in metrics),
        "steady_state_error": max(m.steady_state_error for m in metrics),
        "rms_command": max(m.rms_command for m in metrics),
        "chatter": max(m.chatter for m in metrics),
    }


def evaluate_on_problem(problem: TuneProblem, params: Any) -> tuple[list[Evaluation], Evaluation]:
    """A set on every plant instance of the problem, and on the nominal one with traces."""
    ev = Evaluator(problem.scenario)
    evaluations = [ev.evaluate(params, plant) for plant in problem.plant_instances()]
    nominal = ev.evaluate(params, problem.nominal_plant(), traces=True)
    return evaluations, nominal


def write_trials_csv(trials: list[Any], names: tuple[str, ...], path: Path) -> None:
    """:func:`trials_csv_text` written atomically to ``path``."""
    write_atomic(path, trials_csv_text(trials, names))


def trials_csv_text(trials: list[Any], names: tuple[str, ...]) -> str:
    """Every trial: number, kind, state, objective values, feasibility and the constraints
    it failed (``;``-separated names of :meth:`TuneProblem.constraint_values`), outcome
    figures, loop margins (worst over the plant instances; empty: unbounded or not
    computed), registers, unit-cube coordinates."""
    registers: list[str] = []
    for t in trials:
        for key in t.user_attrs.get("registers", {}):
            if key not in registers:
                registers.append(key)
    n_obj = max((len(t.values) for t in trials if t.values), default=1)
    value_cols = ["cost"] + [f"objective_{i}" for i in range(1, n_obj)]
    outcome_cols = ["n_diverged", "max_following_error", "saturation_fraction",
                    "rms_command", "chatter", "settling_time", "n_unstable", "gain_margin_db",
                    "phase_margin_deg", "delay_margin_s", "bandwidth_hz"]  # fmt: skip
    header = (
        ["number", "kind", "state", *value_cols, "feasible", "failed_constraints", *outcome_cols]
        + registers
        + [UNIT_PREFIX + n for n in names]
        + ["duration_s", "note"]
    )
    fh = io.StringIO(newline="")
    w = csv.writer(fh)
    w.writerow(header)
    for t in trials:
        values = list(t.values) if t.values else []
        values += [""] * (n_obj - len(values))
        outcome = t.user_attrs.get("outcome", {})
        regs = t.user_attrs.get("registers", {})
        duration = t.duration.total_seconds() if t.duration is not None else ""
        note = t.user_attrs.get("note") or t.user_attrs.get("error") or ""
        w.writerow(
            [t.number, t.user_attrs.get("kind", ""), t.state.name, *values,
             is_feasible(t) if t.values else "",
             ";".join(k for k, v in t.constraints.items() if v > 0) if t.values else ""]
            + [_cell(outcome.get(c)) for c in outcome_cols]
            + [regs.get(r, "") for r in registers]
            + [t.params.get(UNIT_PREFIX + n, "") for n in names]
            + [duration, note]
        )  # fmt: skip
    return fh.getvalue()


def _cell(value: Any) -> Any:
    return "" if value is None else value


def convergence_figure(trials: list[Any], default_cost: float, title: str):
    """Cost of each scored trial and the best so far, against the evaluation number."""
    from matplotlib.figure import Figure

    fig = Figure(figsize=(8.0, 5.0))
    ax = fig.subplots()
    scored = scored_trials(trials)
    for ok, style in (
        (True, {"color": "tab:blue", "marker": "o", "label": "trial (feasible)"}),
        (False, {"color": "tab:red", "marker": "x", "label": "trial (infeasible)"}),
    ):
        pts = [(t.number + 1, t.values[0]) for t in scored if is_feasible(t) == ok]
        if pts:
            ax.scatter(*zip(*pts, strict=True), s=10, alpha=0.6, **style)
    best, bx, by = math.inf, [], []
    for t in scored:
        if is_feasible(t) and t.values[0] < best:
            best = t.values[0]
        if math.isfinite(best):
            bx.append(t.number + 1)
            by.append(best)
    if bx:
        bx.append(len(trials))
        by.append(by[-1])
        ax.step(bx, by, where="post", color="k", lw=1.5, label="best so far (feasible)")
    experiments = [t.number + 1 for t in trials if t.user_attrs.get("kind") == "experiment"]
    if experiments:
        ax.plot(experiments, [default_cost] * len(experiments), "|", color="tab:gray",
                ms=12, label="experiment (no cost)")  # fmt: skip
    ax.axhline(default_cost, color="tab:orange", ls="--", lw=1, label="chip defaults")
    ax.set_yscale("log")
    ax.set_xlabel("evaluation")
    ax.set_ylabel("cost (log scale)")
    ax.grid(True, alpha=0.3, which="both")
    ax.legend(fontsize=8, loc="upper center", bbox_to_anchor=(0.5, -0.14), ncol=5)
    ax.set_title(title, fontsize=10)
    fig.tight_layout()
    return fig


def pareto_figure(trials: list[Any], objectives: tuple[str, ...]):
    """Objectives 0 and 1 of every feasible scored trial, the Pareto front highlighted."""
    from matplotlib.figure import Figure

    fig = Figure(figsize=(6.5, 4.5))
    ax = fig.subplots()
    scored = [t for t in scored_trials(trials) if is_feasible(t)] or scored_trials(trials)
    ax.scatter([t.values[0] for t in scored], [t.values[1] for t in scored], s=8, alpha=0.4,
               label="trials")  # fmt: skip
    front = sorted(pareto_front(scored), key=lambda t: t.values[0])
    ax.plot([t.values[0] for t in front], [t.values[1] for t in front], "o-", color="k",
            ms=4, label="Pareto front")  # fmt: skip
    ax.set_xscale("log")
    ax.set_xlabel(objectives[0])
    ax.set_ylabel(objectives[1])
    ax.grid(True, alpha=0.3)
    ax.legend(fontsize=8)
    fig.tight_layout()
    return fig


def param_set_files(
    params: Any,
    *,
    assumptions: Any = None,
    metrics: dict[str, Any] | None = None,
    notes: dict[str, Any] | None = None,
    hardware: bool = True,
) -> dict[str, str]:
    """The tuned set's files: ``best_params.json`` and every export the chip model takes
    (``hardware=False``: only the JSON parameter file, for a set that failed its check).

    Returns:
        File name -> text (each export ends with its checksummed end line).
    """
    family = family_of(params)
    files = {}
    for fmt, name in export_names(family, params.model).items():
        if not hardware and fmt != "json":
            continue
        kw: dict[str, Any] = {"assumptions": assumptions}
        if fmt == "json":
            kw.update(metrics=metrics, notes=notes)
        files[name] = family.export(params, fmt, **kw)
    return files


def write_param_set(
    params: Any,
    out: str | Path,
    *,
    assumptions: Any = None,
    metrics: dict[str, Any] | None = None,
    notes: dict[str, Any] | None = None,
    trial: int | None = None,
    extra_files: dict[str, str | bytes] | None = None,
    hardware: bool = True,
) -> dict[str, Any]:
    """Write a parameter set (JSON and every export) into ``out`` as one set with a manifest.

    The files, with ``extra_files`` (reports that belong to the set), go through
    :func:`servogym._files.write_file_set`: temporary files, a pending manifest, renames,
    then ``manifest.json`` (each file's SHA-256, the trial, the chip model). A reader
    (``servogym.chips.read_params_file``) refuses a file the manifest does not match.

    Returns:
        The manifest written.
    """
    files: dict[str, str | bytes] = dict(
        param_set_files(
            params, assumptions=assumptions, metrics=metrics, notes=notes, hardware=hardware
        )
    )
    files.update(extra_files or {})
    meta = {"trial": trial, "chip_model": params.model}
    return write_file_set(Path(out), files, meta)


def _png(fig: Any) -> bytes:
    buf = io.BytesIO()
    fig.savefig(buf, format="png", dpi=110)
    return buf.getvalue()


def study_fields(
    result: Any, problem: Any, config: Any, default_metrics: dict, tuned_metrics: dict,
    files: dict[str, str],
) -> dict[str, Any]:  # fmt: skip
    """The fields of summary.json a study gives, from ``tuner`` to ``files`` (in order),
    for one axis and for a machine (``_machinejob.write_outputs``)."""
    return {
        "tuner": result.tuner,
        "seed": problem.seed,
        "budget": getattr(config, "budget", len(result.trials)),
        "n_trials": _n_counted(result.trials),
        "kinds": _count_kinds(result.trials),
        "best_trial": result.best.number,
        "feasible": result.feasible,
        "objectives": list(problem.objectives),
        "best_values": list(result.best.values),
        "default": default_metrics,
        "tuned": tuned_metrics,
        "best_params": result.best_values,
        "problem": problem.describe(),
        "config": _jsonable(dataclasses.asdict(config)) if config is not None else None,
        "storage": result.storage,
        "study_name": result.study_name,
        "elapsed_s": result.elapsed_s,
        "files": files,
    }


def study_notes(
    result: Any, problem: Any, default_metrics: dict, tuned_metrics: dict,
    check: dict[str, Any] | None,
) -> dict[str, Any]:  # fmt: skip
    """The notes the written file set carries (its manifest), for one axis and for a
    machine; ``check``: the check's JSON-ready report, if any."""
    notes = {
        "tuner": result.tuner,
        "seed": problem.seed,
        "n_trials": _n_counted(result.trials),
        "best_trial": result.best.number,
        "feasible": result.feasible,
        "cost": tuned_metrics["cost"],
        "default_cost": default_metrics["cost"],
        "scenario": problem.describe(),
        "study": {"storage": result.storage, "name": result.study_name},
    }
    if check is not None:
        notes["check"] = check
    return notes


def write_outputs(
    result: Any,
    out: Path,
    config: Any,
    check: Any = None,
    extra: dict[str, Any] | None = None,
    extra_files: dict[str, str | bytes] | None = None,
) -> dict[str, Any]:
    """Write every output file of a tuned run as one set; return the summary.

    Everything is computed first; then :func:`write_param_set` writes the tuned set, its
    exports, ``trials.csv``, the plots and ``summary.json`` together with ``manifest.json``,
    so a run killed while writing leaves the previous set or this one, never a mix.

    ``check`` is the result's :class:`~servogym.sim.CheckReport` (``None``: not checked).
    When it failed, only the JSON parameter file is written, not the files a drive loads,
    unless ``config.force``. ``extra`` entries are added to the summary, ``extra_files``
    (name -> content, e.g. ``bode.png``) to the set.
    """
    from servogym.sim._plot import response_figure

    problem: TuneProblem = result.problem
    family, model = get_chip(problem.scenario.chip_model)
    mode = problem.robust_mode
    default_params = problem.scenario.default_params()
    d_evals, d_nominal = evaluate_on_problem(problem, default_params)
    t_evals, t_nominal = evaluate_on_problem(problem, result.best_params)
    default_metrics = evaluation_metrics(d_evals, mode)
    tuned_metrics = evaluation_metrics(t_evals, mode)

    notes = study_notes(result, problem, default_metrics, tuned_metrics,
                        None if check is None else _jsonable(check.to_dict()))  # fmt: skip
    withheld = check is not None and not check.passed and not getattr(config, "force", False)
    names = export_names(family, model)
    files: dict[str, str] = {f: n for f, n in names.items() if f == "json" or not withheld}
    reports: dict[str, str | bytes] = dict(extra_files or {})
    if "bode.png" in reports:
        files["bode_plot"] = "bode.png"
    reports["trials.csv"] = trials_csv_text(result.trials, problem.space.names)
    files["trials"] = "trials.csv"
    shown = plant_description(problem.describe())
    if problem.n_plants > 1:  # the traces are the nominal instance's
        shown = f"nominal instance; tuned {shown}"
    title = (
        f"{model} on {problem.scenario.plant} ({shown}): chip defaults vs "
        f"{result.tuner} (cost {default_metrics['cost']:.3g} -> {tuned_metrics['cost']:.3g})"
    )
    reports["response.png"] = _png(
        response_figure([("default", d_nominal), ("tuned", t_nominal)], title)
    )
    files["response_plot"] = "response.png"
    fig = convergence_figure(
        result.trials,
        default_metrics["cost"],
        f"{result.tuner} on {model} / {problem.scenario.plant}: {len(result.trials)} evaluations",
    )
    reports["convergence.png"] = _png(fig)
    files["convergence_plot"] = "convergence.png"
    if problem.multi_objective:
        reports["pareto.png"] = _png(pareto_figure(result.trials, problem.objectives))
        files["pareto_plot"] = "pareto.png"

    summary = {
        "servogym_version": __version__,
        "chip_model": model,
        "chip_family": family.name,
        "plant": problem.scenario.plant,
        **study_fields(result, problem, config, default_metrics, tuned_metrics, files),
        "check": None if check is None else check.to_dict(),
        "hardware_files_withheld": [f for f in names if f != "json"] if withheld else [],
        **(extra or {}),
    }
    if problem.multi_objective:
        scored = scored_trials(result.trials)
        front = pareto_front([t for t in scored if is_feasible(t)] or scored)
        summary["pareto_front"] = [
            {"trial": t.number, "values": list(t.values)}
            for t in sorted(front, key=lambda t: t.values[0])
        ]
    files["summary"] = "summary.json"
    reports["summary.json"] = json.dumps(_jsonable(summary), indent=2) + "\n"
    write_param_set(
        result.best_params,
        out,
        assumptions=problem.scenario.assumptions,
        metrics={"tuned": tuned_metrics, "default": default_metrics},
        notes=notes,
        trial=result.best.number,
        extra_files=reports,
        hardware=not withheld,
    )
    return summary


def _count_kinds(trials: list[Any]) -> dict[str, int]:
    out: dict[str, int] = {}
    for t in trials:
        kind = t.user_attrs.get("kind", "?")
        out[kind] = out.get(kind, 0) + 1
    return out


def _jsonable(obj: Any) -> Any:
    if isinstance(obj, dict):
        return {str(k): _jsonable(v) for k, v in obj.items()}
    if isinstance(obj, list | tuple):
        return [_jsonable(v) for v in obj]
    if isinstance(obj, Path):
        return str(obj)
    if isinstance(obj, np.generic):
        return obj.item()
    if isinstance(obj, float) and not math.isfinite(obj):
        return None
    return obj
