"""Impacts (docs/events.md, "Impacts"): a `contact` with Newton's restitution law against
closed forms written here — the bouncing ball, a mass on a spring hitting a stop, two
masses colliding — with every solver that handles events.

Tolerances: between impacts the motions here are exact for the solvers (a constant force:
a quadratic in t, which the midpoint rules and IDA reproduce to round-off) or measured
against the method's error (the spring); an impact time is located to 1e-12·max(1, t)
(regula falsi on the fixed-step solvers, SUNDIALS' root finding for IDA), so the energy
after an impact, a function of the state at the event, is exact to that location error
times the speeds involved — 1e-9 relative leaves a factor of 100 to round-off growth over
tens of impacts."""

from __future__ import annotations

import math

import numpy as np
import pytest

import phc
from phc.errors import ModelError

SOLVERS = (("ida", {}), ("midpoint", {"step": 1e-3}), ("discrete_gradient", {"step": 1e-3}),
           ("midpoint4", {"step": 2e-3}))

BALL = """\
format_version: 1
name: ball
parameters:
  m: 0.1
  g: 9.81
  h0: 1.0
  e: 0.8
components:
  ball: {type: mass, m: m, position: true}
  weight: {type: effort_source, value: -m*g}
  floor: {type: contact, gap: ball.x, restitution: e}
connections:
  - [weight.port, ball.port]
simulation:
  t_end: 3.0
  n_out: 301
  rtol: 1.0e-11
  atol: 1.0e-12
  initial: {ball.x: h0, ball.p: 0.0}
"""

SPRING_STOP = """\
format_version: 1
name: spring_stop
parameters:
  m: 2.0
  k: 8.0
  d: 0.6
  e: 0.5
components:
  body: {type: mass, m: m, position: true}
  spring: {type: spring, k: k}
  node: {type: junction, kind: common_flow, domain: mechanical.translational, ports: [a, b]}
  stop: {type: contact, gap: d - body.x, restitution: e}
connections:
  - [node.a, body.port]
  - [node.b, spring.port]
simulation:
  t_end: 6.0
  n_out: 601
  rtol: 1.0e-11
  atol: 1.0e-12
  initial: {body.x: 0.0, spring.x: 0.0, body.p: 4.0}
"""

TWO_MASSES = """\
format_version: 1
name: two_masses
parameters:
  ma: 1.0
  mb: 3.0
  L: 0.5
  e: 0.7
components:
  a: {type: mass, m: ma, position: true}
  b: {type: mass, m: mb, position: true}
  hit: {type: contact, gap: b.x - a.x - L, restitution: e}
  free_a: {type: zero_effort}
  free_b: {type: zero_effort}
connections:
  - [a.port, free_a.port]
  - [b.port, free_b.port]
simulation:
  t_end: 1.0
  n_out: 101
  initial: {a.x: 0.0, a.p: 2.0, b.x: 1.0, b.p: -0.3}
"""


def _compile(tmp_path, text, name="model.yaml"):
    path = tmp_path / name
    path.write_text(text)
    return phc.compile_model(path)


def _impacts(result):
    return [ev.t for ev in result.events if ev.kind == "impact"]


