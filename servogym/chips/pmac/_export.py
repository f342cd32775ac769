"""Export and import of Turbo PMAC parameter sets: JSON with provenance, and I-variable files.

Two formats; each imports back to the identical :class:`PMACParams`:

* ``"json"``: a parameter file with provenance (chip model, spec version, assumptions,
  creation time, servogym version, optional metrics and notes), the layout every servogym
  family shares.
* ``"ivar"``: the lines a Turbo PMAC takes for one motor, ``I130=2000``, under ``;`` comment
  lines with the provenance. Notch coefficients are written as exact decimals of their 24-bit
  words (``I136=-1.86072540283203125``); the servo clock as the global ``I7000..I7002``.

Every export validates the set first and refuses an illegal one with the parameter, the value
and the legal range: the controller itself would roll an out-of-range value over silently.
:func:`from_ivar` also reads a file saved by the controller: it takes the motor's registers
and ignores every other variable, comment and program buffer.
"""

from __future__ import annotations

import re
from collections.abc import Mapping
from fractions import Fraction
from typing import Any

from servogym import __version__
from servogym._files import seal, unseal
from servogym.chips._axisfile import axes_text, check_header_axes, header_axes
from servogym.chips._formats import Formats, check_index, resolve_model
from servogym.chips._formats import read_header as read_header_lines
from servogym.chips._paramfile import ExtraKey, FileSchema, assumption_lines
from servogym.chips._space import ParameterError
from servogym.chips.pmac._params import (
    CHIP_MODELS,
    COEFFICIENT_FIELDS,
    COEFFICIENT_FRACTION_BITS,
    FIELDS,
    GLOBAL_FIELDS,
    I_VARIABLES,
    SPEC_VERSION,
    PMACAssumptions,
    PMACChipModel,
    PMACParams,
    coefficient_raw,
    get_model,
    ivar_name,
    parameter_space,
)

FILE_EXTENSIONS: dict[str, str] = {"json": ".json", "ivar": ".pmc"}
"""Every export format, in the order :func:`export` documents them, and its file extension."""

FORMATS: tuple[str, ...] = tuple(FILE_EXTENSIONS)

# --------------------------------------------------------------------------------------
# Shared checks
# --------------------------------------------------------------------------------------


def _check_motor(chip: PMACChipModel, motor: Any, where: str = "") -> int:
    return check_index(chip, motor, chip.n_motors, noun="motor", verb="addresses", where=where)


# --------------------------------------------------------------------------------------
# Format 1: JSON parameter file: the layout every family shares (servogym.chips._paramfile)
# --------------------------------------------------------------------------------------

_SCHEMA = FileSchema(
    "pmac",
    "PMAC",
    SPEC_VERSION,
    PMACParams,
    PMACAssumptions,
    get_model,
    required=parameter_space,
    extra_keys={
        "sample_time_s": ExtraKey(
            kind=(int, float),
            what="a number",
            rule=lambda p: f"the period the clock registers and Ixx60 give ({p.sample_time_s!r} s)",
        )
    },
)

to_json, from_json = _SCHEMA.json_functions(__name__)


# --------------------------------------------------------------------------------------
# Format 2: I-variable file
# --------------------------------------------------------------------------------------


def coefficient_text(raw: int) -> str:
    """The exact decimal of a 24-bit coefficient word ``raw / 2^22`` (e.g. ``-1.5``).

    Every such value has a finite decimal expansion (at most 22 fractional digits), so the
    controller receives exactly the word whatever rounding its parser uses.
    """
    raw = int(raw)
    digits = COEFFICIENT_FRACTION_BITS
    scaled = abs(raw) * 5**digits  # raw / 2^22 = raw * 5^22 / 10^22
    whole, frac = divmod(scaled, 10**digits)
    text = str(whole)
    if frac:
        text += "." + f"{frac:0{digits}d}".rstrip("0")
    return "-" + text if raw < 0 else text


