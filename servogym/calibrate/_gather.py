"""Turbo PMAC data gathering: the capture a controller makes of its own servo loop.

The controller logs up to 48 source registers every ``I5049`` servo interrupts into its
gather buffer (sources ``I5001``..``I5048``, enabled by the bit masks ``I5050``, ``I5051``;
Turbo PMAC/PMAC2 Software Reference, "Data Gathering I-Variables"), and ``LIST GATHER``
reports the buffer as hexadecimal words. A servogym gather file is what a host saves from
that session: the gathering I-variables as the controller reports them (``I5001=$800088``),
then the ``LIST GATHER`` words. docs/calibrate.md, "Turbo PMAC data gathering", says which
points are vendor facts and which are assumptions.

Sources servogym reads, for motor ``xx`` (register block at ``$80 * xx``):

=====================  ==========================  ===============================
register               address (motor 1)           unit
=====================  ==========================  ===============================
commanded position     ``D:$000088`` (``$80*xx+$08``)  1/(Ixx08*32) count, 48 bit
actual position        ``D:$00008B`` (``$80*xx+$0B``)  1/(Ixx08*32) count, 48 bit
filter output          ``X:$0000BF`` (``$80*xx+$3F``)  16-bit DAC value in bits 8..23
servo cycle counter    ``X:$000000`` (optional)        servo cycles, 24 bit
=====================  ==========================  ===============================

A source I-variable's top two bits name the memory: ``$0xxxxx`` Y word (24 bit),
``$4xxxxx`` X word (24 bit), ``$8xxxxx`` both as one 48-bit fixed-point value (D),
``$Cxxxxx`` both as a floating-point value (L, not read here); the low 19 bits are the
address. A 48-bit value is listed as 12 hex digits, or as two 6-digit words with the X
(high) word first.
"""

from __future__ import annotations

import re
from typing import Any

import numpy as np

from servogym.calibrate._trace import Trace, TraceError

_IVAR = re.compile(r"(?i)^\s*I\s*(50\d\d)\s*=\s*(\$[0-9a-f]+|\d+)\s*$")
_HEX = re.compile(r"(?i)^[0-9a-f]+$")

MEMORY = {0: "Y", 1: "X", 2: "D", 3: "L"}
"""Memory of a source by the top two bits of its 24-bit I-variable."""

COMMANDED, ACTUAL, OUTPUT, COUNTER = "commanded", "actual", "output", "counter"


def looks_like_gather(text: str) -> bool:
    """Whether a file sets the data-gathering I-variables (I5001..I5051)."""
    return any(_IVAR.match(line.split(";")[0]) for line in text.splitlines()[:200])


def source_of(address: int, motor: int | None = None) -> tuple[str, int] | None:
    """What a source register is: ``(role, motor)``, or ``None`` for one servogym ignores."""
    mem = MEMORY[(address >> 22) & 3]
    word = address & 0x7FFFF
    if mem == "X" and word == 0:
        return COUNTER, 0
    block, offset = divmod(word, 0x80)
    if block < 1 or block > 32 or (motor is not None and block != motor):
        return None
    if mem == "D" and offset == 0x08:
        return COMMANDED, block
    if mem == "D" and offset == 0x0B:
        return ACTUAL, block
    if mem == "X" and offset == 0x3F:
        return OUTPUT, block
    return None


def _signed(value: int, bits: int) -> int:
    return value - (1 << bits) if value >> (bits - 1) else value


