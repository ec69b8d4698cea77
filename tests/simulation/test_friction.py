"""Coulomb friction at a closed contact (docs/events.md, "Friction at a closed contact"):
a `contact` with `friction` μ and a `tangent`, against closed forms written here — a block
on an inclined plane (sticks for tan θ ≤ μ, else slides with a = g(sin θ − μ cos θ)), a
block pushed by c·t (slips at t* = μ m g/c), a block launched on a floor (stops at
v₀/(μ g) after v₀²/(2 μ g), then stays), a block on a spring (slides, reverses, sticks) —
with every solver.

Tolerances: between events the motions here are polynomials in t of degree ≤ 2 (constant
forces), which IDA and the midpoint rules reproduce to round-off, or of degree 3 (the
ramp: the midpoint rules' trapezoidal error, bounded in the test), or the spring's
harmonic motion (the method's error at the step used); events are located to
EVENT_TOL = 1e-12·max(1, t) in time (regula falsi, SUNDIALS' root finding), so positions
and energies at and after an event are exact to that times the speeds involved."""

from __future__ import annotations

import math

import numpy as np
import pytest

import phc
from phc.errors import ModelError

SOLVERS = (("ida", {}), ("midpoint", {"step": 1e-3}), ("discrete_gradient", {"step": 1e-3}),
           ("midpoint4", {"step": 2e-3}))

# a block (point mass) as a rigid body with the weight in its potential, on the plane through
# the origin at the angle theta: gap = the distance from the plane, tangent = the distance along it
INCLINE = """\
format_version: 1
name: incline
parameters:
  m: 2.0
  g: 9.81
  mu: 0.3
  theta: 0.4
  s0: 2.0
components:
  block:
    type: rigid
    q: [x, y]
    v: [vx, vy]
    M: [[m, 0], [0, m]]
    V: m*g*y
  plane:
    type: contact
    gap: cos(theta)*block.y - sin(theta)*block.x
    tangent: cos(theta)*block.x + sin(theta)*block.y
    restitution: 0.0
    friction: mu
simulation:
  t_end: 1.5
  n_out: 151
  rtol: 1.0e-10
  atol: 1.0e-12
  initial: {block.x: s0*cos(theta), block.y: s0*sin(theta), block.p_vx: 0.0, block.p_vy: 0.0}
"""

FLOOR = """\
format_version: 1
name: floor
parameters:
  m: 2.0
  g: 9.81
  mu: 0.3
  h: 1.0
components:
  block:
    type: rigid
    q: [x, y]
    v: [vx, vy]
    M: [[m, 0], [0, m]]
    V: m*g*y
  floor: {type: contact, gap: block.y - h, tangent: block.x, restitution: 0.5, friction: mu}
simulation:
  t_end: 2.0
  n_out: 201
  rtol: 1.0e-10
  atol: 1.0e-12
  initial: {block.x: 0.0, block.y: h, block.p_vx: 6.0, block.p_vy: 0.0}
"""

# the block as two masses (horizontal, vertical) driven by effort sources
RAMP = """\
format_version: 1
name: ramp
parameters:
  m: 2.0
  g: 9.81
  mu: 0.3
  c: 4.0
components:
  bx: {type: mass, m: m, position: true}
  by: {type: mass, m: m, position: true}
  weight: {type: effort_source, value: -m*g}
  push: {type: effort_source, value: c*t}
  floor: {type: contact, gap: by.x, restitution: 0.0, friction: mu, tangent: bx.x}
connections:
  - [weight.port, by.port]
  - [push.port, bx.port]
simulation:
  t_end: 2.5
  n_out: 251
  rtol: 1.0e-10
  atol: 1.0e-12
  initial: {bx.x: 0.0, bx.p: 0.0, by.x: 0.0, by.p: 0.0}
"""

SPRING = """\
format_version: 1
name: spring_block
parameters:
  m: 1.0
  g: 9.81
  k: 4.0
  Fc: 1.0
components:
  bx: {type: mass, m: m, position: true}
  by: {type: mass, m: m, position: true}
  spring: {type: spring, k: k}
  node: {type: junction, kind: common_flow, domain: mechanical.translational, ports: [a, b]}
  weight: {type: effort_source, value: -m*g}
  floor: {type: contact, gap: by.x, restitution: 0.0, friction: Fc/(m*g), tangent: bx.x}
connections:
  - [node.a, bx.port]
  - [node.b, spring.port]
  - [weight.port, by.port]
simulation:
  t_end: 4.0
  n_out: 401
  rtol: 1.0e-10
  atol: 1.0e-12
  initial: {bx.x: 1.1, spring.x: 1.1, bx.p: 0.0, by.x: 0.0, by.p: 0.0}
"""


