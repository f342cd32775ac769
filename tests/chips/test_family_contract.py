"""Cases every chip family must pass (STYLE.md: shared cases, as optuna.testing does).

The list of families comes from the registry, never a hand-written list: a new family is held
to the same contract the day it registers.
"""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from servogym.chips import ParameterError, all_models, families

MODELS = sorted(all_models())


def random_params(family, model, rng: np.random.Generator):
    """A legal set: every tunable register drawn through the shared [-1, 1] mapping."""
    space = family.parameter_space(model)
    values = {s.name: s.from_unit(float(rng.uniform(-1, 1))) for s in space.tunable()}
    return family.make_params(model, values)


def inputs(rng: np.random.Generator, n: int):
    cp = np.cumsum(rng.integers(-50, 51, n)).astype(np.int64)
    ap = cp - rng.integers(-300, 301, n)
    v = rng.integers(-(2**20), 2**20, n).astype(np.int64)
    a = rng.integers(-(2**16), 2**16, n).astype(np.int64)
    return cp, ap, v, a


@pytest.mark.parametrize("model", MODELS)
@settings(max_examples=8, deadline=None)
@given(seed=st.integers(0, 2**32 - 1))
def test_kernel_equals_reference_for_every_assumption_setting(model, seed):
    from servogym.sim._loop import closed_loop  # noqa: F401  (the loop knows every family)

    family = all_models()[model]
    rng = np.random.default_rng(seed)
    params = random_params(family, model, rng)
    cp, ap, v, a = inputs(rng, 200)
    for asm in family.assumptions_type.all_settings():
        ref = family.reference_filter(params, asm)
        expected = [ref.step(int(c), int(x), int(y), int(z)) for c, x, y, z in
                    zip(cp, ap, v, a, strict=True)]  # fmt: skip
        state = family.new_state()
        p, codes = family.kernel_arrays(params, asm)
        got = [_step(family, state, p, codes, c, x, y, z) for c, x, y, z in
               zip(cp, ap, v, a, strict=True)]  # fmt: skip
        assert got == expected, f"{model} {asm}"
        assert all(-32768 <= c <= 32767 for c in expected)


def _step(family, state, p, codes, c, x, y, z):
    from servogym.chips.parker6k._kernel import parker6k_step
    from servogym.chips.pmac._kernel import pmac_step
    from servogym.chips.pmd._kernel import pmd_step

    step = {"pmd": pmd_step, "pmac": pmac_step, "parker6k": parker6k_step}[family.name]
    return int(step(state, p, codes, c, x, y, z))


def test_every_family_has_a_kernel_here():
    assert set(families()) == {"pmd", "pmac", "parker6k"}, "add the new family's step to _step"


@pytest.mark.parametrize("model", MODELS)
def test_every_export_format_imports_back_identically(model):
    family = all_models()[model]
    params = random_params(family, model, np.random.default_rng(1))
    exported = 0
    for fmt in family.formats:
        try:
            text = family.export(params, fmt, assumptions=family.default_assumptions())
        except ParameterError as exc:
            # A format of another model of the family (the 6K's axis-prefixed file on a
            # 6250) is refused, naming the model; never written wrongly.
            assert model in str(exc), exc
            continue
        assert family.import_params(text, fmt, model) == params, fmt
        exported += 1
    assert exported >= 2  # JSON and at least one hardware format


@pytest.mark.parametrize("model", MODELS)
def test_every_tunable_register_refuses_values_outside_its_range(model):
    family = all_models()[model]
    for spec in family.parameter_space(model).tunable():
        for bad in (spec.low - 1, spec.high + 1):
            with pytest.raises(ParameterError, match=f"{spec.low} <= {spec.name} <= {spec.high}"):
                family.make_params(model, {spec.name: bad})


@pytest.mark.parametrize("model", MODELS)
def test_defaults_round_trip_through_the_unit_mapping(model):
    family = all_models()[model]
    space = family.parameter_space(model)
    for spec in space.tunable():
        if spec.log and spec.default < 0:
            continue  # a log-scaled register searches 0 and positive values only
        assert spec.from_unit(spec.to_unit(spec.default)) == spec.default, spec.name


@pytest.mark.parametrize("model", MODELS)
def test_parameter_space_is_built_once_per_model_and_differs_between_models(model):
    # envs read the space every step, so the register table keeps each model's space
    family = all_models()[model]
    space = family.parameter_space(model)
    assert family.parameter_space(model) is space
    assert space.chip_model == model
    others = [m for m in family.models if m != model]
    for other in others:
        assert family.parameter_space(other).chip_model == other
