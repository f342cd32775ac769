"""Fitting hidden plants and the latency back from synthetic traces; mismatches flagged."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from servogym.calibrate import FitError, calibrate, synthetic_trace
from servogym.plants import PlantParameterError
from servogym.sim import MoveSpec
from tests.calibrate.conftest import HIDDEN_LATENCY, PARAMS, ROTARY_HIDDEN, ROTARY_MOVES


def _rel(value: float, true: float) -> float:
    return abs(value / true - 1.0)


def test_the_load_inertia_comes_back_within_10_percent(rotary_fit):
    assert _rel(rotary_fit.plant["load_inertia_kgm2"], ROTARY_HIDDEN["load_inertia_kgm2"]) < 0.10


def test_coulomb_friction_comes_back_within_25_percent(rotary_fit):
    assert (
        _rel(rotary_fit.plant["coulomb_friction_nm"], ROTARY_HIDDEN["coulomb_friction_nm"]) < 0.25
    )


def test_the_latency_setting_comes_back(rotary_fit):
    assert rotary_fit.latency == HIDDEN_LATENCY
    assert rotary_fit.latency_choices == (HIDDEN_LATENCY,)
    assert rotary_fit.latencies[0].choices == (HIDDEN_LATENCY,)
    assert rotary_fit.latency_decided and rotary_fit.to_dict()["latency_decided"] is True
    # every other latency replays clearly worse
    assert all(
        x.rms_error_counts > 5 * rotary_fit.rms_error_counts for x in rotary_fit.latencies[1:]
    )


def test_a_good_fit_reports_small_errors_and_finite_uncertainties(rotary_fit):
    assert not rotary_fit.poor
    assert rotary_fit.rms_error_counts < 3.0
    assert rotary_fit.open_loop_rms_error_counts < 5.0
    for f in rotary_fit.fitted:
        assert np.isfinite(f.sigma) and f.sigma >= 0
    doc = rotary_fit.to_dict()
    assert doc["latency"] == HIDDEN_LATENCY and doc["poor_fit"] is False
    assert set(doc["fitted"]) == {
        "load_inertia_kgm2",
        "viscous_friction_nms",
        "coulomb_friction_nm",
    }


def test_wrong_registers_are_a_poor_fit_that_names_the_registers(rotary_trace):
    other = dataclasses.replace(PARAMS, kp=90)
    cal = calibrate(rotary_trace, other, "rotary", latency=HIDDEN_LATENCY)
    assert cal.poor
    assert "poor fit" in cal.verdict()


def test_a_trace_of_another_plant_family_is_a_poor_fit():
    moves = (MoveSpec(1.0, 40.0, 3000.0, 0.03),)
    trace = synthetic_trace(
        "MC2100", "two-mass", {"stiffness_nm_per_rad": 2.0, "load_inertia_kgm2": 2e-4},
        params=PARAMS, moves=moves, command_noise_counts=2.0,
    )  # fmt: skip
    cal = calibrate(trace, PARAMS, "rotary", latency="axis_slot")
    assert cal.poor and cal.error_ratio > 0.5


def test_fit_and_fix_are_checked(rotary_trace):
    with pytest.raises(FitError, match="both fitted"):
        calibrate(rotary_trace, PARAMS, "rotary", fit=["coulomb_friction_nm"],
                  fix={"coulomb_friction_nm": 0.01})  # fmt: skip
    with pytest.raises(FitError, match="integer"):
        calibrate(rotary_trace, PARAMS, "rotary", fit=["encoder_counts_per_rev"])
    with pytest.raises(FitError, match="--latency must be one of"):
        calibrate(rotary_trace, PARAMS, "rotary", latency="later")
    with pytest.raises(PlantParameterError, match="Did you mean"):
        calibrate(rotary_trace, PARAMS, "rotary", fix={"coulomb_frictio_nm": 0.01})


def test_a_parameter_the_trace_cannot_see_is_refused(rotary_trace):
    # the rotary plant has no gravity: the travel limits far away change nothing
    with pytest.raises(FitError, match="does not determine travel_max_rad"):
        calibrate(rotary_trace, PARAMS, "rotary", fit=["travel_max_rad"], latency=HIDDEN_LATENCY)


@pytest.mark.slow
@pytest.mark.parametrize(
    ("plant", "hidden", "load"),
    [
        ("vertical-axis", {"payload_kg": 3.5, "coulomb_friction_n": 20.0}, "payload_kg"),
        ("arm", {"payload_kg": 1.0, "coulomb_friction_nm": 0.2}, "payload_kg"),
        ("two-mass", {"load_inertia_kgm2": 1.5e-4, "stiffness_nm_per_rad": 5.0,
                      "coulomb_friction_nm": 0.03}, "load_inertia_kgm2"),
    ],
)  # fmt: skip
def test_every_family_comes_back(plant, hidden, load):
    trace = synthetic_trace("MC2100", plant, hidden, params=PARAMS, loop_latency=HIDDEN_LATENCY,
                            command_noise_counts=2.0)  # fmt: skip
    cal = calibrate(trace, PARAMS, plant)
    assert cal.latency == HIDDEN_LATENCY and not cal.poor
    assert _rel(cal.plant[load], hidden[load]) < 0.10
    coulomb = next(n for n in hidden if n.startswith("coulomb"))
    assert _rel(cal.plant[coulomb], hidden[coulomb]) < 0.25
    if plant == "two-mass":
        assert _rel(cal.plant["stiffness_nm_per_rad"], hidden["stiffness_nm_per_rad"]) < 0.10


def test_rotary_moves_are_the_ones_the_fixture_uses():
    assert ROTARY_MOVES[0].distance == -ROTARY_MOVES[1].distance
