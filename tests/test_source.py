"""Tests for :mod:`phc.frontend.source`: safe YAML loading and source positions."""

from __future__ import annotations

import pytest

from phc.frontend import source
from phc.frontend.source import SourceMap, SourceSpan, load_yaml, read_yaml_file

MODEL = """\
# a model
components:
  mass:
    type: mass
    m: 2.5
    parameters:
      - plain
      - 'single'
      - "double"
  spring: {type: spring, k: 10}
connections:
  - [mass.p, spring.p]
"""


def _load(text: str = MODEL, file: str = "m.yaml"):
    data, smap, diags = load_yaml(text, file)
    return data, smap, diags


def test_load_returns_data_and_map():
    data, smap, diags = _load()
    assert diags == []
    assert isinstance(smap, SourceMap)
    assert data["components"]["mass"]["m"] == 2.5
    assert data["connections"] == [["mass.p", "spring.p"]]


@pytest.mark.parametrize(
    "path, line, col",
    [
        (("components",), 3, 3),
        (("components", "mass"), 4, 5),
        (("components", "mass", "m"), 5, 8),
        (("components", "mass", "parameters", 0), 7, 9),
        (("components", "mass", "parameters", 2), 9, 9),
        (("components", "spring", "k"), 10, 29),
        (("connections", 0, 1), 12, 14),
        ("components.mass.m", 5, 8),
        # unresolvable elements (pydantic tags / type names) are skipped
        (("components", "mass", "mass-tag", "m"), 5, 8),
        (("components", "mass", "function-after[check(), Mass]", "m", "float"), 5, 8),
        (("components", "nope"), 3, 3),
        (("components", "mass", "parameters", 99), 7, 7),
        ((), 2, 1),
    ],
)
def test_locate(path, line, col):
    _, smap, _ = _load()
    assert smap.locate(path) == SourceSpan("m.yaml", line, col)


@pytest.mark.parametrize(
    "path, line, col",
    [
        (("components", "mass", "m"), 5, 5),
        (("components", "spring", "k"), 10, 26),
        (("components", "mass", "mass-tag", "type"), 4, 5),
        (("connections", 0), 12, 5),  # list item: falls back to locate
    ],
)
def test_locate_key(path, line, col):
    _, smap, _ = _load()
    assert smap.locate_key(path) == SourceSpan("m.yaml", line, col)


def test_tag_equal_to_key_is_skipped_when_the_rest_resolves():
    text = "components:\n  mass:\n    mass: 1\n    m: 2\n"
    _, smap, _ = _load(text)
    assert smap.locate(("components", "mass", "mass", "m")) == SourceSpan("m.yaml", 4, 8)
    assert smap.resolved_path(("components", "mass", "mass", "m")) == ("components", "mass", "m")


@pytest.mark.parametrize("index, offset", [(0, 0), (1, 1), (2, 1)])
def test_value_offset(index, offset):
    _, smap, _ = _load()
    assert smap.value_offset(("components", "mass", "parameters", index)) == offset


def test_value_offset_block_scalar_and_collections():
    _, smap, _ = _load("a: |\n  x + y\nb: [1]\n")
    assert smap.value_offset(("a",)) == 0
    assert smap.value_offset(("b",)) == 0


def test_value_offset_maps_expression_column():
    text = 'eq: "x + $y"\n'
    _, smap, _ = _load(text)
    span = smap.locate(("eq",))
    col = span.col + smap.value_offset(("eq",)) + "x + $y".index("$")
    assert text.splitlines()[0][col - 1] == "$"


@pytest.mark.parametrize(
    "path, expected",
    [
        (("components", "mass", "m"), True),
        (("components", "mass", "parameters", 1), True),
        (("components", "mass", "mass-tag", "m"), False),
        (("components", "mass", "parameters", 5), False),
        ((), True),
    ],
)
def test_has(path, expected):
    _, smap, _ = _load()
    assert smap.has(path) is expected


