"""Shared pieces of the loader fuzzer and the corpora it feeds (``tests/fuzz/``).

The oracle
    :func:`check_input` runs one model or scene file through the ``phc validate`` path
    (:func:`phc.build_dae`: read, validate, elaborate, assemble, structural checks) and, when
    asked, through :func:`phc.compile_model`. The input passes when it ends in success, or in
    errors that are all one-line diagnostics located in one of the input's files
    (``file:line:col: ... [PHC-Exxx]``, the line within the file). A diagnostic without a
    location renders as ``<model>: ... [PHC-Exxx]`` (documented in
    :meth:`phc.diagnostics.Diagnostic.render`) and is accepted too. Any other exception, a
    diagnostic spanning lines, or a run longer than :data:`TIME_LIMIT` seconds (SIGALRM in the
    test process) fails the input.

The strategies
    :func:`documents` draws random model documents from a grammar that follows the spec
    classes (:mod:`phc.spec`): keys and component types come from the pydantic models, values
    mostly from each field's annotation and sometimes from anywhere. :func:`mutations` draws
    changes to a shipped model or scene (deleted keys, swapped types, numbers made strings,
    negative or huge numbers, renamed references, duplicated components, truncated text).
"""

from __future__ import annotations

import contextlib
import copy
import io
import math
import os
import re
import shutil
import types
import typing
from pathlib import Path
from typing import Any, Literal

import pydantic
import yaml
from hypothesis import strategies as st

import phc
from phc.errors import ModelError
from phc.spec import ModelSpec
from phc.spec.scene import SceneSpec
from time_limits import Hang, time_limit  # noqa: F401 (the fuzz tests' names)

REPO = Path(__file__).resolve().parents[2]
MODELS = REPO / "models"
SHIPPED = sorted(MODELS.glob("*.yaml")) + sorted((MODELS / "scenes").glob("*.yaml"))
"""Every shipped model and scene; mutations start from these."""

TIME_LIMIT = 5
"""CPU seconds one input may take to validate (load + elaborate + structural checks)."""
COMPILE_TIME_LIMIT = 30
"""CPU seconds one input may take to compile (the flexible slider–crank takes 1–3 s)."""

LOCATED = re.compile(r"^(?P<file>.+?):(?P<line>\d+):(?P<col>\d+): .*\S \[PHC-[EWI]\d{3}\]$")
UNLOCATED = re.compile(r"^<model>: .*\S \[PHC-[EWI]\d{3}\]$")


# -- the oracle ---------------------------------------------------------------------

def _line_count(file: str) -> int:
    """Lines as an editor counts them (LF, CRLF or CR ends a line)."""
    try:
        return len(re.findall(rb"\r\n?|\n", Path(file).read_bytes())) + 1
    except OSError:
        return 1


def check_diagnostics(diags, files: set[str]) -> None:
    """Every diagnostic is one line, located in one of `files` within the file's lines."""
    for d in diags:
        text = d.render()
        assert "\n" not in text and "\r" not in text, f"diagnostic spans lines: {text!r}"
        if d.span is None:
            assert UNLOCATED.match(text), f"not a diagnostic line: {text!r}"
            continue
        match = LOCATED.match(text)
        assert match, f"not a located diagnostic line: {text!r}"
        file = os.path.normpath(match.group("file"))
        assert file in files, f"located in `{file}`, which is none of the input's files {sorted(files)}: {text!r}"
        line, col = int(match.group("line")), int(match.group("col"))
        assert line >= 1 and col >= 1, text
        assert line <= _line_count(file), f"line {line} is past the end of `{file}`: {text!r}"


def check_cli(path: Path, files: set[str]) -> str:
    """``phc validate PATH`` through the command line's `main`: exit 0 or 1, and every line it
    prints on stderr a diagnostic (an internal error would be exit 2 and its own line)."""
    from phc.cli import main

    err = io.StringIO()
    with time_limit(TIME_LIMIT), contextlib.redirect_stderr(err), contextlib.redirect_stdout(io.StringIO()):
        code = main(["validate", str(path)])
    lines = [line for line in err.getvalue().splitlines() if line.strip()]
    assert code in (0, 1) and "internal error" not in err.getvalue(), err.getvalue()
    for line in lines:
        match = LOCATED.match(line)
        assert match or UNLOCATED.match(line), f"not a diagnostic line: {line!r}"
        assert match is None or os.path.normpath(match.group("file")) in files, line
    return "ok (cli)" if code == 0 else "error (cli)"


