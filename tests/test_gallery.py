"""The gallery (docs/gallery.md, issue 15 item 6): every model validates, is certified by
`phc check`, simulates, and matches an independent solution written here — scipy's
integration of the textbook equations, a matrix exponential, or a closed form."""

from __future__ import annotations

import cmath
import math
from functools import lru_cache
from pathlib import Path

import numpy as np
import pytest
import scipy.linalg as sla
from scipy.integrate import solve_ivp
from scipy.optimize import brentq, fsolve

import phc

MODELS = Path(__file__).resolve().parents[1] / "models"
GALLERY = ["dc_motor_gear", "dc_motor_pi", "two_mass_cubic_spring", "quarter_car", "hydraulic_cylinder", "thermal_ladder",
           "rlc_filter", "double_pendulum", "controlled_beam"]
TIGHT = dict(rtol=1e-11, atol=1e-13)


@lru_cache(maxsize=None)
def run(name: str) -> phc.SimResult:
    result = phc.simulate(phc.compile_model(MODELS / f"{name}.yaml"))
    assert result.success, result.message
    assert result.energy_balance_relative < 1e-6, result.energy_balance_relative
    return result


def piecewise(f, y0, breaks, t):
    """solve_ivp across the breakpoints of a piecewise input, evaluated at t."""
    out = np.zeros((len(y0), len(t)))
    edges = [t[0], *[b for b in breaks if t[0] < b < t[-1]], t[-1]]
    y = np.asarray(y0, dtype=float)
    for a, b in zip(edges[:-1], edges[1:]):
        sol = solve_ivp(f, (a, b), y, dense_output=True, **TIGHT)
        inside = (t >= a) & (t <= b)
        out[:, inside] = sol.sol(t[inside])
        y = sol.y[:, -1]
    return out


@pytest.mark.parametrize("name", GALLERY)
def test_gallery_model_is_certified(name):
    report = phc.certify_model(MODELS / f"{name}.yaml")
    assert report.certified, report.render_text()
    assert MODELS.joinpath(f"{name}.yaml").read_text().startswith(
        "# yaml-language-server: $schema=../schemas/model.schema.json\n")


def test_dc_motor_gear_matches_the_motor_equations():
    V, R, L, Km, Jm, N, ks, Jl, c, TL, tl = 12.0, 1.0, 0.01, 0.05, 1e-4, 0.1, 50.0, 0.01, 1e-3, 0.2, 0.5

    def motor(t, y):
        i, wm, th, wl = y
        return [(V - R * i - Km * wm) / L, (Km * i - N * ks * th) / Jm, N * wm - wl,
                (ks * th - c * wl - (TL if t >= tl else 0.0)) / Jl]

    r = run("dc_motor_gear")
    i, wm, th, wl = piecewise(motor, [0, 0, 0, 0], [tl], r.t)
    assert np.abs(r.outputs["current"] - i).max() < 1e-6
    assert np.abs(r.outputs["motor_speed"] - wm).max() < 1e-5
    assert np.abs(r.outputs["load_speed"] - wl).max() < 1e-6
    assert np.abs(r.outputs["shaft_torque"] - ks * th).max() < 1e-6
    assert wl[-1] > 20.0  # a positive voltage turns the load forward
    # the load torque slows the load down: it runs slower after t_load than just before
    assert r.outputs["load_speed"][-1] < np.interp(tl, r.t, r.outputs["load_speed"])


def test_dc_motor_pi_matches_the_closed_loop_equations():
    """The PI-controlled motor against the motor equations plus the controller's integral
    state, integrated by scipy at rtol 1e-11 (phc at 1e-10): both are far below the
    tolerances, which allow for the global error of the looser one over 2 s."""
    V0, Kp, Ki = 10.0, 0.5, 5.0
    R, L, Km, Jm, N, ks, Jl, c, TL, tl = 1.0, 0.01, 0.05, 1e-4, 0.1, 50.0, 0.01, 1e-3, 0.2, 1.0

    def loop(t, y):
        i, wm, th, wl, z = y
        e = V0 - N * wm
        V = Kp * e + Ki * z
        return [(V - R * i - Km * wm) / L, (Km * i - N * ks * th) / Jm, N * wm - wl,
                (ks * th - c * wl - (TL if t >= tl else 0.0)) / Jl, e]

    r = run("dc_motor_pi")
    i, wm, th, wl, z = piecewise(loop, [0, 0, 0, 0, 0], [tl], r.t)
    assert np.abs(r.outputs["current"] - i).max() < 1e-6
    assert np.abs(r.outputs["load_speed"] - wl).max() < 1e-6
    assert np.abs(r.outputs["error_integral"] - z).max() < 1e-7
    assert np.abs(r.outputs["voltage"] - (Kp * (V0 - N * wm) + Ki * z)).max() < 1e-6
    # the integral action holds the speed at the reference before and after the load step
    assert abs(np.interp(tl, r.t, r.outputs["load_speed"]) - V0) < 0.02
    assert abs(r.outputs["load_speed"][-1] - V0) < 0.01
    assert r.outputs["voltage"][-1] > np.interp(tl, r.t, r.outputs["voltage"]) + 0.3  # more voltage for the load


