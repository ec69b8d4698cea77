"""`phc linearize`: the descriptor system and its finite spectrum against closed forms —
string and beam frequencies (and their convergence with the mesh), the mass–spring–damper's
poles, the pendulum's small-angle frequency, transfer functions of the RLC circuit and of a
PD-controlled mass, the static gain of an exposed port."""

from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np
import pytest

import phc
from phc.cli import main
from phc.study.linearize import finite_eigenvalues

ROOT = Path(__file__).resolve().parents[1]
MODELS = ROOT / "models"
LIBRARY = ROOT / "tests" / "library" / "models"


def transfer(lin, s):
    """G(s) = C (sE − A)⁻¹ B + D."""
    return lin.C @ np.linalg.solve(s * lin.E - lin.A, lin.B) + lin.D


def test_mass_spring_damper_poles():
    lin = phc.linearize_model(MODELS / "mass_spring_damper.yaml")
    m, k, c = 1.0, 4.0, 0.4
    wn, zeta = math.sqrt(k / m), c / (2 * math.sqrt(k * m))
    assert len(lin.eigenvalues) == 2 and len(lin.modes) == 1
    pole = complex(-zeta * wn, wn * math.sqrt(1 - zeta**2))
    assert abs(lin.modes[0].eigenvalue - pole) < 1e-10
    assert abs(lin.modes[0].natural_frequency - wn) < 1e-10
    assert abs(lin.modes[0].damping_ratio - zeta) < 1e-10
    assert sorted(np.round(lin.eigenvalues.imag, 8)) == sorted(np.round([pole.imag, -pole.imag], 8))
    assert lin.B.shape == (len(lin.variables), 0)  # no sources, no exposed ports
    # the output x is the spring's elongation
    assert np.allclose(lin.C[lin.outputs.index("x")], [v == "spring.x" for v in lin.variables])
    assert not lin.is_equilibrium()  # the spring starts stretched


def test_mass_spring_damper_at_a_later_time_is_on_the_closed_form_motion():
    lin = phc.linearize_model(MODELS / "mass_spring_damper.yaml", at=3.0)
    m, k, c, x0 = 1.0, 4.0, 0.4, 0.5
    wn = math.sqrt(k / m)
    zw, wd = c / (2 * m), wn * math.sqrt(1 - (c / (2 * math.sqrt(k * m)))**2)
    x = math.exp(-zw * 3.0) * (x0 * math.cos(wd * 3.0) + zw * x0 / wd * math.sin(wd * 3.0))
    assert abs(lin.y[lin.variables.index("spring.x")] - x) < 1e-7
    assert lin.t == 3.0 and abs(lin.modes[0].natural_frequency - wn) < 1e-10


def test_pendulum_small_angle_frequency_about_the_hanging_equilibrium():
    lin = phc.linearize_model(MODELS / "pendulum.yaml", state={"pendulum.x": 0.0, "pendulum.y": -1.0})
    assert lin.is_equilibrium()
    assert len(lin.modes) == 1 and len(lin.eigenvalues) == 2  # one degree of freedom
    assert abs(lin.modes[0].natural_frequency - math.sqrt(9.81 / 1.0)) < 1e-9
    assert abs(lin.modes[0].eigenvalue.real) < 1e-9
    # a longer rod: sqrt(g/L) with L = 2.5 (the state on the new circle)
    lin = phc.linearize_model(MODELS / "pendulum.yaml", params={"L": 2.5},
                              state={"pendulum.x": 0.0, "pendulum.y": -2.5})
    assert abs(lin.modes[0].natural_frequency - math.sqrt(9.81 / 2.5)) < 1e-9


def test_pendulum_about_the_inverted_position_is_unstable():
    lin = phc.linearize_model(MODELS / "pendulum.yaml", state={"pendulum.x": 0.0, "pendulum.y": 1.0})
    assert np.allclose(sorted(lin.eigenvalues.real), [-math.sqrt(9.81), math.sqrt(9.81)], atol=1e-9)


C_STRING, L_STRING = 80.0, 0.64  # models/vibrating_string.yaml: c = sqrt(T/rho), fixed at 0, free at L


def test_string_frequencies_and_mode_shapes_converge_to_the_fixed_free_string():
    exact = (2 * np.arange(1, 4) - 1) * math.pi * C_STRING / (2 * L_STRING)
    errors = []
    for n in (8, 16, 32):
        lin = phc.linearize_model(MODELS / "vibrating_string.yaml", mesh={"string": n}, certify=False)
        assert len(lin.modes) == n  # one mode per momentum DOF off the fixed end
        w = np.array([m.natural_frequency for m in lin.modes[:3]])
        errors.append(np.abs(w / exact - 1))
        assert max(abs(m.damping_ratio) for m in lin.modes) < 1e-9  # lossless
        shape = lin.modes[0].shapes["string"]
        assert np.abs(shape["deflection"] - np.sin(math.pi / 2 * shape["xi_over_L"])).max() < 1e-6
    errors = np.array(errors)
    assert errors[-1].max() < 3e-3
    ratios = errors[:-1] / errors[1:]
    assert np.all((ratios > 3.5) & (ratios < 4.5)), ratios  # O(h²) of the P1/P0 elements


