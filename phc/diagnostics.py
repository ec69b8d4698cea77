"""Located, one-line diagnostics for user mistakes.

Every problem in a user's model is a :class:`Diagnostic` rendered as a single
line ``file:line:col: [warning: ][path: ]message. hint: ... [CODE]``.
:func:`from_pydantic` turns a :class:`pydantic.ValidationError` into such
diagnostics, located through a :class:`~phc.frontend.source.SourceMap`.
"""

from __future__ import annotations

import collections.abc
import difflib
import re
import types
import typing
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any, Callable, Literal, Optional, Sequence

import pydantic

from phc.inert import _one_line, printable
from phc.frontend.source_map import path_text

if TYPE_CHECKING:  # runtime import would be circular (phc.frontend.source imports this module)
    from phc.frontend.source import SourceMap, SourceSpan

__all__ = [
    "ERROR_CODES",
    "Diagnostic",
    "DiagnosticList",
    "Severity",
    "allowed_keys_from_model",
    "from_pydantic",
]

Severity = Literal["error", "warning", "info"]

ERROR_CODES: dict[str, str] = {
    "PHC-E001": "invalid YAML: syntax error, unsupported tag, non-scalar key or several documents",
    "PHC-E002": "duplicate key in a mapping",
    "PHC-E003": "document too large (alias expansion) or nested too deeply",
    "PHC-E004": "the file cannot be read (missing, unreadable or not UTF-8)",
    "PHC-E005": "the model file is empty",
    "PHC-E010": "unknown key",
    "PHC-E011": "missing required key",
    "PHC-E012": "number must be finite (no .inf/.nan)",
    "PHC-E013": "wrong type of value",
    "PHC-E014": "unknown or missing `type` (discriminator) of an entry",
    "PHC-E015": "value is not one of the allowed choices",
    "PHC-E016": "invalid value (rejected by a validation rule)",
    "PHC-E019": "other schema violation",
}
"""Code -> one-line description (documentation table)."""

_printable = printable  # the one-line, inert text of a message (phc.inert)


@dataclass(frozen=True)
class Diagnostic:
    """One problem found in the user's input.

    Parameters
    ----------
    code : str
        Stable code such as ``"PHC-E101"`` (E errors, W warnings, I info).
    message : str
        Full sentence; user identifiers in backticks.
    span : SourceSpan, optional
        Where the problem is.
    hint : str, optional
        How to fix it.
    severity : {"error", "warning", "info"}
        Defaults to ``"error"``.
    path : str, optional
        Dotted YAML path, e.g. ``"components.mass.m"``.
    """

    code: str
    message: str
    span: Optional[SourceSpan] = None
    hint: Optional[str] = None
    severity: Severity = "error"
    path: Optional[str] = None

    def render(self) -> str:
        """Format the diagnostic as exactly one line.

        Returns
        -------
        str
            ``"models/x.yaml:12:5: components.mass.m: unknown key `mm`. hint: did you mean `m`? [PHC-E010]"``;
            ``"<model>: ..."`` without a span; ``"warning: "`` / ``"info: "``
            follows the location for those severities.
        """
        parts = [str(self.span) if self.span is not None else "<model>", ": "]
        if self.severity != "error":
            parts.append(f"{self.severity}: ")
        if self.path:
            parts.append(f"{_printable(self.path)}: ")
        message = _printable(self.message)
        parts.append(message)
        if self.hint:
            if message and message[-1] not in ".!?:;":
                parts.append(".")
            parts.append(f" hint: {_printable(self.hint)}")
        parts.append(f" [{self.code}]")
        return "".join(parts)

    def __str__(self) -> str:
        return self.render()

    def to_dict(self) -> dict[str, Any]:
        """JSON-friendly form.

        Returns
        -------
        dict
            Keys ``code, severity, message, hint, path, file, line, col``
            (the last three are None without a span).
        """
        span = self.span
        return {
            "code": self.code,
            "severity": self.severity,
            "message": self.message,
            "hint": self.hint,
            "path": self.path,
            "file": span.file if span is not None else None,
            "line": span.line if span is not None else None,
            "col": span.col if span is not None else None,
        }


def _sort_key(d: Diagnostic) -> tuple:
    s = d.span
    return (s.file, s.line, s.col, d.code) if s is not None else ("", 0, 0, d.code)


