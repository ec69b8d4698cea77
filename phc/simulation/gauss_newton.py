"""Gauss–Newton with a fresh Jacobian at every step: phc's one iteration for a zero of a
nonlinear system solved from a start, not along a trajectory.

A residual ``g(x)`` (as many rows as it has, more or fewer than the unknowns) is driven to
zero by steps ``x ← x + α Δ``, where ``Δ`` is the caller's correction at the current point
(:func:`gauss_newton`'s `step`: in phc, always a weighted least-norm least-squares
correction of the linearization, from :mod:`phc.simulation.minnorm`) and ``α`` is 1 or, with
`damping`, the first of 1, 1/2, 1/4, … above `damping` that reduces the residual's norm. The
iteration stops when the norm is at most `tol` (after `polish` more steps that keep it
there: they take what is left to round-off), after `max_iter` steps, when `step` has none to
offer, when the residual stalls (`stall`), when a damped step finds no decrease, or when an
undamped step leads to a residual that is not finite.

Two users, with their own residuals, corrections and stopping rules:
:mod:`phc.simulation.initial` (consistent initialization: full steps, the best iterate kept,
refining steps after convergence) and :mod:`phc.checks.rows_dense` (a point of a system of
rows from a random start: damped steps, a stall test, and a full step across a law with a
jump). Where the iteration ends above its tolerance both polish the best point found with a
trust-region least-squares solve (:func:`least_squares`).

The other Newton-type iterations of phc solve other problems and are written once each:
:func:`phc.simulation.step_logic.newton` (the simplified Newton iteration of a fixed-step
method's stage, one matrix kept across iterations and steps; jitted for the numba loop and
ported to C for the C back end), :class:`phc.simulation.chord.ChordIteration` (a
pseudo-inverse kept across calls: the projection onto position invariants, the algebraic
polish at IDA's output times) and IDA's own Newton iteration.
"""

from __future__ import annotations

from typing import Any, Callable, NamedTuple, Optional

import numpy as np

from phc.simulation.chord import max_norm


class Outcome(NamedTuple):
    """What :func:`gauss_newton` ended with."""

    x: np.ndarray
    """The point returned: the last one taken, or with ``keep_best`` the one of least norm."""
    size: float
    """The residual's norm there."""
    iterations: int
    """The iteration the loop ended in (``max_iter`` when it ran out)."""


def gauss_newton(x, evaluate: Callable[[np.ndarray], tuple[np.ndarray, Any]],
                 step: Callable[[np.ndarray, np.ndarray, Any], Optional[np.ndarray]], *, tol: float, max_iter: int,
                 norm: Callable[[np.ndarray], float] = max_norm, damping: Optional[float] = None,
                 jumps: bool = False, stall: Optional[tuple[int, float]] = None, polish: int = 0,
                 keep_best: bool = False) -> Outcome:
    """Iterate from `x` (module docstring).

    ``evaluate(x)`` returns ``(g, data)``: the residual at x and anything the correction needs
    there (the Jacobian, when it comes with the residual), handed back to ``step(x, g, data)``,
    which returns the correction Δ (the step is ``x + α Δ``) or None when there is none to
    take (the iteration stops).

    `tol`: converged when ``norm(g) ≤ tol`` (with ``keep_best``, the best norm so far).
    `damping`: None for full steps; else halve α from 1 while α > `damping` until the norm
    decreases, and stop when it never does — or, with `jumps`, take the full step all the same
    when its residual is finite (a law with a jump need not decrease on the way across it).
    `stall`: ``(k, f)`` stops when the norm is above f times its value k iterations before.
    `polish`: steps taken after convergence; each must stay converged, or the iteration stops
    at the point before it. `keep_best`: return the point of least norm (undamped steps may
    increase the norm on the way) instead of the last one.

    A start whose residual is not finite is returned as it is."""
    x = np.array(x, dtype=float)
    g, data = evaluate(x)
    size = norm(g)
    best_x, best_size = x, size
    history: list[float] = []
    it = polished = 0
    for it in range(1, max_iter + 1):
        if not np.isfinite(size):
            break  # (only a start: no step is taken to a point whose residual is not finite)
        if (best_size if keep_best else size) <= tol:
            if polished >= polish or not g.any():
                break  # (g = 0 exactly: a refining step would be zero)
            polished += 1
        if stall is not None:
            history.append(size)
            back, factor = stall
            if len(history) > back and size > factor * history[-back - 1]:
                break  # stalled (a local minimum of the residual)
        d = step(x, g, data)
        if d is None:
            break
        if damping is None:
            x = x + d
            g, data = evaluate(x)
            if not np.all(np.isfinite(g)):
                break
            size = norm(g)
            if polished:
                if size > tol:
                    break
                best_x, best_size = x, size
            elif size < best_size:
                best_x, best_size = x, size
            continue
        alpha, taken = 1.0, None
        while alpha > damping:
            trial = x + alpha * d
            gt, dt = evaluate(trial)
            st = norm(gt)
            if np.isfinite(st) and st < size:
                taken = (trial, gt, dt, st)
                break
            alpha /= 2
        if taken is None and jumps:
            trial = x + d
            gt, dt = evaluate(trial)
            taken = (trial, gt, dt, norm(gt)) if np.all(np.isfinite(gt)) else None
        if taken is None:
            break
        x, g, data, size = taken
        if size < best_size:
            best_x, best_size = x, size
    if keep_best:
        return Outcome(best_x, best_size, it)
    return Outcome(x, size, it)


def least_squares(fun: Callable, x, jac: Callable, *, gtol: float = 1e-15, max_nfev: Optional[int] = None):
    """The point of least residual near `x`: SciPy's trust-region reflective least-squares
    solve (``scipy.optimize.least_squares``, ``method="trf"``) with the step and residual
    tolerances at round-off (``xtol = ftol = 1e-15``) — where :func:`gauss_newton` ended above its
    tolerance (a residual that cannot vanish, a stall), this still converges to the least
    residual, which the caller then judges. Returns SciPy's result (``x``, ``fun``, ``nfev``)."""
    from scipy import optimize  # rarely needed; its import costs 0.2 s

    return optimize.least_squares(fun, x, jac=jac, method="trf", xtol=1e-15, ftol=1e-15, gtol=gtol,
                                  max_nfev=max_nfev)


__all__ = ["Outcome", "gauss_newton", "least_squares"]
