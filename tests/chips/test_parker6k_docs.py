"""docs/chips/parker6k.md states the same models, registers, rates and assumptions as the code."""

from pathlib import Path

import pytest

from servogym.chips.parker6k import CHIP_MODELS, parameter_space
from servogym.chips.parker6k._params import (
    ASSUMPTION_CHOICES,
    ASSUMPTION_IDS,
    COMMANDS,
    SSFR_FREQUENCY_HZ,
    SSFR_PERIOD_US,
    SSFR_TRAJECTORY_US,
)
from servogym.chips.parker6k._profile import PROFILE_ASSUMPTION_CHOICES, PROFILE_ASSUMPTION_IDS
from servogym.chips.parker6k._reference import W, scale_of

DOC = (Path(__file__).parents[2] / "docs" / "chips" / "parker6k.md").read_text()


def rows(first_cell: str) -> list[list[str]]:
    out = []
    for line in DOC.splitlines():
        cells = [c.strip() for c in line.strip().strip("|").split("|")]
        if line.startswith("|") and cells[0] == first_cell:
            out.append(cells)
    return out


@pytest.mark.parametrize("model", sorted(CHIP_MODELS))
def test_model_table(model):
    m = CHIP_MODELS[model]
    (row,) = rows(model)
    assert row[1:] == [
        m.description,
        str(m.n_axes),
        str(m.default_ssfr),
        "yes" if m.axis_prefix else "no",
    ]
    assert parameter_space(model)["ssfr"].default == m.default_ssfr


@pytest.mark.parametrize("name", list(parameter_space("6250")))
def test_register_table(name):
    s = parameter_space("6250")[name]
    assert all(parameter_space(m)[name] == s for m in CHIP_MODELS)
    (row,) = rows(f"`{name}`")
    legal = "1, 2, 4, 8" if name == "ssfr" else f"{s.low} .. {s.high}"
    assert row[1:] == [
        COMMANDS[name],
        s.width,
        legal,
        str(s.default),
        "yes" if s.log else "no",
        "yes" if s.tunable else "no",
        s.unit,
        s.source,
        s.doc,
    ]


@pytest.mark.parametrize("ssfr", sorted(SSFR_PERIOD_US))
def test_ssfr_table(ssfr):
    (row,) = rows(str(ssfr))
    assert row[1:] == [
        str(SSFR_PERIOD_US[ssfr]),
        str(SSFR_FREQUENCY_HZ[ssfr]),
        str(SSFR_TRAJECTORY_US[ssfr]),
    ]
    # The printed frequency is the period's reciprocal, rounded.
    assert SSFR_FREQUENCY_HZ[ssfr] == round(1e6 / SSFR_PERIOD_US[ssfr])


@pytest.mark.parametrize("unit", ASSUMPTION_CHOICES["gain_unit"])
def test_signal_unit_table(unit):
    from servogym.chips.parker6k import Parker6kAssumptions

    fs, mv, _ = scale_of(Parker6kAssumptions(gain_unit=unit))
    (row,) = rows(f"`{unit}`")
    assert row[2:] == [str(fs), str(mv)]
    assert W == 2**47 and "W = 2^47" in DOC


@pytest.mark.parametrize("name", list(ASSUMPTION_CHOICES))
def test_assumption_table(name):
    (row,) = rows(ASSUMPTION_IDS[name])
    default, *alternatives = ASSUMPTION_CHOICES[name]
    assert row[1:4] == [f"`{name}`", f"`{default}`", ", ".join(f"`{a}`" for a in alternatives)]


@pytest.mark.parametrize("name", list(PROFILE_ASSUMPTION_CHOICES))
def test_profile_assumptions_are_documented(name):
    default, *alternatives = PROFILE_ASSUMPTION_CHOICES[name]
    ident = PROFILE_ASSUMPTION_IDS[name]
    expected = f"**{ident} (switch `{name}`) `{default}` / " + " / ".join(
        f"`{a}`" for a in alternatives
    )
    assert expected in DOC


def test_assumption_ids_are_unique_and_all_in_the_table():
    ids = list(ASSUMPTION_IDS.values())
    assert len(set(ids)) == len(ids) and list(ASSUMPTION_IDS) == list(ASSUMPTION_CHOICES)
    assert ASSUMPTION_IDS["integral_timing"] == "PK-A10"
    step6 = DOC[DOC.index("6. **Integral**") : DOC.index("7. **Feed-forward.**")]
    assert "PK-A10 `integral_timing`" in step6


def test_ssfr_table_is_an_assumption_from_the_apex615n_guide():
    for model in CHIP_MODELS:
        s = parameter_space(model)["ssfr"]
        assert s.source == "A" and "APEX615n" in s.doc
    section3 = DOC[DOC.index("## 3. Sampling (SSFR)") : DOC.index("## 4. One servo sample")]
    assert section3.split("\n\n")[1].startswith("[A, from the *APEX615n Installation Guide*")
    assert "[M: APEX615n" not in DOC


def test_example_gains_are_labelled_as_the_guides_example():
    space = parameter_space("6250")
    notes = {name: s.default_note for name, s in space.items() if s.default_note}
    assert set(notes) == {"sgp", "sgv"}
    assert (space["sgp"].default, space["sgv"].default) == (8500, 230)  # SGP85, SGV2.3
    assert "not controller defaults" in DOC and "`default_note`" in DOC
