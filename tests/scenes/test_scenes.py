"""Scenes (issue 6): effects on/off, pruning, inputs, located errors, reports."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
from scipy.integrate import solve_ivp

import phc
from phc.cli import main
from phc.errors import ModelError

ROOT = Path(__file__).resolve().parents[2]
MODELS = ROOT / "models"
SCENES = MODELS / "scenes"


def write(path: Path, text: str) -> Path:
    path.write_text(text)
    return path


def diagnostics(path) -> list[str]:
    with pytest.raises(ModelError) as err:
        phc.compile_model(path)
    return [d.render() for d in err.value.diagnostics]


# -- effects ----------------------------------------------------------------------------


def test_flexibility_off_reproduces_the_rigid_slider_crank_kinematics():
    """Evidence (a): the rod as a rigid link; the slider follows r cos θ + √(L² − r² sin² θ)."""
    compiled = phc.compile_model(SCENES / "slider_crank_rigid.yaml")
    assert compiled.n_states < 15  # no curvature / transverse momentum states
    assert any("flexibility" in why for _, _, why in compiled.left_out)
    result = phc.simulate(compiled, t_end=0.02, n_out=41)
    assert result.success, result.message
    err = np.abs(result.outputs["slider_x"] - result.outputs["slider_x_rigid"]).max()
    assert err < 1e-8
    assert result.energy_balance_relative < 1e-10  # midpoint: exact for the quadratic H
    assert result.outputs["theta"][-1] > 1.5  # it did turn (about 150 rad/s at the start)


def test_rigid_link_keeps_mass_and_inertia(tmp_path):
    """The rigid link's kinetic energy is that of a uniform bar: ½mv_c² + ½(mL²/12)ω²."""
    compiled = phc.compile_model(SCENES / "slider_crank_rigid.yaml")
    result = phc.simulate(compiled, t_end=0.005, n_out=6)
    mod = compiled.module
    idx = {n: i for i, n in enumerate(mod.VARIABLES)}
    p = phc.simulation.parameter_vector(mod)
    L, rhoA = 0.30, 0.50368
    m = rhoA * L
    y = result.y[-1]
    M = (m / 6) * np.array([[2, 0, 1, 0], [0, 2, 0, 1], [1, 0, 2, 0], [0, 1, 0, 2]])
    v = np.linalg.solve(M, np.array([y[idx[f"rod.p[{k}]"]] for k in range(4)]))
    v0, vf = v[:2], v[2:]
    vc = (v0 + vf) / 2
    q0 = np.array([y[idx["rod.q0[0]"]], y[idx["rod.q0[1]"]]])
    qf = np.array([y[idx["rod.qf[0]"]], y[idx["rod.qf[1]"]]])
    n = np.array([-(qf - q0)[1], (qf - q0)[0]]) / L
    omega = n @ (vf - v0) / L
    T_rod = 0.5 * m * vc @ vc + 0.5 * (m * L**2 / 12) * omega**2
    T_wheel = y[idx["wheel.p_theta"]] ** 2 / (2 * 1e-3)
    assert mod.hamiltonian(0.0, y, p) == pytest.approx(T_rod + T_wheel, rel=1e-12)


def test_moving_frame_off_drops_the_modulation_terms_and_keeps_the_balance(tmp_path):
    scene = write(tmp_path / "s.yaml", f"""
model: {MODELS / 'flexible_slider_crank.yaml'}
effects: {{rod: {{moving_frame: off}}}}
solver: midpoint
accuracy: {{step: 1.0e-5}}
outputs:
  x: rod.qf[0]
""")
    compiled = phc.compile_model(scene)
    full = phc.compile_model(MODELS / "flexible_slider_crank.yaml")
    assert any("moving_frame" in why for _, _, why in compiled.left_out)
    assert compiled.n_states == full.n_states
    result = phc.simulate(compiled, t_end=0.002, n_out=5, step=1e-4)  # any step: the balance is exact
    assert result.success
    assert result.energy_balance_relative < 1e-10


def test_an_output_needing_an_effect_that_is_off_is_a_located_error(tmp_path):
    """Evidence (d): the midspan deflection of a rigid rod is an error, not a silent zero."""
    scene = write(tmp_path / "s.yaml", f"""model: {MODELS / 'flexible_slider_crank.yaml'}
effects:
  rod: {{flexibility: off}}
outputs:
  x: rod.qf[0]
  mid: rod.w[0]
""")
    lines = diagnostics(scene)
    assert len(lines) == 1
    assert lines[0].startswith(f"{scene}:6:8: outputs.mid:")  # the path as written in the scene
    assert "rod.w[0]" in lines[0] and "flexibility" in lines[0] and "PHC-E604" in lines[0]


