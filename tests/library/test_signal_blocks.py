"""Signal blocks (controllers with state): `state_space` and `pi` (phc.library.signal).

The PI speed loop of the geared DC motor against scipy is tests/test_gallery.py
(`models/dc_motor_pi.yaml`). Here: closed-loop eigenvalues of `phc linearize` against
hand-derived matrices, anti-windup against the closed form of a saturated drive, the
certificate's report, and located errors.
"""

from __future__ import annotations

import math

import numpy as np
import pytest

import phc

# A mass m on a spring k (and, for the saturated drive, a damper d), driven by a force
# F = ctrl.y from a velocity controller. Signs (docs/signs.md): on the common-flow
# junction ṗ = −k x + F, ẋ = p/m.
PLANT = """
format_version: 1
parameters: {{m: 2.0, k: 8.0, d: 0.0, v_ref: 1.0, Kp: 3.0, Ki: 5.0, Kd: 0.4, Tf: 0.05, Fmax: 1.5}}
components:
  body: {{type: mass, m: m}}
  spring: {{type: spring, k: k}}
  drag: {{type: damper, d: d}}
  drive: {{type: effort_source, value: "ctrl.y"}}
  node: {{type: junction, kind: common_flow, ports: [m, s, d, f]}}
{controller}
connections:
  - [node.m, body.port]
  - [node.s, spring.port]
  - [node.d, drag.port]
  - [node.f, drive.port]
simulation:
  t_end: {t_end}
  n_out: 401
  rtol: 1.0e-10
  atol: 1.0e-12
  outputs:
    v: body.p / m
    force: ctrl.y
    z: ctrl.z
"""

PI = '  ctrl: {type: pi, input: "v_ref - body.p/m", Kp: Kp, Ki: Ki}'
PID = '  ctrl: {type: pi, input: "v_ref - body.p/m", Kp: Kp, Ki: Ki, Kd: Kd, Tf: Tf}'
# the same PI as a state-space block: ż = e, y = Ki z + Kp e
PI_AS_STATE_SPACE = ('  ctrl: {type: state_space, input: ["v_ref - body.p/m"], A: [[0]], B: [[1]], C: [[Ki]], '
                     'D: [[Kp]]}')
m, k, Kp, Ki, Kd, Tf = 2.0, 8.0, 3.0, 5.0, 0.4, 0.05


def _write(tmp_path, controller, t_end=2.0, name="m.yaml"):
    path = tmp_path / name
    path.write_text(PLANT.format(controller=controller, t_end=t_end))
    return path


def _same_spectrum(found, expected):
    """Eigenvalues as multisets: each expected one matched by its nearest found one. The
    Jacobians are the generated code's exact derivatives, so the only error is the
    round-off of the QZ algorithm on a pencil of norm ~10: 1e-9 relative is far above it."""
    found, expected = np.asarray(found, dtype=complex), np.asarray(expected, dtype=complex)
    assert len(found) == len(expected), (found, expected)
    left = list(found)
    for lam in expected:
        j = int(np.argmin([abs(f - lam) for f in left]))
        assert abs(left[j] - lam) <= 1e-9 * max(1.0, abs(lam)), (found, expected)
        left.pop(j)


PI_LOOP = np.array([[-Kp / m, -k, Ki],  # ṗ = −k x + Kp (v_ref − p/m) + Ki z
                    [1 / m, 0.0, 0.0],  # ẋ = p/m
                    [-1 / m, 0.0, 0.0]])  # ż = v_ref − p/m


@pytest.mark.parametrize("controller", [PI, PI_AS_STATE_SPACE], ids=["pi", "state_space"])
def test_closed_loop_eigenvalues_are_those_of_the_hand_derived_matrix(tmp_path, controller):
    lin = phc.linearize_model(_write(tmp_path, controller), certify=False)
    assert lin.n_states == 3
    _same_spectrum(lin.eigenvalues, np.linalg.eigvals(PI_LOOP))
    # not a trivial spectrum: a damped oscillation, and 0 because ẋ = −ż (x + z is conserved)
    assert sum(1 for lam in lin.eigenvalues if lam.real < -0.1 and abs(lam.imag) > 1.0) == 2


def test_pid_with_a_derivative_filter_has_the_hand_derived_spectrum(tmp_path):
    # states (p, x, z, d): e = v_ref − p/m, ḋ = (e − d)/Tf, F = Kp e + Ki z + Kd (e − d)/Tf
    A = np.array([[-(Kp + Kd / Tf) / m, -k, Ki, -Kd / Tf],
                  [1 / m, 0.0, 0.0, 0.0],
                  [-1 / m, 0.0, 0.0, 0.0],
                  [-1 / (m * Tf), 0.0, 0.0, -1 / Tf]])
    lin = phc.linearize_model(_write(tmp_path, PID), certify=False)
    assert lin.n_states == 4
    _same_spectrum(lin.eigenvalues, np.linalg.eigvals(A))


