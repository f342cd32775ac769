"""docs/plants.md states the same families, parameters, nominals and ranges as the code."""

import re
from pathlib import Path

import pytest

from servogym.plants import MULTI_PLANTS, PLANTS, AxisIO, plant_table_markdown
from servogym.plants._registry import param_row

DOC = (Path(__file__).parents[2] / "docs" / "plants.md").read_text()


def section(name: str) -> str:
    """The text of the family's section, from its heading to the next heading."""
    match = re.search(rf"^### `{re.escape(name)}`\n(.*?)(?=^##)", DOC, re.M | re.S)
    assert match, f"docs/plants.md has no section ### `{name}`"
    return match.group(1)


@pytest.mark.parametrize("name", list(PLANTS))
def test_family_table_matches_code(name):
    family = PLANTS[name]
    text = section(name)
    assert plant_table_markdown(family) in text, (
        f"the {name} table in docs/plants.md differs from the code; regenerate it with "
        f"servogym.plants.plant_table_markdown(PLANTS[{name!r}])"
    )
    assert family.description in text
    for p in family.params:
        assert param_row(p) in text


def test_every_parameter_row_in_the_doc_is_in_the_code():
    families = (*PLANTS.values(), *MULTI_PLANTS.values())
    known = {param_row(p) for family in families for p in family.params}
    rows = [line for line in DOC.splitlines() if line.startswith("| `") and "_" in line]
    io_fields = {f"| `{f}` |" for f in AxisIO.__dataclass_fields__}
    for row in rows:
        if any(row.startswith(f) for f in io_fields):
            continue
        assert row in known, f"docs/plants.md has a parameter row the code does not: {row}"


def test_axis_io_table_lists_every_field():
    for field in AxisIO.__dataclass_fields__:
        assert f"| `{field}` |" in DOC