def test_int_keys_and_merge_keys():
    text = "table:\n  1: one\n  2: two\nbase: &b {x: 1, y: 2}\nd:\n  <<: *b\n  y: 3\n"
    data, smap, diags = _load(text)
    assert diags == []
    assert data["table"] == {1: "one", 2: "two"}
    assert data["d"] == {"x": 1, "y": 3}
    assert smap.locate(("table", 2)) == SourceSpan("m.yaml", 3, 6)
    assert smap.locate(("d", "y")) == SourceSpan("m.yaml", 7, 6)
    assert smap.locate(("d", "x")) == SourceSpan("m.yaml", 4, 14)  # merged value: at the anchor


def test_anchors_and_aliases_are_allowed():
    data, _, diags = _load("a: &v [1, 2]\nb: *v\n")
    assert diags == []
    assert data == {"a": [1, 2], "b": [1, 2]}


def test_duplicate_key():
    text = "components:\n  x: 1\n\n  mass: {}\n  mass: {m: 1}\n"
    data, _, diags = _load(text)
    assert [d.code for d in diags] == ["PHC-E002"]
    d = diags[0]
    assert d.message == "duplicate key `mass`; the first one is at line 4"
    assert d.hint == "remove or rename one of them"
    assert (d.span.line, d.span.col) == (5, 3)
    assert data == {"components": {"x": 1, "mass": {"m": 1}}}  # last one wins, as in PyYAML


def test_all_duplicates_are_collected():
    _, _, diags = _load("a: 1\nb: {c: 1, c: 2}\na: 3\n")
    assert sorted((d.span.line, d.span.col) for d in diags) == [(2, 11), (3, 1)]
    assert {d.code for d in diags} == {"PHC-E002"}


@pytest.mark.parametrize(
    "text, line, col",
    [
        ("a: [1, 2\nb: 3\n", 2, 2),
        ("a:\n  b: 1\n c: 2\n", 3, 2),
        ("a: 1\n\tb: 2\n", 2, 1),
        ("a: *nothing\n", 1, 4),
    ],
)
def test_syntax_error_positioned(text, line, col):
    data, smap, diags = _load(text)
    assert data is None and smap is None
    assert len(diags) == 1
    assert diags[0].code == "PHC-E001"
    assert (diags[0].span.line, diags[0].span.col) == (line, col)
    assert "\n" not in diags[0].render()


def test_python_tag_is_refused_without_executing(tmp_path, monkeypatch):
    import os
    import subprocess

    called = []
    monkeypatch.setattr(os, "system", lambda *a: called.append(a) or 0)
    monkeypatch.setattr(subprocess, "Popen", lambda *a, **k: called.append(a))
    marker = tmp_path / "pwned"
    text = f"a: 1\nb: !!python/object/apply:os.system ['touch {marker}']\nc: !!python/name:os.system\n"
    data, _, diags = _load(text)
    assert data is None
    assert called == [] and not marker.exists()
    assert [(d.code, d.span.line, d.span.col) for d in diags] == [("PHC-E001", 2, 4), ("PHC-E001", 3, 4)]
    assert "python/object/apply:os.system" in diags[0].message


def test_invalid_value_for_standard_tag():
    data, _, diags = _load("a: !!int abc\n")
    assert data is None
    assert [(d.code, d.span.line, d.span.col) for d in diags] == [("PHC-E001", 1, 4)]


def test_non_scalar_key():
    data, _, diags = _load("? [1, 2]\n: 3\n")
    assert data is None
    assert [(d.code, d.span.line) for d in diags] == [("PHC-E001", 1)]


