"""Multi-axis plants: the mechanics against closed forms, in-place editing against a fresh
compile, what the motors can move, the registry's refusal and the docs' tables."""

from __future__ import annotations

import math
import pathlib
from types import SimpleNamespace

import mujoco
import numpy as np
import pytest

from servogym.plants import (
    MULTI_PLANTS,
    PLANTS,
    PlantParameterError,
    TwoLinkArmFamily,
    get_plant,
    plant_table_markdown,
    required_peak_efforts,
)
from servogym.plants._multi import commanded_efforts, worst_sampled_efforts

DOC = (pathlib.Path(__file__).parents[2] / "docs" / "plants.md").read_text()


def full_mass_matrix(plant, qpos):
    plant.reset()
    plant.data.qpos[:] = qpos
    mujoco.mj_forward(plant.model, plant.data)
    out = np.zeros((plant.model.nv, plant.model.nv))
    mujoco.mj_fullM(plant.model, plant.data, out)
    return out


@pytest.mark.parametrize("vertical", [0, 1])
def test_two_link_mass_matrix_is_the_textbook_one_and_changes_with_the_elbow(vertical):
    family = MULTI_PLANTS["two-link-arm"]
    values = family.validate({"vertical": vertical, "payload_kg": 1.3})
    plant = family.build(values)
    for shoulder, elbow in [(0.0, 0.0), (0.4, 1.2), (-1.0, -2.5), (2.0, 0.7)]:
        np.testing.assert_allclose(
            full_mass_matrix(plant, [shoulder, elbow]),
            TwoLinkArmFamily.mass_matrix(values, elbow),
            rtol=1e-12,
        )
    stretched = full_mass_matrix(plant, [0.0, 0.0])[0, 0]
    folded = full_mass_matrix(plant, [0.0, 2.5])[0, 0]
    assert stretched > 3 * folded  # the shoulder's inertia changes several-fold


def test_gravity_acts_on_both_joints_only_when_vertical():
    family = MULTI_PLANTS["two-link-arm"]
    for vertical in (0, 1):
        values = family.validate({"vertical": vertical})
        plant = family.build(values)
        for q in ([0.0, 0.0], [0.5, -0.9]):
            plant.reset()
            plant.data.qpos[:] = q
            mujoco.mj_forward(plant.model, plant.data)
            m1, l1 = values["upper_link_mass_kg"], values["upper_link_length_m"]
            m2, l2 = values["fore_link_mass_kg"], values["fore_link_length_m"]
            mp, g = values["payload_kg"], 9.81
            c1, c12 = math.cos(q[0]), math.cos(q[0] + q[1])
            g2 = (m2 * l2 / 2 + mp * l2) * g * c12
            g1 = (m1 * l1 / 2 + (m2 + mp) * l1) * g * c1 + g2
            expected = [g1, g2] if vertical else [0.0, 0.0]
            np.testing.assert_allclose(plant.data.qfrc_bias, expected, rtol=1e-12, atol=1e-12)


@pytest.mark.parametrize(("x_drive", "y_drive"), [(0, 1), (1, 0), (0, 0)])
def test_x_carries_y_and_each_drive_reflects_its_motor(x_drive, y_drive):
    family = MULTI_PLANTS["xy-stage"]
    v = family.validate({"x_drive": x_drive, "y_drive": y_drive, "payload_kg": 4.0})
    plant = family.build(v)
    arm = {}
    for axis, drive in (("x", x_drive), ("y", y_drive)):
        ratio = 2 * math.pi / v[f"{axis}_screw_lead_m"]
        arm[axis] = v[f"{axis}_rotor_inertia_kgm2"] * ratio**2 if drive == 0 else 0.0
        io = plant.ios[family.axes.index(axis)]
        if drive == 0:
            assert io.counts_per_unit == v[f"{axis}_encoder_counts_per_rev"] / v[
                f"{axis}_screw_lead_m"]  # fmt: skip
            assert plant.model.actuator_gear[io.ctrl_index, 0] == ratio
        else:
            assert io.counts_per_unit == v[f"{axis}_scale_counts_per_m"]
            assert io.torque_constant_nm_per_a == v[f"{axis}_force_constant_n_per_a"]
            assert plant.model.actuator_gear[io.ctrl_index, 0] == 1.0
    moving_y = v["y_carriage_mass_kg"] + v["payload_kg"]
    expected = np.diag([v["x_carriage_mass_kg"] + moving_y + arm["x"], moving_y + arm["y"]])
    for q in ([0.0, 0.0], [0.1, -0.15]):
        np.testing.assert_allclose(full_mass_matrix(plant, q), expected, rtol=1e-12)