def test_effect_mistakes_are_located_in_the_scene(tmp_path):
    scene = write(tmp_path / "s.yaml", f"""model: {MODELS / 'flexible_slider_crank.yaml'}
effects:
  rod: {{stiffness: off}}
  wheeel: {{damping: off}}
  guide: {{damping: off}}
accuracy: {{mesh: {{rail: 4}}}}
""")
    lines = diagnostics(scene)
    text = "\n".join(lines)
    assert f"{scene}:3:" in text and "no effect `stiffness`" in text and "flexibility" in text
    assert f"{scene}:4:3:" in text and "no component `wheeel`" in text
    assert f"{scene}:5:" in text and "no optional effects" in text
    assert f"{scene}:6:" in text and "has no mesh" in text
    assert all(line.startswith(str(scene)) for line in lines)


def test_user_effects_tag_terms_of_the_potential(tmp_path):
    model = write(tmp_path / "pend.yaml", """
format_version: 1
parameters: {m: 1.0, g: 9.81, L: 1.0}
components:
  bob:
    type: rigid
    q: [x, y]
    M: [[m, 0], [0, m]]
    V: {gravity: m*g*y}
    constraints: [x**2 + y**2 - L**2]
simulation:
  t_end: 0.5
  initial: {bob.x: 0.6, bob.y: {value: -0.8, guess: true}, bob.p_v_x: 0.0}
  outputs: {x: bob.x}
""")
    on = phc.simulate(phc.compile_model(model))
    assert on.outputs["x"][-1] < 0.5  # it swings
    scene = write(tmp_path / "s.yaml", "model: pend.yaml\neffects: {bob: {gravity: off}}\n")
    compiled = phc.compile_model(scene)
    assert "g" not in {s.name for s in compiled.dae.hamiltonian.free_symbols}
    off = phc.simulate(compiled)
    assert off.success
    assert np.abs(off.outputs["x"] - 0.6).max() < 1e-9  # at rest without gravity


# -- pruning ------------------------------------------------------------------------------

UNRELATED = """
format_version: 1
parameters: {Iw: 0.01, m: 1.0, k: 4.0}
components:
  wheel: {type: crank_wheel, radius: 0.1, inertia: Iw}
  brake: {type: damper, d: 0.02, domain: mechanical.rotational}
  free_pin: {type: zero_effort, domain: mechanical.translational, dimension: 2}
  mass: {type: mass, m: m}
  spring: {type: spring, k: k}
  node: {type: junction, kind: common_flow, domain: mechanical.translational, ports: [a, b, c]}
  wall: {type: zero_effort, domain: mechanical.translational}
connections:
  - [wheel.drive, brake.port]
  - [wheel.pin, free_pin.port]
  - [node.a, mass.port]
  - [node.b, spring.port]
  - [node.c, wall.port]
simulation:
  t_end: 2.0
  rtol: 1.0e-10
  atol: 1.0e-12
  initial: {wheel.theta: 0.0, wheel.p_theta: 0.1, spring.x: 0.3, mass.p: 0.0}
  outputs: {theta: wheel.theta, x: spring.x}
"""


def test_pruning_leaves_out_what_cannot_influence_the_outputs(tmp_path):
    """Evidence (b): only the wheel angle is requested; the mass–spring is left out."""
    model = write(tmp_path / "model.yaml", UNRELATED)
    scene = write(tmp_path / "scene.yaml", "model: model.yaml\noutputs: {theta: wheel.theta}\n")
    full, pruned = phc.compile_model(model), phc.compile_model(scene)
    assert pruned.n_states < full.n_states
    left = {comp for comp, _, _ in pruned.left_out}
    assert left == {"mass", "spring", "node", "wall"}
    assert pruned.full_size()["states"] == full.n_states
    a, b = phc.simulate(full), phc.simulate(pruned)
    assert a.success and b.success
    assert np.abs(a.outputs["theta"] - b.outputs["theta"]).max() < 1e-8
    # closed form: θ̇ = ω0 exp(−d t / Iw)
    w0, tau = 0.1 / 0.01, 0.01 / 0.02
    assert np.abs(b.outputs["theta"] - w0 * tau * (1 - np.exp(-b.t / tau))).max() < 1e-7


def test_pruning_can_be_switched_off_and_keeps_everything_for_H(tmp_path):
    write(tmp_path / "model.yaml", UNRELATED)
    off = write(tmp_path / "off.yaml", "model: model.yaml\nprune: false\noutputs: {theta: wheel.theta}\n")
    energy = write(tmp_path / "h.yaml", "model: model.yaml\noutputs: {theta: wheel.theta, E: H}\n")
    assert not phc.compile_model(off).left_out
    assert not phc.compile_model(energy).left_out


# -- inputs -------------------------------------------------------------------------------

STEP_MODEL = """
format_version: 1
parameters: {{m: 1.0, k: 4.0}}
components:
  mass: {{type: mass, m: m}}
  spring: {{type: spring, k: k}}
  node: {{type: junction, kind: common_flow, domain: mechanical.translational, ports: [to_mass, to_spring, ext]}}
connections:
  - [node.to_mass, mass.port]
  - [node.to_spring, spring.port]
ports:
  force: {{port: node.ext}}
simulation:
  t_end: 2.0
  n_out: 201
  rtol: 1.0e-10
  atol: 1.0e-12
  inputs:
    force:
      effort: {effort}
  outputs: {{x: spring.x}}
"""