def check_input(path: Path, files: set[str] | None = None, compile: bool = False, cli: bool = False) -> str:
    """Run one input through ``phc validate`` (and ``compile`` when asked); assert the oracle.

    Returns what happened: "error", "ok", "ok, compiled" or "ok, compile refused" (with
    `cli`: "ok (cli)" or "error (cli)", the command line's `main` instead of the API).
    """
    files = {os.path.normpath(f) for f in files or (str(p) for p in Path(path).parent.rglob("*") if p.is_file())}
    if cli:
        return check_cli(path, files)
    with time_limit(TIME_LIMIT):
        dae, diags = phc.build_dae(path)
    check_diagnostics(diags, files)
    if dae is None:
        assert diags.has_errors, "no model and no error"
    if compile and dae is not None:
        try:
            with time_limit(COMPILE_TIME_LIMIT):
                phc.compile_model(path)
            return "ok, compiled"
        except ModelError as err:
            assert err.diagnostics, "ModelError without diagnostics"
            check_diagnostics(err.diagnostics, files)
            return "ok, compile refused"
    return "ok" if dae is not None else "error"


# -- a workspace: the shipped models copied, so mutated files keep their neighbours --

def workspace(root: Path) -> Path:
    """Copy ``models/`` (with ``scenes/``) under `root`; returns the copy."""
    target = root / "models"
    if not target.exists():
        shutil.copytree(MODELS, target)
    return target


# -- values -------------------------------------------------------------------------

NAMES = ["a", "b", "x", "k", "m", "mass", "spring", "node", "port", "rod", "wheel", "p", "q", "theta",
         "L", "r", "H", "t", "pi", "sin", "xi", "y0", "to_mass", "p0", "pf"]
"""A small pool, so that references often meet a declared name (and reserved ones appear)."""

FUNCS = ["sin", "cos", "exp", "log", "sqrt", "abs", "min", "max", "atan2", "ifelse", "heaviside", "open",
         "__import__", "eval"]

HUGE_NUMBERS = [0, -1, 1e308, -1e308, 5e-324, 1e-320, 2 ** 63, 2 ** 64, -(2 ** 64), 10 ** 30, 10 ** 400,
                float("inf"), float("-inf"), float("nan"), 200_000, 10 ** 7, 10 ** 9]

WEIRD_TEXT = ["", " ", "1e400", "10**1000", "9**9**9", "-1e400", "nan", "inf", ".inf", "2**64", "1/0", "0/0",
              "log(0)", "sqrt(-1)", "x" * 300, "a" * 20 + "." + "b" * 20, "é", "\u202e", "\x00", "a\nb",
              '"""; open("OWNED", "w"); """', "__import__('os').system('true')", "().__class__",
              "mass.port", "node.a", "spring.x", "a.b.c", "..", "../x.yaml", "/etc/passwd", "~", "$HOME",
              "!!python/object", "&a", "*a", "{", "[", "'", "#"]

names = st.sampled_from(NAMES) | st.from_regex(r"[A-Za-z][A-Za-z0-9_]{0,6}", fullmatch=True)
numbers = (st.integers(-10, 10) | st.floats(allow_nan=True, allow_infinity=True)
           | st.sampled_from(HUGE_NUMBERS) | st.integers())
references = st.builds(lambda a, b: f"{a}.{b}", names, names)


def _expr_tree(leaves):
    def extend(children):
        binary = st.builds(lambda a, op, b: f"{a} {op} {b}", children,
                           st.sampled_from(["+", "-", "*", "/", "**", "<", "==", "//", "and"]), children)
        call = st.builds(lambda f, args: f"{f}({', '.join(args)})", st.sampled_from(FUNCS),
                         st.lists(children, max_size=3))
        paren = st.builds(lambda a: f"({a})", children)
        neg = st.builds(lambda a: f"-{a}", children)
        return binary | call | paren | neg

    return st.recursive(leaves, extend, max_leaves=8)


expressions = _expr_tree(names | references | st.integers(-5, 10).map(str)
                         | st.sampled_from(["1e400", "10**1000", "2**64", "0.5", "1e-320", "nan", "t", "pi"]))
text = (expressions | names | references | st.sampled_from(WEIRD_TEXT) | st.text(max_size=12))
scalars = st.none() | st.booleans() | numbers | text
keys = names | text | st.integers() | st.none() | st.booleans() | st.floats() | st.sampled_from(["<<", "~", "1.0"])
anything = st.recursive(scalars, lambda c: st.lists(c, max_size=4) | st.dictionaries(keys, c, max_size=4),
                        max_leaves=10)


# -- values that follow the spec's annotations --------------------------------------

def _strip(tp: Any) -> Any:
    while typing.get_origin(tp) is typing.Annotated:
        tp = typing.get_args(tp)[0]
    return tp


def _is_spec(tp: Any) -> bool:
    return isinstance(tp, type) and issubclass(tp, pydantic.BaseModel)


def _field_key(name: str, field) -> str:
    return field.alias or name


def for_annotation(tp: Any, depth: int = 0, key: str = "") -> st.SearchStrategy:
    """Values shaped like annotation `tp` (mostly), sometimes anything at all."""
    shaped = _shaped(tp, depth, key)
    return st.one_of(shaped, shaped, shaped, shaped, shaped, shaped, anything)


