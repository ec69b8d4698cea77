"""No string from a model file can change the generated code (:mod:`phc.codegen.printer`).

A model file travels (shared, validated in pull requests), and phc prints a Python module
from it and imports that module. Every string that reaches the module — the model's name,
file names (top level and nested), variable, parameter and output names, descriptions,
units, expressions — must arrive as a Python literal or a printer-made identifier, never
spliced into source text. Each position is tried with a payload that would create a canary
file if it ever ran; the tests also check the module's syntax tree directly: its docstring
is phc's fixed text, and every identifier in it is one the printer chose.
"""

from __future__ import annotations

import ast
import builtins
import math
import os
from pathlib import Path

import pytest
import yaml

import phc
from phc.errors import ModelError

REPO = Path(__file__).resolve().parents[2]
MODEL_FILES = sorted((REPO / "models").glob("*.yaml"))


def payload(canary: Path, quote: str = '"""') -> str:
    """Text that creates the file ``canary`` (named relative to the working directory, which
    the tests set to its folder) if it is ever spliced into Python source."""
    return f'{quote}; open({canary.name!r}, "w"); {quote}'


OSCILLATOR = """\
format_version: 1
name: osc
description: {description}
parameters:
  k: {{value: 2.0, unit: {unit}, description: {description}}}
components:
  mass: {{type: mass, m: 1}}
  spring: {{type: spring, k: k}}
  node: {{type: junction, kind: common_flow, ports: [a, b]}}
connections:
  - [mass.port, node.a]
  - [spring.port, node.b]
simulation:
  t_end: 0.01
  n_out: 3
  initial: {{spring.x: 0.5, mass.p: 0.0}}
  outputs:
    x: spring.x
"""


def _quoted(text: str) -> str:
    """A YAML double-quoted scalar for arbitrary text."""
    return '"' + text.replace("\\", "\\\\").replace('"', '\\"') + '"'


# Identifiers the printer may emit besides its own prefixed names (y_*, yp_*, p_*, _c*, _*).
_FIXED_NAMES = {
    "base64", "math", "np", "t", "y", "yp", "p", "out", "cj", "base", "key", "H", "S", "P_ports", "P_diss",
    "text", "dtype", "A", "x", "a", "z", "times", "values", "kind", "i",
    "MODEL", "SOURCES", "N", "VARIABLES", "DIFFERENTIAL", "ROLES", "EQUATIONS", "PARAMETERS", "BASE_PARAMETERS",
    "PARAMETER_DEFAULTS", "COMPILE_TIME_PARAMETERS", "INVARIANTS", "VELOCITY_INVARIANTS", "INITIAL", "INITIAL_ROWS",
    "INITIAL_COLS", "INITIAL_DATA", "INITIAL_RHS", "OUTPUTS", "JAC_ROWS", "JAC_COLS", "JAC_DEPENDS_ON_Y", "JAC_DEPENDS_ON_YP",
    "BREAKPOINTS", "full_parameters", "residual", "residual_t", "jacobian", "hamiltonian", "energy_scale",
    "powers", "invariants", "velocity_invariants", "outputs",
    "events", "SWITCHES", "SWITCH_EQUATIONS", "SWITCH_TIME_ONLY", "SWITCH_SLOTS", "STICKS", "STICK_EQUATIONS",
    "STICK_SWITCH", "STICK_ORIENT", "STICK_SLOTS", "SWITCH_SENSE", "SWITCH_COMPARISON",
    "SWITCH_COMPONENTS",
}


def assert_printer_made(source: str) -> None:
    """The module's docstring is fixed text and every identifier is the printer's own."""
    tree = ast.parse(source)
    doc = ast.get_docstring(tree)
    assert doc.startswith("Residual module for the port-Hamiltonian model named in MODEL.")
    assert "from the model files in SOURCES" in doc
    for node in ast.walk(tree):
        names = []
        if isinstance(node, ast.Name):
            names = [node.id]
        elif isinstance(node, (ast.FunctionDef, ast.arg)):
            names = [node.name if isinstance(node, ast.FunctionDef) else node.arg]
        elif isinstance(node, ast.Attribute):
            names = [node.attr]
        for name in names:
            own = name.startswith(("y_", "yp_", "p_", "_")) or name in _FIXED_NAMES
            numpy_attr = isinstance(node, ast.Attribute)  # np.*, math.*, A.shape, out.flags ...
            assert own or numpy_attr or hasattr(builtins, name), f"identifier `{name}` not made by the printer"


