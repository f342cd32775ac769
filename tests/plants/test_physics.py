"""The plants behave as their docs say: gravity, resonance, travel limits, stability."""

import itertools
import math

import mujoco
import numpy as np
import pytest

from servogym.plants import PLANTS, TwoMassFamily

from .helpers import holding_torque_nm, rollout

FAMILIES = list(PLANTS)
G = 9.81


def test_horizontal_axes_need_no_holding_torque():
    for name in ("rotary", "two-mass"):
        plant = PLANTS[name].build()
        for q in (-1.0, 0.0, 2.5):
            assert holding_torque_nm(plant, q) == pytest.approx(0.0, abs=1e-12)


def test_vertical_axis_holding_torque_is_constant_and_matches_the_formula():
    family = PLANTS["vertical-axis"]
    plant = family.build()
    v = plant.values
    expected = (v["carriage_mass_kg"] + v["payload_kg"]) * G * v["screw_lead_m"] / (2 * math.pi)
    for z in (-0.1, 0.0, 0.15):
        assert holding_torque_nm(plant, z) == pytest.approx(expected, rel=1e-12)
    plant.set_params(payload_kg=8.0)
    heavier = (v["carriage_mass_kg"] + 8.0) * G * v["screw_lead_m"] / (2 * math.pi)
    assert holding_torque_nm(plant, 0.0) == pytest.approx(heavier, rel=1e-12)


def test_arm_holding_torque_depends_on_angle():
    plant = PLANTS["arm"].build()
    v = plant.values
    moment = (v["link_mass_kg"] / 2 + v["payload_kg"]) * v["link_length_m"] * G
    torques = []
    for angle in (-1.0, 0.0, 0.5, 1.2):
        tau = holding_torque_nm(plant, angle)
        assert tau == pytest.approx(moment * math.cos(angle) / v["gear_ratio"], rel=1e-12)
        torques.append(tau)
    assert len(set(torques)) == 4 and max(torques) == torques[1]


@pytest.mark.parametrize("name", ["vertical-axis", "arm"])
def test_gravity_holds_with_the_holding_torque_and_falls_without(name):
    plant = PLANTS[name].build(timestep_s=154e-6)
    tau = holding_torque_nm(plant, 0.0)
    assert tau > 0
    plant.reset()
    held = rollout(plant, tau, 3000)[:, plant.io.qpos_adr]
    assert np.abs(held).max() * plant.io.counts_per_unit < 1.0  # within one encoder count
    plant.reset()
    fallen = rollout(plant, 0.0, 3000)[:, plant.io.qpos_adr]
    assert fallen[-1] < -0.01


def test_two_mass_resonance_from_the_model_matches_the_formula():
    family = PLANTS["two-mass"]
    rng = np.random.default_rng(11)
    plant = family.build()
    for values in [family.nominal()] + [family.sample(rng) for _ in range(5)]:
        plant.set_params(values)
        m = plant.model
        mujoco.mj_forward(m, plant.data)
        mass = np.zeros((m.nv, m.nv))
        for i in range(m.nv):  # column i of the joint-space inertia matrix
            column = np.zeros(m.nv)
            mujoco.mj_mulM(m, plant.data, column, np.eye(m.nv)[i])
            mass[:, i] = column
        stiffness = np.diag([0.0, m.jnt_stiffness[m.joint("shaft").id]])
        omega2 = np.linalg.eigvals(np.linalg.solve(mass, stiffness)).real.max()
        f_model = math.sqrt(omega2) / (2 * math.pi)
        assert f_model == pytest.approx(TwoMassFamily.resonance_hz(values), rel=1e-9)
    assert TwoMassFamily.resonance_hz(family.nominal()) == pytest.approx(100, abs=2)


def test_two_mass_free_vibration_rings_at_the_resonance():
    family = PLANTS["two-mass"]
    plant = family.build(
        {"coulomb_friction_nm": 1e-4, "viscous_friction_nms": 1e-6}, timestep_s=50e-6
    )
    plant.data.qpos[plant.model.joint("shaft").qposadr[0]] = 1e-3  # initial twist
    twist = rollout(plant, 0.0, 2000)[:, plant.model.joint("shaft").qposadr[0]]
    # The first 0.1 s: later the twist is too small to overcome the rotor's Coulomb friction,
    # the rotor sticks and the load rings alone at sqrt(k / J2) / (2*pi).
    up = np.flatnonzero((twist[:-1] < 0) & (twist[1:] >= 0))
    assert len(up) >= 8
    period_s = (up[-1] - up[0]) / (len(up) - 1) * plant.timestep_s
    assert 1 / period_s == pytest.approx(TwoMassFamily.resonance_hz(plant.values), rel=0.01)


