"""Time in the model language (issue 14, item 1): rheonomic constraints c(q, t) = 0,
time-dependent velocity constraints A(q, t) v = 0 and energies V(q, t), and the rule that
wherever `t` or a state may appear it is handled or refused with a located error.

Each mechanism is checked against an independent minimal-coordinate solution written here
with scipy's ``solve_ivp`` (Lagrange's equations derived by hand), the energy balance
against the work of the moving constraint computed from that solution, and ``phc check``
certifies each model (Dirac structure and rank at sampled (q, t), rows against the
description with the constraint's c_t, power balance of the compiled equations).
"""

from __future__ import annotations

import numpy as np
import pytest
from scipy.integrate import cumulative_trapezoid, solve_ivp

import phc
from phc.checks.certify import certify

A_X, A_Y, W = 0.2, 0.1, 3.0  # the suspension's path: x_s = A_X sin(W t), y_s = A_Y sin(2 W t)


def _support(t):
    """(s, ṡ, s̈) of the prescribed support path."""
    s = np.array([A_X * np.sin(W * t), A_Y * np.sin(2 * W * t)])
    ds = np.array([A_X * W * np.cos(W * t), 2 * W * A_Y * np.cos(2 * W * t)])
    dds = np.array([-A_X * W**2 * np.sin(W * t), -4 * W**2 * A_Y * np.sin(2 * W * t)])
    return s, ds, dds


PENDULUM = """
format_version: 1
name: moving_pendulum
parameters: {m: 0.7, L: 0.8, g: 9.81, ax: 0.2, ay: 0.1, w: 3.0, th0: 0.5}
components:
  bob:
    type: rigid
    q: [x, y]
    v: [vx, vy]
    M: [[m, 0], [0, m]]
    V: m*g*y
    constraints:
      - (x - ax*sin(w*t))**2 + (y - ay*sin(2*w*t))**2 - L**2
simulation:
  t_end: 4.0
  n_out: 401
  rtol: 1.0e-10
  atol: 1.0e-10
  initial:
    bob.x: L*sin(th0)
    bob.y: -L*cos(th0)
    bob.p_vx: m*ax*w
    bob.p_vy: 2*m*ay*w
"""


def _pendulum_reference(t_eval, m=0.7, L=0.8, g=9.81, th0=0.5):
    """θ measured from the downward vertical; bob = s + L(sin θ, −cos θ).
    Lagrange: θ̈ = −((g + ÿ_s) sin θ + ẍ_s cos θ)/L. W is the work of the rod on the bob,
    F_rod·ṡ (the rod is inextensible: F_rod ⟂ relative velocity), F_rod = m(a + (0, g))."""

    def rhs(t, z):
        th, om, _ = z
        s, ds, dds = _support(t)
        al = -((g + dds[1]) * np.sin(th) + dds[0] * np.cos(th)) / L
        acc = dds + L * (al * np.array([np.cos(th), np.sin(th)]) + om**2 * np.array([-np.sin(th), np.cos(th)]))
        force = m * (acc + np.array([0.0, g]))
        return [om, al, force @ ds]

    sol = solve_ivp(rhs, (0, t_eval[-1]), [th0, 0.0, 0.0], t_eval=t_eval, rtol=1e-12, atol=1e-12, method="DOP853")
    th = sol.y[0]
    s, _, _ = _support(t_eval)
    return s[0] + L * np.sin(th), s[1] - L * np.cos(th), sol.y[2]


def test_pendulum_with_moving_suspension_matches_minimal_coordinates(tmp_path):
    path = tmp_path / "moving_pendulum.yaml"
    path.write_text(PENDULUM)
    result = phc.simulate(phc.compile_model(path))
    assert result.success, result.message
    x, y, work = _pendulum_reference(result.t)
    err = max(np.abs(result["bob.x"] - x).max(), np.abs(result["bob.y"] - y).max())
    assert err < 1e-7, err
    # The moving constraint does work; the balance books it as a port power, so it closes …
    assert result.energy_balance_relative < 1e-7
    # … and the energy the model delivered is minus the rod's work computed independently.
    assert np.abs(result.energy_supplied - result.energy_supplied[0] + work).max() < 1e-6 * np.abs(work).max()
    assert np.abs(work).max() > 0.1  # the support does real work: the test would see it dropped
    assert result.constraint_drift < 1e-9


