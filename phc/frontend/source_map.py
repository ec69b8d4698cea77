"""Source positions of a YAML document: :class:`SourceSpan` and :class:`SourceMap`.

A :class:`SourceMap` knows the file position of every node of one composed YAML document
and answers, for a path such as ``("components", "mass", "m")`` (or a pydantic error
location), where its value, its key or a character inside its (folded) string value is,
so that every later stage can report a problem as ``file:line:col: message [CODE]``.

The loading itself — safe composition, the checks of tags, keys, duplicates and sizes, and
building the Python data — is :mod:`phc.frontend.source`, which makes the :class:`SourceMap` of each
document it loads; the names here are importable from :mod:`phc.frontend.source` as well.
"""

from __future__ import annotations

import bisect
import re
from dataclasses import dataclass
from typing import Any, Sequence, Union

from yaml.constructor import SafeConstructor
from yaml.nodes import MappingNode, Node, ScalarNode, SequenceNode

from phc.inert import inert

__all__ = ["PathElem", "SourceMap", "SourceSpan", "path_text"]

PathElem = Union[str, int]


def path_text(path: Sequence[PathElem]) -> str | None:
    """A YAML path as every message shows it: keys joined by dots, list positions in
    brackets (``connections[7][1]``, ``components.gyro.K[0][1]``); None for the root."""
    out = ""
    for elem in path:
        if isinstance(elem, int) and not isinstance(elem, bool):
            out += f"[{elem}]"
        else:
            out += ("." if out else "") + str(elem)
    return out or None

_YAML_PREFIX = "tag:yaml.org,2002:"
_MAP_TAG = _YAML_PREFIX + "map"
_SEQ_TAG = _YAML_PREFIX + "seq"
_STR_TAG = _YAML_PREFIX + "str"
_MERGE_TAG = _YAML_PREFIX + "merge"
_VALUE_TAG = _YAML_PREFIX + "value"


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
        """``file:line:col``, the file name made inert (:func:`phc.inert.inert`: no control
        characters, no workflow command at the start of a line)."""
        return inert(f"{self.file}:{self.line}:{self.col}")


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
        self._located: dict[tuple, SourceSpan] = {}  # locate() by path: lowerers ask several times

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
        # The common case first: every element resolves in turn. No way of skipping resolves
        # more elements, so this walk is the best one (linear, no memo of the search).
        node, steps = self.root, []
        for i, elem in enumerate(path):
            entry = self._child(node, elem)
            if entry is None:
                break
            steps.append((i, entry))
            node = entry.value
        else:
            return steps
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
        norm = path if type(path) is tuple else self._norm(path)
        key = (norm, tuple(map(type, norm)))  # 1 and True are different elements
        try:
            hit = self._located.get(key)
        except TypeError:  # unhashable path element
            return self._node_span(self.node(norm))
        if hit is None:
            hit = self._located[key] = self._node_span(self.node(norm))
        return hit

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

    def dotted(self, path: Sequence[PathElem] | str) -> str | None:
        """`path` as the user wrote it, in the style of :func:`path_text`: an element the
        file does not have is left out where later ones resolve (``between`` of a connection
        written ``- [a.p, b.q]``: ``connections[7][1]``); the elements after the last one
        that resolves are kept (a key the file lacks), unless that one is a scalar (the
        entry ``[0]`` of a vector written as one number)."""
        norm = self._norm(path)
        steps = self._resolve(norm)
        if not steps:
            return path_text(norm)
        resolved = {i for i, _ in steps}
        last = steps[-1][0] if not isinstance(steps[-1][1].value, ScalarNode) else len(norm)
        return path_text([elem for i, elem in enumerate(norm) if i in resolved or i > last])

    def __repr__(self) -> str:
        return f"SourceMap({self.file!r})"
