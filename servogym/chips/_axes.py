"""The parameter sets of several axes of one controller, and their files in the chip's own
multi-axis form.

A :class:`MultiAxisParams` maps the hardware's axis numbers (PMAC: motor numbers) to one
parameter set each, all of one chip model. :func:`export_axes` writes them as one file in
each format of the family (``docs/chips/*.md``, "Multi-axis files"):

* PMD C-Motion: one axis handle per axis (``PMDSetKp(&hAxis2, 100);``), each axis's calls
  then its ``PMDUpdate``; host commands: each axis's commands with its ``axis=``.
* PMAC I-variables: ``Ixx`` per motor number (``I130``, ``I230`` ...), the global clock
  I-variables once.
* 6000 series: comma-separated per-axis fields (``SGP85,90``; ``SGP,90`` leaves axis 1 alone)
  or, 6K form, one axis-prefixed line per axis (``1SGP85``, ``2SGP90``); ``SSFR`` and
  ``SGSET`` once.
* JSON: the ``servogym-axes`` layout (:mod:`servogym.chips._axisfile`).

:func:`import_axes` reads every one back to the identical :class:`MultiAxisParams`. A set
of one axis is written as today's single-axis file (byte for byte), except JSON, whose
single-axis layout has no axis number. :func:`save_axes` and :func:`load_axes` write and read
files on disk the way every servogym export does (atomic, never over the input, end line
with checksum).
"""

from __future__ import annotations

import datetime as _dt
from collections.abc import Iterator, Mapping, Sequence
from pathlib import Path
from typing import Any

from servogym.chips._axisfile import axes_text, plural
from servogym.chips._family import ChipFamily, families, family_of, get_chip
from servogym.chips._formats import check_index
from servogym.chips._space import ParameterError

DRIVEN_AXES: dict[str, int] = {"GeoBrickLV": 8}
"""Models that drive fewer axes than their firmware addresses: the Geo Brick LV has at most
eight built-in amplifiers (GBL8), though its Turbo firmware addresses motors 1 .. 32 [A]."""

PERIOD_PER_AXIS: frozenset[str] = frozenset({"pmd"})
"""Families whose cycle is time-sliced per enabled axis: ``sample_time_us >= n_axes *
min_sample_time_us`` (PMD, "4axis*154us/axis" [C]; docs/chips/pmd.md, section 7). The one
statement of the rule: :class:`MultiAxisParams` checks it, and the simulator
(``servogym.sim.check_machine``, ``machine_params``) reads it from here."""


def _noun(family: ChipFamily) -> str:
    return family.export_module.FORMAT_TABLE.index


def addressable(model: Any) -> int:
    """The highest axis (PMAC: motor) number a chip model addresses."""
    return int(getattr(model, "n_axes", None) or model.n_motors)


def max_axes(model: str | Any) -> int:
    """How many axes a chip model drives at most (MC2100 4, MC3110 1, Geo Brick LV 8,
    Turbo PMAC2 32, 6250 2, 6K 8)."""
    if isinstance(model, str):
        family, name = get_chip(model)
        model = family.models[name]
    return min(DRIVEN_AXES.get(model.name, addressable(model)), addressable(model))


