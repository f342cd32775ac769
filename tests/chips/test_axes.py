"""Multi-axis files (issue 23, point 4): every axis of a controller in the chip's own form.

The round trip runs every model x format x N in {1, 2, the model's maximum}; the random sets
come from the export corpus's generator (experiments/export_corpus.py), so they span every
register's range, the 6000 series' stored gain sets and schedules, and every assumption.
"""

from __future__ import annotations

import importlib.util
import json
import sys
from pathlib import Path

import numpy as np
import pytest

from servogym._files import FileSafetyError
from servogym.chips import (
    MultiAxisParams,
    ParameterError,
    export_axes,
    families,
    get_chip,
    import_axes,
    load_axes,
    max_axes,
    save_axes,
)

_CORPUS = Path(__file__).resolve().parents[2] / "experiments" / "export_corpus.py"


def _corpus_module():
    spec = importlib.util.spec_from_file_location("export_corpus", _CORPUS)
    module = importlib.util.module_from_spec(spec)
    sys.modules.setdefault("export_corpus", module)
    spec.loader.exec_module(module)
    return module


CORPUS = _corpus_module()

MODELS = [(fam.name, model) for fam in families().values() for model in fam.models]


def _top(chip) -> int:
    return getattr(chip, "n_axes", None) or chip.n_motors


def random_axes(model: str, n: int, rng: np.random.Generator) -> tuple[MultiAxisParams, dict]:
    """``n`` random legal sets of ``model`` on random axis numbers, the controller-wide
    registers shared (PMD: a period long enough for ``n`` axes), and random assumptions."""
    fam, model = get_chip(model)
    chip = fam.models[model]
    numbers = sorted(rng.choice(np.arange(1, _top(chip) + 1), size=n, replace=False).tolist())
    cases = [CORPUS.random_case(fam, model, rng) for _ in range(n)]
    shared = {name: cases[0]["values"][name] for name in fam.registers.controller_wide}
    if fam.name == "pmd":
        slot = chip.min_sample_time_us
        shared["sample_time_us"] = int(rng.integers(n * slot, 65535, endpoint=True))
    sets = {
        k: fam.make_params(model, {**c["values"], **shared})
        for k, c in zip(numbers, cases, strict=True)
    }
    return MultiAxisParams(sets), cases[0]["assumptions"]


def _counts(model: str) -> list[int]:
    return sorted({n for n in (1, 2, max_axes(model)) if n <= max_axes(model)})


ROUND_TRIPS = [
    (model, fmt, n)
    for _family, model in MODELS
    for fmt in get_chip(model)[0].formats_for(model)
    for n in _counts(model)
]


@pytest.mark.parametrize(("model", "fmt", "n"), ROUND_TRIPS)
def test_round_trip(model, fmt, n):
    rng = np.random.default_rng([n, len(model), sum(map(ord, model + fmt))])
    for _ in range(3):
        axes, assumptions = random_axes(model, n, rng)
        text = export_axes(axes, fmt, assumptions)
        back = import_axes(text, fmt)
        assert back == axes
        assert back.numbers == axes.numbers
        assert all(type(p) is type(axes[k]) for k, p in back.items())
        assert import_axes(text, fmt, model=model) == axes


def test_round_trip_reads_the_assumptions_back():
    rng = np.random.default_rng(7)
    for _family, model in MODELS:
        fam = get_chip(model)[0]
        axes, assumptions = random_axes(model, min(2, max_axes(model)), rng)
        for fmt in fam.formats_for(model):
            text = export_axes(axes, fmt, assumptions)
            if fmt == "json":
                read = json.loads(text)["assumptions"]
            else:
                read = fam.export_module.read_header(text)["assumptions"].to_dict()
            assert read == fam.assumptions_type(**assumptions).to_dict()


