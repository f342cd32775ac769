"""PMD export/import: every chip model x every format round-trips; golden lines; refusals."""

from __future__ import annotations

import dataclasses
import datetime as dt
import json

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from servogym.chips import ParameterError
from servogym.chips.pmd import CHIP_MODELS, SPEC_VERSION, PMDAssumptions, PMDParams
from servogym.chips.pmd import parameter_space as space_of
from servogym.chips.pmd._export import (
    FILE_EXTENSIONS,
    FORMATS,
    MAGELLAN_POSITION_LOOP,
    HostCommand,
    export,
    from_cmotion,
    from_host_commands,
    from_host_text,
    from_json,
    host_commands_to_text,
    host_text_to_commands,
    import_params,
    read_header,
    to_cmotion,
    to_host_commands,
    to_host_text,
    to_json,
)
from servogym.chips.pmd._params import ASSUMPTION_CHOICES

MODELS = list(CHIP_MODELS)
CREATED = "2025-01-31T12:00:00+00:00"


@st.composite
def legal_params(draw: st.DrawFn, model: str) -> PMDParams:
    """A legal set: every register drawn from the model's own parameter_space range."""
    values = {
        name: draw(st.integers(spec.low, spec.high), label=name)
        for name, spec in space_of(model).items()
    }
    return PMDParams(model=model, **values)


assumption_sets = st.builds(
    PMDAssumptions, **{name: st.sampled_from(c) for name, c in ASSUMPTION_CHOICES.items()}
)


def kwargs_for(fmt: str, axis: int, assumptions: PMDAssumptions) -> dict:
    if fmt == "json":
        return {"assumptions": assumptions, "created": CREATED}
    return {"axis": axis, "assumptions": assumptions}


# --- round trips: every model x every format ------------------------------------------------


@pytest.mark.parametrize("fmt", FORMATS)
@pytest.mark.parametrize("model", MODELS)
@settings(max_examples=30, deadline=None)
@given(data=st.data())
def test_round_trip(model, fmt, data):
    p = data.draw(legal_params(model))
    a = data.draw(assumption_sets)
    axis = data.draw(st.integers(1, CHIP_MODELS[model].n_axes), label="axis")
    text = export(p, fmt, **kwargs_for(fmt, axis, a))
    assert import_params(text, fmt) == p  # the model comes from the text
    assert import_params(text, fmt, model=model) == p
    if fmt != "json":  # the header keeps the provenance
        head = read_header(text)
        assert head["chip_model"] == model
        assert head["spec_version"] == SPEC_VERSION
        assert int(head["sample_time_us"]) == p.sample_time_us
        assert int(head["axis"]) == axis
        assert head["assumptions"] == a


@pytest.mark.parametrize("model", MODELS)
@settings(max_examples=30, deadline=None)
@given(data=st.data())
def test_host_commands_structured_and_bare_text_round_trip(model, data):
    p = data.draw(legal_params(model))
    axis = data.draw(st.integers(1, CHIP_MODELS[model].n_axes), label="axis")
    cmds = to_host_commands(p, axis)
    assert from_host_commands(cmds, model) == p
    text = host_commands_to_text(cmds)  # no header: the model is an argument
    assert host_text_to_commands(text) == cmds
    assert from_host_text(text, model) == p
    assert all(0 <= w <= 0xFFFF for c in cmds for w in c.words)
    assert {c.axis for c in cmds} == {axis}


@pytest.mark.parametrize("model", MODELS)
@settings(max_examples=20, deadline=None)
@given(data=st.data())
def test_json_round_trip_keeps_assumptions_and_provenance(model, data):
    p = data.draw(legal_params(model))
    a = data.draw(assumption_sets)
    metrics = {"ise": 1234.5, "overshoot_counts": np.int64(7)}
    notes = {"plant": "two-mass", "seed": 3}
    f = from_json(to_json(p, a, metrics=metrics, notes=notes, created=CREATED))
    assert f.params == p
    assert f.assumptions == a
    assert f.provenance == {
        "format": "servogym-params",
        "format_version": 1,
        "chip_family": "pmd",
        "chip_model": model,
        "sample_time_us": p.sample_time_us,
        "spec_version": SPEC_VERSION,
        "created": CREATED,
        "servogym_version": f.provenance["servogym_version"],
        "metrics": {"ise": 1234.5, "overshoot_counts": 7},
        "notes": notes,
    }