def test_moving_pendulum_with_the_midpoint_rule(tmp_path):
    path = tmp_path / "moving_pendulum.yaml"
    path.write_text(PENDULUM)
    result = phc.simulate(phc.compile_model(path), solver="midpoint", step=1e-3)
    assert result.success, result.message
    x, y, _ = _pendulum_reference(result.t)
    err = max(np.abs(result["bob.x"] - x).max(), np.abs(result["bob.y"] - y).max())
    assert err < 1e-5, err  # second order (measured 1.2e-6 at h = 1e-3)
    assert result.constraint_drift < 1e-9


def test_phc_check_certifies_the_moving_pendulum(tmp_path):
    path = tmp_path / "moving_pendulum.yaml"
    path.write_text(PENDULUM)
    dae, diags = phc.build_dae(path)
    assert dae is not None, diags
    cert = certify(dae)
    assert cert.certified, cert.report() if hasattr(cert, "report") else cert
    assert cert.rows is not None and cert.rows.ok and "bob" in cert.rows.compared


def _velocity_row(path):
    dae, diags = phc.build_dae(path)
    assert dae is not None, diags
    rows = next(r for r in dae.topology.rows if r.component == "bob")
    assert rows.derived  # the rigid body's rows are derived from its description
    return dict(rows.equations)["bob.constraints[0].velocity"]


def _at(row, x, y, vx, vy, t):
    values = {"bob.x": x, "bob.y": y, "bob.vx": vx, "bob.vy": vy, "t": t, "ax": 0.2, "ay": 0.1, "w": 3.0,
              "L": 0.8, "m": 0.7, "g": 9.81}
    return float(row.xreplace({s: values[str(s)] for s in row.free_symbols}))


def test_the_velocity_row_carries_the_constraints_rate(tmp_path, monkeypatch):
    """The velocity-level row is d/dt c(q(t), t) with q̇ = v — c_q v + c_t, the rate of the
    moving suspension included — written out here from the constraint of PENDULUM; and it
    is derived from the description: a description without the rate c_t (the old row
    c_q Z v = 0) gives rows without it."""
    import phc.library.rigid as rigid

    path = tmp_path / "moving_pendulum.yaml"
    path.write_text(PENDULUM)
    row = _velocity_row(path)
    real = rigid._describe

    def without_rate(b, name, span, q, dq, p, dp, v, grad_q, M, Minv, Fd, Z, cq, ct, *rest):
        return real(b, name, span, q, dq, p, dp, v, grad_q, M, Minv, Fd, Z, cq, 0 * ct, *rest)

    monkeypatch.setattr(rigid, "_describe", without_rate)
    no_rate = _velocity_row(path)
    rng = np.random.default_rng(3)
    for _ in range(3):
        x, y, vx, vy, t = rng.normal(size=5)
        dx, dy = x - 0.2 * np.sin(3 * t), y - 0.1 * np.sin(6 * t)  # from the suspension point
        c_q_v = 2 * dx * vx + 2 * dy * vy
        c_t = 2 * dx * (-0.6 * np.cos(3 * t)) + 2 * dy * (-0.6 * np.cos(6 * t))
        assert _at(row, x, y, vx, vy, t) == pytest.approx(c_q_v + c_t, rel=1e-12, abs=1e-12)
        assert _at(no_rate, x, y, vx, vy, t) == pytest.approx(c_q_v, rel=1e-12, abs=1e-12)


from model_texts import WHEEL  # noqa: E402 - shared with tests/simulation/test_scaling.py


