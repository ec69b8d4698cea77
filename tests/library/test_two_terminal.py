"""Two-terminal elements (`terminals: [a, b]`), transformers and gyrators, against closed
forms and independent solutions written here."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest
from scipy.integrate import solve_ivp

import phc
from phc.errors import ModelError

HERE = Path(__file__).parent / "models"


def test_a_spring_between_two_masses_oscillates_at_the_two_body_frequency():
    compiled = phc.compile_model(HERE / "two_masses.yaml")
    assert compiled.certificate.certified
    r = phc.simulate(compiled)
    m1, m2, k = 1.0, 3.0, 12.0
    omega = math.sqrt(k * (m1 + m2) / (m1 * m2))
    # relative coordinate: x'' = -omega^2 x with x(0) = 0.1, x'(0) = v1 - v2 = 0.5/m1
    x = 0.1 * np.cos(omega * r.t) + 0.5 / m1 / omega * np.sin(omega * r.t)
    assert np.abs(r.outputs["x"] - x).max() < 1e-7
    p = r["left.p"] + r["right.p"]  # no external force: total momentum conserved
    assert np.abs(p - 0.5).max() < 1e-9


def test_dc_motor_with_gyrator_and_gear_matches_the_motor_equations():
    compiled = phc.compile_model(HERE / "dc_motor.yaml")
    assert compiled.certificate.certified
    r = phc.simulate(compiled)
    V, R, L, Km, N, J, c = 12.0, 2.0, 0.5, 0.1, 0.2, 0.01, 0.001

    def motor(t, y):  # i' and load speed w'; the motor turns at w/N, the gear passes Km i / N
        i, w = y
        return [(V - R * i - Km * w / N) / L, (Km * i / N - c * w) / J]

    ref = solve_ivp(motor, (0.0, 2.0), [0.0, 0.0], t_eval=r.t, rtol=1e-11, atol=1e-13)
    assert np.abs(r.outputs["current"] - ref.y[0]).max() < 1e-7
    assert np.abs(r.outputs["speed"] - ref.y[1]).max() < 1e-6
    assert r.outputs["speed"][-1] > 20.0  # a positive voltage drives the load forward


RC = """\
format_version: 1
parameters: {V: 5.0, R: 2.0, C: 0.1}
components:
  supply: {type: effort_source, domain: electrical, value: V}
  r: {type: resistor, R: R, terminals: [a, b]}
  cap: {type: capacitor, C: C}
connections:
  - [supply.port, r.a]
  - [r.b, cap.port]
simulation:
  t_end: 1.0
  n_out: 101
  rtol: 1.0e-10
  atol: 1.0e-12
"""


def test_a_resistor_between_a_source_and_a_capacitor_charges_it_with_time_constant_RC(tmp_path):
    path = tmp_path / "rc.yaml"
    path.write_text(RC)
    r = phc.simulate(phc.compile_model(path))
    V, R, C = 5.0, 2.0, 0.1
    # the terminal r.b joined to the capacitor is a wire (docs/signs.md, series chains keep
    # the sign you draw): the capacitor charges to +C V as drawn
    q = C * V * (1 - np.exp(-r.t / (R * C)))
    assert np.abs(r["cap.q"] - q).max() < 1e-8


MODULATED = """\
format_version: 1
parameters: {m: 1.0, k: 4.0}
components:
  body: {type: mass, m: m}
  lever: {type: transformer, ratio: "1.5 + 0.5*sin(spring.x)", domain_a: mechanical.translational}
  spring: {type: spring, k: k}
connections:
  - [body.port, lever.a]
  - [lever.b, spring.port]
simulation:
  t_end: 4.0
  n_out: 201
  rtol: 1.0e-10
  atol: 1.0e-12
  initial: {body.p: 0.3, spring.x: 0.2}
"""


def test_a_state_modulated_transformer_is_dirac_and_conserves_energy(tmp_path):
    path = tmp_path / "lever.yaml"
    path.write_text(MODULATED)
    report = phc.certify_model(path)
    assert report.certified, report.render_text()
    r = phc.simulate(phc.compile_model(path))
    assert np.abs(r.H - r.H[0]).max() < 1e-8 * r.H[0]  # lossless: H constant
    # ẋ = N(x) v with v = p/m, ṗ = -N(x) k x: check the rate of the spring from the outputs
    N = 1.5 + 0.5 * np.sin(r["spring.x"])
    dx = np.gradient(r["spring.x"], r.t)
    assert np.abs(dx - N * r["body.p"])[5:-5].max() < 1e-3


@pytest.mark.parametrize("snippet, message", [
    ("{type: spring, k: 1.0, terminals: [a, b], ports: [c]}", "either `terminals`"),
    ("{type: spring, k: 1.0, terminals: [a]}", "exactly two ports"),
    ("{type: spring, k: 1.0, terminals: [a, b], domain: generic}", "no physical domain"),
    ("{type: orthogonal_transform, Q: [[2.0]]}", "transformer"),
])
def test_two_terminal_and_transform_mistakes_are_located(tmp_path, snippet, message):
    path = tmp_path / "bad.yaml"
    path.write_text(f"format_version: 1\ncomponents:\n  el: {snippet}\n")
    with pytest.raises(ModelError) as err:
        phc.compile_model(path)
    text = str(err.value)
    assert message in text, text
    assert f"{path}:3:" in text, text


def test_a_feedback_source_reading_states_controls_the_plant():
    """A PD controller as an effort source whose value reads states by full name: the
    closed loop m x'' = -(k + Kp) x + Kp x* - Kd x' (phc's source value is the force it
    applies)."""
    path = HERE / "pd_controlled_mass.yaml"
    report = phc.certify_model(path)
    assert report.certified, report.render_text()
    note = next(c.note for c in report.structure.components if c.name == "controller")
    assert note.startswith("feedback") and "spring.x" in note and "body.p" in note
    r = phc.simulate(phc.compile_model(path))
    m, k, Kp, Kd, target = 2.0, 8.0, 20.0, 3.0, 0.5
    ref = solve_ivp(lambda t, y: [y[1], (-(k + Kp) * y[0] + Kp * target - Kd * y[1]) / m], (0.0, 5.0), [0.0, 0.0],
                    t_eval=r.t, rtol=1e-11, atol=1e-13)
    assert np.abs(r.outputs["x"] - ref.y[0]).max() < 1e-7
    # the controller supplies energy: the balance closes with it counted as supplied power
    assert np.abs(r.H - r.H[0] + r.energy_supplied).max() < 1e-7
