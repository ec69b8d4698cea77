"""Signal blocks and feedback sources that read port variables (`coil.port.f`,
`cap.port.e`, `drag.port.f`), chains of blocks, and the algebraic loop a reading may close
(PHC-E129; docs/how-to/controllers.md, "Reading a port flow or effort").

Each closed loop is checked against its equations written out here by hand and integrated
by scipy at rtol 1e-11 (phc's IDA at 1e-10): the tolerances of the comparisons allow for
the global error of the looser of the two over the run.
"""

from __future__ import annotations

import inspect

import numpy as np
import pytest
from scipy.integrate import solve_ivp

import phc
from phc.simulation.initial import consistent_initial_conditions

TIGHT = dict(rtol=1e-11, atol=1e-13, method="LSODA")

# A PI current controller on a DC motor: it reads the coil's current as the flow of the
# coil's port and sets the supply voltage.
#   e = i_ref − i,  z' = e,  V = Kp e + Ki z
#   L i' = V − R i − Km ω,   J ω' = Km i − c ω
CURRENT_LOOP = """
format_version: 1
parameters: {R: 1.0, L: 0.01, Km: 0.05, J: 1.0e-4, c: 2.0e-5, i_ref: 2.0, Kp: 5.0, Ki: 500.0}
components:
  ctrl: {type: pi, input: "i_ref - coil.port.f", Kp: Kp, Ki: Ki}
  supply: {type: effort_source, domain: electrical, value: "ctrl.y"}
  winding: {type: resistor, R: R}
  coil: {type: inductor, L: L}
  loop: {type: junction, kind: common_flow, domain: electrical, ports: [s, r, l, m]}
  motor: {type: gyrator, ratio: Km, domain_a: electrical, domain_b: mechanical.rotational}
  shaft: {type: junction, kind: common_flow, domain: mechanical.rotational, ports: [m, j, f]}
  rotor: {type: mass, m: J, domain: mechanical.rotational}
  friction: {type: damper, d: c, domain: mechanical.rotational}
connections:
  - [supply.port, loop.s]
  - [winding.port, loop.r]
  - [coil.port, loop.l]
  - [loop.m, motor.a]
  - [motor.b, shaft.m]
  - [shaft.j, rotor.port]
  - [shaft.f, friction.port]
simulation:
  t_end: 0.2
  n_out: 401
  rtol: 1.0e-10
  atol: 1.0e-12
  outputs:
    i: coil.port.f
    w: rotor.p / J
    V: ctrl.y
"""
R, L, Km, J, c, i_ref, Kp, Ki = 1.0, 0.01, 0.05, 1e-4, 2e-5, 2.0, 5.0, 500.0


def current_loop(t, y):
    i, w, z = y
    e = i_ref - i
    V = Kp * e + Ki * z
    return [(V - R * i - Km * w) / L, (Km * i - c * w) / J, e]


# A lag filters the speed of a mass, read as the flow of its damper's port; a PI speed
# controller reads the lag's output and sets the force (a chain lag → pi).
#   ẋ = v,  m v' = −k x − d v + F,  τ s' = v − s,  z' = v_ref − s,  F = Kp (v_ref − s) + Ki z
SPEED_LOOP = """
format_version: 1
parameters: {m: 2.0, k: 8.0, d: 0.5, tau: 0.1, v_ref: 1.0, Kp: 3.0, Ki: 5.0}
components:
  body: {type: mass, m: m}
  spring: {type: spring, k: k}
  drag: {type: damper, d: d}
  ctrl: {type: pi, input: "v_ref - sensor.y", Kp: Kp, Ki: Ki}
  sensor: {type: state_space, input: ["drag.port.f"], A: [[-1/tau]], B: [[1/tau]], C: [[1]]}
  drive: {type: effort_source, value: "ctrl.y"}
  node: {type: junction, kind: common_flow, ports: [m, s, d, f]}
connections:
  - [node.m, body.port]
  - [node.s, spring.port]
  - [node.d, drag.port]
  - [node.f, drive.port]
simulation:
  t_end: 4.0
  n_out: 401
  rtol: 1.0e-10
  atol: 1.0e-12
  outputs:
    v: body.p / m
    x: spring.x
    s: sensor.y
    z: ctrl.z
"""
m, k, d, tau, v_ref, Kpv, Kiv = 2.0, 8.0, 0.5, 0.1, 1.0, 3.0, 5.0


