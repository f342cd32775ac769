"""The servogym JSON parameter file, and the provenance helpers every family's exporter shares.

One layout for every chip family (``format_version`` 1)::

    {"format": "servogym-params", "format_version": 1, "chip_family": "pmd",
     "chip_model": "MC2300", <family keys, e.g. "sample_time_us": 100>,
     "spec_version": "...", "assumptions": {...}, "params": {...},
     "created": "2025-01-31T12:00:00+00:00", "servogym_version": "...",
     "metrics": {...}, "notes": {...}}          # metrics and notes optional

A family describes what differs in one :class:`FileSchema` (its name, spec version,
parameter and assumption classes, and its own top-level keys as :class:`ExtraKey`); its
``to_json`` / ``from_json`` call :meth:`FileSchema.write` / :meth:`FileSchema.read`.
"""

from __future__ import annotations

import dataclasses
import datetime as _dt
import difflib
import json
import warnings
from collections.abc import Callable, Iterable, Mapping
from typing import Any, Generic, TypeVar

import numpy as np

from servogym import __version__
from servogym.chips._space import ParameterError

FILE_FORMAT = "servogym-params"
"""Value of the ``format`` key of a JSON parameter file."""

FILE_FORMAT_VERSION = 1
"""Version of the JSON parameter-file layout this module writes and reads."""

OPTIONAL_KEYS = ("metrics", "notes", "checksum")
"""Top-level keys a file may add to the required ones. ``checksum`` (``"sha256:<hex>"`` of
the rest of the document, the last key of every file servogym writes) is verified when
present; a hand-written file may leave it out (docs/files.md)."""

P = TypeVar("P")
A = TypeVar("A")


@dataclasses.dataclass(frozen=True)
class ParamFile(Generic[P, A]):
    """A parameter file read by a family's ``from_json``.

    Attributes:
        params: The parameter set, validated.
        assumptions: The assumption switches the set was tuned under.
        provenance: Every other top-level entry of the file: ``format``,
            ``format_version``, ``chip_family``, ``chip_model``, the family's own keys
            (e.g. ``sample_time_us``), ``spec_version``, ``created``, ``servogym_version``
            and, when present, ``metrics`` and ``notes``.
    """

    params: P
    assumptions: A
    provenance: dict[str, Any]


@dataclasses.dataclass(frozen=True)
class ExtraKey:
    """A family's own top-level key: the parameter set's attribute of the same name.

    Attributes:
        kind: JSON type(s) the entry must have (``bool`` never passes for a number).
        what: The type in words, for the error (``"an integer"``).
        rule: What the entry must equal, in words, for a set (``"params.sample_time_us
            (100)"``); the error reads ``<key> must equal <rule>; got <key>=<value>.``
    """

    kind: type | tuple[type, ...]
    what: str
    rule: Callable[[Any], str]


