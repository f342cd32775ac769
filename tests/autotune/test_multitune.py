"""servogym tune on a multi-axis machine (issue 23 point 4): every axis's registers in one
study, the outputs in the chip's multi-axis forms, read back by the importers and by
servogym export."""

from __future__ import annotations

import csv
import json

import pytest
import typer
from typer.testing import CliRunner

from servogym.autotune._cli import tune_command
from servogym.autotune._job import run_study
from servogym.autotune._machine import (
    MachineProblem,
    MachineScenario,
    MachineSpace,
    axis_name,
    split_name,
)
from servogym.chips import ParameterError
from servogym.chips._axes import export_axes, import_axes, load_axes
from servogym.chips._family import get_chip
from servogym.cli import app as main_app

CHIPS = ("MC2100", "TurboPMAC2", "6250")
"""One model of each chip family (PMD, PMAC, 6000 series)."""
PLANTS = ("xy-stage", "two-link-arm")


@pytest.fixture()
def app():
    app = typer.Typer()
    app.command("tune")(tune_command)
    app.command("noop")(lambda: None)  # keeps "tune" a subcommand
    return app


def _tune(app, out, *args: str):
    return CliRunner().invoke(
        app, ["tune", "--budget", "2", "--workers", "2", "--out", str(out), *args],
        env={"COLUMNS": "250"},
    )  # fmt: skip


# ------------------------------------------------------------------------------------------
# The space: names carry the axis
# ------------------------------------------------------------------------------------------


@pytest.mark.parametrize("chip", CHIPS)
def test_every_searched_name_carries_its_axis_and_round_trips(chip):
    family, model = get_chip(chip)
    space = MachineSpace.for_machine(chip, 2)
    tunable = [s.name for s in family.parameter_space(model).tunable()]
    assert space.names == tuple(axis_name(r, k) for k in (1, 2) for r in tunable)
    assert all(split_name(n)[1] in (1, 2) for n in space.names)
    # any point of the unit cube -> legal sets -> the same values back
    unit = {u: (-0.9 + 1.7 * i / len(space.unit_names)) for i, u in enumerate(space.unit_names)}
    values = space.values_from_unit(unit)
    params = space.make_params(values)
    assert params.numbers == (1, 2)
    back = space.register_values(params)
    assert {n: back[n] for n in values} == values
    # axis 2's set holds the axis-2 values, axis 1's the axis-1 ones
    for name in space.names:
        register, axis = split_name(name)
        assert getattr(params[axis], register) == values[name]


def test_controller_wide_registers_are_one_name_and_the_pmd_period_counts_the_axes():
    space = MachineSpace.for_machine("MC2100", 2, names=["kp.2", "sample_time_us"])
    assert space.names == ("kp.2", "sample_time_us")
    assert space.specs[1].low == 2 * 154  # two time slices of the MC2100
    params = space.make_params({"sample_time_us": 400, "kp.2": 7})
    assert params[1].sample_time_us == params[2].sample_time_us == 400
    assert (params[1].kp, params[2].kp) == (params[1].space["kp"].default, 7)
    fixed = MachineSpace.for_machine("MC2100", 2, fixed={"bias": 0, "bias.2": 5}).fixed
    assert fixed == {"bias.1": 0, "bias.2": 5}  # the name with the axis wins


@pytest.mark.parametrize(
    ("kw", "message"),
    [
        ({"fixed": {"kp.1": 40000}}, "kp.1 must satisfy 0 <= kp.1 <= 32767"),
        ({"fixed": {"kp.3": 1}}, "kp.3: the axis must satisfy 1 <= axis <= 2"),
        ({"names": ["kq.1"]}, "MC2100 has no parameter 'kq'"),
        ({"fixed": {"sample_time_us.1": 400}}, "sample_time_us is one setting of the whole"),
        ({"fixed": {"sample_time_us": 200}}, "308 <= sample_time_us <= 65535"),
        ({"n_axes": 5}, "n_axes must satisfy 1 <= n_axes <= 4"),
    ],
)
def test_bad_names_and_values_are_refused_naming_the_name_value_and_range(kw, message):
    kw = {"n_axes": 2, **kw}
    with pytest.raises(ParameterError, match=message):
        MachineSpace.for_machine("MC2100", **kw)


def test_a_chip_that_drives_fewer_axes_than_the_machine_is_refused():
    with pytest.raises(ParameterError, match="drives at most 1"):
        MachineScenario("MC3110", "xy-stage")