class DiagnosticList(list[Diagnostic]):
    """A list of diagnostics with summary helpers."""

    @property
    def has_errors(self) -> bool:
        """True when any diagnostic has severity ``"error"``."""
        return any(d.severity == "error" for d in self)

    @property
    def errors(self) -> DiagnosticList:
        """The diagnostics of severity ``"error"``."""
        return DiagnosticList(d for d in self if d.severity == "error")

    @property
    def warnings(self) -> DiagnosticList:
        """The diagnostics of severity ``"warning"``."""
        return DiagnosticList(d for d in self if d.severity == "warning")

    def sorted(self) -> DiagnosticList:
        """Return a copy sorted by file, line, column and code (diagnostics without span first).

        Returns
        -------
        DiagnosticList
        """
        return DiagnosticList(sorted(self, key=_sort_key))

    def render_text(self) -> str:
        """All diagnostics, sorted, one line each (no trailing newline).

        Returns
        -------
        str
        """
        return "\n".join(d.render() for d in self.sorted())

    def to_json(self) -> list[dict[str, Any]]:
        """The sorted diagnostics as dictionaries (see :meth:`Diagnostic.to_dict`).

        Returns
        -------
        list of dict
        """
        return [d.to_dict() for d in self.sorted()]


# -- pydantic ----------------------------------------------------------------------

_EXPECTED: dict[str, str] = {
    "int_type": "an integer",
    "int_parsing": "an integer",
    "int_from_float": "an integer",
    "int_parsing_size": "an integer",
    "float_type": "a number",
    "float_parsing": "a number",
    "string_type": "a string",
    "string_unicode": "a string",
    "bytes_type": "a string",
    "list_type": "a list",
    "tuple_type": "a list",
    "set_type": "a list",
    "frozen_set_type": "a list",
    "iterable_type": "a list",
    "dict_type": "a mapping",
    "mapping_type": "a mapping",
    "model_type": "a mapping",
    "model_attributes_type": "a mapping",
    "dataclass_type": "a mapping",
    "bool_type": "a boolean (true/false)",
    "bool_parsing": "a boolean (true/false)",
    "none_required": "null",
    "decimal_type": "a number",
    "decimal_parsing": "a number",
    "complex_type": "a complex number",
    "complex_str_parsing": "a complex number",
    "date_type": "a date",
    "date_parsing": "a date",
    "datetime_type": "a date and time",
    "datetime_parsing": "a date and time",
}

_KIND: tuple[tuple[type, str], ...] = (
    (bool, "boolean"),
    (int, "integer"),
    (float, "number"),
    (str, "string"),
    (dict, "mapping"),
    (list, "list"),
    (tuple, "list"),
)

_TAG_ELEM_RE = re.compile(r"'((?:[^'\\]|\\.)*)'")
_OWN_CODE_RE = re.compile(r"^PHC-[EWI]\d{3}$")

AllowedKeys = Callable[[tuple], Sequence[str]]


def _short_repr(value: Any, limit: int = 40) -> str:
    try:
        text = repr(value)
    except Exception:  # noqa: BLE001
        text = f"<{type(value).__name__}>"
    text = _one_line(text)
    return text if len(text) <= limit else text[: limit - 3] + "..."


def _found(value: Any) -> str:
    if value is None:
        return "null"
    for tp, kind in _KIND:
        if isinstance(value, tp):
            return f"{kind} `{_short_repr(value)}`"
    return f"`{_short_repr(value)}` ({type(value).__name__})"


def _quoted_list(text: str) -> list[str]:
    """``"'a', 'b' or 'c'"`` -> ``["a", "b", "c"]`` (pydantic's ctx formatting)."""
    found = _TAG_ELEM_RE.findall(text)
    if found:
        return found
    return [p.strip() for p in re.split(r",|\bor\b", text) if p.strip()]


def _backticked(items: Sequence[str], limit: int = 12) -> str:
    shown = ", ".join(f"`{i}`" for i in items[:limit])
    return shown + (", ..." if len(items) > limit else "")


def _did_you_mean(word: Any, candidates: Sequence[str]) -> Optional[str]:
    if not isinstance(word, str) or not candidates:
        return None
    match = difflib.get_close_matches(word, [c for c in candidates if c != word], n=1, cutoff=0.6)
    return f"did you mean `{match[0]}`?" if match else None