def _wheel_reference(t_eval, m=2.0, J=0.05, e=0.1, g=9.81, c=0.02, th0=0.3, om0=1.0):
    """θ of the wheel; centre of mass r = s + e(cos θ, sin θ). Lagrange:
    (J + m e²) θ̈ = m e (sin θ ẍ_s − cos θ ÿ_s) − m g e cos θ − c θ̇.
    W: work of the axle on the wheel, F·ṡ with F = m(r̈ + (0, g)) (the axle force does no
    work in the wheel's rotation about it); D: the bearing's dissipation ∫cθ̇²."""

    def rhs(t, z):
        th, om, _, _ = z
        s, ds, dds = _support(t)
        al = (m * e * (np.sin(th) * dds[0] - np.cos(th) * dds[1]) - m * g * e * np.cos(th) - c * om) / (J + m * e**2)
        acc = dds + e * (al * np.array([-np.sin(th), np.cos(th)]) - om**2 * np.array([np.cos(th), np.sin(th)]))
        force = m * (acc + np.array([0.0, g]))
        return [om, al, force @ ds, c * om**2]

    sol = solve_ivp(rhs, (0, t_eval[-1]), [th0, om0, 0.0, 0.0], t_eval=t_eval, rtol=1e-12, atol=1e-12,
                    method="DOP853")
    return sol.y


def test_wheel_on_a_moving_axle_matches_minimal_coordinates(tmp_path):
    path = tmp_path / "wheel.yaml"
    path.write_text(WHEEL)
    result = phc.simulate(phc.compile_model(path))
    assert result.success, result.message
    th, om, work, dissipated = _wheel_reference(result.t)
    assert np.abs(result["wheel.theta"] - th).max() < 1e-7
    assert np.abs(result["wheel.p_om"] / 0.05 - om).max() < 1e-5
    assert result.energy_balance_relative < 1e-7
    supplied = result.energy_supplied - result.energy_supplied[0]
    assert np.abs(supplied - (dissipated - work)).max() < 1e-6 * np.abs(work).max()
    assert result.constraint_drift < 1e-9


def test_phc_check_certifies_the_wheel(tmp_path):
    path = tmp_path / "wheel.yaml"
    path.write_text(WHEEL)
    dae, diags = phc.build_dae(path)
    assert dae is not None, diags
    cert = certify(dae)
    assert cert.certified
    assert "wheel" in cert.rows.compared


ROLLING = """
format_version: 1
name: rolling_on_a_belt
parameters: {m: 1.5, J: 0.02, r: 0.1, k: 30.0, a: 0.05, w: 4.0}
components:
  wheel:
    type: rigid
    description: rolls without slipping on a belt whose position is a sin(w t); a spring ties the axle to a wall
    q: [x, theta]
    v: [vx, om]
    M: [[m, 0], [0, J]]
    V: k*x**2/2
    constraints:
      - x + r*theta - a*sin(w*t)
simulation:
  t_end: 3.0
  n_out: 301
  rtol: 1.0e-10
  atol: 1.0e-10
  initial: {wheel.x: 0.0, wheel.theta: 0.0, wheel.p_vx: {value: 0.0, guess: true}, wheel.p_om: {value: 0.0, guess: true}}
"""


def test_rolling_on_a_moving_belt_matches_minimal_coordinates(tmp_path):
    """θ = (x_b(t) − x)/r; Lagrange in x: (m + J/r²) ẍ = (J/r²) ẍ_b − k x. phc starts from the
    consistent velocities it chooses (the guesses), which the reference takes over."""
    path = tmp_path / "rolling.yaml"
    path.write_text(ROLLING)
    result = phc.simulate(phc.compile_model(path))
    assert result.success, result.message
    m, J, r, k, a, w = 1.5, 0.02, 0.1, 30.0, 0.05, 4.0
    v0 = result["wheel.p_vx"][0] / m
    om0 = result["wheel.p_om"][0] / J
    assert abs(v0 + r * om0 - a * w) < 1e-9  # the velocity form of the constraint, with c_t

    def rhs(t, z):
        return [z[1], ((J / r**2) * (-a * w**2 * np.sin(w * t)) - k * z[0]) / (m + J / r**2)]

    sol = solve_ivp(rhs, (0, 3.0), [0.0, v0], t_eval=result.t, rtol=1e-12, atol=1e-12, method="DOP853")
    assert np.abs(result["wheel.x"] - sol.y[0]).max() < 1e-7
    assert np.abs(result["wheel.theta"] - (a * np.sin(w * result.t) - sol.y[0]) / r).max() < 1e-6
    assert result.energy_balance_relative < 1e-7


