"""Tests for :mod:`phc.diagnostics`: one-line diagnostics and pydantic error conversion."""

from __future__ import annotations

import json
import re
from typing import Annotated, Literal, Union

import pytest
from pydantic import BaseModel, ConfigDict, Field, ValidationError, field_validator
from pydantic_core import PydanticCustomError

from phc.diagnostics import (
    ERROR_CODES,
    Diagnostic,
    DiagnosticList,
    allowed_keys_from_model,
    from_pydantic,
)
from phc.frontend.source import SourceSpan, load_yaml

LINE_RE = re.compile(r"^file\.yaml:\d+:\d+: ")


class Strict(BaseModel):
    model_config = ConfigDict(extra="forbid", allow_inf_nan=False)


class Mass(Strict):
    type: Literal["mass"]
    m: float
    kind: Literal["point", "rigid"] = "point"


class Spring(Strict):
    type: Literal["spring"]
    k: float
    steps: int = 1

    @field_validator("k")
    @classmethod
    def _positive(cls, value: float) -> float:
        if value <= 0:
            raise ValueError("stiffness `k` must be positive")
        return value


class Model(Strict):
    components: dict[str, Annotated[Union[Mass, Spring], Field(discriminator="type")]]
    count: int = 0
    size: int | list[int] = 0
    label: str = ""


def _diagnose(text: str, **kwargs) -> list[Diagnostic]:
    data, smap, problems = load_yaml(text, "file.yaml")
    assert problems == []
    with pytest.raises(ValidationError) as info:
        Model.model_validate(data)
    return from_pydantic(info.value, smap, **kwargs)


def _single(text: str, **kwargs) -> Diagnostic:
    diags = _diagnose(text, **kwargs)
    assert len(diags) == 1, [d.render() for d in diags]
    return diags[0]


@pytest.mark.parametrize(
    "text, code, line, col, prefix, path",
    [
        # unknown key, located at the key
        ("components:\n  a:\n    type: mass\n    m: 1\n    mm: 2\n",
         "PHC-E010", 5, 5, "unknown key `mm`", "components.a.mm"),
        ("components: {}\ncount: 1\ncuont: 2\n", "PHC-E010", 3, 1, "unknown key `cuont`", "cuont"),
        # missing key: at the mapping that lacks it
        ("components:\n  a:\n    type: mass\n", "PHC-E011", 3, 5, "missing required key `m`", "components.a"),
        # .inf from YAML
        ("components:\n  a:\n    type: mass\n    m: .inf\n",
         "PHC-E012", 4, 8, "number must be finite (no .inf/.nan)", "components.a.m"),
        ("components:\n  a: {type: spring, k: .nan}\n", "PHC-E012", 2, 24, "number must be finite", "components.a.k"),
        # wrong types
        ("components: {}\ncount: many\n", "PHC-E013", 2, 8, "expected an integer, got string `'many'`", "count"),
        ("components:\n  a: {type: mass, m: [1]}\n", "PHC-E013", 2, 22, "expected a number, got list", "components.a.m"),
        ("components: [1, 2]\n", "PHC-E013", 1, 13, "expected a mapping, got list", "components"),
        ("components:\n  a: {type: spring, k: 1, steps: 1.5}\n", "PHC-E013", 2, 34, "expected an integer",
         "components.a.steps"),
        # bad discriminator tag, located at the tag value
        ("components:\n  a:\n    type: masss\n    m: 1\n",
         "PHC-E014", 3, 11, "unknown type `masss`; expected one of `mass`, `spring`", "components.a"),
        ("components:\n  a:\n    m: 1\n", "PHC-E014", 3, 5, "missing key `type`", "components.a"),
        # literal
        ("components:\n  a: {type: mass, m: 1, kind: 'rigd'}\n",
         "PHC-E015", 2, 31, "invalid value `rigd`; expected one of `point`, `rigid`", "components.a.kind"),
        # custom validator
        ("components:\n  a: {type: spring, k: -1}\n", "PHC-E016", 2, 24, "stiffness `k` must be positive",
         "components.a.k"),
    ],
)
def test_from_pydantic_codes_and_positions(text, code, line, col, prefix, path):
    d = _single(text)
    assert d.code == code
    assert (d.span.file, d.span.line, d.span.col) == ("file.yaml", line, col)
    assert d.message.startswith(prefix), d.message
    assert d.path == path
    rendered = d.render()
    assert "\n" not in rendered
    assert LINE_RE.match(rendered), rendered
    assert rendered.endswith(f"[{code}]")


