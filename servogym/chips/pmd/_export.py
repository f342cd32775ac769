"""Export and import of PMD parameter sets in the forms the hardware and its tools take.

Three formats; each imports back to the identical :class:`PMDParams`:

* ``"json"``: a parameter file with provenance (chip model, spec version, assumptions,
  creation time, servogym version, optional metrics and notes).
* ``"cmotion"``: a C snippet of C-Motion calls, ``PMDSetKp(&hAxis1, 100);`` on
  Navigator/Pilot and ``PMDSetPositionLoop(&hAxis1, PMDPositionLoopKp, 100);`` on Magellan.
* ``"host"``: the instruction stream a host sends: opcode, command name, axis and 16-bit
  data words (32-bit values high word first), as :class:`HostCommand` records or as text,
  one command a line (``0x25 SetKp axis=1 data=0x0064``).

Every export validates the set first and refuses an illegal one with the parameter, the
value and the legal range; nothing is clamped or truncated. Where the opcodes, call names
and word order come from is in ``docs/chips/pmd-export.md``.
"""

from __future__ import annotations

import dataclasses
import difflib
import re
from collections.abc import Callable, Iterable, Mapping, Sequence
from typing import Any

from servogym import __version__
from servogym._files import seal, unseal
from servogym.chips._axisfile import axes_text, check_header_axes, header_axes
from servogym.chips._formats import Formats, check_index, resolve_model
from servogym.chips._formats import read_header as read_header_lines
from servogym.chips._paramfile import ExtraKey, FileSchema, assumption_lines
from servogym.chips._space import ParameterError
from servogym.chips.pmd._params import (
    CHIP_MODELS,
    SPEC_VERSION,
    TABLE,
    PMDAssumptions,
    PMDChipModel,
    PMDParams,
    get_model,
    parameter_space,
)

FILE_EXTENSIONS: dict[str, str] = {"json": ".json", "cmotion": ".c", "host": ".txt"}
"""Every export format, in the order :func:`export` documents them, and its file extension."""

FORMATS: tuple[str, ...] = tuple(FILE_EXTENSIONS)

# --------------------------------------------------------------------------------------
# Command tables. Opcodes, call names and data widths: see docs/chips/pmd-export.md.
# --------------------------------------------------------------------------------------


@dataclasses.dataclass(frozen=True)
class _Command:
    """One Set command: host name, opcode, the register it writes, its data width."""

    name: str
    opcode: int
    register: str
    width: str  # "u16", "s16", "u32" or "s32"

    @property
    def call(self) -> str:
        return "PMD" + self.name


_N_WORDS = {"u16": 1, "s16": 1, "u32": 2, "s32": 2}

# One Set command per register, in the order they are exported, from the register table:
# Navigator / Pilot every register; Magellan the ones outside SetPositionLoop (below).
_NAVIGATOR_COMMANDS: tuple[_Command, ...] = tuple(
    _Command(s.text, s.code, r.name, s.width) for r, s in TABLE.spelled("navigator")
)
_MAGELLAN_COMMANDS: tuple[_Command, ...] = tuple(
    _Command(s.text, s.code, r.name, s.width) for r, s in TABLE.spelled("magellan")
)

_SET_POSITION_LOOP = "SetPositionLoop"
_SET_POSITION_LOOP_OPCODE = 0x67
_UPDATE = "Update"
_UPDATE_OPCODE = 0x1A

MAGELLAN_POSITION_LOOP: tuple[tuple[int, str, str], ...] = tuple(
    (s.code, s.text, r.name) for r, s in TABLE.spelled("magellan_loop")
)
"""Magellan ``SetPositionLoop`` parameters: (number, C-Motion enum name, register)."""

_LOOP_BY_NUMBER = {n: (enum, reg) for n, enum, reg in MAGELLAN_POSITION_LOOP}
_LOOP_BY_ENUM = {enum: (n, reg) for n, enum, reg in MAGELLAN_POSITION_LOOP}
_LOOP_BY_REGISTER = {reg: (n, enum) for n, enum, reg in MAGELLAN_POSITION_LOOP}


def _commands_for(chip: PMDChipModel) -> tuple[_Command, ...]:
    if chip.host_interface == "navigator":
        return _NAVIGATOR_COMMANDS
    if chip.host_interface == "magellan":
        return _MAGELLAN_COMMANDS
    raise ParameterError(
        f"host_interface must be 'navigator' or 'magellan' to export; "
        f"got host_interface={chip.host_interface!r} for {chip.name}."
    )


