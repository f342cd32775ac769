"""One declarative register table per chip family, and what is derived from it.

A family describes every register once, as a :class:`Register` row: its name, its spelling in
each of the family's file dialects, its width and sign, legal range, default, unit and source
tag ([M] manual, [C] public code, [A] assumption). A chip model derives its registers from the
family's table and changes only the rows that differ (:meth:`RegisterTable.space`, like a
CMSIS-SVD ``derivedFrom`` with a patch). From the table come:

* the legal ranges, validation and the parameter space tuners and envs search
  (:class:`~servogym.chips.ParameterSpace`), and ``servogym chips``;
* the parameter-set class's behaviour (:class:`RegisterSet`: defaults, ``from_dict``,
  ``to_dict``, the kernel array order);
* the writers and readers of every file format (the spellings: a PMD command and its opcode,
  a PMAC I-variable number, a 6000-series command and its decimals);
* the spec tables' tests (``tests/chips/test_*_docs.py``).

Family code stays only where the arithmetic differs (the filters, the profiles, the number
formats of the files).
"""

from __future__ import annotations

import dataclasses
from collections.abc import Iterable, Iterator, Mapping
from typing import Any, ClassVar, Self

import numpy as np

from servogym.chips._space import ParameterError, ParameterSpace, ParamSpec


@dataclasses.dataclass(frozen=True)
class Spelling:
    """How one file dialect names a register.

    Attributes:
        text: The name in the file: a command (``"SetKp"``, ``"SGP"``) or an enum
            (``"PMDPositionLoopKp"``).
        code: The number that goes with it, if any: an opcode (``0x25``), a parameter number
            (Magellan ``SetPositionLoop`` 0..21), an I-variable suffix (``30`` of ``Ixx30``)
            or decimal places (6000-series ``SGP``: 2).
        width: The width of the value in that dialect when it differs from the register's
            (``"u32"`` for a 31-bit register sent as two words).
        rank: Position in the dialect's export order when it is not the table's order.
    """

    text: str = ""
    code: int | None = None
    width: str | None = None
    rank: int | None = None


@dataclasses.dataclass(frozen=True)
class Register(ParamSpec):
    """One row of a family's register table: a :class:`ParamSpec` (name, legal range,
    default, width, unit, doc, source tag [M]/[C]/[A], log scale, tunable, default note) and
    the register's spelling in each file dialect.

    Attributes:
        spelling: The register's :class:`Spelling` in each file dialect of the family
            (``"navigator"``, ``"magellan"``, ``"ivar"``, ``"6000"`` ...).
        controller_wide: Whether the register is one setting of the whole controller rather
            than one per axis (the axes are the table's dimension, as CMSIS-SVD's ``dim``):
            every axis of a multi-axis set holds the same value, and a multi-axis file
            writes it once where its format has a controller-wide command
            (:mod:`servogym.chips._axes`).
    """

    spelling: Mapping[str, Spelling] = dataclasses.field(default_factory=dict)
    controller_wide: bool = False

    @property
    def signed(self) -> bool:
        """Whether the register holds negative values."""
        return self.low < 0

    def spec(self) -> ParamSpec:
        """The row as the :class:`ParamSpec` validation and the parameter space use."""
        return ParamSpec(**{f.name: getattr(self, f.name) for f in dataclasses.fields(ParamSpec)})


class RegisterTable(Mapping[str, Register]):
    """A family's registers, in the order of its kernel array.

    Args:
        family: The family's name (``"pmd"``), for messages.
        rows: Every register any model of the family has.
    """

    def __init__(self, family: str, rows: Iterable[Register]) -> None:
        self.family = family
        self.rows = tuple(rows)
        self._by_name = {r.name: r for r in self.rows}
        self._spaces: dict[Any, ParameterSpace] = {}
        if len(self._by_name) != len(self.rows):
            raise ValueError(f"duplicate register names in the {family} register table")

    def __getitem__(self, name: str) -> Register:
        return self._by_name[name]

    def __iter__(self) -> Iterator[str]:
        return iter(self._by_name)

    def __len__(self) -> int:
        return len(self.rows)

    @property
    def names(self) -> tuple[str, ...]:
        """Every register's name, in kernel-array order."""
        return tuple(self._by_name)

    @property
    def controller_wide(self) -> tuple[str, ...]:
        """The registers that are one setting of the whole controller, in table order."""
        return tuple(r.name for r in self.rows if r.controller_wide)

    def index(self) -> dict[str, int]:
        """Position of each register in the kernel array."""
        return {name: i for i, name in enumerate(self._by_name)}

    def space(
        self,
        model: str,
        changes: Mapping[str, Mapping[str, Any]] | None = None,
        omit: Iterable[str] = (),
    ) -> ParameterSpace:
        """A chip model's registers: the table without ``omit``, each row with its ``changes``.

        Args:
            model: The chip model's name.
            changes: Per register, the fields that differ on this model
                (``{"kout": {"high": 65535}}``).
            omit: Registers the model does not have.
        """
        changes = changes or {}
        dropped = frozenset(omit)
        try:  # a ParameterSpace is immutable: build each model's once (envs ask every step)
            key: Any = (
                model,
                tuple(sorted((k, tuple(sorted(v.items()))) for k, v in changes.items())),
                dropped,
            )
            hash(key)
        except TypeError:  # an unhashable change: build it every time
            key = None
        if key is not None and key in self._spaces:
            return self._spaces[key]
        unknown = set(changes).union(dropped) - set(self._by_name)
        if unknown:
            raise ValueError(f"{model} changes registers {sorted(unknown)} the table lacks")
        space = ParameterSpace(
            model,
            [
                dataclasses.replace(r, **changes.get(r.name, {})).spec()
                for r in self.rows
                if r.name not in dropped
            ],
        )
        if key is not None:
            self._spaces[key] = space
        return space

    def spelled(self, dialect: str) -> list[tuple[Register, Spelling]]:
        """The registers a dialect names, with their spelling, in the dialect's export order."""
        pairs = [(r, r.spelling[dialect]) for r in self.rows if dialect in r.spelling]
        if any(s.rank is not None for _, s in pairs):
            pairs.sort(key=lambda pair: pair[1].rank)
        return pairs

    def spellings(self, dialect: str) -> dict[str, Spelling]:
        """Register name -> its spelling in ``dialect``."""
        return {r.name: s for r, s in self.spelled(dialect)}


