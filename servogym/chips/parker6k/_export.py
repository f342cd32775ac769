"""Export and import of 6000-series parameter sets: JSON, and command files the controller takes.

Three formats; each imports back to the identical :class:`Parker6kParams`:

* ``"json"``: a parameter file with provenance (model, spec version, assumptions, creation
  time, servogym version, optional metrics and notes).
* ``"6250"``: a command file with comma-separated axis fields, as the 6250 takes them
  (``SGP.5,.5`` sets both axes; ``SGP,85`` only axis 2).
* ``"6k"``: a command file with axis-prefixed commands, as the 6K takes them (``1SGP10``).

A command file stores each gain set with the five gains followed by ``SGSET<n>``, then gives
the gains in force and the axis settings. The SGENB schedule of a set is simulation data
(ticks of the servo loop), written as ``; sgenb tick=<t> set=<n>`` comment lines that the
controller ignores and the importer reads. Every export validates the set first and refuses
an illegal one; an import refuses an illegal value naming the line, the value and the range,
and a value with more decimals than the command's resolution. Where the syntax comes from:
``docs/chips/parker6k.md``, section 7.
"""

from __future__ import annotations

import difflib
import re
from collections.abc import Mapping
from typing import Any

from servogym import __version__
from servogym._files import seal, unseal
from servogym.chips._axisfile import axes_text, check_header_axes, header_axes
from servogym.chips._formats import Formats, check_index, resolve_model
from servogym.chips._formats import read_header as read_header_lines
from servogym.chips._paramfile import ExtraKey, FileSchema, assumption_lines
from servogym.chips._space import ParameterError
from servogym.chips.parker6k._params import (
    CHIP_MODELS,
    COMMANDS,
    DECIMALS,
    FIELDS,
    GAIN_FIELDS,
    MAX_GAIN_SETS,
    SPEC_VERSION,
    GainSet,
    Parker6kAssumptions,
    Parker6kModel,
    Parker6kParams,
    check_ssfr,
    format_decimal,
    get_model,
    parameter_space,
)

FILE_EXTENSIONS: dict[str, str] = {"json": ".json", "6250": ".prg", "6k": ".prg"}
"""Every export format, in the order :func:`export` documents them, and its file extension."""

FORMATS: tuple[str, ...] = tuple(FILE_EXTENSIONS)

_SYSTEM_COMMANDS = ("SSFR", "SGSET")  # controller-wide: no axis fields, no prefix [A]
_REGISTER_OF = {cmd: reg for reg, cmd in COMMANDS.items()}
_KNOWN = (*COMMANDS.values(), "SGSET", "SGENB")


# --------------------------------------------------------------------------------------
# Shared checks
# --------------------------------------------------------------------------------------


def _check_axis(chip: Parker6kModel, axis: Any, where: str = "") -> int:
    return check_index(chip, axis, chip.n_axes, where=where)


def _check_format(fmt: Any) -> str:
    return FORMAT_TABLE.check(fmt)


def _check_form(chip: Parker6kModel, fmt: str) -> None:
    if fmt == "6k" and not chip.axis_prefix:
        raise ParameterError(
            f"the {chip.name} takes comma-separated axis fields, not axis-prefixed commands; "
            f"use fmt='6250' for a {chip.name} (the '6k' form is for models "
            f"{', '.join(m.name for m in CHIP_MODELS.values() if m.axis_prefix)})."
        )


# --------------------------------------------------------------------------------------
# Decimal values
# --------------------------------------------------------------------------------------

_DECIMAL = re.compile(r"^([+-]?)(\d*)(?:\.(\d*))?$")


