"""Parker 6000 export/import: command files (both forms) and JSON round-trip; golden lines."""

from __future__ import annotations

import json

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from servogym.chips import ParameterError
from servogym.chips.parker6k import (
    CHIP_MODELS,
    FORMATS,
    GAIN_FIELDS,
    MAX_GAIN_SETS,
    PARKER6K,
    SPEC_VERSION,
    GainSet,
    Parker6kAssumptions,
    Parker6kParams,
    export,
    from_command_file,
    from_json,
    import_params,
    parameter_space,
    read_header,
    to_command_file,
    to_json,
)
from servogym.chips.parker6k._export import parse_decimal
from servogym.chips.parker6k._params import ASSUMPTION_CHOICES, DECIMALS, GAIN_MAX, format_decimal

CREATED = "2025-01-31T12:00:00+00:00"
FORMS = [("6250", "6250"), ("6K", "6250"), ("6K", "6k")]


@st.composite
def legal_params(draw, model):
    space = parameter_space(model)
    values = {
        name: draw(st.integers(spec.low, spec.high), label=name)
        for name, spec in space.items()
        if name != "ssfr"
    }
    values["ssfr"] = draw(st.sampled_from([1, 2, 4, 8]))
    gain = st.integers(0, GAIN_MAX)
    n_sets = draw(st.integers(0, MAX_GAIN_SETS), label="n_sets")
    sets = [GainSet(**{g: draw(gain) for g in GAIN_FIELDS}) for _ in range(n_sets)]
    schedule = []
    if n_sets:
        ticks = sorted(draw(st.sets(st.integers(0, 2**31 - 1), max_size=6)))
        schedule = [(t, draw(st.integers(1, n_sets))) for t in ticks]
    return Parker6kParams(model=model, **values, sgset=sets, sgenb=schedule)


assumption_sets = st.builds(
    Parker6kAssumptions, **{name: st.sampled_from(c) for name, c in ASSUMPTION_CHOICES.items()}
)


# --- round trips ---------------------------------------------------------------------------


@pytest.mark.parametrize(("model", "fmt"), FORMS)
@settings(max_examples=40, deadline=None)
@given(data=st.data())
def test_command_file_round_trip(model, fmt, data):
    p = data.draw(legal_params(model))
    a = data.draw(assumption_sets)
    axis = data.draw(st.integers(1, CHIP_MODELS[model].n_axes), label="axis")
    text = export(p, fmt, axis=axis, assumptions=a)
    assert import_params(text, fmt) == p  # model and axis come from the header
    assert import_params(text, fmt, model=model, axis=axis) == p
    head = read_header(text)
    assert head["chip_model"] == model and head["spec_version"] == SPEC_VERSION
    assert int(head["axis"]) == axis and int(head["sample_time_us"]) == p.sample_time_us
    assert head["assumptions"] == a
    # One SGSET line per stored set, numbered from 1.
    sgset = [line for line in text.splitlines() if "SGSET" in line and not line.startswith(";")]
    assert sgset == [f"SGSET{i}" for i in range(1, len(p.sgset) + 1)]
    # Without the header the commands alone still give the set (the schedule is in comments).
    bare = "\n".join(line for line in text.splitlines() if not line.startswith(";"))
    assert from_command_file(bare, fmt, model=model, axis=axis) == p.replace(sgenb=())


@pytest.mark.parametrize("model", sorted(CHIP_MODELS))
@settings(max_examples=25, deadline=None)
@given(data=st.data())
def test_json_round_trip_keeps_assumptions_and_provenance(model, data):
    p = data.draw(legal_params(model))
    a = data.draw(assumption_sets)
    f = from_json(to_json(p, a, metrics={"ise": 1.5}, notes={"seed": 3}, created=CREATED))
    assert f.params == p and f.assumptions == a
    assert f.provenance["chip_family"] == "parker6k"
    assert f.provenance["sample_time_us"] == p.sample_time_us
    assert f.provenance["metrics"] == {"ise": 1.5} and f.provenance["created"] == CREATED
    assert import_params(export(p, "json", axis=2, created=CREATED), "json") == p
    assert PARKER6K.from_json(to_json(p)).params == p