# ------------------------------------------------------------------------------------------
# The study: the safe tuner and the Optuna samplers take a machine
# ------------------------------------------------------------------------------------------


def _problem(chip="MC2100", plant="xy-stage", **kw):
    scenario = MachineScenario(chip, plant)
    space = MachineSpace.for_machine(chip, scenario.n_axes, **kw)
    return MachineProblem(scenario=scenario, space=space)


@pytest.mark.parametrize("tuner", ["safe", "tpe", "cmaes", "random"])
def test_tuners_search_every_axis_with_per_axis_constraints(tuner):
    problem = _problem(names=["kp", "kd"])
    result = run_study(problem, tuner, 3, storage=None, n_workers=2)
    assert len(result.trials) == 3
    t = result.trials[-1]
    assert set(t.params) == {"u_kp.1", "u_kd.1", "u_kp.2", "u_kd.2"}
    assert set(t.constraints) == {
        f"{c}.{k}" for k in (1, 2) for c in ("max_following_error", "saturation_fraction",
                                             "gain_margin", "phase_margin")
    } | {"diverged"}  # fmt: skip
    outcome = t.user_attrs["outcome"]
    assert len(outcome["axis_following_error"]) == 2
    # each loop's margins with the other closed: finite on these stable loops, and the
    # constraint is the minimum minus the margin
    assert all(x is not None for x in outcome["axis_gain_margin_db"])
    assert t.constraints["gain_margin.2"] == pytest.approx(6.0 - outcome["axis_gain_margin_db"][1])
    assert result.best_params.numbers == (1, 2)


def test_classical_tuners_refuse_a_machine():
    from servogym.autotune._session import TuneError

    with pytest.raises(TuneError, match="experiments on one axis; a machine of 2 axes"):
        run_study(_problem(), "relay", 10, storage=None)


# ------------------------------------------------------------------------------------------
# The command: every chip family x both machines, files read back
# ------------------------------------------------------------------------------------------


@pytest.mark.parametrize("plant", PLANTS)
@pytest.mark.parametrize("chip", CHIPS)
def test_tune_writes_every_format_in_the_multi_axis_form_and_it_reads_back(
    app, tmp_path, chip, plant
):
    out = tmp_path / "run"
    result = _tune(app, out, "--chip", chip, "--plant", plant, "--no-check")
    assert result.exit_code == 0, result.output
    assert "(axis 2)" in result.output or "(motor 2)" in result.output  # the per-axis table
    summary = json.loads((out / "summary.json").read_text())
    assert summary["n_axes"] == 2 and summary["axis_numbers"] == [1, 2]
    searched = summary["problem"]["space"]["searched"]
    assert searched and all(split_name(n)[1] in (1, 2) for n in searched)
    # the design start beats the chip defaults by far on every machine
    assert summary["tuned"]["cost"] < 0.2 * summary["default"]["cost"]
    family, model = get_chip(chip)
    best = summary["best_params"]
    files = {f: n for f, n in summary["files"].items() if f in family.formats_for(model)}
    assert set(files) == set(family.formats_for(model))
    for fmt, name in files.items():
        axes = load_axes(out / name)  # format detected, manifest checked
        assert axes.model == model and axes.numbers == (1, 2)
        assert MachineSpace.for_machine(model, 2).register_values(axes) == best
        if fmt != "json":  # the file is the chip's multi-axis export, byte for byte
            assert (out / name).read_text() == export_axes(axes, fmt)
            assert import_axes((out / name).read_text(), fmt).sets == axes.sets
        # servogym export of each file, to each hardware format, is the tuned file
        for target, target_name in files.items():
            if target == "json":
                continue
            r = CliRunner().invoke(main_app, ["export", str(out / name), "--format", target])
            assert r.exit_code == 0, r.output
            assert r.output == (out / target_name).read_text()
    header = next(csv.reader((out / "trials.csv").open()))
    assert {f"u_{n}" for n in searched} <= set(header)


def test_export_picks_one_axis_or_names_the_axes_a_file_sets(app, tmp_path):
    out = tmp_path / "run"
    assert _tune(app, out, "--chip", "MC2100", "--plant", "xy-stage", "--no-check").exit_code == 0
    axes = load_axes(out / "best_params.c")
    r = CliRunner().invoke(main_app, ["export", str(out / "best_params.c"), "--axis", "2"])
    assert r.exit_code == 0, r.output
    assert r.output == get_chip("MC2100")[0].export(axes[2], "cmotion", axis=2)
    r = CliRunner().invoke(main_app, ["export", str(out / "best_params.c"), "--axis", "3"])
    assert r.exit_code == 2
    assert "--axis must be one of the axis numbers the file sets (1, 2); got --axis 3" in r.output