def test_dc_motor_pi_closed_loop_eigenvalues_are_those_of_the_motor_equations():
    """`phc linearize` of the PI loop against the matrix of the equations in the model's
    header, states (i, ω_m, θ, ω_l, z), with V = Kp (w_ref − N ω_m) + Ki z. The Jacobians
    are exact (generated code), so QZ round-off on a matrix of norm ~1e4 is the only error:
    1e-9 relative is far above it."""
    Kp, Ki = 0.5, 5.0
    R, L, Km, Jm, N, ks, Jl, c = 1.0, 0.01, 0.05, 1e-4, 0.1, 50.0, 0.01, 1e-3
    A = np.array([[-R / L, -(Kp * N + Km) / L, 0.0, 0.0, Ki / L],
                  [Km / Jm, 0.0, -N * ks / Jm, 0.0, 0.0],
                  [0.0, N, 0.0, -1.0, 0.0],
                  [0.0, 0.0, ks / Jl, -c / Jl, 0.0],
                  [0.0, -N, 0.0, 0.0, 0.0]])
    expected = sorted(np.linalg.eigvals(A), key=lambda z: (round(z.real, 6), z.imag))
    lin = phc.linearize_model(MODELS / "dc_motor_pi.yaml")
    found = sorted(lin.eigenvalues, key=lambda z: (round(z.real, 6), z.imag))
    assert len(found) == 5 and lin.n_states == 5
    for a, b in zip(found, expected):
        assert abs(a - b) <= 1e-9 * abs(b), (found, expected)
    assert max(z.real for z in expected) < 0  # the loop is stable


def test_two_mass_chain_with_a_cubic_spring_matches_the_duffing_equations():
    m1, m2, k1, k, k3, c = 1.0, 2.0, 10.0, 5.0, 50.0, 0.5

    def chain(t, y):
        x1, x2, v1, v2 = y
        force = k * (x1 - x2) + k3 * (x1 - x2) ** 3
        return [v1, v2, (-k1 * x1 - force) / m1, (force - c * v2) / m2]

    r = run("two_mass_cubic_spring")
    ref = solve_ivp(chain, (0.0, r.t[-1]), [0.0, 0.5, 0.0, 0.0], t_eval=r.t, **TIGHT)
    assert np.abs(r.outputs["x1"] - ref.y[0]).max() < 1e-6
    assert np.abs(r.outputs["x2"] - ref.y[1]).max() < 1e-6
    s = ref.y[0] - ref.y[1]
    H = m1 * ref.y[2] ** 2 / 2 + m2 * ref.y[3] ** 2 / 2 + k1 * ref.y[0] ** 2 / 2 + k * s**2 / 2 + k3 * s**4 / 4
    assert np.abs(r.outputs["energy"] - H).max() < 1e-6
    assert np.abs(s).max() > 0.4  # the cubic term dominates the coupling: k3 s² > k there


def test_quarter_car_matches_the_two_mass_suspension_equations():
    ms, mu, ks, cs, kt, h, Tb, tb = 250.0, 35.0, 16000.0, 1000.0, 160000.0, 0.05, 0.1, 0.1

    def road(t):
        return h * (1 - math.cos(2 * math.pi * (t - tb) / Tb)) / 2 if tb <= t < tb + Tb else 0.0

    def car(t, y):
        zs, zu, vs, vu = y
        return [vs, vu, (ks * (zu - zs) + cs * (vu - vs)) / ms,
                (-ks * (zu - zs) - cs * (vu - vs) + kt * (road(t) - zu)) / mu]

    r = run("quarter_car")
    zs, zu, vs, vu = piecewise(car, [0, 0, 0, 0], [tb, tb + Tb], r.t)
    assert np.abs(r.outputs["body_displacement"] - zs).max() < 1e-8
    assert np.abs(r.outputs["wheel_displacement"] - zu).max() < 1e-8
    # the body's acceleration (der(body.p)/m_s) against the equation of motion at the
    # reference states: ~3 m/s² at most, its errors those of z and v times k_s/m_s = 64 s⁻²
    accel = (ks * (zu - zs) + cs * (vu - vs)) / ms
    assert np.abs(r.outputs["body_acceleration"] - accel).max() < 1e-6
    assert 0.2 * h < zs.max() < h  # the suspension filters the bump


