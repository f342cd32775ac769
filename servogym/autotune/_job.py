"""The main job: run a study, then write the tuned set, its exports and the reports."""

from __future__ import annotations

import dataclasses
import io
import os
import time
from collections.abc import Callable, Mapping
from pathlib import Path
from typing import Any

from servogym.autotune._problem import Constraints, TuneProblem
from servogym.autotune._session import (
    ProgressCallback,
    Session,
    TuneError,
    best_trial,
    default_storage_url,
    is_feasible,
    quiet_optuna,
    scored_trials,
)
from servogym.autotune._space import SearchSpace
from servogym.autotune._tuners import DEFAULT_TUNER, OptunaTuner, get_tuner
from servogym.chips._family import get_chip
from servogym.sim._check import CheckLimits, CheckReport, write_bode
from servogym.sim._scenario import MoveSpec, Scenario


@dataclasses.dataclass(frozen=True)
class StudyResult:
    """What a study produced.

    Attributes:
        problem: The problem tuned.
        tuner: Tuner name.
        trials: Every trial of the study (Optuna ``FrozenTrial``), in order.
        best: The best trial (see :func:`servogym.autotune.best_trial`).
        feasible: Whether the best trial meets the constraints.
        best_values: Its register values (chip units, every register).
        best_params: Its parameter set.
        storage: Storage URL of the study.
        study_name: Name of the study in the storage.
        elapsed_s: Wall time of this run (s).
    """

    problem: TuneProblem
    tuner: str
    trials: list[Any]
    best: Any
    feasible: bool
    best_values: dict[str, int]
    best_params: Any
    storage: str | None
    study_name: str
    elapsed_s: float


def run_study(
    problem: TuneProblem,
    tuner: str,
    budget: int,
    *,
    storage: str | None,
    study_name: str = "servogym",
    resume: bool = False,
    n_workers: int | None = None,
    batch_size: int | None = None,
    warm_start: Mapping[str, int] | None = None,
    progress: ProgressCallback | None = None,
    evaluator_factory: Callable[[Any], Any] | None = None,
    load_if_exists: bool = False,
) -> StudyResult:
    """Tune ``problem`` with a registered tuner and return the best set.

    Args:
        problem: What to tune.
        tuner: A name of :func:`servogym.autotune.tuner_names`.
        budget: Evaluations the study holds in the end (see docs/autotune.md).
        storage: Journal file path or Optuna RDB URL (``sqlite:///path/study.db``,
            ``postgresql://...``); ``None``: in memory only.
        study_name: Study name in that storage.
        resume: Continue an existing study of that name.
        load_if_exists: Join the study of that name if it exists (another worker's), else
            create it; the budget is the study's, shared by every worker.
        n_workers: Evaluation threads; default every core.
        batch_size: Trials per sampler batch (default 8; a resume keeps the stored one).
        warm_start: Register values evaluated first (a new study only).
        progress: Called after every trial with (done, budget, best cost).
        evaluator_factory: One evaluator per thread, from the scenario (default the
            problem's own; tests pass a cheaper one).
    """
    t0 = time.perf_counter()
    tuner_obj = get_tuner(tuner)
    tuner_obj.check(problem, budget)
    workers = n_workers if n_workers is not None else (os.cpu_count() or 1)
    with quiet_optuna():
        session = Session(
            problem,
            budget=budget,
            storage=storage,
            study_name=study_name,
            tuner_name=tuner,
            resume=resume,
            n_workers=workers,
            batch_size=batch_size,
            warm_start=warm_start,
            progress=progress,
            evaluator_factory=evaluator_factory,
            load_if_exists=load_if_exists,
            shared=isinstance(tuner_obj, OptunaTuner),
        )
        with session:
            # Not ``remaining``: a queued warm start (or a re-queued trial) already counts
            # toward the budget but still has to be evaluated.
            if session.n_done < session.budget:
                tuner_obj.run(session)
        trials = session.trials()
    best, feasible = best_trial(trials, problem.multi_objective)
    values = {k: int(v) for k, v in best.user_attrs["registers"].items()}
    return StudyResult(
        problem=problem,
        tuner=tuner,
        trials=list(trials),
        best=best,
        feasible=feasible,
        best_values=values,
        best_params=problem.space.make_params(values),
        storage=storage,
        study_name=study_name,
        elapsed_s=time.perf_counter() - t0,
    )


