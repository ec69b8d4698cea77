"""Implicit midpoint rule for the pH-DAE ``F(t, y, ẏ) = 0`` (structure preserving).

One step solves ``F(t_n + h/2, (y_n + y_{n+1})/2, (y_{n+1} − y_n)/h) = 0`` for ``y_{n+1}``.
For a quadratic Hamiltonian the discrete energy balance
``H(y_{n+1}) − H(y_n) + h·(P_ports + P_diss)(midpoint) = 0`` holds exactly (to the Newton
tolerance), for any step size: ``H(y_{n+1}) − H(y_n) = ∇H(y_mid)·(y_{n+1} − y_n)`` for
quadratic H, and power-isotropy of the Dirac structure (seed, Def. of a Dirac structure and
Remark "Energy balance") at the one point ``y_mid`` where every row of F is evaluated —
modulations, constraints and multipliers included — does the rest. The energy accumulator
of the DAE is integrated by the same rule, so the reported balance residual is the discrete
one. Constraints are imposed at the midpoints; the position invariants are projected back
at the step ends (:class:`Projector`). Non-quadratic Hamiltonians: see
:mod:`phc.simulation.discrete_gradient`.

Linear algebra (why it is cheap)
--------------------------------
The Newton matrix of a step evaluated at ``s`` along the segment is
``s·F_y + F_ẏ/h = s·(F_y + c_j F_ẏ)`` with ``c_j = 1/(s h)``, i.e. the generated
``jacobian`` scaled by ``s``. It is factorized by sparse LU and *reused* across Newton
iterations and steps (simplified Newton, as in Radau IIA codes): a fresh Jacobian is
factorized only when the contraction rate of the iteration degrades
(:data:`REFACTOR_RATE`), when the step size changes, or after :data:`MAX_AGE` steps.
Exactness is unaffected: the residual is always evaluated exactly, so the converged step
is the same — only the iteration count changes.
"""

from __future__ import annotations

import time

import numpy as np
import scipy.sparse as sps
import scipy.sparse.linalg as spla

NEWTON_TOL = 1e-13
"""Newton stops when the estimated error ``θ/(1−θ)·|Δ|`` of the iterate is below this
(relative to ``|y| + 1``); stagnation at round-off level is accepted as well."""
MAX_NEWTON = 12
"""Iterations with one factorization before a refactorization is forced."""
REFACTOR_RATE = 0.25
"""Contraction rate θ = |Δ_k|/|Δ_{k−1}| above which the Newton matrix is refreshed."""
MAX_AGE = 200
"""Steps after which the Newton matrix is refreshed regardless (state-dependent Jacobians)."""


class NewtonMatrix:
    """Sparse LU of ``s·(F_y + c_j F_ẏ)`` with ``c_j = 1/(s h)``, cached between steps."""

    def __init__(self, mod, p):
        self.mod, self.p, self.n = mod, p, mod.N
        rows, cols = np.asarray(mod.JAC_ROWS), np.asarray(mod.JAC_COLS)
        # JAC_ROWS/JAC_COLS are in CSC order: build the structure once
        self.indices = rows.astype(np.int32)
        self.indptr = np.searchsorted(cols, np.arange(self.n + 1)).astype(np.int32)
        self.buf = np.zeros(len(rows))
        self.lu = None
        self.h = self.s = None
        self.age = 0
        self.factorizations = 0

    def factor(self, t, y, yp, h, s=0.5) -> bool:
        """Factorize at ``(t, y, yp)``; False if the matrix is singular."""
        self.mod.jacobian(t, y, yp, self.p, 1.0 / (s * h), self.buf)
        J = sps.csc_matrix((s * self.buf, self.indices, self.indptr), shape=(self.n, self.n))
        self.factorizations += 1
        try:
            self.lu = spla.splu(J)
        except RuntimeError:
            self.lu = None
            return False
        self.h, self.s, self.age = h, s, 0
        return True

    def stale(self, h, s) -> bool:
        return (self.lu is None or abs(h - self.h) > 1e-3 * h or abs(s - self.s) > 0.2
                or self.age >= MAX_AGE)

    def solve(self, rhs):
        return self.lu.solve(rhs)