def _shaped(tp: Any, depth: int, key: str) -> st.SearchStrategy:
    tp = _strip(tp)
    origin = typing.get_origin(tp)
    args = typing.get_args(tp)
    if depth > 5:
        return scalars
    if origin is typing.Union or (hasattr(types, "UnionType") and origin is types.UnionType):
        return st.one_of([_shaped(a, depth + 1, key) for a in args])
    if origin is Literal:
        return st.sampled_from(args)
    if tp is type(None):
        return st.none()
    if tp is bool:
        return st.booleans()
    if tp is int:
        return st.integers(-2, 40) | st.sampled_from(HUGE_NUMBERS)
    if tp is float:
        return st.floats(-10, 10) | numbers
    if tp is str:
        if key in ("between", "port", "model"):
            return references | names
        if key == "file":
            # inside the workspace: path traversal, devices and FIFOs are the corpus's (tests/models/hostile)
            return st.sampled_from(["pendulum.yaml", "scenes/slider_crank_rigid.yaml", "fuzz_doc.yaml",
                                    "nothere.yaml", "table.csv", "m.npz", "", ".", "scenes"])
        return text
    if tp is Any:
        return anything
    if origin is list:
        return st.lists(_shaped(args[0], depth + 1, key), max_size=4)
    if origin is tuple:
        if len(args) == 2 and args[1] is Ellipsis:
            return st.lists(_shaped(args[0], depth + 1, key), max_size=4)
        return st.tuples(*(_shaped(a, depth + 1, key) for a in args)).map(list)
    if origin is dict:
        key_tp, value_tp = args
        keys = st.sampled_from(["a", "b", "x", "port", "mass.port", "spring.x", "rod", "wheel"]) | names
        return st.dictionaries(keys, for_annotation(value_tp, depth + 1, key), max_size=3)
    if _is_spec(tp):
        return spec_dicts(tp, depth + 1)
    return anything


def spec_dicts(model: type[pydantic.BaseModel], depth: int = 0) -> st.SearchStrategy:
    """Dicts with `model`'s keys: required ones usually present, optional ones sometimes,
    an unknown key now and then."""
    required, optional = {}, {}
    for name, field in model.model_fields.items():
        key = _field_key(name, field)
        (required if field.is_required() else optional)[key] = for_annotation(field.annotation, depth, name)

    @st.composite
    def build(draw):
        out = {}
        for key, strat in required.items():
            if draw(st.integers(0, 19)):  # leave a required key out now and then
                out[key] = draw(strat)
        for key in draw(st.lists(st.sampled_from(sorted(optional)), max_size=4, unique=True)) if optional else []:
            out[key] = draw(optional[key])
        if not draw(st.integers(0, 14)):
            out[draw(names)] = draw(anything)
        return out

    return build()


def documents(root: type[pydantic.BaseModel] = ModelSpec) -> st.SearchStrategy:
    """Random model (or scene) documents that follow the spec's grammar."""
    return spec_dicts(root)


scene_documents = documents(SceneSpec)


def dump(doc: Any, flow: bool | None) -> str:
    return yaml.safe_dump(doc, sort_keys=False, allow_unicode=True, default_flow_style=flow, width=10 ** 6)


# -- mutations of shipped files -----------------------------------------------------

def _paths(node: Any, prefix: tuple = ()) -> list[tuple]:
    out = [prefix]
    if isinstance(node, dict):
        for k, v in node.items():
            out.extend(_paths(v, prefix + (k,)))
    elif isinstance(node, list):
        for i, v in enumerate(node):
            out.extend(_paths(v, prefix + (i,)))
    return out


def _get(doc: Any, path: tuple) -> Any:
    for p in path:
        doc = doc[p]
    return doc


def _set(doc: Any, path: tuple, value: Any) -> Any:
    if not path:
        return value
    _get(doc, path[:-1])[path[-1]] = value
    return doc


def _delete(doc: Any, path: tuple) -> Any:
    if not path:
        return {}
    parent = _get(doc, path[:-1])
    del parent[path[-1]]
    return doc


def _rename(value: Any, draw) -> Any:
    if not isinstance(value, str) or not value:
        return value
    how = draw(st.integers(0, 3))
    if how == 0:
        return value + draw(st.sampled_from(["x", "_2", ".port", "."]))
    if how == 1:
        return value[:-1]
    if how == 2:
        parts = value.split(".")
        parts[draw(st.integers(0, len(parts) - 1))] = draw(names)
        return ".".join(parts)
    return value.swapcase()