def speed_loop(t, y):
    x, v, s, z = y
    F = Kpv * (v_ref - s) + Kiv * z
    return [v, (-k * x - d * v + F) / m, (v - s) / tau, v_ref - s]


# A voltage reading: a current source charges a capacitor in series with a resistor; a PI
# controller reads the capacitor's voltage from the effort of its port and sets the current.
# An electrical port reads its node power-in, e = −u (docs/signs.md), so the error is
# u_ref − u = u_ref + cap.port.e.
#   C u' = I,  z' = u_ref − u,  I = Kp (u_ref − u) + Ki z
VOLTAGE_LOOP = """
format_version: 1
parameters: {R: 2.0, C: 0.1, u_ref: 1.0, Kp: 3.0, Ki: 5.0}
components:
  cap: {type: capacitor, C: C}
  res: {type: resistor, R: R}
  ctrl: {type: pi, input: "u_ref + cap.port.e", Kp: Kp, Ki: Ki}
  drive: {type: flow_source, domain: electrical, value: "ctrl.y"}
  node: {type: junction, kind: common_flow, domain: electrical, ports: [s, r, c]}
connections:
  - [drive.port, node.s]
  - [res.port, node.r]
  - [cap.port, node.c]
simulation:
  t_end: 2.0
  n_out: 401
  rtol: 1.0e-10
  atol: 1.0e-12
  outputs:
    u: cap.q / C
    z: ctrl.z
"""
Cc, u_ref = 0.1, 1.0


def voltage_loop(t, y):
    u, z = y
    current = 3.0 * (u_ref - u) + 5.0 * z
    return [current / Cc, u_ref - u]


CASES = {
    "current": (CURRENT_LOOP, current_loop, [0.0, 0.0, 0.0], ["i", "w", "z"]),
    "lag_pi": (SPEED_LOOP, speed_loop, [0.0, 0.0, 0.0, 0.0], ["x", "v", "s", "z"]),
    "voltage": (VOLTAGE_LOOP, voltage_loop, [0.0, 0.0], ["u", "z"]),
}


def _write(tmp_path, text, name="m.yaml"):
    path = tmp_path / name
    path.write_text(text)
    return path


def _reference(case, t):
    _, f, y0, names = CASES[case]
    sol = solve_ivp(f, (t[0], t[-1]), y0, t_eval=t, **TIGHT)
    assert sol.success
    return dict(zip(names, sol.y))


@pytest.mark.parametrize("backend", ["numpy", "numba"])
@pytest.mark.parametrize("case", list(CASES))
def test_a_loop_closed_through_a_port_reading_matches_its_equations(tmp_path, case, backend):
    text = CASES[case][0]
    if case == "current":
        text = text.replace("    V: ctrl.y\n", "    V: ctrl.y\n    z: ctrl.z\n")
    r = phc.simulate(phc.compile_model(_write(tmp_path, text), backend=backend))
    assert r.success, r.message
    ref = _reference(case, r.t)
    for name, expected in ref.items():
        scale = max(1.0, np.abs(expected).max())
        # both integrations are far below 1e-7 relative over the run (rtol 1e-10 and 1e-11)
        assert np.abs(r.outputs[name] - expected).max() < 1e-7 * scale, name
        assert np.abs(expected).max() > 1e-2, name  # not a trivial signal
    assert r.energy_balance_relative < 1e-6


