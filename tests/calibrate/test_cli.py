"""``servogym calibrate`` end to end: exit codes, files, --json, and --plant-file downstream."""

from __future__ import annotations

import json

import pytest
from typer.testing import CliRunner

from servogym.calibrate import read_plant_file, to_csv
from servogym.chips.pmd import to_json
from servogym.cli import app
from tests.calibrate.conftest import HIDDEN_LATENCY, PARAMS, ROTARY_HIDDEN

runner = CliRunner()


@pytest.fixture(scope="module")
def files(tmp_path_factory, rotary_trace):
    folder = tmp_path_factory.mktemp("cal")
    (folder / "trace.csv").write_text(
        to_csv(rotary_trace, ("commanded_velocity", "commanded_acceleration"))
    )
    (folder / "params.json").write_text(to_json(PARAMS))
    return folder


@pytest.fixture(scope="module")
def calibrated(files):
    out = files / "out"
    result = runner.invoke(app, [
        "calibrate", str(files / "trace.csv"), "--chip", "MC2100", "--plant", "rotary",
        "--params", str(files / "params.json"), "--out", str(out), "--json",
        "--latency", HIDDEN_LATENCY,
    ])  # fmt: skip
    return result, out


def test_calibrate_prints_json_and_writes_the_plant_file(calibrated):
    result, out = calibrated
    assert result.exit_code == 0, result.output
    doc = json.loads(result.stdout)
    assert doc["latency"] == HIDDEN_LATENCY and doc["poor_fit"] is False
    assert doc["rms_error_counts"] < 3
    assert abs(doc["plant"]["load_inertia_kgm2"] / ROTARY_HIDDEN["load_inertia_kgm2"] - 1) < 0.1
    for name in ("plant.json", "calibration.json", "calibration.png"):
        assert (out / name).is_file()
    pf = read_plant_file(out / "plant.json", "rotary")
    assert pf.values == doc["plant"]
    assert pf.sources["load_inertia_kgm2"] == "fitted" and pf.sources["peak_current_a"] == "nominal"
    assert pf.provenance["chip_model"] == "MC2100"
    assert pf.provenance["loop_latency"] == HIDDEN_LATENCY


def test_an_existing_plant_file_is_not_replaced_without_force(files, calibrated):
    _, out = calibrated
    result = runner.invoke(app, [
        "calibrate", str(files / "trace.csv"), "--chip", "MC2100", "--plant", "rotary",
        "--params", str(files / "params.json"), "--out", str(out),
    ])  # fmt: skip
    assert result.exit_code == 2 and "already exists; pass --force" in result.output


def test_simulate_and_check_take_the_plant_file(calibrated, tmp_path):
    _, out = calibrated
    plant_file = str(out / "plant.json")
    result = runner.invoke(app, ["simulate", "--chip", "MC2100", "--plant", "rotary",
                                 "--plant-file", plant_file, "--out", str(tmp_path / "sim"),
                                 "--json"])  # fmt: skip
    assert result.exit_code == 0, result.output
    result = runner.invoke(
        app,
        [
            "simulate",
            "--chip",
            "MC2100",
            "--plant",
            "arm",
            "--plant-file",
            plant_file,
            "--out",
            str(tmp_path / "sim"),
        ],
    )
    assert result.exit_code == 2 and "is a 'rotary' plant, but the command runs --plant arm" in (
        result.output
    )


def test_a_poor_fit_exits_1_and_writes_no_plant_file(files, tmp_path):
    import dataclasses

    (tmp_path / "other.json").write_text(to_json(dataclasses.replace(PARAMS, kp=90)))
    result = runner.invoke(app, [
        "calibrate", str(files / "trace.csv"), "--chip", "MC2100", "--plant", "rotary",
        "--params", str(tmp_path / "other.json"), "--out", str(tmp_path / "out"),
        "--latency", HIDDEN_LATENCY,
    ])  # fmt: skip
    assert result.exit_code == 1, result.output
    assert "poor fit" in result.output and "plant.json not written" in result.output
    assert not (tmp_path / "out" / "plant.json").exists()
    assert (tmp_path / "out" / "calibration.png").exists()


def _nan_on_line_10(text: str) -> str:
    lines = text.splitlines()
    cells = lines[9].split(",")
    cells[2] = "nan"
    lines[9] = ",".join(cells)
    return "\n".join(lines) + "\n"