def test_resume_and_warm_start_take_a_machine(app, tmp_path):
    out = tmp_path / "run"
    args = ("--chip", "6250", "--plant", "xy-stage", "--no-check")
    assert _tune(app, out, *args).exit_code == 0
    r = CliRunner().invoke(app, ["tune", "--budget", "3", "--workers", "2", "--out", str(out),
                                 "--resume", *args])  # fmt: skip
    assert r.exit_code == 0, r.output
    assert json.loads((out / "summary.json").read_text())["n_trials"] == 3
    warm = tmp_path / "warm"
    r = _tune(app, warm, *args, "--warm-start", str(out / "best_params.prg"), "--tuner", "tpe")
    assert r.exit_code == 0, r.output
    first = json.loads((warm / "summary.json").read_text())
    assert first["kinds"]["warm_start"] == 1 and "design_start" not in first
    tuned = json.loads((out / "summary.json").read_text())["best_params"]
    with (warm / "trials.csv").open() as fh:
        row = next(csv.DictReader(fh))
    assert row["kind"] == "warm_start"
    assert {n: int(row[n]) for n in tuned} == tuned


@pytest.mark.parametrize(
    ("args", "message"),
    [
        (["--fix", "kp.1=40000"], "kp.1 must satisfy 0 <= kp.1 <= 32767"),
        (["--fix", "kp.3=10"], "kp.3: the axis must satisfy 1 <= axis <= 2"),
        (["--search", "kq"], "MC2100 has no parameter 'kq'"),
        (["--chip", "MC3110"], "the xy-stage has 2 axes (x, y) but the MC3110 drives at most 1"),
        (["--tuner", "relay"], "the 'relay' tuner experiments on one axis"),
        (["--plant-param", "payload=3"], "Did you mean payload_kg"),
        (["--plant-param", "payload_kg=-1"], "payload_kg"),
        (["--plant-file", "plant.json"], "--plant-file takes a plant.json of a single-axis"),
    ],
)
def test_bad_input_is_refused_in_one_line_before_the_study(app, tmp_path, args, message):
    out = tmp_path / "run"
    argv = {"--chip": "MC2100", "--plant": "xy-stage"}
    for i in range(0, len(args), 2):
        argv[args[i]] = args[i + 1]
    result = _tune(app, out, *[x for kv in argv.items() for x in kv])
    assert result.exit_code == 2, result.output
    assert message in " ".join(result.output.split()), result.output
    assert not (out / "study.journal").exists()


@pytest.mark.slow  # the multi-axis check runs its stress set (about 30 s)
def test_the_checked_set_is_written_and_a_failing_one_withheld(app, tmp_path):
    out = tmp_path / "run"
    result = _tune(app, out, "--chip", "MC2100", "--plant", "xy-stage", "--check-candidates", "2")
    assert result.exit_code == 0, result.output
    summary = json.loads((out / "summary.json").read_text())
    assert summary["check"]["passed"] and summary["hardware_files_withheld"] == []
    assert (out / "best_params.c").exists() and "check passed" in " ".join(result.output.split())
    # minima no set of this search can meet: exit 1, the loadable files withheld
    bad = tmp_path / "bad"
    result = _tune(app, bad, "--chip", "MC2100", "--plant", "xy-stage", "--check-candidates",
                   "1", "--min-phase-margin", "89")  # fmt: skip
    assert result.exit_code == 1, result.output
    summary = json.loads((bad / "summary.json").read_text())
    assert not summary["check"]["passed"] and summary["check"]["failures"]
    assert summary["hardware_files_withheld"] == ["cmotion", "host"]
    assert not (bad / "best_params.c").exists() and (bad / "best_params.json").exists()
    assert "phase margin" in " ".join(result.output.split())


def test_a_warm_start_the_outputs_would_replace_is_refused(app, tmp_path):
    out = tmp_path / "run"
    assert _tune(app, out, "--chip", "MC2100", "--plant", "xy-stage", "--no-check").exit_code == 0
    again = tmp_path / "again"
    again.mkdir()
    (again / "best_params.c").write_bytes((out / "best_params.c").read_bytes())
    result = _tune(app, again, "--chip", "MC2100", "--plant", "xy-stage", "--no-check",
                   "--warm-start", str(again / "best_params.c"))  # fmt: skip
    assert result.exit_code == 2, result.output
    assert "is the input file; refusing to overwrite it" in " ".join(result.output.split())