@st.composite
def _mutate_data(draw, doc: Any) -> Any:
    doc = copy.deepcopy(doc)
    for _ in range(draw(st.integers(1, 3))):
        paths = _paths(doc)
        path = draw(st.sampled_from(paths))
        value = _get(doc, path)
        op = draw(st.sampled_from(["delete", "swap", "stringify", "negate", "huge", "rename", "duplicate",
                                   "anything", "expression", "empty", "alias"]))
        if op == "delete" and path:
            doc = _delete(doc, path)
        elif op == "swap":
            doc = _set(doc, path, draw(st.sampled_from([None, True, 0, 1.5, "x", [], {}, [value], {"value": value}])))
        elif op == "stringify":
            doc = _set(doc, path, str(value) if not isinstance(value, str) else draw(numbers))
        elif op == "negate" and isinstance(value, (int, float)) and not isinstance(value, bool):
            doc = _set(doc, path, -value if value else -1)
        elif op == "huge":
            doc = _set(doc, path, draw(st.sampled_from(HUGE_NUMBERS + ["1e400", "10**1000", "2**64"])))
        elif op == "rename":
            if path and isinstance(path[-1], str) and isinstance(_get(doc, path[:-1]), dict):
                parent = _get(doc, path[:-1])
                new = _rename(path[-1], draw)
                parent[new] = parent.pop(path[-1])
            else:
                doc = _set(doc, path, _rename(value, draw))
        elif op == "duplicate":
            parent = _get(doc, path[:-1]) if path else None
            if isinstance(parent, dict):
                parent[str(path[-1]) + "2"] = copy.deepcopy(value)
            elif isinstance(parent, list):
                parent.append(copy.deepcopy(value))
        elif op == "alias":  # the same object twice: the dump writes an anchor and an alias
            parent = _get(doc, path[:-1]) if path else None
            if isinstance(parent, dict) and isinstance(value, (dict, list)):
                parent[str(path[-1]) + "_again"] = value
        elif op == "anything":
            doc = _set(doc, path, draw(anything))
        elif op == "expression":
            doc = _set(doc, path, draw(expressions))
        elif op == "empty":
            doc = _set(doc, path, draw(st.sampled_from(["", [], {}, None])))
    return doc


@st.composite
def _mutate_text(draw, text: str) -> str:
    lines = text.split("\n")
    op = draw(st.sampled_from(["truncate", "duplicate_line", "delete_line", "insert", "indent", "swap_lines"]))
    if op == "truncate":
        return text[: draw(st.integers(0, len(text)))]
    i = draw(st.integers(0, len(lines) - 1))
    if op == "duplicate_line":
        lines.insert(i, lines[i])
    elif op == "delete_line":
        del lines[i]
    elif op == "insert":
        pos = draw(st.integers(0, len(lines[i])))
        junk = draw(st.sampled_from(["\t", ":", " ", "- ", "&a ", "*a", "!!python/object ", "\x00", "\ufeff",
                                     "{", "]", "'", '"', "#", "<<: *a", "\\", "\u2028", "\x85", "\r",
                                     "0x" + "f" * 300, "9" * 400, "1e400", "-.inf", ".nan", "!!binary ",
                                     "!!set ", "? ", "|\n", ">-\n", "--- ", "...", "%YAML 1.1\n"])
                    | st.text(max_size=3))
        lines[i] = lines[i][:pos] + junk + lines[i][pos:]
    elif op == "indent":
        lines[i] = draw(st.sampled_from(["", " ", "   ", "      "])) + lines[i].lstrip()
    elif op == "swap_lines" and len(lines) > 1:
        j = draw(st.integers(0, len(lines) - 1))
        lines[i], lines[j] = lines[j], lines[i]
    return "\n".join(lines)


@st.composite
def mutations(draw, source: Path) -> str:
    """The text of `source` (a shipped model or scene) with random changes."""
    text = source.read_text(encoding="utf-8")
    if draw(st.integers(0, 3)) == 0:
        return draw(_mutate_text(text))
    doc = draw(_mutate_data(yaml.safe_load(text)))
    out = dump(doc, draw(st.sampled_from([None, False, True])))
    if draw(st.integers(0, 5)) == 0:
        out = draw(_mutate_text(out))
    return out


def finite(x: Any) -> bool:
    return not isinstance(x, float) or math.isfinite(x)


# -- a grammar of the model language: documents that mostly make sense --------------
#
# `documents()` above follows the spec's types, but almost every document it draws fails
# schema validation. `models()` builds documents the way a user writes them — parameters,
# components of every library kind with their ports and states, connections between those
# ports, exposed ports with inputs, initial values and outputs over the states — so that
# most inputs reach elaboration, assembly, the structural checks and the compiler. A
# per-document noise level then makes some values wrong (zero, negative, huge, non-finite,
# of the wrong type, expressions outside the language, unknown names).

_LUMPED = {"mass": ("m", "p", "mechanical.translational"), "inductor": ("L", "phi", "electrical"),
           "spring": ("k", "x", "mechanical.translational"), "capacitor": ("C", "q", "electrical"),
           "damper": ("d", None, "mechanical.translational"), "resistor": ("R", None, "electrical")}
_KINDS = [*_LUMPED, "effort_source", "flow_source", "zero_effort", "zero_flow", "junction", "phs", "phs_kernel",
          "rigid", "string", "euler_bernoulli_beam", "timoshenko_beam", "moving_beam", "crank_wheel",
          "modulation", "orthogonal_transform", "model"]
_PARAM_NAMES = ["m", "k", "c", "L", "g", "r", "EI", "rho", "omega", "T0"]
_BAD_NAMES = st.sampled_from(["H", "t", "sin", "1x", "a b", "x\n", "é", "_x", "N", "np", "pi", "xi", "key", ""]) | names
_SAFE_NAMES = st.sampled_from(["a", "b", "mass", "spring", "node", "rod", "wheel", "y", "z", "body"])