def _split_hint(message: str) -> tuple[str, Optional[str]]:
    """Split ``"... hint: fix it"`` written by a custom validator into message and hint."""
    head, sep, tail = message.partition(" hint: ")
    if sep and tail.strip():
        return head.rstrip(), tail.strip()
    return message, None


def _convert(err: dict[str, Any], allowed_keys: Optional[AllowedKeys]) -> tuple[str, str, Optional[str], str]:
    """(code, message, hint, expected) for one pydantic error dict."""
    etype: str = err.get("type", "")
    loc = tuple(err.get("loc", ()))
    msg = _one_line(str(err.get("msg", "")))
    ctx = err.get("ctx") or {}
    value = err.get("input")
    last = loc[-1] if loc else None

    if _OWN_CODE_RE.match(etype):  # PydanticCustomError("PHC-E201", "...") from a validator
        message, hint = _split_hint(msg)
        return etype, message, hint, ""
    if etype == "extra_forbidden":
        names: Sequence[str] = ()
        if "allowed" in ctx:
            names = list(ctx["allowed"])
        elif allowed_keys is not None:
            try:
                names = list(allowed_keys(loc[:-1]))
            except Exception:  # noqa: BLE001 - a hint must never crash reporting
                names = ()
        hint = _did_you_mean(last, names)
        if hint is None and names:
            hint = f"allowed keys: {_backticked(sorted(names))}"
        return "PHC-E010", f"unknown key `{last}`", hint, ""
    if etype == "missing":
        return "PHC-E011", f"missing required key `{last}`", None, ""
    if etype == "finite_number":
        return "PHC-E012", "number must be finite (no .inf/.nan)", None, ""
    if etype in _EXPECTED or etype.endswith("_type") or etype.endswith("_parsing"):
        expected = _EXPECTED.get(etype) or etype.rsplit("_", 1)[0].replace("_", " ")
        hint = None
        if len(loc) == 2 and loc[0] == "ports" and isinstance(value, str) and "mapping" in expected:
            hint = f"an exposed port names its inner port: write `{loc[1]}: {{port: {value}}}`"
        return "PHC-E013", f"expected {expected}, got {_found(value)}", hint, expected
    if etype in ("union_tag_invalid", "union_tag_not_found"):
        disc = _quoted_list(str(ctx.get("discriminator", "'type'")))
        disc_name = disc[0] if disc else "type"
        if etype == "union_tag_invalid":
            tags = _quoted_list(str(ctx.get("expected_tags", "")))
            tag = ctx.get("tag", value)
            hint = _did_you_mean(tag, tags)
            message = f"unknown {disc_name} `{tag}`; expected one of {_backticked(tags, 40)}"
            return "PHC-E014", message, hint, ""
        return ("PHC-E014", f"missing key `{disc_name}` (it selects the kind of entry)",
                f"add `{disc_name}: ...`", "")
    if etype in ("literal_error", "enum"):
        allowed = _quoted_list(str(ctx.get("expected", "")))
        shown = value if isinstance(value, (str, int, float, bool)) or value is None else _short_repr(value)
        message = f"invalid value `{_short_repr(shown) if not isinstance(shown, str) else shown}`; " \
                  f"expected one of {_backticked(allowed, 40)}"
        return "PHC-E015", message, _did_you_mean(value, allowed), ""
    if etype in ("value_error", "assertion_error"):
        error = ctx.get("error")
        text = _one_line(str(error)) if error is not None and str(error) else msg
        for prefix in ("Value error, ", "Assertion failed, "):
            if text.startswith(prefix):
                text = text[len(prefix):]
        message, hint = _split_hint(text)
        return "PHC-E016", message, hint, ""
    message = msg
    if value is None or isinstance(value, (bool, int, float, str)):
        message += f", got {_found(value)}"
    return "PHC-E019", message, None, ""


