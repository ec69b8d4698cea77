"""Units as an engineer writes them (issue 36 item 4): `unit: 1` (a YAML number) and
`unit: "1"` both mean dimensionless, in every place a unit is accepted (parameters,
outputs); an energy is labelled J, not N*m; a sweep's output columns carry their units
onto the plot's axes."""

from __future__ import annotations

import json
import textwrap
from pathlib import Path

import pytest

import phc
from phc.cli import main
from phc.pipeline import build_dae
from phc.spec import ModelSpec

pytest.importorskip("pint")

REPO = Path(__file__).resolve().parents[1]

GEARED = """\
format_version: 1
parameters:
  m: {{value: 2.0, unit: kg}}
  k: {{value: 50.0, unit: N/m}}
  n: {{value: 3.0, unit: {unit}}}
  x0: {{value: 0.1, unit: m}}
components:
  mass: {{type: mass, m: "m*n"}}
  spring: {{type: spring, k: "k*n**2"}}
connections:
  - [mass.port, spring.port]
simulation:
  t_end: 1.0
  n_out: 11
  initial: {{spring.x: x0, mass.p: 0}}
  outputs:
    phase: {{value: "sin(n)*spring.x/x0", unit: {unit}}}
    energy: H
    spring_energy: k*n**2*spring.x**2/2
"""


@pytest.mark.parametrize("unit", ["1", '"1"', "1.0"])
def test_unit_one_written_as_a_number_or_as_text_is_dimensionless(tmp_path, unit):
    """`n` multiplies a mass and a stiffness and is the argument of `sin`: all three are
    checked, and pass only if `n` is dimensionless."""
    path = tmp_path / "geared.yaml"
    path.write_text(GEARED.format(unit=unit))
    dae, diags = build_dae(path)
    assert [d.render() for d in diags] == []
    assert dae.units["phase"] == "1"


def test_unit_one_in_the_spec_and_the_schema():
    spec = ModelSpec.model_validate({"parameters": {"n": {"value": 3, "unit": 1}},
                                     "components": {"w": {"type": "zero_flow"}},
                                     "simulation": {"outputs": {"r": {"value": "n", "unit": 1}}}})
    assert spec.parameters["n"].unit == "1" and spec.simulation.outputs["r"].unit == "1"
    jsonschema = pytest.importorskip("jsonschema")
    schema = json.loads((REPO / "schemas" / "model.schema.json").read_text())
    model = {"format_version": 1, "parameters": {"n": {"value": 3, "unit": 1}},
             "components": {"w": {"type": "zero_flow"}}, "simulation": {"outputs": {"r": {"value": "n", "unit": 1}}}}
    jsonschema.Draft202012Validator(schema).validate(model)
    model["parameters"]["n"]["unit"] = 2
    assert list(jsonschema.Draft202012Validator(schema).iter_errors(model))


def test_any_other_number_as_a_unit_is_one_line_with_the_hint(tmp_path, capsys):
    path = tmp_path / "geared.yaml"
    path.write_text(GEARED.format(unit="1").replace("n: {value: 3.0, unit: 1}", "n: {value: 3.0, unit: 2}"))
    assert main(["validate", str(path)]) == 1
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1, err
    assert err[0].startswith(f"{path}:5:") and "parameters.n.unit" in err[0]
    assert "got the number `2`" in err[0] and "`1` (dimensionless)" in err[0] and "[PHC-E013]" in err[0]


def test_energies_are_labelled_joule_and_torques_newton_metre(tmp_path):
    """`H` and an energy written out are J (before: N*m, the first named unit of that
    dimension). In a model with rotational ports N*m is also a torque's unit: there a
    quantity of that dimension is J when it is an expression of H, N*m otherwise."""
    path = tmp_path / "geared.yaml"
    path.write_text(GEARED.format(unit="1"))
    dae, _ = build_dae(path)
    assert dae.units["H"] == "J" and dae.units["energy"] == "J" and dae.units["spring_energy"] == "J"
    rotor = textwrap.dedent("""\
        format_version: 1
        parameters:
          J: {value: 0.01, unit: kg*m^2}
          c: {value: 2.0, unit: N*m/rad}
        components:
          rotor: {type: mass, m: J, domain: mechanical.rotational}
          shaft: {type: spring, k: c, domain: mechanical.rotational}
        connections:
          - [rotor.port, shaft.port]
        simulation:
          t_end: 0.1
          initial: {shaft.x: 0.1}
          outputs:
            torque: c*shaft.x
            energy: H
            half: H/2
        """)
    path = tmp_path / "rotor.yaml"
    path.write_text(rotor)
    dae, diags = build_dae(path)
    assert [d.render() for d in diags] == []
    assert dae.units["torque"] == "N*m"
    assert dae.units["energy"] == "J" and dae.units["half"] == "J"


def test_sweep_output_columns_carry_their_units_onto_the_plot(tmp_path, monkeypatch):
    pytest.importorskip("matplotlib")
    from matplotlib.figure import Figure

    from phc.sweep import LocalExecutor, run_sweep
    from phc.sweep.plot import plot_sweep

    model = REPO / "models" / "mass_spring_damper.yaml"
    report = run_sweep(model, tmp_path / "r.csv", params=[("k", "1,2"), ("c", "0.2,0.4")], t_end=0.5,
                       executor=LocalExecutor(1), progress=False)
    assert report.units["x.max"] == "m" and report.units["v.rms"] == "m/s" and report.units["energy.final"] == "J"
    meta = json.loads((tmp_path / "r.sweep.json").read_text())
    assert meta["columns"]["x.max"] == {"unit": "m"}
    figures = []
    monkeypatch.setattr(Figure, "savefig", lambda self, *a, **k: figures.append(self))
    plot_sweep(report, tmp_path / "line.png", "x.max", ["k"])
    assert figures[-1].axes[0].get_ylabel() == "x.max [m]"
    plot_sweep(report, tmp_path / "heat.png", "v.rms", ["k", "c"])
    assert figures[-1].axes[-1].get_ylabel() == "v.rms [m/s]"  # the colour bar