def test_hydraulic_cylinder_matches_the_valve_chamber_piston_equations():
    Ps, Rv, V0, beta, A, m, k, c = 1.0, 0.02, 10.0, 1000.0, 200.0, 10.0, 2e4, 100.0
    C = V0 / beta

    def cylinder(t, y):
        p, x, v = y
        return [((Ps - p) / Rv - A * v) / C, v, (A * p - k * x - c * v) / m]

    r = run("hydraulic_cylinder")
    ref = solve_ivp(cylinder, (0.0, r.t[-1]), [0.0, 0.0, 0.0], t_eval=r.t, method="Radau", **TIGHT)
    assert np.abs(r.outputs["pressure"] - ref.y[0]).max() < 1e-6
    assert np.abs(r.outputs["position"] - ref.y[1]).max() < 1e-9
    assert np.abs(r.outputs["velocity"] - ref.y[2]).max() < 1e-7
    assert abs(r.outputs["position"][-1] - A * Ps / k) < 1e-3 * A * Ps / k  # settled: x = A P_s / k


def test_thermal_ladder_matches_the_matrix_exponential_and_the_steady_state():
    P, C1, C2, C3, R12, R23, R3a = 10.0, 100.0, 50.0, 200.0, 0.5, 1.0, 2.0
    K = np.array([[1 / R12, -1 / R12, 0], [-1 / R12, 1 / R12 + 1 / R23, -1 / R23], [0, -1 / R23, 1 / R23 + 1 / R3a]])
    A = -np.diag([1 / C1, 1 / C2, 1 / C3]) @ K
    steady = np.array([P * (R3a + R23 + R12), P * (R3a + R23), P * R3a])
    assert np.allclose(A @ steady + [P / C1, 0, 0], 0.0)
    r = run("thermal_ladder")
    T = np.array([steady - sla.expm(A * t) @ steady for t in r.t]).T
    for k, name in enumerate(["T1", "T2", "T3"]):
        assert np.abs(r.outputs[name] - T[k]).max() < 1e-6
        assert abs(r.outputs[name][-1] - steady[k]) < 0.05  # 7.6 slowest time constants
    assert np.all(np.diff(r.outputs["T3"]) >= -1e-12)  # heating only


def test_rlc_filter_matches_the_circuit_equations_and_its_transfer_function():
    Rs, L, C, RL, V1, V2 = 10.0, 1.0, 1e-3, 50.0, 1.0, 0.5

    def vin(t):
        return V1 * np.sin(2 * np.pi * t) + V2 * np.sin(2 * np.pi * 20 * t)

    r = run("rlc_filter")
    ref = solve_ivp(lambda t, y: [(vin(t) - Rs * y[0] - y[1]) / L, (y[0] - y[1] / RL) / C], (0.0, r.t[-1]),
                    [0.0, 0.0], t_eval=r.t, **TIGHT)
    assert np.abs(r.outputs["current"] - ref.y[0]).max() < 1e-6
    assert np.abs(r.outputs["v_out"] - ref.y[1]).max() < 1e-6
    lin = phc.linearize_model(MODELS / "rlc_filter.yaml")
    row = lin.outputs.index("v_out")
    for f in (0.0, 1.0, 5.0, 20.0):
        s = 2j * math.pi * f
        Z = RL / (1 + s * RL * C)
        G = (lin.C @ np.linalg.solve(s * lin.E - lin.A, lin.B) + lin.D)[row, 0]
        assert abs(G - Z / (Rs + s * L + Z)) < 1e-10
    # the 20 Hz disturbance is attenuated 12×, the 1 Hz signal passes (|H| = 0.85)
    H = [abs(RL / (1 + s * RL * C) / (Rs + s * L + RL / (1 + s * RL * C))) for s in (2j * math.pi, 2j * math.pi * 20)]
    assert H[0] > 0.8 and H[1] < 0.07


