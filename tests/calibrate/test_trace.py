"""Reading traces: the generic CSV, and one-line errors for every malformed trace."""

from __future__ import annotations

import numpy as np
import pytest

from servogym.calibrate import Trace, TraceError, check_trace, parse_csv, read_trace, to_csv

PERIOD = 154e-6  # MC2100


def _csv(n: int = 300, period: float = PERIOD) -> str:
    rows = ["time_s,commanded,actual,command"]
    for k in range(n):
        rows.append(f"{k * period!r},{k * 3},{k * 3 - 1},{100 - k}")
    return "\n".join(rows) + "\n"


def test_a_csv_trace_reads_in_any_column_order_with_comments():
    text = "# recorded on axis 1\nCommand, actual,time_s,commanded\n5,1,0.0,2\n-5,3,0.000154,4\n"
    tr = parse_csv(text, "pmd")
    assert tr.command.tolist() == [5, -5] and tr.actual.tolist() == [1, 3]
    assert tr.commanded.tolist() == [2, 4] and tr.time_s.tolist() == [0.0, 0.000154]
    assert tr.aux1 is None and tr.aux2 is None


def test_the_csv_round_trips_with_the_aux_columns():
    tr = parse_csv(_csv(), "pmd")
    tr = Trace(tr.time_s, tr.commanded, tr.actual, tr.command,
               aux1=tr.commanded * 7, aux2=tr.commanded * 0 + 2)  # fmt: skip
    back = parse_csv(to_csv(tr, ("commanded_velocity", "commanded_acceleration")), "pmd")
    for name in ("time_s", "commanded", "actual", "command", "aux1", "aux2"):
        np.testing.assert_array_equal(getattr(back, name), getattr(tr, name))


def test_a_well_formed_trace_passes_the_check():
    check_trace(parse_csv(_csv(), "pmd"), PERIOD, "MC2100")


@pytest.mark.parametrize(
    ("text", "match"),
    [
        ("time_s,commanded,actual\n0,1,2\n", "missing command"),
        ("time_s,commanded,actual,command\n0,1,nan,3\n",
         r"line 2: column actual must be finite \(no NaN or infinity\); got actual='nan'"),
        ("time_s,commanded,actual,command\nNaN,1,2,3\n", "line 2: column time_s must be finite"),
        ("time_s,commanded,actual,command\n0,1,2.5,3\n", "whole counts; got actual='2.5'"),
        ("time_s,commanded,actual,command\n0,1,x,3\n", "must be a number; got actual='x'"),
        ("time_s,commanded,actual,command\n0,1,2\n", "line 2: 3 values for 4 columns"),
        ("time_s,commanded,actual,command,actual\n0,1,2,3,4\n", "names actual twice"),
        ("", "empty"),
    ],
)  # fmt: skip
def test_malformed_csv_lines_are_refused_naming_line_and_column(text, match):
    with pytest.raises(TraceError, match=match):
        parse_csv(text, "pmd")


def test_too_short_a_trace_is_refused():
    with pytest.raises(TraceError, match=r"too short .* it has 50 samples, at least 200"):
        check_trace(parse_csv(_csv(50), "pmd"), PERIOD, "MC2100")


def test_time_that_does_not_increase_is_refused():
    tr = parse_csv(_csv(), "pmd")
    tr.time_s[10] = tr.time_s[9]
    with pytest.raises(TraceError, match=r"time must increase .* sample 10"):
        check_trace(tr, PERIOD, "MC2100")


def test_a_sample_period_that_is_not_the_chips_is_refused():
    tr = parse_csv(_csv(period=52e-6), "pmd")  # an MC58000's period
    with pytest.raises(TraceError, match=r"the MC2100's servo period 154 us .* 52 us apart"):
        check_trace(tr, PERIOD, "MC2100")


def test_commands_outside_16_bits_and_a_trace_at_rest_are_refused():
    tr = parse_csv(_csv(), "pmd")
    tr.command[5] = 40000
    with pytest.raises(TraceError, match=r"-32768 <= command <= 32767 .* sample 5"):
        check_trace(tr, PERIOD, "MC2100")
    tr = parse_csv(_csv(), "pmd")
    tr.commanded[:] = 7
    with pytest.raises(TraceError, match="never changes"):
        check_trace(tr, PERIOD, "MC2100")


def test_read_trace_names_the_file(tmp_path):
    with pytest.raises(TraceError, match=r"TRACE '.*nope.csv' does not exist"):
        read_trace(tmp_path / "nope.csv", "pmd")
    bad = tmp_path / "bad.csv"
    bad.write_text("time_s,commanded\n0,1\n")
    with pytest.raises(TraceError, match=r"TRACE '.*bad.csv': the trace's header"):
        read_trace(bad, "pmd")
    with pytest.raises(TraceError, match="Did you mean 'csv'"):
        read_trace(bad, "pmd", fmt="cvs")
