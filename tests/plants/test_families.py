"""Registry, parameters, validation and sampling of every plant family."""

import json
import subprocess
import sys

import numpy as np
import pytest

from servogym.plants import (
    PLANTS,
    AxisIO,
    Plant,
    PlantFamily,
    PlantParameterError,
    describe_plants,
    get_plant,
)

FAMILIES = list(PLANTS)


def test_registry_has_the_four_families():
    assert set(PLANTS) == {"rotary", "two-mass", "vertical-axis", "arm"}
    for name, family in PLANTS.items():
        assert isinstance(family, PlantFamily) and family.name == name
        assert get_plant(name) is family


def test_get_plant_suggests_close_names():
    with pytest.raises(KeyError, match="Did you mean two-mass"):
        get_plant("two_mass")
    with pytest.raises(KeyError, match="rotary, two-mass, vertical-axis, arm"):
        get_plant("conveyor")


@pytest.mark.parametrize("name", FAMILIES)
def test_params_are_consistent(name):
    family = PLANTS[name]
    names = [p.name for p in family.params]
    assert len(names) == len(set(names))
    for required in (
        "rotor_inertia_kgm2",
        "torque_constant_nm_per_a",
        "peak_current_a",
        "current_bandwidth_hz",
        "encoder_counts_per_rev",
        f"travel_min_{family.joint_unit}",
        f"travel_max_{family.joint_unit}",
    ):
        assert required in names
    assert any("viscous_friction" in n for n in names)
    assert any("coulomb_friction" in n for n in names)
    assert family.randomised(), "every family randomises something by default"
    for p in family.params:
        assert p.low <= p.nominal <= p.high and p.unit and p.doc
        assert isinstance(p.nominal, int) == p.integer
    unit = family.joint_unit
    assert family.param(f"travel_min_{unit}").high < 0 < family.param(f"travel_max_{unit}").low


@pytest.mark.parametrize("name", FAMILIES)
def test_nominal_builds_and_validates(name):
    family = PLANTS[name]
    assert family.validate(family.nominal()) == family.nominal()
    assert family.validate() == family.nominal()
    plant = family.build()
    assert isinstance(plant, Plant) and plant.values == family.nominal()
    assert isinstance(plant.io, AxisIO)
    io = plant.io
    assert io.qpos_adr == plant.model.joint("motor").qposadr[0]
    assert io.qvel_adr == plant.model.joint("motor").dofadr[0]
    assert 0 <= io.ctrl_index < plant.model.nu
    assert io.travel_min < io.start_qpos < io.travel_max
    assert io.amp_amps_per_count == io.peak_current_a / 32768
    assert plant.data.qpos[io.qpos_adr] == io.start_qpos


@pytest.mark.parametrize("name", FAMILIES)
def test_sample_is_legal_and_deterministic(name):
    family = PLANTS[name]
    a = family.sample(np.random.default_rng(7))
    b = family.sample(np.random.default_rng(7))
    c = family.sample(np.random.default_rng(8))
    assert a == b
    assert a != c
    assert family.validate(a) == a
    for p in family.params:
        if not p.randomised:
            assert a[p.name] == p.nominal
    assert all(a[n] != family.nominal()[n] for n in family.randomised())
    plant = family.build(a)
    assert plant.values == a


@pytest.mark.parametrize("name", FAMILIES)
def test_sample_covers_the_range_and_scale_shrinks_it(name):
    family = PLANTS[name]
    rng = np.random.default_rng(0)
    everything = [p.name for p in family.params]
    draws = [family.sample(rng, randomise=everything) for _ in range(200)]
    for p in family.params:
        xs = np.array([d[p.name] for d in draws], dtype=float)
        assert p.sample_low <= xs.min() and xs.max() <= p.sample_high
        assert p.low <= p.sample_low and p.sample_high <= p.high
        lo, hi = (p.sample_low, p.sample_high)
        if p.distribution == "loguniform":
            lo, hi = np.log(lo), np.log(hi)
        t = (np.log(xs) if p.distribution == "loguniform" else xs) - lo
        assert t.min() < 0.1 * (hi - lo) and t.max() > 0.9 * (hi - lo), p.name
    assert family.sample(rng, 0.0, randomise=everything) == family.nominal()
    small = family.sample(rng, 0.01)
    for n in family.randomised():
        p = family.param(n)
        assert abs(small[n] - p.nominal) <= 0.05 * max(p.nominal, p.high - p.low)