class _Doc:
    """What a document being drawn declares so far (names in scope, ports, states)."""

    def __init__(self, draw, noise: int) -> None:
        self.draw, self.noise = draw, noise
        self.params: list[str] = []
        self.ports: list[tuple[str, str, int]] = []   # (reference, domain, dimension)
        self.states: list[str] = []

    def weird(self) -> bool:
        return self.draw(st.integers(0, 99)) < self.noise

    def value(self, positive: bool = True, extra: tuple = ()) -> Any:
        """A coefficient: a number, a parameter or an expression over the names in scope."""
        draw = self.draw
        if self.weird():
            return draw(st.sampled_from(HUGE_NUMBERS + WEIRD_TEXT) | expressions | anything)
        scope = self.params + list(extra)
        choice = draw(st.integers(0, 3))
        if choice == 0 or not scope:
            return draw(st.floats(0.1, 10) if positive else st.floats(-5, 5)) if draw(st.booleans()) \
                else draw(st.integers(1, 9))
        name = draw(st.sampled_from(scope))
        if choice == 1:
            return name
        op = draw(st.sampled_from(["*", "+", "/", "**"]))
        return f"{name} {op} {draw(st.integers(1, 3))}" if op != "/" else f"{name}/{draw(st.integers(1, 3))}"

    def int_value(self, low: int, high: int) -> Any:
        if self.weird():
            return self.draw(st.sampled_from(HUGE_NUMBERS + ["4", 2.5, True, None, -3]))
        return self.draw(st.integers(low, high))

    def name(self, pool: list[str], taken) -> str:
        if self.weird():
            return self.draw(_BAD_NAMES)
        free = [n for n in pool if n not in taken]
        if free and self.draw(st.integers(0, 3)):
            return self.draw(st.sampled_from(free))
        return f"{self.draw(_SAFE_NAMES)}{len(taken)}"

    def matrix(self, n: int, m: int, kind: str = "any") -> list:
        if self.weird():
            n = max(0, n + self.draw(st.sampled_from([-1, 1])))
        rows = [[0] * m for _ in range(n)]
        for i in range(n):
            for j in range(m):
                if kind == "skew":
                    if j > i:
                        v = self.draw(st.integers(-2, 2))
                        rows[i][j] = v
                        if j < n and i < m:
                            rows[j][i] = -v
                elif kind == "diag":
                    rows[i][j] = self.value() if i == j else 0
                else:
                    rows[i][j] = self.value(positive=False) if self.draw(st.booleans()) else self.draw(st.integers(-1, 1))
        return rows

    def port(self, ref: str, domain: str, dim: int) -> None:
        self.ports.append((ref, domain, dim))