def parse_assignments(items: list[str] | None, what: str) -> dict[str, str]:
    """``["k=v", ...]`` -> ``{"k": "v"}``, with a clear error for a malformed item."""
    out: dict[str, str] = {}
    for item in items or []:
        key, sep, value = item.partition("=")
        if not sep or not key.strip() or not value.strip():
            raise TuneError(f"{what} takes NAME=VALUE (e.g. {what} bias=0); got {item!r}.")
        if key.strip() in out:
            raise TuneError(
                f"{what} names {key.strip()} twice ({key.strip()}={out[key.strip()]} and "
                f"{item.strip()}); give each name once."
            )
        out[key.strip()] = value.strip()
    return out


def _number(text: str, name: str, what: str) -> int | float:
    try:
        return int(text)
    except ValueError:
        pass
    try:
        return float(text)
    except ValueError:
        raise TuneError(f"{what} {name}= needs a number; got {name}={text!r}.") from None


def read_param_file(path: str | Path, chip_model: str) -> dict[str, int]:
    """Register values of a parameter file written for ``chip_model``, in any format
    servogym writes (:func:`servogym.chips.read_params_file` detects it)."""
    from servogym.chips import read_params_file

    family, model = get_chip(chip_model)
    try:
        params = read_params_file(path, model=model, what="--warm-start").params
    except ValueError as exc:
        raise TuneError(str(exc)) from None
    if params.model != model:
        raise TuneError(
            f"the warm-start file {str(path)!r} is for chip {params.model}, not {model}."
        )
    space = family.parameter_space(model)
    return {name: int(getattr(params, name)) for name in space}


