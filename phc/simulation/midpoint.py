"""Implicit midpoint rule for the pH-DAE ``F(t, y, ẏ) = 0`` (structure preserving).

One step solves ``F(t_n + h/2, (y_n + y_{n+1})/2, (y_{n+1} − y_n)/h) = 0`` for ``y_{n+1}``
by Newton's method; its Jacobian is ``½ (F_y + (2/h) F_ẏ)``, i.e. the generated
``jacobian`` with ``cj = 2/h``, factorized by sparse LU. For a quadratic Hamiltonian and a
constant (or state-independent) Dirac structure the discrete energy balance
``H(y_{n+1}) − H(y_n) + h·(P_ports + P_diss)(midpoint) = 0`` holds exactly (to the Newton
tolerance), for any step size: ``H(y_{n+1}) − H(y_n) = ∇H(y_mid)·(y_{n+1} − y_n)`` for
quadratic H, and power-isotropy of the Dirac structure at the midpoint does the rest. The
energy accumulator of the DAE is integrated by the same rule, so the reported balance
residual is the discrete one. Constraints are imposed at the midpoints; position drift at
the step ends is O(h²) and is reported.
"""

from __future__ import annotations

import time

import numpy as np
import scipy.sparse as sps
import scipy.sparse.linalg as spla

NEWTON_TOL = 1e-11
"""Newton stops when the scaled correction is below this (relative to |y| + 1)."""
MAX_NEWTON = 25


def integrate_midpoint(mod, p, t_out, y0, yp0, *, rtol, atol, max_steps, progress=None, max_order=None,
                       step=None):
    """Fixed-step implicit midpoint from ``t_out[0]``; output at every ``t_out`` (which must be a
    multiple of the step). Returns the same dict as the IDA backend."""
    del rtol, atol, max_order  # a fixed-step method: accuracy is set by `step`
    n = mod.N
    rows, cols = np.asarray(mod.JAC_ROWS), np.asarray(mod.JAC_COLS)
    buf = np.zeros(len(rows))
    res = np.zeros(n)
    t_out = np.asarray(t_out, dtype=float)
    intervals = np.diff(t_out)
    h_out = float(intervals.min()) if len(intervals) else 0.0
    substeps = max(1, int(np.ceil(h_out / step - 1e-9))) if step else 1
    ys, yps = np.empty((len(t_out), n)), np.empty((len(t_out), n))
    ys[0], yps[0] = y0, yp0
    start = time.process_time()
    y = np.array(y0, dtype=float)
    steps = nfev = njev = 0
    ok, message = True, "integration finished"
    projector = _Projector(mod, p, y) if len(getattr(mod, "INVARIANTS", ())) else None
    y_prev, h_prev = None, 1.0
    k = 1
    for k in range(1, len(t_out)):
        h = (t_out[k] - t_out[k - 1]) / substeps
        t = t_out[k - 1]
        for _ in range(substeps):
            slope = np.asarray(yp0, dtype=float) if y_prev is None else (y - y_prev) / h_prev
            y_new = y + h * slope  # predictor
            converged, last = False, np.inf
            for _it in range(MAX_NEWTON):
                mid, z = 0.5 * (y + y_new), (y_new - y) / h
                mod.residual(t + 0.5 * h, mid, z, p, res)
                nfev += 1
                mod.jacobian(t + 0.5 * h, mid, z, p, 2.0 / h, buf)
                njev += 1
                J = sps.csc_matrix((0.5 * buf, (rows, cols)), shape=(n, n))
                try:
                    delta = spla.splu(J).solve(-res)
                except RuntimeError:
                    ok, message = False, (f"implicit midpoint: singular Newton matrix at t = {t:.6g}; the model may be "
                                          "at a singular configuration or of index > 1 in a way the rule cannot "
                                          "handle; try the `ida` solver")
                    break
                y_new += delta
                size = float(np.abs(delta).max())
                if size <= NEWTON_TOL * (1.0 + np.abs(y_new).max()):
                    converged = True
                    break
                if _it >= 3 and size >= 0.5 * last and size <= 1e3 * NEWTON_TOL * (1.0 + np.abs(y_new).max()):
                    converged = True  # stagnating at round-off level: accept
                    break
                last = size
            if not ok:
                break
            if not converged:
                ok, message = False, (f"implicit midpoint: Newton did not converge at t = {t:.6g}; reduce `step` "
                                      "(simulation.step)")
                break
            y_prev, h_prev = y, h
            y = projector.project(t + h, y_new) if projector else y_new
            t += h
            steps += 1
            if steps >= max_steps:
                ok, message = False, f"stopped after {steps} steps at t = {t:.6g} (max_steps)"
                break
        if not ok:
            k -= 1
            break
        ys[k] = y
        yps[k] = (y - y_prev) / h_prev
        if progress is not None:
            progress(t)
    else:
        k = len(t_out) - 1
    return dict(t=t_out[:k + 1], y=ys[:k + 1], yp=yps[:k + 1], steps=steps, nfev=nfev, njev=njev, success=ok,
                message=message, cpu=time.process_time() - start)


class _Projector:
    """Keeps the position invariants g(y) = 0 at the step ends (the midpoint rule imposes the
    constraints at the midpoints only): a minimum-norm Gauss–Newton correction of the
    differential variables g depends on. Energies that do not depend on those variables
    (kinetic energies, the beam's) are untouched, so the discrete energy balance stays exact."""

    def __init__(self, mod, p, y):
        self.mod, self.p = mod, p
        diff = np.flatnonzero(np.asarray(mod.DIFFERENTIAL))
        g0 = mod.invariants(0.0, y, p)
        cols = []
        for j in diff:  # the variables the invariants depend on (probe once)
            yh = y.copy()
            yh[j] += 1e-6 * max(1.0, abs(y[j]))
            if np.abs(mod.invariants(0.0, yh, p) - g0).max() > 0:
                cols.append(j)
        self.cols = np.array(cols, dtype=int)

    def project(self, t, y):
        if not len(self.cols):
            return y
        y = y.copy()
        for _ in range(3):
            g = self.mod.invariants(t, y, self.p)
            if np.abs(g).max() <= 1e-14 * (1.0 + np.abs(y[self.cols]).max()):
                break
            G = np.empty((len(g), len(self.cols)))
            for c, j in enumerate(self.cols):
                h = 1e-7 * max(1.0, abs(y[j]))
                yh = y.copy()
                yh[j] += h
                G[:, c] = (self.mod.invariants(t, yh, self.p) - g) / h
            y[self.cols] -= np.linalg.lstsq(G, g, rcond=None)[0]
        return y