def _compile(tmp_path, text):
    path = tmp_path / "model.yaml"
    path.write_text(text)
    return phc.compile_model(path)


def _col(r, name):
    return r.y[:, r.variables.index(name)]


def _kinds(r):
    return [(ev.kind, ev.condition, ev.direction) for ev in r.events]


@pytest.mark.parametrize("solver,kw", SOLVERS, ids=[s for s, _ in SOLVERS])
def test_block_on_a_slope_sticks_when_tan_theta_is_below_mu(tmp_path, solver, kw):
    """tan 0.4 = 0.42 < μ = 0.5: put down at rest the block sticks at once and forever, held
    by λ_t = m g sin θ (up the slope) with the normal force m g cos θ."""
    m, g, theta, s0 = 2.0, 9.81, 0.4, 2.0
    r = phc.simulate(_compile(tmp_path, INCLINE), solver=solver, params={"mu": 0.5}, **kw)
    assert r.success, r.message
    assert _kinds(r) == [("close", "plane", 0), ("stick", "plane", 0)]
    assert np.allclose(_col(r, "block.x"), s0 * math.cos(theta), rtol=0, atol=1e-14)
    assert np.allclose(_col(r, "block.y"), s0 * math.sin(theta), rtol=0, atol=1e-14)
    assert np.abs(_col(r, "plane.slip_rate")).max() < 1e-28  # held at 0 (round-off of the solves)
    assert np.allclose(_col(r, "plane.friction_force"), m * g * math.sin(theta), rtol=1e-12)
    assert np.allclose(_col(r, "plane.force"), m * g * math.cos(theta), rtol=1e-12)
    assert r.energy_balance_relative < 1e-12


@pytest.mark.parametrize("solver,kw", SOLVERS, ids=[s for s, _ in SOLVERS])
def test_block_on_a_slope_slides_when_tan_theta_exceeds_mu(tmp_path, solver, kw):
    """tan θ > μ = 0.3: the stick it tries at the start needs more than μ m g cos θ, so it
    slides down, s = s0 − ½ g (sin θ − μ cos θ) t², with λ_t = μ m g cos θ up the slope; the
    energy dissipated is μ m g cos θ times the distance slid."""
    m, g, mu, theta, s0 = 2.0, 9.81, 0.3, 0.4, 2.0
    r = phc.simulate(_compile(tmp_path, INCLINE), solver=solver, **kw)
    assert r.success, r.message
    assert _kinds(r) == [("close", "plane", 0), ("slip", "plane", -1)]
    a = g * (math.sin(theta) - mu * math.cos(theta))
    s = s0 - 0.5 * a * r.t**2
    x, y = _col(r, "block.x"), _col(r, "block.y")
    # constant forces: the motion is quadratic in t, exact for every solver here (IDA to its rtol)
    tol = 1e-9 if solver == "ida" else 1e-12
    assert np.allclose(math.cos(theta) * x + math.sin(theta) * y, s, rtol=0, atol=tol)
    assert np.allclose(math.cos(theta) * y - math.sin(theta) * x, 0.0, rtol=0, atol=1e-12)
    assert np.allclose(_col(r, "plane.slip_rate"), -a * r.t, rtol=0, atol=tol)
    assert np.allclose(_col(r, "plane.friction_force"), mu * m * g * math.cos(theta), rtol=1e-12)
    dissipated = mu * m * g * math.cos(theta) * (s0 - s)
    assert np.allclose(r.energy_supplied, dissipated, rtol=1e-9, atol=1e-12)  # no ports: E is what friction took
    assert r.energy_balance_relative < 1e-12