def parse_decimal(text: str, register: str) -> int:
    """The register count of a command value: ``parse_decimal('.5', 'sgp') == 50``.

    Args:
        text: The value as written (``85``, ``85.``, ``.5``, ``+2.30``, ``-.25``).
        register: The register it sets (its resolution is :data:`DECIMALS`).

    Raises:
        ParameterError: if the text is not a decimal number, or has a nonzero digit beyond
            the command's resolution (trailing zeros are accepted). The range is not
            checked here.
    """
    command = COMMANDS[register]
    places = DECIMALS[register]
    m = _DECIMAL.match(text.strip())
    if not m or not (m.group(2) or m.group(3)):
        raise ParameterError(
            f"{command} takes a decimal number such as {command}85 or {command}.5; "
            f"got {command}{text!r}."
        )
    sign, whole, frac = m.group(1), m.group(2) or "0", m.group(3) or ""
    extra = frac[places:]
    if extra.strip("0"):
        step = "1" if places == 0 else f"{10**-places:.{places}f}"
        raise ParameterError(
            f"{command} takes at most {places} decimal{'s' if places != 1 else ''} (steps of "
            f"{step}); got {command}{text.strip()}, which has more: the controller would "
            f"not hold it exactly."
        )
    frac = frac[:places].ljust(places, "0")
    value = int(whole) * 10**places + (int(frac) if frac else 0)
    return -value if sign == "-" else value


# --------------------------------------------------------------------------------------
# Provenance header (comment lines)
# --------------------------------------------------------------------------------------

_HEADER_SWITCH = re.compile(r"^\s*sgenb\s+tick\s*=\s*(\S+)\s+set\s*=\s*(\S+)\s*$")
_AXIS_SWITCH = re.compile(
    r"^\s*sgenb\s+axis\s*=\s*(\S+)"  # a file of several axes: the axis first
    r"\s+tick\s*=\s*(\S+)\s+set\s*=\s*(\S+)\s*$"
)


def _split(text: str) -> list[tuple[int, str, str]]:
    """``(line number, code, comment)`` of each line; ``;`` starts a comment."""
    out = []
    for n, raw in enumerate(text.splitlines(), start=1):
        code, sep, comment = raw.partition(";")
        out.append((n, code, comment if sep else ""))
    return out


def read_header(text: str) -> dict[str, Any]:
    """The provenance header of a command file written by :func:`to_command_file`.

    Returns:
        The ``key: value`` comment entries as strings (``chip_model``, ``spec_version``,
        ``axis``, ``form``, ...); under ``"assumptions"`` a :class:`Parker6kAssumptions`
        when the header lists them; under ``"sgenb"`` the schedule's ``(tick, set)`` pairs
        as strings, in file order. Empty if there is no header.

    Raises:
        ParameterError: if the header lists only some assumptions, or an unknown one.
    """
    lines = [(n, comment) for n, _code, comment in _split(text) if comment]
    fields = read_header_lines((c for _n, c in lines), _SCHEMA, "PK")
    switches = [(n, *m.groups()) for n, c in lines if (m := _HEADER_SWITCH.match(c))]
    if switches:
        fields["sgenb"] = switches
    per_axis = [(n, *m.groups()) for n, c in lines if (m := _AXIS_SWITCH.match(c))]
    if per_axis:
        fields["sgenb_axes"] = per_axis
    return fields


def _header_lines(
    axes: Mapping[int, Parker6kParams], a: Parker6kAssumptions, fmt: str
) -> list[str]:
    """The provenance header; ``axis: 2`` and ``sgenb tick=.. set=..`` lines for one axis,
    ``axes: 1, 2`` and ``sgenb axis=.. tick=.. set=..`` lines for several."""
    form = "comma-separated axis fields" if fmt == "6250" else "axis-prefixed commands"
    numbers = list(axes)
    p = axes[numbers[0]]
    lines = [
        f"servogym Parker 6000-series parameter set, {fmt} command file ({form})",
        f"chip_model: {p.model}",
        f"form: {fmt}",
        f"axis: {numbers[0]}" if len(numbers) == 1 else f"axes: {axes_text(numbers)}",
        f"spec_version: {SPEC_VERSION}",
        f"sample_time_us: {p.sample_time_us}",
        f"servogym_version: {__version__}",
        "units: SMPER in encoder counts (scaling off); gains as assumption PK-A1 says",
    ]
    lines += assumption_lines(a)
    if len(numbers) == 1:
        lines += [f"sgenb tick={t} set={s}" for t, s in p.sgenb]
    else:
        lines += [f"sgenb axis={n} tick={t} set={s}" for n, q in axes.items() for t, s in q.sgenb]
    return lines


# --------------------------------------------------------------------------------------
# Command files
# --------------------------------------------------------------------------------------


