"""PMAC export/import: JSON and I-variable files round-trip; a controller's file; refusals."""

from __future__ import annotations

import json
from fractions import Fraction

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from servogym.chips import ParameterError
from servogym.chips.pmac import (
    ASSUMPTION_CHOICES,
    CHIP_MODELS,
    FIELDS,
    SPEC_VERSION,
    PMACAssumptions,
    PMACParams,
    export,
    from_ivar,
    from_json,
    import_params,
    ivar_name,
    parameter_space,
    read_header,
    to_ivar,
    to_json,
)
from servogym.chips.pmac._export import FILE_EXTENSIONS, FORMATS, coefficient_text

MODELS = sorted(CHIP_MODELS)
CREATED = "2025-01-31T12:00:00+00:00"


@st.composite
def legal_params(draw: st.DrawFn, model: str) -> PMACParams:
    """A legal set: every register drawn from the model's own parameter_space range."""
    values = {
        name: draw(st.integers(spec.low, spec.high), label=name)
        for name, spec in parameter_space(model).items()
    }
    return PMACParams(model=model, **values)


assumption_sets = st.builds(
    PMACAssumptions, **{name: st.sampled_from(c) for name, c in ASSUMPTION_CHOICES.items()}
)


# --- round trips ---------------------------------------------------------------------------


@pytest.mark.parametrize("model", MODELS)
@settings(max_examples=40, deadline=None)
@given(data=st.data())
def test_ivar_round_trip_any_motor(model, data):
    p = data.draw(legal_params(model))
    a = data.draw(assumption_sets)
    motor = data.draw(st.integers(1, 32), label="motor")
    text = export(p, "ivar", motor=motor, assumptions=a)
    assert import_params(text, "ivar") == p  # model and motor from the header
    assert import_params(text, "ivar", model=model, motor=motor) == p
    head = read_header(text)
    assert head["chip_model"] == model and int(head["motor"]) == motor
    assert head["spec_version"] == SPEC_VERSION and head["assumptions"] == a
    # Without the header (as a controller would have it), given model and motor.
    bare = "\n".join(line for line in text.splitlines() if not line.startswith(";"))
    assert from_ivar(bare, model, motor) == p
    # Every register on its own line under its own I-variable.
    lines = [line for line in text.splitlines() if line.startswith("I")]
    assert [line.split("=")[0] for line in lines] == [ivar_name(f, motor) for f in FIELDS]


@pytest.mark.parametrize("model", MODELS)
@settings(max_examples=20, deadline=None)
@given(data=st.data())
def test_json_round_trip_keeps_assumptions_and_provenance(model, data):
    p = data.draw(legal_params(model))
    a = data.draw(assumption_sets)
    notes = {"plant": "rotary", "seed": 3}
    text = to_json(p, a, metrics={"ise": 12.5}, notes=notes, created=CREATED)
    f = from_json(text)
    assert f.params == p and f.assumptions == a
    assert import_params(text, "json") == p
    assert f.provenance == {
        "format": "servogym-params",
        "format_version": 1,
        "chip_family": "pmac",
        "chip_model": model,
        "sample_time_s": p.sample_time_s,
        "spec_version": SPEC_VERSION,
        "created": CREATED,
        "servogym_version": f.provenance["servogym_version"],
        "metrics": {"ise": 12.5},
        "notes": notes,
    }


@settings(max_examples=300, deadline=None)
@given(st.integers(-(2**23), 2**23 - 1))
def test_coefficient_text_is_exact(raw):
    text = coefficient_text(raw)
    assert Fraction(text) * 2**22 == raw
    assert len(text.split(".")[-1]) <= 22


def test_formats_and_extensions():
    assert FORMATS == ("json", "ivar")
    assert FILE_EXTENSIONS == {"json": ".json", "ivar": ".pmc"}


# --- golden lines ------------------------------------------------------------------------------


