"""Mutation testing of the spec-bearing modules with cosmic-ray (``make mutation``).

Each module group below is mutated one mutant at a time in a scratch copy of the source
tree (``runs/mutation/src``; the work tree is never touched), and only the tests that cover
the group are run against each mutant. Every mutant gets a fresh, empty ``NUMBA_CACHE_DIR``:
numba's on-disk cache keys a function on its own file only, so a kernel that inlines a
mutated helper from another file (``chips/_fixed.py``) or a loop that calls a mutated chip
kernel (``sim/_loop.py``) would otherwise run the stale, unmutated machine code. The kernels
stay compiled (no ``NUMBA_DISABLE_JIT``): the tests exercise the code that users run, and the
closed loop's ``mj_step`` call only exists in compiled code.

Sessions are cosmic-ray work databases (``runs/mutation/<group>.sqlite``): an interrupted run
continues where it stopped. A group whose source changed since its session began is refused
(positions would point at other code) until ``--fresh``. ``--retest-survivors`` runs the
surviving mutants again, e.g. after new tests were written.

Usage::

    python experiments/mutation.py [GROUP ...] [--max-mutants N] [--seed S] [--fresh]
                                   [--retest-survivors] [--report-only]

``--max-mutants N`` samples N mutants of a group (seeded, uniformly, without replacement) and
marks the rest skipped; the report says a group was sampled. Given again with a larger N for
an existing session, it grows the sample (the mutants already run keep their results).
Results: a summary table on stdout and ``runs/mutation/report.md`` (every survivor with its
changed line, equivalent ones with their reason), the figures that ``docs/testing.md`` quotes.
"""

from __future__ import annotations

import argparse
import contextlib
import hashlib
import json
import os
import random
import shutil
import subprocess
import sys
import tempfile
import time
from collections import Counter
from collections.abc import Iterator
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
OUT = ROOT / "runs" / "mutation"

# Plausible-bug operators: off-by-one at comparisons and constants, swapped signs and
# operations, inverted conditions, dropped branches. (cosmic-ray's full set replaces every
# binary operator by ten others, mostly type errors or absurd code a reviewer would catch.)
OPERATORS = (
    "core/ReplaceBinaryOperator_Add_Sub",
    "core/ReplaceBinaryOperator_Sub_Add",
    "core/ReplaceBinaryOperator_Mul_Add",
    "core/ReplaceBinaryOperator_Mul_FloorDiv",
    "core/ReplaceBinaryOperator_FloorDiv_Mul",
    "core/ReplaceBinaryOperator_Div_Mul",
    "core/ReplaceBinaryOperator_RShift_LShift",
    "core/ReplaceBinaryOperator_LShift_RShift",
    "core/ReplaceBinaryOperator_Mod_FloorDiv",
    "core/ReplaceBinaryOperator_BitAnd_BitOr",
    "core/ReplaceBinaryOperator_Pow_Mul",
    "core/ReplaceComparisonOperator_Lt_LtE",
    "core/ReplaceComparisonOperator_LtE_Lt",
    "core/ReplaceComparisonOperator_Gt_GtE",
    "core/ReplaceComparisonOperator_GtE_Gt",
    "core/ReplaceComparisonOperator_Eq_NotEq",
    "core/ReplaceComparisonOperator_NotEq_Eq",
    "core/ReplaceUnaryOperator_USub_UAdd",
    "core/ReplaceUnaryOperator_Delete_Not",
    "core/ReplaceAndWithOr",
    "core/ReplaceOrWithAnd",
    "core/ReplaceTrueWithFalse",
    "core/ReplaceFalseWithTrue",
    "core/NumberReplacer",
    "core/ZeroIterationForLoop",
)

