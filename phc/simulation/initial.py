"""Consistent initialization (pipeline stage 7, "analyse", run at t₀).

Given fixed initial values for some states and guesses for the rest, find ``(y₀, ẏ₀)``
with ``F(t₀, y₀, ẏ₀) = 0`` that also satisfies the hidden constraints of the index-2
formulation. Those are obtained by one differentiation of every row,
``D = F_y ẏ + F_ẏ ÿ + F_t = 0``, with the second derivatives as extra (nuisance)
unknowns — the numeric counterpart of one Pantelides step. The system ``[F; D] = 0`` is
solved by a Gauss–Newton iteration with minimum-norm steps, starting from the guesses,
so free values move as little as needed. Fixed values are never moved: if the
equations cannot hold with them, the rows that fail are reported with the variables
they involve (never a silent snap onto the constraint manifold).
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
import scipy.sparse as sps
from scipy.optimize import least_squares

from phc.errors import InconsistentInitialError


@dataclass
class InitialResult:
    y0: np.ndarray
    yp0: np.ndarray
    chosen: dict[str, float] = field(default_factory=dict)
    residual: float = 0.0
    iterations: int = 0


class _Jacobians:
    def __init__(self, mod, p):
        self.mod = mod
        self.p = p
        n = mod.N
        self.shape = (len(mod.EQUATIONS), n)
        self.rows = mod.JAC_ROWS
        self.cols = mod.JAC_COLS
        self.buf = np.zeros(len(self.rows))

    def _matrix(self, data):
        return sps.csc_matrix((data, (self.rows, self.cols)), shape=self.shape)

    def split(self, t, y, yp):
        """(F_y, F_ẏ) as sparse matrices."""
        self.mod.jacobian(t, y, yp, self.p, 0.0, self.buf)
        jy = self.buf.copy()
        self.mod.jacobian(t, y, yp, self.p, 1.0, self.buf)
        jyp = self.buf - jy
        return self._matrix(jy), self._matrix(jyp)


def consistent_initial_conditions(mod, p, t0: float, values: dict[int, float], fixed: set[int],
                                  tol: float = 1e-10, max_iter: int = 60) -> InitialResult:
    """Solve for consistent ``(y₀, ẏ₀)``.

    Parameters
    ----------
    mod : module
        A generated residual module.
    p : ndarray
        Full parameter vector.
    t0 : float
        Initial time.
    values : dict
        Initial value (fixed or guess) by variable index; others start at 0.
    fixed : set of int
        Indices whose value must not change.

    Raises
    ------
    InconsistentInitialError
        When the fixed values violate an equation; the message names the equation(s).
    """
    n = mod.N
    diff = np.asarray(mod.DIFFERENTIAL, dtype=bool)
    y = np.zeros(n)
    for j, v in values.items():
        y[j] = v
    yp = np.zeros(n)
    free_y = np.array([j for j in range(n) if j not in fixed], dtype=int)
    dif = np.flatnonzero(diff)
    alg = np.flatnonzero(~diff)
    jac = _Jacobians(mod, p)
    m = len(mod.EQUATIONS)
    nu = len(free_y) + len(dif) + n + len(dif)  # y_free, ẏ (diff), ẏ (all, nuisance for alg), ÿ (diff)
    z = np.zeros(n)   # d/dt y for the D rows (diff part tied to yp)
    w = np.zeros(n)   # second derivatives of differential variables
    F = np.zeros(m)

    def residual_F(y_, yp_):
        mod.residual(t0, y_, yp_, p, F)
        return F.copy()

    def residual_D(y_, yp_, z_, w_):
        jy, jyp = jac.split(t0, y_, yp_)
        ydot = z_.copy()
        ydot[dif] = yp_[dif]
        Ft = np.zeros(m)
        mod.residual_t(t0, y_, yp_, p, Ft)
        return jy @ ydot + jyp @ w_ + Ft, jy, jyp

    def G(y_, yp_, z_, w_):
        d, _, _ = residual_D(y_, yp_, z_, w_)
        return np.concatenate([residual_F(y_, yp_), d])

    def norm(g):
        return float(np.abs(g).max(initial=0.0))

    nf, nd, na = len(free_y), len(dif), len(alg)

    def unpack(u):
        y_, yp_, z_, w_ = y.copy(), yp.copy(), z.copy(), w.copy()
        y_[free_y] = u[:nf]
        yp_[dif] = u[nf:nf + nd]
        z_[alg] = u[nf + nd:nf + nd + na]
        w_[dif] = u[nf + nd + na:]
        return y_, yp_, z_, w_

    def fun(u):
        return G(*unpack(u))

    def jacobian(u):
        y_, yp_, z_, w_ = unpack(u)
        base_d, jy, jyp = residual_D(y_, yp_, z_, w_)
        # Columns: [y_free | yp_diff | z_alg | w_diff]; F is linear in them except y.
        JF = sps.hstack([jy[:, free_y], jyp[:, dif], sps.csc_matrix((m, na)), sps.csc_matrix((m, nd))]).toarray()
        JD = np.zeros((m, nf + nd + na + nd))
        col = 0
        for j in free_y:  # D is bilinear: finite differences for its y and ẏ columns
            h = 1e-7 * max(1.0, abs(y_[j]))
            yh = y_.copy()
            yh[j] += h
            JD[:, col] = (residual_D(yh, yp_, z_, w_)[0] - base_d) / h
            col += 1
        for j in dif:
            h = 1e-7 * max(1.0, abs(yp_[j]))
            yph = yp_.copy()
            yph[j] += h
            JD[:, col] = (residual_D(y_, yph, z_, w_)[0] - base_d) / h
            col += 1
        JD[:, col:col + na] = jy[:, alg].toarray()
        JD[:, col + na:] = jyp[:, dif].toarray()
        return np.vstack([JF, JD])

    u = np.concatenate([y[free_y], yp[dif], z[alg], w[dif]])
    g = fun(u)
    it = 0
    # Gauss–Newton with minimum-norm steps. D is bilinear (velocity products, forces
    # times rotation rates): from a rough guess the first step ignores those products,
    # so the residual may grow once before quadratic convergence (seen on the
    # slider–crank at dead centre). Full steps, no monotonicity test; the best iterate
    # is kept, and a trust-region solve is the fallback.
    best = (norm(g), u)
    for _ in range(max_iter // 4):
        if norm(g) <= tol:
            break
        it += 1
        u = u + np.linalg.lstsq(jacobian(u), -g, rcond=None)[0]
        g = fun(u)
        if not np.all(np.isfinite(g)):
            break
        if norm(g) < best[0]:
            best = (norm(g), u)
    g_best, u = best
    g = fun(u)
    if g_best > tol:
        sol = least_squares(fun, u, jac=jacobian, method="trf", xtol=1e-14, ftol=1e-14, gtol=1e-14,
                            max_nfev=max_iter * 10)
        u, g, it = sol.x, sol.fun, it + sol.nfev
    y, yp, z, w = unpack(u)
    f_final = residual_F(y, yp)
    d_final = g[m:]
    scale = max(1.0, float(np.abs(y).max(initial=0)))
    bad = np.flatnonzero(np.abs(f_final) > 1e3 * tol * scale)
    bad_d = np.flatnonzero(np.abs(d_final) > 1e-6 * scale)
    if len(bad) or len(bad_d):
        raise InconsistentInitialError(_explain(mod, f_final, d_final, bad, bad_d, fixed))
    chosen = {mod.VARIABLES[j]: float(y[j]) for j in dif if j not in fixed
              and mod.ROLES[j] != "energy" and abs(y[j] - values.get(j, 0.0)) > 1e-12 * scale}
    return InitialResult(y, yp, chosen, norm(g), it)


def _explain(mod, f, d, bad, bad_d, fixed) -> list[str]:
    jrows, jcols = np.asarray(mod.JAC_ROWS), np.asarray(mod.JAC_COLS)
    lines = []
    for rows, res, what in ((bad, f, "is violated"), (bad_d, d, "cannot hold: its time derivative is violated")):
        for i in rows[:8]:
            involved = sorted({mod.VARIABLES[j] for j in jcols[jrows == i] if j in fixed})
            fixed_txt = f" (fixed values involved: {', '.join(f'`{v}`' for v in involved)})" if involved else ""
            lines.append(f"equation `{mod.EQUATIONS[i]}` {what} by {res[i]:.3g} at t0{fixed_txt}")
    return lines