@pytest.mark.parametrize(
    ("edit", "message"),
    [
        (lambda t: t.replace("time_s,", "t,", 1), "missing time_s"),
        (lambda t: "\n".join(t.splitlines()[:100]) + "\n", "too short"),
        (_nan_on_line_10, "line 10: column actual must be finite"),
        (lambda t: t.replace("\n0.00015", "\n-0.00015", 1), "time must increase"),
    ],
)  # fmt: skip
def test_malformed_traces_exit_2_with_one_line(files, tmp_path, edit, message):
    bad = tmp_path / "bad.csv"
    bad.write_text(edit((files / "trace.csv").read_text()))
    result = runner.invoke(app, [
        "calibrate", str(bad), "--chip", "MC2100", "--plant", "rotary",
        "--params", str(files / "params.json"), "--out", str(tmp_path / "out"),
    ])  # fmt: skip
    assert result.exit_code == 2
    lines = [ln for ln in result.output.splitlines() if ln.strip()]
    assert len(lines) == 1 and lines[0].startswith("error: ") and message in lines[0]


def test_a_trace_from_another_chip_period_exits_2(files, tmp_path):
    # the MC58000 runs at 52 us: the MC2100's 154 us trace is not one of its traces
    result = runner.invoke(app, [
        "calibrate", str(files / "trace.csv"), "--chip", "MC58000", "--plant", "rotary",
        "--params", str(files / "params.json"), "--out", str(tmp_path / "out"),
    ])  # fmt: skip
    assert result.exit_code == 2 and "error:" in result.output


def test_the_envs_take_the_plant_file(calibrated):
    from servogym.envs import ScheduleEnv, TuneEnv

    _, out = calibrated
    pf = read_plant_file(out / "plant.json")
    env = TuneEnv("MC2100", "rotary", plant_file=str(out / "plant.json"),
                  plant_values={"coulomb_friction_nm": 0.02})  # fmt: skip
    fixed = env.scenario.plant_values
    assert fixed["load_inertia_kgm2"] == pf.values["load_inertia_kgm2"]
    assert fixed["coulomb_friction_nm"] == 0.02
    env = ScheduleEnv("MC2100", "rotary", plant_file=str(out / "plant.json"),
                      plant_range={"load_inertia_kgm2": (1e-4, 2e-4)})  # fmt: skip
    assert "load_inertia_kgm2" not in env.scenario.plant_values
    with pytest.raises(ValueError, match="plant_file or a scenario"):
        TuneEnv(scenario=env.scenario, plant_file=str(out / "plant.json"))


def test_tune_takes_the_plant_file(calibrated, tmp_path):
    _, out = calibrated
    result = runner.invoke(app, [
        "tune", "--chip", "MC2100", "--plant", "arm", "--budget", "1", "--out",
        str(tmp_path / "run"), "--plant-file", str(out / "plant.json"),
    ])  # fmt: skip
    assert result.exit_code == 2
    assert "is a 'rotary' plant, but the command runs --plant arm" in result.output


@pytest.mark.parametrize(
    ("extra", "message"),
    [
        (["--fix", "coulomb=0.1"], "--fix: plant family 'rotary' has no parameter 'coulomb'"),
        (["--fix", "coulomb_friction_nm=5"], "--fix: coulomb_friction_nm must satisfy"),
        (["--fix", "coulomb_friction_nm=abc"], "must be a finite number"),
        (["--fit", "load"], "--fit: plant family 'rotary' has no parameter 'load'"),
        (["--latency", "later"], "--latency must be one of axis_slot"),
        (["--max-error", "0"], "--max-error must satisfy 0 < --max-error"),
        (["--format", "xml"], "--format must be one of csv, pmac-gather"),
        (["--chip", "TurboPMAC2"], "is a pmac model, but the file is a pmd file"),
        (["--fix", "encoder_counts_per_rev=4000"], "4096 <= encoder_counts_per_rev"),
    ],
)
def test_bad_options_exit_2_with_one_line(files, tmp_path, extra, message):
    result = runner.invoke(app, [
        "calibrate", str(files / "trace.csv"), "--chip", "MC2100", "--plant", "rotary",
        "--params", str(files / "params.json"), "--out", str(tmp_path / "out"), *extra,
    ])  # fmt: skip
    lines = [ln for ln in result.output.splitlines() if ln.strip()]
    assert result.exit_code == 2 and len(lines) == 1 and message in lines[0], result.output


@pytest.mark.slow
def test_check_runs_on_the_plant_file(calibrated, files, tmp_path):
    _, out = calibrated
    result = runner.invoke(app, [
        "check", str(files / "params.json"), "--plant", "rotary", "--plant-file",
        str(out / "plant.json"), "--plant-param", "coulomb_friction_nm=0.02",
        "--out", str(tmp_path / "chk"), "--json",
    ])  # fmt: skip
    assert result.exit_code in (0, 1), result.output
    doc = json.loads((tmp_path / "chk" / "check.json").read_text())
    pf = read_plant_file(out / "plant.json")
    assert doc["plant_values"]["load_inertia_kgm2"] == pf.values["load_inertia_kgm2"]
    assert doc["plant_values"]["coulomb_friction_nm"] == 0.02
