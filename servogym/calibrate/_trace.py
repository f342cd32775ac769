"""Hardware traces: what a controller recorded, one sample per servo cycle.

A :class:`Trace` holds, per servo cycle, the time, the commanded position, the encoder
position the chip read and the motor command it wrote (docs/calibrate.md, "Traces").
:func:`read_trace` reads one from a file (a generic CSV, or a Turbo PMAC data-gathering
file: ``servogym.calibrate._gather``); :func:`check_trace` refuses, in one line, a trace
that cannot be replayed against a chip.
"""

from __future__ import annotations

import csv
import dataclasses
import io
import math
from pathlib import Path

import numpy as np

from servogym.chips._space import ParameterError

TRACE_FORMATS: dict[str, str] = {
    "csv": "generic CSV: time_s, commanded, actual, command (+ optional aux columns)",
    "pmac-gather": "Turbo PMAC data gathering: I5001.. addresses, I5049, LIST GATHER words",
}
"""Every trace format :func:`read_trace` reads, with what it is."""

REQUIRED_COLUMNS = ("time_s", "commanded", "actual", "command")
"""Columns every CSV trace has (header names, any order, case-insensitive)."""

AUX_COLUMNS: dict[str, tuple[str, str]] = {
    "pmd": ("commanded_velocity", "commanded_acceleration"),
    "pmac": ("commanded_fraction", ""),
    "parker6k": ("commanded_velocity", "commanded_acceleration"),
}
"""Optional CSV columns per chip family: the profile's two auxiliary filter inputs, in the
chip's own units (PMD: 16.16 counts/cycle and counts/cycle^2; PMAC: the commanded
position's fraction in 1/32 count; Parker: counts/s and counts/s^2)."""

MIN_TICKS = 200
"""Fewest samples a trace needs (a move and its settling; fewer cannot separate inertia
from friction)."""

MAX_TRACE_BYTES = 256 * 1024 * 1024
"""Largest trace file read (about 6 million CSV samples)."""

PERIOD_TOLERANCE = 0.01
"""Largest relative difference between a trace's sample spacing and the chip's period."""


class TraceError(ParameterError):
    """A trace that cannot be read or replayed; the message says which rule it breaks."""


@dataclasses.dataclass(frozen=True, eq=False)
class Trace:
    """One recorded episode, one entry per servo cycle (all arrays of length ``n_ticks``).

    Attributes:
        time_s: Time of each sample (s), strictly increasing.
        commanded: Commanded position (counts, int64).
        actual: Encoder position the chip read (counts, int64).
        command: Motor command the chip wrote (signed 16-bit counts, 32768 = 100 %).
        aux1: The profile's first auxiliary filter input in the chip's units (PMD
            commanded velocity, PMAC commanded fraction, Parker commanded velocity), or
            ``None`` when the trace does not have it (then derived from ``commanded``).
        aux2: The second one (PMD, Parker commanded acceleration), or ``None``.
        source: Where the trace came from (file name), for messages and provenance.
        fmt: The format it was read from (a key of :data:`TRACE_FORMATS`).
    """

    time_s: np.ndarray
    commanded: np.ndarray
    actual: np.ndarray
    command: np.ndarray
    aux1: np.ndarray | None = None
    aux2: np.ndarray | None = None
    source: str = "trace"
    fmt: str = "csv"

    @property
    def n_ticks(self) -> int:
        """Number of samples."""
        return int(self.time_s.shape[0])

    def to_csv(self) -> str:
        """The trace as a generic CSV (the aux columns given as ``aux1``/``aux2`` names)."""
        return to_csv(self)