def test_models_without_biquads_export_no_biquad_registers():
    for model, chip in CHIP_MODELS.items():
        p = PMDParams.default(model)
        doc = json.loads(to_json(p, created=CREATED))
        c_text = to_cmotion(p)
        host = host_commands_to_text(to_host_commands(p))
        has = chip.has_biquads
        assert any(k.startswith("biquad") for k in doc["params"]) == has
        assert ("Biquad" in c_text) == has
        assert ("SetPositionLoop axis=1 data=0x0008" in host) == has


def test_sample_time_round_trips_away_from_default():
    for model in MODELS:
        p = PMDParams(model=model, sample_time_us=65535)
        for fmt in FORMATS:
            assert import_params(export(p, fmt), fmt).sample_time_us == 65535


def test_formats_and_extensions():
    assert FORMATS == ("json", "cmotion", "host")
    assert FILE_EXTENSIONS == {"json": ".json", "cmotion": ".c", "host": ".txt"}


# --- golden lines -----------------------------------------------------------------------------


def test_cmotion_golden_navigator():
    lines = to_cmotion(PMDParams.default("MC2100")).splitlines()
    body = [line for line in lines if line.startswith("PMD")]
    assert body == [
        "PMDSetKp(&hAxis1, 100);",
        "PMDSetKi(&hAxis1, 80);",
        "PMDSetKd(&hAxis1, 400);",
        "PMDSetKvff(&hAxis1, 0);",
        "PMDSetKaff(&hAxis1, 0);",
        "PMDSetIntegrationLimit(&hAxis1, 10000);",
        "PMDSetDerivativeTime(&hAxis1, 10);",
        "PMDSetKout(&hAxis1, 13107);",
        "PMDSetMotorBias(&hAxis1, 0);",
        "PMDSetMotorLimit(&hAxis1, 32767);",
        "PMDSetPositionErrorLimit(&hAxis1, 32767);",
        "PMDSetSampleTime(&hAxis1, 154);",
        "PMDUpdate(&hAxis1);",
    ]
    assert " * chip_model: MC2100" in lines
    assert f" * spec_version: {SPEC_VERSION}" in lines
    assert " * sample_time_us: 154" in lines
    assert " * assumption PMD-A1 rounding: floor" in lines


def test_cmotion_golden_magellan():
    p = PMDParams(model="MC58000", biquad1_enable=1, biquad1_a1=-12000, bias=-5)
    lines = to_cmotion(p, axis=3).splitlines()
    assert lines.index("PMDSetPositionLoop(&hAxis3, PMDPositionLoopKp, 100);") < lines.index(
        "PMDSetPositionLoop(&hAxis3, PMDPositionLoopBiquad2K, 16384);"
    )
    for line in [
        "PMDSetPositionLoop(&hAxis3, PMDPositionLoopIlimit, 10000);",
        "PMDSetPositionLoop(&hAxis3, PMDPositionLoopBiquad1Enable, 1);",
        "PMDSetPositionLoop(&hAxis3, PMDPositionLoopBiquad1A1, -12000);",
        "PMDSetMotorBias(&hAxis3, -5);",
        "PMDSetSampleTime(&hAxis3, 52);",
    ]:
        assert line in lines
    assert lines[-2] == "PMDUpdate(&hAxis3);"
    assert lines[-1].startswith("// servogym-end sha256=")
    assert "PMDSetKp" not in "\n".join(lines)


def test_magellan_parameter_numbers():
    numbers = {reg: n for n, _, reg in MAGELLAN_POSITION_LOOP}
    assert [numbers[r] for r in ("kp", "ki", "integration_limit", "kd")] == [0, 1, 2, 3]
    assert [numbers[r] for r in ("derivative_time", "kout", "kvff", "kaff")] == [4, 5, 6, 7]
    assert numbers["biquad1_enable"] == 8 and numbers["biquad1_k"] == 14
    assert numbers["biquad2_enable"] == 15 and numbers["biquad2_k"] == 21