@pytest.mark.parametrize("solver,kw", SOLVERS, ids=[s for s, _ in SOLVERS])
def test_block_launched_on_a_floor_stops_and_stays(tmp_path, solver, kw):
    """Launched at v0 = 3 along the floor (resting on it: the contact closes at the start,
    sliding): it decelerates at μ g, stops at t_s = v0/(μ g) after v0²/(2 μ g), where the stick
    it tries needs no force, and stays. All of ½ m v0² is dissipated."""
    m, g, mu, v0 = 2.0, 9.81, 0.3, 3.0
    r = phc.simulate(_compile(tmp_path, FLOOR), solver=solver, **kw)
    assert r.success, r.message
    t_s = v0 / (mu * g)
    assert _kinds(r) == [("close", "floor", 0), ("slip", "floor", 1), ("stick", "floor", 0)]
    # a zero of the linear v(t): located to EVENT_TOL = 1e-12 of max(1, t)
    assert r.events[2].t == pytest.approx(t_s, abs=2e-12)
    x = _col(r, "block.x")
    before = r.t < t_s
    exact = np.where(before, v0 * r.t - 0.5 * mu * g * r.t**2, v0**2 / (2 * mu * g))
    tol = 1e-9 if solver == "ida" else 1e-12
    assert np.allclose(x, exact, rtol=0, atol=tol)
    v = _col(r, "floor.slip_rate")
    assert np.abs(v[~before]).max() < 1e-14  # held at 0 (round-off of the solves)
    force_t = _col(r, "floor.friction_force")
    assert np.allclose(force_t[before], -mu * m * g, rtol=1e-12)
    # stuck: λ_t = 0 (the slip rate the stop's location error leaves, μ g·1e-12, is removed by
    # a tangential impulse at the stick, friction._stop; without it midpoint4's stages took it
    # out over a few steps with λ_t ≈ m v/h = 1e-7 m g); round-off of the solves
    assert np.abs(force_t[~before]).max() < 1e-12 * m * g
    assert np.allclose(_col(r, "floor.force"), m * g, rtol=1e-12)
    assert r.energy_supplied[-1] == pytest.approx(0.5 * m * v0**2, rel=1e-9)
    assert r.energy_balance_relative < 1e-12


@pytest.mark.parametrize("solver,kw", SOLVERS, ids=[s for s, _ in SOLVERS])
def test_block_pushed_by_a_ramp_slips_at_t_star(tmp_path, solver, kw):
    """Pushed by c t on the floor: stuck, with λ_t = −c t, until |λ_t| reaches μ m g at
    t* = μ m g/c, where it slips; then m ẍ = c (t − t*), so x = c (t − t*)³/(6 m)."""
    m, g, mu, c = 2.0, 9.81, 0.3, 4.0
    t_star = mu * m * g / c
    r = phc.simulate(_compile(tmp_path, RAMP), solver=solver, **kw)
    assert r.success, r.message
    assert _kinds(r) == [("close", "floor", 0), ("stick", "floor", 0), ("slip", "floor", 1)]
    # μ m g − λ_t is linear in t: its zero is located to round-off, at most EVENT_TOL of max(1, t)
    assert r.events[2].t == pytest.approx(t_star, abs=2e-12)
    x, force_t = _col(r, "bx.x"), _col(r, "floor.friction_force")
    before, after = r.t < t_star, r.t > t_star
    assert np.abs(x[before]).max() < 1e-15
    assert np.allclose(force_t[before], -c * r.t[before], rtol=0, atol=1e-12 * c)
    assert np.allclose(force_t[after], -mu * m * g, rtol=1e-12)
    exact = c * (r.t[after] - t_star)**3 / (6 * m)
    if solver in ("midpoint", "discrete_gradient"):
        # ẋ = p/m is exact (ṗ linear in t); x by the trapezoidal rule of ẋ at the step ends,
        # whose error adds up to at most h² (c/m)(t − t*)/12 (as in test_impacts' lift-off)
        h = kw["step"]
        bound = h**2 * (c / m) * (r.t[after] - t_star) / 12
        assert np.all(np.abs(x[after] - exact) <= bound * (1 + 1e-6) + 1e-13)
    else:  # midpoint4 integrates the cubic exactly; IDA at rtol 1e-10
        assert np.allclose(x[after], exact, rtol=0, atol=1e-12 if solver == "midpoint4" else 1e-9)
    assert r.energy_balance_relative < 1e-12