def test_unknown_key_did_you_mean_from_model():
    text = "components:\n  a:\n    type: spring\n    k: 1\n    stpes: 3\n"
    d = _single(text, allowed_keys=allowed_keys_from_model(Model))
    assert d.hint == "did you mean `steps`?"
    assert d.render() == ("file.yaml:5:5: components.a.stpes: unknown key `stpes`. "
                          "hint: did you mean `steps`? [PHC-E010]")


def test_unknown_key_lists_allowed_keys_without_close_match():
    d = _single("components: {}\nzzz: 1\n", allowed_keys=allowed_keys_from_model(Model))
    assert d.hint == "allowed keys: `components`, `count`, `label`, `size`"


def test_unknown_key_with_custom_allowed_keys_function():
    seen = []

    def allowed(loc):
        seen.append(loc)
        return ["m", "kind", "type"]

    d = _single("components:\n  a: {type: mass, m: 1, knd: point}\n", allowed_keys=allowed)
    assert seen == [("components", "a", "mass")]
    assert d.hint == "did you mean `kind`?"


def test_bad_tag_did_you_mean():
    d = _single("components:\n  a: {type: sprng, k: 1}\n")
    assert d.hint == "did you mean `spring`?"


def test_union_members_are_compacted():
    d = _single("components: {}\nsize: big\n")
    assert d.code == "PHC-E013"
    assert d.message == "expected an integer or a list, got string `'big'`"
    assert (d.span.line, d.span.col) == (2, 7)
    assert d.path == "size"


def test_all_problems_collected_and_sorted():
    text = ("components:\n"
            "  a: {type: mass, m: .inf, extra: 1}\n"
            "  b: {type: spring}\n"
            "count: x\n")
    diags = DiagnosticList(_diagnose(text))
    assert {d.code for d in diags} == {"PHC-E010", "PHC-E011", "PHC-E012", "PHC-E013"}
    lines = diags.render_text().splitlines()
    assert len(lines) == len(diags) == 4
    assert all(LINE_RE.match(line) for line in lines)
    positions = [(d.span.line, d.span.col) for d in diags.sorted()]
    assert positions == sorted(positions)


def test_several_missing_keys_are_all_reported():
    class Two(Strict):
        a: int
        b: int

    data, smap, _ = load_yaml("c: 1\n", "file.yaml")
    with pytest.raises(ValidationError) as info:
        Two.model_validate(data)
    diags = from_pydantic(info.value, smap)
    assert sorted(d.message for d in diags if d.code == "PHC-E011") == [
        "missing required key `a`", "missing required key `b`"]
    assert {d.code for d in diags} == {"PHC-E010", "PHC-E011"}


def test_root_path_for_subdocument():
    data, smap, _ = load_yaml("outer:\n  inner:\n    type: mass\n    m: oops\n", "file.yaml")
    with pytest.raises(ValidationError) as info:
        Mass.model_validate(data["outer"]["inner"])
    (d,) = from_pydantic(info.value, smap, root_path=("outer", "inner"))
    assert (d.code, d.span.line, d.span.col, d.path) == ("PHC-E013", 4, 8, "outer.inner.m")


def test_custom_error_code_and_hint_from_validator():
    class Named(Strict):
        name: str

        @field_validator("name")
        @classmethod
        def _check(cls, value: str) -> str:
            raise PydanticCustomError("PHC-E201", "unknown parameter `{v}` hint: did you mean `m`?", {"v": value})

    data, smap, _ = load_yaml("name: mm\n", "file.yaml")
    with pytest.raises(ValidationError) as info:
        Named.model_validate(data)
    (d,) = from_pydantic(info.value, smap)
    assert d.render() == "file.yaml:1:7: name: unknown parameter `mm`. hint: did you mean `m`? [PHC-E201]"


def test_other_errors_fall_back_to_e019():
    class Bounded(Strict):
        n: int = Field(gt=0)

    data, smap, _ = load_yaml("n: -3\n", "file.yaml")
    with pytest.raises(ValidationError) as info:
        Bounded.model_validate(data)
    (d,) = from_pydantic(info.value, smap)
    assert d.code == "PHC-E019"
    assert d.message.startswith("Input should be greater than 0")


def test_long_values_are_truncated():
    d = _single("components: {}\ncount: '" + "x" * 200 + "'\n")
    found = d.message.split("`")[1]
    assert len(found) <= 40


