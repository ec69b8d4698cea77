"""Safe YAML loading with source positions.

Model files are parsed with PyYAML's *safe* machinery only (no tag can run
code).  Besides the plain Python data, :func:`load_yaml` returns a
:class:`SourceMap` that knows the file position of every node, so later stages
(pydantic validation, elaboration) can report each problem as one line
``file:line:col: message [CODE]``.  Loader problems (syntax errors, duplicate
keys, unsafe tags, alias bombs, unreadable files) are returned as
:class:`~phc.diagnostics.Diagnostic` objects, never raised.
"""

from __future__ import annotations

import bisect
import os
import re
from dataclasses import dataclass
from typing import Any, Iterator, Sequence, Union

import yaml
from yaml.constructor import SafeConstructor
from yaml.events import StreamEndEvent
from yaml.nodes import MappingNode, Node, ScalarNode, SequenceNode

from phc.diagnostics import Diagnostic

__all__ = [
    "MAX_FLOW_DEPTH",
    "MAX_NODES",
    "PathElem",
    "SourceMap",
    "SourceSpan",
    "load_yaml",
    "read_yaml_file",
]

MAX_NODES = 100_000
"""Largest number of nodes (after expanding aliases) a document may construct."""

MAX_FLOW_DEPTH = 200
"""Deepest nesting of flow collections (``[...]``, ``{...}``) accepted."""

PathElem = Union[str, int]

_YAML_PREFIX = "tag:yaml.org,2002:"
_MAP_TAG = _YAML_PREFIX + "map"
_SEQ_TAG = _YAML_PREFIX + "seq"
_STR_TAG = _YAML_PREFIX + "str"
_MERGE_TAG = _YAML_PREFIX + "merge"
_VALUE_TAG = _YAML_PREFIX + "value"
_SAFE_TAGS = frozenset(t for t in SafeConstructor.yaml_constructors
                       if t is not None and t != _YAML_PREFIX + "binary")  # bytes are no model data


@dataclass(frozen=True)
class SourceSpan:
    """A position in a source file (1-based line and column).

    Parameters
    ----------
    file : str
        The file name as given by the user.
    line, col : int
        1-based line and column.
    """

    file: str
    line: int
    col: int

    def __str__(self) -> str:
        return f"{self.file}:{self.line}:{self.col}"


_LINE_BREAK = re.compile(r"\r\n?|\n")
"""What ends a line in a reported position: LF, CRLF or CR, as editors count lines. PyYAML
(YAML 1.1) also breaks lines at NEL, LS and PS (U+0085, U+2028, U+2029), so its own
``mark.line`` would point below the real line in a file that holds one of those characters."""
_LINE_STARTS: dict[int, tuple[str, list[int]]] = {}


def _line_col(mark: Any) -> tuple[int, int]:
    """0-based (line, column) of a PyYAML mark, counted with :data:`_LINE_BREAK`."""
    buffer, index = getattr(mark, "buffer", None), getattr(mark, "index", None)
    if not isinstance(buffer, str) or not isinstance(index, int):
        return mark.line, mark.column
    entry = _LINE_STARTS.get(id(buffer))
    if entry is None or entry[0] is not buffer:
        if len(_LINE_STARTS) >= 8:
            _LINE_STARTS.clear()
        entry = _LINE_STARTS[id(buffer)] = (buffer, [0] + [m.end() for m in _LINE_BREAK.finditer(buffer)])
    starts = entry[1]
    line = bisect.bisect_right(starts, index) - 1
    return line, index - starts[line]


def _span(file: str, mark: Any) -> SourceSpan:
    if mark is None:
        return SourceSpan(file, 1, 1)
    line, col = _line_col(mark)
    return SourceSpan(file, line + 1, col + 1)


def _tag_text(tag: str | None) -> str:
    if tag is None:
        return "?"
    if tag.startswith(_YAML_PREFIX):
        return "!!" + tag[len(_YAML_PREFIX):]
    return tag


def _key_value(node: ScalarNode) -> Any:
    """The Python value of a scalar key node (its text when it cannot be built)."""
    if node.tag in (_STR_TAG, _MERGE_TAG, _VALUE_TAG):
        return node.value
    try:
        value = SafeConstructor().construct_object(node, deep=True)
        hash(value)
        return value
    except Exception:  # noqa: BLE001 - any failure: fall back to the text
        return node.value