class StageSolver:
    """Solves ``F(t + s h, y + s (y1 − y), (y1 − y)/h) = 0`` for ``y1`` by simplified Newton.

    ``s = 1/2`` is the implicit midpoint rule; the discrete-gradient step moves ``s``.
    """

    def __init__(self, mod, p):
        self.mod, self.p = mod, p
        self.matrix = NewtonMatrix(mod, p)
        self.res = np.zeros(mod.N)
        self.nfev = 0
        self.singular = False

    def solve(self, t, h, y, y1, s=0.5):
        """Return ``(y1, converged)``; ``self.singular`` tells a singular Newton matrix."""
        matrix, res, mod, p = self.matrix, self.res, self.mod, self.p
        self.singular = False
        start = y1.copy()
        y1 = y1.copy()
        fresh = False
        matrix.age += 1
        if matrix.stale(h, s):
            if not self._refactor(t, h, y, y1, s):
                return y1, False
            fresh = True
        last = theta = None
        it = 0
        while True:
            d = y1 - y
            mod.residual(t + s * h, y + s * d, d / h, p, res)
            self.nfev += 1
            delta = matrix.solve(-res)
            if not np.all(np.isfinite(delta)):
                size = np.inf
            else:
                size = float(np.abs(delta).max())
            scale = 1.0 + float(np.abs(y1).max())
            if last is not None and last > 0:
                theta = size / last
            if not np.isfinite(size) or (theta is not None and theta >= 1.0 and size > 1e3 * NEWTON_TOL * scale):
                # diverging: refresh the matrix at the start value and begin again
                if fresh:
                    return y1, False
                y1 = start.copy()
                if not self._refactor(t, h, y, y1, s):
                    return y1, False
                fresh, last, theta, it = True, None, None, 0
                continue
            y1 += delta
            it += 1
            if size <= NEWTON_TOL * scale * 1e-2:
                return y1, True
            if theta is not None:
                if theta < 1.0 and theta / (1.0 - theta) * size <= NEWTON_TOL * scale:
                    return y1, True
                if theta >= 0.5 and size <= 1e3 * NEWTON_TOL * scale:
                    return y1, True  # stagnating at round-off level: accept
            if theta is not None and theta > REFACTOR_RATE and not fresh or it >= MAX_NEWTON:
                if fresh and it >= MAX_NEWTON:
                    return y1, False
                if not self._refactor(t, h, y, y1, s):
                    return y1, False
                fresh, last, theta, it = True, None, None, 0
                continue
            last = size

    def _refactor(self, t, h, y, y1, s) -> bool:
        d = y1 - y
        ok = self.matrix.factor(t + s * h, y + s * d, d / h, h, s)
        self.singular = not ok
        return ok


class Projector:
    """Keeps the position invariants g(y) = 0 at the step ends (the midpoint rule imposes the
    constraints at the midpoints only): a minimum-norm Gauss–Newton correction of the
    differential variables g depends on. The invariant Jacobian G is computed by finite
    differences once and reused (a chord iteration) until the iteration contracts slowly.
    Energies that do not depend on those variables (kinetic energies, the beam's) are
    untouched, so the discrete energy balance stays exact; when H depends on them (a
    potential such as ``m g y``), see :class:`EnergyProjector`."""

    TOL = 1e-14

    def __init__(self, mod, p, y, t=0.0):
        self.mod, self.p = mod, p
        diff = np.flatnonzero(np.asarray(mod.DIFFERENTIAL))
        g0 = mod.invariants(t, y, p)
        cols = []
        for j in diff:  # the variables the invariants depend on (probe once)
            yh = y.copy()
            yh[j] += 1e-6 * max(1.0, abs(y[j]))
            if np.abs(mod.invariants(t, yh, p) - g0).max() > 0:
                cols.append(j)
        self.cols = np.array(cols, dtype=int)
        self.pinv = None
        self.updates = 0

    def _constraints(self, t, y):
        return self.mod.invariants(t, y, self.p)

    def _jacobian(self, t, y, g):
        G = np.empty((len(g), len(self.cols)))
        for c, j in enumerate(self.cols):
            h = 1e-7 * max(1.0, abs(y[j]))
            yh = y.copy()
            yh[j] += h
            G[:, c] = (self._constraints(t, yh) - g) / h
        return G

    def _refresh(self, t, y, g):
        self.pinv = np.linalg.pinv(self._jacobian(t, y, g), rcond=1e-12)
        self.updates += 1

    def project(self, t, y):
        if not len(self.cols):
            return y
        y = y.copy()
        last = np.inf
        fresh = False
        for _ in range(8):
            g = self._constraints(t, y)
            size = float(np.abs(g).max())
            if size <= self.TOL * (1.0 + float(np.abs(y[self.cols]).max())):
                break
            if self.pinv is None or (size > 0.1 * last and not fresh):
                self._refresh(t, y, g)
                fresh = True
            elif size > 0.1 * last:
                break  # round-off level reached
            y[self.cols] -= self.pinv @ g
            last = size
        return y


class EnergyProjector(Projector):
    """Projection onto ``{g(y) = 0, H(y) = H(ŷ)}`` for Hamiltonians that depend on the
    projected positions: the step end ŷ is moved (minimum norm, in the positions and the
    variables H depends on) so that the invariants hold *and* the stored energy is the one
    the step produced — the discrete energy balance stays exact while the constraints do not
    drift (the GGL formulation alone keeps them at the midpoints only)."""

    def __init__(self, mod, p, y, t=0.0):
        super().__init__(mod, p, y, t)
        h0 = mod.hamiltonian(t, y, p)
        extra = []
        for j in np.flatnonzero(np.asarray(mod.DIFFERENTIAL)):
            if j in self.cols or mod.VARIABLES[j] == "energy.supplied":
                continue
            yh = y.copy()
            yh[j] += 1e-6 * max(1.0, abs(y[j]))
            if mod.hamiltonian(t, yh, p) != h0:
                extra.append(j)
        self.cols = np.concatenate([self.cols, np.array(extra, dtype=int)]).astype(int)
        self.target = None

    @staticmethod
    def needed(mod, p, y, cols, t=0.0) -> bool:
        """Does H change with the variables the invariants depend on?"""
        h0 = mod.hamiltonian(t, y, p)
        for j in cols:
            yh = y.copy()
            yh[j] += 1e-6 * max(1.0, abs(y[j]))
            if abs(mod.hamiltonian(t, yh, p) - h0) > 1e-13 * (1.0 + abs(h0)):
                return True
        return False

    def _constraints(self, t, y):
        return np.append(self.mod.invariants(t, y, self.p), self.mod.hamiltonian(t, y, self.p) - self.target)

    def project(self, t, y):
        self.target = self.mod.hamiltonian(t, y, self.p)
        return super().project(t, y)