@dataclasses.dataclass(frozen=True)
class FileSchema:
    """What a chip family's JSON parameter file holds beyond the shared layout.

    Attributes:
        family: ``chip_family`` value (``"pmd"``).
        title: The family in messages (``"PMD"``, ``"Parker 6000-series"``).
        spec_version: The spec version the family implements; another one in a file warns.
        params_type: Parameter-set class: ``from_dict``, ``to_dict``, ``model``, dataclass.
        assumptions_type: Assumption-switch class (an ``AssumptionSet``: ``CHOICES``, ``IDS``).
        get_model: Chip model record by name (or the record itself); raises a
            :class:`ParameterError` naming the models for an unknown one.
        required: The ``params`` entries a file must give for a chip model record.
        extra_keys: The family's own top-level keys, written after ``chip_model``.
        noun: What the entries of ``params`` are called (``"register"``, ``"parameter"``).
    """

    family: str
    title: str
    spec_version: str
    params_type: type
    assumptions_type: type
    get_model: Callable[[str], Any]
    required: Callable[[Any], Iterable[str]]
    extra_keys: Mapping[str, ExtraKey] = dataclasses.field(default_factory=dict)
    noun: str = "register"

    @property
    def required_keys(self) -> tuple[str, ...]:
        """Every top-level key a file must have, in the order :meth:`write` writes them."""
        return (
            "format",
            "format_version",
            "chip_family",
            "chip_model",
            *self.extra_keys,
            "spec_version",
            "assumptions",
            "params",
            "created",
            "servogym_version",
        )

    # ----------------------------------------------------------------------------------
    # Validation shared by every export format
    # ----------------------------------------------------------------------------------

    def legal_params(self, params: Any) -> Any:
        """Validate ``params`` again (a mapping is built through ``from_dict``)."""
        cls = self.params_type
        if isinstance(params, cls):
            return cls(**{f.name: getattr(params, f.name) for f in dataclasses.fields(params)})
        if isinstance(params, Mapping):
            return cls.from_dict(params)
        raise ParameterError(
            f"params must be a {cls.__name__} or a mapping of {self.noun} names to values; "
            f"got params of type {type(params).__name__}."
        )

    def check_assumption_names(
        self, values: Mapping[str, Any], where: str, *, require_all: bool
    ) -> None:
        """Refuse unknown assumption names (suggesting close ones) and, if asked, missing ones."""
        names = list(self.assumptions_type.CHOICES)
        for name in values:
            if name not in names:
                close = difflib.get_close_matches(str(name), names, n=3)
                hint = f" Did you mean {', '.join(close)}?" if close else ""
                raise ParameterError(
                    f"{where} has an unknown assumption {name!r}; the assumptions are "
                    f"{', '.join(names)}.{hint}"
                )
        if require_all:
            missing = [n for n in names if n not in values]
            if missing:
                raise ParameterError(
                    f"{where} must give every assumption so the behaviour is pinned down; "
                    f"missing {', '.join(missing)}."
                )

    def legal_assumptions(self, assumptions: Any) -> Any:
        """The assumption switches from an instance, a partial mapping or None (defaults)."""
        cls = self.assumptions_type
        if assumptions is None:
            return cls()
        if isinstance(assumptions, cls):
            return assumptions
        if isinstance(assumptions, Mapping):
            self.check_assumption_names(assumptions, "assumptions", require_all=False)
            return cls(**assumptions)
        raise ParameterError(
            f"assumptions must be a {cls.__name__}, a mapping of assumption names or None; "
            f"got assumptions of type {type(assumptions).__name__}."
        )

    def complete_assumptions(self, values: Mapping[str, Any], where: str) -> Any:
        """The assumption switches from a mapping that must name every one (file, header)."""
        self.check_assumption_names(values, where, require_all=True)
        return self.assumptions_type(**values)

    # ----------------------------------------------------------------------------------
    # JSON parameter file
    # ----------------------------------------------------------------------------------

    def write(
        self,
        params: Any,
        assumptions: Any = None,
        *,
        metrics: Mapping[str, Any] | None = None,
        notes: Mapping[str, Any] | None = None,
        created: str | _dt.datetime | None = None,
    ) -> str:
        """The JSON parameter file of a set; the arguments are a family's ``to_json``'s."""
        p = self.legal_params(params)
        a = self.legal_assumptions(assumptions)
        doc: dict[str, Any] = {
            "format": FILE_FORMAT,
            "format_version": FILE_FORMAT_VERSION,
            "chip_family": self.family,
            "chip_model": p.model,
            **{key: getattr(p, key) for key in self.extra_keys},
            "spec_version": self.spec_version,
            "assumptions": a.to_dict(),
            "params": p.to_dict(),
            "created": created_text(created),
            "servogym_version": __version__,
        }
        return finish_json(doc, metrics, notes)

    def read(self, text: str | bytes) -> ParamFile[Any, Any]:
        """Read a file :meth:`write` wrote; see a family's ``from_json`` for the rules.

        The spec-version warning points at the caller of the family's ``from_json``.
        """
        doc = _load(text)
        self.check_header(doc)
        chip = self.get_model(_expect(doc, "chip_model", str, f"a {self.title} chip model name"))
        values = _expect(doc, "params", dict, f"a JSON object of {self.noun} values")
        params = self.params_type.from_dict(self.complete_values(values, chip))
        for key, extra in self.extra_keys.items():
            got = _expect(doc, key, extra.kind, extra.what)
            if got != getattr(params, key):
                raise ParameterError(f"{key} must equal {extra.rule(params)}; got {key}={got!r}.")
        assumptions = self.check_tail(doc, stacklevel=4)
        provenance = {
            k: v for k, v in doc.items() if k not in ("params", "assumptions", "checksum")
        }
        return ParamFile(params=params, assumptions=assumptions, provenance=provenance)

    def read_params(self, text: str | bytes, model: Any = None) -> Any:
        """The parameter set of a file (``import_params(text, "json", model)``).

        Args:
            text: The file content.
            model: Chip model name or record; if given it must be the file's ``chip_model``.
        """
        params = self.read(text).params
        self.same_model(model, params.model)
        return params

    def same_model(self, model: Any, chip_model: str) -> None:
        """Refuse a ``model`` argument (if given) other than the file's ``chip_model``."""
        if model is not None and self.get_model(model).name != chip_model:
            raise ParameterError(
                f"model={self.get_model(model).name!r} disagrees with the file's chip_model "
                f"{chip_model!r}; pass model={chip_model!r} or model=None."
            )

    def complete_values(self, values: Any, chip: Any, where: str = "params") -> Any:
        """``values`` (a file's ``params`` object, at ``where``) if it names ``chip`` and gives
        every register of it (an import takes no defaults)."""
        if not isinstance(values, dict):
            raise ParameterError(f"{where} must be a JSON object; got {values!r}.")
        if values.get("model") != chip.name:
            raise ParameterError(
                f"{where}.model must equal chip_model {chip.name!r}; "
                f"got params.model={values.get('model')!r}."
            )
        absent = [r for r in self.required(chip) if r not in values]
        if absent:
            raise ParameterError(
                f"{where} must give every {self.noun} of {chip.name} (an import takes no "
                f"defaults); missing {', '.join(absent)}."
            )
        return values

    def check_tail(self, doc: dict[str, Any], *, stacklevel: int) -> Any:
        """The keys every file shares after its sets: the assumptions (returned complete),
        the provenance strings, metrics and notes, then the checksum (last: a structural
        error gets its own message first); a spec version other than this servogym's warns
        (at ``stacklevel`` from here)."""
        asm = _expect(doc, "assumptions", dict, "a JSON object of assumption switches")
        assumptions = self.complete_assumptions(asm, "assumptions")
        spec = _expect(doc, "spec_version", str, "a string")
        created_text(_expect(doc, "created", str, "an ISO 8601 timestamp string"))
        _expect(doc, "servogym_version", str, "a string")
        for key in ("metrics", "notes"):
            if key in doc:
                _expect(doc, key, dict, "a JSON object")
        verify_checksum(doc)
        if spec != self.spec_version:
            warnings.warn(
                f"the parameter file was written for spec_version {spec!r} but this servogym "
                f"implements {self.spec_version!r}: the {self.noun}s load unchanged, but the "
                f"emulated behaviour may differ from the one its metrics were measured with. "
                f"Evaluate the set again to refresh its metrics.",
                UserWarning,
                stacklevel=stacklevel,
            )
        return assumptions

    def json_functions(
        self, module: str
    ) -> tuple[Callable[..., str], Callable[[str | bytes], ParamFile[Any, Any]]]:
        """The family's public ``to_json`` and ``from_json``, documented for the family.

        Args:
            module: ``__name__`` of the family's export module, which re-exports them.
        """
        schema = self

        def to_json(
            params: Any,
            assumptions: Any = None,
            *,
            metrics: Mapping[str, Any] | None = None,
            notes: Mapping[str, Any] | None = None,
            created: str | _dt.datetime | None = None,
        ) -> str:
            return schema.write(params, assumptions, metrics=metrics, notes=notes, created=created)

        def from_json(text: str | bytes) -> ParamFile[Any, Any]:
            return schema.read(text)

        names = {
            "title": self.title,
            "family": self.family,
            "params": self.params_type.__name__,
            "assumptions": self.assumptions_type.__name__,
            "keys": " / ".join(f"``{k}``" for k in ("chip_model", *self.extra_keys)),
        }
        for function, doc in ((to_json, _TO_JSON_DOC), (from_json, _FROM_JSON_DOC)):
            function.__module__ = module
            function.__qualname__ = function.__name__
            function.__doc__ = doc.format(**names)
        return to_json, from_json

    def check_header(
        self,
        doc: dict[str, Any],
        *,
        fmt: str = FILE_FORMAT,
        expected: str = f"{FILE_FORMAT!r} (a servogym parameter file)",
        required: tuple[str, ...] | None = None,
    ) -> None:
        """Format (``fmt``, described as ``expected``), version, family, then the set of
        top-level keys (``required``, the single-axis file's by default, and the optional
        ones)."""
        got = doc.get("format")
        if got != fmt:
            raise ParameterError(f"format must be {expected}; got format={got!r}.")
        version = doc.get("format_version")
        if type(version) is not int or version != FILE_FORMAT_VERSION:
            raise ParameterError(
                f"format_version must be {FILE_FORMAT_VERSION} (the only version servogym "
                f"{__version__} reads); got format_version={version!r}."
            )
        family = doc.get("chip_family")
        if family != self.family:
            raise ParameterError(
                f"chip_family must be {self.family!r} for a {self.title} parameter file; got "
                f"chip_family={family!r}. Read other families with their own importer."
            )
        required = self.required_keys if required is None else required
        missing = [k for k in required if k not in doc]
        if missing:
            raise ParameterError(f"the parameter file misses the keys {', '.join(missing)}.")
        allowed = required + OPTIONAL_KEYS
        unknown = [k for k in doc if k not in allowed]
        if unknown:
            label = "" if fmt == FILE_FORMAT else f"{fmt} "
            raise ParameterError(
                f"the parameter file has unknown keys {', '.join(map(repr, unknown))}; "
                f"{label}format_version {FILE_FORMAT_VERSION} allows {', '.join(allowed)}."
            )