def _lines(command: str, values: Mapping[int, str], fmt: str) -> list[str]:
    """The command lines that give each axis its value: a controller-wide command once
    (``SSFR4``, ``SGSET2``), the 6K form one prefixed line per axis (``1SGP85``, ``2SGP90``),
    the 6250 form one line of comma-separated fields up to the last axis, an axis not given
    an empty field (``SGP85,90``; ``SGP,90``; ``SGP85,,90``) [C]."""
    if command in _SYSTEM_COMMANDS:
        return [f"{command}{next(iter(values.values()))}"]
    if fmt == "6k":
        return [f"{axis}{command}{value}" for axis, value in values.items()]
    fields = [values.get(axis, "") for axis in range(1, max(values) + 1)]
    return [f"{command}{','.join(fields)}"]


def _register_lines(register: str, axes: Mapping[int, Any], fmt: str) -> list[str]:
    """The lines that set ``register`` of each axis to its value (``axes``: axis -> an
    object with the register as attribute: a set, or a stored gain set)."""
    places = DECIMALS[register]
    values = {n: format_decimal(getattr(q, register), places) for n, q in axes.items()}
    return _lines(COMMANDS[register], values, fmt)


def to_command_file(
    params: Parker6kParams | Mapping[str, Any],
    fmt: str = "6250",
    axis: int = 1,
    assumptions: Parker6kAssumptions | Mapping[str, str] | None = None,
) -> str:
    """A command file that loads the set into one axis.

    Order: ``SSFR``; each stored set as its five gains then ``SGSET<n>``; the gains in
    force; ``SGILIM``, ``SOFFS``, ``SMPER``. A ``;`` header carries the provenance and the
    SGENB schedule.

    Args:
        params: The parameter set; validated again first.
        fmt: ``"6250"`` (comma-separated axis fields, any model) or ``"6k"`` (axis-prefixed
            commands, 6K only).
        axis: Axis number, 1 .. the model's axis count.
        assumptions: Recorded in the header; default all defaults.

    Returns:
        The file text, one command a line, newline-terminated.

    Raises:
        ParameterError: for an illegal set, axis or form.
    """
    p = _SCHEMA.legal_params(params)
    fmt = _check_format(fmt)
    if fmt == "json":
        raise ParameterError("to_command_file writes fmt='6250' or fmt='6k'; use to_json.")
    _check_form(p.chip, fmt)
    return _command_text({_check_axis(p.chip, axis): p}, fmt, assumptions)


def _command_text(
    axes: Mapping[int, Parker6kParams],
    fmt: str,
    assumptions: Parker6kAssumptions | Mapping[str, str] | None,
) -> str:
    """The command file of one or several axes (axis -> set, one model, one SSFR).

    Stored set n is every axis's five gains that has a set n, then one ``SGSET<n>`` (a
    controller-wide command: it stores the gains in force of every axis [A]); an axis with
    fewer stored sets gets no fields from there on.
    """
    sets = {n: _SCHEMA.legal_params(p) for n, p in axes.items()}
    a = _SCHEMA.legal_assumptions(assumptions)
    first = next(iter(sets.values()))
    _check_form(first.chip, fmt)
    lines = [f"; {line}" for line in _header_lines(sets, a, fmt)]
    lines += _register_lines("ssfr", sets, fmt)
    for number in range(1, max(len(p.sgset) for p in sets.values()) + 1):
        stored = {n: p.sgset[number - 1] for n, p in sets.items() if len(p.sgset) >= number}
        for g in GAIN_FIELDS:
            lines += _register_lines(g, stored, fmt)
        lines += _lines("SGSET", {0: str(number)}, fmt)
    for r in (*GAIN_FIELDS, "sgilim", "soffs", "smper"):
        lines += _register_lines(r, sets, fmt)
    return seal("".join(line + "\n" for line in lines), ";")


_COMMAND = re.compile(r"^(\d*)\s*([A-Za-z]+)\s*(.*?)\s*$")


