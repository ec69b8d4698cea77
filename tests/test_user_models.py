"""Models a new user wrote from the documentation alone (fifth round), each against an
independent answer computed here: scipy's Radau at tight tolerance on equations derived by
hand, or a closed form.

* an elastic (spring) pendulum, a `rigid` point mass with V = m g y + k/2 (r − L0)²;
* a series circuit with a saturating inductor (H = φ²/2L + a φ⁴/4, a `phs`) and a cubic
  resistor (a state-less `phs` with a resistive port), switched on at t = 0.1;
* a cart–pole linearized about the upright position (`phc linearize`) against the
  hand-derived M q̈ + K q = [F, 0];
* a resonance curve from `phc sweep` against the steady-state amplitude
  F / sqrt((k − m ω²)² + (c ω)²);
* two spring-mounted masses with a hard stop between them (`contact`), against
  piecewise Radau runs with Newton's impact law applied by hand.
"""

from __future__ import annotations

import csv
import math
import warnings

import numpy as np
import pytest
from scipy.integrate import solve_ivp

import phc
from phc.cli import main

ELASTIC = """\
format_version: 1
name: elastic_pendulum
parameters:
  m: {value: 0.5, unit: kg}
  k: {value: 40.0, unit: N/m}
  L0: {value: 1.0, unit: m}
  g: {value: 9.81, unit: m/s^2}
components:
  bob:
    type: rigid
    q: [x, y]
    v: [vx, vy]
    M: [[m, 0], [0, m]]
    V: m*g*y + k/2*(sqrt(x**2 + y**2) - L0)**2
simulation:
  t_end: 5.0
  n_out: 501
  initial: {bob.x: 0.6, bob.y: -1.0, bob.p_vx: 0.0, bob.p_vy: 0.3}
  outputs: {x: bob.x, y: bob.y}
"""


def _elastic_reference():
    m, k, L0, g = 0.5, 40.0, 1.0, 9.81

    def rhs(t, s):
        x, y, vx, vy = s
        r = math.hypot(x, y)
        f = -k * (r - L0) / r
        return [vx, vy, f * x / m, f * y / m - g]

    return solve_ivp(rhs, (0, 5), [0.6, -1.0, 0.0, 0.3 / m], method="Radau", rtol=1e-12, atol=1e-13,
                     dense_output=True).sol


def test_elastic_pendulum_against_radau_with_ida_and_the_discrete_gradient(tmp_path):
    path = tmp_path / "elastic.yaml"
    path.write_text(ELASTIC)
    compiled = phc.compile_model(str(path))
    ref = _elastic_reference()
    run = phc.simulate(compiled, rtol=1e-10, atol=1e-12)
    exact = ref(run.t)
    # IDA at rtol 1e-10 over ~3 swings: global error measured 1e-10; allow 100x for the accumulation
    assert np.abs(run["bob.x"] - exact[0]).max() < 1e-8
    assert np.abs(run["bob.y"] - exact[1]).max() < 1e-8
    errors = []
    for h in (0.01, 0.005):
        dg = phc.simulate(compiled, solver="discrete_gradient", step=h)
        exact = ref(dg.t)
        errors.append(max(np.abs(dg["bob.x"] - exact[0]).max(), np.abs(dg["bob.y"] - exact[1]).max()))
        # the discrete gradient keeps the energy of any H to the Newton tolerance
        assert dg.energy_balance_error < 1e-11
    assert errors[0] < 5e-3  # measured 2.2e-3 at h = 0.01: second order, C h² with C ~ 20
    assert 3.6 < errors[0] / errors[1] < 4.4  # order 2: the error falls by 4 when h halves


NONLINEAR_RLC = """\
format_version: 1
name: nonlinear_rlc
parameters:
  L: {value: 0.5, unit: H}
  a: {value: 20.0, unit: A/Wb^3}
  C: {value: 0.02, unit: F}
  R1: {value: 0.5, unit: Ohm}
  R3: {value: 2.0, unit: V/A^3}
  V0: {value: 5.0, unit: V}
components:
  coil:
    type: phs
    states: [phi]
    hamiltonian: phi**2/(2*L) + a*phi**4/4
    J: [[0]]
    ports:
      p: {domain: electrical, causality: effort_in, B: [[1]]}
  cap: {type: capacitor, C: C}
  res:
    type: phs
    states: []
    ports:
      p: {domain: electrical}
    resistive:
      r: {law: [e_r = R1*f_r + R3*f_r**3]}
    relations:
      - f_r - f_p = 0
      - e_p + e_r = 0
  battery: {type: effort_source, domain: electrical, value: "ifelse(t < 0.1, 0, V0)"}
  loop: {type: junction, kind: common_flow, domain: electrical, ports: [b, l, c, r]}
connections:
  - [loop.b, battery.port]
  - [loop.l, coil.p]
  - [loop.c, cap.port]
  - [loop.r, res.p]
simulation:
  t_end: 3.0
  n_out: 301
  initial: {coil.phi: 0.0, cap.q: 0.0}
  outputs: {i: coil.phi/L + a*coil.phi**3}
"""