@pytest.mark.parametrize("solver,kw", SOLVERS, ids=[s for s, _ in SOLVERS])
def test_bouncing_ball_against_closed_form(tmp_path, solver, kw):
    m, g, h0, e = 0.1, 9.81, 1.0, 0.8
    compiled = _compile(tmp_path, BALL)
    r = phc.simulate(compiled, solver=solver, **kw)
    assert r.success, r.message
    # dropped from rest: lands at t1 with v0 = sqrt(2 g h0); rebound k leaves at e^k v0, flies 2 e^k v0/g
    v0 = math.sqrt(2 * g * h0)
    t1 = v0 / g
    expected = [t1 + sum(2 * e**j * v0 / g for j in range(1, k)) for k in range(1, 30)]
    expected = [t for t in expected if t < 3.0]
    times = _impacts(r)
    assert len(times) == len(expected) == 6
    assert np.allclose(times, expected, rtol=0, atol=1e-9)
    # apex heights e^(2k) h0, midway between impacts k and k+1
    x = r.y[:, r.variables.index("ball.x")]
    p = r.y[:, r.variables.index("ball.p")]
    for k in range(1, 4):
        apex = 0.5 * (expected[k - 1] + expected[k])
        check = phc.simulate(compiled, solver=solver, t_eval=[0.0, apex], **kw)
        assert check.y[-1, check.variables.index("ball.x")] == pytest.approx(e**(2 * k) * h0, rel=1e-9)
    # mechanical energy m g x + p²/2m after impact k is e^(2k) m g h0; the energy the contact
    # took is in the dissipated energy, so the balance closes
    total = m * g * x + p**2 / (2 * m)
    for k, tk in enumerate(expected, start=1):
        after = (r.t > tk) & (r.t < (expected[k] if k < len(expected) else 3.0))
        assert np.allclose(total[after], e**(2 * k) * m * g * h0, rtol=1e-9)
    assert r.energy_balance_relative < 1e-12
    lost = r.energy_supplied[-1] + m * g * (h0 - x[-1])  # E(t) = dissipated − work supplied (gravity's)
    assert lost == pytest.approx((1 - e**(2 * len(expected))) * m * g * h0, rel=1e-9)


def _zeno_time(g, h0, e):
    """t∞ of a ball dropped from rest at h0: it lands at t1 = sqrt(2 h0/g) with v0 = g t1, and
    rebound k flies 2 e^k v0/g, so t∞ = t1 + Σ_{k≥1} 2 e^k t1 = t1 (1 + e)/(1 − e)."""
    t1 = math.sqrt(2 * h0 / g)
    return t1, t1 * (1 + e) / (1 - e)


def _after_rest(r, m, g, h0, t_close, lost_tol):
    """At rest on the floor after `t_close`: gap 0 (to the impacts' location error), p = 0,
    contact force m g; the energy the contact took is m g h0 (all of it), balance closed."""
    x = r.y[:, r.variables.index("ball.x")]
    p = r.y[:, r.variables.index("ball.p")]
    force = r.y[:, r.variables.index("floor.force")]
    after = r.t > t_close
    assert after.sum() > 10
    # the gap is held where the last impact was located: each impact is located to 1e-12 of t
    # (regula falsi, IDA's root finding), the gap to that times the speed, over tens of impacts
    assert np.abs(x[after]).max() < 1e-9
    assert np.abs(p[after]).max() < 1e-15 * m * math.sqrt(2 * g * h0) * 1e3
    assert np.allclose(force[after], m * g, rtol=1e-12)
    assert np.abs(force[~after]).max() < 1e-12 * m * g  # open: no force (round-off of the solves)
    assert r.energy_balance_relative < 1e-12
    lost = r.energy_supplied[-1] + m * g * (h0 - x[-1])  # dissipated = supplied by gravity − stored
    assert lost == pytest.approx(m * g * h0, rel=lost_tol)


@pytest.mark.parametrize("solver,kw", SOLVERS, ids=[s for s, _ in SOLVERS])
def test_ball_comes_to_rest_at_the_zeno_time(tmp_path, solver, kw):
    """Persistent contact: the run goes on past the Zeno point. The contact closes where the
    rebound speed falls below its rest speed, 1e-6 of the first impact speed v0 (62 impacts for
    e = 0.8: 0.8^62 < 1e-6 < 0.8^61), after a plastic last impact; the bounces it leaves out
    would have taken 2 e^62 v0/(g (1 − e)) more, so it closes that much before t∞. Then the
    ball lies on the floor with the contact force m g, and all of m g h0 was dissipated."""
    m, g, h0, e = 0.1, 9.81, 1.0, 0.8
    compiled = _compile(tmp_path, BALL)
    r = phc.simulate(compiled, solver=solver, t_end=6.0, **kw)
    assert r.success, r.message
    times = _impacts(r)
    assert len(times) == 62
    t1, t_inf = _zeno_time(g, h0, e)
    v0 = g * t1
    closes = [ev.t for ev in r.events if ev.kind == "close"]
    assert closes == [times[-1]] and not [ev for ev in r.events if ev.kind == "open"]
    # the impact times as in test_bouncing_ball_against_closed_form; 1e-8 after 62 of them
    assert times[-1] == pytest.approx(t1 * (1 + 2 * e * (1 - e**61) / (1 - e)), abs=1e-8)
    assert t_inf - closes[0] == pytest.approx(2 * e**62 * v0 / (g * (1 - e)), abs=1e-8)
    assert 0 < t_inf - closes[0] <= 2 * 1e-6 * v0 / (g * (1 - e))  # the rest speed's bound
    _after_rest(r, m, g, h0, closes[0], 1e-9)