@pytest.mark.parametrize(
    "diag, expected",
    [
        (Diagnostic("PHC-E201", "unknown parameter `mm`", span=SourceSpan("models/x.yaml", 12, 5),
                    hint="did you mean `m`?", path="components.mass.m"),
         "models/x.yaml:12:5: components.mass.m: unknown parameter `mm`. hint: did you mean `m`? [PHC-E201]"),
        (Diagnostic("PHC-E201", "unknown parameter `mm`.", span=SourceSpan("x.yaml", 1, 2), hint="fix it"),
         "x.yaml:1:2: unknown parameter `mm`. hint: fix it [PHC-E201]"),
        (Diagnostic("PHC-E900", "no location"), "<model>: no location [PHC-E900]"),
        (Diagnostic("PHC-W001", "looks odd", span=SourceSpan("x.yaml", 3, 1), severity="warning", path="a.b"),
         "x.yaml:3:1: warning: a.b: looks odd [PHC-W001]"),
        (Diagnostic("PHC-I001", "note", severity="info"), "<model>: info: note [PHC-I001]"),
        (Diagnostic("PHC-E001", "two\nlines", span=SourceSpan("x.yaml", 1, 1), hint="a\r\n  b"),
         "x.yaml:1:1: two lines. hint: a b [PHC-E001]"),
    ],
)
def test_render(diag, expected):
    assert diag.render() == expected


def test_to_dict_is_json_friendly():
    d = Diagnostic("PHC-E010", "unknown key `x`", span=SourceSpan("f.yaml", 2, 3), path="a.x")
    out = d.to_dict()
    assert out == {"code": "PHC-E010", "severity": "error", "message": "unknown key `x`", "hint": None,
                   "path": "a.x", "file": "f.yaml", "line": 2, "col": 3}
    assert json.loads(json.dumps(out)) == out
    assert Diagnostic("PHC-E010", "m").to_dict()["line"] is None


def test_diagnostic_list():
    diags = DiagnosticList([
        Diagnostic("PHC-W001", "w", span=SourceSpan("b.yaml", 1, 1), severity="warning"),
        Diagnostic("PHC-E002", "e2", span=SourceSpan("a.yaml", 5, 1)),
        Diagnostic("PHC-E001", "e1", span=SourceSpan("a.yaml", 5, 1)),
        Diagnostic("PHC-I001", "i", severity="info"),
    ])
    assert diags.has_errors
    assert [d.code for d in diags.errors] == ["PHC-E002", "PHC-E001"]
    assert [d.code for d in diags.warnings] == ["PHC-W001"]
    assert [d.code for d in diags.sorted()] == ["PHC-I001", "PHC-E001", "PHC-E002", "PHC-W001"]
    assert isinstance(diags.sorted(), DiagnosticList)
    assert len(diags.render_text().splitlines()) == 4
    assert [d["code"] for d in diags.to_json()] == ["PHC-I001", "PHC-E001", "PHC-E002", "PHC-W001"]
    assert not DiagnosticList(diags.warnings).has_errors


def test_error_codes_table():
    for code in ("PHC-E001", "PHC-E002", "PHC-E003", "PHC-E004", "PHC-E010", "PHC-E011", "PHC-E012",
                 "PHC-E013", "PHC-E014", "PHC-E015", "PHC-E016", "PHC-E019"):
        assert ERROR_CODES[code]
        assert "\n" not in ERROR_CODES[code]


def test_loader_diagnostics_render_one_line():
    _, _, diags = load_yaml("a: 1\na: 2\nb: !!python/object/apply:os.system ['echo x']\n", "file.yaml")
    lines = DiagnosticList(diags).render_text().splitlines()
    assert len(lines) == 2
    assert all(LINE_RE.match(line) for line in lines)
    assert lines[0] == ("file.yaml:2:1: duplicate key `a`; the first one is at line 1. "
                        "hint: remove or rename one of them [PHC-E002]")


class Param(Strict):
    value: float
    unit: str = ""


class WithUnion(Strict):
    p: Union[Param, float, str]


@pytest.mark.parametrize(
    "text, expected",
    [
        # the mapping member matched the shape: its specific errors win over the type errors
        ("p: {valeu: 1}\n", [("PHC-E010", 1, 5), ("PHC-E011", 1, 4)]),
        # no member matched: one merged type error
        ("p: [1]\n", [("PHC-E013", 1, 4)]),
    ],
)
def test_non_discriminated_union(text, expected):
    data, smap, _ = load_yaml(text, "file.yaml")
    with pytest.raises(ValidationError) as info:
        WithUnion.model_validate(data)
    diags = DiagnosticList(from_pydantic(info.value, smap)).sorted()
    assert [(d.code, d.span.line, d.span.col) for d in diags] == sorted(expected, key=lambda x: (x[1], x[2]))
    if expected[0][0] == "PHC-E013":
        assert diags[0].message == "expected a mapping, a number or a string, got list `[1]`"
