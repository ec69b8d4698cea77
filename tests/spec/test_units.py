"""Units (issue 15 item 3, docs/units.md): parameter and output units parsed by pint, every
expression checked for dimensional consistency where its names carry units, component
fields checked against the dimension their port domain fixes, connections of different
domains refused, and units in CSV headers, the JSON summary and plot axes."""

from __future__ import annotations

import csv
import json
import re
import textwrap
from pathlib import Path

import numpy as np
import pytest

pytest.importorskip("pint")

import phc.frontend.units as units
from phc.cli import main
from phc.pipeline import build_dae

LINE = re.compile(r"^(?P<file>[^:]+):(?P<line>\d+):(?P<col>\d+): (?P<rest>.*) \[(?P<code>PHC-[EW]\d{3})\]$")


def write(tmp_path: Path, text: str, name: str = "model.yaml") -> Path:
    path = tmp_path / name
    path.write_text(textwrap.dedent(text), encoding="utf-8")
    return path


def diagnostics(path: Path) -> list[tuple[int, int, str, str]]:
    """(line, column, code, text) of each diagnostic, each one a located single line."""
    _, diags = build_dae(path)
    out = []
    for d in diags:
        line = d.render()
        match = LINE.match(line)
        assert match, f"not a located one-line diagnostic: {line}"
        assert match["file"] == str(path)
        out.append((int(match["line"]), int(match["col"]), match["code"], line))
    return out


SPRING_MASS = """\
    format_version: 1
    parameters:
      k: {value: 40.0, unit: N/m}
      m: {value: 2.0, unit: kg}
      x0: {value: 0.1, unit: m}
    components:
      mass: {type: mass, m: m}
      spring: {type: spring, k: K_FIELD}
    connections:
      - [mass.port, spring.port]
    simulation:
      t_end: 1.0
      n_out: 11
      initial: {spring.x: x0, mass.p: 0}
      outputs:
        x: spring.x
        v: mass.p / m
        force: mass.port.e
        stroke: {value: spring.x, unit: mm}
"""


def test_unknown_unit_is_a_located_error_naming_it(tmp_path):
    path = write(tmp_path, """\
        format_version: 1
        parameters:
          m: {value: 2.0, unit: bananas}
        components:
          mass: {type: mass, m: m}
          wall: {type: zero_flow}
        connections:
          - [mass.port, wall.port]
        """)
    [(line, col, code, text)] = diagnostics(path)
    assert (line, code) == (3, "PHC-E170")
    assert col == 25  # the unit's text, not the parameter
    assert "unknown unit `bananas`" in text and "hint:" in text


def test_misspelt_unit_gets_a_did_you_mean(tmp_path):
    path = write(tmp_path, SPRING_MASS.replace("unit: kg}", "unit: Kg}").replace("K_FIELD", "k"))
    [(_, _, code, text)] = diagnostics(path)
    assert code == "PHC-E170" and "unknown unit `Kg`" in text and "did you mean `kg`?" in text


def test_stiffness_plus_mass_is_a_located_error_naming_both_dimensions(tmp_path):
    path = write(tmp_path, SPRING_MASS.replace("K_FIELD", '"k + m"'))
    [(line, col, code, text)] = diagnostics(path)
    assert (line, code) == (8, "PHC-E171")
    assert col == 29  # where `k + m` starts
    assert "`k` is N/m ([mass]·[time]⁻²)" in text and "`m` is kg ([mass])" in text


def test_field_with_the_wrong_dimension_for_its_domain(tmp_path):
    path = write(tmp_path, SPRING_MASS.replace("K_FIELD", "m"))
    [(line, _, code, text)] = diagnostics(path)
    assert (line, code) == (8, "PHC-E172")
    assert "must be effort/displacement" in text and "N/m in mechanical.translational" in text


