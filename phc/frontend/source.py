"""Safe YAML loading with source positions.

Model files are parsed with PyYAML's *safe* machinery only (no tag can run
code).  Besides the plain Python data, :func:`load_yaml` returns a
:class:`SourceMap` that knows the file position of every node, so later stages
(pydantic validation, elaboration) can report each problem as one line
``file:line:col: message [CODE]``.  Loader problems (syntax errors, duplicate
keys, unsafe tags, alias bombs, unreadable files) are returned as
:class:`~phc.diagnostics.Diagnostic` objects, never raised.

Where what lives: this module is the loading — reading a file (:func:`read_yaml_file`),
parsing and composing it, the one pass that checks tags, keys, duplicates and the expanded
size (``_Checker``) and building the data (``_Builder``). The positions —
:class:`SourceSpan`, :class:`SourceMap` and the line/column counting they share with the
loader's messages — are :mod:`phc.frontend.source_map`; they are importable from here as well.
The module is a little over 800 lines because the composition of libyaml's events makes some
of ``_Checker``'s checks itself (issue 38), and the two must be read side by side.
"""

from __future__ import annotations

import copy
import hashlib
import os
import re
import threading
from typing import Any, Iterator

import yaml
from yaml.constructor import SafeConstructor
from yaml.events import (AliasEvent, MappingEndEvent, MappingStartEvent, ScalarEvent, SequenceEndEvent,
                         SequenceStartEvent, StreamEndEvent)
from yaml.nodes import MappingNode, Node, ScalarNode, SequenceNode

from phc.diagnostics import Diagnostic
# the positions (phc.frontend.source_map), every name of theirs importable from here as before
from phc.frontend.source_map import (_LINE_BREAK, _LINE_STARTS, _MAP_TAG, _MERGE_TAG, _SEQ_TAG, _STR_TAG,  # noqa: F401
                            _VALUE_TAG, _YAML_PREFIX, PathElem, SourceMap, SourceSpan, _Entry, _key_value, _line_col,
                            _span)

__all__ = [
    "FAST_MIN_CHARS",
    "MAX_FLOW_DEPTH",
    "MAX_NODES",
    "MAX_VALUES",
    "PathElem",
    "SourceMap",
    "SourceSpan",
    "load_yaml",
    "read_yaml_file",
]

MAX_NODES = 100_000
"""Most nodes that aliases may add to a document by expansion (its "billion laughs" guard)."""

MAX_VALUES = 500_000
"""Most nodes a document may hold as written (a model of about 3·10⁴ lumped components;
large matrices and signals belong in `.npz` and CSV files)."""

MAX_FLOW_DEPTH = 200
"""Deepest nesting of flow collections (``[...]``, ``{...}``) accepted."""

FAST_MIN_CHARS = 1 << 16
"""Documents of at least this many characters are parsed by libyaml (PyYAML's C parser,
about 10× faster than its pure-Python one: a model of 10⁴ lumped components is about
130 000 nodes) when PyYAML was built with it; smaller ones, and any document libyaml
refuses, by the pure-Python parser (see :func:`_fast_compose`)."""

_SAFE_TAGS = frozenset(t for t in SafeConstructor.yaml_constructors
                       if t is not None and t != _YAML_PREFIX + "binary")  # bytes are no model data


