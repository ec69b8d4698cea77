"""The chord iteration with a pseudo-inverse (:mod:`phc.simulation.chord`) against closed forms:
the nearest point of a circle and a sphere, the weighted least-norm solution of a linear
system (one step), a stale matrix refreshed instead of a step that makes things worse."""

from __future__ import annotations

import numpy as np
import pytest

from phc.simulation.chord import ChordIteration, max_norm, two_norm

EPS = np.finfo(float).eps


def _solve(chord, x0, residual, jacobian, **kw):
    kw = dict(steps=20, contraction=0.5, converged=lambda x, size: size <= 4 * EPS) | kw
    return chord.solve(np.asarray(x0, dtype=float), residual, jacobian, **kw)


@pytest.mark.parametrize("x0", [(1.3, 0.4), (0.2, -0.5, 0.7), (-2.0, 1.0, 0.5, 3.0)])
def test_projection_onto_a_sphere_is_the_nearest_point(x0):
    """g(x) = |x|² − 1: the least-norm step is along ∇g = 2x, radial, so every iterate stays on
    the ray through x0 and the limit is the nearest point x0/|x0| of the sphere. Round-off:
    the residual |x|² − 1 is evaluated to a few ulps, so the test stops at 16 of them."""
    x0 = np.asarray(x0, dtype=float)
    chord = ChordIteration(rtol=1e-13)
    jacobian = lambda x, g: 2.0 * x[None, :]  # noqa: E731
    # the matrix of x0 taken before the solve (as the polish does), so that the solve may refresh
    # it once when the steps contract slowly (by 1 − 1/|x| near the sphere); linear convergence
    # with the kept matrix then: room for 100 steps
    assert chord.refresh(jacobian, x0)
    out = _solve(chord, x0, lambda x: np.array([x @ x - 1.0]), jacobian, steps=100,
                 converged=lambda x, size: size <= 16 * EPS)
    assert abs(out.x @ out.x - 1.0) <= 16 * EPS
    # on the ray through x0 up to the rounding of each step (an ulp or so per step, < 30 steps)
    np.testing.assert_allclose(out.x, x0 / np.linalg.norm(x0), rtol=0, atol=64 * EPS)
    assert out.start == pytest.approx(abs(x0 @ x0 - 1.0), rel=1e-15) and out.size <= 16 * EPS
    assert 0 < out.steps < 100


def test_a_consistent_linear_system_is_solved_in_one_step_with_least_weighted_change():
    """A x = b, underdetermined: one step gives the solution nearest to x0 in the weighted
    norm ‖(x − x0)/w‖, x = x0 − W² Aᵀ (A W² Aᵀ)⁻¹ (A x0 − b); the Jacobian (in the scaled
    unknowns: A W) is taken once and kept for the next solve."""
    rng = np.random.default_rng(3)
    A, b = rng.normal(size=(2, 5)), rng.normal(size=2)
    w = np.array([1.0, 10.0, 0.1, 2.0, 1.0])
    calls = []

    def jacobian(x, g):
        calls.append(x)
        return A * w[None, :]

    chord = ChordIteration(rtol=1e-13)
    for x0 in (rng.normal(size=5), rng.normal(size=5)):
        # converged far above the round-off one step leaves (~1e-14) and far below the
        # start's O(1): a chord iteration on a nonlinear g would need more than one step
        out = _solve(chord, x0, lambda x: A @ x - b, jacobian, weights=w, norm=max_norm,
                     converged=lambda x, size: size <= 1e-12)
        W2 = np.diag(w**2)
        exact = x0 - W2 @ A.T @ np.linalg.solve(A @ W2 @ A.T, A @ x0 - b)
        assert out.steps == 1 and out.size <= 1e-13
        # the solution, to the round-off of a 2 × 5 pseudo-inverse of entries ~ 10
        np.testing.assert_allclose(out.x, exact, rtol=0, atol=1e-13 * (1 + np.abs(exact).max()))
    assert len(calls) == 1 and chord.refreshes == 1


def test_an_unchanged_matrix_keeps_its_pseudo_inverse():
    """`same_matrix`: a refresh whose Jacobian equals the last one computes no SVD."""
    A = np.array([[2.0, 1.0], [1.0, 3.0]])
    chord = ChordIteration(rtol=1e-13, same_matrix=1e-14)
    assert chord.refresh(lambda x, g: A, np.zeros(2)) and chord.refreshes == 1
    first = chord.pinv
    assert chord.refresh(lambda x, g: A.copy(), np.ones(2)) and chord.refreshes == 1 and chord.pinv is first
    assert chord.refresh(lambda x, g: 2 * A, np.ones(2)) and chord.refreshes == 2
    np.testing.assert_allclose(chord.pinv, np.linalg.inv(2 * A), rtol=1e-14)
    assert not chord.refresh(lambda x, g: A * np.nan, np.ones(2)) and chord.refreshes == 2  # kept