GROUPS: dict[str, tuple[list[str], list[str]]] = {
    # group: (mutated files, pytest arguments selecting the covering tests)
    "chips-fixed": (
        ["servogym/chips/_fixed.py"],
        ["tests/chips/test_pmd_filter.py", "tests/chips/test_pmd_edges.py"],
    ),
    "pmd-filter": (
        ["servogym/chips/pmd/_kernel.py", "servogym/chips/pmd/_reference.py"],
        ["tests/chips/test_pmd_filter.py", "tests/chips/test_pmd_edges.py"],
    ),
    "pmac-filter": (
        ["servogym/chips/pmac/_kernel.py", "servogym/chips/pmac/_reference.py"],
        ["tests/chips/test_pmac_filter.py", "tests/chips/test_pmac_edges.py"],
    ),
    "parker6k-filter": (
        ["servogym/chips/parker6k/_kernel.py", "servogym/chips/parker6k/_reference.py"],
        ["tests/chips/test_parker6k_filter.py", "tests/chips/test_parker6k_edges.py"],
    ),
    "chips-space": (
        ["servogym/chips/_space.py"],
        [
            "tests/chips/test_space.py",
            "tests/chips/test_space_edges.py",
            "tests/autotune/test_space.py",
            "tests/chips/test_pmd_filter.py",
        ],
    ),
    "chips-params": (
        [
            "servogym/chips/pmd/_params.py",
            "servogym/chips/pmac/_params.py",
            "servogym/chips/parker6k/_params.py",
            "servogym/chips/_assumptions.py",
            "servogym/chips/_family.py",
            "servogym/chips/pmac/_notch.py",
        ],
        [
            "tests/chips",
            "--ignore=tests/chips/test_pmd_profile.py",
            "--ignore=tests/chips/test_pmac_profile.py",
            "--ignore=tests/chips/test_parker6k_profile.py",
        ],
    ),
    "chips-profile": (
        [
            "servogym/chips/pmd/_profile.py",
            "servogym/chips/pmac/_profile.py",
            "servogym/chips/parker6k/_profile.py",
        ],
        [
            "tests/chips/test_pmd_profile.py",
            "tests/chips/test_pmac_profile.py",
            "tests/chips/test_parker6k_profile.py",
        ],
    ),
    "chips-export": (
        [
            "servogym/chips/pmd/_export.py",
            "servogym/chips/pmac/_export.py",
            "servogym/chips/parker6k/_export.py",
            "servogym/chips/_paramfile.py",
        ],
        [
            "tests/chips/test_pmd_export.py",
            "tests/chips/test_pmac_export.py",
            "tests/chips/test_parker6k_export.py",
            "tests/chips/test_paramfile.py",
            "tests/chips/test_export_edges.py",
        ],
    ),
    "sim-metrics": (
        ["servogym/sim/_metrics.py"],
        ["tests/sim/test_metrics_edges.py", "tests/sim/test_runner.py", "-k", "metrics"],
    ),
    "sim-loop": (
        ["servogym/sim/_loop.py", "servogym/sim/_runner.py"],
        ["tests/sim/test_runner.py", "tests/sim/test_metrics_edges.py", "tests/sim/test_inputs.py"],
    ),
    "sim-scenario": (["servogym/sim/_scenario.py"], ["tests/sim/test_scenario.py"]),
    # The filters' linear response C(z): plain numpy, no kernel (the fresh numba cache costs
    # nothing here; the reference filters it is measured against are plain Python).
    "chips-response": (
        [
            "servogym/chips/pmd/_response.py",
            "servogym/chips/pmac/_response.py",
            "servogym/chips/parker6k/_response.py",
        ],
        ["tests/chips/test_filter_response.py", "tests/chips/test_response_edges.py"],
    ),
    # The held input (numba, inlined into the loop kernel: every mutant recompiles the loop,
    # about 6 s of the ~50 s baseline), the margins, the check and the agreement rule.
    "sim-margins": (
        [
            "servogym/sim/_inputs.py",
            "servogym/sim/_margins.py",
            "servogym/sim/_check.py",
            "servogym/sim/_convergence.py",
        ],
        [
            "tests/sim/test_inputs.py",
            "tests/sim/test_margins.py",
            "tests/sim/test_margins_edges.py",
            "tests/sim/test_check.py",
            "tests/sim/test_convergence.py",
        ],
    ),
    "chips-load": (
        [
            "servogym/chips/_load.py",
            "servogym/chips/pmd/_family.py",
            "servogym/chips/pmac/_family.py",
            "servogym/chips/parker6k/_family.py",
        ],
        [
            "tests/chips/test_family_latency.py",
            "tests/chips/test_load_edges.py",
            "tests/chips/test_parker6k_family.py",
            "tests/chips/test_family_contract.py",
            "tests/test_cli.py",
            "tests/files",
            "tests/test_cli_bad_input.py",
        ],
    ),
    "sim-twin": (
        ["servogym/sim/_pyloop.py", "servogym/sim/_plot.py"],
        [
            "tests/sim/test_runner.py::test_compiled_loop_equals_python_loop",
            "tests/test_cli.py::test_simulate_writes_plot_and_metrics",
        ],
    ),
    "autotune-session": (
        ["servogym/autotune/_session.py"],
        [
            "tests/autotune/test_session_edges.py",
            "tests/autotune/test_budget.py",
            "tests/autotune/test_stored_study.py",
            "tests/autotune/test_shared_study.py",
            "tests/autotune/test_resume.py",
        ],
    ),
}


