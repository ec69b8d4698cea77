"""Tests of `phc.library.rigid` (the seed's rigid multibody DAE, eq. mks2)."""

import numpy as np
from scipy.integrate import solve_ivp

import phc

DOUBLE_PENDULUM = """
format_version: 1
parameters: {m1: 1.0, m2: 0.7, L1: 1.0, L2: 0.8, g: 9.81}
components:
  arms:
    type: rigid
    q: [th1, th2]
    v: [w1, w2]
    M: [["(m1 + m2)*L1**2", "m2*L1*L2*cos(th1 - th2)"],
        ["m2*L1*L2*cos(th1 - th2)", "m2*L2**2"]]
    V: -(m1 + m2)*g*L1*cos(th1) - m2*g*L2*cos(th2)
simulation:
  t_end: 3.0
  n_out: 301
  rtol: 1.0e-11
  atol: 1.0e-11
  initial: {arms.th1: 1.2, arms.th2: -0.4, arms.p_w1: 0.0, arms.p_w2: 0.0}
"""


def double_pendulum_rhs(t, s, m1=1.0, m2=0.7, L1=1.0, L2=0.8, g=9.81):
    """Lagrange's equations of the double pendulum, written independently."""
    th1, th2, w1, w2 = s
    d = th1 - th2
    M = np.array([[(m1 + m2) * L1**2, m2 * L1 * L2 * np.cos(d)], [m2 * L1 * L2 * np.cos(d), m2 * L2**2]])
    rhs = np.array([-m2 * L1 * L2 * np.sin(d) * w2**2 - (m1 + m2) * g * L1 * np.sin(th1),
                    m2 * L1 * L2 * np.sin(d) * w1**2 - m2 * g * L2 * np.sin(th2)])
    a = np.linalg.solve(M, rhs)
    return [w1, w2, a[0], a[1]]


def test_configuration_dependent_mass_matrix_matches_lagrange(tmp_path):
    path = tmp_path / "dp.yaml"
    path.write_text(DOUBLE_PENDULUM)
    result = phc.simulate(phc.compile_model(path))
    assert result.success
    ref = solve_ivp(double_pendulum_rhs, (0, 3.0), [1.2, -0.4, 0.0, 0.0], t_eval=result.t, rtol=1e-12,
                    atol=1e-12, method="DOP853")
    assert np.abs(result["arms.th1"] - ref.y[0]).max() < 1e-6
    assert np.abs(result["arms.th2"] - ref.y[1]).max() < 1e-6
    assert result.energy_balance_relative < 1e-7


def test_gyroscopic_term_conserves_energy(tmp_path):
    """A charged particle in a magnetic field: G(p) = B·[[0, 1], [−1, 0]] is skew, so
    the speed is constant and the orbit is a circle of radius m v / (qB)."""
    path = tmp_path / "gyro.yaml"
    path.write_text("""
format_version: 1
parameters: {m: 2.0, Bq: 0.5}
components:
  particle:
    type: rigid
    q: [x, y]
    v: [vx, vy]
    M: [[m, 0], [0, m]]
    G: [[0, Bq], [-Bq, 0]]
simulation:
  t_end: 20.0
  rtol: 1.0e-11
  atol: 1.0e-12
  initial: {particle.x: 0.0, particle.y: 0.0, particle.p_vx: 2.0, particle.p_vy: 0.0}
""")
    result = phc.simulate(phc.compile_model(path))
    assert result.success
    assert result.energy_balance_relative < 1e-8
    x, y = result["particle.x"], result["particle.y"]
    radius = 2.0 * 1.0 / 0.5  # m v / (qB) with v = p/m = 1
    # ṗ = −G v pushes the particle, starting along +x, towards +y: centre (0, radius)
    centre = np.array([0.0, radius])
    r = np.hypot(x - centre[0], y - centre[1])
    assert np.abs(r - radius).max() < 1e-7


def test_damping_dissipates_v_dot_fd(tmp_path):
    path = tmp_path / "d.yaml"
    path.write_text("""
format_version: 1
parameters: {m: 1.0, c: 0.3, k: 2.0}
components:
  body:
    type: rigid
    q: [x]
    M: [[m]]
    V: k*x**2/2
    damping: [c*v_x]
simulation:
  t_end: 5.0
  rtol: 1.0e-10
  atol: 1.0e-12
  initial: {body.x: 1.0, body.p_v_x: 0.0}
""")
    result = phc.simulate(phc.compile_model(path))
    assert result.success
    assert result.H[-1] < 0.5 * result.H[0]
    assert result.energy_balance_relative < 1e-8
    w0, zeta = np.sqrt(2.0), 0.3 / (2 * np.sqrt(2.0))
    wd = w0 * np.sqrt(1 - zeta**2)
    t = result.t
    exact = np.exp(-zeta * w0 * t) * (np.cos(wd * t) + zeta * w0 / wd * np.sin(wd * t))
    assert np.abs(result["body.x"] - exact).max() < 1e-7