class _Reader:
    """The controller's state as a command file sets it, for one axis."""

    def __init__(self, chip: Parker6kModel, axis: int, fmt: str, several: bool = False) -> None:
        self.chip = chip
        self.axis = axis
        self.fmt = fmt
        self.several = several  # a file of several axes: an axis may sit a stored set out
        self.space = parameter_space(chip)
        self.values: dict[str, int] = {}
        self.stored: dict[int, GainSet] = {}
        self.since_store: set[str] = set()  # gains set since the last SGSET

    def field(self, where: str, command: str, prefix: str, value: str) -> str | None:
        """The value for this axis, or None when the command leaves this axis alone."""
        if command in _SYSTEM_COMMANDS:
            if prefix or "," in value:
                raise ParameterError(
                    f"{where}: {command} is a controller-wide command: write it without an "
                    f"axis prefix or axis fields (e.g. {command}4); got "
                    f"{prefix}{command}{value}."
                )
            return value
        if prefix:
            if self.fmt != "6k":
                raise ParameterError(
                    f"{where}: the 6250 form takes comma-separated axis fields, not an axis "
                    f"prefix; got {prefix}{command}{value} (write {command}"
                    f"{',' * (int(prefix) - 1)}{value}, or import with fmt='6k')."
                )
            target = _check_axis(self.chip, int(prefix), where)
            return value if target == self.axis else None
        fields = value.split(",")
        if len(fields) > self.chip.n_axes:
            raise ParameterError(
                f"{where}: {command} has {len(fields)} axis fields but the {self.chip.name} "
                f"has {self.chip.n_axes} axes; got {command}{value}."
            )
        text = fields[self.axis - 1] if self.axis <= len(fields) else ""
        return text if text.strip() else None

    def set_register(self, where: str, register: str, text: str) -> None:
        try:
            value = parse_decimal(text, register)
            self.values[register] = self.space[register].validate(value, context=self.chip.name)
        except ParameterError as exc:
            raise ParameterError(f"{where}: {exc}") from None
        if register == "ssfr":
            try:
                check_ssfr(self.values["ssfr"], self.chip.name)
            except ParameterError as exc:
                raise ParameterError(f"{where}: {exc}") from None
        self.since_store.add(register)

    def set_number(self, where: str, command: str, text: str) -> int:
        if not re.fullmatch(r"\d+", text.strip()):
            raise ParameterError(
                f"{where}: {command} takes a gain set number 1 .. {MAX_GAIN_SETS}; "
                f"got {command}{text}."
            )
        number = int(text)
        if not 1 <= number <= MAX_GAIN_SETS:
            raise ParameterError(
                f"{where}: {command} must name a gain set with 1 <= set <= {MAX_GAIN_SETS}; "
                f"got {command}{text}."
            )
        return number

    def store(self, where: str, number: int) -> None:
        if self.several and not self.since_store.intersection(GAIN_FIELDS):
            self.since_store.clear()  # this axis takes no part in stored set ``number``
            return
        missing = [COMMANDS[g] for g in GAIN_FIELDS if g not in self.since_store]
        if missing:
            raise ParameterError(
                f"{where}: SGSET{number} stores the five gains, but the file does not set "
                f"{', '.join(missing)} for axis {self.axis} since the previous SGSET; each "
                f"stored set must give all five (a gain is never taken over from another set)."
            )
        self.stored[number] = GainSet(**{g: self.values[g] for g in GAIN_FIELDS})
        self.since_store.clear()

    def enable(self, where: str, number: int) -> None:
        if number not in self.stored:
            raise ParameterError(
                f"{where}: SGENB{number} enables gain set {number}, which the file has not "
                f"stored with SGSET{number} before it."
            )
        self.values.update(self.stored[number].to_dict())
        self.since_store.update(GAIN_FIELDS)  # SGENB names all five at once

    def result(self, switches: list[tuple[int, str, str]]) -> Parker6kParams:
        """The axis's set, with the SGENB schedule of ``switches`` ``(line, tick, set)``."""
        axis = self.axis
        missing = [COMMANDS[r] for r in FIELDS if r not in self.values]
        if missing:
            raise ParameterError(
                f"the command file does not set {', '.join(missing)} for axis {axis}; an "
                f"import takes no defaults."
            )
        numbers = sorted(self.stored)
        if numbers != list(range(1, len(numbers) + 1)):
            gap = next(i for i in range(1, MAX_GAIN_SETS + 1) if i not in self.stored)
            where = f" for axis {axis}" if self.several else ""
            raise ParameterError(
                f"the stored gain sets must be numbered from 1 without gaps; the file stores "
                f"{', '.join(f'SGSET{i}' for i in numbers)}{where} but not SGSET{gap}."
            )
        schedule = []
        for n, tick, number in switches:
            if not (tick.isdigit() and number.isdigit()):
                raise ParameterError(
                    f"line {n}: a schedule line reads '; sgenb tick=<integer> set=<integer>'; "
                    f"got tick={tick!r} set={number!r}."
                )
            schedule.append((int(tick), int(number)))
        return Parker6kParams(
            model=self.chip.name,
            **self.values,
            sgset=tuple(self.stored[i] for i in numbers),
            sgenb=tuple(schedule),
        )