def test_shipped_string_input_is_the_pulse_force():
    lin = phc.linearize_model(MODELS / "vibrating_string.yaml")
    assert [u.name for u in lin.inputs] == ["pulse"] and lin.inputs[0].kind == "effort"
    # w(ξ, s) ∝ sinh(sξ/c) (fixed at 0) and T w_ξ(L) = F: the end velocity per unit force
    # is the admittance tanh(sL/c)/Z0 with the impedance Z0 = sqrt(T ρ)
    Z0 = math.sqrt(64.0 * 0.01)
    s = 2j * math.pi * 5.0  # below the first mode (31 Hz): the mesh resolves it
    g = transfer(lin, s)[lin.outputs.index("end_velocity"), 0]
    assert abs(g - np.tanh(s * L_STRING / C_STRING) / Z0) < 1e-5 * abs(g)


def test_cantilever_frequencies_and_first_mode_converge_to_the_closed_form():
    beta = np.array([1.8751040687, 4.6940911330, 7.8547574382])
    EI, rhoA, L = 68.27, 0.50368, 0.3
    exact = (beta / L)**2 * math.sqrt(EI / rhoA)
    b = beta[0]
    sigma = (math.cosh(b) + math.cos(b)) / (math.sinh(b) + math.sin(b))
    errors = []
    for n in (2, 4, 8):
        lin = phc.linearize_model(MODELS / "euler_bernoulli_beam.yaml", mesh={"beam": n}, certify=False)
        w = np.array([m.natural_frequency for m in lin.modes[:3]])
        errors.append(np.abs(w / exact - 1))
        xi = lin.modes[0].shapes["beam"]["xi_over_L"] * b
        phi = np.cosh(xi) - np.cos(xi) - sigma * (np.sinh(xi) - np.sin(xi))
        assert np.abs(lin.modes[0].shapes["beam"]["deflection"] - phi / phi[-1]).max() < 1e-4
    errors = np.array(errors)
    assert errors[-1][0] < 1e-5 and errors[-1].max() < 1e-3
    # O(h⁴) of the Hermite elements (the second mode reaches its rate from 4 elements on)
    assert np.all(errors[:-1, 0] / errors[1:, 0] > 12) and errors[1, 1] / errors[2, 1] > 12, errors


def test_rlc_transfer_function_from_the_source_voltage_to_the_charge():
    lin = phc.linearize_model(MODELS / "rlc_circuit.yaml")
    assert [u.name for u in lin.inputs] == ["source"]
    L, C, R = 0.5, 0.02, 2.0
    for s in (0.0, 1j, 3 + 4j, 40j):
        g = transfer(lin, s)[lin.outputs.index("charge"), 0]
        assert abs(g - 1 / (L * s**2 + R * s + 1 / C)) < 1e-10
    assert abs(lin.modes[0].natural_frequency - 1 / math.sqrt(L * C)) < 1e-10
    assert abs(lin.modes[0].damping_ratio - R / 2 * math.sqrt(C / L)) < 1e-10


def test_feedback_source_closes_the_loop_and_its_input_adds_to_the_controller():
    lin = phc.linearize_model(LIBRARY / "pd_controlled_mass.yaml")
    m, k, Kp, Kd = 2.0, 8.0, 20.0, 3.0
    poles = np.roots([m, Kd, k + Kp])
    assert np.allclose(sorted(lin.eigenvalues, key=lambda z: z.imag), sorted(poles, key=lambda z: z.imag), atol=1e-10)
    for s in (0.0, 0.7j, 2.0 + 1j):
        assert abs(transfer(lin, s)[0, 0] - 1 / (m * s**2 + Kd * s + k + Kp)) < 1e-10


EXPOSED = """\
format_version: 1
parameters: {m: 2.0, k: 5.0, c: 3.0}
components:
  body: {type: mass, m: m}
  spring: {type: spring, k: k}
  damper: {type: damper, d: c}
  node: {type: junction, kind: common_flow, domain: mechanical.translational, ports: [m, s, d, u]}
connections:
  - [body.port, node.m]
  - [spring.port, node.s]
  - [damper.port, node.d]
ports:
  push: {port: node.u}
simulation:
  t_end: 30.0
  n_out: 3
  rtol: 1.0e-10
  atol: 1.0e-12
  inputs:
    push: {effort: "1.5"}
  outputs: {x: spring.x}
"""