def test_saturating_inductor_and_cubic_resistor_against_radau(tmp_path):
    L, a, C, R1, R3, V0 = 0.5, 20.0, 0.02, 0.5, 2.0, 5.0

    def rhs(t, s):  # Kirchhoff's voltage law round the loop, i = dH/dφ
        phi, q = s
        i = phi / L + a * phi**3
        return [V0 - q / C - R1 * i - R3 * i**3, i]

    ref = solve_ivp(rhs, (0.1, 3.0), [0.0, 0.0], method="Radau", rtol=1e-12, atol=1e-14, dense_output=True).sol
    path = tmp_path / "nlrlc.yaml"
    path.write_text(NONLINEAR_RLC)
    compiled = phc.compile_model(str(path))
    for solver, options, tol in (("ida", {"rtol": 1e-10, "atol": 1e-12}, 1e-8),  # 100x the measured 5e-11
                                 ("discrete_gradient", {"step": 1e-3}, 3e-5)):   # measured 1.0e-5: C h², C ~ 10
        run = phc.simulate(compiled, solver=solver, **options)
        on = run.t >= 0.1
        exact = ref(run.t[on])
        assert np.abs(run["coil.phi"][on] - exact[0]).max() < tol, solver
        assert np.abs(run["cap.q"][on] - exact[1]).max() < tol, solver
        assert np.abs(run["i"][on] - (exact[0] / L + a * exact[0] ** 3)).max() < 20 * tol, solver


CART_POLE = """\
format_version: 1
name: cart_pole
parameters:
  Mc: {value: 2.0, unit: kg}
  m: {value: 0.4, unit: kg}
  l: {value: 0.8, unit: m}
  g: {value: 9.81, unit: m/s^2}
  F0: {value: 0.0, unit: N}
components:
  cp:
    type: rigid
    q: [s, th]
    v: [vs, w]
    M: [[Mc + m, m*l*cos(th)], [m*l*cos(th), m*l**2]]
    V: m*g*l*cos(th)
    ports:
      push: {domain: mechanical.translational, B: [[1], [0]]}
  force: {type: effort_source, domain: mechanical.translational, value: F0}
connections:
  - [cp.push, force.port]
simulation:
  t_end: 1.0
  initial: {cp.s: 0.0, cp.th: 0.0, cp.p_vs: 0.0, cp.p_w: 0.0}
  outputs: {s: cp.s, th: cp.th}
"""


def test_cart_pole_linearized_upright_against_the_hand_derived_system(tmp_path, capsys):
    Mc, m, l, g = 2.0, 0.4, 0.8, 9.81
    path = tmp_path / "cart_pole.yaml"
    path.write_text(CART_POLE)
    lin = phc.linearize_model(str(path))
    M0 = np.array([[Mc + m, m * l], [m * l, m * l**2]])  # the mass matrix at th = 0
    K = np.diag([0.0, -m * g * l])                       # V ≈ m g l (1 − th²/2)
    for s in (0.5j, 2j, 1 + 3j, 7.0):
        G = lin.C @ np.linalg.solve(s * lin.E - lin.A, lin.B) + lin.D
        X = np.linalg.solve(s**2 * M0 + K, [1.0, 0.0])  # (s, th) per newton of push
        assert np.abs(G[:, 0] - X).max() < 1e-12 * np.abs(X).max()  # round-off of 6x6 solves
    grow = math.sqrt((Mc + m) * g / (Mc * l))
    values = sorted(md.eigenvalue.real for md in lin.modes)
    assert values[0] == pytest.approx(-grow, rel=1e-12) and values[-1] == pytest.approx(grow, rel=1e-12)
    # the free cart's double zero eigenvalue: exactly 0 in the modes, listed without a damping ratio
    assert [md.eigenvalue for md in lin.modes[:2]] == [0, 0]
    assert all(math.isnan(md.damping_ratio) for md in lin.modes[:2])
    assert main(["linearize", str(path)]) == 0
    rows = [line.split() for line in capsys.readouterr().out.splitlines() if line.strip()[:1] in "1234"]
    assert [r[1] for r in rows[:2]] == ["0", "0"] and [r[-1] for r in rows[:2]] == ["-", "-"], rows


