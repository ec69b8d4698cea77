"""phc's one Gauss–Newton iteration with a fresh Jacobian (:mod:`phc.simulation.gauss_newton`),
on problems whose zeros are known in closed form; its two users (consistent initialization,
the dense rows check) are tested through their own tests."""

import math

import numpy as np

from phc.simulation.gauss_newton import gauss_newton, least_squares

EPS = np.finfo(float).eps


def _newton_step(x, g, J):
    """The least-norm correction −J⁺g (a square nonsingular J: Newton's)."""
    return -np.linalg.lstsq(J, g, rcond=None)[0]


def _square_root_of_two(x):
    return np.array([x[0] ** 2 - 2.0]), np.array([[2.0 * x[0]]])


def test_newton_converges_to_the_square_root_of_two_quadratically():
    """x² = 2 from 1: errors 8.6e-2, 2.5e-3, 2.1e-6, 1.6e-12, then round-off — Newton's quadratic
    convergence reaches 1e-14 in 5 steps (a sixth iteration finds it converged)."""
    out = gauss_newton([1.0], _square_root_of_two, _newton_step, tol=1e-14, max_iter=50)
    # the residual of the float nearest √2 is 2·√2·(its rounding error) ≤ 2·√2·eps·√2/2 = 2 eps
    assert abs(out.x[0] - math.sqrt(2.0)) <= 2 * EPS * math.sqrt(2.0)
    assert out.size <= 1e-14 and out.iterations <= 6


def test_refining_steps_after_convergence_reach_round_off():
    """With a loose tolerance (1e-3) the iteration stops at the first iterate below it (error
    2.1e-6 from 1); `polish` steps after that take it to round-off."""
    loose = gauss_newton([1.0], _square_root_of_two, _newton_step, tol=1e-3, max_iter=50)
    refined = gauss_newton([1.0], _square_root_of_two, _newton_step, tol=1e-3, max_iter=50, polish=3)
    assert abs(loose.x[0] - math.sqrt(2.0)) > 1e-7  # (error 2.1e-6: quadratic convergence's third iterate)
    assert abs(refined.x[0] - math.sqrt(2.0)) <= 2 * EPS * math.sqrt(2.0)


def test_an_underdetermined_linear_system_is_solved_by_its_least_norm_point_in_one_step():
    """x + y = 2 from (0, 0): one least-norm Gauss–Newton step is the least-norm solution (1, 1)."""
    def evaluate(x):
        return np.array([x[0] + x[1] - 2.0]), np.array([[1.0, 1.0]])

    out = gauss_newton([0.0, 0.0], evaluate, _newton_step, tol=1e-14, max_iter=10)
    assert np.allclose(out.x, [1.0, 1.0], rtol=0, atol=4 * EPS) and out.iterations == 2


def _arctan(x):
    return np.array([math.atan(x[0])]), np.array([[1.0 / (1.0 + x[0] ** 2)]])


def test_damping_brings_newton_on_arctan_home_from_where_full_steps_diverge():
    """Newton on atan(x) = 0 diverges from |x₀| > 1.39 (each full step overshoots further); with
    halved steps that must reduce |atan x| it converges to the zero 0."""
    full = gauss_newton([2.0], _arctan, _newton_step, tol=1e-12, max_iter=4)
    damped = gauss_newton([2.0], _arctan, _newton_step, tol=1e-12, max_iter=50, damping=1e-4)
    assert abs(full.x[0]) > 100.0  # 2 → −3.54 → 13.95 → −279.3 → 1.2e5
    assert abs(damped.x[0]) <= 1e-12


def test_keep_best_returns_the_least_residual_met_on_the_way():
    """Full steps on atan from 2 grow the residual at every step: keeping the best returns the start."""
    out = gauss_newton([2.0], _arctan, _newton_step, tol=1e-12, max_iter=4, keep_best=True)
    assert out.x[0] == 2.0 and out.size == math.atan(2.0)


def test_a_stalled_iteration_stops():
    """Steps that shrink the residual x by 5 % each: after 8 of them it is 0.95⁸ ≈ 0.66 of what it
    was, more than half, so with ``stall=(8, 0.5)`` iteration 9 stops (without, it runs on)."""
    def slow(x, g, _):
        return -0.05 * g

    evaluate = lambda x: (x.copy(), None)  # noqa: E731
    stalled = gauss_newton([1.0], evaluate, slow, tol=1e-12, max_iter=100, damping=1e-4, stall=(8, 0.5))
    assert stalled.iterations == 9
    assert abs(stalled.x[0] - 0.95 ** 8) <= 16 * EPS  # (eight roundings of x − 0.05 x)
    free = gauss_newton([1.0], evaluate, slow, tol=1e-12, max_iter=100, damping=1e-4)
    assert free.iterations == 100


def test_a_start_whose_residual_is_not_finite_is_returned_as_it_is():
    def evaluate(x):
        return np.array([math.log(x[0]) if x[0] > 0 else math.nan]), np.array([[1.0]])

    out = gauss_newton([-1.0], evaluate, _newton_step, tol=1e-12, max_iter=10)
    assert out.x[0] == -1.0 and math.isnan(out.size)


def test_least_squares_finds_the_least_residual_of_an_inconsistent_system():
    """x = 1 and x = −1 at once: the least-squares point is 0 (residual norm √2)."""
    fit = least_squares(lambda x: np.array([x[0] - 1.0, x[0] + 1.0]), np.array([3.0]),
                        lambda x: np.array([[1.0], [1.0]]))
    assert abs(fit.x[0]) <= 1e-12 and abs(np.linalg.norm(fit.fun) - math.sqrt(2.0)) <= 1e-12