def test_a_step_that_makes_the_residual_worse_is_not_taken():
    """g(x) = x³ − 8 from x = 3 with the matrix of x = 1 (J = 3) kept from an earlier solve:
    its step (to x = 3 − 19/3) makes |g| worse, so it is not taken; the iteration tries again
    from x = 3 with J = 27 and then converges (linearly, rate 1 − 12/27) to the root 2."""
    chord = ChordIteration(rtol=1e-13)

    def jacobian(x, g):
        return 3.0 * x[None, :] ** 2

    chord.refresh(jacobian, np.array([1.0]))
    visited, sizes = [], []

    def residual(x):
        visited.append(float(x[0]))
        g = x**3 - 8.0
        sizes.append(abs(float(g[0])))
        return g

    out = _solve(chord, [3.0], residual, jacobian, steps=100, converged=lambda x, size: size <= 64 * EPS)
    assert visited[1] == pytest.approx(3.0 - 19.0 / 3.0, rel=1e-15) and sizes[1] > sizes[0]  # the stale step, tried
    assert out.steps >= 1 and chord.refreshes == 2
    assert abs(out.x[0] - 2.0) <= 16 * EPS  # |g| ≤ 64 eps and g' = 12 at the root
    # only better points were taken: where it ended is the best point it looked at
    assert out.size == pytest.approx(min(sizes), rel=1e-15)


def test_a_non_finite_start_is_returned_unchanged():
    chord = ChordIteration(rtol=1e-13)
    x0 = np.array([1.0, 2.0])
    out = _solve(chord, x0, lambda x: np.array([np.inf]), lambda x, g: np.ones((1, 2)))
    assert out.steps == 0 and out.size == np.inf and np.array_equal(out.x, x0) and chord.pinv is None


def test_slow_stops_ends_where_a_fresh_matrix_still_contracts_slowly():
    """g(x) = x with a Jacobian that says 4 (as an inexact matrix would): each step shrinks g
    by 3/4, slower than `contraction`. With ``slow_stops`` the iteration ends after the first
    slow step with a fresh matrix (the projector reads this as round-off); without, it keeps
    the matrix and goes on until the steps run out."""
    kw = dict(steps=20, contraction=0.5, converged=lambda x, size: False, norm=max_norm)
    stop = ChordIteration(rtol=1e-13).solve(np.array([1.0]), lambda x: x.copy(), lambda x, g: np.array([[4.0]]),
                                            slow_stops=True, **kw)
    assert stop.steps == 1 and stop.x[0] == 0.75
    go_on = ChordIteration(rtol=1e-13).solve(np.array([1.0]), lambda x: x.copy(), lambda x, g: np.array([[4.0]]), **kw)
    assert go_on.steps == 20 and go_on.x[0] == pytest.approx(0.75**20, rel=1e-13)


class _Circle:
    """A module with the position invariant x² + y² − L² (differential x, y, v; algebraic λ)."""

    N = 4
    DIFFERENTIAL = [True, True, True, False]
    INVARIANTS = ["circle"]

    def invariants(self, t, y, p):
        return np.array([y[0] ** 2 + y[1] ** 2 - p[0] ** 2])


@pytest.mark.parametrize("scales", [None, np.array([2.0, 2.0, 1.0, 1.0])])
def test_the_midpoint_projector_moves_a_state_to_the_nearest_point_of_its_invariant(scales):
    """:class:`phc.simulation.midpoint.Projector` on the chord iteration: (x, y) off the circle
    of radius L goes to L (x, y)/|(x, y)| (the least-norm correction of the variables the
    invariant depends on is radial, as above); v and λ, which it does not depend on, stay.
    Its Jacobian is a finite difference (step 1e-7 of the sizes): its entries 2x + h are off
    by relative errors below 1e-7, which tilt the step by less than 1e-7 rad, so the point
    reached is the nearest one up to 1e-7 × the distance 2e-4 along the circle (2e-11); and
    on the circle to the projector's own tolerance (TOL of its terms |G| (|y| + s) ~ 2L (L + s))."""
    from phc.simulation.midpoint import Projector

    L = 2.0
    mod, p = _Circle(), np.array([L])
    y = np.array([1.6 * (1 + 1e-4), 1.2 * (1 + 1e-4), 0.3, -4.0])  # 2e-4 off the circle (a drift)
    proj = Projector(mod, p, y, 0.0, scales)
    assert list(proj.cols) == [0, 1]
    out = proj.project(0.0, y)
    assert out is not y and np.array_equal(out[2:], y[2:])
    nearest = L * y[:2] / np.linalg.norm(y[:2])
    np.testing.assert_allclose(out[:2], nearest, rtol=0, atol=1e-10)
    assert abs(out[0] ** 2 + out[1] ** 2 - L**2) <= Projector.TOL * 2 * L * (L + 2.0) * 4
    # a second projection of a nearby point reuses the matrix: a few steps, no new one needed
    refreshes = proj.chord.refreshes
    again = proj.project(0.0, out + np.array([1e-6, -2e-6, 0.0, 0.0]))
    assert abs(again[0] ** 2 + again[1] ** 2 - L**2) <= Projector.TOL * 2 * L * (L + 2.0) * 4
    assert proj.chord.refreshes <= refreshes + 1
