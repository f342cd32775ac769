"""docs/chips/pmac.md states the same models, registers, I-variables and assumptions as the code."""

from pathlib import Path

import pytest

from servogym.chips.pmac import (
    ASSUMPTION_CHOICES,
    ASSUMPTION_IDS,
    CHIP_MODELS,
    I_VARIABLES,
    SPEC_VERSION,
    parameter_space,
)

DOC = (Path(__file__).parents[2] / "docs" / "chips" / "pmac.md").read_text()


def rows(first_cell: str) -> list[list[str]]:
    out = []
    for line in DOC.splitlines():
        cells = [c.strip() for c in line.strip().strip("|").split("|")]
        if line.startswith("|") and cells[0] == first_cell:
            out.append(cells)
    return out


def test_spec_version():
    assert f"Spec version: `{SPEC_VERSION}`" in DOC


@pytest.mark.parametrize("model", sorted(CHIP_MODELS))
def test_model_table(model):
    m = CHIP_MODELS[model]
    (row,) = rows(model)
    assert row[1:] == [
        m.line,
        m.description,
        str(m.n_motors),
        *map(str, m.clock_defaults),
        str(m.servo_period_ticks),
        f"{m.sample_time_us:.2f}",
    ]
    space = parameter_space(model)
    clocks = ("max_phase_frequency_control", "phase_clock_divider", "servo_clock_divider")
    assert tuple(space[c].default for c in clocks) == m.clock_defaults


@pytest.mark.parametrize("name", list(parameter_space("TurboPMAC2")))
def test_register_table(name):
    (row,) = rows(f"`{name}`")
    number = I_VARIABLES[name]
    assert row[1] == (f"I{number}" if number >= 100 else f"Ixx{number:02d}")
    for model in CHIP_MODELS:
        s = parameter_space(model)[name]
        assert row[2:5] == [s.width, f"{s.low} .. {s.high}", str(s.default)]
        assert row[5:7] == ["yes" if s.log else "no", "yes" if s.tunable else "no"]
        assert row[7:] == [s.unit, s.source, s.doc]


@pytest.mark.parametrize("name", list(ASSUMPTION_CHOICES))
def test_assumption_table(name):
    (row,) = rows(ASSUMPTION_IDS[name])
    default, *alternatives = ASSUMPTION_CHOICES[name]
    assert row[1:4] == [f"`{name}`", f"`{default}`", ", ".join(f"`{a}`" for a in alternatives)]


def test_assumption_ids_are_numbered_and_cited():
    ids = list(ASSUMPTION_IDS.values())
    assert ids == [f"PMAC-A{i}" for i in range(1, len(ids) + 1)]
    # Every id is used in the arithmetic of section 3, not only in the table.
    section3 = DOC[DOC.index("## 3. One servo update") : DOC.index("## 4. Assumptions")]
    for ident in ids:
        assert f"{ident} " in section3 or f"{ident}:" in section3, ident
    profile = DOC[DOC.index("## 5. The profile") : DOC.index("## 6. Notch")]
    assert [f"PMAC-P{i}" in profile for i in range(1, 8)] == [True] * 7


def test_sourced_ranges_and_bias_order_name_their_source():
    # Ixx11 and Ixx60: range and default from the public quick reference [M].
    space = parameter_space("TurboPMAC2")
    ixx11, ixx60 = space["fatal_following_error_limit"], space["servo_cycle_extension"]
    assert (ixx11.low, ixx11.high, ixx11.default, ixx11.source) == (0, 8_388_607, 32_000, "M")
    assert (ixx60.low, ixx60.high, ixx60.default, ixx60.source) == (0, 255, 0, "M")
    flat = " ".join(DOC.split())
    assert (
        "Ixx11 (0 .. 8,388,607, default 32,000 = 2000 counts) and Ixx60 (0 .. 255, default 0) "
        "are in Delta Tau's public Turbo PMAC quick reference [M]" in flat
    )
    unsourced = [n for n, s in space.items() if s.source == "A"]
    assert unsourced == [
        "max_phase_frequency_control", "phase_clock_divider", "servo_clock_divider",
    ]  # fmt: skip
    # Ixx29 after the limit: the default of PMAC-A9 is the Software Reference's, quoted in
    # the arithmetic and in the assumption table (the switch stays).
    quote = (
        '"added to the output command value before it is written to the command output register"'
    )
    (row,) = rows(ASSUMPTION_IDS["bias_order"])
    assert row[2] == "`limit_then_bias`" and row[4].startswith("Sourced [M]") and quote in row[4]
    step9 = " ".join(DOC[DOC.index("9. **Output.**") : DOC.index("10. **Killed motor.**")].split())
    assert "`limit_then_bias` (default, sourced [M]" in step9 and quote in step9