@dataclasses.dataclass(frozen=True)
class _Step:
    """One Set command of an export, with the value it carries."""

    name: str
    opcode: int
    register: str
    width: str
    value: int
    loop: int | None = None  # SetPositionLoop parameter number (Magellan)


def _steps(p: PMDParams) -> list[_Step]:
    """The Set commands that load ``p``, in export order (Update not included)."""
    chip = p.chip
    space = p.space
    steps = []
    if chip.host_interface == "magellan":
        for number, _enum, reg in MAGELLAN_POSITION_LOOP:
            if reg in space:  # biquads only on models that have them
                steps.append(
                    _Step(
                        _SET_POSITION_LOOP,
                        _SET_POSITION_LOOP_OPCODE,
                        reg,
                        "s32",
                        getattr(p, reg),
                        number,
                    )
                )
    for c in _commands_for(chip):
        steps.append(_Step(c.name, c.opcode, c.register, c.width, getattr(p, c.register)))
    return steps


# --------------------------------------------------------------------------------------
# Words
# --------------------------------------------------------------------------------------

_WIDTH_RANGE = {
    "u16": (0, 0xFFFF),
    "s16": (-0x8000, 0x7FFF),
    "u32": (0, 0xFFFF_FFFF),
    "s32": (-0x8000_0000, 0x7FFF_FFFF),
}


def _encode(value: int, width: str, register: str) -> tuple[int, ...]:
    """``value`` as 16-bit words, two's complement, high word first."""
    low, high = _WIDTH_RANGE[width]
    if not low <= value <= high:  # cannot happen for a validated set; never truncate
        raise ParameterError(
            f"{register} must fit the command's {width} argument ({low} <= {register} <= "
            f"{high}); got {register}={value}."
        )
    if _N_WORDS[width] == 1:
        return (value & 0xFFFF,)
    v = value & 0xFFFF_FFFF
    return (v >> 16, v & 0xFFFF)


def _decode(words: Sequence[int], width: str) -> int:
    """The inverse of :func:`_encode`."""
    if _N_WORDS[width] == 1:
        v = words[0]
        return v - 0x1_0000 if width == "s16" and v & 0x8000 else v
    v = (words[0] << 16) | words[1]
    return v - 0x1_0000_0000 if width == "s32" and v & 0x8000_0000 else v


# --------------------------------------------------------------------------------------
# Shared checks
# --------------------------------------------------------------------------------------


def _check_axis(chip: PMDChipModel, axis: Any, where: str = "") -> int:
    return check_index(chip, axis, chip.n_axes, where=where)


def _chip(model: str | PMDChipModel) -> PMDChipModel:
    return model if isinstance(model, PMDChipModel) else get_model(model)


def _resolve_model(
    model: str | PMDChipModel | None, header: Mapping[str, Any], what: str
) -> PMDChipModel:
    """The chip model from the argument and/or the header; they must agree."""
    return resolve_model(model, header, _chip, CHIP_MODELS, what)


class _Collector:
    """Register values read from an imported stream: each set once, each validated."""

    def __init__(self, chip: PMDChipModel, describe: Callable[[str], str]) -> None:
        self.chip = chip
        self.space = parameter_space(chip)
        self.describe = describe
        self.values: dict[str, int] = {}
        self.where: dict[str, str] = {}

    def set(self, register: str, value: int, where: str) -> None:
        if register not in self.space:
            raise ParameterError(
                f"{where}: {self.chip.name} has no register {register} "
                f"(set by {self.describe(register)}); its registers are "
                f"{', '.join(self.space)}."
            )
        if register in self.values:
            raise ParameterError(
                f"{where}: {register} is set a second time (first at "
                f"{self.where[register]}); each register must be set exactly once so the "
                f"imported set is unambiguous."
            )
        try:
            self.values[register] = self.space[register].validate(value, context=self.chip.name)
        except ParameterError as exc:
            raise ParameterError(f"{where}: {exc}") from None
        self.where[register] = where

    def result(self, what: str) -> PMDParams:
        missing = [r for r in self.space if r not in self.values]
        if missing:
            listed = ", ".join(f"{r} ({self.describe(r)})" for r in missing)
            raise ParameterError(
                f"the {what} does not set every register of {self.chip.name}; an import "
                f"takes no defaults. Missing: {listed}."
            )
        return PMDParams(model=self.chip.name, **self.values)


# --------------------------------------------------------------------------------------
# Provenance header shared by the C-Motion and host-text formats
# --------------------------------------------------------------------------------------


