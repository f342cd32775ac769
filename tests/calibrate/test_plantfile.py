"""plant.json: written atomically with a checksum, read back checked."""

from __future__ import annotations

import json

import pytest

from servogym.calibrate import (
    PlantFileError,
    plant_document,
    plant_values,
    read_plant_file,
    write_plant_file,
)
from servogym.plants import get_plant


def _write(path, **values):
    fam = get_plant("vertical-axis")
    vals = {**fam.nominal(), **values}
    doc = plant_document("vertical-axis", vals, {n: "nominal" for n in vals}, {"command": "test"})
    write_plant_file(path, doc)
    return vals


def test_a_plant_file_round_trips(tmp_path):
    vals = _write(tmp_path / "plant.json", payload_kg=3.25)
    pf = read_plant_file(tmp_path / "plant.json", "vertical-axis")
    assert pf.family == "vertical-axis" and pf.values == vals
    assert pf.provenance["command"] == "test" and "servogym_version" in pf.provenance


def test_plant_values_puts_plant_params_on_top_and_drops_ranged_names(tmp_path):
    _write(tmp_path / "plant.json", payload_kg=3.25)
    out = plant_values(tmp_path / "plant.json", "vertical-axis", {"coulomb_friction_n": 5.0},
                       drop=("viscous_friction_ns_per_m",))  # fmt: skip
    assert out["payload_kg"] == 3.25 and out["coulomb_friction_n"] == 5.0
    assert "viscous_friction_ns_per_m" not in out
    assert plant_values(None, "vertical-axis", {"payload_kg": 1.0}) == {"payload_kg": 1.0}


def test_an_edited_file_is_refused(tmp_path):
    _write(tmp_path / "plant.json", payload_kg=3.25)
    doc = json.loads((tmp_path / "plant.json").read_text())
    doc["values"]["payload_kg"] = 9.0
    (tmp_path / "plant.json").write_text(json.dumps(doc))
    with pytest.raises(PlantFileError, match="checksum does not match"):
        read_plant_file(tmp_path / "plant.json")


@pytest.mark.parametrize(
    ("text", "match"),
    [
        ("{", "must be JSON; invalid JSON"),
        ('{"format": "servogym-params"}', "is not a plant file"),
        ('{"format": "servogym-plant", "version": 7}', "version must be 1"),
    ],
)
def test_other_files_are_refused_in_one_line(tmp_path, text, match):
    (tmp_path / "p.json").write_text(text)
    with pytest.raises(PlantFileError, match=match):
        read_plant_file(tmp_path / "p.json")


def test_a_file_of_another_family_or_missing_is_refused(tmp_path):
    _write(tmp_path / "plant.json")
    with pytest.raises(PlantFileError, match="is a 'vertical-axis' plant, but the command runs"):
        read_plant_file(tmp_path / "plant.json", "arm")
    with pytest.raises(PlantFileError, match="does not exist"):
        read_plant_file(tmp_path / "nope.json")