def test_a_first_order_lag_as_a_state_space_block(tmp_path):
    """A lag τ ẏ = K u − y in the loop: F = lag(Kp e); the spectrum of (p, x, y)."""
    tau = 0.2
    lag = (f'  ctrl: {{type: state_space, input: ["Kp*(v_ref - body.p/m)"], A: [[-1/{tau}]], B: [[1/{tau}]], '
           'C: [[1]]}')
    A = np.array([[0.0, -k, 1.0], [1 / m, 0.0, 0.0], [-Kp / (m * tau), 0.0, -1 / tau]])
    lin = phc.linearize_model(_write(tmp_path, lag), certify=False)
    _same_spectrum(lin.eigenvalues, np.linalg.eigvals(A))


def test_a_state_space_block_with_two_inputs_states_and_outputs(tmp_path):
    """ż₀ = e, ż₁ = (−x − z₁)/τ; y₀ = Ki z₀ + Kp e, y₁ = z₁; F = y₀ + kx y₁: the spectrum of
    (p, x, z₀, z₁), and the outputs `ctrl.y[1]` and `ctrl.z[1]` are the same signal."""
    tau, kx = 0.2, 2.0
    block = (f'  ctrl: {{type: state_space, input: ["v_ref - body.p/m", "-spring.x"], '
             f'A: [[0, 0], [0, -1/{tau}]], B: [[1, 0], [0, 1/{tau}]], C: [[Ki, 0], [0, 1]], D: [[Kp, 0], [0, 0]]}}')
    text = PLANT.format(controller=block, t_end=2.0).replace('value: "ctrl.y"', f'value: "ctrl.y[0] + {kx}*ctrl.y[1]"')
    text = text.replace("    force: ctrl.y\n    z: ctrl.z\n", "    lagged: ctrl.y[1]\n    z1: ctrl.z[1]\n")
    path = tmp_path / "two.yaml"
    path.write_text(text)
    A = np.array([[-Kp / m, -k, Ki, kx], [1 / m, 0, 0, 0], [-1 / m, 0, 0, 0], [0, -1 / tau, 0, -1 / tau]])
    lin = phc.linearize_model(path, certify=False)
    assert lin.n_states == 4
    _same_spectrum(lin.eigenvalues, np.linalg.eigvals(A))
    r = phc.simulate(phc.compile_model(path))
    assert r.success, r.message
    assert np.array_equal(r.outputs["lagged"], r.outputs["z1"]) and np.abs(r.outputs["z1"]).max() > 1e-3


def test_anti_windup_holds_the_integral_while_the_drive_saturates(tmp_path):
    """A mass with a damper (no spring) driven from rest towards a speed it cannot reach
    quickly: while the output is clamped at Fmax the speed is the closed form
    v = (Fmax/d)(1 − exp(−d t/m)) and the integral stays 0 (conditional integration);
    without limits the integral winds up in the same time."""
    text = PLANT.format(controller='  ctrl: {type: pi, input: "v_ref - body.p/m", Kp: Kp, Ki: Ki, '
                                   'limits: [-Fmax, Fmax]}', t_end=3.0)
    text = text.replace("k: 8.0, d: 0.0", "k: 0.0, d: 0.5").replace("  spring: {type: spring, k: k}\n", "") \
        .replace("  - [node.s, spring.port]\n", "").replace("ports: [m, s, d, f]", "ports: [m, d, f]")
    path = tmp_path / "sat.yaml"
    path.write_text(text)
    r = phc.simulate(phc.compile_model(path))
    assert r.success, r.message
    d, Fmax, v_ref = 0.5, 1.5, 1.0
    # clamped while Kp (v_ref − v) > Fmax (with z = 0): until v = v_ref − Fmax/Kp
    v_switch = v_ref - Fmax / Kp
    t_switch = -m / d * math.log(1 - v_switch * d / Fmax)
    before = r.t < t_switch - 0.01  # away from the switch, where the step size adapts
    assert before.sum() > 50
    v = Fmax / d * (1 - np.exp(-d * r.t[before] / m))
    # IDA at rtol 1e-10, atol 1e-12 on a smooth piece (no switch before t_switch), speeds of order 1
    assert np.abs(r.outputs["v"][before] - v).max() < 1e-9
    assert np.abs(r.outputs["z"][before]).max() < 1e-9
    assert np.abs(r.outputs["force"][before] - Fmax).max() < 1e-9
    assert r.outputs["force"].max() <= Fmax * (1 + 1e-12)
    assert r.outputs["force"][-1] < Fmax - 0.1  # it then leaves the limit
    assert r.outputs["z"][-1] > 1e-3  # and integrates: far above the 1e-9 it was held at