_TO_JSON_DOC = """A JSON parameter file with provenance.

    Args:
        params: The parameter set (a :class:`{params}` or a mapping with ``model``);
            validated again before writing.
        assumptions: The assumption switches the set was tuned under (a
            :class:`{assumptions}` or a mapping of some of them); default all defaults.
        metrics: Optional results to keep with the set (e.g. ``{{"ise": 1.2e3}}``).
        notes: Optional free-form notes (e.g. plant, tuner, seed).
        created: Creation time; default now (UTC). Pass a fixed value for reproducible files.

    Returns:
        The file text (UTF-8 JSON, 2-space indent, trailing newline).

    Raises:
        ParameterError: for an illegal set (naming parameter, value and range), unknown
            assumptions, or metrics/notes that are not JSON values.
    """

_FROM_JSON_DOC = """Read a {title} JSON parameter file written by :func:`to_json`.

    Args:
        text: The file content.

    Returns:
        A :class:`ParamFile`: the validated {params}, its {assumptions} and its provenance.

    Raises:
        ParameterError: if the text is not JSON, is not a servogym parameter file, has an
            unknown ``format_version`` or a ``chip_family`` other than ``"{family}"``, misses
            or adds top-level keys, lists an illegal or incomplete parameter set, or has
            inconsistent {keys} entries.

    Warns:
        UserWarning: if the file was written for another ``spec_version``.
    """