def _header_lines(p: PMDParams, a: PMDAssumptions, axes: Sequence[int], title: str) -> list[str]:
    """The provenance header; ``axis: 2`` for one axis, ``axes: 1, 2`` for several."""
    chip = p.chip
    lines = [
        f"servogym PMD parameter set, {title}",
        f"chip_model: {chip.name}",
        f"chip_line: {chip.line}",
        f"host_interface: {chip.host_interface}",
        f"spec_version: {SPEC_VERSION}",
        f"sample_time_us: {p.sample_time_us}",
        f"axis: {axes[0]}" if len(axes) == 1 else f"axes: {axes_text(axes)}",
        f"servogym_version: {__version__}",
    ]
    lines += assumption_lines(a)
    return lines


_C_COMMENT = re.compile(r"/\*.*?\*/|//[^\n]*", re.DOTALL)


def _comment_lines(text: str) -> list[str]:
    """Lines of ``/* */`` and ``//`` comments, and lines starting with ``#``."""
    out = []
    for m in _C_COMMENT.finditer(text):
        body = m.group(0)
        body = body[2:-2] if body.startswith("/*") else body[2:]
        out += body.splitlines()
    out += [line for line in text.splitlines() if line.lstrip().startswith("#")]
    return out


def read_header(text: str) -> dict[str, Any]:
    """The provenance header of a C-Motion snippet or host-command text.

    Args:
        text: Output of :func:`to_cmotion` or :func:`to_host_text` (possibly edited).

    Returns:
        The ``key: value`` header entries as strings (``chip_model``, ``spec_version``,
        ``sample_time_us``, ``axis``, ...), and under ``"assumptions"`` a
        :class:`PMDAssumptions` when the header lists them. Empty if there is no header.

    Raises:
        ParameterError: if the header lists only some assumptions, or an unknown one.
    """
    return read_header_lines(_comment_lines(text), _SCHEMA, "PMD", lead=r"[\s*#/]*")


# --------------------------------------------------------------------------------------
# Format 1: JSON parameter file: the layout every family shares (servogym.chips._paramfile)
# --------------------------------------------------------------------------------------

_SCHEMA = FileSchema(
    "pmd",
    "PMD",
    SPEC_VERSION,
    PMDParams,
    PMDAssumptions,
    _chip,
    required=parameter_space,
    extra_keys={
        "sample_time_us": ExtraKey(
            kind=int,
            what="an integer",
            rule=lambda p: f"params.sample_time_us ({p.sample_time_us})",
        )
    },
)

to_json, from_json = _SCHEMA.json_functions(__name__)


# --------------------------------------------------------------------------------------
# Format 2: C-Motion C snippet
# --------------------------------------------------------------------------------------


def to_cmotion(
    params: PMDParams | Mapping[str, Any],
    axis: int = 1,
    assumptions: PMDAssumptions | Mapping[str, str] | None = None,
) -> str:
    """A C snippet of C-Motion calls that loads the set into one axis.

    Navigator/Pilot models get one call per register (``PMDSetKp(&hAxis1, 100);``);
    MC58000 gets ``PMDSetPositionLoop(&hAxis1, PMDPositionLoopKp, 100);`` for the filter
    and the biquads, then bias, motor limit, position-error limit and sample time. Every
    snippet ends with ``PMDUpdate(&hAxis1);``. A header comment carries the provenance.

    Args:
        params: The parameter set; validated again before writing.
        axis: Axis number, 1 .. the model's axis count; the handle is ``hAxis<axis>``.
        assumptions: Recorded in the header; default all defaults.

    Returns:
        The snippet, newline-terminated.

    Raises:
        ParameterError: for an illegal set or axis.
    """
    p = _SCHEMA.legal_params(params)
    return _cmotion_text({_check_axis(p.chip, axis): p}, assumptions)