def _tag_text(tag: str | None) -> str:
    if tag is None:
        return "?"
    if tag.startswith(_YAML_PREFIX):
        return "!!" + tag[len(_YAML_PREFIX):]
    return tag


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

    def __init__(self, file: str, max_nodes: int, max_values: int) -> None:
        self.file = file
        self.max_nodes = max_nodes
        self.cap = max_nodes + max_values + 1  # sizes saturate here (aliases could make them astronomic)
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
            return self.cap
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
        total = min(total, self.cap)
        self.sizes[nid] = total
        return total

    def check_merge(self, value: Node) -> None:
        ok = isinstance(value, MappingNode) or (
            isinstance(value, SequenceNode) and all(isinstance(v, MappingNode) for v in value.value))
        if not ok:
            self.diags.append(Diagnostic(
                "PHC-E001", "the merge key `<<` needs a mapping or a list of mappings (usually an alias `*name`)",
                span=self.span(value)))

    def blame_large(self, root: Node, limit: int) -> Node:
        """The deepest node whose expansion alone exceeds `limit`."""
        node = root
        while True:
            for child in _children(node):
                if self.sizes.get(id(child), 0) > limit:
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

    def build_plain(self, root: Node) -> Any:
        """:meth:`build` of a plain document (:func:`_fast_compose`: no alias, so no node is
        met twice, no merge key, only string keys, none twice in a mapping, nested less than
        :data:`_FAST_MAX_DEPTH` levels): the same data, without the memo of shared nodes and
        the search for merge keys (issue 38: a fifth of loading a chain of 10⁴ components)."""
        scalar, build = self.scalar, self.build
        str_tag, seq_tag, map_tag = _STR_TAG, _SEQ_TAG, _MAP_TAG

        def plain(node):
            kind = type(node)
            if kind is ScalarNode:
                return node.value if node.tag == str_tag else scalar(node)
            if kind is MappingNode and node.tag == map_tag:
                value = {}
                for key, item in node.value:  # as build() does: the item first, then the key
                    built = plain(item)
                    value[plain(key)] = built
                return value
            if kind is SequenceNode and node.tag == seq_tag:
                return [plain(item) for item in node.value]
            return build(node)  # !!omap, !!pairs, !!set, a subclass of a node: as build() does

        return plain(root)

    def scalar(self, node: ScalarNode) -> Any:
        if node.tag in (_MERGE_TAG, _VALUE_TAG, _STR_TAG):  # a string as written (SafeConstructor's `str`)
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


_LIBYAML = bool(getattr(yaml, "__with_libyaml__", False)) and hasattr(yaml, "CSafeLoader")


class _TextMark:
    """A position in the text for a node composed from libyaml's events: its character
    offset (libyaml counts characters, as Python's `str` does) and the text, from which
    :func:`phc.frontend.source_map._line_col` counts lines (LF, CR, CRLF) as for PyYAML's marks."""

    __slots__ = ("index", "buffer")
    name = "<unicode string>"

    def __init__(self, index: int, buffer: str) -> None:
        self.index = index
        self.buffer = buffer

    @property
    def pointer(self) -> int:
        return self.index

    @property
    def line(self) -> int:
        return _line_col(self)[0]

    @property
    def column(self) -> int:
        return _line_col(self)[1]


_SLOW_SAID = False


def _fast_compose(text: str) -> tuple[bool, Node | None, int | None]:
    """``(True, root, plain)`` of the one document in `text` composed from libyaml's events
    (root None for an empty document); ``(False, None, None)`` when libyaml is not available
    or the text is anything but one well-formed document without a duplicate or undefined
    anchor: the pure-Python parser then parses it again, so every error message and
    position is the same whichever parser ran first. `plain` is the number of nodes of a
    document that the checks of ``_Checker`` would pass without a word (no alias, no merge
    key, only safe tags, only string keys, none twice in a mapping), None for any other:
    ``_Checker`` then walks it (issue 38: its walk was a quarter of loading a chain of 10⁴
    components).

    libyaml scans and parses (in C, with explicit stacks); the nodes are composed here,
    without recursion, with PyYAML's resolver (the tags of plain scalars, remembered per
    text), as PyYAML's composer makes them: the same nodes, tags, styles and aliases
    (libyaml's own composer recurses in C, so a document nested thousands of levels
    deep could overflow the C stack)."""
    global _SLOW_SAID
    if not _LIBYAML:
        if not _SLOW_SAID:
            _SLOW_SAID = True
            import warnings

            from phc.errors import PhcWarning

            warnings.warn(f"PyYAML was built without libyaml: large model files ({len(text):,} characters here) are "
                          "parsed by its pure-Python parser, several times slower; install PyYAML with libyaml "
                          "(e.g. the wheel from PyPI) for faster loading", PhcWarning, stacklevel=3)
        return False, None, None
    loader = yaml.CSafeLoader(text)
    try:
        return _compose_events(loader, text)
    except (yaml.YAMLError, ValueError, TypeError, AttributeError, IndexError):
        return False, None, None
    finally:
        loader.dispose()


_FAST_MAX_DEPTH = 100
"""Deeper collections are left to the pure-Python parser (a model needs a few levels)."""