class _Entry:
    __slots__ = ("key", "value")

    def __init__(self, key: Node | None, value: Node) -> None:
        self.key = key
        self.value = value


class SourceMap:
    """Positions of every node of one YAML document.

    Nodes are addressed by path tuples such as
    ``("components", "mass", "parameters", 0)``: strings (or other scalar key
    values) select mapping entries, integers select list items.  A dotted
    string ``"components.mass.m"`` is accepted as a shorthand.

    Parameters
    ----------
    file : str
        File name used in every returned :class:`SourceSpan`.
    root : yaml.Node or None
        The composed document (None for an empty document).
    """

    def __init__(self, file: str, root: Node | None) -> None:
        self.file = file
        self.root = root
        self._index: dict[int, tuple[dict[Any, _Entry], dict[str, _Entry]]] = {}

    # -- node tree ---------------------------------------------------------------
    def _mapping_index(self, node: MappingNode) -> tuple[dict[Any, _Entry], dict[str, _Entry]]:
        cached = self._index.get(id(node))
        if cached is not None:
            return cached
        by_value: dict[Any, _Entry] = {}
        by_text: dict[str, _Entry] = {}
        self._fill_index(node, by_value, by_text, set())
        self._index[id(node)] = (by_value, by_text)
        return by_value, by_text

    def _fill_index(self, node: MappingNode, by_value: dict, by_text: dict, seen: set) -> None:
        # merged (``<<``) entries first, explicit keys override them (YAML merge semantics)
        if id(node) in seen:
            return
        seen.add(id(node))
        merges: list[Node] = []
        explicit: list[tuple[Node, Node]] = []
        for key, value in node.value:
            if isinstance(key, ScalarNode) and key.tag == _MERGE_TAG:
                if isinstance(value, MappingNode):
                    merges.append(value)
                elif isinstance(value, SequenceNode):
                    merges.extend(v for v in value.value if isinstance(v, MappingNode))
            else:
                explicit.append((key, value))
        for source in reversed(merges):  # earlier merge sources take precedence
            self._fill_index(source, by_value, by_text, seen)
        for key, value in explicit:
            if not isinstance(key, ScalarNode):
                continue
            entry = _Entry(key, value)
            by_value[_key_value(key)] = entry
            by_text[key.value] = entry

    def _child(self, node: Node | None, elem: Any) -> _Entry | None:
        if isinstance(node, MappingNode):
            by_value, by_text = self._mapping_index(node)
            try:
                entry = by_value.get(elem)
            except TypeError:  # unhashable path element
                entry = None
            if entry is None and not isinstance(elem, (list, dict)):
                entry = by_text.get(str(elem))
            return entry
        if isinstance(node, SequenceNode):
            if isinstance(elem, str) and elem.isdigit():
                elem = int(elem)
            if isinstance(elem, int) and not isinstance(elem, bool) and 0 <= elem < len(node.value):
                return _Entry(None, node.value[elem])
        return None

    @staticmethod
    def _norm(path: Sequence[PathElem] | str) -> tuple:
        if isinstance(path, str):
            return tuple(path.split(".")) if path else ()
        return tuple(path)

    def _resolve(self, path: Sequence[PathElem] | str) -> list[tuple[int, _Entry]]:
        """Best-effort walk: the steps ``(index in path, entry)`` that resolved.

        Unresolvable elements are skipped.  Among all ways of skipping, the one
        resolving the most elements wins; ties go to the one resolving a later
        element (so a pydantic tag that happens to equal a key is skipped when
        the following element only resolves without it).
        """
        path = self._norm(path)
        memo: dict[tuple[int, int], tuple[tuple[int, int], tuple]] = {}

        def best(node: Node | None, i: int) -> tuple[tuple[int, int], tuple]:
            if i >= len(path):
                return (0, -1), ()
            key = (id(node), i)
            if key in memo:
                return memo[key]
            result = best(node, i + 1)  # skip path[i]
            entry = self._child(node, path[i])
            if entry is not None:
                (count, last), steps = best(entry.value, i + 1)
                taken = ((count + 1, max(last, i)), ((i, entry),) + steps)
                if taken[0] >= result[0]:
                    result = taken
            memo[key] = result
            return result

        return list(best(self.root, 0)[1])

    def _node_span(self, node: Node | None) -> SourceSpan:
        if node is None:
            return SourceSpan(self.file, 1, 1)
        return _span(self.file, node.start_mark)

    def node(self, path: Sequence[PathElem] | str) -> Node | None:
        """The deepest node reached by the best-effort walk of `path` (see :meth:`locate`).

        Parameters
        ----------
        path : sequence of str or int
            The path to look up.

        Returns
        -------
        yaml.Node or None
            The node, or the root (None for an empty document).
        """
        steps = self._resolve(path)
        return steps[-1][1].value if steps else self.root

    # -- public queries -----------------------------------------------------------
    def locate(self, path: Sequence[PathElem] | str) -> SourceSpan:
        """Span of the value node at `path` (best effort).

        Elements that do not resolve (for instance the discriminator tags or
        type names such as ``'function-after[...]'`` or ``'float'`` that
        pydantic inserts into error locations) are skipped; the result is the
        deepest node reached.

        Parameters
        ----------
        path : sequence of str or int
            Path such as ``("components", "mass", "m")``.

        Returns
        -------
        SourceSpan
            Start of the value node; the document start when nothing resolves.
        """
        return self._node_span(self.node(path))

    def locate_key(self, path: Sequence[PathElem] | str) -> SourceSpan:
        """Span of the mapping *key* of the last element of `path`.

        Parameters
        ----------
        path : sequence of str or int
            Path whose last element names a mapping key.

        Returns
        -------
        SourceSpan
            Start of the key node; falls back to :meth:`locate` when the last
            element is not a resolved mapping key (e.g. a list index).
        """
        norm = self._norm(path)
        steps = self._resolve(norm)
        if steps and steps[-1][0] == len(norm) - 1 and steps[-1][1].key is not None:
            return self._node_span(steps[-1][1].key)
        return self.locate(norm)

    def value_offset(self, path: Sequence[PathElem] | str) -> int:
        """Number of characters before the scalar text at the value's column.

        Parameters
        ----------
        path : sequence of str or int
            Path of a scalar value (resolved like :meth:`locate`).

        Returns
        -------
        int
            1 for single- or double-quoted scalars, 0 otherwise (plain scalars,
            block scalars ``|``/``>``, collections).  A 0-based column `c` inside
            the string maps to file column ``locate(path).col + value_offset(path) + c``.
        """
        node = self.node(path)
        if isinstance(node, ScalarNode) and node.style in ("'", '"'):
            return 1
        return 0

    def locate_in_value(self, path: Sequence[PathElem] | str, offset: int) -> SourceSpan:
        """Position of character `offset` of the (folded) string value at `path`.

        Single-line scalars map directly (plus one for a quote); multi-line plain,
        quoted and block (``|``, ``>``) scalars are mapped through their folding, so
        an error inside a long expression points at the right line and column.
        """
        span = self.locate(path)
        node = self.node(path)
        if not isinstance(node, ScalarNode):
            return span
        start, end = node.start_mark, node.end_mark
        buffer = getattr(start, "buffer", None)
        start_line, start_col = _line_col(start)
        if buffer is None or (start_line == _line_col(end)[0] and node.style not in ("|", ">")):
            return SourceSpan(span.file, span.line, span.col + self.value_offset(path) + offset)
        raw = buffer[start.index:end.index]
        lines = _LINE_BREAK.split(raw)
        positions: list[tuple[int, int]] = []
        block = node.style in ("|", ">")
        quoted = node.style in ("'", '"')
        for k, text in enumerate(lines):
            if block and k == 0:
                continue  # the header line `|` / `>-`
            line_no = start_line + k
            if k == 0:
                lead, body = start_col + (1 if quoted else 0), text[1:] if quoted else text
            else:
                body = text.lstrip()
                lead = len(text) - len(body)
            body = body.rstrip()
            if quoted and k == len(lines) - 1 and body.endswith(node.style):
                body = body[:-1]
            if not body:
                continue
            if positions:
                positions.append(positions[-1][0:1] + (positions[-1][1] + 1,))
            positions.extend((line_no, lead + i) for i in range(len(body)))
        if not positions:
            return span
        line, col = positions[min(max(offset, 0), len(positions) - 1)]
        return SourceSpan(span.file, line + 1, col + 1)

    def has(self, path: Sequence[PathElem] | str) -> bool:
        """Whether every element of `path` resolves exactly (no skipping).

        Parameters
        ----------
        path : sequence of str or int
            The path to test.

        Returns
        -------
        bool
        """
        node = self.root
        for elem in self._norm(path):
            entry = self._child(node, elem)
            if entry is None:
                return False
            node = entry.value
        return True

    def resolved_path(self, path: Sequence[PathElem] | str) -> tuple[PathElem, ...]:
        """The elements of `path` that the best-effort walk resolved.

        Parameters
        ----------
        path : sequence of str or int
            Typically a pydantic error location.

        Returns
        -------
        tuple
            The path without pydantic's tag and type elements.
        """
        norm = self._norm(path)
        return tuple(norm[i] for i, _ in self._resolve(norm))

    def __repr__(self) -> str:
        return f"SourceMap({self.file!r})"