def _cmotion_text(
    axes: Mapping[int, PMDParams], assumptions: PMDAssumptions | Mapping[str, str] | None
) -> str:
    """The C-Motion snippet of one or several axes: one handle ``hAxis<n>`` per axis, each
    axis's calls then its ``PMDUpdate``, the blocks in axis order, a blank line between."""
    sets = {n: _SCHEMA.legal_params(p) for n, p in axes.items()}
    a = _SCHEMA.legal_assumptions(assumptions)
    numbers = list(sets)
    first = sets[numbers[0]]
    if len(numbers) == 1:
        title = "C-Motion calls for one axis"
        needs = f"Needs an open PMDAxisHandle hAxis{numbers[0]} for PMDAxis{numbers[0]}"
    else:
        title = f"C-Motion calls for {len(numbers)} axes"
        needs = (
            f"Needs open PMDAxisHandles {', '.join(f'hAxis{n}' for n in numbers)} for "
            f"{', '.join(f'PMDAxis{n}' for n in numbers)}"
        )
    head = _header_lines(first, a, numbers, title)
    head += [needs, "(C-Motion numbers axes from 0: PMDAxis1 = 0)."]
    lines = ["/*", *(f" * {line}" for line in head), " */"]
    for i, (number, p) in enumerate(sets.items()):
        handle = f"&hAxis{number}"
        if i:
            lines.append("")
        for s in _steps(p):
            if s.loop is not None:
                loop = _LOOP_BY_NUMBER[s.loop][0]
                lines.append(f"PMDSetPositionLoop({handle}, {loop}, {s.value});")
            else:
                lines.append(f"PMD{s.name}({handle}, {s.value});")
        lines.append(f"PMDUpdate({handle});")
    return seal("\n".join(lines) + "\n", "//")


_CALL = re.compile(r"^\s*([A-Za-z_]\w*)\s*\((.*)\)\s*$", re.DOTALL)
_C_INT = re.compile(r"^([+-]?)\s*(0[xX][0-9a-fA-F]+|[0-9]+)[uUlL]*$")


def _blank(m: re.Match[str]) -> str:
    return re.sub(r"[^\n]", " ", m.group(0))


def _c_int(arg: str, where: str, name: str) -> int:
    m = _C_INT.match(arg)
    if not m:
        raise ParameterError(
            f"{where}: the value of {name} must be an integer literal (decimal or 0x hex); "
            f"got {arg!r}."
        )
    sign, digits = m.groups()
    if len(digits) > 1 and digits[0] == "0" and digits[1] not in "xX":
        raise ParameterError(
            f"{where}: {digits} is an octal literal in C; write the value of {name} in "
            f"decimal or 0x hex."
        )
    value = int(digits, 0)
    return -value if sign == "-" else value


def from_cmotion(text: str, model: str | PMDChipModel | None = None) -> PMDParams:
    """Read a C-Motion snippet written by :func:`to_cmotion` (or by hand) back.

    Comments, whitespace, blank statements and preprocessor lines are ignored; each
    statement must be one of the calls :func:`to_cmotion` writes for the model, all on
    the same axis handle, each register set exactly once (``PMDUpdate`` optional).

    Args:
        text: The snippet.
        model: Chip model; default the header's ``chip_model:``. If both are given they
            must agree.

    Returns:
        The parameter set.

    Raises:
        ParameterError: naming the line, for an unknown call, a call the model does not
            take, a malformed argument, an illegal value (with its range), a second
            set of a register, or a register left unset.
    """
    return next(iter(_read_cmotion(text, model, several=False)[1].values()))


_HANDLE = re.compile(r"^&hAxis([0-9]+)$")