@pytest.mark.parametrize("path", MODEL_FILES, ids=[p.stem for p in MODEL_FILES])
def test_shipped_models_use_only_printer_made_identifiers(path):
    assert_printer_made(phc.compile_model(path).source)


def test_a_file_name_is_data_not_code(tmp_path, monkeypatch):
    canary = tmp_path / "OWNED"
    name = payload(canary) + "x.yaml"
    model = tmp_path / name
    model.write_text(OSCILLATOR.format(description="plain", unit="N/m"))
    monkeypatch.setenv("PHC_CACHE_DIR", str(tmp_path / "cache"))
    monkeypatch.chdir(tmp_path)
    compiled = phc.compile_model(model)
    result = phc.simulate(compiled)
    assert result.success
    assert not canary.exists()
    assert_printer_made(compiled.source)
    assert compiled.module.SOURCES == (name,)


def test_a_nested_file_name_is_data_not_code(tmp_path, monkeypatch):
    canary = tmp_path / "OWNED"
    inner = payload(canary, quote="'''") + "inner.yaml"
    (tmp_path / inner).write_text(OSCILLATOR.format(description="plain", unit="N/m"))
    outer = tmp_path / "outer.yaml"
    outer.write_text("format_version: 1\ncomponents:\n"
                     f"  sub: {{type: model, file: {_quoted(inner)}}}\n")
    monkeypatch.setenv("PHC_CACHE_DIR", str(tmp_path / "cache"))
    monkeypatch.chdir(tmp_path)
    compiled = phc.compile_model(outer)
    phc.simulate(compiled, t_end=0.001)
    assert not canary.exists()
    assert_printer_made(compiled.source)
    assert inner in compiled.module.SOURCES


def test_descriptions_and_units_do_not_reach_the_code(tmp_path, monkeypatch):
    canary = tmp_path / "OWNED"
    text = _quoted(payload(canary) + "\n" + payload(canary, quote="'"))
    model = tmp_path / "m.yaml"
    monkeypatch.setenv("PHC_CACHE_DIR", str(tmp_path / "cache"))
    monkeypatch.chdir(tmp_path)
    # a unit is read (docs/units.md): code in it is refused, located, before anything reads it
    model.write_text(OSCILLATOR.format(description=text, unit=text))
    with pytest.raises(phc.ModelError, match=r"m.yaml:\d+:\d+: .*unit.*PHC-E170"):
        phc.compile_model(model)
    assert not canary.exists()
    # a description is text that never reaches the code
    model.write_text(OSCILLATOR.format(description=text, unit="N/m"))
    compiled = phc.compile_model(model)
    phc.simulate(compiled)
    assert not canary.exists()
    assert_printer_made(compiled.source)


def _set(doc: dict, where: str, bad: str) -> None:
    if where == "model name":
        doc["name"] = bad
    elif where == "parameter name":
        doc["parameters"][bad] = 1.0
    elif where == "component name":
        doc["components"][bad] = {"type": "mass", "m": 1}
    elif where == "port name":
        doc["components"]["node"]["ports"].append(bad)
    elif where == "output name":
        doc["simulation"]["outputs"][bad] = "spring.x"