# -- loading ------------------------------------------------------------------------

def _children(node: Node) -> Iterator[Node]:
    if isinstance(node, MappingNode):
        for key, value in node.value:
            yield key
            yield value
    elif isinstance(node, SequenceNode):
        yield from node.value


def _syntax_hint(problem: str) -> str | None:
    if "'\\t'" in problem or "\\t" in problem:
        return "indent with spaces, not tabs"
    if "mapping values are not allowed" in problem:
        return "check the indentation, or quote a value that contains `: `"
    if "could not find expected ':'" in problem:
        return "each entry of a mapping needs `key: value`"
    if "found undefined alias" in problem:
        return "define the anchor (`&name`) before using the alias (`*name`)"
    if "cannot start any token" in problem:
        return "quote the value if it starts with a special character such as `@`, `` ` `` or `%`"
    return None


def _marked_error(err: yaml.MarkedYAMLError, file: str) -> Diagnostic:
    problem = (err.problem or err.context or "invalid YAML").strip()
    mark = err.problem_mark or err.context_mark
    message = f"YAML syntax error: {problem}"
    if err.context and err.problem and err.context_mark is not None and mark is not None \
            and _line_col(err.context_mark)[0] != _line_col(mark)[0]:
        message += f" ({err.context} at line {_line_col(err.context_mark)[0] + 1})"
    hint = _syntax_hint(problem)
    start = err.context_mark or mark
    buffer = getattr(start, "buffer", None)
    if isinstance(buffer, str) and mark is not None and buffer[mark.index:mark.index + 1] == ":":
        key_start = max(buffer.rfind(c, 0, mark.index) for c in "\n{[,")
        if mark.index - key_start - 1 > 1024:  # YAML's implicit keys end within 1024 characters
            hint = "YAML allows keys of at most 1024 characters; shorten the key"
    if isinstance(buffer, str) and mark is not None:
        odd = None
        for odd in _ODD_BREAK.finditer(buffer, max(0, min(start.index, mark.index) - 200), mark.index + 1):
            pass  # the last one before the problem
        if odd is not None:
            hint = (f"the text holds U+{ord(odd.group()):04X}, which YAML reads as a line break; "
                    "remove it or quote the value")
    return Diagnostic("PHC-E001", message, span=_span(file, mark), hint=hint)