class MultiAxisParams(Mapping[int, Any]):
    """The parameter sets of several axes of one controller, by the hardware's axis number.

    A read-only mapping ``axis number -> parameter set`` (PMAC: motor number), in axis
    order. ``MultiAxisParams([p1, p2])`` numbers the sets 1, 2 (as
    :func:`servogym.sim.machine_params` returns them); ``MultiAxisParams({1: p1, 3: p3})``
    names them. :class:`servogym.sim.MultiServoLoop` (and ``servogym.sim.check_machine``)
    take it as it is; :attr:`sets` is the list of its sets in axis order.

    Args:
        axes: A mapping of axis numbers to parameter sets, or a sequence of sets (axes 1..n).

    Raises:
        ParameterError: for no set, a number outside the model's ``1 .. n``, sets of more
            than one chip model, more axes than the model drives (naming the model, the
            count and the legal range), controller-wide registers that differ between axes
            (``sample_time_us`` on PMD, I7000..I7002 on PMAC, ``ssfr`` on the 6000 series),
            or a PMD period shorter than its enabled axes need.
    """

    def __init__(self, axes: Mapping[int, Any] | Sequence[Any]) -> None:
        if isinstance(axes, Mapping):
            items = list(axes.items())
        elif isinstance(axes, Sequence) and not isinstance(axes, str | bytes):
            items = list(enumerate(axes, start=1))
        else:
            raise ParameterError(
                f"axes must be a mapping of axis numbers to parameter sets or a sequence of "
                f"sets; got axes of type {type(axes).__name__}."
            )
        if not items:
            raise ParameterError("axes must hold at least one parameter set; got none.")
        self._family = _family(items[0][1], items[0][0])
        self._noun = _noun(self._family)
        model = items[0][1].model
        for number, p in items:
            family = _family(p, number)
            if family is not self._family or p.model != model:
                raise ParameterError(
                    f"every {self._noun} of one controller must be the same chip model; "
                    f"{self._noun} {items[0][0]} is {model!r} ({self._family.name}), "
                    f"{self._noun} {number} is {p.model!r} ({family.name})."
                )
        chip = self._family.models[model]
        top = addressable(chip)
        n, most = len(items), max_axes(chip)
        if n > most:
            raise ParameterError(
                f"the {model} drives at most {most} {plural(self._noun)}; got {n} parameter "
                f"sets (1 <= number of {plural(self._noun)} <= {most})."
            )
        for number, _p in items:
            check_index(chip, number, top, noun=self._noun, verb="addresses")
        self._axes: dict[int, Any] = {int(k): v for k, v in sorted(items, key=lambda i: i[0])}
        self._check_shared()

    def _check_shared(self) -> None:
        table = self._family.registers
        first_n, first = next(iter(self._axes.items()))
        for name in table.controller_wide:
            for number, p in self._axes.items():
                if getattr(p, name) != getattr(first, name):
                    raise ParameterError(
                        f"{name} is one setting of the whole controller, so every "
                        f"{self._noun} must hold the same value; {self._noun} {first_n} has "
                        f"{name}={getattr(first, name)!r}, {self._noun} {number} has "
                        f"{name}={getattr(p, name)!r}."
                    )
        if self._family.name in PERIOD_PER_AXIS:
            n, slot = len(self._axes), self.chip.min_sample_time_us
            high = first.space["sample_time_us"].high
            if first.sample_time_us < n * slot:
                raise ParameterError(
                    f"sample_time_us must satisfy {n * slot} <= sample_time_us <= {high} for "
                    f"{n} enabled axes on the {self.model} (the cycle is time-sliced, {slot} us "
                    f"per axis); got sample_time_us={first.sample_time_us}."
                )

    def __getitem__(self, number: int) -> Any:
        return self._axes[number]

    def __iter__(self) -> Iterator[int]:
        return iter(self._axes)

    def __len__(self) -> int:
        return len(self._axes)

    def __repr__(self) -> str:
        return f"MultiAxisParams({self._axes!r})"

    @property
    def family(self) -> ChipFamily:
        """The chip family."""
        return self._family

    @property
    def model(self) -> str:
        """The chip model's name."""
        return next(iter(self._axes.values())).model

    @property
    def chip(self) -> Any:
        """The chip model record."""
        return self._family.models[self.model]

    @property
    def noun(self) -> str:
        """What the hardware calls its axes: ``"axis"``, or ``"motor"`` on PMAC."""
        return self._noun

    @property
    def numbers(self) -> tuple[int, ...]:
        """The axis (motor) numbers, ascending."""
        return tuple(self._axes)

    @property
    def sets(self) -> list[Any]:
        """The parameter sets in axis order (what :class:`servogym.sim.MultiServoLoop` takes)."""
        return list(self._axes.values())


def _family(params: Any, number: Any) -> ChipFamily:
    try:
        return family_of(params)
    except TypeError:
        raise ParameterError(
            f"each axis must hold a parameter set of a chip family (PMDParams, PMACParams, "
            f"Parker6kParams); axis {number!r} holds a {type(params).__name__}."
        ) from None


def export_axes(
    axes: MultiAxisParams | Mapping[int, Any] | Sequence[Any],
    fmt: str | None = None,
    assumptions: Any = None,
    *,
    metrics: Mapping[str, Any] | None = None,
    notes: Mapping[str, Any] | None = None,
    created: str | _dt.datetime | None = None,
) -> str:
    """The file that loads every axis of a controller, in the chip's own multi-axis form.

    Args:
        axes: The sets (a :class:`MultiAxisParams`, or what builds one).
        fmt: One of the family's formats that the model takes; default the model's own
            (``cmotion``, ``ivar``, ``6250`` or ``6k``).
        assumptions: Recorded in the file (one set for the controller); default all defaults.
        metrics: JSON only: results to keep with the sets.
        notes: JSON only: free-form notes.
        created: JSON only: creation time; default now (UTC).

    Returns:
        The text; a set of one axis gives the family's single-axis file of that axis,
        byte for byte (JSON excepted: its single-axis layout has no axis number).

    Raises:
        ParameterError: for anything :class:`MultiAxisParams` refuses, an illegal set, an
            unknown format or one the model does not take.
    """
    axes = MultiAxisParams(axes)
    family = axes.family
    fmt = _format(family, axes.model, fmt)
    kw = {k: v for k, v in (("metrics", metrics), ("notes", notes)) if v is not None}
    if created is not None:
        kw["created"] = created
    table = family.export_module.FORMAT_TABLE
    return table.export_axes(dict(axes), fmt, assumptions, **kw)