@pytest.mark.parametrize("solver,kw", SOLVERS, ids=[s for s, _ in SOLVERS])
def test_block_on_a_spring_slides_reverses_and_sticks(tmp_path, solver, kw):
    """m = 1, k = 4, μ m g = F_c = 1, from x0 = 1.1 at rest (the Karnopp case of docs/events.md,
    here as friction at a contact): x = 1/4 + 0.85 cos 2t until v = 0 at π/2 (x = −0.6, the
    spring's 2.4 > F_c: the stick fails and it reverses), then x = −1/4 + 0.35 cos 2t until
    v = 0 at π (x = 0.1, spring 0.4 < F_c: it sticks for good)."""
    r = phc.simulate(_compile(tmp_path, SPRING), solver=solver, **kw)
    assert r.success, r.message
    assert _kinds(r) == [("close", "floor", 0), ("slip", "floor", -1), ("slip", "floor", 1),
                         ("stick", "floor", 0)]
    # the midpoint rules' phase error over π/2 at h: (ω h)² ω t/24 (order 2), midpoint4 order 4
    tol = {"ida": 1e-8, "midpoint": 2e-6, "discrete_gradient": 2e-6, "midpoint4": 1e-10}[solver]
    assert r.events[2].t == pytest.approx(math.pi / 2, abs=tol)
    assert r.events[3].t == pytest.approx(math.pi, abs=tol)
    x = _col(r, "bx.x")
    exact = np.where(r.t < math.pi / 2, 0.25 + 0.85 * np.cos(2 * r.t),
                     np.where(r.t < math.pi, -0.25 + 0.35 * np.cos(2 * r.t), 0.1))
    assert np.allclose(x, exact, rtol=0, atol=tol)
    # the midpoint rules balance energy to round-off (H quadratic); IDA to its rtol 1e-10 (2e-11 measured)
    assert r.energy_balance_relative < (1e-9 if solver == "ida" else 1e-12)


def test_friction_mistakes_are_located(tmp_path):
    with pytest.raises(ModelError) as err:
        _compile(tmp_path, FLOOR.replace(", tangent: block.x", ""))
    assert "components.floor.friction" in str(err.value) or "floor" in str(err.value)
    assert "friction needs both" in str(err.value)
    with pytest.raises(ModelError) as err:
        _compile(tmp_path, FLOOR.replace("friction: mu}", "friction: -mu}"))
    assert "`friction` of contact `floor` is -0.3" in str(err.value)


def test_check_sees_the_masses_friction_couples_as_one_part(tmp_path):
    """`phc check`: the tangent's mass (bx) is coupled to the gap's (by) through the contact
    (its friction), so the ramp model is one part (no PHC-W201)."""
    from phc.checks.certify import certify

    path = tmp_path / "model.yaml"
    path.write_text(RAMP)
    dae, _ = phc.build_dae(path)
    cert = certify(dae)
    assert len(cert.parts) == 1, cert.parts
    assert not [d for d in cert.diagnostics if d.code == "PHC-W201"]


