"""``servogym tune`` on a multi-axis machine: the design start, the check and the outputs.

:func:`servogym.autotune._job.tune` runs the study of a :class:`MachineProblem` as of any
problem and calls this module where a machine differs:

* :func:`design_start` turns the single-axis model-based rule
  (:func:`~servogym.autotune._classical.pole_placement_designs`) into designs of every axis:
  each axis's acceleration per command count comes from the plant's own model at its start
  configuration (joint-space inertia with the others held, actuator gear, amplifier and
  torque constant), the seven bandwidths are tried on every axis at once, and the best
  feasible design starts the study.
* :func:`check_machine` is the multi-axis check (``servogym.sim._multicheck``).
* :func:`write_outputs` writes the tuned sets in every format of the chip model, each file
  the chip's multi-axis form (:func:`servogym.chips.export_axes`: one C-Motion axis handle
  per axis, PMAC I-variables per motor, 6000-series comma-separated fields), with
  ``trials.csv``, ``convergence.png``, ``contour.png`` and ``summary.json``, as one file set
  with its manifest (``servogym._files.write_file_set``).
"""

from __future__ import annotations

import dataclasses
import json
from pathlib import Path
from typing import Any

from servogym.autotune._machine import MachineEvaluator, MachineProblem, axis_name
from servogym.autotune._session import TuneError
from servogym.chips._axes import MultiAxisParams

DESIGN_NOTE = "model-based design of every axis from the plant's model"


def axis_accel_gains(evaluator: MachineEvaluator) -> tuple[float, ...]:
    """Per axis, its acceleration per motor command count (counts/s^2) at the plant's start
    configuration, the other axes held: ``gear * amps_per_count * torque_constant / M_kk *
    counts_per_unit`` with ``M`` the joint-space inertia (armature included)."""
    import mujoco
    import numpy as np

    plant = evaluator.plant
    plant.reset()
    mujoco.mj_forward(plant.model, plant.data)
    m = np.zeros((plant.model.nv, plant.model.nv))
    mujoco.mj_fullM(plant.model, plant.data, m)
    out = []
    for io_ in plant.ios:
        gear = float(plant.model.actuator_gear[io_.ctrl_index][0])
        effort = gear * io_.amp_amps_per_count * io_.torque_constant_nm_per_a
        out.append(effort / float(m[io_.qvel_adr, io_.qvel_adr]) * io_.counts_per_unit)
    return tuple(out)


def design_candidates(problem: MachineProblem, evaluator: MachineEvaluator) -> list[tuple]:
    """``(values, note)`` of the model-based designs of every axis, fastest first."""
    from servogym.autotune._classical import N_BANDWIDTHS, pole_placement_designs
    from servogym.autotune._gains import gain_map_for

    space = problem.space
    base_values = space.base_values()
    base = space.make_params(base_values)
    family = space.family
    gain_map = gain_map_for(family)
    dt = family.sample_time_s(base.sets[0])
    per_axis = [pole_placement_designs(g, dt) for g in axis_accel_gains(evaluator)]
    out = []
    for k in range(N_BANDWIDTHS):
        values = dict(base_values)
        for axis, designs in enumerate(per_axis, start=1):
            design, _ = designs[k]
            regs = gain_map.registers(design, base[axis], problem.scenario.assumptions)
            for register, v in regs.items():
                name = axis_name(register, axis)
                if name in space.names:
                    values[name] = int(v)
        out.append((values, per_axis[0][k][1].replace("model-based", DESIGN_NOTE)))
    return out