def test_the_reading_is_the_port_variable_as_outputs_name_it(tmp_path):
    """`coil.port.f` is the coil's current φ/L, in a block's input as in an output."""
    text = CURRENT_LOOP.replace("    V: ctrl.y\n", "    V: ctrl.y\n    i_state: coil.phi / L\n")
    r = phc.simulate(phc.compile_model(_write(tmp_path, text)))
    assert r.success, r.message
    size = np.abs(r.outputs["i"]).max()
    # the same variable of the same solution: equal to round-off where the algebraic unknowns
    # are polished from the states (every output time after the first)
    assert np.abs(r.outputs["i"] - r.outputs["i_state"])[1:].max() <= 1e-12 * size
    # at t0 the port current is the consistent initialization's unknown, solved to that
    # solve's tolerance (relative to the rows' sizes; this loop's rows are of the current's
    # size): 1e-12 of it on one BLAS kernel, 2e-12 on another (measured)
    tol = inspect.signature(consistent_initial_conditions).parameters["tol"].default
    assert abs(r.outputs["i"][0] - r.outputs["i_state"][0]) <= tol * size
    assert np.abs(r.outputs["i"]).max() > 1.0


def test_a_feedback_source_may_read_a_port_variable(tmp_path):
    """A P controller without state, `value: "Kp*(u_ref + cap.port.e)"`: C u' = Kp (u_ref − u),
    the closed form u = u_ref (1 − exp(−Kp t / C))."""
    text = (VOLTAGE_LOOP.replace('  ctrl: {type: pi, input: "u_ref + cap.port.e", Kp: Kp, Ki: Ki}\n', "")
            .replace('value: "ctrl.y"', 'value: "Kp*(u_ref + cap.port.e)"').replace("    z: ctrl.z\n", ""))
    r = phc.simulate(phc.compile_model(_write(tmp_path, text)))
    assert r.success, r.message
    exact = u_ref * (1 - np.exp(-3.0 * r.t / Cc))
    assert np.abs(r.outputs["u"] - exact).max() < 1e-7


def test_the_midpoint_rule_integrates_a_port_reading_at_second_order(tmp_path):
    """The reading is one more algebraic unknown for the midpoint rule: halving the step
    divides the error against scipy (rtol 1e-11, far below it) by 4; the loop's
    eigenvalues are of modulus ≤ 11, so at h ≤ 0.002 the ratio is 4 to within (hλ)² ~ 5e-4."""
    compiled = phc.compile_model(_write(tmp_path, SPEED_LOOP))
    errors = []
    for h in (0.002, 0.001, 0.0005):
        r = phc.simulate(compiled, solver="midpoint", step=h)
        assert r.success, r.message
        ref = _reference("lag_pi", r.t)
        errors.append(max(np.abs(r.outputs[n] - ref[n]).max() for n in ("v", "s", "z")))
    for coarse, fine in zip(errors, errors[1:]):
        assert 3.9 < coarse / fine < 4.1, errors


def _refusal(tmp_path, text, code):
    path = _write(tmp_path, text)
    dae, diags = phc.build_dae(path)
    errors = [dg for dg in diags if dg.severity == "error"]
    assert dae is None and errors, "expected a refusal"
    assert errors[0].code == code, [str(dg) for dg in errors]
    return path, errors[0]


def test_a_reading_the_readers_output_acts_on_at_once_is_an_algebraic_loop(tmp_path):
    """The resistor's voltage R I is set by the current I the controller commands from it:
    refused at the controller's `input`, naming the loop."""
    text = VOLTAGE_LOOP.replace('"u_ref + cap.port.e"', '"u_ref + res.port.e"')
    path, error = _refusal(tmp_path, text, "PHC-E129")
    line = text.splitlines().index('  ctrl: {type: pi, input: "u_ref + res.port.e", Kp: Kp, Ki: Ki}') + 1
    assert (error.span.line, error.span.col) == (line, text.splitlines()[line - 1].index('"u_ref') + 1)
    assert "`ctrl` reads `res.port.e`" in error.message and "`drive`" in error.message
    assert str(error).startswith(f"{path}:{line}:")


def test_a_loop_through_a_junction_is_refused_and_a_lag_breaks_it(tmp_path):
    """The force on the mass, `body.port.e`, includes the drive's force at the same instant
    (a loop through the junction); a lag (no feedthrough) between them makes it a state's
    function: accepted."""
    loop = SPEED_LOOP.replace('"v_ref - sensor.y"', '"v_ref - body.port.e"')
    _, error = _refusal(tmp_path, loop, "PHC-E129")
    assert "`ctrl` reads `body.port.e`" in error.message and "`node`" in error.message
    lagged = SPEED_LOOP.replace('input: ["drag.port.f"]', 'input: ["body.port.e"]')
    dae, diags = phc.build_dae(_write(tmp_path, lagged, "lagged.yaml"))
    assert dae is not None, [str(dg) for dg in diags]