def _compose_events(loader, text: str) -> tuple[bool, Node | None, int | None]:
    get_event, check_event = loader.get_event, loader.check_event
    reference = yaml.SafeLoader("")  # its resolver: the very tags the pure-Python parser gives
    resolve = reference.resolve
    if reference.yaml_path_resolvers:  # someone added path resolvers to PyYAML: its composer, not this one
        return False, None, None
    get_event()  # StreamStartEvent
    if check_event(StreamEndEvent):
        return True, None, 0
    get_event()  # DocumentStartEvent
    plain: dict[str, str] = {}  # a plain scalar's text -> its resolved tag
    anchors: dict[str, Node] = {}
    stack: list[list] = []  # [collection node, mapping key waiting for its value, keys seen (mappings)]
    root: Node | None = None
    count, clean = 0, True  # nodes, and whether _Checker would pass them all without a word
    while True:
        event = get_event()
        kind = type(event)
        if kind is ScalarEvent or kind is SequenceStartEvent or kind is MappingStartEvent:
            tag, anchor = event.tag, event.anchor
            if anchor is not None and anchor in anchors:
                return False, None, None  # duplicate anchor: PyYAML's composer reports it
            start = _TextMark(event.start_mark.index, text)
            if kind is ScalarEvent:
                value = event.value
                if tag is None or tag == "!":
                    if event.implicit[0]:
                        tag = plain.get(value)
                        if tag is None:
                            tag = plain[value] = resolve(ScalarNode, value, event.implicit)
                    else:
                        tag = resolve(ScalarNode, value, event.implicit)
                node: Node = ScalarNode(tag, value, start, _TextMark(event.end_mark.index, text),
                                        style=event.style or None)
            elif kind is SequenceStartEvent:
                if tag is None or tag == "!":
                    tag = resolve(SequenceNode, None, event.implicit)
                node = SequenceNode(tag, [], start, None, flow_style=event.flow_style)
            else:
                if tag is None or tag == "!":
                    tag = resolve(MappingNode, None, event.implicit)
                node = MappingNode(tag, [], start, None, flow_style=event.flow_style)
            if anchor is not None:
                anchors[anchor] = node
            count += 1
            if clean and node.tag not in _SAFE_TAGS:  # what _Checker.check_tag refuses (and !!value, <<)
                clean = False
        elif kind is AliasEvent:
            clean = False  # sizes with aliases: _Checker counts them
            node = anchors.get(event.anchor)
            if node is None:
                return False, None, None  # undefined alias: PyYAML's composer reports it
        elif kind is SequenceEndEvent or kind is MappingEndEvent:
            node = stack.pop()[0]
            node.end_mark = _TextMark(event.end_mark.index, text)
            if not stack:
                root = node
                break
            top = stack[-1]
            if top[1] is None and top[2] is not None:
                clean = False  # a collection as a mapping's key (_Checker refuses it)
            _attach(top, node)
            continue
        else:
            return False, None
        if kind is SequenceStartEvent or kind is MappingStartEvent:
            if len(stack) >= _FAST_MAX_DEPTH:
                return False, None, None  # nested very deeply: the pure-Python parser says where it gave up
            stack.append([node, None, set() if kind is MappingStartEvent else None])
        elif stack:
            top = stack[-1]
            if clean and top[1] is None and top[2] is not None:  # a mapping's key
                # a string key not seen before in this mapping; anything else (a key that is
                # a number or a collection, twice the same) is left to _Checker
                if node.tag != _STR_TAG or type(node) is not ScalarNode or node.value in top[2]:
                    clean = False
                else:
                    top[2].add(node.value)
            _attach(top, node)
        else:
            root = node
        if not stack:
            break
    get_event()  # DocumentEndEvent
    if not check_event(StreamEndEvent):
        return False, None, None  # more than one document: reported by the pure-Python parser
    return True, root, count if clean else None


def _attach(top: list, node: Node) -> None:
    """Add `node` to the collection being composed (a mapping takes key, then value)."""
    parent = top[0]
    if isinstance(parent, SequenceNode):
        parent.value.append(node)
    elif top[1] is None:
        top[1] = node
    else:
        parent.value.append((top[1], node))
        top[1] = None