@pytest.mark.parametrize("where", ["model name", "parameter name", "component name", "port name", "output name"])
@pytest.mark.parametrize("bad", ['x"""; import os; """', "x'; import os; '", "x\n", "x\nimport os", "x y", "é"])
def test_names_that_are_not_identifiers_are_refused_with_a_location(tmp_path, where, bad):
    doc = yaml.safe_load(OSCILLATOR.format(description="plain", unit="N/m"))
    _set(doc, where, bad)
    model = tmp_path / "m.yaml"
    model.write_text(yaml.safe_dump(doc, allow_unicode=True))
    with pytest.raises(ModelError) as err:
        phc.compile_model(model)
    first = err.value.diagnostics[0].render()
    assert first.startswith(f"{model}:"), first
    assert "not a valid name" in first, first
    assert "\n" not in first.rstrip("\n"), "a diagnostic is one line"


@pytest.mark.parametrize("expression", [
    "__import__('os').system('touch OWNED')",
    "k.__class__",
    "(lambda: 1)()",
    "open('OWNED', 'w')",
    "[x for x in ()]",
    "k if k else k",
    "spring.x; import os",
])
def test_expressions_outside_the_language_are_refused(tmp_path, expression):
    model = tmp_path / "m.yaml"
    model.write_text(OSCILLATOR.format(description="plain", unit="N/m").replace("x: spring.x", f"x: {_quoted(expression)}"))
    with pytest.raises(ModelError) as err:
        phc.compile_model(model)
    assert err.value.diagnostics[0].render().startswith(f"{model}:")
    assert not (tmp_path / "OWNED").exists() and not Path("OWNED").exists()


@pytest.mark.parametrize("name, meaning", [("H", "energy"), ("t", "time"), ("pi", "π"), ("abs", "function"),
                                           ("sqrt", "function"), ("ifelse", "function")])
def test_phc_names_are_reserved(tmp_path, name, meaning):
    model = tmp_path / "m.yaml"
    model.write_text(OSCILLATOR.format(description="plain", unit="N/m").replace("  k: {", f"  {name}: 1\n  k: {{"))
    with pytest.raises(ModelError) as err:
        phc.compile_model(model)
    line = err.value.diagnostics[0].render()
    assert line.startswith(f"{model}:5:3:"), line
    assert "reserved" in line and meaning in line


@pytest.mark.parametrize("name", ["N", "key", "P_ports", "P_diss", "np", "math", "out", "residual", "MODEL",
                                  "y", "p", "cj", "base", "S"])
def test_user_names_cannot_meet_module_globals(tmp_path, name, monkeypatch):
    """A parameter and a state named like a module global or local of the generated code
    simulate exactly like the same model with innocent names."""
    monkeypatch.setenv("PHC_CACHE_DIR", str(tmp_path / "cache"))
    monkeypatch.chdir(tmp_path)
    text = """\
format_version: 1
parameters: {PNAME: 3.0}
components:
  CNAME:
    type: phs
    states: [SNAME]
    hamiltonian: SNAME**2/(2*PNAME)
    J: [[0]]
    R: [[0.5]]
simulation:
  t_end: 0.5
  n_out: 5
  solver: midpoint
  step: 0.01
  initial: {CNAME.SNAME: 1.0}
  outputs: {x: CNAME.SNAME}
"""
    runs = []
    for k, names in enumerate([("c", "xs", "osc"), (name, "xs", "osc"), ("c", name, "osc"), ("c", "xs", name)]):
        path = tmp_path / f"run{k}.yaml"
        path.write_text(text.replace("PNAME", names[0]).replace("SNAME", names[1]).replace("CNAME", names[2]))
        compiled = phc.compile_model(path)
        assert_printer_made(compiled.source)
        runs.append(phc.simulate(compiled))
    b = runs[0]
    for a in runs[1:]:
        assert a.success
        assert abs(a.outputs["x"] - b.outputs["x"]).max() == 0.0
        assert abs(a.dissipation - b.dissipation).max() == 0.0
    assert b.dissipation[0] == pytest.approx(0.5 * (1.0 / 3.0) ** 2, rel=1e-12)  # R (∂H/∂x)², really computed
    # H = x²/(2c), ẋ = −R ∂H/∂x = −(R/c) x: x(t) = e^{−Rt/c}
    assert b.outputs["x"][-1] == pytest.approx(math.exp(-0.5 * 0.5 / 3.0), rel=1e-4)