def test_host_golden_navigator():
    p = PMDParams(model="MC2100", integration_limit=100_000, bias=-1)
    assert host_commands_to_text(to_host_commands(p)).splitlines() == [
        "0x25 SetKp axis=1 data=0x0064",
        "0x26 SetKi axis=1 data=0x0050",
        "0x27 SetKd axis=1 data=0x0190",
        "0x2B SetKvff axis=1 data=0x0000",
        "0x93 SetKaff axis=1 data=0x0000",
        "0x95 SetIntegrationLimit axis=1 data=0x0001 0x86A0",
        "0x9C SetDerivativeTime axis=1 data=0x000A",
        "0x9E SetKout axis=1 data=0x3333",
        "0x0F SetMotorBias axis=1 data=0xFFFF",
        "0x06 SetMotorLimit axis=1 data=0x7FFF",
        "0x97 SetPositionErrorLimit axis=1 data=0x0000 0x7FFF",
        "0x38 SetSampleTime axis=1 data=0x009A",
        "0x1A Update axis=1",
    ]


def test_host_golden_words():
    cmds = to_host_commands(PMDParams(model="MC2100", integration_limit=100_000), axis=2)
    ilim = next(c for c in cmds if c.name == "SetIntegrationLimit")
    assert ilim == HostCommand(0x95, "SetIntegrationLimit", 2, (0x0001, 0x86A0))
    assert ilim.words == (0x0195, 0x0001, 0x86A0)  # axis - 1 in the high byte
    assert cmds[-1].words == (0x011A,)


def test_host_golden_magellan():
    p = PMDParams(model="MC58000", integration_limit=100_000, biquad1_b1=-2, sample_time_us=100)
    lines = host_commands_to_text(to_host_commands(p)).splitlines()
    assert lines[0] == "0x67 SetPositionLoop axis=1 data=0x0000 0x0000 0x0064"
    assert "0x67 SetPositionLoop axis=1 data=0x0002 0x0001 0x86A0" in lines
    assert "0x67 SetPositionLoop axis=1 data=0x000A 0xFFFF 0xFFFE" in lines
    assert "0x3B SetSampleTime axis=1 data=0x0000 0x0064" in lines
    assert lines[-1] == "0x1A Update axis=1"


def test_json_golden_layout():
    doc = json.loads(to_json(PMDParams.default("MC3110"), created=CREATED))
    assert list(doc) == [
        "format",
        "format_version",
        "chip_family",
        "chip_model",
        "sample_time_us",
        "spec_version",
        "assumptions",
        "params",
        "created",
        "servogym_version",
        "checksum",
    ]
    assert doc["params"] == {"model": "MC3110", **space_of("MC3110").defaults()}
    assert doc["assumptions"] == PMDAssumptions().to_dict()


def test_json_created_default_and_datetime():
    doc = json.loads(to_json(PMDParams(), created=dt.datetime(2025, 1, 2, 3, 4, 5)))
    assert doc["created"] == "2025-01-02T03:04:05"
    now = dt.datetime.fromisoformat(json.loads(to_json(PMDParams()))["created"])
    assert now.tzinfo is not None


# --- refusals on export -----------------------------------------------------------------------


@pytest.mark.parametrize("fmt", FORMATS)
def test_export_refuses_illegal_dict(fmt):
    with pytest.raises(ParameterError, match=r"0 <= kp <= 32767.*got kp=40000"):
        export({"model": "MC2100", "kp": 40000}, fmt)
    with pytest.raises(ParameterError, match=r"-32768 <= bias <= 32767"):
        export({"model": "MC58000", "bias": 40000}, fmt)
    with pytest.raises(ParameterError, match=r"biquad1_enable exists only on models"):
        export({"model": "MC2300", "biquad1_enable": 1}, fmt)


@pytest.mark.parametrize("fmt", FORMATS)
def test_export_refuses_tampered_params(fmt):
    p = PMDParams()
    object.__setattr__(p, "integration_limit", 2**31)  # bypasses validation
    with pytest.raises(ParameterError, match=r"0 <= integration_limit <= 2147483647"):
        export(p, fmt)


def test_export_refuses_bad_axis_and_format():
    with pytest.raises(ParameterError, match=r"1 <= axis <= 1 \(MC3110 has 1 axis\); got axis=2"):
        to_cmotion(PMDParams(model="MC3110"), axis=2)
    with pytest.raises(ParameterError, match=r"1 <= axis <= 4.*got axis=0"):
        to_host_commands(PMDParams(), axis=0)
    with pytest.raises(ParameterError, match=r"'json' \(\.json\), 'cmotion' \(\.c\), 'host'"):
        export(PMDParams(), "xml")
    with pytest.raises(ParameterError, match=r"Did you mean 'cmotion'"):
        import_params("", "c-motion")