def test_ivar_golden_defaults_motor_1():
    lines = to_ivar(PMACParams()).splitlines()
    body = [line for line in lines if not line.startswith(";")]
    assert body == [
        "I108=96 ; position_loop_scale",
        "I109=96 ; velocity_loop_scale",
        "I111=32000 ; fatal_following_error_limit",
        "I129=0 ; output_bias",
        "I130=2000 ; proportional_gain",
        "I131=1280 ; derivative_gain",
        "I132=1280 ; velocity_ff",
        "I133=0 ; integral_gain",
        "I134=1 ; integration_mode",
        "I135=0 ; acceleration_ff",
        "I136=0 ; notch_n1",
        "I137=0 ; notch_n2",
        "I138=0 ; notch_d1",
        "I139=0 ; notch_d2",
        "I160=0 ; servo_cycle_extension",
        "I163=4194304 ; integration_limit",
        "I164=0 ; deadband_gain",
        "I165=16 ; deadband_size",
        "I167=4194304 ; big_step_limit",
        "I168=0 ; friction_ff",
        "I169=20480 ; output_limit",
        "I7000=6527 ; max_phase_frequency_control",
        "I7001=0 ; phase_clock_divider",
        "I7002=3 ; servo_clock_divider",
    ]
    assert "; chip_model: TurboPMAC2" in lines
    assert "; motor: 1" in lines
    assert "; sample_time_us: 442.742242" in lines
    assert "; assumption PMAC-A1 rounding: floor" in lines


def test_ivar_golden_motor_10_and_coefficients():
    p = PMACParams(notch_n1=-(2**23), notch_n2=3 * 2**20, notch_d1=1, notch_d2=-(2**21))
    lines = to_ivar(p, motor=10).splitlines()
    assert "I1030=2000 ; proportional_gain" in lines
    assert "I1036=-2 ; notch_n1" in lines
    assert "I1037=0.75 ; notch_n2" in lines
    assert "I1038=0.0000002384185791015625 ; notch_d1" in lines
    assert "I1039=-0.5 ; notch_d2" in lines
    assert "I7000=6527 ; max_phase_frequency_control" in lines


# --- a file saved by the controller ---------------------------------------------------------

CONTROLLER_FILE = """\
; Turbo PMAC2 backup, saved by the Executive
CLOSE
END GATHER
DELETE GATHER
I0=0 I1=0 I2=0
I100=1 I101=0 I102=$078002
I103=$3501 I104=$3501
I108=96
I109=96
I111=32000
I129=0
I130=2000 I131=1280 I132=1280 I133=0 I134=1 I135=0
I136..139=0
I160=0 I163=4194304 I164=0 I165=16 I167=4194304 I168=0 I169=20480
I200=1
I208=32 ; motor 2 has its own scale
I209=$60
I211=16000
I229=-120
i230 = 45000
I231=2500 I232=2700
I233=50000
I234=0
I235=150
I236=-1.8607254028320312 I237=0.875
I238=-1.5 I239=.5625
I260=1
I263=-200000
I264=-16
I265=32
I267=800000
I268=90
I269=$5000
I7000=6527
I7001=0
I7002=3
I7100=6527 I7101=0 I7102=3
M201->Y:$0000C0,11,1
M230->X:$0000B6,0,24,S
P1=I230 P2=5 Q10=-1.5
M130=0
#2j/
OPEN PLC 1 CLEAR
I230=I230+1
I7002=7
CLOSE
"""