def _header_lines(motors: Mapping[int, PMACParams], a: PMACAssumptions) -> list[str]:
    """The provenance header; ``motor: 3`` for one motor, ``motors: 1, 2`` for several (with
    each motor's sample time, which its Ixx60 sets, in motor order)."""
    p = next(iter(motors.values()))
    chip = p.chip
    many = len(motors) > 1
    numbers = axes_text(motors)
    lines = [
        f"servogym PMAC parameter set: I-variables of motor{'s' if many else ''} {numbers}",
        f"chip_model: {chip.name}",
        f"chip_line: {chip.line}",
        f"spec_version: {SPEC_VERSION}",
        f"motor{'s' if many else ''}: {numbers}",
        f"servo_period_us: {p.servo_period_s * 1e6:.6f}",
        f"sample_time_us: {', '.join(f'{q.sample_time_us:.6f}' for q in motors.values())}",
        f"servogym_version: {__version__}",
    ]
    lines += assumption_lines(a)
    lines += [
        "Every value was checked against its legal range: the controller rolls an",
        "out-of-range I-variable over silently. I7000..I7002 set the servo clock of every",
        "motor on the controller.",
    ]
    return lines


def to_ivar(
    params: PMACParams | Mapping[str, Any],
    motor: int = 1,
    assumptions: PMACAssumptions | Mapping[str, str] | None = None,
) -> str:
    """The I-variable assignments that load the set into one motor, under a provenance header.

    Args:
        params: The parameter set; validated again first.
        motor: Motor number ``xx`` (1 .. 32): ``proportional_gain`` becomes ``Ixx30``.
        assumptions: Recorded in the header; default all defaults.

    Returns:
        The text: ``;`` comment lines, then one ``I130=2000 ; proportional_gain`` line per
        register, in I-variable order; newline-terminated.

    Raises:
        ParameterError: for an illegal set (naming parameter, value and range) or motor.
    """
    p = _SCHEMA.legal_params(params)
    return _ivar_text({_check_motor(p.chip, motor): p}, assumptions)


def _assignment(p: PMACParams, name: str, motor: int) -> str:
    value = getattr(p, name)
    text = coefficient_text(value) if name in COEFFICIENT_FIELDS else str(value)
    return f"{ivar_name(name, motor)}={text} ; {name}"


def _ivar_text(
    motors: Mapping[int, PMACParams], assumptions: PMACAssumptions | Mapping[str, str] | None
) -> str:
    """The I-variable file of one or several motors: each motor's ``Ixx`` lines in motor
    order (a blank line between), then the global I-variables once (every motor holds the
    same values: :class:`servogym.chips.MultiAxisParams` checks it)."""
    sets = {n: _SCHEMA.legal_params(p) for n, p in motors.items()}
    a = _SCHEMA.legal_assumptions(assumptions)
    out = [f"; {line}" for line in _header_lines(sets, a)]
    for i, (motor, p) in enumerate(sets.items()):
        if i:
            out.append("")
        out += [_assignment(p, name, motor) for name in FIELDS if name not in GLOBAL_FIELDS]
    first = next(iter(sets.items()))
    out += [_assignment(first[1], name, first[0]) for name in GLOBAL_FIELDS]
    return seal("\n".join(out) + "\n", ";")


def read_header(text: str) -> dict[str, Any]:
    """The provenance header of an I-variable file (``; key: value`` comment lines).

    Returns:
        The entries as strings (``chip_model``, ``spec_version``, ``motor``, ...), and under
        ``"assumptions"`` a :class:`PMACAssumptions` when the header lists them. Empty if the
        file has no header (e.g. one saved by the controller).

    Raises:
        ParameterError: if the header lists only some assumptions, or an unknown one.
    """
    return read_header_lines(text.splitlines(), _SCHEMA, "PMAC", lead=r"\s*;+\s*")


# An assignment to one I-variable or a range of them (``I130..139=0``); the value runs to
# the next blank. ``(?<![\w$.])`` keeps ``MI130``, ``PI130`` and ``$I1`` from matching.
_ASSIGN = re.compile(r"(?<![\w$.])I\s*(\d+)(?:\s*\.\.\s*(\d+))?\s*=\s*([^\s]*)", re.IGNORECASE)
_INTEGER = re.compile(r"^[-+]?\d+$")
_HEX = re.compile(r"^\$[0-9a-fA-F]+$")
_DECIMAL = re.compile(r"^[-+]?(?:\d+\.?\d*|\.\d+)(?:[eE][-+]?\d+)?$")
_OPEN = re.compile(r"^\s*OPEN\b", re.IGNORECASE)
_CLOSE = re.compile(r"^\s*CLOSE\b", re.IGNORECASE)


def _ours(motor: int) -> dict[int, str]:
    """I-variable number -> register, for ``motor``."""
    return {int(ivar_name(f, motor)[1:]): f for f in FIELDS}