def to_csv(trace: Trace, aux_names: tuple[str, str] = ("", "")) -> str:
    """A trace as the generic CSV format (``aux_names``: the columns of ``aux1``, ``aux2``)."""
    cols = list(REQUIRED_COLUMNS)
    arrays = [trace.time_s, trace.commanded, trace.actual, trace.command]
    for name, arr in zip(aux_names, (trace.aux1, trace.aux2), strict=True):
        if name and arr is not None:
            cols.append(name)
            arrays.append(arr)
    out = io.StringIO()
    out.write(",".join(cols) + "\n")
    for row in zip(*arrays, strict=True):
        out.write(",".join([repr(float(row[0]))] + [str(int(v)) for v in row[1:]]) + "\n")
    return out.getvalue()


def _float_cell(text: str, column: str, line: int) -> float:
    try:
        value = float(text)
    except ValueError:
        raise TraceError(
            f"line {line}: column {column} must be a number; got {column}={text!r}."
        ) from None
    if not math.isfinite(value):
        raise TraceError(
            f"line {line}: column {column} must be finite (no NaN or infinity); "
            f"got {column}={text!r}."
        )
    return value


def _int_cell(text: str, column: str, line: int) -> int:
    value = _float_cell(text, column, line)
    if value != int(value):
        raise TraceError(f"line {line}: column {column} holds whole counts; got {column}={text!r}.")
    return int(value)


def parse_csv(text: str, family: str, source: str = "trace") -> Trace:
    """A :class:`Trace` from the text of a generic CSV trace.

    The header names the columns (any order, case-insensitive): ``time_s`` (s),
    ``commanded``, ``actual`` (counts), ``command`` (motor-command counts), and optionally
    the family's auxiliary columns (:data:`AUX_COLUMNS`). Lines starting with ``#`` are
    comments.

    Raises:
        TraceError: naming the line and the column of the first bad value.
    """
    lines = [ln for ln in text.replace("\r\n", "\n").split("\n")]
    rows = [
        (i + 1, ln) for i, ln in enumerate(lines) if ln.strip() and not ln.lstrip().startswith("#")
    ]
    if not rows:
        raise TraceError("the trace is empty: no header line and no samples.")
    header_line, header = rows[0]
    names = [h.strip().lower() for h in next(csv.reader([header]))]
    missing = [c for c in REQUIRED_COLUMNS if c not in names]
    if missing:
        raise TraceError(
            f"the trace's header (line {header_line}) must name the columns "
            f"{', '.join(REQUIRED_COLUMNS)}; missing {', '.join(missing)} "
            f"(got {', '.join(names) or 'nothing'})."
        )
    dupes = sorted({n for n in names if names.count(n) > 1})
    if dupes:
        raise TraceError(f"the trace's header names {', '.join(dupes)} twice.")
    aux = [a for a in AUX_COLUMNS.get(family, ()) if a and a in names]
    index = {n: names.index(n) for n in (*REQUIRED_COLUMNS, *aux)}
    data: dict[str, list] = {n: [] for n in index}
    for line, row_text in rows[1:]:
        cells = next(csv.reader([row_text]))
        if len(cells) != len(names):
            raise TraceError(
                f"line {line}: {len(cells)} values for {len(names)} columns in the header."
            )
        for name, i in index.items():
            cell = cells[i].strip()
            if name == "time_s":
                data[name].append(_float_cell(cell, name, line))
            else:
                data[name].append(_int_cell(cell, name, line))
    names_aux = AUX_COLUMNS.get(family, ("", ""))
    return Trace(
        time_s=np.asarray(data["time_s"], dtype=float),
        commanded=np.asarray(data["commanded"], dtype=np.int64),
        actual=np.asarray(data["actual"], dtype=np.int64),
        command=np.asarray(data["command"], dtype=np.int64),
        aux1=np.asarray(data[names_aux[0]], dtype=np.int64) if names_aux[0] in data else None,
        aux2=np.asarray(data[names_aux[1]], dtype=np.int64) if names_aux[1] in data else None,
        source=source,
        fmt="csv",
    )


def detect_trace_format(text: str) -> str:
    """``"pmac-gather"`` for a file that sets the gathering I-variables, else ``"csv"``."""
    from servogym.calibrate._gather import looks_like_gather

    return "pmac-gather" if looks_like_gather(text) else "csv"