def from_command_file(
    text: str,
    fmt: str = "6250",
    model: str | Parker6kModel | None = None,
    axis: int | None = None,
) -> Parker6kParams:
    """Read a command file back into the parameter set of one axis.

    The file is read as the controller executes it: commands are separated by newlines or
    ``:``; ``;`` starts a comment; later commands overwrite earlier ones; ``SGSET<n>`` stores
    the gains set so far as set n; ``SGENB<n>`` makes set n's gains the gains in force. The
    stored sets must be numbered from 1 without gaps. The SGENB schedule comes from the
    header's ``; sgenb tick=<t> set=<n>`` lines.

    Args:
        text: The file.
        fmt: ``"6250"`` or ``"6k"`` (which also takes comma-separated fields).
        model: Default the header's ``chip_model``; if both are given they must agree.
        axis: Default the header's ``axis``, else 1; if both are given they must agree.

    Returns:
        The parameter set.

    Raises:
        ParameterError: naming the line, for an unknown command, a value out of range (with
            the range) or finer than the command's resolution, an axis field or prefix the
            model does not have, a setting the file never makes, or a gap in the stored sets.
    """
    fmt = _check_format(fmt)
    if fmt == "json":
        raise ParameterError("from_command_file reads fmt='6250' or fmt='6k'; use from_json.")
    original = text
    text, _sealed = unseal(text, verify=False)
    header = read_header(text)
    chip = _resolve_model(model, header)
    _check_form(chip, fmt)
    named_axis = header.get("axis")
    if axis is None:
        axis = int(named_axis) if named_axis is not None and named_axis.isdigit() else 1
    axis = _check_axis(chip, axis)
    if named_axis is not None and named_axis != str(axis):
        raise ParameterError(
            f"axis={axis} disagrees with the header's 'axis: {named_axis}'; pass "
            f"axis={named_axis}, or axis=None to use the header."
        )
    reader = _Reader(chip, axis, fmt)
    _execute(text, {axis: reader})
    params = reader.result(header.get("sgenb", []))
    unseal(original)
    return params


def _command_axes(text: str, fmt: str, model: str | Parker6kModel | None) -> dict[int, Any]:
    """Axis number -> set, of a command file of one or several axes: the axes the header
    names (``axes:`` or ``axis:``), or without a header every axis the file sets.

    Read as the controller executes it, as :func:`from_command_file` reads one axis, with one
    difference: an axis that sets none of its five gains between two ``SGSET`` takes no part
    in that stored set (its stored sets end before it; another stored set after that is a
    gap and refused).
    """
    original = text
    text, _sealed = unseal(text, verify=False)
    header = read_header(text)
    chip = _resolve_model(model, header)
    _check_form(chip, fmt)
    readers = {n: _Reader(chip, n, fmt, several=True) for n in range(1, chip.n_axes + 1)}
    _execute(text, readers)
    found = [n for n, r in readers.items() if r.stored or set(r.values) - {"ssfr"}]
    if not found:
        raise ParameterError("the command file sets the registers of no axis.")
    check_header_axes(header_axes(header), found)
    plain = header.get("sgenb", [])
    if plain and len(found) > 1:
        raise ParameterError(
            f"line {plain[0][0]}: a schedule line of a file of several axes names its axis "
            f"('; sgenb axis=<n> tick=<t> set=<n>'); got one without."
        )
    per_axis: dict[int, list[tuple[int, str, str]]] = {}
    for n, number, tick, gain_set in header.get("sgenb_axes", []):
        if not number.isdigit() or int(number) not in found:
            raise ParameterError(
                f"line {n}: the schedule line's axis must be one the file sets "
                f"({axes_text(found)}); got axis={number!r}."
            )
        per_axis.setdefault(int(number), []).append((n, tick, gain_set))
    sets = {n: readers[n].result(per_axis.get(n, plain)) for n in found}
    unseal(original)
    return sets