def _digest(files: list[str]) -> str:
    h = hashlib.sha256()
    for f in files:
        h.update((ROOT / f).read_bytes())
    return h.hexdigest()


def _commit() -> str:
    """The work tree's commit, ``-dirty`` when it has uncommitted changes."""
    out = subprocess.run(["git", "describe", "--always", "--dirty"], cwd=ROOT,
                         capture_output=True, text=True)  # fmt: skip
    return out.stdout.strip()


def scratch(group: str) -> Path:
    """The group's own copy of the tree (groups may run in parallel processes)."""
    return OUT / "src" / group


def sync_tree(group: str) -> None:
    """Copy the package, the tests and the pytest settings into the group's scratch tree."""
    src = scratch(group)
    src.mkdir(parents=True, exist_ok=True)
    for name in ("servogym", "tests", "docs"):  # docs: the tests compare the spec tables
        if (src / name).exists():
            shutil.rmtree(src / name)
        shutil.copytree(ROOT / name, src / name, ignore=shutil.ignore_patterns("__pycache__"))
    shutil.copy2(ROOT / "pyproject.toml", src / "pyproject.toml")


def test_command(tests: list[str]) -> str:
    existing = [t for t in tests if t.startswith("-") or not t.startswith("tests/")
                or (ROOT / t).exists()]  # fmt: skip
    return (
        f"{sys.executable} -m pytest -x -q -p no:cacheprovider -m 'not slow' "
        f"--hypothesis-seed=0 {' '.join(existing)}"
    )


@contextlib.contextmanager
def in_tree(src: Path) -> Iterator[None]:
    """Run in the scratch tree ``src`` with a fresh numba cache and no hypothesis database."""
    cache = tempfile.mkdtemp(prefix="numba-mut-")
    shutil.rmtree(src / ".hypothesis", ignore_errors=True)
    env = {"NUMBA_CACHE_DIR": cache, "PYTHONPATH": str(src)}
    old = {k: os.environ.get(k) for k in env}
    os.environ.update(env)
    cwd = os.getcwd()
    os.chdir(src)
    try:
        yield
    finally:
        os.chdir(cwd)
        for k, v in old.items():
            if v is None:
                os.environ.pop(k, None)
            else:
                os.environ[k] = v
        shutil.rmtree(cache, ignore_errors=True)


def init_group(name: str, max_mutants: int | None, seed: int) -> None:
    from cosmic_ray.commands.init import _all_work_items
    from cosmic_ray.work_db import WorkDB, use_db
    from cosmic_ray.work_item import WorkerOutcome, WorkResult

    files, tests = GROUPS[name]
    from cosmic_ray.testing import run_tests

    command = test_command(tests)
    src = scratch(name)
    with in_tree(src):
        t0 = time.monotonic()
        outcome, output = run_tests(command, 1800)
        seconds = time.monotonic() - t0
    if outcome.value != "survived":  # cosmic-ray's word for "the tests passed"
        raise SystemExit(f"{name}: the covering tests fail on the unmutated code:\n{output}")
    db_path = OUT / f"{name}.sqlite"
    db_path.unlink(missing_ok=True)
    items = [
        w
        for w in _all_work_items([src / f for f in files], {})
        if w.mutations[0].operator_name in OPERATORS
    ]
    with use_db(str(db_path), WorkDB.Mode.create) as db:
        db.clear()
        db.add_work_items(items)
        chosen = {w.job_id for w in items}
        if max_mutants is not None and len(items) > max_mutants:
            chosen = {w.job_id for w in random.Random(seed).sample(items, max_mutants)}
            for w in items:
                if w.job_id not in chosen:
                    db.set_result(w.job_id, WorkResult(worker_outcome=WorkerOutcome.SKIPPED))
    meta = {
        "files": files,
        "tests": tests,
        "command": command,
        "digest": _digest(files),
        "baseline_s": round(seconds, 1),
        "timeout_s": round(max(60.0, 4 * seconds), 1),
        "n_mutants": len(items),
        "n_sampled": len(chosen),
        "sampled": len(chosen) < len(items),
        "seed": seed,
        "commit": _commit(),
    }
    (OUT / f"{name}.json").write_text(json.dumps(meta, indent=1))
    print(f"{name}: {len(items)} mutants, {len(chosen)} to run, baseline {seconds:.1f} s")


