"""phc does not convert units, so a model's numbers must be in one system of units: a unit
that passes the dimension check but is in another scale than the rest of the model is
refused with the factor (PHC-E172), where it is written. Before, 60 rpm drove a damper as
60 rad/s, 4 N/mm beside a mass in kg was used as 4 N/m, and a table column `P [bar]` or
`t [ms]` was read as Pa or s — all without a word. A consistent non-SI system (mm, g, ms)
still runs, and a table column written as phc writes its own results (`P [Pa]`) can be
named by its bare name."""

from __future__ import annotations

import math
import textwrap

import numpy as np
import pytest

import phc
from phc.cli import main

pytest.importorskip("pint")


def _refusal(capsys, path) -> str:
    assert main(["validate", str(path)]) == 1
    out = capsys.readouterr()
    lines = [ln for ln in (out.out + out.err).splitlines() if "PHC-E172" in ln]
    assert len(lines) == 1, out.out + out.err
    return lines[0]


def test_a_speed_in_rpm_feeding_a_damper_in_si_is_refused_with_the_conversion(tmp_path, capsys):
    path = tmp_path / "rpm.yaml"
    path.write_text(textwrap.dedent("""\
        format_version: 1
        parameters:
          w: {value: 60.0, unit: rpm}
          c: {value: 0.5, unit: N*m*s/rad}
        components:
          drive: {type: flow_source, domain: mechanical.rotational, value: w}
          brake: {type: damper, d: c, domain: mechanical.rotational}
        connections:
          - [drive.port, brake.port]
        """))
    line = _refusal(capsys, path)
    assert line.startswith(f"{path}:6:68: components.drive.value")  # at the source's `value: w`
    # 1 rpm = 2π/60 rad/s
    assert f"1 rpm = {2 * math.pi / 60:.4g} rad/s" in line
    assert f"give w in rad/s: 60 rpm = {2 * math.pi:.4g} rad/s" in line


def _mass_spring(m_unit: str, k_unit: str, x_unit: str, m: float = 1.0, k: float = 4.0, x0: float = 0.01,
                 t_end: float = 1.0, n_out: int = 2) -> str:
    return textwrap.dedent(f"""\
        format_version: 1
        parameters:
          k: {{value: {k}, unit: "{k_unit}"}}
          m: {{value: {m}, unit: {m_unit}}}
          x0: {{value: {x0}, unit: {x_unit}}}
        components:
          mass: {{type: mass, m: m}}
          spring: {{type: spring, k: k}}
        connections:
          - [mass.port, spring.port]
        simulation:
          t_end: {t_end}
          n_out: {n_out}
          rtol: 1.0e-10
          atol: 1.0e-12
          initial: {{spring.x: x0, mass.p: 0}}
          outputs: {{x: spring.x}}
        """)


def test_a_stiffness_in_n_per_mm_beside_a_mass_in_kg_is_refused_with_the_factor(tmp_path, capsys):
    # k·x in N/mm · m = kN against ṗ in kg·m/s² = N: a factor 1000
    path = tmp_path / "mixed.yaml"
    path.write_text(_mass_spring("kg", "N/mm", "m"))
    line = _refusal(capsys, path)
    assert line.startswith(f"{path}:8:29: components.spring.k:")
    assert "must be in N/m" in line and "1 N/mm = 1000 N/m" in line
    assert "give k in N/m: 4 N/mm = 4000 N/m" in line


def test_a_consistent_mm_g_ms_mass_spring_runs_and_matches_its_closed_form(tmp_path):
    # m = 2 g, k = 0.5 N/mm, x0 = 10 mm: the force is in N (g·mm/ms²), the time in ms and
    # ω = sqrt(k/m) = sqrt(500 N/m / 0.002 kg) = 500 rad/s = 0.5 rad/ms
    path = tmp_path / "mm_g_ms.yaml"
    path.write_text(_mass_spring("g", "N/mm", "mm", m=2.0, k=0.5, x0=10.0, t_end=10.0, n_out=21))
    result = phc.simulate(phc.compile_model(path, certify=False))
    assert result.success
    t = np.asarray(result.t)
    assert np.max(np.abs(np.asarray(result["x"]) - 10.0 * np.cos(0.5 * t))) < 1e-6


