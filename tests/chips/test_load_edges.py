"""The parameter-file loader's edges: a misspelt format's suggestion, and a second axis
(PMAC: motor) read back from a file that addresses it."""

from __future__ import annotations

import pytest

from servogym.chips import ParameterError, get_chip
from servogym.chips._load import load_params_file


def test_a_misspelt_format_gets_the_closest_name_and_the_list():
    with pytest.raises(ParameterError) as err:
        load_params_file("{}", fmt="ivr")
    message = str(err.value)
    assert message.endswith("got --format 'ivr'. Did you mean 'ivar'?")
    assert "ivar (pmac)" in message and "6250 (parker6k)" in message
    with pytest.raises(ParameterError, match=r"got --format 'zzzz'\.$"):  # nothing close
        load_params_file("{}", fmt="zzzz")


@pytest.mark.parametrize(
    ("model", "fmt", "register", "value"),
    [
        ("TurboPMAC2", "ivar", "proportional_gain", 4321),  # I230 of motor 2
        ("6250", "6250", "sgp", 37),  # 2SGP of axis 2
        ("6K", "6k", "sgp", 37),
    ],
)
def test_a_second_axis_is_read_back_with_axis(model, fmt, register, value):
    family, model = get_chip(model)
    params = family.make_params(model, {register: value})
    text = family.export_module.export(params, fmt, axis=2)
    loaded = load_params_file(text, fmt=fmt, model=model, axis=2)
    assert getattr(loaded.params, register) == value
    assert loaded.provenance["file_format"] == fmt
    # The same through detection, with the axis named as PMAC names it (motor = axis).
    assert getattr(load_params_file(text, model=model, axis=2).params, register) == value