@settings(max_examples=200, deadline=None)
@given(register=st.sampled_from(sorted(DECIMALS)), value=st.integers(-(10**8), 10**8))
def test_decimal_text_round_trips(register, value):
    assert parse_decimal(format_decimal(value, DECIMALS[register]), register) == value


def test_formats():
    assert FORMATS == ("json", "6250", "6k") == PARKER6K.formats


# --- golden lines -----------------------------------------------------------------------------


def test_golden_6250_axis_2():
    p = Parker6kParams(
        sgp=50,
        sgv=230,
        sgaf=12345,
        sgilim=2500,
        soffs=-250,
        smper=4000,
        ssfr=2,
        sgset=[GainSet(sgp=8500, sgi=1, sgv=0, sgvf=100, sgaf=1)],
        sgenb=[(640, 1)],
    )
    lines = to_command_file(p, "6250", axis=2).splitlines()
    assert "; sgenb tick=640 set=1" in lines and "; chip_model: 6250" in lines
    assert [line for line in lines if not line.startswith(";")] == [
        "SSFR2",
        "SGP,85",
        "SGI,.01",
        "SGV,0",
        "SGVF,1",
        "SGAF,.0001",
        "SGSET1",
        "SGP,.5",
        "SGI,0",
        "SGV,2.3",
        "SGVF,0",
        "SGAF,1.2345",
        "SGILIM,2.5",
        "SOFFS,-.25",
        "SMPER,4000",
    ]


def test_golden_6k_axis_prefix():
    body = [
        line
        for line in to_command_file(Parker6kParams(model="6K"), "6k", axis=3).splitlines()
        if not line.startswith(";")
    ]
    assert body == [
        "SSFR4",
        "3SGP85",
        "3SGI0",
        "3SGV2.3",
        "3SGVF0",
        "3SGAF0",
        "3SGILIM10",
        "3SOFFS0",
        "3SMPER0",
    ]


def test_hand_written_files_as_the_controller_reads_them():
    # Both axes in one line, ':' separators, lower case, spaces, SGENB, SGSET and overrides.
    text = """
    ssfr 8 : SGP.5,.5 : SGI 0,1 : SGV 2.3,2.30 : sgvf0,0 : SGAF 0,0   ; comment: ignored
    SGSET1
    SGP85,40.00 : SGI0,1 : SGV2.3,2.3 : SGVF0,0 : SGAF0,0
    SGSET2
    SGENB1,2
    SGILIM10,5 : SOFFS 0,-1.5 : SMPER 4000,0
    """
    one = from_command_file(text, "6250", model="6250", axis=1)
    two = from_command_file(text, "6250", model="6250", axis=2)
    stored1 = GainSet(sgp=50, sgi=0, sgv=230, sgvf=0, sgaf=0)
    assert one.sgset == (stored1, GainSet(sgp=8500, sgi=0, sgv=230, sgvf=0, sgaf=0))
    assert one.gains == stored1 and one.ssfr == 8 and one.smper == 4000  # SGENB1
    assert two.gains == GainSet(sgp=4000, sgi=100, sgv=230, sgvf=0, sgaf=0)  # SGENB2 on axis 2
    assert two.sgset[0].sgp == 50 and two.soffs == -1500 and two.sgilim == 5000
    # The 6K takes prefixed commands and comma fields; other axes' commands are skipped.
    text6k = "SSFR4\n2SGP1:1SGP2\nSGI0,0:SGV0,0:SGVF0,0:SGAF0,0:SGILIM1,1:SOFFS0,0:SMPER0,0"
    assert from_command_file(text6k, "6k", model="6K", axis=1).sgp == 200
    assert from_command_file(text6k, "6k", model="6K", axis=2).sgp == 100
    assert from_command_file(text6k, "6k", model="6K", axis=2).sgilim == 1000