KNIFE = """
format_version: 1
name: steered_skate
parameters: {m: 2.0, F: 1.5, w: 2.0, u0: 0.5}
components:
  skate:
    type: rigid
    description: a point on a blade whose heading is steered, phi(t) = w t; pushed by a constant force along x
    q: [x, y]
    v: [vx, vy]
    M: [[m, 0], [0, m]]
    V: -F*x
    velocity_constraints:
      - ["-sin(w*t)", "cos(w*t)"]
simulation:
  t_end: 3.0
  n_out: 301
  rtol: 1.0e-10
  atol: 1.0e-10
  initial: {skate.x: 0.0, skate.y: 0.0, skate.p_vx: m*u0, skate.p_vy: 0.0}
"""


def test_time_dependent_velocity_constraint_matches_the_closed_form(tmp_path):
    """A(t) v = 0 with the heading e(t) = (cos wt, sin wt): v = u e, m u̇ = F·e = F cos wt, so
    u = u0 + F sin(wt)/(m w); the constraint is ideal (no work): H(t) − H(0) = F x(t)… is
    the work of the constant force, i.e. the balance closes with no port power."""
    path = tmp_path / "skate.yaml"
    path.write_text(KNIFE)
    result = phc.simulate(phc.compile_model(path))
    assert result.success, result.message
    m, F, w, u0 = 2.0, 1.5, 2.0, 0.5

    def rhs(t, z):
        u = u0 + F * np.sin(w * t) / (m * w)
        return [u * np.cos(w * t), u * np.sin(w * t)]

    sol = solve_ivp(rhs, (0, 3.0), [0.0, 0.0], t_eval=result.t, rtol=1e-12, atol=1e-12, method="DOP853")
    assert np.abs(result["skate.x"] - sol.y[0]).max() < 1e-7
    assert np.abs(result["skate.y"] - sol.y[1]).max() < 1e-7
    assert result.energy_balance_relative < 1e-8
    assert np.abs(result.energy_supplied).max() < 1e-7  # an ideal constraint does no work
    assert certify(phc.build_dae(path)[0]).certified


def test_time_dependent_potential_is_booked_in_the_balance(tmp_path):
    """V(x, t) = ½k(t)x²: H changes by ∂H/∂t at fixed state; the balance books −∂H/∂t."""
    path = tmp_path / "vt.yaml"
    path.write_text("""
format_version: 1
parameters: {m: 1.0, k: 4.0}
components:
  body: {type: rigid, q: [x], v: [vx], M: [[m]], V: 0.5*k*(1 + 0.5*sin(3*t))*x**2}
simulation:
  t_end: 3.0
  n_out: 301
  rtol: 1.0e-10
  atol: 1.0e-10
  initial: {body.x: 1.0, body.p_vx: 0.0}
""")
    result = phc.simulate(phc.compile_model(path))
    assert result.success

    def rhs(t, z):
        return [z[1], -4.0 * (1 + 0.5 * np.sin(3 * t)) * z[0]]

    sol = solve_ivp(rhs, (0, 3.0), [1.0, 0.0], t_eval=result.t, rtol=1e-12, atol=1e-12, method="DOP853")
    assert np.abs(result["body.x"] - sol.y[0]).max() < 1e-7
    assert result.energy_balance_relative < 1e-7
    # the energy put in by varying k: ∫ ½ k'(t) x² dt (independently, from the reference)
    put_in = cumulative_trapezoid(0.5 * 4.0 * 1.5 * np.cos(3 * result.t) * sol.y[0] ** 2, result.t, initial=0)
    assert np.abs(-(result.energy_supplied - result.energy_supplied[0]) - put_in).max() < 1e-3


# ---------------------------------------------------------------------------------------
# Refused, located: where t or a state would be dropped.

def _refused(tmp_path, text, code):
    path = tmp_path / "m.yaml"
    path.write_text(text)
    dae, diags = phc.build_dae(path)
    errors = [d for d in diags if d.severity == "error"]
    assert dae is None and errors, "expected a refusal"
    assert errors[0].code == code, [str(d) for d in errors]
    assert errors[0].span is not None and errors[0].span.line > 1
    return errors[0], text.splitlines()


RIGID = """
format_version: 1
parameters: {{m: 1.0, k: 2.0}}
components:
  body:
    type: rigid
    q: [x, y]
    v: [vx, vy]
    M: [[m, 0], [0, m]]
{body}
simulation:
  t_end: 1.0
  initial: {{body.x: 1.0, body.y: 0.0}}
"""