def test_an_unknown_state_names_the_close_ones(tmp_path, capsys):
    path = tmp_path / "cart_pole.yaml"
    path.write_text(CART_POLE)
    assert main(["linearize", str(path), "--state", "cp.theta=0.1"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "did you mean `cp.th`?" in err[0], err
    assert main(["linearize", str(path), "--state", "pole.angle=0.1"]) == 2
    err = capsys.readouterr().err.strip()
    assert "the states are `cp.s`, `cp.th`, `cp.p_vs`, `cp.p_w`" in err, err


RESONANCE = """\
format_version: 1
name: resonance
parameters:
  m: {value: 2.0, unit: kg}
  k: {value: 50.0, unit: N/m}
  c: {value: 1.2, unit: N*s/m}
  F0: {value: 1.0, unit: N}
  w: {value: 5.0, unit: rad/s}
components:
  mass: {type: mass, m: m}
  spring: {type: spring, k: k}
  damper: {type: damper, d: c}
  force: {type: effort_source, value: F0*sin(w*t)}
  node: {type: junction, kind: common_flow, domain: mechanical.translational, ports: [m, s, d, f]}
connections:
  - [node.m, mass.port]
  - [node.s, spring.port]
  - [node.d, damper.port]
  - [node.f, force.port]
simulation:
  t_end: 80.0
  rtol: 1.0e-10
  atol: 1.0e-12
  initial: {spring.x: 0.0, mass.p: 0.0}
  outputs: {amp: {value: "sqrt(spring.x**2 + (mass.p/(m*w))**2)", unit: m}}
"""


def test_sweep_traces_the_resonance_curve(tmp_path):
    m, k, c, F = 2.0, 50.0, 1.2, 1.0
    path = tmp_path / "resonance.yaml"
    path.write_text(RESONANCE)
    out = tmp_path / "res.csv"
    assert main(["sweep", str(path), "--param", "w=3,5,7", "--workers", "1", "--quiet", "-o", str(out)]) == 0
    rows = list(csv.DictReader(out.open()))
    assert len(rows) == 3
    for row in rows:
        w = float(row["w"])
        steady = F / math.hypot(k - m * w * w, c * w)
        # in steady state x = X cos(wt − φ), v = −Xw sin(wt − φ): sqrt(x² + (v/w)²) = X exactly; the
        # transient has decayed by exp(−c t/2m) = exp(−24) ≈ 4e-11 by t = 80, IDA's error is ~1e-9
        assert float(row["amp.final"]) == pytest.approx(steady, rel=1e-7), row


TWO_MASS_STOP = """\
format_version: 1
name: two_mass_stop
parameters:
  ma: {value: 1.0, unit: kg}
  mb: {value: 0.5, unit: kg}
  ka: {value: 40.0, unit: N/m}
  kb: {value: 10.0, unit: N/m}
  D: {value: 0.2, unit: m}
  e: {value: 0.6, unit: "1"}
components:
  a: {type: mass, m: ma, position: true}
  b: {type: mass, m: mb, position: true}
  sa: {type: spring, k: ka}
  sb: {type: spring, k: kb}
  hit: {type: contact, gap: D + b.x - a.x, restitution: e}
connections:
  - [a.port, sa.port]
  - [b.port, sb.port]
simulation:
  t_end: 4.0
  n_out: 401
  initial: {a.x: 0.0, sa.x: 0.0, a.p: 2.0, b.x: 0.0, sb.x: 0.0, b.p: 0.0}
"""


def _two_mass_reference(T):
    ma, mb, ka, kb, D, e = 1.0, 0.5, 40.0, 10.0, 0.2, 0.6

    def rhs(t, s):
        xa, xb, pa, pb = s
        return [pa / ma, pb / mb, -ka * xa, -kb * xb]

    def gap(t, s):
        return D + s[1] - s[0]

    gap.terminal, gap.direction = True, -1
    t0, s, pieces, hits = 0.0, np.array([0.0, 0.0, 2.0, 0.0]), [], []
    while True:
        sol = solve_ivp(rhs, (t0, T), s, method="Radau", rtol=1e-12, atol=1e-14, events=gap, dense_output=True)
        pieces.append((t0, sol.t[-1], sol.sol))
        if sol.status != 1:
            break
        t0, s = sol.t_events[0][0], sol.y_events[0][0].copy()
        closing = s[3] / mb - s[2] / ma
        impulse = -(1 + e) * closing / (1 / ma + 1 / mb)  # Newton: closing rate reversed times e
        s[2] -= impulse
        s[3] += impulse
        hits.append(t0)

    def at(t):
        return next(sol(t) for a, b, sol in pieces if a <= t <= b)

    return hits, at


@pytest.mark.parametrize("solver, options, tol", [
    ("ida", {"rtol": 1e-10, "atol": 1e-12}, 1e-8),     # measured 2e-10 at rtol 1e-11: 50x margin at 1e-10
    ("midpoint4", {"step": 2e-3}, 2e-8),              # measured 4.7e-9: order 4 (and 3.8e-10 at h = 1e-3)
])
def test_two_masses_with_a_hard_stop_against_radau_and_newtons_law(tmp_path, solver, options, tol):
    hits, at = _two_mass_reference(4.0)
    assert len(hits) == 4
    path = tmp_path / "stop.yaml"
    path.write_text(TWO_MASS_STOP)
    with warnings.catch_warnings():
        # the C step loop hands a run with events to the Python loop and says so: a note, not a fault
        warnings.simplefilter("ignore", phc.PhcWarning)
        run = phc.simulate(phc.compile_model(str(path)), solver=solver, **options)
    assert run.success
    times = [ev.t for ev in run.events if ev.kind == "impact"]
    assert len(times) == 4 and np.abs(np.array(times) - hits).max() < tol
    for t, xa, xb in zip(run.t, run["a.x"], run["b.x"]):
        if min(abs(t - h) for h in hits) > 1e-6:  # a sample at an impact is on either side of it
            ref = at(t)
            assert abs(xa - ref[0]) < tol and abs(xb - ref[1]) < tol, (t, xa - ref[0], xb - ref[1])
    assert run.energy_balance_error < 1e-8  # the impact losses are booked: the balance closes



BEAM_TIP_DAMPER = """\
format_version: 1
name: beam_tip_damper
parameters:
  EI: {value: 68.27, unit: N*m^2}
  rhoA: {value: 0.50368, unit: kg/m}
  L: {value: 0.3, unit: m}
  c: {value: 2.0, unit: N*s/m}
components:
  beam: {type: euler_bernoulli_beam, length: L, elements: 8, rhoA: rhoA, EI: EI}
  clamp: {type: zero_flow, domain: mechanical.translational}
  clamp_rot: {type: zero_flow, domain: mechanical.rotational}
  tip_damper: {type: damper, d: c}
  free_rot: {type: zero_effort, domain: mechanical.rotational}
connections:
  - [beam.a, clamp.port]
  - [beam.a_rot, clamp_rot.port]
  - [beam.b, tip_damper.port]
  - [beam.b_rot, free_rot.port]
simulation:
  t_end: 0.02
  outputs: {tip_velocity: beam.b.f}
"""


def _damped_cantilever_eigenvalues(EI, rhoA, L, c, betas):
    """Exact complex eigenvalues λ of ρA ẅ + EI w'''' = 0, w(0) = w'(0) = 0, w''(L) = 0,
    EI w'''(L) = c ẇ(L) (the damper's force −c ẇ(L) at the tip): with w = W e^{λt},
    λ = i β² sqrt(EI/ρA) and W = A (cosh βx − cos βx) + B (sinh βx − sin βx), the 2×2
    determinant of the tip conditions in β, from the undamped roots β L by secant steps."""
    from scipy.optimize import newton

    a = math.sqrt(EI / rhoA)

    def det(b):
        lam = 1j * b**2 * a
        ch, sh, co, si = np.cosh(b * L), np.sinh(b * L), np.cos(b * L), np.sin(b * L)
        r2 = (EI * b**3 * (sh - si) - c * lam * (ch - co), EI * b**3 * (ch + co) - c * lam * (sh - si))
        return ((ch + co) * r2[1] - (sh + si) * r2[0]) / np.cosh(b * L) ** 2

    return [1j * newton(det, complex(bl / L, 0.01), tol=1e-14, maxiter=200) ** 2 * a for bl in betas]


def test_cantilever_with_a_tip_damper_converges_to_the_exact_complex_eigenvalues(tmp_path):
    path = tmp_path / "beam.yaml"
    path.write_text(BEAM_TIP_DAMPER)
    exact = _damped_cantilever_eigenvalues(68.27, 0.50368, 0.3, 2.0, (1.8751040687, 4.6940911330))
    # the tip damper damps every mode alike: Re λ → −c φ(L)²/(2 ρA L) = −2c/(ρA L) for a large mode number
    assert all(-27 < lam.real < -26 for lam in exact)
    errors = []
    for n in (4, 8, 16):
        lin = phc.linearize_model(str(path), mesh={"beam": n})
        modes = [md.eigenvalue for md in lin.modes[:2]]
        errors.append([abs(m - e) / abs(e) for m, e in zip(modes, exact)])
    first, second = np.array(errors).T
    assert first[-1] < 1e-6 and second[-1] < 1e-5  # measured 1.3e-7 and 5.1e-6 at 16 elements
    # Hermite elements: O(h⁴) in the frequencies (docs/linearize.md), damped or not
    assert second[0] / second[1] > 12 and second[1] / second[2] > 12  # measured 14.6, 15.6 (16 asymptotically)


SPHERICAL = """\
format_version: 1
name: spherical_pendulum
parameters:
  m: {value: 0.7, unit: kg}
  l: {value: 1.2, unit: m}
  g: {value: 9.81, unit: m/s^2}
  th0: {value: 0.6, unit: rad}
  om0: {value: 2.0, unit: rad/s}
components:
  bob:
    type: rigid
    q: [x, y, z]
    v: [vx, vy, vz]
    M: [[m, 0, 0], [0, m, 0], [0, 0, m]]
    V: m*g*z
    constraints:
      - x**2 + y**2 + z**2 - l**2
simulation:
  t_end: 6.0
  n_out: 601
  rtol: 1.0e-10
  atol: 1.0e-10
  initial:
    bob.x: l*sin(th0)
    bob.y: 0.0
    bob.z: -l*cos(th0)
    bob.p_vx: 0.0
    bob.p_vy: m*l*sin(th0)*om0
    bob.p_vz: 0.0
  outputs:
    Lz: {value: "bob.x*bob.p_vy - bob.y*bob.p_vx", unit: kg*m^2/s}
"""


def test_spherical_pendulum_against_its_spherical_coordinates_and_its_conserved_Lz(tmp_path):
    m, l, g, th0, om0 = 0.7, 1.2, 9.81, 0.6, 2.0
    Lz = m * l * l * math.sin(th0) ** 2 * om0  # angular momentum about the vertical, conserved

    def rhs(t, s):  # polar angle θ from the downward vertical, azimuth φ with φ' from Lz
        th, thd, ph = s
        phd = Lz / (m * l * l * math.sin(th) ** 2)
        return [thd, math.sin(th) * math.cos(th) * phd**2 - g / l * math.sin(th), phd]

    ref = solve_ivp(rhs, (0, 6), [th0, 0.0, 0.0], method="Radau", rtol=1e-12, atol=1e-13, dense_output=True).sol
    path = tmp_path / "spherical.yaml"
    path.write_text(SPHERICAL)
    compiled = phc.compile_model(str(path))
    for solver, options, tol in (("ida", {}, 1e-8),                        # measured 1.0e-10 at rtol 1e-10
                                 ("midpoint4", {"step": 2e-3}, 1e-8)):     # measured 9.7e-10 (6.1e-11 at h/2)
        run = phc.simulate(compiled, solver=solver, **options)
        th, _, ph = ref(run.t)
        exact = (l * np.sin(th) * np.cos(ph), l * np.sin(th) * np.sin(ph), -l * np.cos(th))
        for name, value in zip("xyz", exact):
            assert np.abs(run[f"bob.{name}"] - value).max() < tol, (solver, name)
        assert np.abs(run["Lz"] - Lz).max() < 1e-8, solver
    # the implicit midpoint rule keeps the quadratic invariant Lz to round-off at any step
    run = phc.simulate(compiled, solver="midpoint", step=2e-3)
    assert np.abs(run["Lz"] - Lz).max() < 1e-11  # measured 1.9e-13 over 3000 steps
