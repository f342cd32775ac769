"""End lines, hand-written files, JSON checksums and the export command's file rules."""

from __future__ import annotations

import json

import pytest
from typer.testing import CliRunner

from servogym._files import FileSafetyError, seal, unseal
from servogym.chips import ParameterError, families, load_params_file
from servogym.cli import app

FILES = [
    (family, model, fmt)
    for family in families().values()
    for model in family.models
    for fmt in family.formats_for(model)
    if fmt != "json"
]


def _hand_written(text: str) -> str:
    return "".join(
        line + "\n"
        for line in text.splitlines()
        if "parameter set" not in line and "servogym-end" not in line
    )


def test_seal_and_unseal_round_trip_and_survive_crlf():
    text = seal("a\nb\n", ";")
    assert text.splitlines()[-1].startswith("; servogym-end sha256=")
    assert unseal(text) == ("a\nb\n", True)
    assert unseal(text.replace("\n", "\r\n")) == ("a\nb\n", True)
    assert unseal("plain\n") == ("plain\n", False)
    with pytest.raises(FileSafetyError, match="does not match the content above it"):
        unseal("A" + text[1:])
    with pytest.raises(FileSafetyError, match="is not the last line"):
        unseal(text + "c\n")
    with pytest.raises(FileSafetyError, match="is cut short"):
        unseal(text[:-20])


@pytest.mark.parametrize(("family", "model", "fmt"), FILES, ids=lambda x: getattr(x, "name", x))
def test_every_export_ends_with_a_verified_end_line(family, model, fmt):
    params = family.make_params(model)
    text = family.export(params, fmt)
    assert "servogym-end sha256=" in text.splitlines()[-1]
    assert load_params_file(text).params == params
    # Cut anywhere before the end line: refused as cut short, whatever the cut leaves.
    body = text[: text.rindex("servogym-end")]
    for cut in (len(body) - 2, len(body) // 2, len(body) - 40):
        with pytest.raises(ParameterError):
            load_params_file(text[:cut])
    # A hand-written copy (no title, no end line) is read when it sets every register ...
    assert load_params_file(_hand_written(text), model=model).params == params
    # ... and names what is missing when it does not.
    lines = _hand_written(text).splitlines()
    last = next(  # the last line that sets a register (not a comment, not Update)
        i
        for i in range(len(lines) - 1, -1, -1)
        if not lines[i].startswith(("#", ";", "/", " *")) and "Update" not in lines[i]
    )
    with pytest.raises(ParameterError, match=r"does not set|Missing|missing|not set"):
        load_params_file("\n".join(lines[:last] + lines[last + 1 :]) + "\n", model=model)


@pytest.mark.parametrize("name", sorted(families()))
def test_json_checksum_refuses_an_edit_and_a_hand_written_file_loads(name):
    family = families()[name]
    model = next(iter(family.models))
    doc = json.loads(family.export(family.make_params(model), "json"))
    assert list(doc)[-1] == "checksum" and doc["checksum"].startswith("sha256:")
    doc["notes"] = {"edited": True}
    with pytest.raises(ParameterError, match="checksum must equal the sha256"):
        load_params_file(json.dumps(doc))
    del doc["checksum"]
    assert load_params_file(json.dumps(doc)).params == family.make_params(model)


def test_export_is_atomic_refuses_its_input_and_needs_force(tmp_path):
    family = families()["pmd"]
    src = tmp_path / "p.json"
    src.write_text(family.export(family.make_params("MC2100", {"kp": 77}), "json"))
    runner = CliRunner()
    res = runner.invoke(app, ["export", str(src), "--out", str(src), "--force"])
    assert res.exit_code == 2 and "is the input file" in res.output
    assert json.loads(src.read_text())["params"]["kp"] == 77  # untouched
    link = tmp_path / "link.json"
    link.symlink_to(src)
    res = runner.invoke(app, ["export", str(src), "--out", str(link), "--force"])
    assert res.exit_code == 2 and "is the input file" in res.output
    out = tmp_path / "axis.c"
    out.write_text("old\n")
    res = runner.invoke(app, ["export", str(src), "--out", str(out)])
    assert res.exit_code == 2 and "--force" in res.output and out.read_text() == "old\n"
    res = runner.invoke(app, ["export", str(src), "--out", str(out), "--force"])
    assert res.exit_code == 0, res.output
    assert load_params_file(out.read_text()).params.kp == 77
    assert not [p for p in tmp_path.iterdir() if p.name.endswith(".tmp")]


@pytest.mark.parametrize(("model", "fmt"), [("MC2100", "cmotion"), ("TurboPMAC2", "ivar"),
                                            ("6250", "6250"), ("6K", "6k")])  # fmt: skip
def test_export_defaults_to_the_chips_own_format_and_reads_every_format(tmp_path, model, fmt):
    from servogym.chips import get_chip

    family, _ = get_chip(model)
    assert family.native_format(model) == fmt
    params = family.make_params(model)
    for source_fmt in family.formats_for(model):
        src = tmp_path / f"in_{source_fmt}"
        src.write_text(family.export(params, source_fmt))
        out = tmp_path / f"out_{source_fmt}"
        res = CliRunner().invoke(app, ["export", str(src), "--out", str(out)])
        assert res.exit_code == 0, res.output
        loaded = load_params_file(out.read_text())
        assert loaded.params == params and loaded.provenance["file_format"] == fmt
