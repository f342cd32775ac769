"""The Parker 6000 family in the chip registry, and its kernel closing a loop on a tiny plant."""

from __future__ import annotations

import math

import numpy as np
import pytest

from servogym.chips._family import FAMILY_CODES, Move, families, family_of, get_chip
from servogym.chips.parker6k import (
    PARKER6K,
    S_TRIPPED,
    STATE_SIZE,
    GainSet,
    Parker6kAssumptions,
    Parker6kParams,
    StoredSetActions,
    parker6k_step,
)
from servogym.chips.parker6k._params import ASSUMPTION_CHOICES
from servogym.chips.pmd._kernel import S_TRIPPED as PMD_S_TRIPPED


def test_registered_with_its_code():
    assert families()["parker6k"] is PARKER6K
    assert PARKER6K.code == FAMILY_CODES["parker6k"] == 2
    assert get_chip("6k") == (PARKER6K, "6K") and get_chip("6250") == (PARKER6K, "6250")
    assert family_of(Parker6kParams()) is PARKER6K
    # The compiled loop reads the shutdown flag at the same index for every family.
    assert S_TRIPPED == PMD_S_TRIPPED


def test_family_interface():
    p = PARKER6K.make_params("6K", {"sgp": 100, "sgset": [GainSet().to_dict()]})
    assert p.model == "6K" and p.sgp == 100 and len(p.sgset) == 1
    space = PARKER6K.parameter_space("6250")
    assert [s.name for s in space.tunable()] == ["sgp", "sgi", "sgv", "sgvf", "sgaf"]
    assert all(s.log for s in space.tunable())
    assert PARKER6K.default_assumptions() == Parker6kAssumptions()
    pa, aa = PARKER6K.kernel_arrays(p, None)
    assert pa.dtype == aa.dtype == np.int64 and aa.tolist() == [0] * len(ASSUMPTION_CHOICES)
    with pytest.raises(TypeError, match="must be Parker6kAssumptions"):
        PARKER6K.kernel_arrays(p, object())
    assert PARKER6K.new_state().shape == (STATE_SIZE,)
    assert PARKER6K.sample_time_s(p) == 160e-6 and PARKER6K.motor_limit(p) == 32752
    assert PARKER6K.export(p, "6k", axis=2).count("2SGP1") == 1


def closed_loop(params, dist=20_000, settle_s=0.3):
    """The kernel around an ideal rotary plant: J = 1.2e-4 kg*m^2, 0.2 N*m/A, 10 A at full
    scale, 131072 counts/rev (the project's nominal rotary plant, without friction)."""
    inertia, kt, peak, counts_per_rad = 1.2e-4, 0.2, 10.0, 131072 / (2 * math.pi)
    prof = PARKER6K.profile(Move(dist, 2e5, 4e6, settle_s=settle_s), params.sample_time_s)
    dt = params.sample_time_s
    p, a, state = params.to_array(), Parker6kAssumptions().to_array(), PARKER6K.new_state()
    theta = omega = 0.0
    err = np.zeros(prof.n_ticks, np.int64)
    for k in range(prof.n_ticks):
        actual = math.floor(theta * counts_per_rad)
        c = parker6k_step(state, p, a, prof.position[k], actual, prof.velocity[k],
                          prof.acceleration[k])  # fmt: skip
        omega += kt * max(-peak, min(peak, c / 32768 * peak)) / inertia * dt
        theta += omega * dt
        err[k] = prof.position[k] - actual
    return err, state


def test_default_gains_close_a_stable_loop():
    # The manual's SGP85, SGV2.3 in uV units: soft (about 9 Hz) but stable on this plant.
    err, _ = closed_loop(Parker6kParams())
    assert np.abs(err).max() < 10_000 and abs(err[-1]) < 100


def test_tuned_gains_track_closely_and_smper_trips():
    tuned = Parker6kParams(sgp=200_000, sgv=2000, sgvf=2000, smper=1000)
    err, state = closed_loop(tuned)
    assert np.abs(err).max() < 100 and err[-1] == 0 and state[S_TRIPPED] == 0
    err, state = closed_loop(Parker6kParams(smper=1000))  # the soft default lags > 1000
    assert state[S_TRIPPED] == 1


def test_stored_set_actions():
    sets = [GainSet(sgp=100), GainSet(sgp=200_000, sgv=2000), GainSet(sgi=5)]
    base = Parker6kParams(sgp=1, smper=77, sgset=sets, sgenb=[(10, 3)])
    m = StoredSetActions(base)
    assert m.space.n == 3 and m.names == ("sgp", "sgi", "sgv", "sgvf", "sgaf")
    assert m.to_params(1) == base.enable(2) and m.to_params(np.int64(0)).gains == sets[0]
    values = m.to_values(1)
    assert values["sgp"] == 200_000 and values["smper"] == 77 and values["ssfr"] == 4
    assert m.from_values(values) == 1 and m.from_values(sets[2].to_dict()) == 2
    assert m.from_values({"sgp": 150}) == 0  # nearest on the log scale
    assert m.space.contains(m.from_values({}))
    for bad in (3, -1, 0.5, [1], "1"):
        with pytest.raises(ValueError, match=r"0 <= action <= 2"):
            m.to_params(bad)
    with pytest.raises(ValueError, match="at least one stored gain set"):
        StoredSetActions(Parker6kParams())