def test_a_reading_of_an_unknown_port_variable_is_located(tmp_path):
    text = VOLTAGE_LOOP.replace('"u_ref + cap.port.e"', '"u_ref + cap.prt.e"')
    _, error = _refusal(tmp_path, text, "PHC-E101")
    assert "cap.prt.e" in error.message and error.span.line > 1


INNER = """
format_version: 1
parameters: {m: 2.0, v_ref: 1.0, Kp: 3.0, Ki: 5.0}
components:
  drive: {type: effort_source, value: "ctrl.y"}
  body: {type: mass, m: m}
  ctrl: {type: pi, input: "v_ref - body.port.f", Kp: Kp, Ki: Ki}
  node: {type: junction, kind: common_flow, ports: [m, f, x]}
connections:
  - [node.m, body.port]
  - [node.f, drive.port]
ports:
  x: {port: node.x}
"""

OUTER = """
format_version: 1
components:
  plant: {type: model, file: inner.yaml}
  spring: {type: spring, k: 8.0}
connections:
  - [plant.x, spring.port]
simulation:
  t_end: 2.0
  n_out: 201
  rtol: 1.0e-10
  atol: 1.0e-12
  outputs:
    v: plant.body.p / 2.0
    z: plant.ctrl.z
"""


def test_a_reading_in_a_nested_file_uses_the_names_written_there(tmp_path):
    """Inside `inner.yaml` the controller reads `body.port.f` (not `plant.body.port.f`):
    the loop is v' = (−8 x + 3 (1 − v) + 5 z)/2, x' = v, z' = 1 − v, against scipy."""
    (tmp_path / "inner.yaml").write_text(INNER)
    r = phc.simulate(phc.compile_model(_write(tmp_path, OUTER, "outer.yaml")))
    assert r.success, r.message

    def f(t, y):
        x, v, z = y
        return [v, (-8.0 * x + 3.0 * (1.0 - v) + 5.0 * z) / 2.0, 1.0 - v]

    ref = solve_ivp(f, (0.0, r.t[-1]), [0.0, 0.0, 0.0], t_eval=r.t, **TIGHT)
    assert np.abs(r.outputs["v"] - ref.y[1]).max() < 1e-7 and np.abs(ref.y[1]).max() > 0.1
    assert np.abs(r.outputs["z"] - ref.y[2]).max() < 1e-7


def test_a_block_reading_the_port_of_the_source_it_drives_is_a_cycle(tmp_path):
    """`drive.port.f` belongs to the source that reads `ctrl.y`: the two read each other,
    which no lowering order resolves (PHC-E128 at both, naming both)."""
    text = VOLTAGE_LOOP.replace('"u_ref + cap.port.e"', '"u_ref - drive.port.f"')
    _, error = _refusal(tmp_path, text, "PHC-E128")
    assert "`ctrl`, `drive`" in error.message and error.path in ("components.ctrl", "components.drive")


def test_linearize_gives_the_spectrum_of_the_current_loop(tmp_path):
    """(i, ω, z): L i' = −(R + Kp) i − Km ω + Ki z + Kp i_ref, J ω' = Km i − c ω, z' = i_ref − i.
    The reading is an algebraic unknown that `phc linearize` eliminates; the Jacobians are
    exact, so the only error is the eigensolver's round-off on a matrix of norm ~1e3."""
    A = np.array([[-(R + Kp) / L, -Km / L, Ki / L], [Km / J, -c / J, 0.0], [-1.0, 0.0, 0.0]])
    lin = phc.linearize_model(_write(tmp_path, CURRENT_LOOP), certify=False)
    assert lin.n_states == 3
    found, expected = sorted(lin.eigenvalues, key=lambda z: (z.real, z.imag)), np.linalg.eigvals(A)
    for lam in expected:
        assert min(abs(f - lam) for f in found) <= 1e-9 * max(1.0, abs(lam)), (found, expected)