def _component(doc: _Doc, cname: str, kind: str) -> dict:
    draw = doc.draw
    if kind in _LUMPED:
        coeff, state, domain = _LUMPED[kind]
        comp = {"type": kind, coeff: doc.value()}
        dim = 1
        if draw(st.integers(0, 5)) == 0:
            dim = comp["dimension"] = doc.int_value(1, 3)
        ports = ["port"]
        if draw(st.integers(0, 4)) == 0:
            ports = comp["ports"] = draw(st.lists(st.sampled_from(["a", "b", "c", "port"]), min_size=1, max_size=3,
                                                  unique=not doc.weird()))
        for p in ports:
            doc.port(f"{cname}.{p}", domain, dim if isinstance(dim, int) and 1 <= dim <= 4 else 1)
        if state:
            doc.states += [f"{cname}.{state}"] if dim == 1 else [f"{cname}.{state}[{k}]" for k in range(2)]
        return comp
    if kind in ("effort_source", "flow_source"):
        comp = {"type": kind, "value": doc.value(positive=False, extra=("t", "sin(t)", "t**2"))}
        if draw(st.booleans()):
            comp["domain"] = draw(st.sampled_from(["mechanical.translational", "electrical", "generic"]))
        doc.port(f"{cname}.port", comp.get("domain", "generic"), 1)
        return comp
    if kind in ("zero_effort", "zero_flow"):
        comp = {"type": kind}
        if draw(st.booleans()):
            comp["domain"] = draw(st.sampled_from(["mechanical.translational", "electrical", "generic"]))
        doc.port(f"{cname}.port", comp.get("domain", "generic"), 1)
        return comp
    if kind == "junction":
        ports = draw(st.lists(st.sampled_from(["a", "b", "c", "d", "to_mass", "port"]), min_size=2, max_size=4,
                              unique=not doc.weird()))
        domain = draw(st.sampled_from(["mechanical.translational", "electrical", "generic"]))
        comp = {"type": kind, "kind": draw(st.sampled_from(["common_flow", "common_effort"])), "ports": ports,
                "domain": domain}
        for p in ports:
            doc.port(f"{cname}.{p}", domain, 1)
        return comp
    if kind in ("phs", "phs_kernel"):
        n = draw(st.integers(1, 3))
        states = [f"x{i}" for i in range(n)]
        ham = " + ".join(f"{doc.value()}*{s}**2/2" if draw(st.booleans()) else f"{s}**2" for s in states)
        if doc.weird():
            ham = draw(st.sampled_from([f"exp({states[0]})", f"max({states[0]}, 1)", f"abs({states[0]})", "x9",
                                        f"log({states[0]})", f"sqrt({states[0]})", {"spring": f"{states[0]}**2"}]))
        comp = {"type": "phs", "states": states, "hamiltonian": ham}
        doc.states += [f"{cname}.{s}" for s in states]
        if kind == "phs":
            comp["J"] = doc.matrix(n, n, "skew")
            if draw(st.booleans()):
                comp["R"] = doc.matrix(n, n, "diag")
            pdim = draw(st.integers(1, 2))
            comp["ports"] = {"u": {"B": doc.matrix(n, pdim), "dimension": pdim,
                                   "causality": draw(st.sampled_from(["effort_in", "flow_in"]))}}
            doc.port(f"{cname}.u", "generic", pdim)
        else:  # kernel form: f_x = -e_u, f_u = e_x  (a storage on one port)
            comp["ports"] = {"u": {}}
            comp["relations"] = [f"f_{states[0]} = -e_u", f"f_u = e_{states[0]}"] + \
                [f"f_{s} = -e_{s}" for s in states[1:]]
            if doc.weird():
                comp["relations"].append(draw(st.sampled_from(["f_u = f_u", "e_u = 1", "f_x0 * e_u = 0", "x = "])))
            doc.port(f"{cname}.u", "generic", 1)
        return comp
    if kind == "rigid":
        q = draw(st.lists(st.sampled_from(["x", "y", "theta", "phi"]), min_size=1, max_size=2, unique=True))
        n = len(q)
        comp = {"type": "rigid", "q": q, "M": doc.matrix(n, n, "diag"),
                "V": {"gravity": f"{doc.value()}*{q[0]}"} if draw(st.booleans()) else f"{q[0]}**2/2"}
        if draw(st.booleans()):
            comp["ports"] = {"tip": {"B": doc.matrix(n, 1), "domain": "mechanical.translational",
                                     "position": [q[0]] if draw(st.booleans()) else None}}
            if comp["ports"]["tip"]["position"] is None:
                del comp["ports"]["tip"]["position"]
            doc.port(f"{cname}.tip", "mechanical.translational", 1)
        if n == 2 and draw(st.integers(0, 3)) == 0:
            comp["constraints"] = [f"{q[0]}**2 + {q[1]}**2 - 1"]
        doc.states += [f"{cname}.{s}" for s in q] + [f"{cname}.p_v_{s}" for s in q]
        return comp
    if kind in ("string", "euler_bernoulli_beam", "timoshenko_beam"):
        comp = {"type": kind, "length": doc.value(), "elements": doc.int_value(1, 6)}
        if kind == "string":
            comp.update(rho=doc.value(extra=("1 + xi",)), T=doc.value())
            ports = ["a", "b"]
        elif kind == "euler_bernoulli_beam":
            comp.update(rhoA=doc.value(), EI=doc.value())
            ports = ["a", "b", "a_rot", "b_rot"]
        else:
            comp.update(rho=doc.value(), I_rho=doc.value(), EI=doc.value(), K=doc.value())
            ports = ["a", "b", "a_rot", "b_rot"]
        if draw(st.integers(0, 3)) == 0:
            comp["damping"] = doc.value(extra=("xi",))
        if draw(st.integers(0, 3)) == 0:
            comp["effects"] = {"damping": draw(st.booleans())}
            if draw(st.booleans()):
                comp["effects"]["modes"] = doc.int_value(1, 4)
        for p in ports:
            doc.port(f"{cname}.{p}", "mechanical.rotational" if p.endswith("rot") else "mechanical.translational", 1)
        return comp
    if kind == "moving_beam":
        comp = {"type": kind, "length": doc.value(), "rhoA": doc.value(), "EI": doc.value(),
                "elements": doc.int_value(1, 4)}
        if draw(st.booleans()):
            comp["deflection_at"] = draw(st.lists(st.floats(-0.5, 1.5) | st.sampled_from([0.0, 1.0, 0.5]),
                                                  max_size=2))
        for p in ("p0", "pf"):
            doc.port(f"{cname}.{p}", "mechanical.translational", 2)
        for p in ("m0", "mf"):
            doc.port(f"{cname}.{p}", "mechanical.rotational", 1)
        doc.states += [f"{cname}.q0[0]", f"{cname}.p_t"]
        return comp
    if kind == "crank_wheel":
        doc.port(f"{cname}.drive", "mechanical.rotational", 1)
        doc.port(f"{cname}.pin", "mechanical.translational", 2)
        doc.states += [f"{cname}.theta", f"{cname}.p_theta"]
        return {"type": kind, "radius": doc.value(), "inertia": doc.value()}
    if kind == "modulation":
        w = doc.value(extra=tuple(doc.states) + ("t",))
        doc.port(f"{cname}.a", "generic", 2)
        doc.port(f"{cname}.b", "generic", 2)
        return {"type": kind, "K": [[0, w], [f"-({w})" if isinstance(w, str) else -w if finite(w) and
                                            not isinstance(w, (bool, type(None))) and isinstance(w, (int, float))
                                            else w, 0]]}
    if kind == "orthogonal_transform":
        a = doc.value(positive=False, extra=("t",))
        doc.port(f"{cname}.a", "generic", 2)
        comp = {"type": kind, "Q": [[f"cos({a})", f"-sin({a})"], [f"sin({a})", f"cos({a})"]]}
        if draw(st.booleans()):
            comp["split"] = {"s": 1, "n": doc.int_value(1, 1)}
            doc.port(f"{cname}.s", "generic", 1)
            doc.port(f"{cname}.n", "generic", 1)
        else:
            doc.port(f"{cname}.b", "generic", 2)
        return comp
    # a nested model: one of the shipped files that exposes ports, or a missing/bad one
    target = draw(st.sampled_from(["rlc_circuit.yaml", "mass_spring_damper.yaml", "vibrating_string.yaml",
                                   "fuzz_doc.yaml", "nothere.yaml", "scenes/slider_crank_rigid.yaml"]))
    comp = {"type": "model", "file": target}
    if draw(st.booleans()):
        comp["parameters"] = {draw(st.sampled_from(["m", "k", "c", "R", "L", "x"])): doc.value()}
    return comp


