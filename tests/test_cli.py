"""The `servogym` command: listings, export, simulate, and its errors."""

from __future__ import annotations

import json

import pytest
from typer.testing import CliRunner

from servogym.chips import families, get_chip
from servogym.chips.pmd import PMDParams, import_params, to_json
from servogym.cli import app
from servogym.plants import MULTI_PLANTS, PLANTS

runner = CliRunner()


def test_chips_json_lists_every_model_with_ranges():
    result = runner.invoke(app, ["chips", "--json"])
    assert result.exit_code == 0, result.output
    listed = {entry["model"]: entry for entry in json.loads(result.output)}
    for family in families().values():
        for model in family.models:
            space = family.parameter_space(model)
            got = {
                p["name"]: (p["low"], p["high"], p["default"]) for p in listed[model]["parameters"]
            }
            assert got == {n: (s.low, s.high, s.default) for n, s in space.items()}


def test_chips_table_names_ranges():
    result = runner.invoke(app, ["chips"])
    assert result.exit_code == 0
    assert "MC58000" in result.output and "0 .. 65535" in result.output


def test_chips_says_where_example_defaults_come_from():
    # Parker's SGP 85 / SGV 2.3 are the 6250 guide's worked example, not controller defaults;
    # every other register's default carries no such note.
    listed = json.loads(runner.invoke(app, ["chips", "--json"]).output)
    noted = {(e["model"], p["name"]) for e in listed for p in e["parameters"] if p["default_note"]}
    assert noted == {(m, n) for m in ("6250", "6K") for n in ("sgp", "sgv")}
    for e in listed:
        for p in e["parameters"]:
            if p["default_note"]:
                assert "worked tuning example" in p["default_note"]
                assert "not a controller default" in p["default_note"]
    text = runner.invoke(app, ["chips"]).output
    assert text.count("default sgp=8500: the 6250 guide's worked tuning example") == 2
    assert text.count("default sgv=230: the 6250 guide's worked tuning example") == 2


def test_plants_json_lists_every_family():
    result = runner.invoke(app, ["plants", "--json"])
    assert result.exit_code == 0
    assert {f["name"] for f in json.loads(result.output)} == set(PLANTS) | set(MULTI_PLANTS)


@pytest.mark.parametrize("fmt", ["cmotion", "host", "json"])
@pytest.mark.parametrize("model", ["MC2100", "MC58000"])
def test_export_round_trip(tmp_path, fmt, model):
    params = PMDParams(model=model, kp=321, ki=12, kd=4567, bias=-77)
    src = tmp_path / "p.json"
    src.write_text(to_json(params))
    out = tmp_path / f"out.{fmt}"
    result = runner.invoke(app, ["export", str(src), "--format", fmt, "--out", str(out)])
    assert result.exit_code == 0, result.output
    assert import_params(out.read_text(), fmt, model=model) == params


def test_export_refuses_an_unknown_format_and_a_bad_file(tmp_path):
    src = tmp_path / "p.json"
    src.write_text(to_json(PMDParams()))
    result = runner.invoke(app, ["export", str(src), "--format", "pdf"])
    assert result.exit_code == 2 and "cmotion" in result.output
    src.write_text('{"chip_family": "nope"}')
    result = runner.invoke(app, ["export", str(src)])
    assert result.exit_code == 2 and "chip_family must be one of" in result.output


def test_simulate_writes_plot_and_metrics(tmp_path):
    params = tmp_path / "p.json"
    params.write_text(to_json(PMDParams(model="MC3110", kp=150, kd=900)))
    result = runner.invoke(app, [
        "simulate", "--plant", "rotary", "--params", str(params), "--move", "1.0,20,2000,0.05",
        "--plant-param", "load_inertia_kgm2=2e-4", "--out", str(tmp_path), "--json",
    ])  # fmt: skip
    assert result.exit_code == 0, result.output
    summary = json.loads(result.output)
    assert summary["chip_model"] == "MC3110" and len(summary["moves"]) == 1
    assert (tmp_path / "response.png").stat().st_size > 10_000
    assert json.loads((tmp_path / "metrics.json").read_text())["cost"] == summary["cost"]
    assert get_chip("mc3110")[1] == "MC3110"


@pytest.mark.parametrize(
    "args,message",
    [
        (["--plant", "rotor"], "Did you mean"),
        (["--chip", "MC9999"], "unknown chip model 'MC9999'"),
        (["--plant-param", "payload_kg"], "--plant-param takes NAME=VALUE"),
        (["--plant", "arm", "--plant-param", "payload_kg=99"], "0.05 <= payload_kg <= 5"),
        (["--move", "1,2"], "--move takes DISTANCE,MAX_VELOCITY,MAX_ACCELERATION"),
    ],
)
def test_simulate_errors_name_the_problem(tmp_path, args, message):
    result = runner.invoke(app, ["simulate", "--out", str(tmp_path), *args])
    assert result.exit_code == 2
    assert message in result.output
