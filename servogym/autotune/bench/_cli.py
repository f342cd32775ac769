"""``servogym benchmark``: register with ``app.command("benchmark")(benchmark_command)``.

Imports nothing heavy at module level (Optuna, MuJoCo and numba load when the command runs).
"""

from __future__ import annotations

import json
import time
from pathlib import Path
from typing import Annotated

import typer

DEFAULT_TUNERS = "safe,tpe,gp,cmaes,random,sobol,vendor-step,relay,model-based"


MAX_BUDGET = 10_000
"""Largest benchmark budget (evaluations per job)."""


def _ints(text: str, option: str, high: int = MAX_BUDGET) -> list[int]:
    try:
        out = [int(x) for x in text.split(",") if x.strip()]
    except ValueError:
        out = []
    if not out or any(b < 1 or b > high for b in out):
        raise typer.BadParameter(
            f"{option} takes integers 1 <= {option} <= {high}, comma separated; got {text!r}"
        )
    if len(set(out)) != len(out):
        raise typer.BadParameter(f"{option} names a budget twice; got {text!r}")
    return sorted(out)


def benchmark_command(
    out: Annotated[
        Path | None,
        typer.Option("--out", help="Output folder (job results, report); required to run."),
    ] = None,
    suite: Annotated[
        str, typer.Option("--suite", help="Suite name: servobench-v1 or servobench-v0.")
    ] = "servobench-v1",
    list_ids: Annotated[
        bool,
        typer.Option(
            "--list", help="Print the split's instance ids (chip, plant, load, task) and stop."
        ),
    ] = False,
    split: Annotated[
        str, typer.Option("--split", help="Instances: train, heldout or all.")
    ] = "train",
    tuners: Annotated[
        str, typer.Option("--tuners", help="Comma-separated tuner names.")
    ] = DEFAULT_TUNERS,
    budget: Annotated[
        str, typer.Option("--budget", help="Budget(s), comma separated, e.g. 20,50,100.")
    ] = "50",
    seeds: Annotated[int, typer.Option("--seeds", help="Seeds 0..N-1 per tuner.")] = 5,
    workers: Annotated[int, typer.Option("--workers", help="Processes.")] = 1,
    scheduler: Annotated[
        str | None,
        typer.Option(
            "--scheduler",
            help="Run the jobs on an existing Dask cluster: the address `dask scheduler` "
            "prints, e.g. tcp://10.0.0.5:8786 (every worker needs servogym; "
            "docs/benchmark.md). Without it: --workers local processes.",
        ),
    ] = None,
    limit: Annotated[
        list[str] | None,
        typer.Option(
            "--limit",
            help="Reduced plan for a tuner: TUNER:seeds=N,budget=B,instances=K (repeatable), "
            "e.g. gp:seeds=1,budget=50,instances=8.",
        ),
    ] = None,
    instance: Annotated[
        list[str] | None,
        typer.Option("--instance", help="Run only these instance ids (repeatable)."),
    ] = None,
    dry_run: Annotated[
        bool, typer.Option("--dry-run", help="Print the plan and the time estimate only.")
    ] = False,
    reference: Annotated[
        bool,
        typer.Option(
            "--reference",
            help="Run the reference search instead (best-known costs) and write the data "
            "file to OUT/<suite>.json.",
        ),
    ] = False,
    seed_from: Annotated[
        Path | None,
        typer.Option(
            "--seed-from",
            help="With --reference: instead of the first stage, refine the data file OUT/"
            "<suite>.json from the best safe sets of the benchmark runs in this folder.",
        ),
    ] = None,
    as_json: Annotated[
        bool,
        typer.Option("--json", help="Print the report's summary as JSON (messages go to stderr)."),
    ] = False,
) -> None:
    """Benchmark autotuners on a versioned suite (resumable: finished jobs are skipped)."""
    from rich.console import Console
    from rich.progress import BarColumn, MofNCompleteColumn, Progress, TextColumn, TimeElapsedColumn

    from servogym._cli_common import check_choice, check_count, check_writable_folder, fail
    from servogym.autotune.bench._reference import (
        load_best_known,
        refine_from_runs,
        run_reference,
        superseded_note,
    )
    from servogym.autotune.bench._report import write_report
    from servogym.autotune.bench._runner import (
        ClusterError,
        Job,
        TunerLimit,
        check_scheduler_address,
        check_workers,
        connect,
        estimate_seconds,
        load_job,
        load_results,
        pack_results,
        plan_jobs,
        run_jobs,
    )
    from servogym.autotune.bench._suite import get_suite

    console = Console(stderr=as_json)
    check_count("--seeds", seeds, high=1000)
    check_count("--workers", workers, high=1024)
    if scheduler is not None:
        try:
            check_scheduler_address(scheduler)
        except ValueError as exc:
            fail(exc)
        if reference:
            fail(
                "--scheduler applies to benchmark jobs, not to --reference (the reference "
                f"search runs in --workers local processes); drop --scheduler {scheduler}."
            )
        if workers != 1:
            fail(
                f"--workers {workers} applies to the local process pool; with --scheduler the "
                "cluster's workers run the jobs (dask worker --nworkers N); drop --workers."
            )
    tuner_list = [t.strip() for t in tuners.split(",")]
    if not [t for t in tuner_list if t]:
        fail(f"--tuners must name at least one tuner; got --tuners {tuners!r}.")
    if "" in tuner_list:
        fail(f"--tuners takes tuner names separated by single commas; got --tuners {tuners!r}.")
    twice = sorted({t for t in tuner_list if tuner_list.count(t) > 1})
    if twice:
        fail(f"--tuners names {', '.join(twice)} twice; got --tuners {tuners!r}.")
    if out is not None and out.exists() and not out.is_dir():
        fail(f"--out {str(out)!r} is a file; give a folder for the benchmark.")
    from servogym.autotune._tuners import get_tuner

    check_choice("--suite", suite, get_suite)
    s = get_suite(suite)
    if list_ids:
        check_choice("--split", split, lambda v: s.ids(v))
        for i in s.ids(split):
            spec = s.spec(i)
            fixed = " ".join(f"{k}={v}" for k, v in spec.fixed.items())
            typer.echo(f"{i}\t{spec.split}\t{spec.plant_values}\t{fixed}".rstrip())
        return
    if out is None:
        fail("--out is required: the folder for the job results and the report.")
        return
    if split not in ("train", "heldout", "all"):
        fail(f"--split must be one of train, heldout, all; got --split {split!r}.")
    ids = s.ids(split)
    for t in tuner_list:
        check_choice("--tuners", t, get_tuner)
    if instance:
        for i in instance:
            try:
                spec = s.spec(i)  # raises with close matches
            except (KeyError, ValueError) as exc:
                fail(f"--instance: {exc.args[0] if isinstance(exc, KeyError) else exc}")
            if i not in ids:
                fail(
                    f"--instance {i!r} is in the {spec.split} split, not in --split {split}; "
                    f"pass --split {spec.split} or --split all."
                )
            if instance.count(i) > 1:
                fail(f"--instance names {i!r} twice.")
        ids = [i for i in ids if i in set(instance)]
    if seed_from is not None:
        if not reference:
            fail(f"--seed-from {str(seed_from)!r} applies only with --reference.")
        if not seed_from.is_dir():
            what = "does not exist" if not seed_from.exists() else "is not a folder"
            fail(f"--seed-from {str(seed_from)!r} {what}; give a benchmark's --out folder.")
    if reference:
        bad = [o for o, v in (("--tuners", tuners != DEFAULT_TUNERS), ("--budget", budget != "50"),
               ("--seeds", seeds != 5), ("--limit", bool(limit))) if v]  # fmt: skip
        if bad:
            fail(
                f"{bad[0]} does not apply to --reference (the reference search runs its own "
                f"plan); drop {', '.join(bad)}."
            )
    if not reference:
        budgets = _ints(budget, "--budget")
        names = set(tuner_list)
        try:
            limits = dict(TunerLimit.parse(x) for x in limit or [])
        except ValueError as exc:
            raise typer.BadParameter(str(exc)) from None
        for x in limit or []:
            name = x.partition(":")[0].strip()
            if name not in names:
                fail(f"--limit {x!r} names {name!r}, which is not in --tuners {tuners!r}.")
            if sum(y.partition(":")[0].strip() == name for y in limit or []) > 1:
                fail(f"--limit names {name!r} twice; got --limit {x!r}.")
    recs: list = []
    if reference and seed_from is not None and not (out / f"{suite}.json").is_file():
        fail(
            f"--seed-from refines the reference search in --out {str(out)!r}, which holds no "
            f"{suite}.json; run `servogym benchmark --reference --out {out}` first."
        )
    if reference and seed_from is not None:
        try:
            recs = [r for r in load_results(seed_from) if r["instance"] in set(ids)]
        except ValueError as exc:
            fail(f"--seed-from {str(seed_from)!r}: {exc}")
        if not recs:
            fail(
                f"--seed-from {str(seed_from)!r} holds no finished benchmark job of the "
                f"{len(ids)} instance(s) asked (runs.jsonl or jobs/); give a benchmark's --out."
            )
    cluster_threads = 0
    if scheduler is not None:  # refused before anything is written: a scheduler that is
        try:  # not there, a worker that cannot run servogym's jobs
            client = connect(scheduler)
            try:
                cluster_threads = sum(check_workers(client).values())
            finally:
                client.close()
        except ClusterError as exc:
            fail(exc)
    check_writable_folder("--out", out)
    if reference and seed_from is not None:
        t0 = time.perf_counter()
        path = out / f"{suite}.json"
        if dry_run:
            console.print(f"stage 2 would refine {len(ids)} instances from {len(recs)} runs "
                          f"-> {path} (dry run: nothing started)")  # fmt: skip
            return
        try:
            doc = refine_from_runs(suite, recs, path, workers=workers, run_label=str(seed_from))
        except ValueError as exc:
            fail(f"--out {str(out)!r}: {exc}")
        st2 = doc["method"]["stage2"]
        n_ref, n_imp = len(st2["instances_refined"]), len(st2["instances_improved"])
        dt = time.perf_counter() - t0
        console.print(f"stage 2: refined {n_ref} instances, improved {n_imp}; {dt:.0f} s")
        return
    if reference:
        t0 = time.perf_counter()
        path = out / f"{suite}.json"
        console.print(f"reference search on {len(ids)} instances -> {path}")
        if dry_run:
            console.print("dry run: the search is not started")
            return
        with Progress(TextColumn("{task.description}"), BarColumn(), MofNCompleteColumn(),
                      TimeElapsedColumn(), console=console) as bar:  # fmt: skip
            task = bar.add_task("reference", total=len(ids))

            def done(i: str, rec: dict) -> None:
                bar.console.print(f"{i}: {rec['cost']:.4g} (feasible {rec['feasible']}, "
                                  f"{rec['found_by']}, {rec['wall_s']:.0f} s)")  # fmt: skip
                bar.advance(task)

            try:
                run_reference(suite, path, split=split, workers=workers, on_done=done)
            except ValueError as exc:
                fail(f"--out {str(out)!r}: {exc}")
        console.print(f"done in {time.perf_counter() - t0:.0f} s")
        return
    instances = [s.instance(i) for i in ids]
    from servogym.autotune._session import TuneError

    try:
        jobs, skipped = plan_jobs(instances, tuner_list, budgets, list(range(seeds)), limits)
    except TuneError as exc:
        raise typer.BadParameter(str(exc)) from None
    # Measure one evaluation of each instance for the estimate.
    # CPU time (not wall time: the machine may be busy), the median of three after a warm-up.
    # (Through the evaluator: the instance keeps its last evaluation.)
    eval_s = {}
    for inst in instances:
        params = inst.problem.space.make_params(inst.values_from_unit(
            dict.fromkeys(inst.search_space, 0.0)))  # fmt: skip
        inst.evaluator.evaluate(params)
        samples = []
        for _ in range(3):
            t = time.process_time()
            inst.evaluator.evaluate(params)
            samples.append(time.process_time() - t)
        eval_s[inst.id] = sorted(samples)[1]
    try:
        todo = [j for j in jobs if load_job(out, j) is None]
    except ValueError as exc:
        fail(f"--out {str(out)!r}: {exc}")
    est = estimate_seconds(todo, eval_s)
    config = {
        "suite": suite, "split": split, "tuners": tuner_list, "budgets": budgets,
        "seeds": seeds, "workers": workers, "limits": {k: vars(v) for k, v in limits.items()},
        "instances": ids, "n_jobs": len(jobs), "scheduler": scheduler,
    }  # fmt: skip
    if not dry_run:  # a dry run leaves the folder's record of the last real run alone
        (out / "config.json").write_text(json.dumps(config, indent=1) + "\n")
    n_procs, where = workers, f"{workers} process(es)"
    if scheduler is not None:
        n_procs = cluster_threads
        where = f"the {cluster_threads} worker thread(s) the Dask cluster at {scheduler} has now"
    console.print(
        f"{len(jobs)} jobs, {len(todo)} to run ({len(ids)} instances, tuners "
        f"{', '.join(tuner_list)}, budgets "
        f"{budgets}, {seeds} seeds); {len(skipped)} (tuner, instance) pairs n/a. Estimate: "
        f"{est:.0f} CPU-s, about {est / max(n_procs, 1) / 60:.1f} min on {where} "
        f"(mean evaluation {1000 * sum(eval_s.values()) / len(eval_s):.1f} ms of CPU, median of "
        f"3 per instance)."
    )
    if dry_run:
        return
    t0 = time.perf_counter()
    with Progress(TextColumn("{task.description}"), BarColumn(), MofNCompleteColumn(),
                  TimeElapsedColumn(), console=console) as bar:  # fmt: skip
        task = bar.add_task("jobs", total=len(jobs))

        def on_done(job: Job, rec: dict | None, was_skipped: bool) -> None:
            if not was_skipped and rec is not None:
                best = min((c for c in rec["cost"] if c is not None), default=None)
                bar.update(task, description=f"{job.tuner} {job.instance.split('/', 1)[1]} "
                           f"s{job.seed}: best {best} in {rec['wall_s']:.1f} s")  # fmt: skip
            bar.advance(task)

        try:
            n_run, n_skip = run_jobs(jobs, out, workers=workers, scheduler=scheduler,
                                     on_done=on_done)  # fmt: skip
        except ClusterError as exc:
            fail(f"--scheduler {scheduler}: {exc}")
    console.print(f"{n_run} jobs run, {n_skip} already finished; {time.perf_counter() - t0:.0f} s")
    pack_results(out)
    wanted = {j.key for j in jobs}
    records = [r for r in load_results(out)
               if Job(r["tuner"], r["instance"], r["seed"], r["budget"]).key in wanted]  # fmt: skip
    notes = []
    for name, lim in limits.items():
        notes.append(f"{name} reduced: " + ", ".join(
            f"{k}={v}" for k, v in vars(lim).items() if v is not None) + ".")  # fmt: skip
    superseded = superseded_note(suite)
    if superseded is not None:
        notes.append(f"The best-known costs of {suite} are superseded: {superseded['reason']}.")
    summary = write_report(records, out, best_known=load_best_known(suite), budgets=budgets,
                           tuners=tuner_list, instances=ids, skipped=skipped,
                           notes=notes)  # fmt: skip
    console.print(f"report: {out / 'report.md'} ({len(summary['rows'])} rows)")
    if as_json:
        typer.echo(json.dumps({"report": str(out / "report.md"), **summary}, indent=1, default=str))