_ODD_BREAK = re.compile("[\x85\u2028\u2029]")


_FLOW_CHARS = re.compile(r"[\[\]{}'\"#\\]")
_TOKEN_START = frozenset(" \t\r\n[{,:-?")


def _flow_too_deep(text: str, limit: int) -> int:
    """Offset where ``[``/``{`` nesting first exceeds `limit`, or -1.

    PyYAML's pure-Python scanner is quadratic (or worse) in the flow nesting
    depth, so absurd nesting is refused before parsing.  The scan is
    approximate: quoted scalars (opened at a token boundary) and comments are
    skipped.
    """
    depth = 0
    pos = 0
    search = _FLOW_CHARS.search
    while True:
        m = search(text, pos)
        if m is None:
            return -1
        ch, pos = m.group(), m.end()
        before = text[m.start() - 1] if m.start() else "\n"
        if ch == "#" and before in _TOKEN_START:  # comment: skip to end of line
            pos = text.find("\n", pos)
            if pos < 0:
                return -1
        elif ch == "'" and before in _TOKEN_START:  # '...' with '' as escaped quote
            while True:
                pos = text.find("'", pos)
                if pos < 0:
                    return -1
                if text.startswith("''", pos):
                    pos += 2
                    continue
                pos += 1
                break
        elif ch == '"' and before in _TOKEN_START:  # "..." with backslash escapes
            while True:
                nxt = min((i for i in (text.find('"', pos), text.find("\\", pos)) if i >= 0), default=-1)
                if nxt < 0:
                    return -1
                if text[nxt] == "\\":
                    pos = nxt + 2
                    continue
                pos = nxt + 1
                break
        elif ch in "[{":
            depth += 1
            if depth > limit:
                return m.start()
        elif ch in "]}":
            depth = max(0, depth - 1)