def read_trace(
    path: str | Path,
    family: str,
    fmt: str | None = None,
    *,
    params: object = None,
    what: str = "TRACE",
) -> Trace:
    """A trace from a file, with one-line errors naming it.

    Args:
        path: The trace file.
        family: The chip family (``"pmd"``, ``"pmac"``, ``"parker6k"``): which auxiliary
            columns a CSV may carry.
        fmt: A key of :data:`TRACE_FORMATS`; default detected from the content.
        params: The register set that ran (a PMAC gathering file's positions are read in
            its ``1/(32*Ixx08)`` count units).
        what: The argument that named the file, for messages.
    """
    path = Path(path)
    if fmt is not None and fmt not in TRACE_FORMATS:
        import difflib

        close = difflib.get_close_matches(str(fmt), list(TRACE_FORMATS), n=1)
        hint = f" Did you mean {close[0]!r}?" if close else ""
        raise TraceError(
            f"--format must be one of {', '.join(TRACE_FORMATS)}; got --format {fmt!r}.{hint}"
        )
    from servogym._input import InputError, read_text

    try:
        text = read_text(path, what, max_bytes=MAX_TRACE_BYTES).removeprefix("\ufeff")
    except InputError as exc:
        raise TraceError(str(exc)) from None
    try:
        fmt = detect_trace_format(text) if fmt is None else fmt
        if fmt == "pmac-gather":
            from servogym.calibrate._gather import parse_gather

            return parse_gather(text, params, source=str(path))
        return parse_csv(text, family, source=str(path))
    except TraceError as exc:
        raise TraceError(f"{what} {str(path)!r}: {exc}") from None


def check_trace(trace: Trace, period_s: float, chip_model: str) -> None:
    """Refuse a trace the chip's loop cannot have produced, in one line.

    Rules: at least :data:`MIN_TICKS` samples; time strictly increasing; every sample
    spacing within :data:`PERIOD_TOLERANCE` of the chip's servo period ``period_s``;
    motor commands in the signed 16-bit range; the commanded position moves (a trace at
    rest determines no inertia).

    Raises:
        TraceError: naming the rule, the offending value and the sample.
    """
    n = trace.n_ticks
    if n < MIN_TICKS:
        raise TraceError(
            f"the trace is too short to determine the plant: it has {n} samples, at least "
            f"{MIN_TICKS} are needed (a move and its settling)."
        )
    dt = np.diff(trace.time_s)
    bad = np.flatnonzero(dt <= 0)
    if bad.size:
        k = int(bad[0]) + 1
        raise TraceError(
            f"time must increase from sample to sample; sample {k} has time_s="
            f"{trace.time_s[k]!r} after time_s={trace.time_s[k - 1]!r}."
        )
    off = np.flatnonzero(np.abs(dt - period_s) > PERIOD_TOLERANCE * period_s)
    if off.size:
        k = int(off[0]) + 1
        raise TraceError(
            f"the sample period must be the {chip_model}'s servo period "
            f"{period_s * 1e6:.4g} us (within {PERIOD_TOLERANCE:.0%}), one sample per cycle; "
            f"samples {k - 1} and {k} are {dt[k - 1] * 1e6:.4g} us apart (median spacing "
            f"{float(np.median(dt)) * 1e6:.4g} us). Record every servo cycle, or give the "
            f"register set that ran (its sample time)."
        )
    cmd = trace.command
    out = np.flatnonzero((cmd < -32768) | (cmd > 32767))
    if out.size:
        k = int(out[0])
        raise TraceError(
            f"motor commands must satisfy -32768 <= command <= 32767 (signed 16 bit); "
            f"sample {k} has command={int(cmd[k])}."
        )
    if np.all(trace.commanded == trace.commanded[0]):
        raise TraceError(
            "the commanded position never changes: a trace at rest determines no inertia "
            "or friction; record a move (and its settling)."
        )