def make_projector(mod, p, y, t=0.0):
    """The projector the model needs, or None without position invariants."""
    if not len(getattr(mod, "INVARIANTS", ())):
        return None
    plain = Projector(mod, p, y, t)
    if EnergyProjector.needed(mod, p, y, plain.cols, t):
        return EnergyProjector(mod, p, y, t)
    return plain


def integrate_fixed_step(mod, p, t_out, y0, yp0, *, max_steps, progress, step, advance, name, project=True):
    """Fixed-step driver shared by the structure-preserving backends.

    ``advance(t, h, y, guess) -> (y1, ok, reason)`` takes one step. Output at every
    ``t_out`` (each output interval is split into equal steps no longer than ``step``).
    Returns the same dict as the IDA backend."""
    n = mod.N
    t_out = np.asarray(t_out, dtype=float)
    intervals = np.diff(t_out)
    ys, yps = np.empty((len(t_out), n)), np.empty((len(t_out), n))
    ys[0], yps[0] = y0, yp0
    start = time.process_time()
    y = np.array(y0, dtype=float)
    steps = 0
    ok, message = True, "integration finished"
    projector = make_projector(mod, p, y, float(t_out[0])) if project else None
    y_prev, h_prev = None, 1.0
    # Predictor: extrapolate the step midpoints m = (y_n + y_{n+1})/2, not the step ends —
    # algebraic variables (multipliers) of a midpoint rule oscillate about their midpoint
    # values from step end to step end, which ruins an extrapolation of the ends.
    mid, mid_slope = None, np.asarray(yp0, dtype=float)
    k = 0
    for k in range(1, len(t_out)):
        substeps = max(1, int(np.ceil(intervals[k - 1] / step - 1e-9))) if step else 1
        h = intervals[k - 1] / substeps
        t = t_out[k - 1]
        for _ in range(substeps):
            mid_guess = y + 0.5 * h * mid_slope if mid is None else mid + 0.5 * (h + h_prev) * mid_slope
            y_new, converged, reason = advance(t, h, y, 2.0 * mid_guess - y)
            if not converged:
                ok, message = False, f"{name}: {reason} at t = {t:.6g}; results up to this time are kept"
                break
            new_mid = 0.5 * (y + y_new)
            if mid is not None:
                mid_slope = (new_mid - mid) / (0.5 * (h + h_prev))
            mid = new_mid
            y_prev, h_prev = y, h
            y = projector.project(t + h, y_new) if projector else y_new
            t += h
            steps += 1
            if steps >= max_steps:
                ok, message = False, (f"stopped after {steps} steps at t = {t:.6g} (max_steps); raise `max_steps` "
                                      "or the step size")
                break
        if not ok:
            k -= 1
            break
        ys[k] = y
        yps[k] = (y - y_prev) / h_prev
        if progress is not None:
            progress(t)
    return dict(t=t_out[:k + 1], y=ys[:k + 1], yp=yps[:k + 1], steps=steps, success=ok, message=message,
                cpu=time.process_time() - start)


SINGULAR_HINT = ("singular Newton matrix; the model may be at a singular configuration (an interconnection "
                 "losing rank: run `phc check`) or of index > 1 in a way the rule cannot handle; try the `ida` solver")
NEWTON_HINT = "Newton did not converge; reduce `step` (simulation.step)"


def integrate_midpoint(mod, p, t_out, y0, yp0, *, rtol, atol, max_steps, progress=None, max_order=None,
                       step=None):
    """Fixed-step implicit midpoint from ``t_out[0]``; output at every ``t_out`` (each output
    interval is split into equal steps no longer than `step`). Returns the same dict as the
    IDA backend."""
    del rtol, atol, max_order  # a fixed-step method: accuracy is set by `step`
    stage = StageSolver(mod, p)

    def advance(t, h, y, guess):
        y1, ok = stage.solve(t, h, y, guess, 0.5)
        return y1, ok, (SINGULAR_HINT if stage.singular else NEWTON_HINT)

    out = integrate_fixed_step(mod, p, t_out, y0, yp0, max_steps=max_steps, progress=progress, step=step,
                               advance=advance, name="implicit midpoint")
    out.update(nfev=stage.nfev, njev=stage.matrix.factorizations)
    return out
