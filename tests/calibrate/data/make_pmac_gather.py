"""Writes pmac_gather_rotary.txt and pmac_rotary.pmc, the example Turbo PMAC capture.

A TurboPMAC2 motor 1 (the model-based set of tests/sim/data/convergence_sets.json) on a
rotary axis with a hidden load of 1.5e-4 kg*m^2 and Coulomb friction 0.03 N*m, loop latency
full_period (not the family's phase_edge), 2 counts of noise on the recorded command.

    .venv/bin/python tests/calibrate/data/make_pmac_gather.py
"""

from __future__ import annotations

import json
from pathlib import Path

from servogym.calibrate import synthetic_trace
from servogym.calibrate._gather import to_gather
from servogym.chips import get_chip
from servogym.sim import MoveSpec

HERE = Path(__file__).parent
HIDDEN = {"load_inertia_kgm2": 1.5e-4, "coulomb_friction_nm": 0.03}
LATENCY = "full_period"


def main() -> None:
    sets = json.loads((HERE.parents[1] / "sim" / "data" / "convergence_sets.json").read_text())
    family, model = get_chip("TurboPMAC2")
    params = family.make_params(model, sets["TurboPMAC2/rotary/default"]["values"])
    moves = (MoveSpec(1.0, 40.0, 3000.0, 0.05), MoveSpec(-1.0, 40.0, 3000.0, 0.05))
    trace = synthetic_trace("TurboPMAC2", "rotary", HIDDEN, params=params, loop_latency=LATENCY,
                            moves=moves, command_noise_counts=2.0, seed=3)  # fmt: skip
    (HERE / "pmac_gather_rotary.txt").write_text(to_gather(trace, params, motor=1))
    (HERE / "pmac_rotary.pmc").write_text(family.export(params, "ivar"))


if __name__ == "__main__":
    main()