def load_yaml(text: str, file: str, *, max_nodes: int = MAX_NODES, max_values: int = MAX_VALUES
              ) -> tuple[object | None, SourceMap | None, list[Diagnostic]]:
    """Parse one YAML document safely and record node positions.

    Parameters
    ----------
    text : str
        The YAML text.
    file : str
        File name used in spans and diagnostics.
    max_nodes : int, optional
        Most nodes that alias expansion may add to the document (default
        :data:`MAX_NODES`, guards against "billion laughs").
    max_values : int, optional
        Most nodes the document may hold as written (default :data:`MAX_VALUES`).

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
    constructors are used, so loading never executes code. A document of at least
    :data:`FAST_MIN_CHARS` characters is scanned and parsed by libyaml when PyYAML has
    it (the same events, composed by PyYAML's composer; see :func:`_fast_compose`).
    """
    diags: list[Diagnostic] = []
    deep = _flow_too_deep(text, MAX_FLOW_DEPTH)
    if deep >= 0:
        return None, None, [Diagnostic(
            "PHC-E003", f"document nested too deeply (more than {MAX_FLOW_DEPTH} levels of `[` / `{{`)",
            span=_offset_span(text, file, deep))]
    fast, root, plain = _fast_compose(text) if len(text) >= FAST_MIN_CHARS else (False, None, None)
    if not fast:
        root, diags = _compose(text, file)
        if root is _FAILED:
            return None, None, diags
        if diags:
            return None, SourceMap(file, root), diags
    return _checked(root, file, diags, max_nodes, max_values, plain)


_FAILED = object()


def _compose(text: str, file: str) -> tuple[Any, list[Diagnostic]]:
    """The one document in `text` composed by PyYAML's pure-Python parser: ``(root, [])``,
    ``(root, [more than one document])`` or ``(_FAILED, [the error])``."""
    diags: list[Diagnostic] = []
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
            return root, diags
    except yaml.MarkedYAMLError as err:
        return _FAILED, [_marked_error(err, file)]
    except yaml.reader.ReaderError as err:
        char = err.character if isinstance(err.character, str) else chr(err.character)
        return _FAILED, [Diagnostic(
            "PHC-E001", f"the file contains a character YAML does not allow (U+{ord(char):04X})",
            span=_offset_span(text, file, err.position), hint="remove the control character")]
    except RecursionError:
        where = SourceSpan(file, 1, 1)
        try:  # where the parser gave up: the deepest point it reached
            where = _span(file, loader.get_mark()) if loader is not None else where
        except Exception:  # noqa: BLE001 - a position is a courtesy; never fail on it
            pass
        return _FAILED, [Diagnostic(
            "PHC-E003", "document nested too deeply (block mappings or lists inside each other, hundreds "
            "of levels)", span=where, hint="flatten the data; a model needs only a few levels")]
    except yaml.YAMLError as err:
        return _FAILED, [Diagnostic("PHC-E001", f"YAML error: {' '.join(str(err).split())}",
                                    span=SourceSpan(file, 1, 1))]
    finally:
        if loader is not None:
            loader.dispose()
    return root, diags


def _checked(root: Node | None, file: str, diags: list[Diagnostic], max_nodes: int, max_values: int,
             plain: int | None = None) -> tuple[object | None, SourceMap | None, list[Diagnostic]]:
    """The data of a composed document, after the checks of tags, keys, duplicates and
    sizes. `plain`: the number of nodes of a document the composition found to pass those
    checks (:func:`_fast_compose`), None when not known: then ``_Checker`` walks it."""
    smap = SourceMap(file, root)
    if root is None:
        return None, smap, diags
    if plain is not None and plain <= max_values and not diags:
        return _built(root, file, smap, diags, plain=True)

    checker = _Checker(file, max_nodes, max_values)
    try:
        size = checker.visit(root)
    except RecursionError:
        diags.append(Diagnostic("PHC-E003", "document nested too deeply", span=_span(file, root.start_mark)))
        return None, smap, diags
    diags.extend(checker.diags)
    written = len(checker.sizes)  # the distinct nodes; `size` counts each alias's expansion again
    if written > max_values and not checker.recursive:
        diags.append(Diagnostic(  # large without aliases: inline data beyond what a model file is for
            "PHC-E003", f"document too large: more than {max_values} values",
            span=_span(file, checker.blame_large(root, max_values).start_mark),
            hint="put large matrices into an `.npz` file (`matrices:` of a `linear_phs`) and long signals "
                 "into a CSV table"))
    elif size - written > max_nodes and not checker.recursive:
        diags.append(Diagnostic(
            "PHC-E003", f"document too large (alias expansion): more than {max_nodes} nodes",
            span=_span(file, checker.blame_large(root, max_nodes).start_mark),
            hint="aliases (`*name`) that repeat large anchors multiply the size; write the data out instead"))
    if any(d.code != "PHC-E002" for d in diags):
        return None, smap, diags
    return _built(root, file, smap, diags)