@pytest.mark.parametrize("solver,kw", SOLVERS[:2], ids=[s for s, _ in SOLVERS[:2]])
def test_accumulating_impacts_close_the_contact(tmp_path, solver, kw):
    """With `rest_speed: 0` the contact closes where 50 impacts fall within 1e-6 of the run
    (impacts.ACCUMULATE_COUNT, ACCUMULATE_SPAN): the 110th for e = 0.8 over 6 s, where the
    bounces left out would have taken 2 e^110 v0/(g (1 − e)) = 1e-10 s: it closes at t∞."""
    from phc.simulation.impacts import ACCUMULATE_COUNT, ACCUMULATE_SPAN

    m, g, h0, e = 0.1, 9.81, 1.0, 0.8
    compiled = _compile(tmp_path, BALL.replace("restitution: e}", "restitution: e, rest_speed: 0}"))
    r = phc.simulate(compiled, solver=solver, t_end=6.0, **kw)
    assert r.success, r.message
    t1, t_inf = _zeno_time(g, h0, e)
    times = np.array(_impacts(r))
    closes = [ev.t for ev in r.events if ev.kind == "close"]
    assert closes == [times[-1]]
    assert times[-1] - times[-ACCUMULATE_COUNT] <= ACCUMULATE_SPAN * 6.0 < times[-2] - times[-ACCUMULATE_COUNT - 1]
    # each impact time is located to 1e-10 or better (IDA's root finding, regula falsi); the
    # error of t∞ is their accumulated error over the 110 impacts
    assert closes[0] == pytest.approx(t_inf, abs=2e-8)
    _after_rest(r, m, g, h0, closes[0], 1e-9)


LIFT = """\
format_version: 1
name: lift
parameters:
  m: 0.1
  g: 9.81
  c: 2.0
  e: 0.5
components:
  ball: {type: mass, m: m, position: true}
  load: {type: effort_source, value: c*t - m*g}
  floor: {type: contact, gap: ball.x, restitution: e}
connections:
  - [load.port, ball.port]
simulation:
  t_end: 1.0
  n_out: 101
  rtol: 1.0e-10
  atol: 1.0e-12
  initial: {ball.x: 0.0, ball.p: 0.0}
"""