def _execute(text: str, readers: Mapping[int, _Reader]) -> None:
    """Run a command file's commands on every axis's reader, in file order."""
    for n, code, _comment in _split(text):
        for part in code.split(":"):
            command_text = part.strip()
            if not command_text:
                continue
            where = f"line {n}"
            m = _COMMAND.match(command_text)
            if not m:
                raise ParameterError(
                    f"{where}: cannot read {command_text!r}; a command reads like SGP85, "
                    f"SGP,.5 or 1SGP10."
                )
            prefix, name, value = m.group(1), m.group(2).upper(), m.group(3)
            if name not in _KNOWN:
                close = difflib.get_close_matches(name, _KNOWN, n=2)
                hint = f" Did you mean {', '.join(close)}?" if close else ""
                raise ParameterError(
                    f"{where}: unknown command {name}; the commands of a servogym 6000-series "
                    f"file are {', '.join(_KNOWN)}.{hint}"
                )
            for reader in readers.values():
                field = reader.field(where, name, prefix, value)
                if field is None:
                    continue
                if name == "SGSET":
                    reader.store(where, reader.set_number(where, name, field))
                elif name == "SGENB":
                    reader.enable(where, reader.set_number(where, name, field))
                else:
                    reader.set_register(where, _REGISTER_OF[name], field)


def _resolve_model(model: str | Parker6kModel | None, header: Mapping[str, Any]) -> Parker6kModel:
    return resolve_model(model, header, get_model, CHIP_MODELS, "command file")


# --------------------------------------------------------------------------------------
# JSON parameter file: the layout every family shares (servogym.chips._paramfile)
# --------------------------------------------------------------------------------------

_SCHEMA = FileSchema(
    "parker6k",
    "Parker 6000-series",
    SPEC_VERSION,
    Parker6kParams,
    Parker6kAssumptions,
    get_model,
    required=lambda chip: (*FIELDS, "sgset", "sgenb"),
    extra_keys={
        "sample_time_us": ExtraKey(
            kind=int,
            what="an integer",
            rule=lambda p: f"the servo period of params.ssfr={p.ssfr} ({p.sample_time_us})",
        )
    },
    noun="parameter",
)

to_json, from_json = _SCHEMA.json_functions(__name__)


# --------------------------------------------------------------------------------------
# Dispatch
# --------------------------------------------------------------------------------------


FORMAT_TABLE = Formats(
    _SCHEMA,
    FILE_EXTENSIONS,
    writers={
        form: lambda params, form=form, **kw: to_command_file(params, form, **kw)
        for form in ("6250", "6k")
    },
    readers={
        form: lambda text, model, axis=None, form=form: from_command_file(text, form, model, axis)
        for form in ("6250", "6k")
    },
    import_keywords={"6250": ("axis",), "6k": ("axis",)},
    ignore_case=True,
    axis_writers={
        form: lambda axes, assumptions, form=form: _command_text(axes, form, assumptions)
        for form in ("6250", "6k")
    },
    axis_readers={
        form: lambda text, model, form=form: _command_axes(text, form, model)
        for form in ("6250", "6k")
    },
)

export, import_params = FORMAT_TABLE.functions(
    __name__,
    "Parker6kParams",
    '``"json"`` (:func:`to_json`), ``"6250"`` or ``"6k"`` (:func:`to_command_file`)',
    "``assumptions`` to every format; ``axis`` to the command files (a JSON file holds one "
    "axis' set and ignores ``axis``); ``metrics``, ``notes``, ``created`` to JSON.",
    index_doc="``axis``, command files only: the axis to read (default the header's, else 1).",
)