def _built(root: Node, file: str, smap: SourceMap, diags: list[Diagnostic], plain: bool = False
           ) -> tuple[object | None, SourceMap | None, list[Diagnostic]]:
    """The Python data of a checked document (:class:`_Builder`); `plain`: a document the
    composition found plain (:func:`_fast_compose`), built by :meth:`_Builder.build_plain`."""
    builder = _Builder(file)
    try:
        data = builder.build_plain(root) if plain else builder.build(root)
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
    at most the model-file size limit of :mod:`phc.frontend.files`."""
    import stat as _stat

    from phc.frontend.files import size_limit

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


PARSED_KEPT = 4
"""How many parsed files :func:`read_yaml_file` keeps (the most recently read)."""
_PARSED: dict[bytes, tuple[str, tuple]] = {}
_PARSED_LOCK = threading.Lock()


def read_yaml_file(path: str | os.PathLike) -> tuple[object | None, SourceMap | None, list[Diagnostic]]:
    """Read a UTF-8 YAML file and load it with :func:`load_yaml`.

    A run reads its model file several times (is it a scene? the model itself, where its
    outputs are written); the file is parsed once: the last :data:`PARSED_KEPT` files parsed
    are kept by their content (a changed file is parsed again), and each caller gets
    its own copy of the data (the source map, read-only, is shared).

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
    data, smap, diags = _read_parsed(path)
    if data is not None and not isinstance(data, (str, int, float, bool)):
        data = _copy_data(data)
    return data, smap, list(diags)


_IMMUTABLE = (str, int, float, bool, type(None))


def _copy_data(data, memo=None):
    """``copy.deepcopy`` of loaded YAML data: its mappings and sequences copied (one copy of
    a collection met twice through an alias, as deepcopy), its scalars shared (immutable);
    anything else deep-copied (measured: 0.09 s against deepcopy's 0.14 s for the chain of 10⁴
    components of benchmarks/bench_components.py)."""
    if memo is None:
        memo = {}
    t = type(data)
    if t is dict or t is list:
        hit = memo.get(id(data))
        if hit is not None:
            return hit
        if t is dict:
            out = memo[id(data)] = {}
            for k, v in data.items():
                out[k if type(k) in _IMMUTABLE else copy.deepcopy(k)] = v if type(v) in _IMMUTABLE else _copy_data(v, memo)
        else:
            out = memo[id(data)] = []
            out.extend(v if type(v) in _IMMUTABLE else _copy_data(v, memo) for v in data)
        return out
    if t in _IMMUTABLE:
        return data
    return copy.deepcopy(data)


def _read_parsed(path: str | os.PathLike) -> tuple[object | None, SourceMap | None, list[Diagnostic]]:
    """:func:`read_yaml_file` without the copy: the data is shared with other callers and
    must not be changed (for phc's own read-only looks, e.g. whether a file is a scene)."""
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
    key = hashlib.sha256(raw).digest()
    with _PARSED_LOCK:
        kept = _PARSED.pop(key, None)
    if kept is None:
        kept = (file, load_yaml(text, file))
    with _PARSED_LOCK:
        _PARSED.pop(key, None)
        while len(_PARSED) >= PARSED_KEPT:
            _PARSED.pop(next(iter(_PARSED)))
        _PARSED[key] = kept  # the most recent last
    return kept[1] if kept[0] == file else _named(kept[1], kept[0], file)


def _named(parsed: tuple, old: str, file: str) -> tuple:
    """A parse of the same text under another file name (``./m.yaml`` and ``m.yaml``): the
    positions it reports name `file`."""
    import dataclasses

    data, smap, diags = parsed
    diags = [dataclasses.replace(d, span=dataclasses.replace(d.span, file=file))
             if d.span is not None and d.span.file == old else d for d in diags]
    return data, (SourceMap(file, smap.root) if smap is not None else None), diags