def _offset_span(text: str, file: str, pos: int) -> SourceSpan:
    pos = max(0, min(pos, len(text)))
    starts = [0] + [m.end() for m in _LINE_BREAK.finditer(text, 0, pos)]
    return SourceSpan(file, len(starts), pos - starts[-1] + 1)


class _Checker:
    """One pass over the composed tree: tags, keys, duplicates, expanded size."""

    def __init__(self, file: str, max_nodes: int) -> None:
        self.file = file
        self.max_nodes = max_nodes
        self.diags: list[Diagnostic] = []
        self.sizes: dict[int, int] = {}
        self.active: set[int] = set()
        self.recursive = False

    def span(self, node: Node) -> SourceSpan:
        return _span(self.file, node.start_mark)

    def check_tag(self, node: Node) -> None:
        tag = node.tag
        if tag in _SAFE_TAGS or tag == _VALUE_TAG or (tag == _MERGE_TAG and isinstance(node, ScalarNode)):
            return
        self.diags.append(Diagnostic(
            "PHC-E001", f"unsupported YAML tag `{_tag_text(tag)}`", span=self.span(node),
            hint="only plain data is allowed (mappings, lists, strings, numbers, booleans, null); "
                 "remove the tag"))

    def visit(self, node: Node) -> int:
        nid = id(node)
        if nid in self.sizes:
            return self.sizes[nid]
        if nid in self.active:
            if not self.recursive:
                self.recursive = True
                self.diags.append(Diagnostic(
                    "PHC-E003", "document too large (alias expansion): an anchor contains an alias to itself",
                    span=self.span(node), hint="remove the recursive alias"))
            return self.max_nodes + 1
        self.active.add(nid)
        self.check_tag(node)
        total = 1
        if isinstance(node, MappingNode):
            first: dict[Any, Node] = {}
            for key, value in node.value:
                if isinstance(key, ScalarNode) and key.tag == _MERGE_TAG:
                    self.check_merge(value)
                    total += self.visit(value)
                    continue
                if not isinstance(key, ScalarNode):
                    kind = "a mapping" if isinstance(key, MappingNode) else "a list"
                    self.diags.append(Diagnostic(
                        "PHC-E001", f"a mapping key must be a plain value, not {kind}",
                        span=self.span(key), hint="use a string as the key"))
                else:
                    kval = _key_value(key)
                    try:
                        previous = first.get(kval)
                    except TypeError:
                        previous = None
                    if previous is not None:
                        self.diags.append(Diagnostic(
                            "PHC-E002",
                            f"duplicate key `{key.value}`; the first one is at line {_line_col(previous.start_mark)[0] + 1}",
                            span=self.span(key), hint="remove or rename one of them"))
                    else:
                        try:
                            first[kval] = key
                        except TypeError:
                            pass
                total += self.visit(key) + self.visit(value)
        elif isinstance(node, SequenceNode):
            for item in node.value:
                total += self.visit(item)
        self.active.discard(nid)
        total = min(total, self.max_nodes + 1)
        self.sizes[nid] = total
        return total

    def check_merge(self, value: Node) -> None:
        ok = isinstance(value, MappingNode) or (
            isinstance(value, SequenceNode) and all(isinstance(v, MappingNode) for v in value.value))
        if not ok:
            self.diags.append(Diagnostic(
                "PHC-E001", "the merge key `<<` needs a mapping or a list of mappings (usually an alias `*name`)",
                span=self.span(value)))

    def blame_large(self, root: Node) -> Node:
        """The deepest node whose expansion alone exceeds the limit."""
        node = root
        while True:
            for child in _children(node):
                if self.sizes.get(id(child), 0) > self.max_nodes:
                    node = child
                    break
            else:
                return node