@pytest.mark.parametrize("name", list(MULTI_PLANTS))
def test_in_place_edit_equals_a_fresh_compile(name):
    family = MULTI_PLANTS[name]
    rng = np.random.default_rng(11)
    a = family.sample(rng, base={"vertical": 1} if name == "two-link-arm" else None)
    b = family.sample(rng)
    b["x_drive" if name == "xy-stage" else "vertical"] = 1 - (
        a["x_drive"] if name == "xy-stage" else a["vertical"])  # fmt: skip
    edited = family.build(a, timestep_s=1e-4)
    model_id, data_id = id(edited.model), id(edited.data)
    edited.set_params(b)
    fresh = family.build(b, timestep_s=1e-4)
    assert (id(edited.model), id(edited.data)) == (model_id, data_id)
    assert edited.ios == fresh.ios
    for attr in ("body_mass", "body_inertia", "body_pos", "body_quat", "dof_armature",
                 "dof_damping", "dof_frictionloss", "jnt_range", "actuator_gear",
                 "actuator_ctrlrange", "dof_M0"):  # fmt: skip
        np.testing.assert_array_equal(getattr(edited.model, attr), getattr(fresh.model, attr))
    traj = []
    for plant in (edited, fresh):
        plant.reset()
        out = []
        for _ in range(400):
            for io in plant.ios:
                plant.data.ctrl[io.ctrl_index] = 0.3 * io.peak_torque_nm
            mujoco.mj_step(plant.model, plant.data)
            out.append(plant.data.qpos.copy())
        traj.append(np.array(out))
    np.testing.assert_array_equal(traj[0], traj[1])
    assert np.all(np.abs(traj[0][-1]) > 0)


def test_parameters_are_checked_and_named_per_axis():
    family = MULTI_PLANTS["two-link-arm"]
    with pytest.raises(PlantParameterError, match=r"5 <= elbow_gear_ratio <= 160.*got elbow_gear"):
        family.build({"elbow_gear_ratio": 2.0})
    with pytest.raises(PlantParameterError, match=r"vertical must be an integer with 0 <= vert"):
        family.validate({"vertical": 0.5})
    with pytest.raises(PlantParameterError, match="Did you mean shoulder_gear_ratio"):
        family.validate({"shoulder_gear_ratoi": 10})
    with pytest.raises(TypeError, match=r"2 axes \(x, y\): use plant.ios"):
        _ = MULTI_PLANTS["xy-stage"].build().io


def test_single_axis_commands_refuse_a_multi_axis_plant_in_one_line():
    with pytest.raises(KeyError) as info:
        get_plant("two-link-arm")
    text = info.value.args[0]
    assert "multi-axis plant (2 axes: shoulder, elbow)" in text and "\n" not in text
    assert ", ".join(PLANTS) in text
    assert not set(MULTI_PLANTS) & set(PLANTS)  # tune, check, simulate and envs iterate PLANTS