def extend_sample(name: str, max_mutants: int) -> None:
    """Grow a sampled session to ``max_mutants``: more of its skipped mutants become pending
    (seeded; the mutants already run keep their results)."""
    from cosmic_ray.work_db import WorkDB, WorkResultStorage, use_db

    meta = json.loads((OUT / f"{name}.json").read_text())
    if max_mutants <= meta["n_sampled"]:
        return
    with use_db(str(OUT / f"{name}.sqlite"), WorkDB.Mode.open) as db:
        skipped = sorted(
            item.job_id
            for item, res in db.completed_work_items
            if res.worker_outcome.value == "skipped"
        )
        more = random.Random(meta["seed"] + meta["n_sampled"]).sample(
            skipped, min(len(skipped), max_mutants - meta["n_sampled"])
        )
        with db._session_maker.begin() as session:  # cosmic-ray has no public "unset"
            for job_id in more:
                session.query(WorkResultStorage).filter_by(job_id=job_id).delete()
    meta["n_sampled"] += len(more)
    meta["sampled"] = meta["n_sampled"] < meta["n_mutants"]
    (OUT / f"{name}.json").write_text(json.dumps(meta, indent=1))
    print(f"{name}: {len(more)} more mutants sampled, {meta['n_sampled']} in all")


def exec_group(name: str, retest: bool) -> None:
    from cosmic_ray.mutating import mutate_and_test
    from cosmic_ray.work_db import WorkDB, WorkResultStorage, use_db

    meta = json.loads((OUT / f"{name}.json").read_text())
    files, tests = GROUPS[name]
    if meta["digest"] != _digest(files):
        raise SystemExit(
            f"{name}: the source changed since this session began; run with --fresh {name}"
        )
    command = test_command(tests)  # new covering test files are picked up
    meta["commit"] = _commit()  # the tests in force (the source is the one of the digest)
    meta["command"] = command
    (OUT / f"{name}.json").write_text(json.dumps(meta, indent=1))
    with use_db(str(OUT / f"{name}.sqlite"), WorkDB.Mode.open) as db:
        if retest:
            table = json.loads(EQUIVALENT_FILE.read_text()) if EQUIVALENT_FILE.exists() else []
            survivors = []
            for item, result in db.completed_work_items:
                if result.test_outcome is None or result.test_outcome.value != "survived":
                    continue
                rel = str(Path(item.mutations[0].module_path).relative_to(scratch(name)))
                line = item.mutations[0].start_pos[0]
                if equivalence(rel, *_changed_lines(result.diff or ""), table, line) is None:
                    survivors.append(item.job_id)
            with db._session_maker.begin() as session:  # cosmic-ray has no public "unset"
                for job_id in survivors:
                    session.query(WorkResultStorage).filter_by(job_id=job_id).delete()
            print(f"{name}: {len(survivors)} non-equivalent survivors to test again")
        pending = list(db.pending_work_items)
        for i, item in enumerate(pending):
            with in_tree(scratch(name)):
                result = mutate_and_test(item.mutations, command, meta["timeout_s"])
            db.set_result(item.job_id, result)
            m = item.mutations[0]
            print(
                f"{name} {i + 1}/{len(pending)} {result.test_outcome} "
                f"{Path(m.module_path).name}:{m.start_pos[0]} {m.operator_name}",
                flush=True,
            )


EQUIVALENT_FILE = Path(__file__).with_name("mutation_equivalent.json")
"""Survivors judged equivalent (the mutant computes the same results for every legal input),
each with its reason: ``[{"file", "from", "to", "reason"}]``, matched on the file and the
changed line's text before and after (so the judgement survives unrelated edits); ``"to":
"*"`` covers every mutant of a line (a dead constant)."""