@dataclasses.dataclass(frozen=True)
class TuneConfig:
    """Everything ``servogym tune`` is told (see :func:`tune`).

    Attributes:
        chip: Chip model.
        plant: Plant family.
        out: Run folder.
        budget: Evaluations.
        tuner: Tuner name (default :data:`~servogym.autotune._tuners.DEFAULT_TUNER`,
            ``"safe"``; it is single objective: a multi-objective study names another).
        plant_params: Fixed plant parameters (``{"payload_kg": 3.0}``).
        plant_ranges: Ranges the robust draws take parameters from
            (``{"payload_kg": (0.5, 2.0)}``; ``Scenario.plant_ranges``).
        seed: Seed of the study and the plant draws.
        workers: Evaluation threads (default every core).
        robust: K plant instances per evaluation (1: the nominal plant).
        robust_mode: ``"mean"`` or ``"worst"`` over the K.
        constraints: Report constraints to Optuna.
        max_following_error: Constraint limit (counts; ``None``: 1 % of the longest move).
        max_saturation: Constraint limit (fraction of ticks at the motor limit).
        multi_objective: Minimize cost and peak following error (a Pareto front).
        warm_start: A parameter file to evaluate first.
        storage: Journal file or Optuna RDB URL (default ``OUT/study.journal``).
        resume: Continue the run folder's study.
        fix: Registers held at a value.
        search: Registers to search (default every tunable one).
        moves: Evaluation moves (default the plant's).
        batch_size: Trials per sampler batch.
        study_name: Study name (default ``servogym-<folder name>``); when given, the run
            joins the study of that name if it exists (several workers, one study).
        min_gain_margin_db: Margin constraint during tuning and minimum of the check (dB).
        min_phase_margin_deg: The same for the phase margin (degrees).
        check: Check the result before writing it (``servogym.sim.check_params``).
        check_candidates: How many trials the check may try, until one passes: the best
            trial first, then the next feasible ones by cost. A set other than the best
            that passes is written with the gap stated (``check.fallback`` in the summary).
        force: Write the hardware files even when the check fails.
        design_start: For an Optuna tuner on a new study without ``warm_start``: first run
            the model-based tuner (:data:`DESIGN_BUDGET` simulations, not counted in
            ``budget``) and start the study from its best design (the ``safe`` tuner
            too; without a warm start, as in :func:`run_study`, it runs a design inside
            its budget).
    """

    chip: str
    plant: str
    out: Path
    budget: int
    tuner: str = DEFAULT_TUNER
    plant_params: Mapping[str, float] = dataclasses.field(default_factory=dict)
    plant_ranges: Mapping[str, tuple[float, float]] = dataclasses.field(default_factory=dict)
    seed: int = 0
    workers: int | None = None
    robust: int = 1
    robust_mode: str = "mean"
    constraints: bool = True
    max_following_error: float | None = None
    max_saturation: float = 0.05
    multi_objective: bool = False
    warm_start: Path | None = None
    storage: str | None = None
    resume: bool = False
    fix: Mapping[str, int] = dataclasses.field(default_factory=dict)
    search: tuple[str, ...] | None = None
    moves: tuple[MoveSpec, ...] = ()
    batch_size: int | None = None
    study_name: str | None = None
    min_gain_margin_db: float = 6.0
    min_phase_margin_deg: float = 30.0
    check: bool = True
    check_candidates: int = 5
    force: bool = False
    design_start: bool = True

    def __post_init__(self) -> None:
        n = self.check_candidates
        if isinstance(n, bool) or not isinstance(n, int) or n < 1:
            raise TuneError(
                f"check_candidates must be an integer >= 1; got check_candidates={n!r}."
            )

    def check_limits(self) -> CheckLimits:
        """The minima of the check."""
        return CheckLimits(
            min_gain_margin_db=self.min_gain_margin_db,
            min_phase_margin_deg=self.min_phase_margin_deg,
            max_following_error=self.max_following_error,
            max_saturation=self.max_saturation,
        )

    def problem(self) -> TuneProblem:
        """The :class:`TuneProblem` this configuration describes (a
        :class:`~servogym.autotune._machine.MachineProblem` for a multi-axis plant)."""
        from servogym.autotune._problem import DEFAULT_MULTI_OBJECTIVES
        from servogym.plants import MULTI_PLANTS

        if self.plant in MULTI_PLANTS:
            return self.machine_problem()
        constraints = Constraints(
            enabled=self.constraints,
            max_following_error=self.max_following_error,
            max_saturation=self.max_saturation,
            min_gain_margin_db=self.min_gain_margin_db,
            min_phase_margin_deg=self.min_phase_margin_deg,
        )
        scenario = Scenario(
            self.chip,
            self.plant,
            plant_values=dict(self.plant_params),
            plant_ranges=dict(self.plant_ranges),
            moves=self.moves,
            margins=constraints.margins,
        )
        return TuneProblem(
            scenario=scenario,
            space=SearchSpace.for_chip(scenario.chip_model, self.search, self.fix),
            n_plants=self.robust,
            robust_mode=self.robust_mode,
            constraints=constraints,
            objectives=DEFAULT_MULTI_OBJECTIVES if self.multi_objective else ("cost",),
            seed=self.seed,
        )

    def machine_problem(self) -> Any:
        """The :class:`~servogym.autotune._machine.MachineProblem` of a multi-axis plant:
        every axis's registers searched together (``--search``/``--fix`` names ``kp.2`` for
        one axis, ``kp`` for every axis), the constraints per axis (margins at the
        scenario's own timing; the check tries every latency and sequencing choice)."""
        from servogym.autotune._machine import MachineProblem, MachineScenario, MachineSpace
        from servogym.autotune._problem import DEFAULT_MULTI_OBJECTIVES

        if self.moves:
            raise TuneError(
                f"moves are a single-axis plant's; the {self.plant} is evaluated on its "
                "coordinated moves and contours (servogym.sim._multieval.DEFAULT_TASKS)."
            )
        scenario = MachineScenario(
            self.chip, self.plant, plant_values=dict(self.plant_params),
            plant_ranges=dict(self.plant_ranges),
        )  # fmt: skip
        return MachineProblem(
            scenario=scenario,
            space=MachineSpace.for_machine(
                scenario.chip_model, scenario.n_axes, self.search, self.fix
            ),
            n_plants=self.robust,
            robust_mode=self.robust_mode,
            constraints=Constraints(
                enabled=self.constraints,
                max_following_error=self.max_following_error,
                max_saturation=self.max_saturation,
                min_gain_margin_db=self.min_gain_margin_db,
                min_phase_margin_deg=self.min_phase_margin_deg,
            ),
            objectives=DEFAULT_MULTI_OBJECTIVES if self.multi_objective else ("cost",),
            seed=self.seed,
        )