def test_an_exposed_port_is_an_input_whose_static_gain_matches_the_settled_simulation(tmp_path):
    path = tmp_path / "pushed.yaml"
    path.write_text(EXPOSED)
    lin = phc.linearize_model(path)
    assert [(u.name, u.kind) for u in lin.inputs] == [("push", "effort")]
    # independent: the simulated response to the constant 1.5 settles at the static gain × 1.5
    r = phc.simulate(phc.compile_model(path))
    x_end = r.outputs["x"][-1]
    assert abs(x_end) > 0.1 and abs(transfer(lin, 0.0)[0, 0] * 1.5 - x_end) < 1e-6
    assert abs(abs(x_end) - 1.5 / 5.0) < 1e-6  # |x| = F/k
    # a free exposed port (no input given) is an input too
    path.write_text(EXPOSED.replace('  inputs:\n    push: {effort: "1.5"}\n', ""))
    free = phc.linearize_model(path)
    assert [u.name for u in free.inputs] == ["push"]
    assert abs(transfer(free, 0.0)[0, 0] - transfer(lin, 0.0)[0, 0]) < 1e-10


def test_wong_sequence_separates_an_index_two_pencil():
    # x1' = x2, 0 = x1 - u(=0) style chain: a nilpotent block of index 2 plus one finite mode
    E = np.array([[1.0, 0, 0, 0], [0, 0, 1, 0], [0, 0, 0, 0], [0, 0, 0, 0]])
    A = np.array([[-3.0, 0, 0, 0], [0, 1, 0, 0], [0, 0, 1, 0], [0, 0, 0, 1]])
    lam, vectors, n_inf, singular = finite_eigenvalues(A, E)
    assert np.allclose(lam, [-3.0]) and n_inf == 3 and not singular
    assert np.allclose(A @ vectors[:, 0], lam[0] * E @ vectors[:, 0])


def test_cli_writes_json_and_npz_and_refuses_npz_on_stdout(tmp_path, capsys):
    out = tmp_path / "lin.json"
    assert main(["linearize", str(MODELS / "rlc_circuit.yaml"), "-o", str(out)]) == 0
    data = json.loads(out.read_text())
    assert data["n_finite"] == 2 and data["inputs"][0]["name"] == "source"
    assert np.array(data["E"]).shape == (len(data["variables"]),) * 2
    npz = tmp_path / "lin.npz"
    assert main(["linearize", str(MODELS / "pendulum.yaml"), "--state", "pendulum.x=0", "--state",
                 "pendulum.y=-1", "-o", str(npz)]) == 0
    with np.load(npz) as arrays:
        assert abs(arrays["natural_frequency"][0] - math.sqrt(9.81)) < 1e-9
        assert arrays["A"].shape == arrays["E"].shape
    capsys.readouterr()
    assert main(["linearize", str(MODELS / "rlc_circuit.yaml"), "--format", "npz"]) == 2
    assert "needs -o" in capsys.readouterr().err
    assert main(["linearize", str(MODELS / "pendulum.yaml"), "--state", "pendulum.q=1"]) == 2
    assert "not a state" in capsys.readouterr().err
    assert main(["linearize", str(MODELS / "pendulum.yaml"), "--state", "pendulum.x=0"]) == 1
    assert "inconsistent initial values" in capsys.readouterr().err


@pytest.mark.parametrize("args", [["--at", "-1"], ["--mesh", "string=0"], ["--state", "x"]])
def test_cli_usage_mistakes_are_one_line(args, capsys):
    assert main(["linearize", str(MODELS / "vibrating_string.yaml"), *args]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and err[0].startswith("phc linearize: error:"), err


@pytest.mark.parametrize("block", [2, 3])
def test_a_defective_zero_eigenvalue_is_zero_and_a_small_one_is_kept(block):
    """A free body's zero eigenvalue is defective (position and momentum: a Jordan block of
    size 2; 3 with a free integrator behind it). Rounding splits it by about ε^(1/m) of the
    largest eigenvalue (±1.6e-5 at 7000 for m = 2), so no test on the size of λ can tell it
    from a slow mode; the ranks of the block's chain can, and a slow mode at 1e-6 of the
    largest eigenvalue (10⁴ times the rank tolerance) must stay what it is."""
    rng = np.random.default_rng(7)
    n = block + 4
    J = np.zeros((n, n))
    for i in range(block - 1):
        J[i, i + 1] = 1.0
    J[block, block] = -7e-6                         # the slow mode, -1e-6 of the largest |λ|
    J[block + 1, block + 1] = -3.0
    J[block + 2:, block + 2:] = [[-0.5, 7.0], [-7.0, -0.5]]
    Q, _ = np.linalg.qr(rng.standard_normal((n, n)))
    A, E = 1e3 * Q @ J @ Q.T, np.eye(n)
    lam, _, n_inf, singular = finite_eigenvalues(A, E)
    assert n_inf == 0 and not singular
    assert list(lam[:block]) == [0] * block
    # the others to the round-off of an orthogonal similarity: ~ε‖A‖ absolute, 1e-12 of 7000
    expected = np.array([-7e-3, -3e3, -500 + 7e3j, -500 - 7e3j])
    assert np.abs(lam[block:] - expected).max() < 1e-12 * 7e3 * 10