def test_controller_saved_file_imports_the_chosen_motor():
    p = from_ivar(CONTROLLER_FILE, "GeoBrickLV", motor=2)
    assert p == PMACParams(
        model="GeoBrickLV",
        position_loop_scale=32,
        velocity_loop_scale=0x60,
        fatal_following_error_limit=16000,
        output_bias=-120,
        proportional_gain=45000,
        derivative_gain=2500,
        velocity_ff=2700,
        integral_gain=50000,
        integration_mode=0,
        acceleration_ff=150,
        notch_n1=-7804448,  # -1.8607254028320312 * 2^22 = -7804447.99999..., nearest word
        notch_n2=7 * 2**19,
        notch_d1=-3 * 2**21,
        notch_d2=9 * 2**18,
        servo_cycle_extension=1,
        integration_limit=-200000,
        deadband_gain=-16,
        deadband_size=32,
        big_step_limit=800000,
        friction_ff=90,
        output_limit=0x5000,
    )
    assert from_ivar(CONTROLLER_FILE, "TurboPMAC2", motor=1) == PMACParams()
    # Saved again and read back: the identical set.
    assert from_ivar(to_ivar(p, motor=7)) == p


def test_controller_file_needs_model_and_motor():
    with pytest.raises(ParameterError, match=r"names no chip model.*pass model="):
        from_ivar(CONTROLLER_FILE)
    with pytest.raises(ParameterError, match="sets registers of motors 1, 2; pass motor="):
        from_ivar(CONTROLLER_FILE, "TurboPMAC2")
    with pytest.raises(ParameterError, match=r"does not set every register of motor 3.*I330"):
        from_ivar(CONTROLLER_FILE, "TurboPMAC2", motor=3)


def _hand_written(text: str) -> str:
    """An exported file as a hand-edited copy: title line and end line removed."""
    return "".join(
        line + "\n"
        for line in text.splitlines()
        if "parameter set" not in line and "servogym-end" not in line
    )


@pytest.mark.parametrize("token", ["-1.86", "1e-9", "0.0000001", "1.5e-7", "-1.8607255"])
def test_coefficient_that_names_no_single_word_is_refused(token):
    text = _hand_written(to_ivar(PMACParams())).replace("I136=0 ", f"I136={token} ")
    with pytest.raises(
        ParameterError, match=rf"notch_n1 \(Ixx36\) holds multiples of 2\^-22; got {token}"
    ):
        from_ivar(text)


@pytest.mark.parametrize(
    ("token", "word"),
    [("-1.86072540283203125", -7804448), ("-1.8607254028320312", -7804448),
     ("-1.8607254", -7804448), ("0.5", 2**21), ("5e-1", 2**21), ("2.384185791015625e-7", 1)],
)  # fmt: skip
def test_coefficient_exact_or_printed_to_a_unique_word_is_read(token, word):
    text = _hand_written(to_ivar(PMACParams())).replace("I136=0 ", f"I136={token} ")
    assert from_ivar(text).notch_n1 == word


# --- refusals on export ------------------------------------------------------------------------


@pytest.mark.parametrize("fmt", FORMATS)
def test_export_refuses_illegal_sets(fmt):
    with pytest.raises(ParameterError, match=r"-8388608 <= proportional_gain <= 8388607.*9000000"):
        export({"model": "TurboPMAC2", "proportional_gain": 9_000_000}, fmt)
    with pytest.raises(ParameterError, match=r"0 <= output_limit <= 32767"):
        export({"model": "GeoBrickLV", "output_limit": 40000}, fmt)
    p = PMACParams()
    object.__setattr__(p, "notch_d1", 2**23)  # bypasses validation: 2.0 does not fit
    with pytest.raises(ParameterError, match=r"-8388608 <= notch_d1 <= 8388607.*notch_d1=8388608"):
        export(p, fmt)


def test_export_refuses_bad_motor_and_format():
    with pytest.raises(ParameterError, match=r"1 <= motor <= 32 \(TurboPMAC2.*got motor=33"):
        to_ivar(PMACParams(), motor=33)
    with pytest.raises(ParameterError, match=r"motor must be an integer.*got motor=True"):
        to_ivar(PMACParams(), motor=True)
    with pytest.raises(ParameterError, match=r"'json' \(\.json\), 'ivar' \(\.pmc\).*Did you"):
        export(PMACParams(), "ivars")
    # The CLI's axis= is the motor.
    assert export(PMACParams(), "ivar", axis=4) == to_ivar(PMACParams(), motor=4)
    with pytest.raises(ParameterError, match="axis and motor name the same thing"):
        export(PMACParams(), "ivar", axis=4, motor=5)