def _read_cmotion(
    text: str, model: str | PMDChipModel | None, *, several: bool
) -> tuple[PMDChipModel, dict[str, PMDParams]]:
    """The sets a C-Motion snippet loads, by axis handle (as written, blanks removed), in
    file order. ``several=False`` refuses a second handle (:func:`from_cmotion`)."""
    original = text
    text, _sealed = unseal(text, verify=False)
    header = read_header(text)
    chip = _resolve_model(model, header, "C-Motion snippet")
    code = _C_COMMENT.sub(_blank, text)
    for m in re.finditer(r"(?m)^[ \t]*#[ \t]*(\w*)[^\n]*", code):
        if m.group(1) != "include":
            line = code.count("\n", 0, m.start()) + 1
            raise ParameterError(
                f"line {line}: the preprocessor line {m.group(0).strip()!r} is not read: the "
                f"importer cannot tell which calls the compiler would keep (#if, #ifdef, "
                f"#define ...). Remove it; only #include lines are allowed."
            )
    code = re.sub(r"(?m)^[ \t]*#[^\n]*", _blank, code)  # #include lines

    commands = {c.call: c for c in _commands_for(chip)}
    calls = [*commands, "PMDUpdate"]
    if chip.host_interface == "magellan":
        calls.insert(0, "PMDSetPositionLoop")

    def describe(register: str) -> str:
        if chip.host_interface == "magellan" and register in _LOOP_BY_REGISTER:
            return f"PMDSetPositionLoop(..., {_LOOP_BY_REGISTER[register][1]}, ...)"
        return next((c.call for c in commands.values() if c.register == register), "no call")

    collectors: dict[str, _Collector] = {}
    handle: tuple[str, str] | None = None

    def line_at(pos: int) -> int:
        return code.count("\n", 0, pos) + 1

    pos = 0
    for m in re.finditer(r"[^;]*;", code):
        pos = m.end()
        stmt = m.group(0)[:-1]
        if not stmt.strip():
            continue
        start = m.start() + len(stmt) - len(stmt.lstrip())
        where = f"line {line_at(start)}"
        if "/*" in stmt:
            raise ParameterError(f"{where}: unterminated /* comment.")
        call = _CALL.match(stmt)
        if not call:
            raise ParameterError(
                f"{where}: cannot read {stmt.strip()!r}; each statement must be a C-Motion "
                f"call such as {calls[0]}(&hAxis1, ...);"
            )
        name, argtext = call.group(1), call.group(2)
        args = [arg.strip() for arg in argtext.split(",")]
        if name not in calls:
            close = difflib.get_close_matches(name, calls, n=2)
            hint = f" Did you mean {', '.join(close)}?" if close else ""
            raise ParameterError(
                f"{where}: unknown C-Motion call {name}(); the {chip.name} ({chip.line}) "
                f"calls are {', '.join(calls)}.{hint}"
            )
        wanted = {"PMDUpdate": 1, "PMDSetPositionLoop": 3}.get(name, 2)
        if len(args) != wanted or not all(args):
            raise ParameterError(
                f"{where}: {name} takes {wanted} argument{'s' if wanted > 1 else ''} "
                f"(axis handle{', parameter' if wanted == 3 else ''}"
                f"{', value' if wanted > 1 else ''}); got {argtext.strip()!r}."
            )
        this = re.sub(r"\s+", "", args[0])
        if handle is None:
            handle = (this, where)
        elif this != handle[0] and not several:
            raise ParameterError(
                f"{where}: {name} addresses {this} but {handle[1]} addresses {handle[0]}; "
                f"a snippet loads one axis (read a file of several axes with "
                f"servogym.chips.import_axes)."
            )
        if this not in collectors:
            if several and not _HANDLE.match(this):
                raise ParameterError(
                    f"{where}: {name} addresses {this}; in a file of several axes each "
                    f"axis's handle must be &hAxis<n>, n its axis number (1 .. "
                    f"{chip.n_axes} on the {chip.name})."
                )
            collectors[this] = _Collector(chip, describe)
        collect = collectors[this]
        if name == "PMDUpdate":
            continue
        if name == "PMDSetPositionLoop":
            param = args[1]
            if param in _LOOP_BY_ENUM:
                register = _LOOP_BY_ENUM[param][1]
            else:
                if not _C_INT.match(param):
                    close = difflib.get_close_matches(param, list(_LOOP_BY_ENUM), n=2)
                    hint = f" Did you mean {', '.join(close)}?" if close else ""
                    raise ParameterError(
                        f"{where}: unknown SetPositionLoop parameter {param!r}; the parameters "
                        f"are {', '.join(_LOOP_BY_ENUM)} (or their numbers 0..21).{hint}"
                    )
                number = _c_int(param, where, "the SetPositionLoop parameter")
                if number not in _LOOP_BY_NUMBER:
                    raise ParameterError(
                        f"{where}: the SetPositionLoop parameter must satisfy 0 <= parameter "
                        f"<= 21; got parameter={number}."
                    )
                register = _LOOP_BY_NUMBER[number][1]
            collect.set(register, _c_int(args[2], where, register), where)
        else:
            register = commands[name].register
            collect.set(register, _c_int(args[1], where, register), where)
    rest = code[pos:]
    if rest.strip():
        start = pos + len(rest) - len(rest.lstrip())
        raise ParameterError(
            f"line {line_at(start)}: {rest.strip()!r} does not end with ';'; each C-Motion "
            f"call must be a statement ending in ';'."
        )
    if handle is None:
        raise ParameterError("the C-Motion snippet contains no calls.")
    what = "C-Motion snippet"
    sets = {h: c.result(f"{what} ({h})" if several else what) for h, c in collectors.items()}
    unseal(original)
    return chip, sets


def _cmotion_axes(text: str, model: str | PMDChipModel | None) -> dict[int, PMDParams]:
    """Axis number -> set, of a C-Motion snippet of one or several axes (``hAxis<n>``)."""
    chip, by_handle = _read_cmotion(text, model, several=True)
    sets: dict[int, PMDParams] = {}
    for handle, params in by_handle.items():
        number = _check_axis(chip, int(_HANDLE.match(handle).group(1)), f"handle {handle}")
        if number in sets:
            raise ParameterError(
                f"handle {handle} names axis {number}, which another handle loads already."
            )
        sets[number] = params
    check_header_axes(header_axes(read_header(unseal(text, verify=False)[0])), sets)
    return sets


