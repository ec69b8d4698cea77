"""An initial value written in another scale than its state (mm for a spring whose
stiffness is in N/m) is refused at its `initial:` entry: phc does not convert units, and
using 10 mm as 10 m changed the stored energy by a factor 10⁶ without a word."""

from __future__ import annotations

import textwrap

import pytest

import phc
from phc.cli import main

pytest.importorskip("pint")


def _model(x0_unit: str, k_unit: str = "N/m", x0: float = 10.0, m_unit: str = "kilogram") -> str:
    return textwrap.dedent(f"""\
        format_version: 1
        parameters:
          m: {{value: 1.0, unit: {m_unit}}}
          k: {{value: 4.0, unit: "{k_unit}"}}
          x0: {{value: {x0}, unit: {x0_unit}}}
        components:
          mass: {{type: mass, m: m}}
          spring: {{type: spring, k: k}}
        connections:
          - [mass.port, spring.port]
        simulation:
          t_end: 0.5
          n_out: 3
          initial: {{spring.x: x0}}
        """)


def test_initial_value_in_mm_for_a_state_in_m_is_refused_at_its_entry(tmp_path, capsys):
    path = tmp_path / "e7.yaml"
    path.write_text(_model("mm"))
    assert main(["validate", str(path)]) == 1
    out = capsys.readouterr()
    line = next(ln for ln in (out.out + out.err).splitlines() if "PHC-E172" in ln)
    assert line.startswith(f"{path}:14:23:")  # the `initial:` entry
    assert "simulation.initial.spring.x" in line
    assert "`spring.x` is in m" in line and "mm" in line and "0.001" in line


def test_initial_value_in_m_runs_with_the_closed_form_energy(tmp_path):
    path = tmp_path / "ok.yaml"
    path.write_text(_model("m", x0=0.01))
    result = phc.simulate(phc.compile_model(path, certify=False))
    assert result.success
    assert abs(result["H"][0] - 0.5 * 4.0 * 0.01 ** 2) < 1e-15  # k x0²/2 = 2e-4 J


def test_a_consistent_scaled_system_is_not_refused(tmp_path, capsys):
    # mm, g and ms throughout (the force comes out in N, the stiffness in N/mm): not SI,
    # phc uses the values as written (N/mm beside kg would be refused: tests/test_unit_scales.py)
    path = tmp_path / "scaled.yaml"
    path.write_text(_model("mm", k_unit="N/mm", m_unit="g"))
    assert main(["validate", str(path)]) == 0


def test_a_scene_initial_value_in_mm_is_refused(tmp_path, capsys):
    (tmp_path / "model.yaml").write_text(_model("m", x0=0.01).replace(
        "  x0: {value: 0.01, unit: m}\n", "  x0: {value: 0.01, unit: m}\n  x_mm: {value: 10, unit: mm}\n"))
    scene = tmp_path / "s.scene.yaml"
    scene.write_text("format_version: 1\nmodel: model.yaml\ninitial: {spring.x: x_mm}\n")
    assert main(["validate", str(scene)]) == 1
    out = capsys.readouterr()
    assert "PHC-E172" in out.out + out.err and "mm" in out.out + out.err


def test_inconsistent_fixed_initial_values_are_located_with_a_code(tmp_path, capsys):
    # x² + y² = L² cannot hold with x = 0.6, y = 0, L = 1 (residual 0.36 - 1 = -0.64)
    path = tmp_path / "fixed.yaml"
    path.write_text(textwrap.dedent("""\
        format_version: 1
        parameters: {m: 1.0, L: 1.0, g: 9.81}
        components:
          pendulum:
            type: rigid
            q: [x, y]
            M: [[m, 0], [0, m]]
            V: m*g*y
            constraints: [x**2 + y**2 - L**2]
        simulation:
          initial: {pendulum.x: 0.6, pendulum.y: 0.0}
        """))
    for _ in range(2):  # the second run may come from the cached front end, which keeps no spans
        assert main(["simulate", str(path), "--quiet", "--no-certify"]) == 1
        err = capsys.readouterr().err.strip().splitlines()
        assert len(err) == 1
        assert err[0].startswith(f"{path}:11:25: simulation.initial.pendulum.x: inconsistent initial values")
        assert "violated by -0.64" in err[0] and err[0].endswith("[PHC-E218]")