@pytest.mark.parametrize("solver,kw", SOLVERS, ids=[s for s, _ in SOLVERS])
def test_resting_ball_lifts_off_when_the_force_exceeds_its_weight(tmp_path, solver, kw):
    """A ball lying on the floor (gap 0, at rest: the contact closes at the start) under the
    force c t − m g: the contact force is λ = m g − c t until it reaches 0 at t* = m g/c, where
    the contact opens; then m ẍ = c (t − t*), so x = c (t − t*)³/(6 m). The closed contact
    does no work: the energy balance closes to round-off."""
    m, g, c = 0.1, 9.81, 2.0
    t_lift = m * g / c
    r = phc.simulate(_compile(tmp_path, LIFT), solver=solver, **kw)
    assert r.success, r.message
    assert [(ev.kind, ev.condition) for ev in r.events] == [("close", "floor"), ("open", "floor")]
    assert r.events[0].t == 0.0
    # λ is linear in t: IDA's root finding and regula falsi locate its zero to round-off, at
    # most EVENT_TOL = 1e-12 of max(1, t) (phc.simulation.midpoint)
    assert r.events[1].t == pytest.approx(t_lift, abs=1e-12)
    x = r.y[:, r.variables.index("ball.x")]
    force = r.y[:, r.variables.index("floor.force")]
    before, after = r.t < t_lift, r.t > t_lift
    assert np.allclose(force[before], m * g - c * r.t[before], rtol=0, atol=1e-13 * m * g)  # round-off
    assert np.abs(force[after]).max() < 1e-12 * m * g  # open: no force (round-off of the solves)
    assert np.abs(x[before]).max() < 1e-15  # held at rest: ẋ = p/m = 0
    exact = c * (r.t[after] - t_lift)**3 / (6 * m)
    if solver in ("midpoint", "discrete_gradient"):
        # ẋ = p/m with p = c (t − t*)²/(2m) exact (ṗ is linear in t), and x by the trapezoidal
        # rule of ẋ at the step ends: its error, h_i³ ẋ''/12 per step with ẋ'' = c/m, adds up
        # to at most h² (c/m)(t − t*)/12
        h = kw["step"]
        bound = h**2 * (c / m) * (r.t[after] - t_lift) / 12
        assert np.all(np.abs(x[after] - exact) <= bound * (1 + 1e-6) + 1e-14)
        assert np.abs(x[after] - exact)[-1] > 0.5 * bound[-1]  # that is the error there is
    else:
        # midpoint4 (fourth order) integrates the cubic exactly; IDA at rtol 1e-10
        assert np.allclose(x[after], exact, rtol=0, atol=1e-12 if solver == "midpoint4" else 1e-9)
    assert r.energy_balance_relative < 1e-12


def test_a_touching_ball_pulled_away_does_not_close(tmp_path):
    """Touching at the start, but with the net force upward (c t + m g): the contact stays
    open and the ball leaves at once, x = (c t³/6 + m g t²/2)/m."""
    m, g, c = 0.1, 9.81, 2.0
    r = phc.simulate(_compile(tmp_path, LIFT.replace("c*t - m*g", "c*t + m*g")), solver="midpoint4", step=2e-3)
    assert r.success, r.message
    assert r.events == []
    x = r.y[:, r.variables.index("ball.x")]
    assert np.allclose(x, (c * r.t**3 / 6 + m * g * r.t**2 / 2) / m, rtol=0, atol=1e-12)


@pytest.mark.parametrize("solver,kw", SOLVERS, ids=[s for s, _ in SOLVERS])
def test_plastic_and_elastic(tmp_path, solver, kw):
    m, g, h0 = 0.1, 9.81, 1.0
    compiled = _compile(tmp_path, BALL)
    plastic = phc.simulate(compiled, solver=solver, params={"e": 0.0}, **kw)
    assert plastic.success, plastic.message  # e = 0: it comes to rest at its first impact
    t1 = math.sqrt(2 * h0 / g)
    assert _impacts(plastic) == [pytest.approx(t1, abs=1e-9)]
    assert [ev.kind for ev in plastic.events] == ["impact", "close"]
    _after_rest(plastic, m, g, h0, t1, 1e-9)
    elastic = phc.simulate(compiled, solver=solver, params={"e": 1.0}, **kw)
    assert elastic.success, elastic.message
    x = elastic.y[:, elastic.variables.index("ball.x")]
    p = elastic.y[:, elastic.variables.index("ball.p")]
    assert np.allclose(m * g * x + p**2 / (2 * m), m * g * h0, rtol=1e-9)
    t1 = math.sqrt(2 * h0 / g)
    assert np.allclose(_impacts(elastic), [t1, 3 * t1, 5 * t1], rtol=0, atol=1e-9)  # within 3 s