# --------------------------------------------------------------------------------------
# Format 3: host commands
# --------------------------------------------------------------------------------------

_MAX_AXES = max(m.n_axes for m in CHIP_MODELS.values())


@dataclasses.dataclass(frozen=True)
class HostCommand:
    """One instruction of the host-command stream.

    Attributes:
        opcode: Command code, 0x00..0xFF.
        name: Command name without the ``PMD`` prefix, e.g. ``"SetKp"``.
        axis: Axis number, 1..4 (the command word carries ``axis - 1``).
        data: The 16-bit data words that follow the command word (0x0000..0xFFFF each);
            32-bit values high word first, signed values two's complement.
    """

    opcode: int
    name: str
    axis: int
    data: tuple[int, ...] = ()

    def __post_init__(self) -> None:
        object.__setattr__(self, "data", tuple(self.data))
        for label, value, high in (("opcode", self.opcode, 0xFF), ("axis", self.axis, _MAX_AXES)):
            low = 1 if label == "axis" else 0
            if isinstance(value, bool) or not isinstance(value, int) or not low <= value <= high:
                raise ParameterError(
                    f"HostCommand {label} must be an integer with {low} <= {label} <= {high}; "
                    f"got {label}={value!r}."
                )
        if not isinstance(self.name, str) or not re.fullmatch(r"[A-Za-z]\w*", self.name):
            raise ParameterError(
                f"HostCommand name must be a command name such as 'SetKp'; got name={self.name!r}."
            )
        for i, word in enumerate(self.data):
            if isinstance(word, bool) or not isinstance(word, int) or not 0 <= word <= 0xFFFF:
                raise ParameterError(
                    f"HostCommand data words must be integers with 0 <= word <= 0xFFFF; "
                    f"got data[{i}]={word!r}."
                )

    @property
    def command_word(self) -> int:
        """The 16-bit command word: opcode in bits 0-7, ``axis - 1`` from bit 8."""
        return ((self.axis - 1) << 8) | self.opcode

    @property
    def words(self) -> tuple[int, ...]:
        """Command word followed by the data words, as sent."""
        return (self.command_word, *self.data)

    def to_text(self) -> str:
        """The text line, e.g. ``0x95 SetIntegrationLimit axis=1 data=0x0001 0x86A0``."""
        line = f"0x{self.opcode:02X} {self.name} axis={self.axis}"
        if self.data:
            line += " data=" + " ".join(f"0x{w:04X}" for w in self.data)
        return line


def to_host_commands(params: PMDParams | Mapping[str, Any], axis: int = 1) -> list[HostCommand]:
    """The host-command stream that loads the set into one axis, ending with ``Update``.

    Args:
        params: The parameter set; validated again first.
        axis: Axis number, 1 .. the model's axis count.

    Returns:
        One :class:`HostCommand` per register (``SetPositionLoop`` per filter parameter on
        MC58000), then ``Update``.

    Raises:
        ParameterError: for an illegal set or axis.
    """
    p = _SCHEMA.legal_params(params)
    axis = _check_axis(p.chip, axis)
    cmds = []
    for s in _steps(p):
        words = _encode(s.value, s.width, s.register)
        data = words if s.loop is None else (s.loop, *words)
        cmds.append(HostCommand(s.opcode, s.name, axis, data))
    cmds.append(HostCommand(_UPDATE_OPCODE, _UPDATE, axis))
    return cmds


def host_commands_to_text(cmds: Iterable[HostCommand]) -> str:
    """The text form of a command list: one :meth:`HostCommand.to_text` line each."""
    return "".join(c.to_text() + "\n" for c in cmds)


def to_host_text(
    params: PMDParams | Mapping[str, Any],
    axis: int = 1,
    assumptions: PMDAssumptions | Mapping[str, str] | None = None,
) -> str:
    """The text form of :func:`to_host_commands`, under a ``#`` provenance header.

    Args:
        params: The parameter set; validated again first.
        axis: Axis number, 1 .. the model's axis count.
        assumptions: Recorded in the header; default all defaults.

    Returns:
        The text, newline-terminated.
    """
    p = _SCHEMA.legal_params(params)
    return _host_text({_check_axis(p.chip, axis): p}, assumptions)


