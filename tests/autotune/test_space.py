"""The search space: registers of any chip on u in [-1, 1], legal by construction."""

from __future__ import annotations

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from servogym.autotune import UNIT_PREFIX, SearchSpace
from servogym.chips import ParameterError
from servogym.chips._family import all_models

MODELS = sorted(all_models())


@pytest.mark.parametrize("model", MODELS)
def test_default_space_is_the_tunable_registers(model):
    family = all_models()[model]
    space = SearchSpace.for_chip(model)
    assert space.names == tuple(s.name for s in family.parameter_space(model).tunable())
    assert space.unit_names == tuple(UNIT_PREFIX + n for n in space.names)
    assert all(d.low == -1.0 and d.high == 1.0 for d in space.distributions().values())


@pytest.mark.parametrize("model", MODELS)
@settings(max_examples=60, deadline=None)
@given(data=st.data())
def test_every_point_of_the_unit_cube_is_a_legal_set(model, data):
    space = SearchSpace.for_chip(model)
    unit = {u: data.draw(st.floats(-1.0, 1.0, allow_nan=False), label=u) for u in space.unit_names}
    values = space.values_from_unit(unit)
    chip_space = space.family.parameter_space(space.chip_model)
    for name, value in values.items():
        assert chip_space[name].validate(value) == value
    space.make_params(values)  # the family accepts it as a whole


@pytest.mark.parametrize("model", MODELS)
def test_zero_stays_reachable_and_defaults_round_trip(model):
    space = SearchSpace.for_chip(model)
    lowest = space.values_from_unit({u: -1.0 for u in space.unit_names})
    for spec in space.specs:
        if spec.log and spec.low == 0:
            assert lowest[spec.name] == 0, spec.name
    defaults = space.family.parameter_space(space.chip_model).defaults()
    back = space.values_from_unit(space.to_unit(defaults))
    assert all(back[n] == defaults[n] for n in space.names)


def test_fixed_registers_leave_the_search_and_keep_their_value():
    space = SearchSpace.for_chip("MC2100", fixed={"bias": 0, "kaff": 12})
    assert "bias" not in space.names and "kaff" not in space.names
    values = space.values_from_unit({u: 0.3 for u in space.unit_names})
    assert values["bias"] == 0 and values["kaff"] == 12


def test_a_subset_may_name_a_register_that_is_not_tunable_by_default():
    space = SearchSpace.for_chip("mc2100", names=["kp", "motor_limit"])
    assert space.chip_model == "MC2100"
    assert space.names == ("kp", "motor_limit")


def test_errors_name_the_register_the_value_and_the_range():
    with pytest.raises(ParameterError, match=r"0 <= kp <= 32767.*kp=40000"):
        SearchSpace.for_chip("MC2100", fixed={"kp": 40000})
    with pytest.raises(ParameterError, match="Did you mean kp"):
        SearchSpace.for_chip("MC2100", names=["kpp"])
    with pytest.raises(ParameterError, match="unknown chip model 'MC9999'"):
        SearchSpace.for_chip("MC9999")
    with pytest.raises(ParameterError, match="search space of MC2100 is empty"):
        SearchSpace.for_chip("MC2100", names=["kp"], fixed={"kp": 1})