@pytest.mark.parametrize("body, field, what", [
    ("    V: k*x**2/2 + p_vx**2", "V", "momentum"),
    ("    constraints: [x - vy]", "constraints", "velocity"),
    ('    velocity_constraints: [["1", "vy"]]', "velocity_constraints", "velocity"),
    ('    M: [["m", 0], [0, "m + vx**2"]]', "M", "velocity"),
    ("    ports:\n      a: {B: [[1], [0]], position: [x + t]}", "position", "time"),
], ids=["V(p)", "c(v)", "A(v)", "M(v)", "position(t)"])
def test_rigid_fields_refuse_what_they_would_drop(tmp_path, body, field, what):
    text = RIGID.format(body=body)
    if body.lstrip().startswith("M:"):
        text = text.replace("    M: [[m, 0], [0, m]]\n", "", 1)
    if "ports" in body:
        text = text.replace("components:", "components:\n  free: {type: zero_effort, dimension: 1}", 1)
        text += "connections:\n  - [body.a, free.port]\n"
    err, lines = _refused(tmp_path, text, "PHC-E126")
    assert what in err.message
    assert field in lines[err.span.line - 1]


SLIDER = """
format_version: 1
parameters: {m: 1.0}
components:
  body:
    type: rigid
    q: [x]
    M: [[m]]
    ports:
      a: {B: [[1]], position: [x]}
  drive: {type: %s, %s}
connections:
  - [body.a, drive.port]
simulation:
  t_end: 1.0
  initial: {body.x: 0.0}
"""


def test_flow_source_position_must_integrate_its_value(tmp_path):
    ok = tmp_path / "ok.yaml"
    ok.write_text(SLIDER % ("flow_source", 'value: "0.3*cos(t)", position: ["0.3*sin(t)"]'))
    result = phc.simulate(phc.compile_model(ok))
    assert result.success and np.abs(result["body.x"] - 0.3 * np.sin(result.t)).max() < 1e-8
    err, lines = _refused(tmp_path, SLIDER % ("flow_source", 'value: "0.3*cos(t)", position: ["0.2*sin(t)"]'),
                          "PHC-E127")
    assert "position" in lines[err.span.line - 1] and "does not integrate" in err.message


def test_a_fixed_support_may_not_move(tmp_path):
    err, lines = _refused(tmp_path, SLIDER % ("zero_flow", 'position: ["0.1*t"]'), "PHC-E127")
    assert "position" in lines[err.span.line - 1]


def test_coefficients_in_t_are_checked_over_the_run(tmp_path):
    err, lines = _refused(tmp_path, """
format_version: 1
components:
  mass: {type: mass, m: 1.0}
  spring: {type: spring, k: "4 - 3*t"}
connections:
  - [mass.port, spring.port]
simulation:
  t_end: 2.0
  initial: {spring.x: 0.5}
""", "PHC-E405")
    assert "at t = " in err.message and "k:" in lines[err.span.line - 1]


def test_crank_wheel_geometry_and_linear_scales_refuse_t(tmp_path):
    crank = """
format_version: 1
components:
  wheel: {type: crank_wheel, radius: "0.1*(1 + t)", inertia: 1.0}
  free: {type: zero_effort, domain: mechanical.translational, dimension: 2}
  loose: {type: zero_effort, domain: mechanical.rotational}
connections:
  - [wheel.pin, free.port]
  - [wheel.drive, loose.port]
simulation: {t_end: 1.0}
"""
    err, lines = _refused(tmp_path, crank, "PHC-E127")
    assert "radius" in lines[err.span.line - 1]
    linear = """
format_version: 1
components:
  lc:
    type: linear_phs
    states: [q, phi]
    J: [[0, 1], [-1, 0]]
    scale: {Q: "1 + 0.5*sin(t)"}
    ports:
      p: {B: [[0], [1]]}
  free: {type: zero_effort}
connections:
  - [lc.p, free.port]
simulation: {t_end: 1.0}
"""
    err, lines = _refused(tmp_path, linear, "PHC-E127")
    assert "scale" in lines[err.span.line - 1]