# --------------------------------------------------------------------------------------
# Helpers
# --------------------------------------------------------------------------------------


def finish_json(
    doc: dict[str, Any], metrics: Mapping[str, Any] | None, notes: Mapping[str, Any] | None
) -> str:
    """A file's JSON text: ``doc`` with its optional metrics and notes, then its checksum."""
    if metrics is not None:
        doc["metrics"] = json_object(metrics, "metrics")
    if notes is not None:
        doc["notes"] = json_object(notes, "notes")
    from servogym._files import json_checksum  # servogym._files imports chips

    doc["checksum"] = json_checksum(doc)
    return json.dumps(doc, indent=2, allow_nan=False) + "\n"


def assumption_lines(assumptions: Any) -> list[str]:
    """Header-comment lines of the switches: ``assumption PMD-A1 rounding: nearest``."""
    ids = assumptions.IDS
    return [
        f"assumption {ids[name]} {name}: {value}" for name, value in assumptions.to_dict().items()
    ]


def _json_default(obj: Any) -> Any:
    if isinstance(obj, np.generic):
        return obj.item()
    if isinstance(obj, np.ndarray):
        return obj.tolist()
    raise TypeError(f"values of type {type(obj).__name__} cannot be written as JSON")


def json_object(value: Any, name: str) -> dict[str, Any]:
    """``value`` as it reads back from JSON (NumPy scalars and arrays converted)."""
    if not isinstance(value, Mapping):
        raise ParameterError(
            f"{name} must be a mapping (written as a JSON object); got {name} of type "
            f"{type(value).__name__}."
        )
    try:
        # Round trip now, so the file holds exactly what from_json will return.
        return json.loads(json.dumps(dict(value), allow_nan=False, default=_json_default))
    except (TypeError, ValueError) as exc:
        raise ParameterError(
            f"{name} must hold only JSON values (str keys; str, int, finite float, bool, "
            f"None, lists and mappings of them; NumPy scalars are converted): {exc}."
        ) from None