def _host_text(
    axes: Mapping[int, PMDParams], assumptions: PMDAssumptions | Mapping[str, str] | None
) -> str:
    """The host-command text of one or several axes: each axis's commands then its
    ``Update``, the blocks in axis order, a blank line between."""
    sets = {n: _SCHEMA.legal_params(p) for n, p in axes.items()}
    a = _SCHEMA.legal_assumptions(assumptions)
    numbers = list(sets)
    title = "host commands for " + ("one axis" if len(numbers) == 1 else f"{len(numbers)} axes")
    head = _header_lines(sets[numbers[0]], a, numbers, title)
    head.append("Format: opcode name axis=N data=16-bit words (32-bit values high word first).")
    body = "\n".join(host_commands_to_text(to_host_commands(p, n)) for n, p in sets.items())
    return seal("".join(f"# {line}\n" for line in head) + body, "#")


_HOST_LINE = re.compile(
    r"^(0[xX][0-9a-fA-F]{1,2})\s+([A-Za-z]\w*)\s+axis\s*=\s*([0-9]+)(?:\s+data\s*=(.*))?$"
)
_HOST_WORD = re.compile(r"^0[xX][0-9a-fA-F]{1,4}$")


def _parse_host_text(text: str) -> list[tuple[str, HostCommand]]:
    out = []
    for n, raw in enumerate(text.splitlines(), start=1):
        line = raw.split("#", 1)[0].strip()
        if not line:
            continue
        where = f"line {n}"
        m = _HOST_LINE.match(line)
        if not m:
            raise ParameterError(
                f"{where}: cannot read {line!r}; a command line reads "
                f"'0x25 SetKp axis=1 data=0x0064'."
            )
        opcode, name, axis, data = m.groups()
        words = []
        for token in (data or "").replace(",", " ").split():
            if not _HOST_WORD.match(token):
                raise ParameterError(
                    f"{where}: data words must be 16-bit hex such as 0x0064; got {token!r}."
                )
            words.append(int(token, 16))
        try:
            cmd = HostCommand(int(opcode, 16), name, int(axis), tuple(words))
        except ParameterError as exc:
            raise ParameterError(f"{where}: {exc}") from None
        out.append((where, cmd))
    return out


def host_text_to_commands(text: str) -> list[HostCommand]:
    """Parse the text form back into :class:`HostCommand` records (``#`` starts a comment).

    Raises:
        ParameterError: naming the line, for a line that is not a command.
    """
    return [cmd for _, cmd in _parse_host_text(text)]


def _decode_commands(
    items: Sequence[tuple[str, HostCommand]], chip: PMDChipModel, what: str = "host-command list"
) -> PMDParams:
    table = {c.name: c for c in _commands_for(chip)}
    names = [*table, _UPDATE]
    if chip.host_interface == "magellan":
        names.insert(0, _SET_POSITION_LOOP)

    def describe(register: str) -> str:
        if chip.host_interface == "magellan" and register in _LOOP_BY_REGISTER:
            return f"SetPositionLoop parameter {_LOOP_BY_REGISTER[register][0]}"
        return next((c.name for c in table.values() if c.register == register), "no command")

    collect = _Collector(chip, describe)
    axis: tuple[int, str] | None = None
    for where, cmd in items:
        if cmd.name not in names:
            close = difflib.get_close_matches(cmd.name, names, n=2)
            hint = f" Did you mean {', '.join(close)}?" if close else ""
            raise ParameterError(
                f"{where}: unknown command {cmd.name} (0x{cmd.opcode:02X}); the {chip.name} "
                f"({chip.host_interface} interface) commands are {', '.join(names)}.{hint}"
            )
        if axis is None:
            axis = (_check_axis(chip, cmd.axis, where), where)
        elif cmd.axis != axis[0]:
            raise ParameterError(
                f"{where}: {cmd.name} addresses axis={cmd.axis} but {axis[1]} addresses "
                f"axis={axis[0]}; a command list loads one axis (read a file of several axes "
                f"with servogym.chips.import_axes)."
            )
        if cmd.name == _UPDATE:
            opcode, n_words = _UPDATE_OPCODE, 0
        elif cmd.name == _SET_POSITION_LOOP:
            opcode, n_words = _SET_POSITION_LOOP_OPCODE, 3
        else:
            opcode, n_words = table[cmd.name].opcode, _N_WORDS[table[cmd.name].width]
        if cmd.opcode != opcode:
            raise ParameterError(
                f"{where}: {cmd.name} has opcode 0x{opcode:02X} on {chip.name} "
                f"({chip.host_interface} interface); got opcode 0x{cmd.opcode:02X}."
            )
        if len(cmd.data) != n_words:
            raise ParameterError(
                f"{where}: {cmd.name} takes {n_words} data word{'s' if n_words != 1 else ''}; "
                f"got {len(cmd.data)}."
            )
        if cmd.name == _UPDATE:
            continue
        if cmd.name == _SET_POSITION_LOOP:
            number = cmd.data[0]
            if number not in _LOOP_BY_NUMBER:
                raise ParameterError(
                    f"{where}: the SetPositionLoop parameter must satisfy 0 <= parameter <= "
                    f"21; got parameter={number}."
                )
            register = _LOOP_BY_NUMBER[number][1]
            collect.set(register, _decode(cmd.data[1:], "s32"), where)
        else:
            c = table[cmd.name]
            collect.set(c.register, _decode(cmd.data, c.width), where)
    if axis is None:
        raise ParameterError("the host-command list contains no commands.")
    return collect.result(what)