def test_the_midpoint_rule_integrates_the_block_with_the_plant_at_second_order(tmp_path):
    """The block's state is one more state for the midpoint rule: halving the step divides
    the error against IDA (rtol 1e-10, far below it) by 4. The closed loop's eigenvalues
    are of modulus ≤ 3, so at h ≤ 0.005 the ratio is 4 to within (hλ)² ~ 1e-4."""
    compiled = phc.compile_model(_write(tmp_path, PI))
    ref = phc.simulate(compiled)
    errors = []
    for h in (0.005, 0.0025, 0.00125):
        r = phc.simulate(compiled, solver="midpoint", step=h)
        assert r.success, r.message
        assert r.energy_balance_relative < 1e-12  # exact for the quadratic H (the block is not in it)
        errors.append(max(np.abs(r.outputs[k] - ref.outputs[k]).max() for k in ("v", "z")))
    for coarse, fine in zip(errors, errors[1:]):
        assert 3.9 < coarse / fine < 4.1, errors


def test_a_blocks_state_starts_where_the_initial_values_say(tmp_path):
    r = phc.simulate(phc.compile_model(_write(tmp_path, PI)), initial={"ctrl.z": 0.2})
    assert r.success, r.message
    assert r.outputs["z"][0] == 0.2
    assert abs(r.outputs["force"][0] - (Kp * 1.0 + Ki * 0.2)) < 1e-12  # at rest: e = v_ref = 1


def test_check_lists_the_block_outside_the_certificate_and_certifies_the_plant(tmp_path):
    report = phc.certify_model(_write(tmp_path, PI))
    text = report.render_text()
    assert report.certified, text
    line = next(line for line in text.splitlines() if line.strip().startswith("ctrl "))
    assert "signal block: outside the port-Hamiltonian certificate" in line
    drive = next(line for line in text.splitlines() if line.strip().startswith("drive "))
    assert "Dirac ok" in drive and "supplied power" in drive
    assert "independent parts" not in text  # the block is not a part of its own
    by_name = {c["name"]: c for c in report.to_dict()["components"]}
    assert by_name["ctrl"]["dirac"] is None and by_name["body"]["dirac"] is True


def test_energy_balance_counts_the_drive_as_supplied_power(tmp_path):
    """H is the plant's energy only (the block's state is not in it); the work of the
    driven source enters as supplied energy, ∫ F v dt."""
    r = phc.simulate(phc.compile_model(_write(tmp_path, PI)))
    assert r.success, r.message
    assert r.energy_balance_relative < 1e-6
    x = r.y[:, r.variables.index("spring.x")]
    assert np.abs(r.H - (m * r.outputs["v"] ** 2 / 2 + k * x**2 / 2)).max() < 1e-12 * max(1.0, r.H.max())
    # the trapezoidal rule on 401 points: its error, h²/12 ∫|(Fv)''|, is below 1e-3 of the work here
    work = np.concatenate([[0.0], np.cumsum(np.diff(r.t) * (r.outputs["force"] * r.outputs["v"])[1:]
                                           + np.diff(r.t) * (r.outputs["force"] * r.outputs["v"])[:-1]) / 2])
    # P_ports is the power the model delivers (H − H₀ + ∫(P_ports + P_diss) dt = 0,
    # phc.simulation.result), so the work done on it is −∫ P_ports
    assert np.abs(-r.energy_supplied - work).max() < 1e-3 * np.abs(work).max()
    assert work[-1] > 0.1  # the controller did work on the plant


INNER = """
format_version: 1
parameters: {m: 2.0, v_ref: 1.0, Kp: 3.0, Ki: 5.0}
components:
  drive: {type: effort_source, value: "ctrl.y"}
  body: {type: mass, m: m}
  ctrl: {type: pi, input: "v_ref - body.p/m", Kp: Kp, Ki: Ki}
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
  n_out: 401
  rtol: 1.0e-10
  atol: 1.0e-12
  outputs:
    v: plant.body.p / 2.0
    force: plant.ctrl.y
"""


def test_a_block_in_a_nested_file_reads_the_names_written_there(tmp_path):
    """Inside a nested file the block reads `body.p` and the source `ctrl.y` (the names
    written there, without the `plant.` prefix); the model equals the flat one. Both are
    integrated by IDA at rtol 1e-10: 1e-7 allows for two runs' global errors."""
    (tmp_path / "inner.yaml").write_text(INNER)
    (tmp_path / "outer.yaml").write_text(OUTER)
    nested = phc.simulate(phc.compile_model(tmp_path / "outer.yaml"))
    flat = phc.simulate(phc.compile_model(_write(tmp_path, PI)))
    assert nested.success and flat.success
    for name in ("v", "force"):
        assert np.abs(nested.outputs[name] - flat.outputs[name]).max() < 1e-7, name


