"""Fuzzed exports: every damaged copy is refused with a ParameterError or reads back the
identical set. Nothing imports silently wrong, nothing raises anything else.

For every chip model and every format it takes, the exported file is cut at many points,
has lines deleted and duplicated, and single characters replaced; each copy goes through
the loader every command uses (format detected from the content).
"""

from __future__ import annotations

import random

import pytest

from servogym.chips import ParameterError, families, load_params_file

FILES = [
    (family, model, fmt)
    for family in families().values()
    for model in family.models
    for fmt in family.formats_for(model)
]


def _mutants(text: str, rng: random.Random) -> list[tuple[str, str]]:
    lines = text.splitlines(keepends=True)
    out = []
    cuts = sorted(rng.sample(range(1, len(text)), min(25, len(text) - 1)))
    out += [(f"cut at {c}", text[:c]) for c in cuts]
    for i in range(len(lines)):
        out.append((f"line {i + 1} deleted", "".join(lines[:i] + lines[i + 1 :])))
    for i in rng.sample(range(len(lines)), min(5, len(lines))):
        out.append((f"line {i + 1} doubled", "".join(lines[: i + 1] + lines[i:])))
    for _ in range(15):
        pos = rng.randrange(len(text))
        new = rng.choice("0123456789-.;:,#/ xI=S\n")
        if text[pos] != new:
            out.append((f"char {pos} -> {new!r}", text[:pos] + new + text[pos + 1 :]))
    return out


def test_fuzzed_exports_are_refused_or_read_back_identically():
    rng = random.Random(11)
    n_cases = n_refused = 0
    for family, model, fmt in FILES:
        params = family.make_params(model)
        text = family.export(params, fmt)
        assert load_params_file(text).params == params
        for what, mutant in _mutants(text, rng):
            n_cases += 1
            try:
                got = load_params_file(mutant).params
            except ParameterError:
                n_refused += 1
                continue
            assert got == params, (model, fmt, what)
    assert n_cases >= 1000 and n_refused >= 0.9 * n_cases, (n_cases, n_refused)


@pytest.mark.parametrize("cut", ["1SMPER40", "I7002=1"])
def test_the_cuts_of_issue_11_are_refused(cut):
    family = families()["parker6k" if "SMPER" in cut else "pmac"]
    model = "6K" if "SMPER" in cut else "TurboPMAC2"
    params = family.make_params(
        model, {"smper": 4000} if "SMPER" in cut else {"servo_clock_divider": 15}
    )
    text = family.export(params, family.native_format(model))
    full = cut + ("00" if "SMPER" in cut else "5")
    assert full in text
    cut_text = text[: text.index(full) + len(cut)]
    with pytest.raises(ParameterError, match=r"cut short|does not set|Missing"):
        load_params_file(cut_text)