def from_pydantic(err: pydantic.ValidationError, smap: SourceMap, *, root_path: Sequence = (),
                  allowed_keys: Optional[AllowedKeys] = None) -> list[Diagnostic]:
    """Convert a pydantic validation error into located diagnostics.

    Parameters
    ----------
    err : pydantic.ValidationError
        The error raised by ``Model.model_validate(data)``.
    smap : SourceMap
        Source map of the YAML document the data came from.
    root_path : sequence, optional
        Path (in `smap`) of the data that was validated, when it is not the
        whole document.
    allowed_keys : callable, optional
        ``allowed_keys(loc) -> field names`` for the did-you-mean hint of
        unknown keys.  `loc` is pydantic's location of the *mapping* holding
        the unknown key (without `root_path`, with pydantic's tag/type
        elements, e.g. ``("components", "a", "mass")``).  Use
        :func:`allowed_keys_from_model` to build it from the validated model.

    Returns
    -------
    list of Diagnostic
        One per pydantic error, compacted to at most one per (location, code)
        (unknown and missing keys also keep one per key name; wrong-type errors
        from several union members are merged into one "expected A or B").

    Notes
    -----
    Codes: ``extra_forbidden`` -> PHC-E010 (located at the key), ``missing``
    -> PHC-E011, ``finite_number`` -> PHC-E012, type/parsing errors ->
    PHC-E013, ``union_tag_invalid``/``union_tag_not_found`` -> PHC-E014,
    ``literal_error``/``enum`` -> PHC-E015, ``value_error``/``assertion_error``
    (custom validators) -> PHC-E016, anything else -> PHC-E019.  A validator
    raising ``pydantic_core.PydanticCustomError("PHC-E201", "message hint: fix")``
    keeps its own code; " hint: " in a validator message becomes the hint.
    """
    root = tuple(root_path)
    records: list[dict[str, Any]] = []
    for e in err.errors(include_url=False):
        loc = tuple(e.get("loc", ()))
        code, message, hint, expected = _convert(e, allowed_keys)
        etype = e.get("type", "")
        full = root + loc
        if etype == "extra_forbidden":
            span = smap.locate_key(full)
        elif loc and loc[-1] == "[key]":  # bad dict key: point at the key itself
            full = full[:-1]
            span = smap.locate_key(full)
        elif etype == "union_tag_invalid" and smap.has(smap.resolved_path(full) + (_disc(e),)):
            span = smap.locate(smap.resolved_path(full) + (_disc(e),))
        else:
            span = smap.locate(full)
        resolved = smap.resolved_path(full)
        branch = len(resolved) < len(full)  # pydantic tag/type elements: possibly a union member
        if etype == "extra_forbidden" and (not resolved or resolved[-1] != loc[-1]):
            resolved = resolved + (loc[-1],)
        records.append(dict(code=code, message=message, hint=hint, expected=expected, span=span,
                            resolved=resolved, branch=branch, input=e.get("input"),
                            detail=loc[-1] if code in ("PHC-E010", "PHC-E011") and loc else None))

    def superseded(rec: dict[str, Any]) -> bool:
        # a wrong-type error of one union member is noise when another member matched the
        # shape and reported something more specific at or below the same place
        if rec["code"] != "PHC-E013" or not rec["branch"]:
            return False
        n = len(rec["resolved"])
        return any(o is not rec and (o["code"] != "PHC-E013" or len(o["resolved"]) > n)
                   and o["resolved"][:n] == rec["resolved"] for o in records)

    out: list[Diagnostic] = []
    index: dict[tuple, int] = {}
    expected_seen: dict[int, list[str]] = {}
    for rec in records:
        if superseded(rec):
            continue
        code, span = rec["code"], rec["span"]
        key = (span, code, rec["detail"])
        if key in index:
            i = index[key]
            seen = expected_seen[i]
            if code == "PHC-E013" and rec["expected"] and rec["expected"] not in seen:
                seen.append(rec["expected"])
                alternatives = seen[0] if len(seen) == 1 else ", ".join(seen[:-1]) + " or " + seen[-1]
                out[i] = Diagnostic(code, f"expected {alternatives}, got {_found(rec['input'])}",
                                    span=span, hint=out[i].hint, path=out[i].path)
            continue
        index[key] = len(out)
        expected_seen[len(out)] = [rec["expected"]] if rec["expected"] else []
        dotted = path_text(rec["resolved"])
        out.append(Diagnostic(code, rec["message"], span=span, hint=rec["hint"], path=dotted))
    return out


def _disc(e: dict[str, Any]) -> str:
    disc = _quoted_list(str((e.get("ctx") or {}).get("discriminator", "'type'")))
    return disc[0] if disc else "type"