def _refused(tmp_path, controller, code):
    path = _write(tmp_path, controller)
    dae, diags = phc.build_dae(path)
    errors = [d for d in diags if d.severity == "error"]
    assert dae is None and errors, "expected a refusal"
    assert errors[0].code == code, [str(d) for d in errors]
    assert errors[0].span is not None and errors[0].span.line > 1
    return errors


def test_an_unknown_name_in_the_input_is_located(tmp_path):
    errors = _refused(tmp_path, '  ctrl: {type: pi, input: "v_ref - bodyy.p/m", Kp: Kp, Ki: Ki}', "PHC-E101")
    assert "bodyy.p" in errors[0].message


def test_blocks_reading_each_other_with_feedthrough_all_round_are_an_algebraic_loop(tmp_path):
    """ctrl.y = z + other.y and other.y = w + ctrl.y: each output depends on itself at the
    same instant. Refused at one of them, naming both."""
    cycle = ('  ctrl: {type: state_space, input: ["other.y"], A: [[-1]], B: [[1]], C: [[1]], D: [[1]]}\n'
             '  other: {type: state_space, input: ["ctrl.y"], A: [[-1]], B: [[1]], C: [[1]], D: [[1]]}')
    errors = _refused(tmp_path, cycle, "PHC-E128")
    loop = [e for e in errors if e.code == "PHC-E128"]
    assert len(loop) == 1 and "algebraic loop" in loop[0].message, [str(e) for e in errors]
    assert "`ctrl`" in loop[0].message and "`other`" in loop[0].message
    lines = PLANT.format(controller=cycle, t_end=2.0).splitlines()
    line = lines.index(cycle.splitlines()[loop[0].path == "components.other"]) + 1  # the block's own entry
    assert (loop[0].span.line, loop[0].span.col) == (line, lines[line - 1].index("{") + 1)


def test_blocks_reading_each_other_through_a_state_are_no_loop(tmp_path):
    """Two blocks that read each other, one without feedthrough (D = 0 breaks the loop):
    F = a.y = z_a, ż_a = b.y − v, b.y = z_b, ż_b = −z_b − a.y, with the plant
    ẋ = v, m v̇ = −k x + F: against scipy (rtol 1e-11; phc's IDA at 1e-10), and the
    spectrum of `phc linearize` against the hand-derived matrix."""
    from scipy.integrate import solve_ivp

    pair = ('  ctrl: {type: state_space, input: ["other.y - body.p/m"], A: [[0]], B: [[1]], C: [[1]]}\n'
            '  other: {type: state_space, input: ["-ctrl.y"], A: [[-1]], B: [[1]], C: [[1]]}')
    path = _write(tmp_path, pair)
    r = phc.simulate(phc.compile_model(path), initial={"ctrl.z": 0.5})
    assert r.success, r.message

    def f(t, y):
        x, v, za, zb = y
        return [v, (-k * x + za) / m, zb - v, -zb - za]

    ref = solve_ivp(f, (0.0, r.t[-1]), [0.0, 0.0, 0.5, 0.0], t_eval=r.t, rtol=1e-11, atol=1e-13)
    v, za = ref.y[1], ref.y[2]
    assert np.abs(v).max() > 1e-2 and np.abs(r.outputs["v"] - v).max() < 1e-7
    assert np.abs(r.outputs["force"] - za).max() < 1e-7
    A = np.array([[0.0, -k, 1.0, 0.0],  # (p, x, z_a, z_b): ṗ = −k x + z_a
                  [1 / m, 0.0, 0.0, 0.0],
                  [-1 / m, 0.0, 0.0, 1.0],
                  [0.0, 0.0, -1.0, -1.0]])
    lin = phc.linearize_model(path, certify=False)
    _same_spectrum(lin.eigenvalues, np.linalg.eigvals(A))


def test_a_pid_needs_a_positive_filter_time_constant_and_limits_in_order(tmp_path):
    errors = _refused(tmp_path, '  ctrl: {type: pi, input: "v_ref - body.p/m", Kp: Kp, Ki: Ki, Kd: Kd}', "PHC-E102")
    assert "`Tf`" in errors[0].message and errors[0].path == "components.ctrl.Kd"
    errors = _refused(tmp_path, '  ctrl: {type: pi, input: "v_ref - body.p/m", Kp: Kp, Ki: Ki, Kd: Kd, Tf: -Tf}',
                      "PHC-E405")
    assert "`Tf` of `ctrl` is -0.05" in errors[0].message
    errors = _refused(tmp_path, '  ctrl: {type: pi, input: "v_ref - body.p/m", Kp: Kp, Ki: Ki, limits: [Fmax, -Fmax]}',
                      "PHC-E405")
    assert "`limits` of `ctrl` are [1.5, -1.5]" in errors[0].message