_TOO_LARGE = 2 ** 1024
"""Integers from here on do not fit a double (the largest is about 1.8e308)."""
_TOO_LARGE_HINT = "a model's numbers must fit a double (at most about 1.8e308); write it with an exponent, e.g. 1.0e+300"


class _Builder:
    """Builds Python data from checked nodes with SafeLoader semantics (shared aliases)."""

    def __init__(self, file: str) -> None:
        self.file = file
        self.ctor = SafeConstructor()
        self.memo: dict[int, Any] = {}
        self.diags: list[Diagnostic] = []

    def build(self, node: Node) -> Any:
        nid = id(node)
        if nid in self.memo:
            return self.memo[nid]
        if isinstance(node, ScalarNode):
            value = self.scalar(node)
        elif isinstance(node, SequenceNode) and node.tag == _SEQ_TAG:
            value = [self.build(item) for item in node.value]
        elif isinstance(node, MappingNode) and node.tag == _MAP_TAG:
            value = {}
            merged = [v for k, v in node.value if isinstance(k, ScalarNode) and k.tag == _MERGE_TAG]
            for source in merged:
                sources = [source] if isinstance(source, MappingNode) else list(source.value)
                for sub in reversed(sources):  # earlier sources take precedence
                    data = self.build(sub)
                    if isinstance(data, dict):
                        value.update(data)
            for key, item in node.value:
                if isinstance(key, ScalarNode) and key.tag == _MERGE_TAG:
                    continue
                value[self.build(key)] = self.build(item)
        else:  # !!omap, !!pairs, !!set: delegate to PyYAML's safe constructor
            try:
                value = self.ctor.construct_object(node, deep=True)
            except Exception as exc:  # noqa: BLE001
                value = None
                self.error(node, exc)
        self.memo[nid] = value
        return value

    def scalar(self, node: ScalarNode) -> Any:
        if node.tag in (_MERGE_TAG, _VALUE_TAG):
            return node.value
        try:
            value = self.ctor.construct_object(node, deep=True)
        except Exception as exc:  # noqa: BLE001 - e.g. `!!int abc` raises ValueError
            self.error(node, exc)
            return None
        if isinstance(value, int) and not isinstance(value, bool) and abs(value) >= _TOO_LARGE:
            # `0xfff…` or `0b…` of any length: it cannot be a number of the model, and printing it
            # in a message would fail (Python's int_max_str_digits)
            self.diags.append(Diagnostic(
                "PHC-E001", f"integer `{node.value[:20]}…` ({len(node.value)} characters) is too large",
                span=_span(self.file, node.start_mark), hint=_TOO_LARGE_HINT))
            return None
        return value

    def error(self, node: Node, exc: Exception) -> None:
        if node.tag == _YAML_PREFIX + "int" and isinstance(node, ScalarNode) and "digits" in str(exc):
            digits = sum(c.isdigit() for c in node.value)
            self.diags.append(Diagnostic(  # Python refuses to convert integers this long (int_max_str_digits)
                "PHC-E001", f"integer with {digits} digits is too large", span=_span(self.file, node.start_mark),
                hint=_TOO_LARGE_HINT))
            return
        message = f"invalid `{_tag_text(node.tag)}` value"
        if isinstance(node, ScalarNode):
            text = " ".join(node.value.split())
            message += f" `{text[:37] + '...' if len(text) > 40 else text}`"
        problem = getattr(exc, "problem", None)
        if problem:
            message += ": " + " ".join(str(problem).split())
        self.diags.append(Diagnostic(
            "PHC-E001", message, span=_span(self.file, node.start_mark), hint="remove the tag or fix the value"))