@pytest.mark.parametrize("solver", ["ida", "midpoint"])
def test_a_step_input_is_located_at_its_breakpoint(tmp_path, solver):
    """A force of 1 N switched on at t = 0.5: x = (1 − cos 2(t − 0.5))/4 after it."""
    model = write(tmp_path / "m.yaml", STEP_MODEL.format(effort="[{until: 0.5, value: 0}, {value: -1.0}]"))
    compiled = phc.compile_model(model)
    assert compiled.module.BREAKPOINTS == (0.5,)
    # IDA runs at the model's rtol 1e-10, the midpoint rule at the step 1e-3
    result = phc.simulate(compiled, solver=solver, step=1e-3 if solver == "midpoint" else None)
    assert result.success
    exact = np.where(result.t < 0.5, 0.0, 0.25 * (1 - np.cos(2 * (result.t - 0.5))))
    assert np.abs(result.outputs["x"] - exact).max() < (1e-8 if solver == "ida" else 1e-6)
    assert result.energy_balance_relative < 1e-8


def test_a_table_input_is_interpolated(tmp_path):
    (tmp_path / "force.csv").write_text("t,F\n0,0\n0.5,0\n1.0,-1\n3.0,-1\n")
    model = write(tmp_path / "m.yaml", STEP_MODEL.format(effort="{file: force.csv, column: F}"))
    result = phc.simulate(phc.compile_model(model))
    assert result.success

    def force(t):
        return float(np.interp(t, [0, 0.5, 1.0, 3.0], [0, 0, 1, 1]))

    ref = solve_ivp(lambda t, z: [z[1], force(t) - 4 * z[0]], (0, 2), [0, 0], t_eval=result.t, rtol=1e-11,
                    atol=1e-13, max_step=0.01)
    assert np.abs(result.outputs["x"] - ref.y[0]).max() < 1e-7


def test_table_mistakes_are_located(tmp_path):
    (tmp_path / "force.csv").write_text("t,F\n0,0\n1,x\n")
    model = write(tmp_path / "m.yaml", STEP_MODEL.format(effort="{file: force.csv, column: G}"))
    lines = diagnostics(model)
    assert len(lines) == 1 and "no column `G`" in lines[0] and lines[0].startswith(f"{model}:")
    model = write(tmp_path / "m2.yaml", STEP_MODEL.format(effort="{file: force.csv, column: F}"))
    lines = diagnostics(model)
    assert len(lines) == 1 and "row 3" in lines[0] and "must be numbers" in lines[0]


# -- the CLI --------------------------------------------------------------------------------


def test_cli_reports_what_was_left_out_and_the_size(tmp_path, capsys):
    write(tmp_path / "model.yaml", UNRELATED)
    scene = write(tmp_path / "scene.yaml", "model: model.yaml\nname: wheel_only\noutputs: {theta: wheel.theta}\n")
    assert main(["simulate", str(scene), "--quiet"]) == 0
    out = capsys.readouterr().out
    assert "wheel_only (scene of" in out
    assert "left out mass: the whole component — cannot influence the requested outputs" in out
    assert "full     model model.yaml:" in out
    assert main(["simulate", str(scene), "--quiet", "--format", "json"]) == 0
    data = json.loads(capsys.readouterr().out)
    assert data["scene"] == "wheel_only"
    assert data["compiled"]["states"] < data["full_model"]["states"]
    assert {d["component"] for d in data["left_out"]} == {"mass", "spring", "node", "wall"}


def test_scene_schema_errors_are_located(tmp_path, capsys):
    scene = write(tmp_path / "s.yaml", f"model: {MODELS / 'pendulum.yaml'}\nt_end: -1\nsolvr: ida\n")
    assert main(["validate", str(scene)]) == 1
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 2
    assert err[0].startswith(f"{scene}:2:8:") and err[1].startswith(f"{scene}:3:1:")


def test_missing_model_is_located(tmp_path, capsys):
    scene = write(tmp_path / "s.yaml", "model: nowhere.yaml\n")
    assert main(["simulate", str(scene), "--quiet"]) == 1
    err = capsys.readouterr().err
    assert err.startswith(f"{scene}:1:8:") and "not found" in err


@pytest.mark.parametrize("scene", sorted(p.name for p in SCENES.glob("*.yaml")))
def test_shipped_scenes_compile_and_start(scene):
    """Every shipped scene compiles and its first milliseconds run with the balance closed
    (the full runs are `phc simulate models/scenes/<scene>`)."""
    compiled = phc.compile_model(SCENES / scene)
    assert compiled.scene is not None and compiled.name == compiled.scene.name
    result = phc.simulate(compiled, t_end=0.006, n_out=7)  # past the spin-up's torque step at 5 ms
    assert result.success, result.message
    assert result.energy_balance_relative < 1e-9
    assert result.constraint_drift < 1e-9
    assert set(compiled.scene.spec.outputs) <= set(result.outputs)