@pytest.mark.parametrize("solver,kw", SOLVERS, ids=[s for s, _ in SOLVERS])
def test_block_bounces_then_slides_to_rest(tmp_path, solver, kw):
    """Thrown from the floor with (vx, vy) = (3, 0.5): its bounces (e = 0.5) accumulate and
    the contact closes at the 20th impact (0.5^20 < 1e-6 < 0.5^19), 2 e^20 vy/(g (1 − e)) before
    t∞ = 2 vy/(g (1 − e)), sliding. The impacts are frictional (Coulomb, sliding: the tangential
    impulse is μ times the normal one), so bounce j (normal speed e^(j−1) vy) takes μ (1 + e) e^(j−1) vy
    of vx, and the plastic close the rest of the normal momentum: by the balance of the normal
    momentum vx(t_c) = vx − μ (g t_c − vy). Then it decelerates at μ g and sticks at
    t_c + vx(t_c)/(μ g) = vx/(μ g) + vy/g."""
    m, g, mu, e, vx, vy = 2.0, 9.81, 0.3, 0.5, 3.0, 0.5
    r = phc.simulate(_compile(tmp_path, FLOOR.replace("block.p_vy: 0.0", f"block.p_vy: {m * vy}")),
                     solver=solver, **kw)
    assert r.success, r.message
    kinds = [ev.kind for ev in r.events]
    n = kinds.count("impact")
    assert kinds == ["impact"] * n + ["close", "slip", "stick"]
    t_c = r.events[n].t
    t_inf = 2 * vy / (g * (1 - e))
    if solver == "ida":
        # the last bounces fly (e^k vy)²/2g < atol = 1e-12 high from k = 17 on: IDA locates them
        # to its atol (measured: the 19th 1.3e-7 s early, where it closes): within the time the
        # bounces from the 19th on would take
        assert n in (19, 20)
        assert t_inf - 2 * e**18 * vy / (g * (1 - e)) < t_c < t_inf
    else:
        # each impact is located to 1e-12 of t, which the next, slower flight turns into a larger
        # time error (test_impacts' rigid body: 2.3e-10 after 20 impacts)
        assert n == 20
        assert t_c == pytest.approx(t_inf - 2 * e**20 * vy / (g * (1 - e)), abs=1e-9)
    assert r.events[n + 1].direction == 1
    t_s = vx / (mu * g) + vy / g
    assert r.events[n + 2].t == pytest.approx(t_s, abs=1e-9)
    starts = [0.0] + [2 * vy / g * sum(e**i for i in range(j)) for j in range(1, n)] + [t_c]
    speeds = [vx - mu * (1 + e) * vy * sum(e**i for i in range(j)) for j in range(n)]
    v_c = vx - mu * (g * t_c - vy)
    assert v_c == pytest.approx(mu * g * (t_s - t_c), rel=1e-12)
    exact = np.zeros_like(r.t)
    x0 = 0.0
    for a, b, v in zip(starts[:-1], starts[1:], speeds):
        inside = (r.t >= a) & (r.t <= b)
        exact[inside] = x0 + v * (r.t[inside] - a)
        x0 += v * (b - a)
    tau = np.clip(r.t - t_c, 0.0, t_s - t_c)
    exact[r.t > t_c] = (x0 + v_c * tau - 0.5 * mu * g * tau**2)[r.t > t_c]
    assert np.allclose(_col(r, "block.x"), exact, rtol=0, atol=1e-8)
    # all the kinetic energy went: the normal part at the impacts, the tangential by friction
    assert r.energy_supplied[-1] + m * g * (_col(r, "block.y")[-1] - 1.0) == pytest.approx(
        0.5 * m * (vx**2 + vy**2), rel=1e-9)
    assert r.energy_balance_relative < 1e-12


@pytest.mark.parametrize("h, t_end", [(1e-3, 0.5), (7e-4, 2.5)])
def test_midpoint4_rejects_no_step_of_the_stuck_ramp_block(tmp_path, h, t_end):
    """The block pushed by c t (above) while it sticks: at rest its energy scale is ~1e-100
    to 1e-72, and the dissipated power's round-off was rejected by midpoint4's passivity guard
    against a floor of 1e-13 times that alone (to t = 0.5 at h = 1e-3: 8 steps retried in
    pieces; h = 7e-4: the run stopped at t = 0, "the resistive ports supply power"). The floor
    takes the run's energy scale (phc.simulation.scaling.run_energy): no step is retried, and
    the motion is the closed form of test_block_pushed_by_a_ramp_slips_at_t_star (stuck until
    t* = μ m g/c, then x = c (t − t*)³/(6 m), which the composition of order 4 integrates
    exactly: 1e-12 as there)."""
    m, g, mu, c = 2.0, 9.81, 0.3, 4.0
    t_star = mu * m * g / c
    r = phc.simulate(_compile(tmp_path, RAMP), solver="midpoint4", step=h, t_end=t_end)
    assert r.success, r.message
    assert "needed a restart or a split" not in r.message, r.message
    x = _col(r, "bx.x")
    before, after = r.t < t_star, r.t > t_star
    assert np.abs(x[before]).max() < 1e-15
    if t_end < t_star:
        assert _kinds(r) == [("close", "floor", 0), ("stick", "floor", 0)]
        return
    assert _kinds(r) == [("close", "floor", 0), ("stick", "floor", 0), ("slip", "floor", 1)]
    assert r.events[2].t == pytest.approx(t_star, abs=2e-12)
    assert np.allclose(x[after], c * (r.t[after] - t_star)**3 / (6 * m), rtol=0, atol=1e-12)