def _spring_stop_impacts(m, k, d, e, v0, n):
    """Impact times and closing speeds of x'' = -ω² x from x = 0, ẋ = v0, against a stop at d."""
    w = math.sqrt(k / m)
    A = v0 / w
    t = math.asin(d / A) / w
    v = A * w * math.cos(w * t)
    out = [(t, v)]
    for _ in range(n - 1):
        # leaves d with speed -e v: x = d cos ws - (e v/w) sin ws returns to d after (2π - 2φ)/w
        A2 = math.hypot(d, e * v / w)
        phi = math.acos(d / A2)
        t += (2 * math.pi - 2 * phi) / w
        v = e * v  # the spring is conservative between impacts
        out.append((t, v))
    return out


@pytest.mark.parametrize("solver,kw", SOLVERS, ids=[s for s, _ in SOLVERS])
def test_mass_on_a_spring_hits_a_stop(tmp_path, solver, kw):
    m, k, d, e, p0 = 2.0, 8.0, 0.6, 0.5, 4.0
    compiled = _compile(tmp_path, SPRING_STOP)
    r = phc.simulate(compiled, solver=solver, **kw)
    assert r.success, r.message
    expected = [tv for tv in _spring_stop_impacts(m, k, d, e, p0 / m, 6) if tv[0] < 6.0]
    times = _impacts(r)
    assert len(times) == len(expected) >= 3
    # method error of the spring's motion between impacts: IDA at rtol 1e-11, the midpoint rules
    # at h = 1e-3 (order 2, error ~ (ωh)²/12 · t ~ 1e-6), midpoint4 at h = 2e-3 (order 4)
    tol = {"ida": 1e-8, "midpoint4": 1e-8}.get(solver, 1e-5)
    assert np.allclose(times, [t for t, _ in expected], rtol=0, atol=tol)
    # the energy H (kinetic + spring) after impact j is H0 - Σ (1 - e²) ½ m v_i²
    H0 = p0**2 / (2 * m)
    lost = np.cumsum([(1 - e**2) * 0.5 * m * v**2 for _, v in expected])
    for j, (tj, _) in enumerate(expected):
        nxt = expected[j + 1][0] if j + 1 < len(expected) else 6.0
        inside = (r.t > tj + 1e-6) & (r.t < nxt - 1e-6)
        assert np.allclose(r.H[inside], H0 - lost[j], rtol=0, atol=tol * H0 * 10)
    assert r.energy_balance_relative < (1e-8 if solver == "ida" else 1e-12)


def test_two_masses_collide(tmp_path):
    """Newton's law between two bodies: momentum conserved, relative velocity reversed times e."""
    ma, mb, L, e = 1.0, 3.0, 0.5, 0.7
    compiled = _compile(tmp_path, TWO_MASSES)
    r = phc.simulate(compiled, solver="midpoint", step=1e-3)
    assert r.success, r.message
    va, vb = 2.0 / ma, -0.3 / mb
    t_hit = (1.0 - L) / (va - vb)
    assert _impacts(r) == [pytest.approx(t_hit, abs=1e-12)]
    pa = r.y[-1, r.variables.index("a.p")]
    pb = r.y[-1, r.variables.index("b.p")]
    assert pa + pb == pytest.approx(2.0 - 0.3, abs=1e-13)
    assert pb / mb - pa / ma == pytest.approx(-e * (vb - va), abs=1e-13)
    lost = (1 - e**2) * 0.5 * (ma * mb / (ma + mb)) * (va - vb)**2
    assert r.H[-1] == pytest.approx(r.H[0] - lost, abs=1e-13)
    assert r.energy_balance_error < 1e-13


@pytest.mark.parametrize("gap,restitution,field,text", [
    ("ball.p", "e", "gap", "not the position of a mass"),
    ("ball.x - t", "e", "gap", "depends on `t`"),
    ("h0", "e", "gap", "uses no position"),
    ("ball.x", "1.5", "restitution", "must lie in [0, 1]"),
    ("ball.x", "t/10", "restitution", "parameters only"),
    ("ball.x", "ball.x", "restitution", "unknown name `ball.x`"),
])
def test_contact_mistakes_are_located(tmp_path, gap, restitution, field, text):
    model = BALL.replace("gap: ball.x, restitution: e", f"gap: {gap}, restitution: {restitution}")
    with pytest.raises(ModelError) as err:
        _compile(tmp_path, model)
    message = str(err.value)
    assert text in message and f"components.floor.{field}" in message
    assert "model.yaml:11:" in message