def test_trailing_zeros_beyond_resolution_are_accepted():
    assert parse_decimal("85.000", "sgp") == 8500
    assert parse_decimal("+2.3", "sgv") == 230
    assert parse_decimal("85.", "sgp") == 8500
    assert parse_decimal("-.25", "soffs") == -250
    assert parse_decimal("4000", "smper") == 4000


# --- refusals -----------------------------------------------------------------------------------

VALID = "SSFR4\nSGP85\nSGI0\nSGV2.3\nSGVF0\nSGAF0\nSGILIM10\nSOFFS0\nSMPER0\n"


@pytest.mark.parametrize(
    ("text", "match"),
    [
        (VALID.replace("SGP85", "SGP85.123"), r"line 2: SGP takes at most 2 decimals.*SGP85\.123"),
        (VALID.replace("SGAF0", "SGAF.00001"), r"line 6: SGAF takes at most 4 decimals"),
        (VALID.replace("SMPER0", "SMPER1.5"), r"line 9: SMPER takes at most 0 decimals"),
        (VALID.replace("SGP85", "SGP100000"), r"line 2: .*0 <= sgp <= 9999999.*sgp=10000000"),
        (VALID.replace("SGP85", "SGP-1"), r"line 2: .*0 <= sgp <= 9999999.*sgp=-100"),
        (VALID.replace("SOFFS0", "SOFFS10.001"), r"line 8: .*-10000 <= soffs <= 10000"),
        (VALID.replace("SGILIM10", "SGILIM-1"), r"line 7: .*0 <= sgilim <= 10000"),
        (VALID.replace("SSFR4", "SSFR3"), r"line 1: ssfr must be one of 1, 2, 4, 8"),
        (VALID.replace("SSFR4", "SSFR4,4"), r"line 1: SSFR is a controller-wide command"),
        (VALID.replace("SGP85", "SGP8x5"), r"line 2: SGP takes a decimal number"),
        (VALID.replace("SGP85", "SGQ85"), r"line 2: unknown command SGQ.*Did you mean .*SGP"),
        (VALID.replace("SGP85", "1SGP85"), r"line 2: the 6250 form takes comma-separated"),
        (VALID.replace("SGP85", "SGP85,1,1"), r"line 2: SGP has 3 axis fields but the 6250"),
        (VALID.replace("SGI0\n", ""), r"does not set SGI for axis 1; an import takes no defaults"),
        ("SGP1\nSGSET1\n" + VALID, r"line 2: SGSET1 stores the five gains.*SGI, SGV, SGVF"),
        (VALID + "SGSET6", r"1 <= set <= 5; got SGSET6"),
        (VALID + "SGSET1\n" + VALID + "SGSET3", r"numbered from 1 without gaps.*not SGSET2"),
        (VALID + "SGSET1\nSGP9\nSGSET2", r"line 12: SGSET2 .* does not set SGI, SGV, SGVF, SGAF"),
        (VALID + "SGENB2", r"SGENB2 enables gain set 2, which the file has not stored"),
        (VALID + "SGENB-1", r"SGENB takes a gain set number"),
        ("; sgenb tick=5 set=1\n" + VALID, r"sgenb\[0\] enables a stored gain set, but sgset"),
        ("; sgenb tick=x set=1\n" + VALID, r"line 1: a schedule line reads"),
        (": ; nothing\n" + VALID + "!!", r"cannot read '!!'"),
    ],
)
def test_import_refuses(text, match):
    with pytest.raises(ParameterError, match=match):
        from_command_file(text, "6250", model="6250")


