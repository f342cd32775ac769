"""The servogym JSON parameter file, once for every registered chip family.

The layout and its checks live in ``servogym.chips._paramfile``; each family's ``to_json`` /
``from_json`` only adds its own keys. Family-specific rules (ranges of registers, the
family's own consistency messages) stay in ``test_<family>_export.py``.
"""

import datetime as dt
import importlib
import json
import types
import warnings

import numpy as np
import pytest

import servogym.chips.pmac  # noqa: F401  (chips.families() does not load PMAC by itself yet)
from servogym import __version__
from servogym.chips import ChipFamily, ParameterError, families, load_params_file

CREATED = "2025-01-31T12:00:00+00:00"
FAMILIES = sorted(families())
COMMON_KEYS = {
    "format",
    "format_version",
    "chip_family",
    "chip_model",
    "spec_version",
    "assumptions",
    "params",
    "created",
    "servogym_version",
}


def _family(name: str) -> tuple[ChipFamily, types.ModuleType]:
    """The registered family and its package (which exports ``to_json`` / ``from_json``)."""
    fam = families()[name]
    return fam, importlib.import_module(type(fam).__module__.rpartition(".")[0])


def _doc(name: str, **changes) -> str:
    fam, pkg = _family(name)
    model = next(iter(fam.models))
    doc = json.loads(pkg.to_json(fam.make_params(model), created=CREATED))
    del doc["checksum"]  # edited below: read as a hand-written file (no checksum)
    doc.update(changes)
    return json.dumps(doc)


def _extra_keys(name: str) -> list[str]:
    return [k for k in json.loads(_doc(name)) if k not in COMMON_KEYS]


@pytest.fixture(params=FAMILIES)
def family(request) -> str:
    return request.param


def test_round_trip_keeps_set_assumptions_and_provenance(family):
    fam, pkg = _family(family)
    assumptions = fam.assumptions_type.all_settings()[-1]  # a non-default switch
    for model in fam.models:
        params = fam.make_params(model)
        text = pkg.to_json(
            params,
            assumptions,
            metrics={"ise": np.float64(1.5), "curve": np.arange(3)},
            notes={"seed": np.int64(7), "tuner": "random"},
            created=CREATED,
        )
        assert text.endswith("\n")
        for f in (pkg.from_json(text), load_params_file(text)):
            assert f.params == params
            assert f.assumptions == assumptions
            p = f.provenance
            assert p["format"] == "servogym-params" and p["format_version"] == 1
            assert p["chip_family"] == fam.name and p["chip_model"] == params.model
            assert p["created"] == CREATED and p["servogym_version"] == __version__
            assert p["metrics"] == {"ise": 1.5, "curve": [0, 1, 2]}
            assert p["notes"] == {"seed": 7, "tuner": "random"}
            assert "params" not in p and "assumptions" not in p


def test_layout_order_and_optional_keys(family):
    fam, pkg = _family(family)
    doc = json.loads(pkg.to_json(fam.make_params(next(iter(fam.models))), created=CREATED))
    extra = _extra_keys(family)
    assert list(doc) == [
        "format",
        "format_version",
        "chip_family",
        "chip_model",
        *extra,
        "spec_version",
        "assumptions",
        "params",
        "created",
        "servogym_version",
        "checksum",
    ]
    assert "metrics" not in doc and "notes" not in doc


def test_created_default_and_datetime(family):
    fam, pkg = _family(family)
    params = fam.make_params(next(iter(fam.models)))
    doc = json.loads(pkg.to_json(params, created=dt.datetime(2025, 1, 2, 3, 4, 5)))
    assert doc["created"] == "2025-01-02T03:04:05"
    assert dt.datetime.fromisoformat(json.loads(pkg.to_json(params))["created"]).tzinfo


def test_write_refuses_bad_metrics_notes_created_assumptions(family):
    fam, pkg = _family(family)
    params = fam.make_params(next(iter(fam.models)))
    with pytest.raises(ParameterError, match="metrics must hold only JSON values"):
        pkg.to_json(params, metrics={"ise": float("nan")})
    with pytest.raises(ParameterError, match="notes must be a mapping"):
        pkg.to_json(params, notes="tuned by hand")
    with pytest.raises(ParameterError, match="created must be an ISO 8601"):
        pkg.to_json(params, created="yesterday")
    with pytest.raises(ParameterError, match="created must be a datetime"):
        pkg.to_json(params, created=20250131)
    name = next(iter(fam.assumptions_type.CHOICES))
    with pytest.raises(ParameterError, match=rf"unknown assumption '{name}x'.*Did you mean"):
        pkg.to_json(params, {f"{name}x": "y"})
    with pytest.raises(ParameterError, match="params must be a"):
        pkg.to_json([1, 2])


