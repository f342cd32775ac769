"""The peak torque a plant needs for its moves: from the model, checked by simulation."""

import math
import re
from pathlib import Path

import mujoco
import numpy as np
import pytest

from servogym.plants import (
    PEAK_HEADROOM,
    PLANTS,
    MotorFeasibilityError,
    PlantParameterError,
    check_motor,
    feasible_range,
    parse_plant_ranges,
    required_peak_effort,
)
from servogym.plants._feasibility import default_moves, feasibility_table_markdown

FAMILIES = list(PLANTS)
DOC = (Path(__file__).parents[2] / "docs" / "plants.md").read_text()


def open_loop_acceleration(plant, torque_nm: float, q: float, n_steps: int = 40) -> float:
    """Mean rigid-body acceleration from rest at ``q`` under a constant motor torque.

    Simulated; the motor joint's generalised momentum (``M @ qvel``, the whole drive train's
    angular momentum for the two-mass plant, whose spring is internal) over its inertia.
    """
    m, d = plant.model, plant.data
    plant.set_timestep(1e-5)
    mujoco.mj_resetData(m, d)
    d.qpos[plant.io.qpos_adr] = q
    d.ctrl[plant.io.ctrl_index] = torque_nm
    for _ in range(n_steps):
        mujoco.mj_step(m, d)
    full = np.zeros((m.nv, m.nv))
    mujoco.mj_fullM(m, d, full)
    dof = plant.io.qvel_adr
    momentum = (full @ d.qvel)[dof]
    return momentum / full[dof, dof] / (n_steps * m.opt.timestep)


@pytest.mark.parametrize("name", FAMILIES)
def test_need_matches_an_open_loop_simulation(name):
    # A torque of inertia + gravity + Coulomb (no velocity yet: no viscous term) from rest at
    # the worst position accelerates the axis at the moves' peak acceleration.
    family = PLANTS[name]
    plant = family.build({"coulomb_friction_nm": 1e-3} if name != "vertical-axis" else {})
    moves = default_moves(family)
    need = required_peak_effort(family, plant.values, moves)
    accel = max(m.max_acceleration for m in moves)
    worst_q = plant.io.start_qpos  # gravity (the arm's) is largest at 0 = horizontal
    torque = need.inertia_nm + need.gravity_nm + need.coulomb_nm
    a = open_loop_acceleration(plant, torque, worst_q)
    assert a == pytest.approx(accel, rel=0.03), (name, a, accel)
    # Twice the inertia term: twice the acceleration.
    a2 = open_loop_acceleration(plant, torque + need.inertia_nm, worst_q)
    assert a2 == pytest.approx(2 * accel, rel=0.03)


def test_need_terms_of_the_nominal_arm_by_hand():
    need = required_peak_effort("arm")
    v = PLANTS["arm"].nominal()
    n, length = v["gear_ratio"], v["link_length_m"]
    gravity = (v["link_mass_kg"] / 2 + v["payload_kg"]) * length * 9.81 / n
    assert need.gravity_nm == pytest.approx(gravity, rel=1e-9)
    assert need.coulomb_nm == pytest.approx(v["coulomb_friction_nm"] / n)
    assert need.viscous_nm == pytest.approx(v["viscous_friction_nms"] * 2.0 / n)  # 2 rad/s
    assert need.peak_nm == 2.0 and need.headroom == PEAK_HEADROOM
    assert need.feasible and 0.1 < need.fraction < 0.3


def test_refusal_names_parameter_value_need_and_motor():
    with pytest.raises(MotorFeasibilityError) as info:
        check_motor("arm", {"payload_kg": 4.6}, what={"payload_kg": "--plant-param"})
    text = str(info.value)
    assert "\n" not in text
    assert "payload_kg=4.6 (--plant-param)" in text
    assert re.search(r"needs 2\.31 N\*m at the motor shaft .*115% of the motor's peak", text)
    assert "the motor has 2 N*m peak" in text and "1.6 N*m (80%)" in text
    assert "0.05 <= payload_kg <= 3.115 (kg)" in text
    assert isinstance(info.value, PlantParameterError)