def test_sample_in_a_fresh_process_is_the_same():
    code = (
        "import json, numpy as np; from servogym.plants import PLANTS; "
        "print(json.dumps({n: f.sample(np.random.default_rng(123)) for n, f in PLANTS.items()}))"
    )
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    here = {n: f.sample(np.random.default_rng(123)) for n, f in PLANTS.items()}
    assert json.loads(out.stdout) == json.loads(json.dumps(here))


def test_sample_argument_errors():
    family = PLANTS["arm"]
    with pytest.raises(TypeError, match=r"numpy\.random\.Generator"):
        family.sample(np.random.RandomState(0))
    with pytest.raises(ValueError, match=r"0 <= scale <= 1; got scale=1.5"):
        family.sample(np.random.default_rng(0), 1.5)
    with pytest.raises(PlantParameterError, match="Did you mean payload_kg"):
        family.sample(np.random.default_rng(0), randomise=["payload_kgs"])


def test_unknown_parameter_names_close_matches():
    with pytest.raises(
        PlantParameterError, match=r"no parameter 'payload'.*Did you mean payload_kg"
    ):
        PLANTS["vertical-axis"].validate({"payload": 3.0})
    with pytest.raises(PlantParameterError, match="its parameters are load_inertia_kgm2, "):
        PLANTS["rotary"].validate({"inertia": 1e-4})


def test_out_of_range_names_param_value_and_range():
    with pytest.raises(
        PlantParameterError,
        match=r"payload_kg must satisfy 0\.5 <= payload_kg <= 10 \(kg\), the legal range for "
        r"the 'vertical-axis' plant family; got payload_kg=20\.0",
    ):
        PLANTS["vertical-axis"].validate({"payload_kg": 20.0})
    with pytest.raises(PlantParameterError, match=r"1 <= stiffness_nm_per_rad <= 20"):
        PLANTS["two-mass"].build({"stiffness_nm_per_rad": 0.5})
    with pytest.raises(PlantParameterError, match=r"got load_inertia_kgm2=nan"):
        PLANTS["rotary"].validate({"load_inertia_kgm2": float("nan")})


def test_wrong_types_are_rejected():
    family = PLANTS["rotary"]
    with pytest.raises(PlantParameterError, match="encoder_counts_per_rev must be an integer"):
        family.validate({"encoder_counts_per_rev": 4096.0})
    with pytest.raises(PlantParameterError, match="peak_current_a must be a real number"):
        family.validate({"peak_current_a": "10"})
    with pytest.raises(PlantParameterError, match="of type bool"):
        family.validate({"peak_current_a": True})
    with pytest.raises(PlantParameterError, match="values must be a mapping"):
        family.validate([("peak_current_a", 10.0)])
    assert (
        family.validate({"encoder_counts_per_rev": np.int64(4096)})["encoder_counts_per_rev"]
        == 4096
    )


def test_set_params_rejects_and_leaves_the_plant_unchanged():
    plant = PLANTS["arm"].build()
    before = dict(plant.values)
    mass = plant.model.body_mass.copy()
    with pytest.raises(PlantParameterError, match=r"0\.05 <= payload_kg <= 5"):
        plant.set_params(payload_kg=50.0)
    assert plant.values == before
    np.testing.assert_array_equal(plant.model.body_mass, mass)


def test_timestep_range():
    plant = PLANTS["rotary"].build(timestep_s=154e-6)
    assert plant.model.opt.timestep == 154e-6
    plant.set_timestep(51.2e-6)
    assert plant.model.opt.timestep == 51.2e-6 == plant.timestep_s
    with pytest.raises(ValueError, match=r"1e-06 <= dt_s|timestep_s must satisfy"):
        plant.set_timestep(0.01)
    with pytest.raises(ValueError, match=r"got timestep_s=0"):
        PLANTS["rotary"].build(timestep_s=0)


def test_describe_plants_is_json_ready_and_complete():
    described = describe_plants()
    assert [d["name"] for d in described] == list(PLANTS)
    text = json.dumps(described)
    for entry, family in zip(json.loads(text), PLANTS.values(), strict=True):
        assert entry["description"] == family.description
        assert [p["name"] for p in entry["params"]] == [p.name for p in family.params]
        for row, p in zip(entry["params"], family.params, strict=True):
            assert (row["unit"], row["nominal"], row["low"], row["high"]) == (
                p.unit,
                p.nominal,
                p.low,
                p.high,
            )
            assert row["type"] in ("int", "float") and row["randomised"] == p.randomised