def import_axes(text: str, fmt: str, model: str | None = None) -> MultiAxisParams:
    """The sets of every axis a file loads (a file of one axis gives one).

    Args:
        text: The file content.
        fmt: The file's format; names the family (``"cmotion"`` and ``"host"`` PMD,
            ``"ivar"`` PMAC, ``"6250"`` and ``"6k"`` 6000 series); ``"json"`` needs the
            file's ``chip_family``.
        model: Chip model, for a file that names none; if both name one they must agree.

    Returns:
        The :class:`MultiAxisParams`, identical to the one exported.

    Raises:
        ParameterError: naming the line or entry, for anything the format's single-axis
            importer refuses, an axis the model does not have, a header whose axes differ
            from the ones the file sets, or a set :class:`MultiAxisParams` refuses.
    """
    from servogym.chips._load import FILE_FORMATS, _check_fmt, _family_of_json

    fmt = _check_fmt(fmt)
    family = _family_of_json(text) if fmt == "json" else families()[FILE_FORMATS[fmt]]
    if model is not None:
        owner, model = get_chip(model)
        if owner is not family:
            raise ParameterError(
                f"model={model!r} is a {owner.name} model, but fmt={fmt!r} is a {family.name} "
                f"format; pass a {family.name} model or model=None."
            )
    sets = family.export_module.FORMAT_TABLE.import_axes(text, fmt, model)
    return MultiAxisParams(sets)


def _format(family: ChipFamily, model: str, fmt: str | None) -> str:
    if fmt is None:
        return family.native_format(model)
    allowed = family.formats_for(model)
    name = fmt.lower() if isinstance(fmt, str) else fmt
    if name not in allowed:
        listed = ", ".join(repr(f) for f in allowed)
        raise ParameterError(f"fmt must be one of {listed} for the {model}; got fmt={fmt!r}.")
    return name


def save_axes(
    path: str | Path,
    axes: MultiAxisParams | Mapping[int, Any] | Sequence[Any],
    fmt: str | None = None,
    assumptions: Any = None,
    *,
    inputs: Sequence[str | Path] = (),
    force: bool = False,
    **kw: Any,
) -> Path:
    """Write :func:`export_axes`'s file to ``path`` atomically (temporary file, rename).

    Args:
        path: Where the file goes.
        axes: The sets.
        fmt: As for :func:`export_axes`; default the model's own format.
        assumptions: As for :func:`export_axes`.
        inputs: Files the caller read; ``path`` is never one of them.
        force: Replace another existing file.
        **kw: ``metrics``, ``notes``, ``created`` (JSON only).

    Raises:
        servogym._files.FileSafetyError: for an input, an existing file without ``force``,
            a folder, or a missing folder.
    """
    from servogym._files import check_target, write_atomic

    target = check_target(path, inputs=inputs, force=force, what="path")
    text = export_axes(axes, fmt, assumptions, **kw)
    return write_atomic(target, text)


def load_axes(path: str | Path, fmt: str | None = None, model: str | None = None):
    """:func:`import_axes` of a file on disk (format detected when not named); a cut, edited
    or torn file is refused (its end line or checksum, its folder's manifest)."""
    from servogym._files import check_against_manifest
    from servogym._input import read_text
    from servogym.chips._load import detect_format

    path = Path(path)
    text = read_text(path, "path")
    check_against_manifest(path)
    try:
        return import_axes(text, detect_format(text) if fmt is None else fmt, model)
    except ParameterError as exc:
        raise type(exc)(f"{str(path)!r}: {exc}") from None


__all__ = [
    "DRIVEN_AXES",
    "PERIOD_PER_AXIS",
    "MultiAxisParams",
    "axes_text",
    "export_axes",
    "import_axes",
    "load_axes",
    "max_axes",
    "save_axes",
]
