"""docs/chips/pmd.md states the same models, ranges, defaults and assumptions as the code."""

from pathlib import Path

import pytest

from servogym.chips.pmd import CHIP_MODELS, parameter_space
from servogym.chips.pmd._params import ASSUMPTION_CHOICES, ASSUMPTION_IDS

DOC = (Path(__file__).parents[2] / "docs" / "chips" / "pmd.md").read_text()


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
        m.line,
        m.description,
        str(m.n_axes),
        str(m.sample_time_us),
        str(m.min_sample_time_us),
        "yes" if m.has_biquads else "no",
        m.host_interface,
        str(m.kout_max),
    ]
    assert parameter_space(model)["kout"].high == m.kout_max


@pytest.mark.parametrize("name", list(parameter_space("MC58000")))
def test_register_table(name):
    navigator = parameter_space("MC2100")
    s = navigator[name] if name in navigator else parameter_space("MC58000")[name]
    (row,) = rows(f"`{name}`")
    if name == "sample_time_us":
        assert row[2:4] == ["model minimum .. 65535", "model default"]
        assert all(parameter_space(m)[name].high == 65535 for m in CHIP_MODELS)
    else:
        assert row[2:4] == [f"{s.low} .. {s.high}", str(s.default)]
    assert row[1] == s.width and row[6:] == [s.unit, s.source, s.doc]
    assert row[4:6] == ["yes" if s.log else "no", "yes" if s.tunable else "no"]


@pytest.mark.parametrize("name", list(ASSUMPTION_CHOICES))
def test_assumption_table(name):
    (row,) = rows(ASSUMPTION_IDS[name])
    default, *alternatives = ASSUMPTION_CHOICES[name]
    assert row[1:4] == [f"`{name}`", f"`{default}`", ", ".join(f"`{a}`" for a in alternatives)]


def test_kout_tension_with_the_manuals_kp_range_is_stated_with_its_arithmetic():
    # The manual: Kp "typically 1 to 150 when no output scaling is done"; Kout/65536 can
    # never be 1. The spec's figures must be the code's ranges and default.
    para = DOC[DOC.index("**Kout and the manual's Kp range") :].split("\n\n")[0]
    para = " ".join(para.split())
    navigator = {m.kout_max for m in CHIP_MODELS.values() if m.line != "Magellan"}
    assert navigator == {32767} and CHIP_MODELS["MC58000"].kout_max == 65535
    top = 32767 / 65536
    assert top < 0.5 and f"32767/65536 = {top:.6f}" in para
    assert f"Kp {top:.6f} .. {150 * top:.4f} unscaled" in para
    default = parameter_space("MC2100")["kout"].default
    assert f"Kout {default} ({default}/65536 = {default / 65536:.6f})" in para
    assert f"Kp {default / 65536:.6f} .. {150 * default / 65536:.4f}" in para
    assert f"(65535/65536 = {65535 / 65536:.6f})" in para
    assert '"no output scaling" cannot be set on Navigator or Pilot' in para