def design_start(problem: MachineProblem, config: Any) -> dict[str, Any]:
    """The best model-based design of every axis (in memory, not in the budget).

    Only for the Optuna tuners (the safe tuner among them) and single-objective studies;
    returns ``{"values", "cost", "feasible", "evaluations", "note"}`` or ``{"skipped": why}``.
    """
    from servogym.autotune._tuners import OptunaTuner, get_tuner

    if not isinstance(get_tuner(config.tuner), OptunaTuner):
        return {"skipped": f"{config.tuner} is not an Optuna tuner"}
    if problem.multi_objective:
        return {"skipped": "multi-objective study"}
    evaluator = problem.make_evaluator()
    evaluator.plant.set_params(problem.nominal_plant())
    try:
        candidates = design_candidates(problem, evaluator)
    except (TuneError, ValueError) as exc:  # no gain map for the family
        return {"skipped": str(exc)}
    fe_limit = problem.following_error_limit(evaluator)
    plants = problem.plant_instances()
    best = None
    for values, note in candidates:
        params = problem.space.make_params(values)
        outcome = problem.aggregate(values, [evaluator.evaluate(params, p) for p in plants])
        feasible = all(v <= 0 for v in problem.constraint_values(outcome, fe_limit).values())
        key = (not feasible, outcome.cost)
        if best is None or key < best[0]:
            best = (key, values, outcome, note)
    (infeasible, cost), values, _, note = best
    return {"values": values, "cost": float(cost), "feasible": not infeasible,
            "evaluations": len(candidates) * len(plants), "note": note}  # fmt: skip


def check_machine(
    problem: MachineProblem,
    params: Any,
    limits: Any,
    *,
    extra_plants: Any = (),
    workers: Any = None,
) -> Any:
    """The multi-axis check of ``params`` on the problem's machine
    (``servogym.sim._multicheck.check_machine_params``: the stress set on the reference
    integration, every loop-latency and sequencing choice, each loop's margins with the
    others closed), on the nominal plant with the scenario's tasks, weights, assumptions,
    sequencing and contour mode, then on each of ``extra_plants`` (a robust run's draws).

    Returns:
        The nominal plant's report if every plant passes, else the first failing one, its
        failures prefixed with the plant instance.
    """
    from servogym.sim._multicheck import check_machine_params

    evaluator = problem.make_evaluator()
    evaluator.plant.set_params(problem.nominal_plant())
    first = check_machine_params(params, evaluator.multi, limits, workers=workers)
    if not first.passed:
        return first
    for i, values in enumerate(extra_plants):
        report = check_machine_params(params, evaluator.multi, limits, plant_values=values,
                                      workers=workers)  # fmt: skip
        if not report.passed:
            where = f"plant instance {i + 1} of {len(extra_plants)}"
            failures = tuple(f"{where}: {f}" for f in report.failures)
            return dataclasses.replace(report, failures=failures)
    return first


def read_warm_start(path: str | Path, problem: MachineProblem) -> dict[str, int]:
    """The values of a multi-axis parameter file (any format servogym writes) for the
    problem's machine (its chip model, its number of axes)."""
    from servogym.chips._axes import load_axes
    from servogym.chips._space import ParameterError

    model = problem.space.chip_model
    try:
        axes = load_axes(path, model=model)
    except (ParameterError, ValueError) as exc:
        raise TuneError(f"--warm-start: {exc}") from None
    if axes.model != model:
        raise TuneError(f"--warm-start {str(path)!r} is for chip {axes.model}, not {model}.")
    if len(axes) != problem.n_axes:
        raise TuneError(
            f"--warm-start {str(path)!r} holds {len(axes)} {axes.noun} set(s) "
            f"({', '.join(map(str, axes.numbers))}); the {problem.scenario.plant} needs "
            f"{problem.n_axes}."
        )
    return problem.space.register_values(axes)


def check_inputs(problem: MachineProblem, out: Path, inputs: list[str | Path]) -> None:
    """Refuse a run whose outputs would replace one of its input files (a warm start kept
    in the run folder as ``best_params.json``), before the study.

    Raises:
        servogym._files.FileSafetyError: naming the file.
    """
    from servogym._files import check_target

    names = [*output_names(problem).values(), "trials.csv", "convergence.png", "contour.png",
             "summary.json"]  # fmt: skip
    for name in names:
        check_target(Path(out) / name, inputs=inputs, force=True, what="--out")


