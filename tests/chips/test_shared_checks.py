"""Checks every family shares: the keywords of ``export`` / ``import_params``
(``chips._formats``), the profile arrays (``chips._profiles``), and where the multi-axis
file's spec-version warning points (``chips._axisfile``)."""

from __future__ import annotations

import json
import re

import numpy as np
import pytest

import servogym.chips.pmac  # noqa: F401  (chips.families() does not load PMAC by itself yet)
from servogym.chips import ParameterError, export_axes, families, import_axes, load_axes
from servogym.chips.parker6k._profile import Parker6kProfile
from servogym.chips.pmac._profile import Profile as PMACProfile
from servogym.chips.pmd._profile import Profile as PMDProfile

CASES = [(name, fmt) for name, fam in sorted(families().items()) for fmt in fam.formats]
"""Every family's every export format (from the registry)."""


def _family(name: str, fmt: str = "json"):
    """The family, its export module and the defaults of its first model that takes ``fmt``."""
    fam = families()[name]
    model = next(m for m in fam.models if fmt in fam.formats_for(m))
    return fam, fam.export_module, fam.make_params(model)


@pytest.mark.parametrize(("family", "fmt"), CASES)
def test_an_unknown_keyword_is_refused_naming_the_format_and_its_keywords(family, fmt):
    _, module, params = _family(family, fmt)
    takes = module.FORMAT_TABLE.export_keywords[fmt]
    with pytest.raises(ParameterError) as info:
        module.export(params, fmt, bogus=1)
    message = str(info.value)
    assert f"export(fmt={fmt!r}) takes the keywords {', '.join(takes)}; got bogus=1." in message
    text = module.export(params, fmt)
    with pytest.raises(ParameterError, match=rf"import_params\(fmt={fmt!r}\) takes the keywords"
                       r" .*\(besides model\); got bogus=1\."):  # fmt: skip
        module.import_params(text, fmt, bogus=1)
    # A near miss gets a suggestion.
    with pytest.raises(ParameterError, match=r"got axes=2\. Did you mean axis\?"):
        module.export(params, fmt, axes=2)


@pytest.mark.parametrize(("family", "fmt"), CASES)
def test_every_keyword_a_format_lists_is_taken(family, fmt):
    fam, module, params = _family(family, fmt)
    values = {"axis": 1, "motor": 1, "assumptions": fam.default_assumptions(), "metrics": {},
              "notes": {}, "created": "2025-01-31T12:00:00+00:00"}  # fmt: skip
    table = module.FORMAT_TABLE
    kw = {k: values[k] for k in table.export_keywords[fmt]}
    text = module.export(params, fmt, **kw)
    ikw = {k: values[k] for k in table.import_keywords[fmt]}
    assert module.import_params(text, fmt, **ikw) == params
    if fmt == "json":  # the axis keyword may be None (its default) for a JSON file
        assert module.import_params(text, fmt, **{table.index: None}) == params


def test_pmd_axis_on_import_is_a_parameter_error_for_every_format():
    _, module, params = _family("pmd")
    json_text = module.export(params, "json")
    # Was silently accepted (JSON) or a TypeError from a lambda (C-Motion, host).
    with pytest.raises(ParameterError, match=r"import_params\(fmt='json'\) takes no axis: a "
                       r"JSON file holds one set; got axis=5\."):  # fmt: skip
        module.import_params(json_text, "json", axis=5)
    for fmt in ("cmotion", "host"):
        text = module.export(params, fmt, axis=2)
        with pytest.raises(ParameterError, match=rf"import_params\(fmt={fmt!r}\) takes the "
                           r"keywords none \(besides model\); got axis=2\."):  # fmt: skip
            module.import_params(text, fmt, axis=2)


@pytest.mark.parametrize("family", ["pmac", "parker6k"])
def test_a_json_import_refuses_the_axis_the_native_format_takes(family):
    _, module, params = _family(family)
    table = module.FORMAT_TABLE
    text = module.export(params, "json")
    native = [f for f, names in table.import_keywords.items() if table.index in names]
    assert native, "the family's own format reads one axis of a file"
    listed = " or ".join(map(repr, native))
    with pytest.raises(ParameterError, match=rf"takes no {table.index}: a JSON file holds one "
                       rf"set \({table.index}= applies to fmt={re.escape(listed)} only\); "
                       rf"got {table.index}=2\."):  # fmt: skip
        module.import_params(text, "json", **{table.index: 2})


# ---------------------------------------------------------------- profile arrays

PROFILES = [
    (PMDProfile, {"move_ticks": 3, "start": 0}),
    (PMACProfile, {"start": 0, "move_ticks": 3}),
    (Parker6kProfile, {"start": 0, "move_ticks": 3}),
]


@pytest.mark.parametrize(("cls", "extra"), PROFILES, ids=lambda c: getattr(c, "__module__", ""))
@pytest.mark.parametrize("array", ["position", "velocity", "acceleration"])
def test_a_profile_array_that_a_cast_would_change_is_refused_naming_it(cls, extra, array):
    ok = {"position": [0, 5, 9], "velocity": [0, 3, 1], "acceleration": [0, 1, -1]}
    whole = cls(**{**ok, array: np.array(ok[array], dtype=float)}, **extra)
    assert getattr(whole, array).dtype == np.int64  # whole numbers in a float array: taken
    assert getattr(whole, array).tolist() == ok[array]
    for bad, shown in ((1.5, "1.5"), (np.nan, "nan"), (np.inf, "inf"), (2.0**63, "9.2")):
        values = np.array(ok[array], dtype=float)
        values[1] = bad
        with pytest.raises(ValueError, match=rf"{cls.__name__}\.{array} must hold integers.*"
                           rf"entry 1 = {shown}"):  # fmt: skip
            cls(**{**ok, array: values}, **extra)
    with pytest.raises(ValueError, match=rf"{cls.__name__}\.{array} must be an integer array; "
                       r"got dtype bool"):  # fmt: skip
        cls(**{**ok, array: np.array([True, False, True])}, **extra)
    with pytest.raises(ValueError, match=rf"{cls.__name__}\.{array} must fit int64"):
        cls(**{**ok, array: np.array([0, 2**64 - 1, 0], dtype=np.uint64)}, **extra)


# ---------------------------------------------------------------- spec-version warning


def _old_spec_axes_json() -> str:
    _, _, params = _family("pmac")  # per-motor sets, no shared servo period
    doc = json.loads(export_axes({1: params, 2: params}, "json"))
    del doc["checksum"]  # hand-edited: read without a checksum
    doc["spec_version"] = "old-spec"
    return json.dumps(doc)


def test_the_spec_version_warning_points_at_the_callers_line(tmp_path):
    text = _old_spec_axes_json()
    with pytest.warns(UserWarning, match=r"written for spec_version 'old-spec'") as w:
        axes = import_axes(text, "json")
    assert len(axes) == 2
    assert [r.filename for r in w] == [__file__]  # was servogym/chips/_axes.py
    path = tmp_path / "axes.json"
    path.write_text(text)
    with pytest.warns(UserWarning, match=r"written for spec_version 'old-spec'") as w:
        load_axes(path)
    assert [r.filename for r in w] == [__file__]


def test_user_stacklevel_counts_the_servogym_frames():
    from servogym.chips import _axisfile

    # Called from here (outside servogym) the warning's own caller is the user: level 1.
    assert _axisfile.user_stacklevel() == 1
