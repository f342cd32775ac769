"""Edges of the filters' linear response C(z) that the measured cases leave open (issue 14).

Each number is derived by hand in the comments from the formula of the module's docstring
(docs/chips/*.md, the "linear response" sections).
"""

from __future__ import annotations

import numpy as np
import pytest

from servogym.chips import get_chip
from servogym.chips.parker6k import GainSet


def test_parker_gains_switched_in_at_tick_one_are_not_those_at_reset():
    """C(z) takes the gains in force at sample 0: a stored set switched in at tick 1 is not
    (test_filter_response covers a switch at tick 0 and at tick 5)."""
    family, model = get_chip("6250")
    stored = GainSet(sgp=100, sgi=0, sgv=0, sgvf=0, sgaf=0)
    base = dict(sgp=8500, sgi=0, sgv=0, sgset=[stored])
    z = np.exp(0.4j)
    # SGP85 (uV): 8500 q per count, 32768 / 10^9 counts per q: 0.278528 at any z.
    at1 = family.make_params(model, dict(base, sgenb=[(1, 1)]))
    assert complex(family.filter_response(at1, None, z)) == pytest.approx(0.278528, rel=1e-12)
    # Switched in at tick 0: SGP1 (100 q per count): 100 * 32768 / 10^9 = 0.0032768.
    at0 = family.make_params(model, dict(base, sgenb=[(0, 1)]))
    assert complex(family.filter_response(at0, None, z)) == pytest.approx(0.0032768, rel=1e-12)