@pytest.mark.parametrize(
    ("changes", "match"),
    [
        ({"format": "other"}, r"format must be 'servogym-params'.*got format='other'"),
        ({"format_version": 2}, r"format_version must be 1.*got format_version=2"),
        ({"format_version": True}, r"got format_version=True"),
        ({"format_version": "1"}, r"got format_version='1'"),
        ({"chip_family": "delta_tau"}, r"chip_family must be '\w+'.*'delta_tau'.*own importer"),
        ({"extra": 1}, r"unknown keys 'extra'; format_version 1 allows"),
        ({"chip_model": 7}, r"chip_model must be a .* model name; got chip_model=7"),
        ({"params": []}, r"params must be a JSON object"),
        ({"spec_version": 1}, r"spec_version must be a string"),
        ({"created": "yesterday"}, r"created must be an ISO 8601"),
        ({"servogym_version": None}, r"servogym_version must be a string"),
        ({"metrics": [1]}, r"metrics must be a JSON object"),
        ({"notes": "x"}, r"notes must be a JSON object"),
    ],
)
def test_read_refuses_wrong_header_and_types(family, changes, match):
    _, pkg = _family(family)
    with pytest.raises(ParameterError, match=match):
        pkg.from_json(_doc(family, **changes))


def test_read_refuses_text_that_is_not_a_json_object(family):
    _, pkg = _family(family)
    with pytest.raises(ParameterError, match="must be JSON; invalid JSON at line 1"):
        pkg.from_json("{not json")
    with pytest.raises(ParameterError, match="must be a JSON object; got a JSON list"):
        pkg.from_json("[]")


def test_read_refuses_every_missing_key(family):
    _, pkg = _family(family)
    for key in json.loads(_doc(family)):
        if key in ("format", "format_version", "chip_family"):
            continue  # checked first, with their own messages (above)
        doc = json.loads(_doc(family))
        del doc[key]
        with pytest.raises(ParameterError, match=f"misses the keys {key}"):
            pkg.from_json(json.dumps(doc))


def test_read_refuses_inconsistent_or_incomplete_sets(family):
    fam, pkg = _family(family)
    doc = json.loads(_doc(family))
    params = doc["params"]
    first = next(k for k in params if k != "model")
    with pytest.raises(ParameterError, match=r"takes no defaults.*missing"):
        pkg.from_json(_doc(family, params={k: v for k, v in params.items() if k != first}))
    others = [m for m in fam.models if m != doc["chip_model"]]
    if others:
        with pytest.raises(ParameterError, match=r"params\.model must equal chip_model"):
            pkg.from_json(_doc(family, chip_model=others[0]))
    with pytest.raises(ParameterError, match=r"unknown .*model 'NoSuchChip'; known models are"):
        pkg.from_json(_doc(family, chip_model="NoSuchChip"))
    for key in _extra_keys(family):
        with pytest.raises(ParameterError, match=f"{key} must equal"):
            pkg.from_json(_doc(family, **{key: doc[key] * 2}))
        with pytest.raises(ParameterError, match=f"{key} must be"):
            pkg.from_json(_doc(family, **{key: True}))


def test_read_refuses_unknown_or_missing_assumptions(family):
    _, pkg = _family(family)
    asm = json.loads(_doc(family))["assumptions"]
    name = next(iter(asm))
    with pytest.raises(ParameterError, match=rf"unknown assumption '{name}x'.*Did you mean"):
        pkg.from_json(_doc(family, assumptions={**asm, f"{name}x": "y"}))
    with pytest.raises(ParameterError, match=rf"every assumption.*missing {name}"):
        pkg.from_json(_doc(family, assumptions={k: v for k, v in asm.items() if k != name}))
    with pytest.raises(ParameterError, match=rf"{name} must be one of"):
        pkg.from_json(_doc(family, assumptions={**asm, name: "no-such-choice"}))


def test_other_spec_version_warns_at_the_callers_line_and_loads(family):
    fam, pkg = _family(family)
    with pytest.warns(UserWarning, match=r"spec_version 'old-spec'.*Evaluate the set again") as w:
        f = pkg.from_json(_doc(family, spec_version="old-spec"))
    assert w[0].filename == __file__
    assert f.params == fam.make_params(next(iter(fam.models)))
    assert f.provenance["spec_version"] == "old-spec"
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        pkg.from_json(_doc(family))  # its own spec_version: no warning


def test_public_functions_are_documented_for_their_family(family):
    fam, pkg = _family(family)
    for function in (pkg.to_json, pkg.from_json):
        assert function.__module__.startswith(type(fam).__module__.rpartition(".")[0])
        assert fam.params_type.__name__ in function.__doc__
    assert f'``"{fam.name}"``' in pkg.from_json.__doc__