def _tank(tmp_path, header: str, rows: str, entry: str) -> object:
    (tmp_path / "p.csv").write_text(header + "\n" + rows)
    path = tmp_path / "tank.yaml"
    path.write_text(textwrap.dedent(f"""\
        format_version: 1
        parameters:
          R: {{value: 2.0, unit: Pa*s/m^3}}
          C: {{value: 0.5, unit: m^3/Pa}}
        components:
          valve: {{type: resistor, R: R, domain: hydraulic, terminals: [a, b]}}
          tank: {{type: capacitor, C: C, domain: hydraulic}}
        connections:
          - [valve.b, tank.port]
        ports:
          supply: {{port: valve.a}}
        simulation:
          t_end: 2.0
          n_out: 5
          rtol: 1.0e-10
          atol: 1.0e-12
          inputs:
            supply: {{effort: {entry}}}
          outputs: {{q: tank.q}}
        """))
    return path


def test_a_table_column_in_bar_for_a_pressure_in_pa_is_refused_at_the_column(tmp_path, capsys):
    path = _tank(tmp_path, "t [s],P [bar]", "0,3\n1,3\n", '{file: p.csv, column: "P [bar]"}')
    line = _refusal(capsys, path)
    assert line.startswith(f"{path}:18:44: simulation.inputs.supply.effort.column:")
    assert "column `P [bar]`" in line and "is in Pa" in line and "1 bar = 1e+05 Pa" in line
    assert "`P [Pa]`" in line  # the fix: the header phc reads


def test_a_time_column_in_ms_is_refused_at_the_time_column(tmp_path, capsys):
    path = _tank(tmp_path, "t [ms],P [Pa]", "0,3\n1000,3\n", '{file: p.csv, column: P, time_column: "t [ms]"}')
    line = _refusal(capsys, path)
    assert line.startswith(f"{path}:18:60: simulation.inputs.supply.effort.time_column:")
    assert "column `t [ms]`" in line and "1 ms = 0.001 s" in line


def test_a_table_in_phc_s_own_header_format_is_read_by_bare_names_and_runs(tmp_path):
    # header `t [s],P [Pa]` as phc writes its results; `column: P` and the default time
    # column `t` name it. A step of 3 Pa through R = 2 Pa·s/m³ into C = 0.5 m³/Pa:
    # |q(t)| = C·P0·(1 - exp(-t/(R·C))) with R·C = 1 s.
    path = _tank(tmp_path, "t [s],P [Pa]", "0,3\n1,3\n", "{file: p.csv, column: P}")
    result = phc.simulate(phc.compile_model(path, certify=False))
    assert result.success
    t = np.asarray(result.t)
    expected = 0.5 * 3.0 * (1.0 - np.exp(-t))
    assert np.max(np.abs(np.abs(np.asarray(result["q"])) - expected)) < 1e-7


def test_an_input_expression_in_bar_for_a_pressure_in_pa_is_refused_at_its_value(tmp_path, capsys):
    path = _tank(tmp_path, "t [s],P [Pa]", "0,3\n1,3\n", "P0")
    path.write_text(path.read_text().replace("  C: {value: 0.5, unit: m^3/Pa}\n",
                                             "  C: {value: 0.5, unit: m^3/Pa}\n  P0: {value: 2.0, unit: bar}\n"))
    line = _refusal(capsys, path)
    assert line.startswith(f"{path}:19:22: simulation.inputs.supply.effort:")
    assert "1 bar = 1e+05 Pa" in line and "give P0 in Pa: 2 bar = 2e+05 Pa" in line