def output_names(problem: MachineProblem) -> dict[str, str]:
    """File name of each format of the tuned sets (those of a single-axis tune)."""
    from servogym.autotune._report import export_names

    return export_names(problem.space.family, problem.space.chip_model)


def param_set_files(
    params: MultiAxisParams,
    names: dict[str, str],
    *,
    assumptions: Any = None,
    metrics: dict[str, Any] | None = None,
    notes: dict[str, Any] | None = None,
    hardware: bool = True,
) -> dict[str, str]:
    """The sets' files: ``best_params.json`` (``servogym-axes``) and, with ``hardware``,
    every other format of the chip model, each in its multi-axis form."""
    from servogym.chips._axes import export_axes

    files = {}
    for fmt, name in names.items():
        if fmt == "json":
            files[name] = export_axes(params, fmt, assumptions, metrics=metrics, notes=notes)
        elif hardware:
            files[name] = export_axes(params, fmt, assumptions)
    return files


def machine_metrics(evaluations: list[Any], mode: str) -> dict[str, Any]:
    """:func:`~servogym.autotune._report.evaluation_metrics` plus the contouring error and
    each axis's worst following error and saturation over the plant instances."""
    from servogym.autotune._report import evaluation_metrics

    n = len(evaluations[0].axis_following_error)
    out: dict[str, Any] = evaluation_metrics(evaluations, mode)
    out["max_contour_error_um"] = max(e.max_contour_error_um for e in evaluations)
    out["rms_contour_error_um"] = max(e.rms_contour_error_um for e in evaluations)
    out["axis_following_error"] = [max(e.axis_following_error[k] for e in evaluations)
                                   for k in range(n)]  # fmt: skip
    out["axis_saturation"] = [max(e.axis_saturation[k] for e in evaluations) for k in range(n)]
    return out


def contour_figure(runs: list[tuple[str, Any]], title: str, dt: float):
    """Each task's contouring error (distance of the tool point from the commanded path, um)
    against time from the start of its motion, one panel per task, one line per labelled
    run (a :class:`~servogym.sim._multieval.MultiEvaluation` with traces)."""
    import numpy as np
    from matplotlib.figure import Figure

    n_tasks = len(runs[0][1].tasks)
    fig = Figure(figsize=(4.0 * n_tasks, 3.6))
    axes = fig.subplots(1, n_tasks, squeeze=False, sharey=True)[0]
    for j, ax in enumerate(axes):
        for label, run in runs:
            if j >= len(run.tasks) or run.tasks[j].traces is None:
                continue
            task = run.tasks[j]
            cmd = task.commands
            first, end = cmd.motion
            end = min(end, int(task.metrics[0].n_ticks))
            actual = np.stack([tr.actual[first:end] for tr in task.traces]).astype(float)
            tool = cmd.kinematics.forward(cmd.joint_positions(actual))
            d = cmd.path.distance(tool) * 1e6
            ax.plot(np.arange(len(d)) * dt, d, lw=1.0,
                    label=f"{label} (max {task.contour.max_um:.3g} um)")  # fmt: skip
        ax.set_yscale("log")
        ax.set_ylim(bottom=1e-2)  # below, encoder quantization's chatter
        ax.set_xlabel("time from the motion's start (s)")
        ax.set_title(f"task {j + 1}: {type(runs[0][1].tasks[j].commands.path).__name__}",
                     fontsize=9)  # fmt: skip
        ax.grid(True, alpha=0.3, which="both")
        ax.legend(fontsize=7)
    axes[0].set_ylabel("contouring error (um)")
    fig.suptitle(title, fontsize=10)
    fig.tight_layout()
    return fig