@st.composite
def models(draw) -> dict:
    """A model document drawn from the model language's grammar (see the comment above)."""
    doc = _Doc(draw, draw(st.sampled_from([0, 0, 0, 1, 3, 10, 30])))
    out: dict[str, Any] = {"format_version": 1}
    if draw(st.booleans()):
        out["name"] = doc.name(["fuzz", "model"], ())
    params: dict[str, Any] = {}
    for pname in draw(st.lists(st.sampled_from(_PARAM_NAMES), max_size=4, unique=True)):
        value = doc.value()
        if isinstance(value, str) and pname in value:   # x = x * 2: a cycle, sometimes kept
            value = value if doc.weird() else 1.0
        if draw(st.integers(0, 3)) == 0:
            value = {"value": value, "unit": draw(st.sampled_from(["kg", "N/m", "", '"""', "m/s**2"])),
                     "description": draw(text)}
        params[doc.name([pname], params) if doc.weird() else pname] = value
        doc.params.append(pname)
    if params:
        out["parameters"] = params
    comps: dict[str, Any] = {}
    for i in range(draw(st.integers(1, 5))):
        kind = draw(st.sampled_from(_KINDS))
        cname = doc.name([f"{kind.split('_')[0]}{i}", ["mass", "spring", "node", "rod", "wheel"][i % 5]], comps)
        comps[cname] = _component(doc, cname, kind)
    out["components"] = comps
    # connections: pair up ports, mostly of equal domain and dimension
    free = list(doc.ports)
    connections = []
    while len(free) >= 2 and draw(st.integers(0, 5)):
        a = free.pop(draw(st.integers(0, len(free) - 1)))
        same = [p for p in free if p[1:] == a[1:]] or free
        b = draw(st.sampled_from(same))
        free.remove(b)
        pair = [a[0], b[0]]
        if doc.weird():
            pair[draw(st.integers(0, 1))] = draw(references | st.sampled_from([a[0], "x", ""]))
        connections.append(pair)
    if connections:
        out["connections"] = connections
    sim: dict[str, Any] = {}
    if free:   # every port left over is exposed (a dangling port is an error), now and then one is not
        exposed = free[: len(free) - (1 if doc.weird() else 0)]
        out["ports"] = {f"P{i}": {"port": ref} for i, (ref, _, _) in enumerate(exposed)}
        inputs = {}
        for i, (_, _, dim) in enumerate(exposed):
            if draw(st.booleans()):
                sig = doc.value(positive=False, extra=("t", "sin(t)"))
                if draw(st.integers(0, 3)) == 0:
                    sig = [{"until": 0.5, "value": sig}, {"value": 0}]
                inputs[f"P{i}"] = {draw(st.sampled_from(["effort", "flow"])): sig if dim == 1 else [sig] * min(dim, 4)}
        if inputs:
            sim["inputs"] = inputs
    if draw(st.booleans()):
        sim["t_end"] = draw(st.sampled_from([0.01, 0.1, 1.0])) if not doc.weird() else draw(numbers)
        sim["n_out"] = doc.int_value(2, 11)
    if draw(st.integers(0, 3)) == 0:
        sim["solver"] = draw(st.sampled_from(["ida", "midpoint", "discrete_gradient", "midpoint4"]))
        if sim["solver"] != "ida" and draw(st.booleans()):
            sim["step"] = 0.01 if not doc.weird() else draw(numbers)
    if doc.states and draw(st.booleans()):
        sim["initial"] = {s: doc.value(positive=False) for s in draw(st.lists(st.sampled_from(doc.states),
                                                                               max_size=3, unique=True))}
        if draw(st.integers(0, 3)) == 0 and sim["initial"]:
            key = next(iter(sim["initial"]))
            sim["initial"][key] = {"value": sim["initial"][key], "guess": draw(st.booleans())}
    if draw(st.booleans()):
        scope = tuple(doc.states) + ("H", "t")
        sim["outputs"] = {f"o{i}": doc.value(positive=False, extra=scope) for i in range(draw(st.integers(1, 3)))}
    if sim:
        out["simulation"] = sim
    return out


