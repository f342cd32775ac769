"""Editing a compiled plant in place is exactly like compiling the new instance afresh."""

import mujoco
import numpy as np
import pytest

from servogym.plants import PLANTS

from .helpers import rollout

FAMILIES = list(PLANTS)
N_STEPS = 400

# Statistics the compiler derives from geometry alone, for the viewer's camera and decor
# sizes; MuJoCo's dynamics never read them. Only the arm's link_length_m changes geometry.
VISUAL_ONLY = {"stat.meansize", "stat.extent", "stat.center"}


def model_differences(a: mujoco.MjModel, b: mujoco.MjModel) -> list[str]:
    """Names of the model arrays and statistics that differ between two models."""
    out = []
    for name in dir(a):
        va = getattr(a, name, None)
        if name.startswith("_") or not isinstance(va, np.ndarray):
            continue
        vb = getattr(b, name)
        if va.shape != vb.shape or not np.array_equal(va, vb, equal_nan=True):
            out.append(name)
    for name in ("meaninertia", "meanmass", "meansize", "extent", "center"):
        if not np.array_equal(getattr(a.stat, name), getattr(b.stat, name)):
            out.append(f"stat.{name}")
    return out


def all_params(family):
    return [p.name for p in family.params]


@pytest.mark.parametrize("name", FAMILIES)
def test_set_params_is_bit_identical_to_a_fresh_compile(name):
    family = PLANTS[name]
    rng = np.random.default_rng(2024)
    plant = family.build(timestep_s=200e-6)
    for episode in range(3):
        values = family.sample(rng, randomise=all_params(family))
        torque = (0.2 if episode % 2 else -0.15) * plant.io.peak_torque_nm
        rollout(plant, 0.1, 50)  # dirty state from a previous episode
        plant.set_params(values)
        fresh = family.build(values, timestep_s=200e-6)
        assert plant.io == fresh.io
        assert set(model_differences(plant.model, fresh.model)) <= VISUAL_ONLY
        for tau in (torque, 0.0):  # driven, then coasting into stiction, limits or a fall
            np.testing.assert_array_equal(
                rollout(plant, tau, N_STEPS), rollout(fresh, tau, N_STEPS)
            )
        np.testing.assert_array_equal(plant.data.qvel, fresh.data.qvel)
        np.testing.assert_array_equal(plant.data.efc_force, fresh.data.efc_force)


@pytest.mark.parametrize("name", FAMILIES)
def test_kept_spec_compiles_to_the_current_instance(name):
    family = PLANTS[name]
    plant = family.build()
    plant.set_params(family.sample(np.random.default_rng(5)))
    plant.set_timestep(500e-6)
    recompiled = plant.spec.compile()
    assert set(model_differences(plant.model, recompiled)) <= VISUAL_ONLY
    fresh = family.build(plant.values, timestep_s=500e-6)
    np.testing.assert_array_equal(rollout(plant, 0.05, 200), rollout(fresh, 0.05, 200))


@pytest.mark.parametrize("name", FAMILIES)
def test_set_params_does_not_recompile_or_reallocate(name):
    family = PLANTS[name]
    plant = family.build()
    model, data, spec = plant.model, plant.data, plant.spec
    fields = ("body_mass", "body_inertia", "dof_damping", "dof_frictionloss", "jnt_range")
    model_ptrs = {f: getattr(model, f).ctypes.data for f in (*fields, "actuator_gear")}
    data_ptrs = {f: getattr(data, f).ctypes.data for f in ("qpos", "qvel", "ctrl")}
    plant.set_params(family.sample(np.random.default_rng(1), randomise=all_params(family)))
    assert plant.model is model and plant.data is data and plant.spec is spec
    assert {f: getattr(model, f).ctypes.data for f in model_ptrs} == model_ptrs
    assert {f: getattr(data, f).ctypes.data for f in data_ptrs} == data_ptrs


@pytest.mark.parametrize("name", FAMILIES)
def test_set_params_merges_and_resets(name):
    family = PLANTS[name]
    plant = family.build()
    rollout(plant, 0.3 * plant.io.peak_torque_nm, 100)
    p = family.randomised()[0]
    plant.set_params({p: family.param(p).low})
    assert plant.values == {**family.nominal(), p: family.param(p).low}
    assert plant.data.time == 0.0
    assert plant.data.qpos[plant.io.qpos_adr] == plant.io.start_qpos
    assert not plant.data.qvel.any() and not plant.data.ctrl.any()
    plant.set_params(**{p: family.param(p).high})
    assert plant.values[p] == family.param(p).high


@pytest.mark.parametrize("name", ["vertical-axis", "arm"])
def test_payload_mass_changes_the_dynamics(name):
    """mj_setConst took effect: the same torque accelerates a heavier payload less."""
    family = PLANTS[name]
    plant = family.build()
    accelerations = []
    for payload in (family.param("payload_kg").low, family.param("payload_kg").high):
        plant.set_params(payload_kg=payload)
        plant.data.ctrl[plant.io.ctrl_index] = 0.5 * plant.io.peak_torque_nm
        mujoco.mj_forward(plant.model, plant.data)
        accelerations.append(plant.data.qacc[plant.io.qvel_adr])
        i = plant.model.body("payload").id
        assert plant.model.body_mass[i] == payload
        assert plant.model.body_subtreemass[i] == payload  # derived by mj_setConst
    assert accelerations[0] > 0 > accelerations[1] or accelerations[0] > 2 * accelerations[1]


@pytest.mark.parametrize("name", ["rotary", "two-mass"])
def test_load_inertia_changes_the_dynamics(name):
    family = PLANTS[name]
    plant = family.build()
    responses = []
    for inertia in (family.param("load_inertia_kgm2").low, family.param("load_inertia_kgm2").high):
        plant.set_params(load_inertia_kgm2=inertia)
        responses.append(rollout(plant, 0.5, 200)[-1, plant.io.qpos_adr])
    assert responses[0] > 10 * responses[1] > 0


def test_inertia_scales_with_mass():
    family = PLANTS["vertical-axis"]
    plant = family.build()
    i = plant.model.body("payload").id
    inertia = plant.model.body_inertia[i].copy()
    plant.set_params(payload_kg=2 * family.nominal()["payload_kg"])
    np.testing.assert_allclose(plant.model.body_inertia[i], 2 * inertia, rtol=1e-15)


def test_keep_state_changes_the_instance_without_moving_the_axis():
    # A payload picked up at rest mid-sequence: state carries over, dynamics change.
    from servogym.plants import get_plant

    plant = get_plant("vertical-axis").build()
    d = plant.data
    for _ in range(50):
        d.ctrl[plant.io.ctrl_index] = 0.3
        mujoco.mj_step(plant.model, d)
    qpos, qvel, time = d.qpos.copy(), d.qvel.copy(), d.time
    mass_before = plant.model.body_subtreemass.copy()
    plant.set_params(payload_kg=8.0, keep_state=True)
    np.testing.assert_array_equal(d.qpos, qpos)
    np.testing.assert_array_equal(d.qvel, qvel)
    assert d.time == time
    assert not np.array_equal(plant.model.body_subtreemass, mass_before)
    plant.set_params(payload_kg=8.0)
    assert d.time == 0.0 and np.all(d.qvel == 0)