def test_two_mass_resonance_spans_tens_to_hundreds_of_hz():
    family = PLANTS["two-mass"]
    names = ("stiffness_nm_per_rad", "rotor_inertia_kgm2", "load_inertia_kgm2")
    freqs = [
        TwoMassFamily.resonance_hz(
            dict(
                zip(
                    names,
                    (
                        family.param(n).low if c else family.param(n).high
                        for n, c in zip(names, corner, strict=True)
                    ),
                    strict=True,
                )
            )
        )
        for corner in itertools.product((0, 1), repeat=3)
    ]
    assert 15 < min(freqs) < 20 and 300 < max(freqs) < 320  # the 17..318 Hz of the docs


@pytest.mark.parametrize("name", FAMILIES)
def test_travel_limits_stop_motion(name):
    plant = PLANTS[name].build(timestep_s=154e-6)
    for sign, limit in ((1, plant.io.travel_max), (-1, plant.io.travel_min)):
        plant.reset()
        q = rollout(plant, sign * plant.io.peak_torque_nm, 20000)[:, plant.io.qpos_adr]
        assert abs(q[-1] - limit) < 0.01 * (plant.io.travel_max - plant.io.travel_min)
        assert abs(plant.data.qvel[plant.io.qvel_adr]) < 1e-3
        assert sign * (q[-1] - q[-1000]) < 1e-6  # stopped, not creeping on


def corners(family, rng, n):
    """``n`` random corners of the legal ranges (every parameter at its low or high end)."""
    for _ in range(n):
        yield {p.name: (p.high if rng.random() < 0.5 else p.low) for p in family.params}


@pytest.mark.parametrize("name", FAMILIES)
def test_stable_at_700us_in_the_corners_of_the_ranges(name):
    """Free motion loses energy at the longest servo period, in every corner of the ranges.

    A numerically unstable integration would grow the energy exponentially. The two-mass
    corners include the stiffest shaft on the lightest inertias (318 Hz).
    """
    family = PLANTS[name]
    plant = family.build(timestep_s=700e-6)
    model, data = plant.model, plant.data
    model.opt.enableflags |= mujoco.mjtEnableBit.mjENBL_ENERGY  # diagnostics only
    rng = np.random.default_rng(3)
    for values in [*corners(family, rng, 8), stiffest_two_mass(family)]:
        plant.set_params(values)
        data.qvel[plant.io.qvel_adr] = 0.2 * min(plant.io.travel_max, -plant.io.travel_min)
        if name == "two-mass":
            data.qpos[model.joint("shaft").qposadr[0]] = 0.01
        mujoco.mj_forward(model, data)
        start = data.energy.sum()
        energy = []
        for _ in range(1500):
            mujoco.mj_step(model, data)
            energy.append(data.energy.sum())
        assert np.isfinite(energy).all()
        assert data.warning[mujoco.mjtWarning.mjWARN_BADQACC].number == 0
        assert max(energy[-100:]) - start <= 0.5 * abs(start) + 1e-9, values


@pytest.mark.parametrize("name", FAMILIES)
def test_driven_at_700us_stays_finite(name):
    """Driven at peak torque into the end stops, nothing diverges (and nothing auto-resets)."""
    family = PLANTS[name]
    plant = family.build(timestep_s=700e-6)
    for values in [*corners(family, np.random.default_rng(4), 4), stiffest_two_mass(family)]:
        plant.set_params(values)
        torque = plant.io.peak_torque_nm
        for k in range(1500):
            plant.data.ctrl[0] = torque * math.sin(2 * math.pi * 20 * k * plant.timestep_s)
            mujoco.mj_step(plant.model, plant.data)
        assert np.isfinite(plant.data.qpos).all() and np.isfinite(plant.data.qvel).all()
        assert plant.data.warning[mujoco.mjtWarning.mjWARN_BADQACC].number == 0
        assert plant.io.travel_min - 1 < plant.data.qpos[0] < plant.io.travel_max + 1


def stiffest_two_mass(family):
    """The highest resonance of the two-mass family (its other values nominal)."""
    if family.name != "two-mass":
        return family.nominal()
    return family.validate(
        {
            "stiffness_nm_per_rad": family.param("stiffness_nm_per_rad").high,
            "rotor_inertia_kgm2": family.param("rotor_inertia_kgm2").low,
            "load_inertia_kgm2": family.param("load_inertia_kgm2").low,
            "shaft_damping_nms": family.param("shaft_damping_nms").low,
        }
    )


@pytest.mark.parametrize("name", ["vertical-axis", "arm"])
def test_the_motor_can_hold_every_payload_of_an_otherwise_nominal_plant(name):
    family = PLANTS[name]
    plant = family.build()
    for payload in (family.param("payload_kg").low, family.param("payload_kg").high):
        plant.set_params(payload_kg=payload)
        worst = max(abs(holding_torque_nm(plant, q)) for q in (plant.io.travel_min, 0.0))
        assert 0 < worst < 0.8 * plant.io.peak_torque_nm
