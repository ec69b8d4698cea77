"""Frictional impacts of several contacts (docs/events.md, "Frictional impacts";
``phc.simulation.impact_law``): the impact law against closed forms written here, its
energy, and a run where a closed frictional contact takes part in another contact's impact.

Tolerances: the law's cases are linear systems solved in double precision (1e-12 relative);
the run's motions between events are quadratics in t, which the solvers reproduce to
round-off, and events are located to 1e-12·max(1, t), so times and positions agree to 1e-9."""

from __future__ import annotations

import numpy as np
import pytest

import phc
from phc.simulation.impact_law import solve

SOLVERS = (("ida", {}), ("midpoint", {"step": 1e-3}), ("midpoint4", {"step": 2e-3}))


def test_single_frictionless_contact_is_newton():
    m, e, v = 2.0, 0.6, -3.0
    lam, after = solve(np.array([[1 / m]]), np.array([v]), np.array([e]), np.array([np.nan]))
    assert lam[0] == pytest.approx(-(1 + e) * m * v, rel=1e-12)
    assert after[0] == pytest.approx(-e * v, rel=1e-12)


@pytest.mark.parametrize("vt,sticks", [(1.0, False), (-1.0, False), (0.5, True), (-0.5, True)])
def test_oblique_impact_of_a_point_mass_slides_or_sticks(vt, sticks):
    """A point mass m hits a floor with (v_n, v_t) = (−2, vt), e = 0.5, μ = 0.3: the normal
    impulse is (1 + e) m 2 = 3m; the tangential one is −vt m where that is within μ 3m = 0.9m
    (it sticks), else ∓0.9m (it slides on at vt ∓ 0.9)."""
    m, e, mu = 2.0, 0.5, 0.3
    W = np.eye(2) / m
    lam, after = solve(W, np.array([-2.0, vt]), np.array([e]), np.array([mu]))
    assert lam[0] == pytest.approx(3 * m, rel=1e-12)
    assert after[0] == pytest.approx(1.0, rel=1e-12)
    if sticks:
        assert after[1] == pytest.approx(0.0, abs=1e-12)
        assert lam[1] == pytest.approx(-vt * m, rel=1e-12)
    else:
        assert lam[1] == pytest.approx(-np.sign(vt) * mu * 3 * m, rel=1e-12)
        assert after[1] == pytest.approx(vt - np.sign(vt) * 0.9, rel=1e-12)


def test_plastic_frictional_impacts_never_gain_energy():
    """e = 0: Λ_N ġ⁺ = 0 and Λ_T v_T⁺ ≤ 0 (Coulomb), so the change of kinetic energy
    Λ·(γ⁻ + γ⁺)/2 = Λ·γ⁺ − ½ ΛᵀWΛ ≤ 0 (Glocker). Random Delassus matrices of 1–3 contacts,
    some frictional: every case has a solution satisfying the law and loses energy."""
    rng = np.random.default_rng(7)
    for _ in range(300):
        k = int(rng.integers(1, 4))
        f = int(rng.integers(0, k + 1))
        D = rng.normal(size=(4, k + f))
        W = D.T @ D + 1e-3 * np.eye(k + f)
        before = rng.normal(size=k + f)
        mu = np.full(k, np.nan)
        mu[:f] = rng.uniform(0.0, 1.0, f)
        solution = solve(W, before, np.zeros(k), mu)
        assert solution is not None
        lam, after = solution
        scale = np.abs(lam).sum() * np.abs(before).max()
        assert lam @ (before + after) / 2 <= 1e-12 * scale
        assert np.all(lam[:k] >= -1e-12 * scale) and np.all(after[:k] >= -1e-12 * np.abs(before).max())
        assert np.all(lam[:k] * after[:k] <= 1e-10 * scale)
        for j in range(f):
            assert abs(lam[k + j]) <= mu[j] * lam[j] * (1 + 1e-9) + 1e-12 * scale
            if abs(after[k + j]) > 1e-9 * np.abs(before).max():  # sliding: the full friction against it
                assert lam[k + j] == pytest.approx(-np.sign(after[k + j]) * mu[j] * lam[j], rel=1e-9, abs=1e-12)


WALL = """\
format_version: 1
name: wall
parameters:
  m: 2.0
  g: 9.81
  mu: 0.2
  L: 1.0
  e: 0.5
  v0: 3.0
components:
  block:
    type: rigid
    q: [x, y]
    v: [vx, vy]
    M: [[m, 0], [0, m]]
    V: m*g*y
  floor: {type: contact, gap: block.y, tangent: block.x, restitution: 0.0, friction: mu}
  wall: {type: contact, gap: L - block.x, restitution: e}
simulation:
  t_end: 2.0
  n_out: 201
  rtol: 1.0e-10
  atol: 1.0e-12
  initial: {block.x: 0.0, block.y: 0.0, block.p_vx: m*v0, block.p_vy: 0.0}
"""


@pytest.mark.parametrize("solver,kw", SOLVERS, ids=[s for s, _ in SOLVERS])
def test_block_sliding_on_a_floor_bounces_off_a_wall(tmp_path, solver, kw):
    """A block lies on a floor (closed, Coulomb μ) and slides at v0 towards a wall at L: it
    decelerates at μ g, hits the wall at t_w (L = v0 t_w − ½ μ g t_w²) with v_w = v0 − μ g t_w,
    and the joint impact of the wall and the closed floor (their normals orthogonal: the floor
    takes no impulse) sends it back at −e v_w; it slides back and sticks e v_w/(μ g) later."""
    path = tmp_path / "wall.yaml"
    path.write_text(WALL)
    r = phc.simulate(phc.compile_model(path), solver=solver, **kw)
    assert r.success, r.message
    m, g, mu, L, e, v0 = 2.0, 9.81, 0.2, 1.0, 0.5, 3.0
    a = mu * g
    t_w = (v0 - np.sqrt(v0**2 - 2 * a * L)) / a
    v_w = v0 - a * t_w
    t_s = t_w + e * v_w / a
    kinds = [(ev.kind, ev.condition, ev.direction) for ev in r.events]
    assert kinds == [("close", "floor", 0), ("slip", "floor", 1), ("impact", "wall", -1), ("slip", "floor", -1),
                     ("stick", "floor", 0)]
    assert r.events[2].t == pytest.approx(t_w, abs=1e-9)
    assert r.events[4].t == pytest.approx(t_s, abs=1e-9)
    x = r.y[:, r.variables.index("block.x")]
    tau = np.clip(r.t - t_w, 0.0, t_s - t_w)
    exact = np.where(r.t < t_w, v0 * r.t - 0.5 * a * r.t**2, L - e * v_w * tau + 0.5 * a * tau**2)
    assert np.allclose(x, exact, rtol=0, atol=1e-9)
    assert np.abs(r.y[:, r.variables.index("block.y")]).max() < 1e-12
    # the kinetic energy all went: (1 − e²) ½ m v_w² at the wall, the rest by friction
    assert r.energy_supplied[-1] == pytest.approx(0.5 * m * v0**2, rel=1e-9)
    assert r.energy_balance_relative < 1e-9