def test_export_refuses_bad_metrics():
    with pytest.raises(ParameterError, match="metrics must hold only JSON values"):
        to_json(PMDParams(), metrics={"ise": float("nan")})
    with pytest.raises(ParameterError, match="notes must be a mapping"):
        to_json(PMDParams(), notes="tuned by hand")
    with pytest.raises(ParameterError, match="created must be an ISO 8601"):
        to_json(PMDParams(), created="yesterday")
    with pytest.raises(
        ParameterError, match=r"unknown assumption 'roundng'.*Did you mean rounding"
    ):
        to_json(PMDParams(), {"roundng": "trunc"})


# --- refusals on import: JSON -------------------------------------------------------------


def _doc(**changes) -> str:
    doc = json.loads(to_json(PMDParams(model="MC2300"), created=CREATED))
    del doc["checksum"]  # edited below: read as a hand-written file
    doc.update(changes)
    return json.dumps(doc)


def test_json_rejects_wrong_format_version_family():
    with pytest.raises(ParameterError, match=r"format must be 'servogym-params'.*got format="):
        from_json(_doc(format="other"))
    with pytest.raises(ParameterError, match=r"format_version must be 1.*got format_version=2"):
        from_json(_doc(format_version=2))
    with pytest.raises(ParameterError, match=r"got format_version=True"):
        from_json(_doc(format_version=True))
    with pytest.raises(ParameterError, match=r"chip_family must be 'pmd'.*'delta_tau'"):
        from_json(_doc(chip_family="delta_tau"))
    with pytest.raises(ParameterError, match="must be JSON; invalid JSON at line 1"):
        from_json("{not json")


def test_json_rejects_inconsistent_or_incomplete_files():
    base = json.loads(_doc())
    with pytest.raises(ParameterError, match="unknown keys 'extra'"):
        from_json(_doc(extra=1))
    del base["created"]
    with pytest.raises(ParameterError, match="misses the keys created"):
        from_json(json.dumps(base))
    with pytest.raises(ParameterError, match=r"params.model must equal chip_model 'MC2100'"):
        from_json(_doc(chip_model="MC2100"))
    with pytest.raises(ParameterError, match=r"sample_time_us must equal params.sample_time_us"):
        from_json(_doc(sample_time_us=200))
    params = json.loads(_doc())["params"]
    with pytest.raises(ParameterError, match=r"0 <= kd <= 32767.*got kd=-1"):
        from_json(_doc(params={**params, "kd": -1}))
    with pytest.raises(ParameterError, match=r"kd must be an integer.*got kd=1.5"):
        from_json(_doc(params={**params, "kd": 1.5}))
    with pytest.raises(ParameterError, match=r"takes no defaults.*missing kd"):
        from_json(_doc(params={k: v for k, v in params.items() if k != "kd"}))
    with pytest.raises(ParameterError, match="MC2300 has no parameter 'kpp'"):
        from_json(_doc(params={**params, "kpp": 1}))
    asm = PMDAssumptions().to_dict()
    del asm["rounding"]
    with pytest.raises(ParameterError, match=r"every assumption.*missing rounding"):
        from_json(_doc(assumptions=asm))
    with pytest.raises(ParameterError, match="PMD-A1 rounding must be one of"):
        from_json(_doc(assumptions={**PMDAssumptions().to_dict(), "rounding": "up"}))
    with pytest.raises(ParameterError, match="disagrees with the file's chip_model 'MC2300'"):
        import_params(_doc(), "json", model="MC2100")


def test_json_warns_on_other_spec_version():
    with pytest.warns(UserWarning, match="spec_version 'pmd-spec-0'"):
        f = from_json(_doc(spec_version="pmd-spec-0"))
    assert f.params == PMDParams(model="MC2300")
    assert f.provenance["spec_version"] == "pmd-spec-0"


# --- refusals on import: C-Motion -----------------------------------------------------------