def test_import_refuses_disagreements_and_forms():
    text = to_command_file(Parker6kParams(model="6K"), "6k", axis=2)
    with pytest.raises(ParameterError, match=r"model='6250' disagrees with the header"):
        from_command_file(text, "6k", model="6250")
    with pytest.raises(ParameterError, match=r"axis=1 disagrees with the header's 'axis: 2'"):
        from_command_file(text, "6k", axis=1)
    with pytest.raises(ParameterError, match=r"command file names no chip model"):
        from_command_file(VALID, "6250")
    with pytest.raises(ParameterError, match=r"the 6250 takes comma-separated axis fields"):
        from_command_file(VALID, "6k", model="6250")
    with pytest.raises(ParameterError, match=r"1 <= axis <= 8.*got 2SGP1|1 <= axis <= 8"):
        from_command_file("9SGP1", "6k", model="6K")
    with pytest.raises(ParameterError, match=r"SGSET is a controller-wide command"):
        from_command_file("1SGSET1", "6k", model="6K")
    with pytest.raises(ParameterError, match=r"1 <= axis <= 2.*got axis=3"):
        from_command_file(VALID, "6250", model="6250", axis=3)
    json_text = to_json(Parker6kParams(), created=CREATED)
    with pytest.raises(ParameterError, match=r"model='6K' disagrees with the file's chip_model"):
        import_params(json_text, "json", model="6K")


def test_export_refuses_illegal_sets_forms_and_axes():
    for fmt in FORMATS:
        model = "6K" if fmt == "6k" else "6250"
        with pytest.raises(ParameterError, match=r"0 <= sgp <= 9999999.*got sgp=10000000"):
            export({"model": model, "sgp": 10**7}, fmt)
        p = Parker6kParams(model=model)
        object.__setattr__(p, "soffs", 20_000)  # bypasses validation
        with pytest.raises(ParameterError, match=r"-10000 <= soffs <= 10000"):
            export(p, fmt)
    with pytest.raises(ParameterError, match=r"the 6250 takes comma-separated axis fields"):
        export(Parker6kParams(), "6k")
    with pytest.raises(ParameterError, match=r"1 <= axis <= 2 \(6250 has 2 axes\); got axis=3"):
        export(Parker6kParams(), "6250", axis=3)
    with pytest.raises(ParameterError, match=r"'json' \(\.json\), '6250' \(\.prg\), '6k'"):
        export(Parker6kParams(), "xml")
    with pytest.raises(ParameterError, match=r"Did you mean '6k'"):
        import_params("", "6kk")
    with pytest.raises(ParameterError, match=r"unknown assumption 'roundng'.*Did you mean"):
        to_json(Parker6kParams(), {"roundng": "trunc"})


def _doc(**changes) -> str:
    doc = json.loads(to_json(Parker6kParams(model="6K"), created=CREATED))
    del doc["checksum"]  # edited below: read as a hand-written file
    doc.update(changes)
    return json.dumps(doc)


def test_json_refusals():
    with pytest.raises(ParameterError, match=r"chip_family must be 'parker6k'.*'pmd'"):
        from_json(_doc(chip_family="pmd"))
    with pytest.raises(ParameterError, match=r"format_version must be 1"):
        from_json(_doc(format_version=2))
    with pytest.raises(ParameterError, match=r"unknown keys 'extra'"):
        from_json(_doc(extra=1))
    base = json.loads(_doc())
    del base["params"]["sgset"]
    with pytest.raises(ParameterError, match=r"missing sgset"):
        from_json(json.dumps(base))
    base = json.loads(_doc())
    base["params"]["sgset"] = [{**GainSet().to_dict(), "sgv": -1}]
    with pytest.raises(ParameterError, match=r"0 <= sgv <= 9999999.*stored gain set 1"):
        from_json(json.dumps(base))
    with pytest.raises(ParameterError, match=r"sample_time_us must equal the servo period"):
        from_json(_doc(sample_time_us=154))
    with pytest.warns(UserWarning, match="spec_version"):
        from_json(_doc(spec_version="parker6k-spec-0"))
    with pytest.raises(ParameterError, match="must be JSON"):
        from_json("{nope")