@pytest.mark.parametrize(("family", "model"), MODELS)
def test_one_axis_is_todays_file(family, model):
    """A one-axis set through the multi-axis writer is the single-axis export, byte for byte
    (JSON excepted: the single-axis layout has no axis number); today's file reads back as
    that one axis."""
    fam = get_chip(model)[0]
    rng = np.random.default_rng(len(model))
    for _ in range(20):
        axes, assumptions = random_axes(model, 1, rng)
        ((axis, params),) = axes.items()
        for fmt in fam.formats_for(model):
            if fmt == "json":
                single = fam.export(params, fmt, assumptions=assumptions, created="2025-01-01")
                assert import_axes(single, fmt) == MultiAxisParams({1: params})
                continue
            single = fam.export(params, fmt, axis=axis, assumptions=assumptions)
            assert export_axes(axes, fmt, assumptions) == single
            assert import_axes(single, fmt) == axes


def _sets(model, n, **values):
    fam, model = get_chip(model)
    return [fam.make_params(model, values) for _ in range(n)]


def test_pmd_one_handle_per_axis():
    from servogym.sim import machine_params

    sets = machine_params("MC2300", 2, [{"kp": 100}, {"kp": 250}])
    text = export_axes(MultiAxisParams(sets), "cmotion")
    assert "PMDSetKp(&hAxis1, 100);" in text
    assert "PMDSetKp(&hAxis2, 250);" in text
    assert " * axes: 1, 2\n" in text
    assert text.index("PMDUpdate(&hAxis1);") < text.index("PMDSetKp(&hAxis2, 250);")
    assert text.count("PMDSetSampleTime(") == 2  # each axis's block, the same period
    host = export_axes(MultiAxisParams(sets), "host")
    assert "0x25 SetKp axis=1 data=0x0064\n" in host
    assert "0x25 SetKp axis=2 data=0x00FA\n" in host
    assert host.count("Update axis=") == 2


def test_pmac_ivariables_per_motor_number():
    fam, _ = get_chip("GeoBrickLV")
    p1 = fam.make_params("GeoBrickLV", {"proportional_gain": 3000})
    p8 = fam.make_params("GeoBrickLV", {"proportional_gain": 4000, "integral_gain": 5})
    text = export_axes({1: p1, 8: p8}, "ivar")
    assert "\nI130=3000 ; proportional_gain\n" in text
    assert "\nI830=4000 ; proportional_gain\n" in text
    assert "\nI833=5 ; integral_gain\n" in text
    assert text.count("I7000=") == 1  # the servo clock: once for the controller
    assert "; motors: 1, 8\n" in text
    p10 = fam.make_params("TurboPMAC2", {"derivative_gain": 77})
    text = export_axes({10: p10, 2: fam.make_params("TurboPMAC2")}, "ivar")
    assert "\nI1031=77 ; derivative_gain\n" in text
    assert text.index("I230=") < text.index("I1030=")


def test_parker_comma_fields_and_prefixes():
    fam, _ = get_chip("6250")
    a1 = fam.make_params("6250", {"sgp": 8500})
    a2 = fam.make_params("6250", {"sgp": 9000, "sgv": 50})
    lines = export_axes([a1, a2], "6250").splitlines()
    assert "SGP85,90" in lines
    assert "SGV2.3,.5" in lines
    assert lines.count("SSFR4") == 1
    k = [fam.make_params("6K", {"sgp": v}) for v in (8500, 9000)]
    lines = export_axes({1: k[0], 3: k[1]}, "6250").splitlines()
    assert "SGP85,,90" in lines  # axis 2 not given: an empty field
    lines = export_axes({1: k[0], 3: k[1]}, "6k").splitlines()
    assert "1SGP85" in lines and "3SGP90" in lines
    assert export_axes({2: k[0]}, "6250").splitlines().count("SGP,85") == 1