def created_text(created: str | _dt.datetime | None) -> str:
    """The ``created`` entry: now (UTC) for None, else the checked ISO 8601 text."""
    if created is None:
        return _dt.datetime.now(_dt.UTC).isoformat(timespec="seconds")
    if isinstance(created, _dt.datetime):
        return created.isoformat()
    if isinstance(created, str):
        try:
            _dt.datetime.fromisoformat(created)
        except ValueError:
            raise ParameterError(
                f"created must be an ISO 8601 timestamp such as '2025-01-31T12:00:00+00:00'; "
                f"got created={created!r}."
            ) from None
        return created
    raise ParameterError(
        f"created must be a datetime, an ISO 8601 string or None; got created of type "
        f"{type(created).__name__}."
    )


def verify_checksum(doc: Mapping[str, Any]) -> None:
    """Check a document's ``checksum`` entry, when it has one, against the rest of it."""
    from servogym._files import json_checksum  # servogym._files imports chips

    if "checksum" not in doc:
        return
    given = doc["checksum"]
    rest = {k: v for k, v in doc.items() if k != "checksum"}
    expected = json_checksum(rest)
    if given != expected:
        raise ParameterError(
            f"checksum must equal the sha256 of the rest of the file ({expected[:19]}...); got "
            f"checksum={str(given)[:19]!r}...: the file was changed or corrupted after it was "
            f"written. Write it again; to load a hand-edited copy, delete its checksum entry."
        )


def _no_duplicates(pairs: list[tuple[str, Any]]) -> dict[str, Any]:
    out: dict[str, Any] = {}
    for key, value in pairs:
        if key in out:
            raise ParameterError(
                f"the key {key!r} appears twice in one JSON object (values {out[key]!r} and "
                f"{value!r}); a parameter file must name each entry once."
            )
        out[key] = value
    return out


def _no_constant(name: str) -> Any:
    raise ParameterError(
        f"a parameter file must be strict JSON; got the non-JSON number {name} (NaN and "
        f"infinities are not register values)."
    )


def strict_json(text: str | bytes) -> Any:
    """``json.loads`` that refuses a key named twice in an object, NaN and infinities, and
    nesting deeper than :data:`servogym._input.MAX_JSON_DEPTH` (a ``ParameterError``)."""
    from servogym._input import json_depth_error

    why = json_depth_error(text)
    if why is not None:
        raise ParameterError(f"a parameter file must be plain JSON; got {why}.")
    return json.loads(text, object_pairs_hook=_no_duplicates, parse_constant=_no_constant)


def _load(text: str | bytes) -> dict[str, Any]:
    try:
        doc = strict_json(text)
    except json.JSONDecodeError as exc:
        raise ParameterError(
            f"a parameter file must be JSON; invalid JSON at line {exc.lineno} column "
            f"{exc.colno}: {exc.msg}."
        ) from None
    if not isinstance(doc, dict):
        raise ParameterError(
            f"a parameter file must be a JSON object; got a JSON {type(doc).__name__}."
        )
    return doc


def _expect(doc: Mapping[str, Any], key: str, kind: type | tuple[type, ...], what: str) -> Any:
    value = doc[key]
    if (isinstance(value, bool) and kind is not bool) or not isinstance(value, kind):
        raise ParameterError(f"{key} must be {what}; got {key}={value!r}.")
    return value


def check_format(fmt: Any, extensions: Mapping[str, str], *, ignore_case: bool = False) -> str:
    """``fmt`` if it names one of a family's export formats (the keys of ``extensions``),
    else a :class:`ParameterError` listing them with their extensions and the closest match.
    """
    name = fmt.lower() if ignore_case and isinstance(fmt, str) else fmt
    if name in extensions:
        return name
    formats = list(extensions)
    close = difflib.get_close_matches(str(name), formats, n=1)
    hint = f" Did you mean {close[0]!r}?" if close else ""
    listed = ", ".join(f"{f!r} ({extensions[f]})" for f in formats)
    raise ParameterError(f"fmt must be one of {listed}; got fmt={fmt!r}.{hint}")