def _changed_lines(diff: str) -> tuple[str, str]:
    old = [ln[1:].strip() for ln in diff.splitlines() if ln[:1] == "-" and ln[:3] != "---"]
    new = [ln[1:].strip() for ln in diff.splitlines() if ln[:1] == "+" and ln[:3] != "+++"]
    return " / ".join(old), " / ".join(new)


def equivalence(rel: str, old: str, new: str, table: list[dict], line: int = 0) -> str | None:
    """The reason a survivor is equivalent, or None (an entry with a ``line`` matches there
    only, for a text that occurs on several lines)."""
    if old.startswith("@njit("):
        return "a compilation option of the decorator (cache, nogil): results unchanged"
    for e in table:
        same = e["file"] == rel and e["from"] == old and e["to"] in (new, "*")
        if same and e.get("line", line) == line:
            return e["reason"]
    return None


def report(names: list[str]) -> str:
    from cosmic_ray.work_db import WorkDB, use_db

    table = json.loads(EQUIVALENT_FILE.read_text()) if EQUIVALENT_FILE.exists() else []
    rows = [
        "| group | commit | mutants | run | killed | equivalent | survived | incompetent "
        "| killed of non-equivalent |",
        "|---|---|---|---|---|---|---|---|---|",
    ]
    live, equivalent = [], []
    for name in names:
        meta_path = OUT / f"{name}.json"
        if not meta_path.exists():
            continue
        meta = json.loads(meta_path.read_text())
        n = Counter()
        with use_db(str(OUT / f"{name}.sqlite"), WorkDB.Mode.open) as db:
            pending = db.num_work_items - db.num_results
            for item, res in db.completed_work_items:
                if res.worker_outcome.value == "skipped":
                    continue
                outcome = res.test_outcome.value if res.test_outcome else "incompetent"
                if outcome != "survived":
                    n[outcome if outcome == "killed" else "incompetent"] += 1
                    continue
                m = item.mutations[0]
                rel = str(Path(m.module_path).relative_to(scratch(name)))
                old, new = _changed_lines(res.diff or "")
                where = f"`{rel}:{m.start_pos[0]}` ({m.operator_name.removeprefix('core/')})"
                reason = equivalence(rel, old, new, table, m.start_pos[0])
                if reason is None:
                    n["survived"] += 1
                    live.append(f"- {name}: {where}: `{old}` -> `{new}`")
                else:
                    n["equivalent"] += 1
                    equivalent.append(f"- {name}: {where}: `{old}` -> `{new}`: {reason}")
        judged = n["killed"] + n["survived"]
        rate = f"{100 * n['killed'] / judged:.1f} %" if judged else "-"
        sampled = f"{meta['n_sampled']} sampled" if meta["sampled"] else "all"
        ran = judged + n["equivalent"] + n["incompetent"]
        rows.append(
            f"| {name} | {meta['commit']} | {meta['n_mutants']} ({sampled}) | "
            f"{ran}{f' ({pending} pending)' if pending else ''} | {n['killed']} | "
            f"{n['equivalent']} | {n['survived']} | {n['incompetent']} | {rate} |"
        )
    return (
        "\n".join(rows)
        + "\n\n## Surviving mutants, not equivalent\n\n"
        + ("\n".join(live) or "None.")
        + "\n\n## Equivalent mutants\n\n"
        + ("\n".join(equivalent) or "None.")
        + "\n"
    )


def main(argv: list[str] | None = None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("groups", nargs="*", help=f"default: all of {', '.join(GROUPS)}")
    ap.add_argument("--max-mutants", type=int, default=None)
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--fresh", action="store_true", help="start the groups' sessions anew")
    ap.add_argument("--retest-survivors", action="store_true")
    ap.add_argument("--report-only", action="store_true")
    args = ap.parse_args(argv)
    names = args.groups or list(GROUPS)
    unknown = [n for n in names if n not in GROUPS]
    if unknown:
        raise SystemExit(f"unknown group(s) {unknown}; known: {', '.join(GROUPS)}")
    OUT.mkdir(parents=True, exist_ok=True)
    if not args.report_only:
        for name in names:
            sync_tree(name)
            if args.fresh or not (OUT / f"{name}.json").exists():
                init_group(name, args.max_mutants, args.seed)
            elif args.max_mutants is not None:
                extend_sample(name, args.max_mutants)
            exec_group(name, args.retest_survivors)
    text = report(names)
    (OUT / "report.md").write_text(text)
    print(text)


if __name__ == "__main__":
    main()