def write_outputs(
    result: Any,
    out: Path,
    config: Any,
    check: Any = None,
    extra: dict[str, Any] | None = None,
) -> dict[str, Any]:
    """Write every output of a machine's tune as one file set; return the summary.

    As :func:`servogym.autotune._report.write_outputs`: when the check failed, only the JSON
    parameter file (with the failing report) and the reports are written, not the files a
    controller loads, unless ``config.force``.
    """
    from servogym import __version__
    from servogym._files import write_file_set
    from servogym.autotune._report import (
        _jsonable,
        _png,
        convergence_figure,
        study_fields,
        study_notes,
        trials_csv_text,
    )

    problem: MachineProblem = result.problem
    model = problem.space.chip_model
    family = problem.space.family
    mode = problem.robust_mode
    evaluator = problem.make_evaluator()
    default_params = problem.scenario.default_params()

    def on_problem(params: Any) -> tuple[list[Any], Any]:
        evals = [evaluator.evaluate(params, p) for p in problem.plant_instances()]
        nominal = evaluator.evaluate(params, problem.nominal_plant(), traces=True)
        return evals, nominal

    d_evals, d_nominal = on_problem(default_params)
    t_evals, t_nominal = on_problem(result.best_params)
    default_metrics = machine_metrics(d_evals, mode)
    tuned_metrics = machine_metrics(t_evals, mode)
    check_dict = None if check is None else _jsonable(_report_dict(check))
    notes = study_notes(result, problem, default_metrics, tuned_metrics, check_dict)
    withheld = check is not None and not check.passed and not getattr(config, "force", False)
    names = output_names(problem)
    files: dict[str, str] = {f: n for f, n in names.items() if f == "json" or not withheld}
    reports: dict[str, str | bytes] = {}
    reports["trials.csv"] = trials_csv_text(result.trials, problem.space.names)
    files["trials"] = "trials.csv"
    plant = problem.scenario.plant
    reports["convergence.png"] = _png(convergence_figure(
        result.trials, default_metrics["cost"],
        f"{result.tuner} on {model} / {plant}: {len(result.trials)} evaluations",
    ))  # fmt: skip
    files["convergence_plot"] = "convergence.png"
    reports["contour.png"] = _png(contour_figure(
        [("default", d_nominal.run), ("tuned", t_nominal.run)],
        f"{model} on {plant} (nominal plant): chip defaults vs {result.tuner} (cost "
        f"{default_metrics['cost']:.3g} -> {tuned_metrics['cost']:.3g})",
        evaluator.multi.loop.dt,
    ))  # fmt: skip
    files["contour_plot"] = "contour.png"
    summary = {
        "servogym_version": __version__,
        "chip_model": model,
        "chip_family": family.name,
        "plant": plant,
        "n_axes": problem.n_axes,
        "axes": list(problem.scenario.family.axes),
        "axis_numbers": list(result.best_params.numbers),
        "axis_noun": result.best_params.noun,
        **study_fields(result, problem, config, default_metrics, tuned_metrics, files),
        "check": check_dict,
        "hardware_files_withheld": [f for f in names if f != "json"] if withheld else [],
        **(extra or {}),
    }
    files["summary"] = "summary.json"
    reports["summary.json"] = json.dumps(_jsonable(summary), indent=2) + "\n"
    sets = param_set_files(
        result.best_params, names, assumptions=problem.scenario.assumptions,
        metrics=_jsonable({"tuned": tuned_metrics, "default": default_metrics}),
        notes=_jsonable(notes), hardware=not withheld,
    )  # fmt: skip
    meta = {"trial": result.best.number, "chip_model": model, "n_axes": problem.n_axes}
    write_file_set(Path(out), {**sets, **reports}, meta)
    return summary


def _report_dict(report: Any) -> dict[str, Any]:
    """A check report as JSON-ready data (its ``to_dict`` when it has one)."""
    if hasattr(report, "to_dict"):
        return report.to_dict()
    return {"passed": bool(report.passed), "failures": list(getattr(report, "failures", ()))}


__all__ = [
    "axis_accel_gains",
    "check_machine",
    "design_candidates",
    "design_start",
    "read_warm_start",
    "write_outputs",
]
