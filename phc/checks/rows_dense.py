"""Points of a nonlinear system of rows, for the dense rows check (:mod:`phc.checks.rows`).

A system is a :class:`phc.checks.rows._System` (rows ``F(u) = 0`` over unknowns u =
(visible, hidden), with ``F`` and its Jacobian ``J``). Here: a zero near a start (a
minimum-norm damped Gauss–Newton iteration), whether a visible point lies in a system (its
hidden unknowns solved for, from several starts, then by a trust-region least-squares
solve), whether a residual left there is a true minimum (a mismatch) or an iteration that
stopped on its way (no verdict), and the tangent space of the solution set.
"""

from __future__ import annotations

from typing import Optional

import numpy as np

RESIDUAL_TOL = 1e-9
"""A point satisfies a system when every row's residual is below this, relative to the
row's largest Jacobian entry times the size of the point."""
MEMBERSHIP_TOL = 1e-6
"""A point of one system lies in the other when the other's residual, scaled likewise, is
below this (the hidden unknowns are solved for, which costs accuracy)."""
RESTARTS = 5
"""Random starts tried before a system is reported as having no point found."""
def _scaled(system, u):
    F, J = system.F(u), system.J(u)
    scale = np.maximum(np.abs(J).max(axis=1, initial=0.0), 1e-300) * max(1.0, float(np.abs(u).max(initial=0.0)))
    return F / scale, J / scale[:, None]


def _newton(system, u, free: Optional[np.ndarray] = None, iterations: int = 60):
    """A zero of the system near `u`, moving only the unknowns in `free`: minimum-norm damped
    Gauss–Newton (:func:`phc.simulation.gauss_newton.gauss_newton`) on the rows scaled at each
    iterate. Returns (point, largest scaled residual)."""
    # (not at import: phc.simulation is large)
    from phc.simulation.gauss_newton import gauss_newton
    from phc.simulation.minnorm import dense_min_norm

    u = np.array(u, dtype=float)
    free = np.arange(len(u)) if free is None else free

    def step(x, r, J):
        Jf = J[:, free]
        if not np.all(np.isfinite(Jf)):
            return None  # an infinite slope: no step to take from here (the caller restarts elsewhere)
        # the rows are equilibrated: minnorm's rank threshold leaves out the directions only
        # round-off of the Jacobian determines (a step along them would be that round-off magnified)
        d = np.zeros(len(x))
        d[free] = -dense_min_norm(Jf, r)
        return d

    with np.errstate(all="ignore"):
        # halving down to 1e-4 of the step; a stall (no halving of the residual in 8 iterations:
        # a local minimum) ends it, and the caller restarts elsewhere; a law with a jump (sign,
        # heaviside, ifelse) need not decrease on the way across it: the full step is taken
        # there (the iteration count still bounds this)
        out = gauss_newton(u, lambda x: _scaled(system, x), step, tol=RESIDUAL_TOL * 1e-2, max_iter=iterations,
                           damping=1e-4, jumps=not system._complex, stall=(8, 0.5))
    return out.x, out.size


SETTLED_FRACTION = 0.1
"""A least-squares point of a system where a linear step of the unknowns that may move could
remove at most this fraction of the residual (``‖P r‖ ≤ 0.1 ‖r‖``, P the projection onto
the range of their Jacobian) is settled: the residual left there is outside what those
unknowns can change, so it is a mismatch. A true minimum has ``P r = 0``; an iteration that
stopped on its way (a steep law from a bad start, an overflow) still has most of its
residual in that range, and then nothing is decided."""


def _member(b, w: np.ndarray, rng) -> tuple[np.ndarray, float, bool]:
    """Whether the visible point `w` lies in `b`: b's hidden unknowns solved for from up to
    :data:`RESTARTS` random starts. Returns ``(point, residual, settled)``: the best point
    found, its largest scaled residual, and whether that point is a stationary point of the
    residual (:func:`_stationary`), i.e. whether a residual above the tolerance says
    that `w` is not in `b` rather than that the iteration failed."""
    n_vis = len(w)
    hidden = np.arange(n_vis, len(b.unknowns))
    best = None
    for _ in range(RESTARTS):
        start = np.concatenate([w, rng.normal(size=len(hidden))])
        point, err = _newton(b, start, free=hidden)
        if err <= MEMBERSHIP_TOL:
            return point, err, True
        if best is None or not err >= best[1]:  # NaN never wins
            best = (point, err)
        if not len(hidden):
            break  # nothing to move: one evaluation decides
    point, err = _least_squares(b, best[0], hidden)
    if err <= MEMBERSHIP_TOL:
        return point, err, True
    return point, err, _stationary(b, point, hidden)