class RegisterSet:
    """What a family's parameter-set dataclass derives from its register table.

    The dataclass has ``model`` and one field per row of the table (a field whose default is
    ``None`` takes the model's default, e.g. the sample time); it names its table, model
    look-up and space function as class arguments and calls :meth:`_check_registers` from
    ``__post_init__``::

        @dataclasses.dataclass(frozen=True)
        class PMDParams(RegisterSet, table=TABLE, get_model=get_model, space=parameter_space):
            model: str = "MC2100"
            kp: int = 100
            ...

    Attributes:
        TABLE: The family's register table; the fields in kernel-array order.
    """

    TABLE: ClassVar[RegisterTable]
    model: str

    def __init_subclass__(
        cls,
        *,
        table: RegisterTable | None = None,
        get_model: Any = None,
        space: Any = None,
        **kw: Any,
    ) -> None:
        super().__init_subclass__(**kw)
        if table is not None:
            cls.TABLE = table
        if get_model is not None:
            cls._get_model = staticmethod(get_model)  # type: ignore[method-assign]
        if space is not None:
            cls._space_of = staticmethod(space)  # type: ignore[method-assign]

    @staticmethod
    def _get_model(name: Any) -> Any:
        raise NotImplementedError

    @staticmethod
    def _space_of(model: Any) -> ParameterSpace:
        raise NotImplementedError

    @classmethod
    def _field_default(cls, name: str) -> Any:
        return cls.__dataclass_fields__[name].default  # type: ignore[attr-defined]

    def _absent(self, name: str, chip: Any, value: Any) -> ParameterError:
        """The error for a register the model lacks, set away from the table's default."""
        return ParameterError(
            f"{name} does not exist on {chip.name}, so it must stay "
            f"{self.TABLE[name].default}; got {name}={value!r}."
        )

    def _check_registers(self) -> tuple[Any, ParameterSpace]:
        """Validate every register field against the model's space (in table order)."""
        chip = self._get_model(self.model)
        object.__setattr__(self, "model", chip.name)
        space = self._space_of(chip)
        for name in self.TABLE.names:
            value = getattr(self, name)
            if value is None and self._field_default(name) is None:
                value = space[name].default
            if name in space:
                value = space[name].validate(value, context=chip.name)
            elif value != self.TABLE[name].default:
                raise self._absent(name, chip, value)
            object.__setattr__(self, name, value)
        return chip, space

    @property
    def chip(self) -> Any:
        """The chip model record."""
        return self._get_model(self.model)

    @property
    def space(self) -> ParameterSpace:
        """The legal ranges for this set's chip model."""
        return self._space_of(self.model)

    @classmethod
    def default(cls, model: str) -> Self:
        """The default set of a model (see the family's spec for where each default comes from)."""
        return cls(model=model)  # type: ignore[call-arg]

    @classmethod
    def from_dict(cls, values: Mapping[str, Any]) -> Self:
        """Build from a mapping of register names; unknown names raise with close matches."""
        values = dict(values)
        model = values.pop("model", cls._field_default("model"))
        space = cls._space_of(model)
        for name in values:
            if name not in cls.TABLE:
                raise ParameterError(space.unknown_message(name))
        return cls(model=model, **values)  # type: ignore[call-arg]

    def to_dict(self) -> dict[str, Any]:
        """Every register the model has, ``model`` first."""
        space = self.space
        return {"model": self.model, **{n: getattr(self, n) for n in self.TABLE if n in space}}

    def replace(self, **changes: Any) -> Self:
        """A copy with some registers changed (validated)."""
        return dataclasses.replace(self, **changes)  # type: ignore[type-var]

    def to_array(self) -> np.ndarray:
        """All registers as an int64 array in table order, for the kernel."""
        return np.array([getattr(self, n) for n in self.TABLE], dtype=np.int64)
