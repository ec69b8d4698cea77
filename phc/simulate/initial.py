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
        h = 1e-7 * max(1.0, abs(t0))
        Fp = np.zeros(m)
        Fm = np.zeros(m)
        mod.residual(t0 + h, y_, yp_, p, Fp)
        mod.residual(t0 - h, y_, yp_, p, Fm)
        return jy @ ydot + jyp @ w_ + (Fp - Fm) / (2 * h), jy, jyp

    def G(y_, yp_, z_, w_):
        d, _, _ = residual_D(y_, yp_, z_, w_)
        return np.concatenate([residual_F(y_, yp_), d])

    def norm(g):
        return float(np.abs(g).max(initial=0.0))

    it = 0
    g = G(y, yp, z, w)
    for it in range(1, max_iter + 1):
        if norm(g) <= tol:
            break
        _, jy, jyp = residual_D(y, yp, z, w)
        # Columns: [y_free | yp_diff | z_alg | w_diff]
        JF = sps.hstack([jy[:, free_y], jyp[:, dif], sps.csc_matrix((m, len(alg))),
                         sps.csc_matrix((m, len(dif)))]).toarray()
        JD = np.zeros((m, len(free_y) + len(dif) + len(alg) + len(dif)))
        base_d, _, _ = residual_D(y, yp, z, w)
        col = 0
        for j in free_y:  # finite differences of D in y (second-order terms)
            h = 1e-7 * max(1.0, abs(y[j]))
            yh = y.copy()
            yh[j] += h
            JD[:, col] = (residual_D(yh, yp, z, w)[0] - base_d) / h
            col += 1
        for j in dif:
            h = 1e-7 * max(1.0, abs(yp[j]))
            yph = yp.copy()
            yph[j] += h
            JD[:, col] = (residual_D(y, yph, z, w)[0] - base_d) / h
            col += 1
        JD[:, col:col + len(alg)] = jy[:, alg].toarray()
        col += len(alg)
        JD[:, col:] = jyp[:, dif].toarray()
        J = np.vstack([JF, JD])
        step = np.linalg.lstsq(J, -g, rcond=None)[0]
        alpha = 1.0
        g0 = norm(g)
        for _ in range(30):
            y2, yp2, z2, w2 = y.copy(), yp.copy(), z.copy(), w.copy()
            k = 0
            y2[free_y] += alpha * step[k:k + len(free_y)]
            k += len(free_y)
            yp2[dif] += alpha * step[k:k + len(dif)]
            k += len(dif)
            z2[alg] += alpha * step[k:k + len(alg)]
            k += len(alg)
            w2[dif] += alpha * step[k:k + len(dif)]
            g2 = G(y2, yp2, z2, w2)
            if norm(g2) < g0 or alpha < 1e-6:
                break
            alpha /= 2
        if norm(g2) >= g0 and alpha < 1e-6:
            break
        y, yp, z, w, g = y2, yp2, z2, w2, g2
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