def _parse_value(field: str, token: str, where: str) -> int:
    ivar = I_VARIABLES[field]
    if field in COEFFICIENT_FIELDS:
        if not _DECIMAL.match(token):
            raise ParameterError(
                f"{where}: {field} (Ixx{ivar}) must be a decimal coefficient such as -1.86; "
                f"got {token!r}."
            )
        return _coefficient_word(field, ivar, token, where)
    if _INTEGER.match(token):
        return int(token)
    if _HEX.match(token):
        return int(token[1:], 16)
    if _DECIMAL.match(token):
        raise ParameterError(
            f"{where}: {field} must be an integer (the controller would truncate "
            f"{token!r} silently); got {field}={token!r}."
        )
    raise ParameterError(
        f"{where}: {field} must be assigned a constant (decimal or $hex integer); got "
        f"{token!r}. Expressions are not read."
    )


def _coefficient_word(field: str, ivar: int, token: str, where: str) -> int:
    """The 24-bit word a coefficient text names, refusing text that names none exactly.

    Accepted: the exact decimal of a word (as :func:`coefficient_text` writes it), or a
    word printed to so many digits that no other word rounds to the same text (a step of
    the last digit below 2^-22, as a controller prints it). Refused: anything else, e.g.
    ``-1.86`` or ``1e-9``, which the controller would round to a word the file does not
    show.
    """
    value = Fraction(token)
    raw = coefficient_raw(value)
    scale = 1 << COEFFICIENT_FRACTION_BITS
    if value * scale == raw:
        return raw
    mantissa, _, exponent = token.lower().partition("e")
    decimals = len(mantissa.partition(".")[2])
    step = Fraction(10) ** (int(exponent or 0) - decimals)  # place of the last digit
    if step * scale < 1 and abs(value - Fraction(raw, scale)) <= step / 2:
        return raw
    raise ParameterError(
        f"{where}: {field} (Ixx{ivar}) holds multiples of 2^-{COEFFICIENT_FRACTION_BITS}; got "
        f"{token}, which names no single one (the controller would round it to "
        f"{coefficient_text(raw)}). Write the exact value, e.g. {coefficient_text(raw)}."
    )