def test_rotational_and_electrical_fields_follow_their_domain(tmp_path):
    path = write(tmp_path, """\
        format_version: 1
        parameters:
          J: {value: 0.01, unit: kg*m^2}
          k: {value: 5.0, unit: N*m/rad}
          L: {value: 0.01, unit: H}
          C: {value: 1.0e-3, unit: F}
          Km: {value: 0.05, unit: N*m/A}
        components:
          rotor: {type: mass, m: J, domain: mechanical.rotational}
          shaft: {type: spring, k: k, domain: mechanical.rotational}
          node: {type: junction, kind: common_flow, domain: mechanical.rotational, ports: [r, s, g]}
          motor: {type: gyrator, ratio: Km, domain_a: electrical, domain_b: mechanical.rotational}
          coil: {type: inductor, L: L}
          cap: {type: capacitor, C: C}
          loop: {type: junction, kind: common_flow, domain: electrical, ports: [l, c, m]}
        connections:
          - [rotor.port, node.r]
          - [shaft.port, node.s]
          - [node.g, motor.b]
          - [motor.a, loop.m]
          - [coil.port, loop.l]
          - [cap.port, loop.c]
        """)
    assert diagnostics(path) == []
    wrong = path.read_text().replace("unit: N*m/A", "unit: N/A")
    [(line, _, code, text)] = diagnostics(write(tmp_path, wrong))
    assert (line, code) == (12, "PHC-E172") and "`ratio` of `motor`" in text


def test_derived_parameters_get_and_check_units(tmp_path):
    text = SPRING_MASS.replace("K_FIELD", "k").replace(
        "  x0: {value: 0.1, unit: m}\n",
        "  x0: {value: 0.1, unit: m}\n      w: {value: 'sqrt(k/m)', unit: rad/s}\n      w2: 'k/m'\n"
        "      bad: {value: 'k*x0', unit: m}\n      s: {value: 'sin(k)', unit: '1'}\n")
    found = diagnostics(write(tmp_path, text))
    assert [(code, line) for _, line, code, _ in [(0, ln, c, t) for ln, _, c, t in found]] == [
        ("PHC-E172", 8), ("PHC-E171", 9)]
    assert "declared in m ([length])" in found[0][3] and "`k*x0` is in N" in found[0][3]
    assert "the argument of `sin` must be dimensionless" in found[1][3]


def test_terms_of_one_dimension_but_different_scales(tmp_path):
    text = SPRING_MASS.replace("K_FIELD", "k").replace(
        "  x0: {value: 0.1, unit: m}\n", "  x0: {value: 0.1, unit: m}\n      d: {value: 5, unit: mm}\n"
        "      l: 'x0 + d'\n")
    [(_, _, code, text)] = diagnostics(write(tmp_path, text))
    assert code == "PHC-E171" and "different scales" in text and "phc does not convert units" in text


def test_a_consistent_model_in_scaled_units_passes():
    """The hydraulic cylinder works in MPa and cm³ (a consistent, non-SI system)."""
    assert diagnostics(Path("models/hydraulic_cylinder.yaml")) == []


def test_some_parameters_without_units_is_a_warning(tmp_path):
    text = SPRING_MASS.replace("K_FIELD", "k").replace("  m: {value: 2.0, unit: kg}", "  m: 2.0")
    [(line, col, code, text)] = diagnostics(write(tmp_path, text))
    assert (line, col, code) == (4, 3, "PHC-W170")
    assert "warning:" in text and "`m`" in text


def test_a_model_without_units_is_unchanged(tmp_path):
    text = re.sub(r"\{value: ([0-9.]+), unit: [^}]+\}", r"\1", SPRING_MASS.replace("K_FIELD", "k"))
    text = text.replace("stroke: {value: spring.x, unit: mm}", "stroke: spring.x")
    path = write(tmp_path, text)
    assert diagnostics(path) == []
    dae, _ = build_dae(path)
    assert dae.units == {}


def test_output_and_initial_value_units(tmp_path):
    path = write(tmp_path, SPRING_MASS.replace("K_FIELD", "k"))
    dae, diags = build_dae(path)
    assert not diags
    assert dae.units["x"] == "m" and dae.units["v"] == "m/s" and dae.units["force"] == "N"
    assert dae.units["stroke"] == "mm"  # declared
    assert dae.units["H"] == "J" and dae.units["mass.p"] == "kg*m/s"
    wrong = SPRING_MASS.replace("K_FIELD", "k").replace("spring.x: x0", "spring.x: m").replace(
        "unit: mm}", "unit: kg}")
    found = diagnostics(write(tmp_path, wrong))
    assert [c for _, _, c, _ in found] == ["PHC-E172", "PHC-E172"]
    assert "initial value of `spring.x`" in found[0][3] and "output `stroke` is declared in kg" in found[1][3]


