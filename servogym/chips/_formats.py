"""What every family's exporter shares: the axis check, the model and the provenance header of a
file, and the ``export`` / ``import_params`` dispatch over the family's formats.

The family exporters keep only what differs: how a register is written in their files (the
spellings of the family's register table, :mod:`servogym.chips._registers`) and the number
formats of those files.
"""

from __future__ import annotations

import difflib
import re
from collections.abc import Callable, Iterable, Mapping
from typing import Any

import numpy as np

from servogym.chips._axisfile import read_axes_json, write_axes_json
from servogym.chips._paramfile import FileSchema, check_format
from servogym.chips._space import ParameterError


def check_index(
    chip: Any, value: Any, count: int, *, noun: str = "axis", verb: str = "has", where: str = ""
) -> int:
    """An axis (or motor) number ``1 <= value <= count`` of ``chip``, or a ParameterError.

    Args:
        chip: The chip model record (its ``name`` goes into the message).
        value: The number given.
        count: How many the model has.
        noun: ``"axis"`` or ``"motor"``.
        verb: How the model relates to them in the message (``"has"``, ``"addresses"``).
        where: Where the number was read (``"line 3"``), prefixed to the message.
    """
    at = f"{where}: " if where else ""
    if isinstance(value, bool) or not isinstance(value, int | np.integer):
        raise ParameterError(
            f"{at}{noun} must be an integer with 1 <= {noun} <= {count} ({chip.name}); "
            f"got {noun}={value!r} of type {type(value).__name__}."
        )
    if not 1 <= value <= count:
        plural = "axes" if noun == "axis" else noun + "s"
        raise ParameterError(
            f"{at}{noun} must satisfy 1 <= {noun} <= {count} ({chip.name} {verb} "
            f"{count} {plural if count > 1 else noun}); got {noun}={int(value)}."
        )
    return int(value)


def resolve_model(
    model: Any,
    header: Mapping[str, Any],
    get_model: Callable[[Any], Any],
    models: Iterable[str],
    what: str,
) -> Any:
    """The chip model from the ``model`` argument and/or the file header; they must agree.

    Args:
        model: The model the caller named (a name or a record), or None.
        header: The file's header entries (``chip_model``).
        get_model: The family's model look-up.
        models: The family's model names, for the message.
        what: The kind of file, for messages (``"C-Motion snippet"``).
    """
    named = header.get("chip_model")
    if model is None:
        if named is None:
            raise ParameterError(
                f"the {what} names no chip model (no 'chip_model:' header line); pass "
                f"model=, one of {', '.join(models)}."
            )
        return get_model(named)
    chip = get_model(model)
    if named is not None and get_model(named).name != chip.name:
        raise ParameterError(
            f"model={chip.name!r} disagrees with the header's 'chip_model: {named}' ({what}); "
            f"pass model={named!r}, or model=None to use the header."
        )
    return chip


def read_header(
    comments: Iterable[str], schema: FileSchema, id_prefix: str, lead: str = r"\s*"
) -> dict[str, Any]:
    """The provenance header of an exported file, from its comment lines.

    Args:
        comments: The comment lines, in file order.
        schema: The family's file schema (its assumption switches).
        id_prefix: The family's assumption-id prefix (``"PMD"``, ``"PMAC"``, ``"PK"``).
        lead: What may precede an entry on a comment line (comment marks, blanks).

    Returns:
        The ``key: value`` entries as strings (the first of each key), and under
        ``"assumptions"`` the switches when the header lists them.

    Raises:
        ParameterError: if the header lists only some assumptions, or an unknown one.
    """
    key = re.compile(rf"^{lead}([a-z_]+)\s*:\s*(\S.*?)\s*$")
    assumption = re.compile(rf"^{lead}assumption\s+{id_prefix}-A\d+\s+([a-z_]+)\s*:\s*(\S+)\s*$")
    fields: dict[str, Any] = {}
    assumed: dict[str, str] = {}
    for line in comments:
        m = assumption.match(line)
        if m:
            assumed.setdefault(m.group(1), m.group(2))
            continue
        m = key.match(line)
        if m:
            fields.setdefault(m.group(1), m.group(2))
    if assumed:
        fields["assumptions"] = schema.complete_assumptions(assumed, "the header")
    return fields