def _motors_in(assignments: list[tuple[int, int | None, str, str]]) -> list[int]:
    suffixes = {n for f, n in I_VARIABLES.items() if f not in GLOBAL_FIELDS}
    motors = set()
    for first, last, _, _ in assignments:
        for number in range(first, (last if last is not None else first) + 1):
            if 100 <= number < 3300 and number % 100 in suffixes:
                motors.add(number // 100)
    return sorted(motors)


def from_ivar(
    text: str, model: str | PMACChipModel | None = None, motor: int | None = None
) -> PMACParams:
    """Read the registers of one motor from an I-variable file.

    Reads what :func:`to_ivar` writes and what the controller saves: ``I130=2000`` lines
    (several per line, ``I130..139=0`` ranges and ``$`` hex integers too), ``;`` comments.
    Every other variable (I-variables of other motors or other functions, P, Q and M
    variables) and the contents of program buffers (``OPEN PLC 1 ... CLOSE``) are ignored.

    Args:
        text: The file content.
        model: Chip model; default the header's ``chip_model:``. Required when the file has
            no header (a controller's file does not name its model). If both are given they
            must agree.
        motor: Motor number; default the header's ``motor:``, else the only motor whose
            registers the file sets.

    Returns:
        The parameter set.

    Raises:
        ParameterError: naming the line, for a register set to a non-constant, a
            non-integer where an integer belongs, an out-of-range value (with its range), a
            register set twice to different values, or a register left unset.
    """
    original = text
    text, _sealed = unseal(text, verify=False)
    header = read_header(text)
    chip = resolve_model(model, header, get_model, CHIP_MODELS, "I-variable file")
    assignments = _assignments(text)

    if motor is None:
        if "motor" in header:
            try:
                motor = int(header["motor"])
            except ValueError:
                raise ParameterError(
                    f"the header's 'motor: {header['motor']}' is not a motor number."
                ) from None
        else:
            found = _motors_in(assignments)
            if len(found) != 1:
                listed = ", ".join(map(str, found)) or "none"
                raise ParameterError(
                    f"the file sets registers of motors {listed}; pass motor= to choose one "
                    f"(or read them all with servogym.chips.import_axes)."
                )
            motor = found[0]
    motor = _check_motor(chip, motor)
    params = _motor_params(chip, motor, assignments)
    unseal(original)
    return params


def _ivar_axes(text: str, model: str | PMACChipModel | None) -> dict[int, PMACParams]:
    """Motor number -> set, of every motor the header names (``motors:`` or ``motor:``), or
    without a header every motor whose registers the file sets."""
    original = text
    text, _sealed = unseal(text, verify=False)
    header = read_header(text)
    chip = resolve_model(model, header, get_model, CHIP_MODELS, "I-variable file")
    assignments = _assignments(text)
    named = header_axes(header, "motor")
    found = _motors_in(assignments)
    if not found:
        raise ParameterError("the I-variable file sets the registers of no motor.")
    if named is not None:
        check_header_axes(named, found, "motor")
    sets = {m: _motor_params(chip, _check_motor(chip, m), assignments) for m in found}
    unseal(original)
    return sets


def _assignments(text: str) -> list[tuple[int, int | None, str, str]]:
    """Every ``I<n>=<token>`` (or ``I<n>..<m>=``) outside program buffers, with its line."""
    assignments: list[tuple[int, int | None, str, str]] = []
    in_buffer = False
    for n, raw in enumerate(text.splitlines(), start=1):
        line = raw.split(";", 1)[0]
        if in_buffer:
            in_buffer = not _CLOSE.match(line)
            continue
        if _OPEN.match(line):
            in_buffer = True
            continue
        for m in _ASSIGN.finditer(line):
            first = int(m.group(1))
            last = int(m.group(2)) if m.group(2) else None
            assignments.append((first, last, m.group(3), f"line {n}"))
    return assignments


def _motor_params(
    chip: PMACChipModel, motor: int, assignments: list[tuple[int, int | None, str, str]]
) -> PMACParams:
    """The set of one motor from a file's assignments (global I-variables included)."""
    ours = _ours(motor)
    space = parameter_space(chip)
    values: dict[str, int] = {}
    where_set: dict[str, str] = {}
    for first, last, token, where in assignments:
        for number in range(first, (last if last is not None else first) + 1):
            field = ours.get(number)
            if field is None:
                continue
            value = _parse_value(field, token, where)
            try:
                value = space[field].validate(value, context=f"I{number}")
            except ParameterError as exc:
                raise ParameterError(f"{where}: {exc}") from None
            if field in values and values[field] != value:
                raise ParameterError(
                    f"{where}: I{number} ({field}) is set to {token} but {where_set[field]} "
                    f"set it to another value; the controller would keep the last, so the "
                    f"file is ambiguous. Remove one."
                )
            values[field] = value
            where_set[field] = where
    missing = [f for f in FIELDS if f not in values]
    if missing:
        listed = ", ".join(f"{ivar_name(f, motor)} ({f})" for f in missing)
        raise ParameterError(
            f"the I-variable file does not set every register of motor {motor}; an import "
            f"takes no defaults. Missing: {listed}."
        )
    return PMACParams(model=chip.name, **values)


# --------------------------------------------------------------------------------------
# Dispatch
# --------------------------------------------------------------------------------------


def _write_ivar(params: Any, **kw: Any) -> str:
    if "axis" in kw:  # every family's export takes axis; for PMAC it is the motor
        axis = kw.pop("axis")
        if "motor" in kw and kw["motor"] != axis:
            raise ParameterError(
                f"axis and motor name the same thing for PMAC; got axis={axis!r} and "
                f"motor={kw['motor']!r}."
            )
        kw["motor"] = axis
    return to_ivar(params, **kw)


FORMAT_TABLE = Formats(
    _SCHEMA,
    FILE_EXTENSIONS,
    writers={"ivar": _write_ivar},
    readers={"ivar": lambda text, model, motor=None: from_ivar(text, model, motor)},
    export_keywords={"ivar": ("motor", "axis", "assumptions")},
    import_keywords={"ivar": ("motor",)},
    index="motor",
    axis_writers={"ivar": _ivar_text},
    axis_readers={"ivar": _ivar_axes},
)

export, import_params = FORMAT_TABLE.functions(
    __name__,
    "PMACParams",
    '``"json"`` (:func:`to_json`) or ``"ivar"`` (:func:`to_ivar`)',
    "``assumptions`` to both formats; ``motor`` (or its other name ``axis``, which every "
    "family's export takes) to ``\"ivar\"`` (a JSON file holds one motor's set and ignores "
    "it); ``metrics``, ``notes``, ``created`` to JSON.",
    index_doc='``motor``, for ``"ivar"`` only: the motor to read; default the header\'s, '
    "else the only one.",
)
