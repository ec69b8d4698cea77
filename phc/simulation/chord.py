"""Chord iteration with a pseudo-inverse: phc's one Gauss–Newton iteration on a matrix kept
across steps and calls.

A residual ``g(x)`` (as many rows as it has, more or fewer than the unknowns x) is driven to
zero by steps ``x ← x − W J⁺ g(x)``: ``J`` is the Jacobian of g in the scaled unknowns
``x / W`` (W a vector of positive column scales, 1 when none is given) and ``J⁺`` its
pseudo-inverse, computed by an SVD that drops the singular values at or below ``rtol`` times
the largest. Each step is the weighted least-norm least-squares correction of the
linearization at the point where J was taken — for a consistent linear system, one step
solves it. J⁺ is computed once and reused (a chord, or simplified Gauss–Newton, iteration):
a refresh costs a Jacobian and an SVD, a step a matrix–vector product and one residual.
The matrix is kept between solves of one :class:`ChordIteration` (the next solve starts
near the last one's solution), and refreshed, once per solve:

* when a step reduced the residual by less than the factor `contraction` (a stale
  matrix), before the next step — after the convergence test, so a solve that has just
  converged does not pay for a matrix it does not need;
* when a step did not reduce the residual: the step is not taken, and is taken again from
  the same point with the fresh matrix. A step that does not reduce the residual is
  never taken, so a solve never returns a point worse than its start.

It stops when `converged` says so (before each step), after `steps` steps tried (taken or
not), when a step is `negligible` (round-off of the unknowns), when a step that does not
reduce the residual was tried with a fresh matrix already, or — with ``slow_stops`` — when a
step with the fresh matrix still contracts slowly (the residual is at its round-off).

Two users, with their own residuals, Jacobians and stopping rules:
:class:`phc.simulation.midpoint.Projector` (position invariants at the step ends of the
fixed-step methods) and :class:`phc.simulation.polish.AlgebraicPolish` (the algebraic
variables at IDA's output times).

Why a pseudo-inverse and not :mod:`phc.simulation.minnorm` (phc's least-norm solver of one
system): a chord iteration solves with one matrix many times; its SVD once, then a product
per step, is cheaper than a QR factorization (gelsy) per step. Both are for small dense
systems (the callers bound their size).
"""

from __future__ import annotations

from typing import Callable, NamedTuple, Optional

import numpy as np
import scipy.linalg as sla


def max_norm(g: np.ndarray) -> float:
    """The largest |entry| (0 for no entries)."""
    return float(np.abs(g).max(initial=0.0))


def two_norm(g: np.ndarray) -> float:
    """The Euclidean norm."""
    return float(np.linalg.norm(g))


class Outcome(NamedTuple):
    """What a solve ended with."""

    x: np.ndarray
    """The last point taken (the start when no step reduced the residual)."""
    size: float
    """The residual's size there (`norm`; inf when the start's residual is not finite)."""
    start: float
    """The residual's size at the start."""
    steps: int
    """Steps taken."""


class ChordIteration:
    """The chord iteration of the module docstring, with its matrix kept between solves.

    `rtol`: the pseudo-inverse's rank threshold, relative to the largest singular value.
    `same_matrix`: a refresh whose Jacobian differs from the matrix of the pseudo-inverse by
    at most this fraction of that matrix's largest entry keeps the pseudo-inverse (no SVD;
    a linear system's Jacobian is constant); None: every refresh computes it."""

    def __init__(self, *, rtol: float, same_matrix: Optional[float] = None):
        self.rtol = rtol
        self.same_matrix = same_matrix
        self.pinv: Optional[np.ndarray] = None
        self.matrix: Optional[np.ndarray] = None
        """The matrix whose pseudo-inverse :attr:`pinv` is."""
        self.refreshes = 0
        """Pseudo-inverses computed."""

    def refresh(self, jacobian: Callable, x: np.ndarray, g: Optional[np.ndarray] = None) -> bool:
        """A new pseudo-inverse from ``jacobian(x, g)`` (the scaled Jacobian at x, g the
        residual there when known). False, and the old one kept, when the Jacobian is not
        finite."""
        J = np.asarray(jacobian(x, g), dtype=float)
        if not np.all(np.isfinite(J)):
            return False
        old = self.matrix
        if self.same_matrix is not None and old is not None and old.shape == J.shape and \
                float(np.abs(J - old).max(initial=0.0)) <= self.same_matrix * float(np.abs(old).max(initial=0.0)):
            return True  # the same matrix: its pseudo-inverse stands
        self.pinv = sla.pinv(J, atol=0.0, rtol=self.rtol)
        self.matrix = J
        self.refreshes += 1
        return True

    def solve(self, x, residual: Callable, jacobian: Callable, *, steps: int, contraction: float,
              converged: Callable, norm: Callable = two_norm, weights: Optional[np.ndarray] = None,
              negligible: Optional[Callable] = None, slow_stops: bool = False) -> Outcome:
        """Iterate from `x` (module docstring).

        ``residual(x)`` is g; ``jacobian(x, g)`` the Jacobian of g in the scaled unknowns
        ``x / weights`` (g: the residual at x, or None); ``converged(x, size)`` (size: the
        residual's `norm`) ends the iteration before a step; ``negligible(x, step)``
        (`step` scaled, the change of x is ``weights * step``) ends it instead of a step.
        The first solve computes the pseudo-inverse where it first needs it."""
        x = np.asarray(x, dtype=float)
        g = residual(x)
        size = norm(g) if np.all(np.isfinite(g)) else np.inf
        start, taken = size, 0
        if not np.isfinite(size):
            return Outcome(x, size, start, taken)
        fresh = slow = False
        for _ in range(steps):
            if converged(x, size):
                break
            if self.pinv is None:
                if not self.refresh(jacobian, x, g):
                    break
                fresh = True
            elif slow:
                if fresh:
                    if slow_stops:
                        break  # slow with a fresh matrix: round-off
                else:
                    fresh = self.refresh(jacobian, x, g)  # a stale matrix (kept if this fails)
            step = self.pinv @ g
            if negligible is not None and negligible(x, step):
                break
            x1 = x - (step if weights is None else weights * step)
            g1 = residual(x1)
            size1 = norm(g1) if np.all(np.isfinite(g1)) else np.inf
            if size1 < size:
                slow = size1 > contraction * size
                x, g, size = x1, g1, size1
                taken += 1
                continue
            # no progress: a stale matrix; once more from x with a fresh one
            if fresh or not self.refresh(jacobian, x, g):
                break
            fresh, slow = True, False
        return Outcome(x, size, start, taken)


__all__ = ["ChordIteration", "Outcome", "max_norm", "two_norm"]