@pytest.mark.parametrize("name", list(MULTI_PLANTS))
def test_the_motors_move_the_default_moves_with_headroom(name):
    """Every axis, nominal, both mountings / drives, and the worst corner of the default
    sampling box: at most 80 % of its motor's peak (docs/plants.md)."""
    family = MULTI_PLANTS[name]
    other = {"vertical": 1} if name == "two-link-arm" else {"x_drive": 1, "y_drive": 0}
    for needs in (required_peak_efforts(family), required_peak_efforts(family, other)):
        assert all(n.feasible for n in needs), [n.text() for n in needs]
    worst = worst_sampled_efforts(family)
    assert all(n.feasible for n in worst), [n.text() for n in worst]
    # and a heavy payload on a vertical arm is refused by the same figure
    if name == "two-link-arm":
        heavy = required_peak_efforts(family, {"vertical": 1, "payload_kg": 5.0,
                                               "upper_link_length_m": 0.8})  # fmt: skip
        assert not heavy[0].feasible and heavy[0].gravity_nm > 0.5


def test_coupling_terms_are_in_the_need():
    family = MULTI_PLANTS["two-link-arm"]
    (shoulder, elbow) = required_peak_efforts(family)
    m = TwoLinkArmFamily.mass_matrix(family.nominal(), 0.0)  # stretched: the largest inertia
    acc = [20.0, 30.0]  # the default moves' accelerations
    assert shoulder.inertia_nm == pytest.approx((m[0, 0] * acc[0] + m[0, 1] * acc[1]) / 50)
    assert elbow.inertia_nm == pytest.approx((m[1, 0] * acc[0] + m[1, 1] * acc[1]) / 30)


def test_the_need_of_a_commanded_trajectory_is_its_inverse_dynamics():
    """A bang-bang shoulder move from rest to rest, the elbow stretched: the shoulder needs
    M_00 * a, the elbow the coupling |M_10| * a (no gravity, no Coriolis at the elbow's 0)."""
    family = MULTI_PLANTS["two-link-arm"]
    plant = family.build()
    dt, a, half = 0.0002, 20.0, 0.1
    t = np.arange(0.0, 2 * half + dt / 2, dt)
    q0 = np.where(t <= half, 0.5 * a * t**2, a * half**2 - 0.5 * a * (2 * half - t) ** 2)
    q = np.stack([q0, np.zeros_like(q0)], axis=1)
    shoulder, elbow = commanded_efforts(plant, [q], dt)
    m = TwoLinkArmFamily.mass_matrix(family.nominal(), 0.0)
    assert shoulder.inertia_nm == pytest.approx(m[0, 0] * a / 50, rel=1e-6)
    assert elbow.inertia_nm == pytest.approx(abs(m[1, 0]) * a / 30, rel=1e-6)
    assert shoulder.gravity_nm == pytest.approx(0.0, abs=1e-9)
    assert shoulder.viscous_nm > 0 and elbow.viscous_nm == 0
    # the bound from the same move's specification is never below it
    need = required_peak_efforts(
        family,
        moves=(
            (SimpleNamespace(distance=a * half**2, max_velocity=a * half, max_acceleration=a),),
            (SimpleNamespace(distance=0.0, max_velocity=0.0, max_acceleration=0.0),),
        ),
    )
    assert need[0].total_nm >= shoulder.total_nm * (1 - 1e-9)
    with pytest.raises(ValueError, match=r"\(n_ticks, 2\)"):
        commanded_efforts(plant, [q[:, :1]], dt)


@pytest.mark.parametrize("name", list(MULTI_PLANTS))
def test_docs_table_matches_the_code(name):
    assert plant_table_markdown(MULTI_PLANTS[name]) in DOC
    assert f"### `{name}`" in DOC


def test_docs_feasibility_table_matches_the_code():
    from servogym.plants._multi import multi_feasibility_table_markdown

    start = DOC.index("<!-- multi-axis feasibility table")
    end = DOC.index("<!-- end of multi-axis feasibility table -->")
    assert multi_feasibility_table_markdown() in DOC[start:end]