def test_box_corners_are_checked():
    fam = PLANTS["rotary"]
    check_motor(fam, None, {"load_inertia_kgm2": (1e-5, 4e-4)})
    with pytest.raises(MotorFeasibilityError, match=r"load_inertia_kgm2=0\.0008"):
        check_motor(fam, None, {"load_inertia_kgm2": (1e-5, 8e-4)})
    # Each end movable alone, not together: the corner is refused, naming both.
    both = r"load_inertia_kgm2=0\.00049, coulomb_friction_nm=0\.1 "
    with pytest.raises(MotorFeasibilityError, match=both):
        check_motor(fam, None, {"load_inertia_kgm2": (1e-5, 4.9e-4),
                                "coulomb_friction_nm": (1e-4, 0.1)})  # fmt: skip


@pytest.mark.parametrize("name", FAMILIES)
def test_default_sampling_box_is_movable(name):
    family = PLANTS[name]
    need = check_motor(family, None, family.sample_bounds())
    assert need.feasible
    for p in family.params:
        assert p.low <= p.sample_low <= p.nominal <= p.sample_high <= p.high
        if not p.randomised:
            continue
        movable = feasible_range(family, p.name)
        assert movable is not None
        assert movable[0] <= p.sample_low and p.sample_high <= movable[1], p.name


def test_issue_examples_are_not_movable():
    assert not required_peak_effort("arm", {"payload_kg": 4.6}).feasible
    for load in (8e-4, 2.6e-3):
        need = required_peak_effort("rotary", {"load_inertia_kgm2": load})
        assert need.total_nm > need.peak_nm


def test_doc_table_is_the_scripts_output():
    assert feasibility_table_markdown() in DOC, (
        "docs/plants.md's feasibility table is stale: run experiments/plant_feasibility.py --write"
    )


@pytest.mark.parametrize(
    ("items", "match"),
    [
        (["payload_kg"], r"--plant-range must be NAME=LOW:HIGH .*got 'payload_kg'"),
        (["payload_kg=1"], r"NAME=LOW:HIGH"),
        (["payload_kg=1:2:3"], r"NAME=LOW:HIGH"),
        (["payload_kg=a:2"], r"needs two numbers .*'a' is not a number"),
        (["payload_kg=1:2", "payload_kg=1:3"], r"payload_kg is given twice \(1:2 and 1:3\)"),
        (["payload=1:2"], r"--plant-range: .*no parameter 'payload'.*Did you mean payload_kg"),
        (["payload_kg=3:1"], r"payload_kg=3:1 must have low <= high.*0\.05 <= payload_kg <= 5"),
        (["payload_kg=0.01:2"], r"payload_kg=0\.01:2 must lie inside .*0\.05 <= payload_kg <= 5"),
        (["payload_kg=1:nan"], r"must lie inside the legal range 0\.05 <= payload_kg <= 5"),
    ],
)
def test_plant_range_text_errors(items, match):
    with pytest.raises(PlantParameterError, match=match) as info:
        parse_plant_ranges(items, PLANTS["arm"])
    assert "\n" not in str(info.value)


def test_plant_range_text_parses_and_draws_inside():
    ranges = parse_plant_ranges(["payload_kg=0.5:2", "link_mass_kg = 1:1"], PLANTS["arm"])
    assert ranges == {"payload_kg": (0.5, 2.0), "link_mass_kg": (1.0, 1.0)}
    rng = np.random.default_rng(0)
    draws = [PLANTS["arm"].sample(rng, ranges=ranges) for _ in range(50)]
    xs = [d["payload_kg"] for d in draws]
    assert 0.5 <= min(xs) < 0.6 and 1.8 < max(xs) <= 2.0
    assert all(d["link_mass_kg"] == 1.0 for d in draws)  # not randomised, drawn from 1..1
    assert math.isclose(
        PLANTS["arm"].sample(rng, 0.0, ranges={"payload_kg": (1, 2)})["payload_kg"], 1.0
    )  # fmt: skip  (nominal 0.5 clipped into the range)