def load_yaml(text: str, file: str, *, max_nodes: int = MAX_NODES
              ) -> tuple[object | None, SourceMap | None, list[Diagnostic]]:
    """Parse one YAML document safely and record node positions.

    Parameters
    ----------
    text : str
        The YAML text.
    file : str
        File name used in spans and diagnostics.
    max_nodes : int, optional
        Largest number of nodes the constructed data may have, counting every
        alias expansion (default :data:`MAX_NODES`, guards against "billion laughs").

    Returns
    -------
    data : object or None
        The Python data (SafeLoader semantics: dicts, lists, str, int, float,
        bool, None, dates...).  None for an empty document, or when an error
        prevents construction.  Duplicate keys (``PHC-E002``) alone do not: the
        data is then built with the last occurrence, as PyYAML does.
    smap : SourceMap or None
        Positions of the document's nodes; None when the text does not parse.
    diagnostics : list of Diagnostic
        ``PHC-E001`` syntax errors, unsafe/unknown tags (``!!python/...``),
        non-scalar keys, several documents; ``PHC-E002`` duplicate keys;
        ``PHC-E003`` alias expansion too large or recursive, nesting too deep.

    Notes
    -----
    Only ``yaml.SafeLoader`` composition and ``SafeConstructor`` scalar
    constructors are used, so loading never executes code.
    """
    diags: list[Diagnostic] = []
    deep = _flow_too_deep(text, MAX_FLOW_DEPTH)
    if deep >= 0:
        return None, None, [Diagnostic(
            "PHC-E003", f"document nested too deeply (more than {MAX_FLOW_DEPTH} levels of `[` / `{{`)",
            span=_offset_span(text, file, deep))]
    loader: yaml.SafeLoader | None = None
    try:
        loader = yaml.SafeLoader(text)
        loader.get_event()  # StreamStartEvent
        root: Node | None = None
        if not loader.check_event(StreamEndEvent):
            root = loader.compose_document()
        if not loader.check_event(StreamEndEvent):
            event = loader.peek_event()
            diags.append(Diagnostic(
                "PHC-E001", "the file contains more than one YAML document", span=_span(file, event.start_mark),
                hint="remove the `---` separator; a model file holds exactly one document"))
            return None, SourceMap(file, root), diags
    except yaml.MarkedYAMLError as err:
        return None, None, [_marked_error(err, file)]
    except yaml.reader.ReaderError as err:
        char = err.character if isinstance(err.character, str) else chr(err.character)
        return None, None, [Diagnostic(
            "PHC-E001", f"the file contains a character YAML does not allow (U+{ord(char):04X})",
            span=_offset_span(text, file, err.position), hint="remove the control character")]
    except RecursionError:
        where = SourceSpan(file, 1, 1)
        try:  # where the parser gave up: the deepest point it reached
            where = _span(file, loader.get_mark()) if loader is not None else where
        except Exception:  # noqa: BLE001 - a position is a courtesy; never fail on it
            pass
        return None, None, [Diagnostic(
            "PHC-E003", "document nested too deeply (block mappings or lists inside each other, hundreds "
            "of levels)", span=where, hint="flatten the data; a model needs only a few levels")]
    except yaml.YAMLError as err:
        return None, None, [Diagnostic("PHC-E001", f"YAML error: {' '.join(str(err).split())}",
                                       span=SourceSpan(file, 1, 1))]
    finally:
        if loader is not None:
            loader.dispose()

    smap = SourceMap(file, root)
    if root is None:
        return None, smap, diags

    checker = _Checker(file, max_nodes)
    try:
        size = checker.visit(root)
    except RecursionError:
        diags.append(Diagnostic("PHC-E003", "document nested too deeply", span=_span(file, root.start_mark)))
        return None, smap, diags
    diags.extend(checker.diags)
    if size > max_nodes and not checker.recursive and len(checker.sizes) > max_nodes:
        diags.append(Diagnostic(  # large without aliases: inline data beyond what a model file is for
            "PHC-E003", f"document too large: more than {max_nodes} values",
            span=_span(file, checker.blame_large(root).start_mark),
            hint="put large matrices into an `.npz` file (`matrices:` of a `linear_phs`) and long signals "
                 "into a CSV table"))
    elif size > max_nodes and not checker.recursive:
        diags.append(Diagnostic(
            "PHC-E003", f"document too large (alias expansion): more than {max_nodes} nodes",
            span=_span(file, checker.blame_large(root).start_mark),
            hint="aliases (`*name`) that repeat large anchors multiply the size; write the data out instead"))
    if any(d.code != "PHC-E002" for d in diags):
        return None, smap, diags

    builder = _Builder(file)
    try:
        data = builder.build(root)
    except RecursionError:
        diags.append(Diagnostic("PHC-E003", "document nested too deeply", span=_span(file, root.start_mark)))
        return None, smap, diags
    diags.extend(builder.diags)
    if builder.diags:
        return None, smap, diags
    return data, smap, diags