def test_billion_laughs_stopped_without_expanding(monkeypatch):
    """9**10 nodes after expansion: the size check visits each node and each alias of the text
    once (an alias reuses its anchor's size) and nothing is built (counted, not timed)."""
    lines = ['a: &a ["lol","lol","lol","lol","lol","lol","lol","lol","lol"]']
    for i in range(1, 10):
        prev, cur = chr(ord("a") + i - 1), chr(ord("a") + i)
        lines.append(f"{cur}: &{cur} [" + ",".join([f"*{prev}"] * 9) + "]")
    visits = []
    visit = source._Checker.visit

    def counting_visit(self, node):
        visits.append(id(node))   # ids: a node's repr would expand the bomb
        count = len(visits)
        assert count <= 111, "the size check expands aliases"   # fails here rather than hang
        return visit(self, node)

    def no_build(self, node):
        raise AssertionError("an alias bomb must not be built")

    monkeypatch.setattr(source._Checker, "visit", counting_visit)
    monkeypatch.setattr(source._Builder, "build", no_build)
    data, _, diags = _load("\n".join(lines) + "\n")
    distinct = len(set(visits))   # 1 root + 10 keys + 10 lists + 9 strings; + 81 aliases = 111 visits
    assert distinct == 30
    assert data is None
    assert [d.code for d in diags] == ["PHC-E003"]
    assert diags[0].message.startswith("document too large (alias expansion)")


def test_recursive_alias_rejected():
    data, _, diags = _load("a: &x [1, *x]\n")
    assert data is None
    assert [d.code for d in diags] == ["PHC-E003"]


def test_multiple_documents_rejected():
    data, _, diags = _load("a: 1\n---\nb: 2\n")
    assert data is None
    assert [(d.code, d.span.line) for d in diags] == [("PHC-E001", 2)]


@pytest.mark.parametrize("text", ["", "# only a comment\n", "---\n"])
def test_empty_document(text):
    data, smap, diags = _load(text)
    assert data is None and diags == []
    assert isinstance(smap, SourceMap)
    assert smap.locate(("x",)).line in (1, 2)


def test_control_character():
    data, _, diags = _load("a: 1\nb: \x07\n")
    assert data is None
    assert [(d.code, d.span.line, d.span.col) for d in diags] == [("PHC-E001", 2, 4)]


def test_read_yaml_file(tmp_path):
    path = tmp_path / "model.yaml"
    path.write_text("a:\n  b: 1\n", encoding="utf-8")
    data, smap, diags = read_yaml_file(path)
    assert diags == [] and data == {"a": {"b": 1}}
    assert smap.locate(("a", "b")) == SourceSpan(str(path), 2, 6)


def test_read_yaml_file_with_bom(tmp_path):
    path = tmp_path / "bom.yaml"
    path.write_bytes(b"\xef\xbb\xbfa: 1\n")
    data, smap, diags = read_yaml_file(path)
    assert data == {"a": 1} and smap.locate(("a",)).col == 4


def test_missing_file(tmp_path):
    path = tmp_path / "nope.yaml"
    data, smap, diags = read_yaml_file(path)
    assert data is None and smap is None
    assert [(d.code, d.span.file, d.span.line, d.span.col) for d in diags] == [("PHC-E004", str(path), 1, 1)]
    assert "nope.yaml" in diags[0].message


def test_not_utf8(tmp_path):
    path = tmp_path / "latin.yaml"
    path.write_bytes(b"a: 1\nb: caf\xe9\n")
    data, _, diags = read_yaml_file(path)
    assert data is None
    assert [(d.code, d.span.line, d.span.col) for d in diags] == [("PHC-E004", 1, 1)]
    assert "UTF-8" in diags[0].message


def test_span_str():
    assert str(SourceSpan("a/b.yaml", 3, 7)) == "a/b.yaml:3:7"


def test_deep_flow_nesting_stopped_before_parsing(monkeypatch):
    """PyYAML's scanner is quadratic in the flow nesting depth: absurd nesting is refused
    by a linear scan of the text, before the YAML parser is even created."""
    def no_parser(*args, **kwargs):
        raise AssertionError("the YAML parser must not see absurd nesting")

    monkeypatch.setattr(source.yaml, "SafeLoader", no_parser)
    data, _, diags = _load("a: " + "[" * 5000 + "]" * 5000 + "\n")
    assert data is None
    assert [(d.code, d.span.line) for d in diags] == [("PHC-E003", 1)]


def test_brackets_in_quotes_and_comments_are_not_nesting():
    text = "a: '" + "[" * 300 + "'\nb: \"" + "{" * 300 + "\"  # " + "[" * 300 + "\n"
    data, _, diags = _load(text)
    assert diags == [] and data["a"] == "[" * 300