def tune(
    config: TuneConfig, progress: ProgressCallback | None = None
) -> tuple[StudyResult, dict[str, Any]]:
    """Run ``servogym tune``: the study, then every output file in ``config.out``.

    Returns:
        The study result and the summary written to ``summary.json``.
    """
    from servogym.autotune import _machinejob
    from servogym.autotune._report import write_outputs

    problem = config.problem()
    machine = problem.n_axes > 1
    out = Path(config.out)
    out.mkdir(parents=True, exist_ok=True)
    storage = config.storage or default_storage_url(out)
    warm = None
    if machine and config.warm_start is not None:
        _machinejob.check_inputs(problem, out, [config.warm_start])
    if config.warm_start is not None:
        warm = (
            _machinejob.read_warm_start(config.warm_start, problem)
            if machine
            else read_param_file(config.warm_start, problem.scenario.chip_model)
        )
    design = None
    if warm is None and config.design_start and not config.resume:
        design = (_machinejob.design_start if machine else design_start)(problem, config)
        warm = design.get("values")
    result = run_study(
        problem,
        config.tuner,
        config.budget,
        storage=storage,
        study_name=config.study_name or f"servogym-{out.resolve().name}",
        resume=config.resume,
        n_workers=config.workers,
        batch_size=config.batch_size,
        warm_start=warm,
        progress=progress,
        load_if_exists=config.study_name is not None,
    )
    report = None
    files: dict[str, bytes] = {}
    extra = {} if design is None else {"design_start": design}
    if machine:
        if config.check:
            result, report = check_candidates(result, config)
        summary = _machinejob.write_outputs(result, out, config, check=report, extra=extra)
        return result, summary
    if config.check:
        result, report = check_candidates(result, config)
        buf = io.BytesIO()
        write_bode(buf, problem.scenario, result.best_params, report.limits)
        files["bode.png"] = buf.getvalue()
    summary = write_outputs(result, out, config, check=report, extra=extra, extra_files=files)
    return result, summary


DESIGN_BUDGET = 9
"""Simulations of the model-based design a default tune starts from (2 identification
moves and 7 candidate bandwidths)."""


def design_start(problem: TuneProblem, config: TuneConfig) -> dict[str, Any]:
    """The model-based tuner's best design on ``problem`` (in memory), as a warm start.

    Only for the Optuna tuners (the classical ones are procedures of their own) and
    single-objective studies; returns ``{"values": ..., "cost": ..., "feasible": ...}``, or
    ``{"skipped": why}``.
    """
    from servogym.autotune._tuners import OptunaTuner

    if not isinstance(get_tuner(config.tuner), OptunaTuner):
        return {"skipped": f"{config.tuner} is not an Optuna tuner"}
    if problem.multi_objective:
        return {"skipped": "multi-objective study"}
    try:
        res = run_study(problem, "model-based", DESIGN_BUDGET, storage=None,
                        n_workers=config.workers)  # fmt: skip
    except TuneError as exc:
        return {"skipped": str(exc)}
    return {
        "values": res.best_values,
        "cost": float(res.best.values[0]),
        "feasible": bool(res.feasible),
        "evaluations": len(res.trials),
    }


