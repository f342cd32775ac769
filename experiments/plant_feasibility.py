"""What each plant family's default motor can move with the default moves (docs/plants.md).

    .venv/bin/python experiments/plant_feasibility.py            # print the table
    .venv/bin/python experiments/plant_feasibility.py --write    # and update docs/plants.md

For every family in the plant registry (``servogym.plants.PLANTS``): the peak motor torque
the nominal plant and the worst corner of the default sampling ranges need
(``servogym.plants.required_peak_effort``, from the MuJoCo models), and each parameter whose
movable part of the legal range (the others nominal) is not the whole of it
(``servogym.plants.feasible_range``). "Movable": the moves need at most
``servogym.plants.PEAK_HEADROOM`` (80 %) of the motor's peak torque. The table in
docs/plants.md, "What the motor can move", is this script's output
(``tests/plants/test_feasibility.py`` checks that it still is).
"""

from __future__ import annotations

import argparse
import re
from pathlib import Path

from servogym.plants._feasibility import feasibility_table_markdown

DOC = Path(__file__).parents[1] / "docs" / "plants.md"
BEGIN = "<!-- feasibility table: experiments/plant_feasibility.py -->"
END = "<!-- end of feasibility table -->"


def write_block(doc: Path, begin: str, end: str, table: str) -> None:
    """Replace the one block between the ``begin`` and ``end`` markers of ``doc`` by
    ``table`` (also used by schedule_feasibility.py)."""
    block = f"{begin}\n{table}\n{end}"
    text = doc.read_text()
    new, n = re.subn(re.escape(begin) + r".*?" + re.escape(end), block, text, flags=re.S)
    if n != 1:
        raise SystemExit(f"{doc.parent.name}/{doc.name} has no block {begin} ... {end}")
    doc.write_text(new)
    print(f"wrote {doc}")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--write", action="store_true", help="replace the table in docs/plants.md")
    args = ap.parse_args()
    table = feasibility_table_markdown()
    print(table)
    if args.write:
        write_block(DOC, BEGIN, END, table)


if __name__ == "__main__":
    main()