class _NotRegular(OSError):
    """The named file is not a regular file of acceptable size."""


def _read_regular(path: str | os.PathLike) -> bytes:
    """The bytes of a regular file, opened non-blocking (a FIFO cannot hang the read) and
    at most the model-file size limit of :mod:`phc.files`."""
    import stat as _stat

    from phc.files import size_limit

    flags = os.O_RDONLY | getattr(os, "O_NONBLOCK", 0) | getattr(os, "O_CLOEXEC", 0) | getattr(os, "O_BINARY", 0)
    fd = os.open(path, flags)
    try:
        st = os.fstat(fd)
        if _stat.S_ISDIR(st.st_mode):
            raise IsADirectoryError(21, "it is a directory")
        if not _stat.S_ISREG(st.st_mode):
            raise _NotRegular("it is not a regular file (a FIFO, device or socket); phc reads only regular files")
        limit = size_limit("model")
        if st.st_size > limit:
            raise _NotRegular(f"it is {st.st_size / 2**20:.3g} MiB, above the limit of {limit / 2**20:.3g} MiB "
                              "for a model or scene file")
        with os.fdopen(fd, "rb", closefd=False) as fh:
            data = fh.read(limit + 1)
    finally:
        os.close(fd)
    if len(data) > limit:
        raise _NotRegular(f"it is above the limit of {limit / 2**20:.3g} MiB for a model or scene file")
    return data


def read_yaml_file(path: str | os.PathLike) -> tuple[object | None, SourceMap | None, list[Diagnostic]]:
    """Read a UTF-8 YAML file and load it with :func:`load_yaml`.

    Parameters
    ----------
    path : str or os.PathLike
        The file; ``str(path)`` is used as the file name in diagnostics.

    Returns
    -------
    data, smap, diagnostics
        As :func:`load_yaml`.  A missing/unreadable file or invalid UTF-8 gives
        a single ``PHC-E004`` diagnostic at line 1, column 1 and ``(None, None, ...)``.
    """
    file = str(path)
    where = SourceSpan(file, 1, 1)
    try:
        raw = _read_regular(path)
    except _NotRegular as err:
        return None, None, [Diagnostic("PHC-E004", f"cannot read `{file}`: {err}", span=where,
                                       hint="name a regular model or scene file")]
    except FileNotFoundError:
        return None, None, [Diagnostic("PHC-E004", f"cannot read `{file}`: no such file", span=where,
                                       hint="check the path")]
    except IsADirectoryError:
        return None, None, [Diagnostic("PHC-E004", f"cannot read `{file}`: it is a directory", span=where)]
    except OSError as err:
        reason = err.strerror or str(err)
        return None, None, [Diagnostic("PHC-E004", f"cannot read `{file}`: {reason}", span=where)]
    try:
        text = raw.decode("utf-8-sig")
    except UnicodeDecodeError as err:
        line = raw.count(b"\n", 0, err.start) + 1
        return None, None, [Diagnostic(
            "PHC-E004", f"the file is not valid UTF-8 (byte {raw[err.start]:#04x} on line {line})", span=where,
            hint="save the file with UTF-8 encoding")]
    return load_yaml(text, file)