def _least_squares(system, u: np.ndarray, free: np.ndarray) -> tuple[np.ndarray, float]:
    """The point of least residual near `u` over the unknowns `free` (a trust-region
    least-squares solve, rows scaled as at `u`): where the Gauss–Newton iteration of
    :func:`_newton` stalls on a residual that cannot vanish, this one still converges to the
    minimum, whose residual :func:`_stationary` then judges. Returns (point, largest scaled
    residual)."""
    from phc.simulation.gauss_newton import least_squares

    if not len(free):
        return u, float(np.abs(_scaled(system, u)[0]).max(initial=0.0))
    with np.errstate(all="ignore"):
        r, J = _scaled(system, u)
        if not (np.all(np.isfinite(r)) and np.all(np.isfinite(J))):
            return u, float("inf")
        scale = np.maximum(np.abs(system.J(u)).max(axis=1, initial=0.0), 1e-300) * max(1.0, float(np.abs(u).max()))

        def at(x):
            v = u.copy()
            v[free] = x
            return v

        def fun(x):
            value = system.F(at(x)) / scale
            return np.where(np.isfinite(value), value, 1e300)

        def jac(x):
            value = system.J(at(x))[:, free] / scale[:, None]
            return np.where(np.isfinite(value), value, 0.0)

        try:
            fit = least_squares(fun, u[free], jac, gtol=1e-14, max_nfev=100 * (len(free) + 1))
        except (ValueError, np.linalg.LinAlgError):
            return u, float(np.abs(r).max(initial=0.0))
        point = at(fit.x)
        err = float(np.abs(_scaled(system, point)[0]).max(initial=0.0))
        return point, err if np.isfinite(err) else float("inf")


def _stationary(system, u: np.ndarray, free: np.ndarray) -> bool:
    """Whether `u` is a settled least-squares point of the scaled residual over the unknowns
    `free` (:data:`SETTLED_FRACTION`)."""
    from phc.simulation.minnorm import dense_min_norm

    with np.errstate(all="ignore"):
        r, J = _scaled(system, u)
        if not (np.all(np.isfinite(r)) and np.all(np.isfinite(J))):
            return False
        if not len(free):
            return True
        Jf = J[:, free]
        # Every direction above round-off (numpy's lstsq threshold, eps·max(m, n), as this
        # check had before) counts as one the unknowns can move along: a residual is called
        # settled — a mismatch — only when it is outside all of them. A coarser threshold
        # would leave weak directions out and claim mismatches where the iteration may only
        # have stopped on its way.
        reach = Jf @ dense_min_norm(Jf, r, cond=np.finfo(float).eps * max(Jf.shape))
        return float(np.linalg.norm(reach)) <= SETTLED_FRACTION * float(np.linalg.norm(r))


def _visible_tangent(system, u) -> np.ndarray:
    """Orthonormal basis (columns) of the solution set's tangent space at u, projected onto
    the visible unknowns."""
    _, J = _scaled(system, u)
    n = len(u)
    if J.size:
        _, s, vt = np.linalg.svd(J)
        rank = int(np.sum(s > 1e-9 * max(s.max(initial=0.0), 1e-300)))
        null = vt[rank:].T
    else:
        null = np.eye(n)
    proj = null[:system.n_visible]
    if proj.size == 0:
        return np.zeros((system.n_visible, 0))
    U, s, _ = np.linalg.svd(proj, full_matrices=False)
    return U[:, s > 1e-8 * max(s.max(initial=0.0), 1.0)]


def _worst(system, u) -> tuple[str, float]:
    r, _ = _scaled(system, u)
    i = int(np.argmax(np.abs(r)))
    return system.labels[i], float(system.F(u)[i])