def check_candidates(result: StudyResult, config: TuneConfig) -> tuple[StudyResult, CheckReport]:
    """Check the best trial, then the next feasible trials by cost, until one passes.

    Each is checked on the reference integration, every loop latency, the load and friction
    spreads and, for a robust run, its plant draws, against every limit of the run
    (``servogym.sim.check_params``). At most ``config.check_candidates`` trials are checked.

    Returns the first that passes; when it is not the best trial, the report's
    ``fallback`` says what failed and how much worse the written set is. When none passes,
    the best trial with its failing report (``tune`` then withholds the hardware files and
    exits 1, unless ``force``).
    """
    problem = result.problem
    extra = problem.plant_instances() if problem.n_plants > 1 else ()
    limits = config.check_limits()
    candidates = [result.best]
    if not problem.multi_objective:
        # Only trials that met every constraint during tuning, cheapest first: a trial
        # that missed one on the nominal plant cannot pass the stricter check.
        ranked = sorted(
            (
                t
                for t in scored_trials(result.trials)
                if t.number != result.best.number and is_feasible(t)
            ),
            key=lambda t: t.values[0],
        )
        candidates += ranked[: config.check_candidates - 1]
    first = None
    chosen = None
    checked = []
    for trial in candidates:
        values = {k: int(v) for k, v in trial.user_attrs["registers"].items()}
        params = problem.space.make_params(values)
        report = problem.check(params, limits, extra_plants=extra, workers=config.workers)
        checked.append({"trial": trial.number, "cost": float(trial.values[0]),
                        "passed": report.passed, "failures": list(report.failures)})  # fmt: skip
        if first is None:
            first = (trial, values, params, report)
        if report.passed:
            chosen = (trial, values, params, report)
            break
    trial, values, params, report = chosen or first
    fallback = None
    if chosen is not None and trial.number != first[0].number:
        best_cost, cost = float(first[0].values[0]), float(trial.values[0])
        fallback = {
            "best_trial": first[0].number,
            "best_cost": best_cost,
            "best_failures": list(first[3].failures),
            "written_trial": trial.number,
            "written_cost": cost,
            "cost_ratio": cost / best_cost if best_cost > 0 else None,
        }
    if isinstance(report, CheckReport):
        report = dataclasses.replace(report, candidates=tuple(checked), fallback=fallback)
    else:  # a machine's report (servogym.sim.MachineCheckReport)
        report = CheckedChoice(report, tuple(checked), fallback)
    chosen_result = dataclasses.replace(
        result, best=trial, best_values=values, best_params=params,
        feasible=is_feasible(trial),
    )  # fmt: skip
    return chosen_result, report


@dataclasses.dataclass(frozen=True)
class CheckedChoice:
    """A check report that has no place for the tune's choice (a machine's,
    ``servogym.sim.MachineCheckReport``), with that choice beside it.

    Attributes:
        report: The chosen set's report.
        candidates: Each trial checked, its cost, whether it passed and why not.
        fallback: As :attr:`servogym.sim.CheckReport.fallback`.
    """

    report: Any
    candidates: tuple[dict[str, Any], ...] = ()
    fallback: dict[str, Any] | None = None

    @property
    def passed(self) -> bool:
        """Whether the chosen set passed."""
        return bool(self.report.passed)

    @property
    def failures(self) -> tuple[str, ...]:
        """The chosen set's failures."""
        return tuple(self.report.failures)

    def to_dict(self) -> dict[str, Any]:
        """The report's JSON with ``candidates`` and ``fallback``."""
        return {**self.report.to_dict(), "candidates": list(self.candidates),
                "fallback": self.fallback}  # fmt: skip


def parse_plant_params(items: list[str] | None) -> dict[str, int | float]:
    """``--plant-param k=v`` items as numbers."""
    return {
        k: _number(v, k, "--plant-param")
        for k, v in parse_assignments(items, "--plant-param").items()
    }


def parse_fix(items: list[str] | None) -> dict[str, int]:
    """``--fix k=v`` items as integers (chip registers hold integers)."""
    out = {}
    for k, v in parse_assignments(items, "--fix").items():
        try:
            out[k] = int(v)
        except ValueError:
            raise TuneError(
                f"--fix {k}= needs an integer (a chip register); got {k}={v!r}."
            ) from None
    return out