# -- scenes over the shipped models ---------------------------------------------------

_FACTS: dict[str, dict] = {}
_EFFECTS = ["damping", "modes", "flexibility", "moving_frame", "shear", "rotary_inertia", "gravity", "spring", "x"]


def _facts(model: Path) -> dict:
    """Names a scene of `model` can refer to: parameters, components, states, exposed ports."""
    key = str(model)
    if key not in _FACTS:
        doc = yaml.safe_load(model.read_text(encoding="utf-8"))
        dae, _ = phc.build_dae(model)
        states = [v.name for v in dae.variables if v.role == "state"] if dae is not None else []
        others = [v.name for v in dae.variables if v.role in ("flow", "effort")][:20] if dae is not None else []
        _FACTS[key] = {"parameters": list(doc.get("parameters", {})), "components": doc.get("components", {}),
                       "states": states, "variables": others, "ports": list(doc.get("ports", {}))}
    return _FACTS[key]


@st.composite
def scenes(draw) -> dict:
    """A scene of a shipped model, written the way a user writes one (see `models()`): real
    component, parameter, state and port names, with a per-scene noise level."""
    model = draw(st.sampled_from(sorted(MODELS.glob("*.yaml"))))
    facts = _facts(model)
    doc = _Doc(draw, draw(st.sampled_from([0, 0, 1, 3, 10, 30])))
    doc.params, doc.states = facts["parameters"], facts["states"]
    out: dict[str, Any] = {"format_version": 1, "model": f"../{model.name}" if not doc.weird()
                           else draw(st.sampled_from(["../nothere.yaml", model.name, "../scenes", "", "../" + model.name + "x"]))}
    if draw(st.booleans()):
        out["name"] = doc.name(["scene", "run"], ())
    if facts["parameters"] and draw(st.booleans()):
        out["parameters"] = {draw(st.sampled_from(facts["parameters"])) if not doc.weird() else draw(names):
                             draw(st.floats(0.1, 10)) if not doc.weird() else draw(numbers | text)}
    comps = list(facts["components"])
    if draw(st.booleans()):
        effects = {}
        for comp in draw(st.lists(st.sampled_from(comps), max_size=2, unique=True)):
            effects[comp if not doc.weird() else draw(references | names)] = {
                draw(st.sampled_from(_EFFECTS)): draw(st.booleans()) if draw(st.booleans()) else doc.int_value(1, 4)}
        out["effects"] = effects
    distributed = [c for c, spec in facts["components"].items() if "elements" in spec] or comps
    if draw(st.integers(0, 2)) == 0:
        out["accuracy"] = {"mesh": {draw(st.sampled_from(distributed)): doc.int_value(1, 6)}}
        if draw(st.booleans()):
            out["accuracy"]["rtol"] = draw(st.sampled_from([1e-6, 1e-3, 0.5])) if not doc.weird() else draw(numbers)
    if draw(st.booleans()):
        out["t_end"] = draw(st.sampled_from([0.01, 0.1])) if not doc.weird() else draw(numbers)
        out["n_out"] = doc.int_value(2, 21)
    if draw(st.integers(0, 2)) == 0:
        out["solver"] = draw(st.sampled_from(["ida", "midpoint", "discrete_gradient", "midpoint4"]))
    if facts["states"] and draw(st.booleans()):
        out["initial"] = {draw(st.sampled_from(facts["states"])): doc.value(positive=False)}
    if facts["ports"] and draw(st.integers(0, 2)) == 0:
        out["inputs"] = {draw(st.sampled_from(facts["ports"])): {draw(st.sampled_from(["effort", "flow"])):
                                                                  doc.value(positive=False, extra=("t",))}}
    if draw(st.integers(0, 4)):
        scope = tuple(facts["states"] + facts["variables"]) + ("H", "t")
        outs = {f"o{i}": doc.value(positive=False, extra=scope) for i in range(draw(st.integers(1, 3)))}
        out["outputs"] = outs
        if draw(st.integers(0, 3)) == 0:
            out["reference"] = {draw(st.sampled_from(list(outs) + ["nothere"])): doc.value(extra=("t",))}
    if draw(st.integers(0, 4)) == 0:
        out["prune"] = draw(st.booleans())
    if draw(st.integers(0, 5)) == 0:
        out["bench"] = {"solvers": [draw(st.sampled_from(["ida", "midpoint"]))], "repeats": doc.int_value(1, 3)}
    return out
