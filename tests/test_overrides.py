"""Parameter values from outside the model file (`--param`, `phc.simulate(params=...)`, a
sweep's points, a scene's `parameters:`) go through the checks that values written in the
file get (PHC-E405 positive coefficients, PHC-E122 positive definite mass matrices), and
a refusal names where the value came from."""

from __future__ import annotations

import math
import textwrap

import pytest

import phc
from phc.cli import main
from phc.errors import SimulationSetupError
from phc.sweep import run_point

OSCILLATOR = """\
format_version: 1
parameters:
  m: {value: 2.0, unit: kg}
  k: {value: 50.0, unit: N/m}
  c: {value: 0.8, unit: N*s/m}
  x0: {value: 0.1, unit: m}
components:
  mass: {type: mass, m: m}
  spring: {type: spring, k: k}
  damper: {type: damper, d: c}
  node: {type: junction, kind: common_flow, domain: mechanical.translational, ports: [a, b, c]}
connections:
  - [node.a, mass.port]
  - [node.b, spring.port]
  - [node.c, damper.port]
simulation:
  t_end: 0.5
  n_out: 11
  initial: {spring.x: x0, mass.p: 0}
"""

PIVOT = """\
format_version: 1
parameters: {m: 0.5, L: 1.2, g: 9.81}
components:
  bob:
    type: rigid
    q: [x, y]
    v: [vx, vy]
    M: [[m, 0], [0, m]]
    V: m*g*y
    constraints:
      - x**2 + y**2 - L**2
simulation:
  t_end: 0.2
  n_out: 5
  initial: {bob.x: 0.0, bob.y: {value: -1.2, guess: true}, bob.p_vx: 0.1, bob.p_vy: {value: 0, guess: true}}
"""


@pytest.fixture(scope="module")
def oscillator(tmp_path_factory):
    path = tmp_path_factory.mktemp("ovr") / "osc.yaml"
    path.write_text(OSCILLATOR)
    return path


@pytest.fixture(scope="module")
def compiled(oscillator):
    return phc.compile_model(oscillator, certify=False)


def test_cli_param_negative_damping_is_refused_and_names_the_option(oscillator, capsys):
    code = main(["simulate", str(oscillator), "--param", "c=-5", "--quiet"])
    err = capsys.readouterr().err
    assert code == 2
    line = next(ln for ln in err.splitlines() if "--param c=-5" in ln)
    assert "[PHC-E405]" in line and "`d` of `damper` is -5" in line
    assert "osc.yaml:10:29" in line  # where `c` is used: the damper's `d`
    assert "at the default parameters" not in line


def test_cli_param_negative_mass_is_refused(oscillator, capsys):
    assert main(["simulate", str(oscillator), "--param", "m=-2", "--quiet"]) == 2
    assert "--param m=-2: `m` of `mass` is -2; it must be positive" in capsys.readouterr().err


def test_cli_param_allowed_value_still_runs(oscillator, tmp_path, capsys):
    out = tmp_path / "r.csv"
    assert main(["simulate", str(oscillator), "--param", "c=0", "--quiet", "--out", str(out)]) == 0


def test_python_params_are_checked(compiled):
    with pytest.raises(SimulationSetupError, match=r"parameter `m` = -1: .*\[PHC-E405\]"):
        phc.simulate(compiled, params={"m": -1.0})
    # a valid override runs, and gives the undamped closed form x0*cos(sqrt(k/m) t)
    result = phc.simulate(compiled, params={"c": 0.0}, rtol=1e-10, atol=1e-12)
    assert result.success
    x = result["spring.x"]
    w = math.sqrt(50.0 / 2.0)
    assert abs(x[-1] - 0.1 * math.cos(w * result.t[-1])) < 1e-6


def test_sweep_point_with_refused_value_fails(compiled):
    bad = run_point(compiled, {"index": 0, "params": {"c": -1.0, "m": 2.0}, "options": {}, "run": {}})
    assert bad["row"]["success"] is False and "PHC-E405" in bad["row"]["message"]
    good = run_point(compiled, {"index": 1, "params": {"c": 0.5, "m": 2.0}, "options": {}, "run": {}})
    assert good["row"]["success"] is True


def test_rigid_mass_matrix_override_is_refused(tmp_path):
    path = tmp_path / "pivot.yaml"
    path.write_text(PIVOT)
    compiled = phc.compile_model(path, certify=False)
    with pytest.raises(SimulationSetupError, match=r"not positive definite.*\[PHC-E122\]"):
        phc.simulate(compiled, params={"m": -1.0})


def test_scene_override_refusal_names_the_scene(oscillator, tmp_path, capsys):
    (tmp_path / "osc.yaml").write_text(OSCILLATOR)
    scene = tmp_path / "neg.scene.yaml"
    scene.write_text(textwrap.dedent("""\
        format_version: 1
        model: osc.yaml
        parameters: {m: -2}
        """))
    assert main(["validate", str(scene)]) != 0
    captured = capsys.readouterr()
    err = captured.out + captured.err
    assert "the scene's `m` = -2 (" in err and "neg.scene.yaml:3:" in err and "[PHC-E405]" in err


def test_simulate_accepts_a_path_and_refuses_other_objects(oscillator):
    result = phc.simulate(str(oscillator), t_end=0.1)
    assert result.success
    with pytest.raises(TypeError, match="compiled model"):
        phc.simulate(42)