def test_parker_axes_with_fewer_stored_sets_sit_the_later_sets_out():
    from servogym.chips.parker6k import GainSet

    fam, _ = get_chip("6250")
    g1 = GainSet(sgp=100, sgi=1, sgv=2, sgvf=3, sgaf=4)
    g2 = GainSet(sgp=200, sgi=0, sgv=0, sgvf=0, sgaf=0)
    a1 = fam.make_params("6250", {"sgset": (g1, g2), "sgenb": ((5, 2), (9, 1))})
    a2 = fam.make_params("6250", {"sgset": (g2,), "sgenb": ((3, 1),)})
    text = export_axes([a1, a2], "6250")
    lines = text.splitlines()
    first, second = lines.index("SGSET1"), lines.index("SGSET2")
    assert "SGP1,2" in lines[:first]
    assert "SGP2" in lines[first:second]  # axis 2 has no stored set 2
    assert "; sgenb axis=1 tick=5 set=2" in lines
    assert "; sgenb axis=2 tick=3 set=1" in lines
    assert import_axes(text, "6250") == MultiAxisParams([a1, a2])
    # an axis that gives only some of the five gains before SGSET is still refused
    bad = text.replace("SGP2\n", "SGP2,3\n", 1).replace("; servogym", "; hand", 1)
    bad = "\n".join(line for line in bad.splitlines() if "servogym-end" not in line) + "\n"
    with pytest.raises(ParameterError, match=r"SGSET2 stores the five gains.*axis 2"):
        import_axes(bad, "6250")


def test_too_many_axes_named_with_the_model_count_and_range():
    for model, n in (("GeoBrickLV", 9), ("6250", 3), ("MC58000", 5), ("MC3110", 2)):
        most = max_axes(model)
        with pytest.raises(
            ParameterError,
            match=rf"the {model} drives at most {most} .*got {n} "
            rf"parameter sets \(1 <= number of (axes|motors) <= {most}\)",
        ):
            MultiAxisParams(_sets(model, n))
    assert [max_axes(m) for m in ("MC2100", "MC3110", "MC58000", "GeoBrickLV", "TurboPMAC2",
                                   "6250", "6K")] == [4, 1, 4, 8, 32, 2, 8]  # fmt: skip


def test_refusals_of_the_set():
    pmd = get_chip("MC2100")[0]
    with pytest.raises(ParameterError, match=r"same chip model.*'MC2100'.*'MC2300'"):
        MultiAxisParams([pmd.make_params("MC2100", {"sample_time_us": 400}),
                         pmd.make_params("MC2300", {"sample_time_us": 400})])  # fmt: skip
    with pytest.raises(ParameterError, match=r"same chip model.*'MC2100' \(pmd\).*'6250'"):
        MultiAxisParams([pmd.make_params("MC2100"), get_chip("6250")[0].make_params("6250")])
    with pytest.raises(ParameterError, match="sample_time_us is one setting of the whole"):
        MultiAxisParams([pmd.make_params("MC2100", {"sample_time_us": 400}),
                         pmd.make_params("MC2100", {"sample_time_us": 500})])  # fmt: skip
    with pytest.raises(ParameterError, match="308 <= sample_time_us <= 65535 for 2 enabled"):
        MultiAxisParams(_sets("MC2100", 2))  # the one-axis period is too short for two
    pmac = get_chip("TurboPMAC2")[0]
    with pytest.raises(ParameterError, match="servo_clock_divider is one setting"):
        MultiAxisParams([pmac.make_params("TurboPMAC2"),
                         pmac.make_params("TurboPMAC2", {"servo_clock_divider": 1})])  # fmt: skip
    with pytest.raises(ParameterError, match="ssfr is one setting"):
        MultiAxisParams([get_chip("6K")[0].make_params("6K", {"ssfr": s}) for s in (4, 8)])
    with pytest.raises(ParameterError, match=r"1 <= motor <= 32 \(TurboPMAC2"):
        MultiAxisParams({33: pmac.make_params("TurboPMAC2")})
    with pytest.raises(ParameterError, match=r"axis must be an integer with 1 <= axis <= 8 \(6K\)"):
        MultiAxisParams({"1": get_chip("6K")[0].make_params("6K")})
    with pytest.raises(ParameterError, match="at least one parameter set"):
        MultiAxisParams([])
    with pytest.raises(ParameterError, match="axis 1 holds a dict"):
        MultiAxisParams([{"kp": 1}])
    with pytest.raises(ParameterError, match="fmt must be one of 'json', '6250' for the 6250"):
        export_axes([get_chip("6250")[0].make_params("6250")], "6k")