JSON_EXPORT_KEYWORDS = ("assumptions", "metrics", "notes", "created")
"""The keywords a JSON export takes (:meth:`FileSchema.write`)."""


def _check_keywords(function: str, fmt: str, kw: Mapping[str, Any], takes: Iterable[str]) -> None:
    """A ParameterError naming the format and the keywords it takes, for any other in ``kw``."""
    takes = tuple(takes)
    unknown = [k for k in kw if k not in takes]
    if not unknown:
        return
    listed = ", ".join(takes) if takes else "none"
    got = ", ".join(f"{k}={kw[k]!r}" for k in unknown)
    close = [m for k in unknown for m in difflib.get_close_matches(k, takes, n=1)]
    hint = f" Did you mean {', '.join(close)}?" if close else ""
    raise ParameterError(
        f"{function}(fmt={fmt!r}) takes the keywords {listed}"
        f"{' (besides model)' if function == 'import_params' else ''}; got {got}.{hint}"
    )


class Formats:
    """A family's export formats: JSON (the shared layout) and its own files.

    Args:
        schema: The family's JSON file schema.
        extensions: Format -> suggested file extension, ``"json"`` first.
        writers: Format -> ``(params, **kw) -> str`` for every format but JSON.
        readers: Format -> ``(text, model, **kw) -> params`` for every format but JSON.
        export_keywords: Format -> the keywords its writer takes (default ``axis`` and
            ``assumptions``), for every format but JSON; any other keyword is refused with a
            ParameterError naming the format and these. JSON's export takes ``assumptions``,
            ``metrics``, ``notes``, ``created``, and ignores ``axis`` and ``index`` (a JSON file
            holds one set).
        import_keywords: Format -> the keywords its reader takes besides ``model`` (default
            none), for every format but JSON. JSON's import takes none: ``axis`` or
            ``index`` other than None is refused (a JSON file holds one set).
        index: The keyword that names the axis (``"axis"``; PMAC: ``"motor"``).
        ignore_case: Whether ``fmt`` matches in any case.
        axis_writers: Format -> ``(axes, assumptions) -> str`` for every format but JSON:
            the file of several axes (``axes`` maps axis number -> set, in axis order).
        axis_readers: Format -> ``(text, model) -> (chip, {axis: set})`` for every format
            but JSON.
    """

    def __init__(
        self,
        schema: FileSchema,
        extensions: Mapping[str, str],
        writers: Mapping[str, Callable[..., str]],
        readers: Mapping[str, Callable[..., Any]],
        *,
        export_keywords: Mapping[str, Iterable[str]] | None = None,
        import_keywords: Mapping[str, Iterable[str]] | None = None,
        index: str = "axis",
        ignore_case: bool = False,
        axis_writers: Mapping[str, Callable[..., str]] | None = None,
        axis_readers: Mapping[str, Callable[..., Any]] | None = None,
    ) -> None:
        self.schema = schema
        self.extensions = dict(extensions)
        self.writers = dict(writers)
        self.readers = dict(readers)
        self.index = index
        self.export_keywords = {
            "json": tuple(dict.fromkeys((*JSON_EXPORT_KEYWORDS, "axis", index))),
            **{f: tuple((export_keywords or {}).get(f, ("axis", "assumptions")))
               for f in self.writers},
        }  # fmt: skip
        self.import_keywords = {
            "json": (),
            **{f: tuple((import_keywords or {}).get(f, ())) for f in self.readers},
        }
        self.ignore_case = ignore_case
        self.axis_writers = dict(axis_writers or {})
        self.axis_readers = dict(axis_readers or {})

    def check(self, fmt: Any) -> str:
        """``fmt`` if it names one of the formats, else a ParameterError listing them."""
        return check_format(fmt, self.extensions, ignore_case=self.ignore_case)

    def export(self, params: Any, fmt: str, **kw: Any) -> str:
        """See the family's ``export``."""
        fmt = self.check(fmt)
        _check_keywords("export", fmt, kw, self.export_keywords[fmt])
        if fmt == "json":
            kw.pop("axis", None)
            kw.pop(self.index, None)
            return self.schema.write(params, **kw)
        return self.writers[fmt](params, **kw)

    def import_params(self, text: str, fmt: str, model: Any = None, **kw: Any) -> Any:
        """See the family's ``import_params``."""
        fmt = self.check(fmt)
        if fmt == "json":
            for name in dict.fromkeys(("axis", self.index)):
                if kw.get(name) is not None:
                    takes = [f for f, names in self.import_keywords.items() if name in names]
                    where = f" ({name}= applies to fmt={' or '.join(map(repr, takes))} only)"
                    raise ParameterError(
                        f"import_params(fmt='json') takes no {name}: a JSON file holds one "
                        f"set{where if takes else ''}; got {name}={kw[name]!r}."
                    )
                kw.pop(name, None)
        _check_keywords("import_params", fmt, kw, self.import_keywords[fmt])
        if fmt == "json":
            return self.schema.read_params(text, model)
        return self.readers[fmt](text, model, **kw)

    def export_axes(
        self, axes: Mapping[int, Any], fmt: str, assumptions: Any = None, **kw: Any
    ) -> str:
        """The file of several axes' sets (see :func:`servogym.chips.export_axes`).

        Args:
            axes: Axis (PMAC: motor) number -> parameter set, checked by the caller.
            fmt: One of the family's formats.
            assumptions: Recorded in the file; default all defaults.
            **kw: ``metrics``, ``notes``, ``created`` (JSON only).
        """
        fmt = self.check(fmt)
        if fmt == "json":
            return write_axes_json(self.schema, axes, assumptions, noun=self.index, **kw)
        if kw:
            raise ParameterError(
                f"{', '.join(sorted(kw))} apply to fmt='json' only; got them with fmt={fmt!r}."
            )
        return self.axis_writers[fmt](dict(sorted(axes.items())), assumptions)

    def import_axes(self, text: str, fmt: str, model: Any = None) -> dict[int, Any]:
        """Axis (PMAC: motor) number -> set, read from a file of one or several axes."""
        fmt = self.check(fmt)
        if fmt == "json":
            return read_axes_json(self.schema, text, model, noun=self.index)[0]
        return self.axis_readers[fmt](text, model)

    def functions(
        self, module: str, params: str, formats: str, kw: str, index_doc: str = ""
    ) -> tuple[Callable[..., str], Callable[..., Any]]:
        """The family's public ``export`` and ``import_params``, documented for the family.

        Args:
            module: ``__name__`` of the family's export module.
            params: The parameter-set class's name.
            formats: The formats and their writers, for the docstring.
            kw: What ``**kw`` passes on, for the docstring.
            index_doc: The docstring entry of ``import_params``'s axis keyword; empty for a
                family whose files hold one axis.
        """
        formats_obj = self

        def export(params: Any, fmt: str, **kw: Any) -> str:
            return formats_obj.export(params, fmt, **kw)

        def import_params(text: str, fmt: str, model: Any = None, **kw: Any) -> Any:
            return formats_obj.import_params(text, fmt, model, **kw)

        names = {
            "params": params,
            "formats": formats,
            "kw": kw,
            "index": f"\n        **kw: {index_doc}" if index_doc else "",
            "listed": ", ".join(f'``"{f}"``' for f in self.extensions),
        }
        for function, doc in ((export, _EXPORT_DOC), (import_params, _IMPORT_DOC)):
            function.__module__ = module
            function.__qualname__ = function.__name__
            function.__doc__ = doc.format(**names)
        return export, import_params


_EXPORT_DOC = """Export a parameter set in one of :data:`FORMATS`.

    Args:
        params: The parameter set (a :class:`{params}` or a mapping); validated again first.
        fmt: {formats}.
        **kw: Passed on: {kw}

    Returns:
        The exported text; :data:`FILE_EXTENSIONS` suggests a file extension.

    Raises:
        ParameterError: for an unknown format (listing the formats), a keyword the format
            does not take (naming those it takes) or an illegal set.
    """

_IMPORT_DOC = """Import a parameter set exported in one of :data:`FORMATS`.

    Args:
        text: The exported text.
        fmt: One of {listed}.
        model: Chip model; default the one the text names. If both are given they must
            agree. Required for a file without a header that does not name it.{index}

    Returns:
        The {params} (for the provenance of a JSON file use :func:`from_json`).

    Raises:
        ParameterError: for an unknown format (listing the formats), a keyword the format
            does not take (naming those it takes; a JSON file takes no axis), or anything
            the format's importer rejects.
    """