def _with_line(text: str, after: str, new: str) -> tuple[str, int]:
    lines = text.splitlines()
    i = lines.index(after) + 1
    lines.insert(i, new)
    return "\n".join(lines) + "\n", i + 1


def test_cmotion_rejects_unknown_call_naming_the_line():
    text, n = _with_line(
        to_cmotion(PMDParams()), "PMDSetKd(&hAxis1, 400);", "PMDSetKq(&hAxis1, 3);"
    )
    with pytest.raises(ParameterError, match=rf"line {n}: unknown C-Motion call PMDSetKq\(\)"):
        from_cmotion(text)
    text, n = _with_line(
        to_cmotion(PMDParams()), "PMDSetKd(&hAxis1, 400);", "PMDSetPositionLoop(&hAxis1, 0, 3);"
    )
    with pytest.raises(
        ParameterError, match=rf"line {n}: unknown C-Motion call PMDSetPositionLoop"
    ):
        from_cmotion(text)


def test_cmotion_rejects_bad_statements():
    good = to_cmotion(PMDParams())
    bad = good.replace("PMDSetKd(&hAxis1, 400);", "PMDSetKd(&hAxis1, 40000);")
    with pytest.raises(
        ParameterError, match=r"line \d+: kd must satisfy 0 <= kd <= 32767 .*got kd=40000"
    ):
        from_cmotion(bad)
    with pytest.raises(ParameterError, match=r"octal literal"):
        from_cmotion(good.replace("PMDSetKd(&hAxis1, 400);", "PMDSetKd(&hAxis1, 0400);"))
    with pytest.raises(ParameterError, match=r"must be an integer literal.*'kd_value'"):
        from_cmotion(good.replace("PMDSetKd(&hAxis1, 400);", "PMDSetKd(&hAxis1, kd_value);"))
    with pytest.raises(ParameterError, match=r"PMDSetKd takes 2 arguments"):
        from_cmotion(good.replace("PMDSetKd(&hAxis1, 400);", "PMDSetKd(400);"))
    with pytest.raises(ParameterError, match=r"addresses &hAxis2 but line \d+ addresses &hAxis1"):
        from_cmotion(good.replace("PMDSetKd(&hAxis1, 400);", "PMDSetKd(&hAxis2, 400);"))
    with pytest.raises(ParameterError, match=r"kd is set a second time \(first at line \d+\)"):
        from_cmotion(
            good.replace("PMDSetKd(&hAxis1, 400);", "PMDSetKd(&hAxis1, 1); PMDSetKd(&hAxis1, 2);")
        )
    with pytest.raises(ParameterError, match=r"takes no defaults.*kd \(PMDSetKd\)"):
        from_cmotion(good.replace("PMDSetKd(&hAxis1, 400);", ""))
    with pytest.raises(ParameterError, match=r"does not end with ';'"):
        from_cmotion(good.replace("PMDUpdate(&hAxis1);", "PMDUpdate(&hAxis1)"))
    with pytest.raises(ParameterError, match=r"cannot read 'kp = 5'"):
        from_cmotion(good.replace("PMDUpdate(&hAxis1);", "kp = 5;"))


def test_cmotion_model_from_header_or_argument():
    text = to_cmotion(PMDParams(model="MC2800"))
    body = "\n".join(line for line in text.splitlines() if line.startswith("PMD"))
    with pytest.raises(ParameterError, match=r"names no chip model.*pass model="):
        from_cmotion(body)
    assert from_cmotion(body, model="MC2800") == PMDParams(model="MC2800")
    with pytest.raises(ParameterError, match=r"model='MC2100' disagrees.*chip_model: MC2800"):
        from_cmotion(text, model="MC2100")
    # A Navigator snippet read as a Magellan one fails on the first Navigator call.
    with pytest.raises(ParameterError, match=r"line 1: unknown C-Motion call PMDSetKp\(\)"):
        from_cmotion(body, model="MC58000")