def test_connection_of_different_domains_is_refused_with_their_units(tmp_path):
    path = write(tmp_path, """\
        format_version: 1
        components:
          mass: {type: mass, m: 1.0}
          cap: {type: capacitor, C: 1.0}
        connections:
          - [mass.port, cap.port]
        """)
    [(line, _, code, text)] = diagnostics(path)
    assert (line, code) == (6, "PHC-E204")
    assert "(effort N, flow m/s)" in text and "(effort V, flow A)" in text


def test_units_in_csv_header_json_and_plot(tmp_path, capsys):
    path = write(tmp_path, SPRING_MASS.replace("K_FIELD", "k"))
    out = tmp_path / "r.csv"
    assert main(["simulate", str(path), "--quiet", "--format", "json", "--out", str(out)]) == 0
    summary = json.loads(capsys.readouterr().out)
    assert summary["units"]["x"] == "m" and summary["units"]["stroke"] == "mm"
    with out.open(newline="") as fh:
        rows = list(csv.reader(fh))
    header = rows[0]
    for column in ("t [s]", "spring.x [m]", "output.x [m]", "output.v [m/s]", "output.force [N]",
                   "output.stroke [mm]", "H [J]", "P_diss [W]"):
        assert column in header
    data = np.array(rows[1:], dtype=float)
    k, m, x0 = 40.0, 2.0, 0.1
    t = data[:, header.index("t [s]")]
    np.testing.assert_allclose(data[:, header.index("output.x [m]")], x0 * np.cos(np.sqrt(k / m) * t), atol=1e-6)

    pytest.importorskip("matplotlib")
    from phc import simulate
    from phc.pipeline import compile_model
    from phc.study.viz import outputs_figure

    result = simulate(compile_model(path))
    figure = outputs_figure(result, ["x", "force"])
    assert [ax.get_ylabel() for ax in figure.axes] == ["x [m]", "force [N]"]


def test_unit_text_is_whitelisted_before_pint_reads_it():
    for text in ("__import__('os')", "m; rm", "N/m\"\"\"", "m**99999999", "x" * 100):
        with pytest.raises(units.UnitError):
            units.parse_unit(text)
    assert units.unit_label(units.parse_unit("N*m/rad")) == "N*m/rad"
    assert units.unit_label(units.parse_unit("kg*m/s^2")) == "N"


def test_without_pint_units_are_only_spelled_and_a_warning_says_so(tmp_path, monkeypatch):
    monkeypatch.setattr(units, "_registry", lambda: None)
    monkeypatch.setattr(units, "have_pint", lambda: False)  # the SI table is read only where pint is installed
    units.parse_unit.cache_clear()
    units.domain_units.cache_clear()
    try:
        path = write(tmp_path, SPRING_MASS.replace("K_FIELD", '"k + m"'))
        found = diagnostics(path)
        assert [c for _, _, c, _ in found] == ["PHC-W172"]
        bad = write(tmp_path, SPRING_MASS.replace("K_FIELD", "k").replace("unit: kg", "unit: \"kg'\""), "bad.yaml")
        assert sorted(c for _, _, c, _ in diagnostics(bad)) == ["PHC-E170", "PHC-W172"]
    finally:
        units.parse_unit.cache_clear()
        units.domain_units.cache_clear()


@pytest.mark.parametrize("model, expected", [
    ("rlc_circuit", {"charge": "C", "current": "A", "capacitor_voltage": "V", "H": "J"}),
    ("thermal_ladder", {"T1": "K", "T2": "K", "T3": "K"}),
    # a torsion spring stores N·m/rad · rad² = J (radians are dimensionless)
    ("dc_motor_gear", {"current": "A", "shaft_torque": "N*m", "H": "J"}),
    ("rigid_slider_crank", {"slider_x": "m", "slider_x_exact": "m", "drive_torque": "N*m"}),
    ("pendulum", {"angle": "rad", "rod_length_error": "m"}),
])
def test_shipped_models_label_their_results(model, expected):
    dae, diags = build_dae(Path("models") / f"{model}.yaml")
    # thermal_ladder's heater is wired against the drawn sign on purpose (its value is −P):
    # the sign hint says so (PHC-W230, docs/signs.md); no other diagnostic
    assert [d.code for d in diags] == (["PHC-W230"] if model == "thermal_ladder" else [])
    assert {name: dae.units.get(name) for name in expected} == expected


def test_a_model_in_scaled_units_labels_only_what_it_declares():
    """MPa and cm³: the port variables are not in the hydraulic domain's SI units."""
    dae, _ = build_dae(Path("models/hydraulic_cylinder.yaml"))
    assert dae.units == {}