def test_the_set_is_what_the_sim_takes():
    from servogym.sim import machine_params

    sets = machine_params("MC58000", 3)
    axes = MultiAxisParams(sets)
    assert axes.sets == sets and axes.numbers == (1, 2, 3) and axes.noun == "axis"
    assert MultiAxisParams(axes) == axes
    assert MultiAxisParams({3: sets[2], 1: sets[0], 2: sets[1]}).numbers == (1, 2, 3)
    assert MultiAxisParams(machine_params("TurboPMAC2", 2)).noun == "motor"


def _two(model="MC58000"):
    from servogym.sim import machine_params

    return MultiAxisParams(machine_params(model, 2, [{}, {}]))


def test_import_refusals():
    axes = _two()
    text = export_axes(axes, "cmotion")
    with pytest.raises(FileSafetyError, match="cut short"):
        import_axes(text[: len(text) // 2], "cmotion")
    edited = text.replace("PMDPositionLoopKp, 100", "PMDPositionLoopKp, 101", 1)
    with pytest.raises(FileSafetyError, match="does not match the content"):
        import_axes(edited, "cmotion")
    body = "\n".join(x for x in text.splitlines() if "servogym" not in x)
    with pytest.raises(ParameterError, match="handle must be &hAxis<n>"):
        import_axes(body.replace("&hAxis2", "&axisB"), "cmotion", model="MC58000")
    with pytest.raises(ParameterError, match="header names axes 1, 3 but the file sets"):
        import_axes(body.replace("axes: 1, 2", "axes: 1, 3"), "cmotion")
    with pytest.raises(ParameterError, match=r"snippet \(&hAxis2\) does not set every"):
        import_axes(body.replace("PMDSetMotorBias(&hAxis2, 0);", ""), "cmotion")
    with pytest.raises(ParameterError, match=r"a snippet loads one axis.*import_axes"):
        get_chip("MC58000")[0].import_params(text, "cmotion")
    with pytest.raises(ParameterError, match="model='6250' is a parker6k model"):
        import_axes(text, "cmotion", model="6250")
    doc = json.loads(export_axes(axes, "json"))
    doc.pop("checksum")
    doc["axes"][1]["axis"] = 1
    with pytest.raises(ParameterError, match=r"axes\[1\]: axis 1 is listed twice"):
        import_axes(json.dumps(doc), "json")
    doc["axes"][1]["axis"] = 2
    doc["axes"][1]["params"]["kp"] = -1
    with pytest.raises(ParameterError, match=r"axes\[1\] \(axis 2\): .*kp"):
        import_axes(json.dumps(doc), "json")
    sgenb = export_axes(MultiAxisParams(_sets("6250", 2)), "6250")
    plain = "\n".join(x for x in sgenb.splitlines() if "servogym" not in x)
    with pytest.raises(ParameterError, match="a schedule line of a file of several axes"):
        import_axes(plain + "\n; sgenb tick=3 set=1\n", "6250")


def test_pmac_file_without_header_reads_every_motor(tmp_path):
    axes = _two("GeoBrickLV")
    text = export_axes(axes, "ivar")
    saved = "\n".join(x for x in text.splitlines() if not x.startswith(";"))  # a controller's
    assert import_axes(saved, "ivar", model="GeoBrickLV") == axes
    with pytest.raises(ParameterError, match="sets registers of motors 1, 2; pass motor="):
        get_chip("GeoBrickLV")[0].import_params(text, "ivar")


def test_save_and_load(tmp_path):
    axes = _two()
    path = save_axes(tmp_path / "axes.c", axes)
    assert load_axes(path) == axes
    assert path.read_text() == export_axes(axes)
    assert not [p for p in tmp_path.iterdir() if p.name != "axes.c"]  # no temporary left
    with pytest.raises(FileSafetyError, match="already exists"):
        save_axes(path, axes)
    with pytest.raises(FileSafetyError, match="is the input file"):
        save_axes(path, axes, inputs=[path], force=True)
    save_axes(path, _two("MC2300"), "host", force=True)
    assert load_axes(path, "host") == _two("MC2300")
    path.write_text(path.read_text()[:-80])
    with pytest.raises(FileSafetyError, match=r"axes\.c"):
        load_axes(path)
    json_path = save_axes(tmp_path / "axes.json", axes, "json", notes={"plant": "xy-stage"})
    assert load_axes(json_path) == axes