def from_host_commands(cmds: Iterable[HostCommand], model: str | PMDChipModel) -> PMDParams:
    """Read a structured command list (as :func:`to_host_commands` returns) back.

    Args:
        cmds: The commands; all on one axis, each register set exactly once, ``Update``
            optional.
        model: Chip model the commands are for.

    Returns:
        The parameter set.

    Raises:
        ParameterError: naming the command's index, for an unknown command, an opcode or
            data length that does not match the model, an illegal value (with its range), a
            second set of a register, or a register left unset.
    """
    chip = _chip(model)
    items = []
    for i, cmd in enumerate(cmds):
        if not isinstance(cmd, HostCommand):
            raise ParameterError(
                f"command {i}: each command must be a HostCommand; got {type(cmd).__name__}."
            )
        items.append((f"command {i}", cmd))
    return _decode_commands(items, chip)


def from_host_text(text: str, model: str | PMDChipModel | None = None) -> PMDParams:
    """Read the text form back (from :func:`to_host_text` or :func:`host_commands_to_text`).

    Args:
        text: The command lines; ``#`` starts a comment.
        model: Chip model; default the header's ``chip_model:``. Required when the text has
            no header (Navigator and Pilot streams are the same, so the commands alone do
            not name the model). If both are given they must agree.

    Returns:
        The parameter set.

    Raises:
        ParameterError: naming the line, as :func:`from_host_commands` does.
    """
    body, _sealed = unseal(text, verify=False)
    chip = _resolve_model(model, read_header(body), "host-command text")
    params = _decode_commands(_parse_host_text(body), chip)
    unseal(text)
    return params


def _host_axes(text: str, model: str | PMDChipModel | None) -> dict[int, PMDParams]:
    """Axis number -> set, of a host-command text of one or several axes (commands grouped
    by their ``axis=``, in the order the axes first appear)."""
    body, _sealed = unseal(text, verify=False)
    header = read_header(body)
    chip = _resolve_model(model, header, "host-command text")
    groups: dict[int, list[tuple[str, HostCommand]]] = {}
    for where, cmd in _parse_host_text(body):
        groups.setdefault(cmd.axis, []).append((where, cmd))
    if not groups:
        raise ParameterError("the host-command list contains no commands.")
    sets = {}
    for axis, items in groups.items():
        _check_axis(chip, axis, items[0][0])
        sets[axis] = _decode_commands(items, chip, f"host-command list (axis {axis})")
    check_header_axes(header_axes(header), sets)
    unseal(text)
    return sets


# --------------------------------------------------------------------------------------
# Dispatch
# --------------------------------------------------------------------------------------


FORMAT_TABLE = Formats(
    _SCHEMA,
    FILE_EXTENSIONS,
    writers={"cmotion": lambda params, **kw: to_cmotion(params, **kw),
             "host": lambda params, **kw: to_host_text(params, **kw)},
    readers={"cmotion": lambda text, model: from_cmotion(text, model),
             "host": lambda text, model: from_host_text(text, model)},
    axis_writers={"cmotion": _cmotion_text, "host": _host_text},
    axis_readers={"cmotion": _cmotion_axes, "host": _host_axes},
)  # fmt: skip

export, import_params = FORMAT_TABLE.functions(
    __name__,
    "PMDParams",
    '``"json"`` (:func:`to_json`), ``"cmotion"`` (:func:`to_cmotion`) or ``"host"`` '
    "(:func:`to_host_text`)",
    "``assumptions`` to every format; ``axis`` to the C-Motion and host formats (a JSON "
    "file holds one axis' set and ignores ``axis``); ``metrics``, ``notes``, ``created`` to "
    "JSON.",
)