PUCK = """\
format_version: 1
name: puck
parameters:
  m: 0.5
  e: 0.6
  g: 9.81
components:
  puck:
    type: rigid
    q: [x, y]
    v: [vx, vy]
    M: [[m, 0], [0, m]]
    V: m*g*y
  wall: {type: contact, gap: 1 - puck.x, restitution: e}
simulation:
  t_end: 1.0
  n_out: 101
  initial: {puck.x: 0.0, puck.y: 0.0, puck.p_vx: 1.0, puck.p_vy: 2.0}
"""


@pytest.mark.parametrize("solver,kw", SOLVERS[:2], ids=[s for s, _ in SOLVERS[:2]])
def test_rigid_body_hits_a_wall(tmp_path, solver, kw):
    """A rigid point mass thrown against a wall x = 1 under gravity: the normal velocity reverses
    times e, the tangential one is untouched, and the energy drops by (1 − e²)·½ m v_n²."""
    m, e, g = 0.5, 0.6, 9.81
    compiled = _compile(tmp_path, PUCK)
    r = phc.simulate(compiled, solver=solver, **kw)
    assert r.success, r.message
    vx, vy = 1.0 / m, 2.0 / m
    t_hit = 1.0 / vx
    assert _impacts(r) == [pytest.approx(t_hit, abs=1e-9)]
    x = r.y[:, r.variables.index("puck.x")]
    y = r.y[:, r.variables.index("puck.y")]
    after = r.t > t_hit
    assert np.allclose(x[after], 1 - e * vx * (r.t[after] - t_hit), rtol=0, atol=1e-9)
    assert np.allclose(y, vy * r.t - 0.5 * g * r.t**2, rtol=0, atol=1e-9)
    assert r.H[-1] - r.H[0] + r.energy_supplied[-1] == pytest.approx(0, abs=1e-12)
    assert r.energy_supplied[-1] == pytest.approx((1 - e**2) * 0.5 * m * vx**2, rel=1e-9)


@pytest.mark.parametrize("solver,kw", SOLVERS, ids=[s for s, _ in SOLVERS])
def test_rigid_body_bounces_then_slides_on_the_floor(tmp_path, solver, kw):
    """A rigid point mass launched from the floor (gap y) with (vx, vy): its bounces on the
    floor (e = 0.5) accumulate at t∞ = (2 vy/g)/(1 − e); the contact closes at the 20th impact
    (0.5^20 < 1e-6 < 0.5^19), 2 e^20 vy/(g (1 − e)) before t∞, and the body then slides at vx
    with the contact force m g. The contact acts along y only: x = vx t throughout."""
    m, e, g = 0.5, 0.5, 9.81
    model = PUCK.replace("  wall: {type: contact, gap: 1 - puck.x, restitution: e}",
                         "  floor: {type: contact, gap: puck.y, restitution: e}")
    model = model.replace("puck.p_vy: 2.0}", "puck.p_vy: 1.0}").replace("  e: 0.6", "  e: 0.5")
    r = phc.simulate(_compile(tmp_path, model), solver=solver, **kw)
    assert r.success, r.message
    vx, vy = 1.0 / m, 1.0 / m
    t_inf = 2 * vy / g / (1 - e)
    assert len(_impacts(r)) == 20
    closes = [ev.t for ev in r.events if ev.kind == "close"]
    assert len(closes) == 1
    # each impact is located to 1e-12 of t in time, so to ~1e-12 times the speed in the gap,
    # which the next, slower flight turns into a larger time error (2.3e-10 measured on every
    # solver after 20 impacts, as for the ball in test_ball_comes_to_rest_at_the_zeno_time)
    assert t_inf - closes[0] == pytest.approx(2 * e**20 * vy / (g * (1 - e)), abs=1e-9)
    x = r.y[:, r.variables.index("puck.x")]
    y = r.y[:, r.variables.index("puck.y")]
    force = r.y[:, r.variables.index("floor.force")]
    after = r.t > closes[0]
    assert np.allclose(x, vx * r.t, rtol=0, atol=1e-13)
    assert np.abs(y[after]).max() < 1e-10  # held where the last impact was located
    assert np.allclose(force[after], m * g, rtol=1e-12)
    assert r.energy_balance_relative < 1e-13