# --- refusals on import ------------------------------------------------------------------------


def _edit(old: str, new: str) -> str:
    text = to_ivar(PMACParams())
    assert old in text
    return text.replace(old, new)


@pytest.mark.parametrize(
    ("text", "match"),
    [
        (_edit("I130=2000", "I130=9000000"), r"line \d+: .*-8388608 <= proportional_gain"),
        (_edit("I169=20480", "I169=-1"), r"0 <= output_limit <= 32767.*got output_limit=-1"),
        (_edit("I130=2000", "I130=2000.5"), "proportional_gain must be an integer"),
        (_edit("I130=2000", "I130=P1"), "must be assigned a constant"),
        (_edit("I136=0", "I136=$10"), "must be a decimal coefficient"),
        (_edit("I136=0", "I136=2.5"), r"-8388608 <= notch_n1 <= 8388607"),
        (_edit("I131=1280", "I131=1280 I131=1281"), "I131 .derivative_gain. is set to 1281"),
        (_edit("I7002=3", "I7003=3"), r"Missing: I7002 \(servo_clock_divider\)"),
        (_edit("; motor: 1", "; motor: one"), "is not a motor number"),
    ],
)
def test_ivar_import_refusals(text, match):
    with pytest.raises(ParameterError, match=match):
        from_ivar(text)


def test_ivar_import_model_disagreement_and_duplicates_that_agree():
    text = to_ivar(PMACParams(model="GeoBrickLV"))
    with pytest.raises(
        ParameterError, match=r"disagrees with the header's 'chip_model: GeoBrickLV' \(I-variable"
    ):
        from_ivar(text, "TurboPMAC2")
    with pytest.raises(ParameterError, match=r"end line .* is not the last line"):
        from_ivar(text + "I130=2000\n")
    assert from_ivar(_hand_written(text) + "I130=2000\n") == PMACParams(model="GeoBrickLV")


def _doc(**changes) -> str:
    doc = json.loads(to_json(PMACParams(model="GeoBrickLV"), created=CREATED))
    del doc["checksum"]  # edited below: read as a hand-written file
    doc.update(changes)
    return json.dumps(doc)


def test_json_refusals():
    with pytest.raises(ParameterError, match=r"chip_family must be 'pmac'.*'pmd'"):
        from_json(_doc(chip_family="pmd"))
    with pytest.raises(ParameterError, match="sample_time_s must equal"):
        from_json(_doc(sample_time_s=1e-3))
    params = json.loads(_doc())["params"]
    with pytest.raises(ParameterError, match=r"0 <= integral_gain <= 8388607.*integral_gain=-1"):
        from_json(_doc(params={**params, "integral_gain": -1}))
    with pytest.raises(ParameterError, match=r"takes no defaults.*missing notch_n1"):
        from_json(_doc(params={k: v for k, v in params.items() if k != "notch_n1"}))
    with pytest.raises(ParameterError, match="PMAC-A2 integral_timing must be one of"):
        from_json(_doc(assumptions={**PMACAssumptions().to_dict(), "integral_timing": "x"}))
    with pytest.raises(ParameterError, match=r"every assumption.*missing first_cycle"):
        asm = PMACAssumptions().to_dict()
        del asm["first_cycle"]
        from_json(_doc(assumptions=asm))
    with pytest.raises(ParameterError, match="disagrees with the file's chip_model 'GeoBrickLV'"):
        import_params(_doc(), "json", model="TurboPMAC2")
    with pytest.raises(ParameterError, match="motor= applies to fmt='ivar' only"):
        import_params(_doc(), "json", motor=1)
    with pytest.warns(UserWarning, match="spec_version 'pmac-spec-0'"):
        assert from_json(_doc(spec_version="pmac-spec-0")).params == PMACParams(model="GeoBrickLV")