def parse_gather(text: str, params: Any, source: str = "trace") -> Trace:
    """A :class:`Trace` from a servogym gather file (module docstring).

    Args:
        text: The file's text.
        params: The PMAC register set that ran: its ``position_loop_scale`` (Ixx08) gives
            the positions' unit and its servo period the time of each sample.
        source: The file name, for messages.

    Raises:
        TraceError: one line naming the rule (missing sources, a cut-off sample, ...).
    """
    if params is None or not hasattr(params, "position_loop_scale"):
        raise TraceError(
            "a PMAC data-gathering file needs a PMAC register set (--params, --chip "
            "TurboPMAC...): its Ixx08 scales the gathered positions."
        )
    ivars: dict[int, int] = {}
    words: list[tuple[int, str]] = []
    for n, raw in enumerate(text.replace("\r\n", "\n").split("\n"), start=1):
        line = raw.split(";")[0].strip()
        if not line:
            continue
        m = _IVAR.match(line)
        if m:
            num = int(m.group(1))
            val = m.group(2)
            ivars[num] = int(val[1:], 16) if val.startswith("$") else int(val)
            continue
        for tok in line.split():
            if not _HEX.match(tok) or len(tok) not in (6, 12):
                raise TraceError(
                    f"line {n}: LIST GATHER data are hex words of 6 or 12 digits; got {tok!r}."
                )
            words.append((n, tok))
    period = ivars.get(5049)
    if period is None:
        raise TraceError("the gather file does not give I5049 (the gathering period).")
    mask = ivars.get(5050, 0) | (ivars.get(5051, 0) << 24)
    enabled = [i for i in range(48) if mask >> i & 1]
    if not enabled:
        raise TraceError("I5050 and I5051 enable no source (both masks are 0).")
    sources = []
    for i in enabled:
        addr = ivars.get(5001 + i)
        if addr is None:
            raise TraceError(
                f"source {i + 1} is enabled (I5050/I5051) but I{5001 + i} is not given."
            )
        if MEMORY[(addr >> 22) & 3] == "L":
            raise TraceError(
                f"I{5001 + i}=${addr:06X} gathers a floating-point (L:) value; gather the "
                f"positions as D: (fixed, $8xxxxx)."
            )
        sources.append((i, addr, source_of(addr)))
    motors = {s[2][1] for s in sources if s[2] and s[2][0] != COUNTER}
    roles = {m: {s[2][0] for s in sources if s[2] and s[2][1] == m} for m in motors}
    full = [m for m, r in roles.items() if {COMMANDED, ACTUAL, OUTPUT} <= r]
    if len(full) != 1:
        raise TraceError(
            "the gathered sources must hold one motor's commanded position (D:$xx08), "
            "actual position (D:$xx0B) and filter output (X:$xx3F), xx = $80 * motor; "
            + ("none does" if not full else f"motors {sorted(full)} all do")
            + f" (gathered {', '.join(f'I{5001 + i}=${a:06X}' for i, a, _ in sources)})."
        )
    motor = full[0]
    # the stream of 24-bit words, a 12-digit token being two (X word first)
    stream = []
    for n, tok in words:
        if len(tok) == 12:
            stream.extend([(n, int(tok[:6], 16)), (n, int(tok[6:], 16))])
        else:
            stream.append((n, int(tok, 16)))
    widths = [2 if MEMORY[(a >> 22) & 3] == "D" else 1 for _, a, _ in sources]
    per = sum(widths)
    if len(stream) % per:
        last = stream[-1][0] if stream else 0
        raise TraceError(
            f"the gathered data end inside a sample: {len(stream)} words for samples of "
            f"{per} words (the file was cut at line {last}?)."
        )
    data = np.array([w for _, w in stream], dtype=np.int64).reshape(-1, per)
    cols: dict[str, np.ndarray] = {}
    j = 0
    for (_, _, role), width in zip(sources, widths, strict=True):
        if width == 2:
            raw48 = (data[:, j] << 24) | data[:, j + 1]
            value = np.where(raw48 >> 47 == 1, raw48 - (1 << 48), raw48)
        else:
            value = data[:, j]
        j += width
        if role and (role[1] == motor or role[0] == COUNTER) and role[0] not in cols:
            cols[role[0]] = value
    scale = 32 * int(params.position_loop_scale)
    if scale <= 0:
        raise TraceError("Ixx08 (position_loop_scale) must be >= 1 to read gathered positions.")
    fine_cmd = cols[COMMANDED]
    commanded = np.floor_divide(fine_cmd, scale)
    fraction = np.floor_divide(np.mod(fine_cmd, scale), int(params.position_loop_scale))
    actual = np.floor_divide(cols[ACTUAL], scale)
    out24 = np.where(cols[OUTPUT] >> 23 == 1, cols[OUTPUT] - (1 << 24), cols[OUTPUT])
    command = out24 >> 8
    servo = float(params.servo_period_s)
    if COUNTER in cols:
        counter = np.unwrap(cols[COUNTER].astype(float), period=float(1 << 24))
        time_s = (counter - counter[0]) * servo
    else:
        time_s = (
            np.arange(data.shape[0]) * period * servo if period > 0 else np.zeros(data.shape[0])
        )
    return Trace(
        time_s=time_s,
        commanded=commanded.astype(np.int64),
        actual=actual.astype(np.int64),
        command=command.astype(np.int64),
        aux1=fraction.astype(np.int64),
        aux2=None,
        source=source,
        fmt="pmac-gather",
    )


def to_gather(trace: Trace, params: Any, motor: int = 1, *, counter: bool = True) -> str:
    """A trace as a servogym gather file (the inverse of :func:`parse_gather`).

    For examples and tests: the set-up I-variables for motor ``motor``, then one line of
    ``LIST GATHER`` words per sample (12 digits for the 48-bit positions).
    """
    base = 0x80 * motor
    srcs = ([(0x400000, "counter")] if counter else []) + [
        (0x800000 | (base + 0x08), "commanded"),
        (0x800000 | (base + 0x0B), "actual"),
        (0x400000 | (base + 0x3F), "output"),
    ]
    lines = [
        "; Turbo PMAC data gathering, read back with LIST GATHER (servogym gather file)",
        f"; motor {motor}: commanded position, actual position, filter output",
        "I5000=0",
        f"I5049={int(params.servo_cycle_extension) + 1}",
        f"I5050=${(1 << len(srcs)) - 1:06X}",
        "I5051=$000000",
    ]
    for i, (addr, what) in enumerate(srcs):
        lines.append(f"I{5001 + i}=${addr:06X} ; {what}")
    scale = 32 * int(params.position_loop_scale)
    frac = trace.aux1 if trace.aux1 is not None else np.zeros(trace.n_ticks, np.int64)
    step = int(params.servo_cycle_extension) + 1
    for k in range(trace.n_ticks):
        words = []
        if counter:
            words.append(f"{(k * step) & 0xFFFFFF:06X}")
        cmd = (int(trace.commanded[k]) * 32 + int(frac[k])) * int(params.position_loop_scale)
        act = int(trace.actual[k]) * scale
        words.append(f"{cmd & ((1 << 48) - 1):012X}")
        words.append(f"{act & ((1 << 48) - 1):012X}")
        words.append(f"{(int(trace.command[k]) << 8) & 0xFFFFFF:06X}")
        lines.append(" ".join(words))
    return "\n".join(lines) + "\n"