def test_double_pendulum_matches_the_lagrange_equations_in_the_angles():
    m1, m2, L1, L2, g = 1.0, 0.5, 1.0, 0.7, 9.81

    def lagrange(t, y):
        a, b, wa, wb = y
        d = a - b
        M = np.array([[(m1 + m2) * L1, m2 * L2 * math.cos(d)], [L1 * math.cos(d), L2]])
        rhs = [-m2 * L2 * wb**2 * math.sin(d) - (m1 + m2) * g * math.sin(a), L1 * wa**2 * math.sin(d) - g * math.sin(b)]
        return [wa, wb, *np.linalg.solve(M, rhs)]

    r = run("double_pendulum")
    ref = solve_ivp(lagrange, (0.0, r.t[-1]), [1.0, 0.5, 0.0, 0.0], t_eval=r.t, method="DOP853", rtol=1e-12,
                    atol=1e-12)
    a, b = ref.y[0], ref.y[1]
    assert np.abs(r["bobs.x1"] - L1 * np.sin(a)).max() < 1e-6
    assert np.abs(r["bobs.x2"] - L1 * np.sin(a) - L2 * np.sin(b)).max() < 1e-6
    assert np.abs(r["bobs.y2"] + L1 * np.cos(a) + L2 * np.cos(b)).max() < 1e-6
    assert np.abs(r.outputs["energy"] - r.outputs["energy"][0]).max() < 1e-7
    assert r.constraint_drift < 1e-8


EI, RHOA, LB, MT, KD = 68.27, 0.50368, 0.3, 0.05, 2.0  # models/controlled_beam.yaml


def beam_determinant(s: complex, Kd: float) -> complex:
    """Clamped–tip-mass beam with tip velocity feedback: w = a (cosh − cos) + b (sinh − sin)
    satisfies the clamp; the rows are w''(L) = 0 and EI w'''(L) = (m_t s² + K_d s) w(L)."""
    k = (-RHOA * s**2 / EI) ** 0.25
    ch, sh, co, si = cmath.cosh(k * LB), cmath.sinh(k * LB), cmath.cos(k * LB), cmath.sin(k * LB)
    z = MT * s**2 + Kd * s
    r1 = (k**2 * (ch + co), k**2 * (sh + si))
    r2 = (EI * k**3 * (sh - si) - z * (ch - co), EI * k**3 * (ch + co) - z * (sh - si))
    return r1[0] * r2[1] - r1[1] * r2[0]


def beam_root(guess: complex, Kd: float) -> complex:
    sol = fsolve(lambda v: [beam_determinant(complex(*v), Kd).real, beam_determinant(complex(*v), Kd).imag],
                 [guess.real, guess.imag], xtol=1e-14)
    return complex(*sol)


def test_controlled_beam_first_eigenvalue_and_energy_decay_match_the_continuous_beam():
    # without feedback: the tip-mass cantilever's frequency equation (independent form)
    mu = MT / (RHOA * LB)
    b1 = brentq(lambda b: 1 + math.cos(b) * math.cosh(b) + mu * b * (math.cos(b) * math.sinh(b) - math.sin(b) * math.cosh(b)),
                0.5, 1.87)
    w1 = (b1 / LB) ** 2 * math.sqrt(EI / RHOA)
    assert abs(beam_root(complex(0, 0.9 * w1), 0.0) - 1j * w1) < 1e-8 * w1
    s1 = beam_root(complex(-1.0, w1), KD)
    assert s1.real < 0 and abs(s1.imag - w1) < 0.01 * w1  # damped, barely detuned
    lin = phc.linearize_model(MODELS / "controlled_beam.yaml")
    assert [u.name for u in lin.inputs] == ["actuator", "hammer"]
    first = lin.modes[0]
    assert abs(first.eigenvalue - s1) < 1e-4 * abs(s1)  # 6 Hermite elements
    assert abs(first.damping_ratio - (-s1.real / abs(s1))) < 1e-4
    # the simulated energy after the pulse decays over whole damped periods like exp(2 Re s1 T)
    r = run("controlled_beam")
    T = 2 * math.pi / s1.imag
    t1 = 0.03
    ratio = np.interp(t1 + 3 * T, r.t, r.H) / np.interp(t1, r.t, r.H)
    assert abs(ratio / math.exp(2 * s1.real * 3 * T) - 1) < 0.01
    # the controller only takes energy out: its power −K_d v² is the supplied power
    v = r.outputs["tip_velocity"]
    after = r.t >= 0.005
    assert np.all(np.diff(r.H[after]) <= 1e-12)
    assert r.energy_balance_relative < 1e-10
    assert np.abs(r.outputs["actuator_force"] + KD * v).max() < 1e-12