# -- field names of a pydantic model at an error location -------------------------

def _strip_annotated(tp: Any) -> Any:
    while typing.get_origin(tp) is typing.Annotated:
        tp = typing.get_args(tp)[0]
    return tp


def _is_model(tp: Any) -> bool:
    return isinstance(tp, type) and issubclass(tp, pydantic.BaseModel)


def _field_keys(model: type[pydantic.BaseModel]) -> set[str]:
    names: set[str] = set()
    for name, field in model.model_fields.items():
        names.add(field.alias or name)
        if isinstance(field.validation_alias, str):
            names.add(field.validation_alias)
        if model.model_config.get("populate_by_name") or model.model_config.get("validate_by_name"):
            names.add(name)
    return names


def _literal_values(model: type[pydantic.BaseModel]) -> set[Any]:
    values: set[Any] = set()
    for field in model.model_fields.values():
        ann = _strip_annotated(field.annotation)
        if typing.get_origin(ann) is Literal:
            values.update(typing.get_args(ann))
    return values


def _member_matches(member: Any, head: Any) -> bool:
    if not _is_model(member):
        return False
    if head == member.__name__:
        return True
    if isinstance(head, str) and re.search(rf"\b{re.escape(member.__name__)}\b", head):
        return True
    try:
        return head in _literal_values(member)
    except TypeError:
        return False


def _tag_of(tp: Any) -> Any:
    """The `Tag` of a tagged union member (``Annotated[X, Tag("x")]``), else None."""
    while typing.get_origin(tp) is typing.Annotated:
        tag = next((m.tag for m in tp.__metadata__ if isinstance(m, pydantic.Tag)), None)
        if tag is not None:
            return tag
        tp = typing.get_args(tp)[0]
    return None


def _names_at(tp: Any, loc: tuple, depth: int = 0) -> set[str]:
    if depth > 64:
        return set()
    tp = _strip_annotated(tp)
    origin = typing.get_origin(tp)
    if origin is typing.Union or (hasattr(types, "UnionType") and origin is types.UnionType):
        members = [m for m in typing.get_args(tp) if m is not type(None)]
        if loc:
            for m in members:
                if _tag_of(m) == loc[0]:  # a member of a union with a callable discriminator
                    return _names_at(m, loc[1:], depth + 1)
                if _member_matches(_strip_annotated(m), loc[0]):
                    return _names_at(m, loc[1:], depth + 1)
        found: set[str] = set()
        for m in members:
            found |= _names_at(m, loc, depth + 1)
        return found
    if _is_model(tp):
        if not loc:
            return _field_keys(tp)
        for name, field in tp.model_fields.items():
            if loc[0] in (name, field.alias, field.validation_alias):
                return _names_at(field.annotation, loc[1:], depth + 1)
        return set()
    args = typing.get_args(tp)
    if not loc or origin is None:
        return set()
    if isinstance(origin, type) and issubclass(origin, (dict, collections.abc.Mapping)):
        return _names_at(args[1], loc[1:], depth + 1) if len(args) == 2 else set()
    if isinstance(origin, type) and issubclass(origin, (list, set, frozenset, tuple, collections.abc.Iterable)):
        if not args:
            return set()
        if origin is tuple and not (len(args) == 2 and args[1] is Ellipsis):
            i = loc[0]
            return _names_at(args[i], loc[1:], depth + 1) if isinstance(i, int) and 0 <= i < len(args) else set()
        return _names_at(args[0], loc[1:], depth + 1)
    return set()


def allowed_keys_from_model(model: type[pydantic.BaseModel]) -> AllowedKeys:
    """Build an `allowed_keys` function for :func:`from_pydantic` from a model class.

    Parameters
    ----------
    model : type[pydantic.BaseModel]
        The model that was validated.

    Returns
    -------
    callable
        ``f(loc) -> sorted field names`` of the (sub)model at pydantic location
        `loc`; it follows fields, dict values, list items and union members
        (selected by discriminator tag or class name in `loc`).  Unknown
        locations give an empty list.
    """

    def allowed(loc: tuple) -> list[str]:
        try:
            return sorted(_names_at(model, tuple(loc)))
        except Exception:  # noqa: BLE001
            return []

    return allowed
