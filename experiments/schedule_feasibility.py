"""What every Schedule env's box needs of its motor (docs/envs.md, "Why each range is ...").

    .venv/bin/python experiments/schedule_feasibility.py            # print the table
    .venv/bin/python experiments/schedule_feasibility.py --write    # and update docs/envs.md

For every registered Schedule id (the plant-family ids with their default pick-and-place
cycle, and the gain-scheduling scenarios of ``servogym.envs.SCENARIOS``): the scheduled
parameter's empty value and part range, the fixed plant values, the moves, and the peak motor
torque the worst corner of the env's box needs (``servogym.plants.check_motor`` over the
scheduled parameter from empty to the part's high end and every other drawn parameter over
its range). Every row must stay within ``servogym.plants.PEAK_HEADROOM`` (80 %) of the
motor's peak: the env refuses a box that does not. ``tests/envs/test_schedule_scenarios.py``
checks that docs/envs.md still holds this script's output.
"""

from __future__ import annotations

import argparse
from pathlib import Path

from plant_feasibility import write_block  # this folder: the script runs from it

from servogym.envs._scenarios import feasibility_table_markdown

DOC = Path(__file__).parents[1] / "docs" / "envs.md"
BEGIN = "<!-- schedule feasibility table: experiments/schedule_feasibility.py -->"
END = "<!-- end of schedule feasibility table -->"


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--write", action="store_true", help="replace the table in docs/envs.md")
    args = ap.parse_args()
    table = feasibility_table_markdown()
    print(table)
    if args.write:
        write_block(DOC, BEGIN, END, table)


if __name__ == "__main__":
    main()