def test_cmotion_tolerates_whitespace_comments_and_hand_edits():
    text = """
    #include "C-Motion.h"
    // hand-written for the MC58000 bench, axis 2
    PMDSetPositionLoop( phAxis , 0 , 0x64 ) ;   /* Kp */
    PMDSetPositionLoop(phAxis, PMDPositionLoopKi, 80); PMDSetPositionLoop(phAxis,
        PMDPositionLoopIlimit, 10000);
    PMDSetPositionLoop(phAxis, 3, 400);  PMDSetPositionLoop(phAxis, 4, 10);
    PMDSetPositionLoop(phAxis, 5, 13107); PMDSetPositionLoop(phAxis, 6, 0);
    PMDSetPositionLoop(phAxis, 7, 0);
    """
    text += "".join(
        f"PMDSetPositionLoop(phAxis, {n}, {v});\n"
        for n, v in zip(range(8, 22), [0, 16384, 0, 0, 0, 0, 16384] * 2, strict=True)
    )
    text += "PMDSetMotorBias(phAxis, -0x10);\nPMDSetMotorLimit(phAxis, 32767U);\n"
    text += "PMDSetPositionErrorLimit(phAxis, 32767);\nPMDSetSampleTime(phAxis, 52);\n"
    assert from_cmotion(text, model="MC58000") == PMDParams(model="MC58000", bias=-16)


# --- refusals on import: host commands ---------------------------------------------------------


def test_host_text_rejects_bad_lines_naming_the_line():
    good = to_host_text(PMDParams())
    lines = good.splitlines()
    n = lines.index("0x27 SetKd axis=1 data=0x0190") + 1
    cases = [
        ("0x28 SetKd axis=1 data=0x0190", r"SetKd has opcode 0x27 on MC2100.*got opcode 0x28"),
        ("0x27 SetKdd axis=1 data=0x0190", r"unknown command SetKdd \(0x27\).*Did you mean SetKd"),
        ("0x27 SetKd axis=1 data=0x0000 0x0190", r"SetKd takes 1 data word; got 2"),
        ("0x27 SetKd axis=2 data=0x0190", r"SetKd addresses axis=2 but line \d+ addresses axis=1"),
        (
            "0x27 SetKd axis=1 data=0x8000",
            r"kd must satisfy 0 <= kd <= 32767 .*\(MC2100\); got kd=32768",
        ),
        (
            "0x27 SetKd axis=1 data=0x10000",
            r"data words must be 16-bit hex such as 0x0064; got '0x10000'",
        ),
        ("SetKd 400", r"cannot read 'SetKd 400'"),
    ]
    for new, message in cases:
        bad = "\n".join([*lines[: n - 1], new, *lines[n:]])
        with pytest.raises(ParameterError, match=rf"line {n}: {message}"):
            from_host_text(bad)


def test_host_import_model_rules():
    cmds = to_host_commands(PMDParams(model="MC3310"))
    bare = host_commands_to_text(cmds)
    with pytest.raises(ParameterError, match="names no chip model"):
        from_host_text(bare)
    # Magellan takes the filter through SetPositionLoop, not SetKp ...
    with pytest.raises(ParameterError, match=r"unknown command SetKp"):
        from_host_commands(cmds, "MC58000")
    # ... and SetSampleTime is 0x3B there, not the Navigator's 0x38.
    mag = to_host_commands(PMDParams(model="MC58000"))
    nav_time = dataclasses.replace(mag[-2], opcode=0x38)
    with pytest.raises(ParameterError, match=r"command 25: SetSampleTime has opcode 0x3B"):
        from_host_commands([*mag[:-2], nav_time, mag[-1]], "MC58000")
    with pytest.raises(ParameterError, match=r"1 <= axis <= 1 \(MC3110 has 1 axis\); got axis=2"):
        from_host_commands(to_host_commands(PMDParams(model="MC2100"), axis=2), "MC3110")
    with pytest.raises(
        ParameterError, match=r"takes no defaults.*kp \(SetPositionLoop parameter 0\)"
    ):
        from_host_commands(mag[1:], "MC58000")
    with pytest.raises(ParameterError, match="contains no commands"):
        from_host_commands([], "MC2100")


def test_host_command_validates_fields():
    with pytest.raises(ParameterError, match=r"0 <= word <= 0xFFFF; got data\[1\]=70000"):
        HostCommand(0x95, "SetIntegrationLimit", 1, (1, 70000))
    with pytest.raises(ParameterError, match=r"1 <= axis <= 4; got axis=5"):
        HostCommand(0x25, "SetKp", 5, (1,))
    with pytest.raises(ParameterError, match=r"0 <= opcode <= 255; got opcode=256"):
        HostCommand(0x100, "SetKp", 1, (1,))