def test_rigid_body_with_constraints_is_refused(tmp_path):
    model = PUCK.replace("    V: m*g*y\n", "    V: m*g*y\n    constraints: [x**2 + y**2 - 1]\n")
    with pytest.raises(ModelError) as err:
        _compile(tmp_path, model)
    assert "constraint impulses" in str(err.value) and "components.wall.gap" in str(err.value)


@pytest.mark.parametrize("solver,kw", SOLVERS[:2], ids=[s for s, _ in SOLVERS[:2]])
def test_plastic_stop_on_a_spring_lets_go(tmp_path, solver, kw):
    """e = 0 against a stop the spring pulls away from: the body stops dead at x = d (one
    impact, no rest: the gap's acceleration is positive) and oscillates between ±d with
    H = ½ k d² ever after."""
    m, k, d, p0 = 2.0, 8.0, 0.6, 4.0
    compiled = _compile(tmp_path, SPRING_STOP)
    r = phc.simulate(compiled, solver=solver, params={"e": 0.0}, **kw)
    assert r.success, r.message
    w = math.sqrt(k / m)
    t_hit = math.asin(d / (p0 / m / w)) / w
    tol = 1e-8 if solver == "ida" else 1e-6  # the spring's motion: IDA's tolerance, midpoint's O(h²)
    assert _impacts(r) == [pytest.approx(t_hit, abs=tol)]
    after = r.t > t_hit + 1e-6
    assert np.allclose(r.H[after], 0.5 * k * d**2, rtol=tol)
    x = r.y[:, r.variables.index("body.x")]
    assert x.max() <= d + 1e-9 and x.min() == pytest.approx(-d, abs=1e-3)


def test_check_sees_the_bodies_a_contact_couples_as_one_part(tmp_path):
    """`phc check`: a contact has no port, but the two masses it couples are not independent
    parts (no PHC-W201), and a ball with its floor is one part."""
    from phc.checks.certify import certify

    for text in (TWO_MASSES, BALL):
        path = tmp_path / "model.yaml"
        path.write_text(text)
        dae, _ = phc.build_dae(path)
        cert = certify(dae)
        assert len(cert.parts) == 1, cert.parts
        assert not [d for d in cert.diagnostics if d.code == "PHC-W201"]


def test_shipped_bouncing_ball_against_closed_form():
    """models/bouncing_ball.yaml (m = 0.1 kg, h0 = 1 m, e = 0.8, to 2.5 s): its 4 impacts."""
    from pathlib import Path

    path = Path(__file__).resolve().parents[2] / "models" / "bouncing_ball.yaml"
    r = phc.simulate(phc.compile_model(path))
    assert r.success, r.message
    g, h0, e = 9.81, 1.0, 0.8
    t1 = math.sqrt(2 * h0 / g)
    expected = [t1 * (1 + 2 * sum(e**j for j in range(1, k))) for k in range(1, 5)]
    assert np.allclose(_impacts(r), expected, rtol=0, atol=1e-9)
    assert r.outputs["energy"][-1] == pytest.approx(0.5 * 0.1 * r.outputs["v"][-1]**2, rel=1e-12)


def test_a_contact_that_starts_penetrated_stops_the_run_with_a_message(tmp_path):
    compiled = _compile(tmp_path, BALL)
    r = phc.simulate(compiled, initial={"ball.x": -0.01})
    assert not r.success
    assert "contact `floor` starts penetrated" in r.message and "-0.01" in r.message
