"""The Turbo PMAC data-gathering format: round trip, the example capture, malformed files."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from servogym.calibrate import TraceError, read_trace
from servogym.calibrate._gather import parse_gather, source_of, to_gather
from servogym.chips import read_params_file

DATA = Path(__file__).parent / "data"
GATHER = DATA / "pmac_gather_rotary.txt"
PMC = DATA / "pmac_rotary.pmc"


@pytest.fixture(scope="module")
def params():
    return read_params_file(PMC).params


def test_the_example_capture_reads_as_a_trace(params):
    tr = read_trace(GATHER, "pmac", params=params)
    assert tr.fmt == "pmac-gather" and tr.n_ticks == 400
    assert tr.actual[0] == 0 and tr.commanded[-1] == 0  # out and back
    assert tr.aux1 is not None and tr.aux1.min() >= 0 and tr.aux1.max() <= 31
    np.testing.assert_allclose(np.diff(tr.time_s), params.servo_period_s)
    assert np.abs(tr.command).max() <= 32767


def test_writing_and_reading_a_capture_gives_the_same_trace(params):
    tr = read_trace(GATHER, "pmac", params=params)
    for counter in (True, False):
        back = parse_gather(to_gather(tr, params, motor=3, counter=counter), params)
        for name in ("commanded", "actual", "command", "aux1"):
            np.testing.assert_array_equal(getattr(back, name), getattr(tr, name))
        np.testing.assert_allclose(back.time_s, tr.time_s)


def test_source_addresses_name_the_motor_registers():
    assert source_of(0x800088) == ("commanded", 1)
    assert source_of(0x80008B) == ("actual", 1)
    assert source_of(0x4000BF) == ("output", 1)
    assert source_of(0x80010B) == ("actual", 2)
    assert source_of(0x400000) == ("counter", 0)
    assert source_of(0x0000BF) is None  # the Y word is not the filter output


def _lines(text: str) -> list[str]:
    return text.splitlines()


@pytest.mark.parametrize(
    ("edit", "match"),
    [
        (lambda ls: [x for x in ls if not x.startswith("I5049")], "does not give I5049"),
        (lambda ls: [x.replace("I5050=$00000F", "I5050=$000007") for x in ls],
         "one motor's commanded position"),
        (lambda ls: [*ls[:-1], ls[-1].rsplit(" ", 1)[0]], "end inside a sample"),
        (lambda ls: [*ls, "000190 00000000XY80 000000000000 000000"], "hex words of 6 or 12"),
        (lambda ls: [x.replace("I5002=$800088", "I5002=$C00088") for x in ls],
         "floating-point"),
    ],
)  # fmt: skip
def test_malformed_captures_are_refused_in_one_line(params, edit, match):
    text = "\n".join(edit(_lines(GATHER.read_text()))) + "\n"
    with pytest.raises(TraceError, match=match):
        parse_gather(text, params)


def test_a_capture_needs_a_pmac_register_set():
    from tests.calibrate.conftest import PARAMS  # a PMD set

    with pytest.raises(TraceError, match="needs a PMAC register set"):
        parse_gather(GATHER.read_text(), PARAMS)


def test_the_example_capture_calibrates(params):
    from servogym.calibrate import calibrate

    loaded = read_params_file(PMC)
    tr = read_trace(GATHER, "pmac", params=loaded.params)
    cal = calibrate(tr, loaded.params, "rotary", latency="full_period")
    assert not cal.poor
    assert abs(cal.plant["load_inertia_kgm2"] / 1.5e-4 - 1) < 0.10
    assert abs(cal.plant["coulomb_friction_nm"] / 0.03 - 1) < 0.25
