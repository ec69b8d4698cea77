"""Watch the conditioning of the DAE iteration matrix during a run.

Near a configuration where an interconnection loses surjectivity (the seed's
Prop. "Interconnection through a finite-dimensional coupling space"; e.g. a slider–crank
whose guide direction becomes orthogonal to the rod) the constraint Jacobian becomes
rank deficient and so does the iteration matrix ``J = F_y + c_j F_ẏ`` for every step
size. A BDF code may then take tiny steps or return garbage. We evaluate J (with
``c_j = 1/h`` of the last step), equilibrate its rows and columns, and compute the
ratio of its extreme singular values; below :data:`THRESHOLD` the run stops with a
message naming the time and the equations that become dependent.
"""

from __future__ import annotations

from typing import Optional

import numpy as np
import scipy.linalg as sla

THRESHOLD = 1e-11
"""σ_min/σ_max of the equilibrated iteration matrix below which a run stops."""
MAX_SIZE = 120
"""Systems larger than this are not monitored (the dense SVD would dominate)."""


class SingularityMonitor:
    def __init__(self, mod, p, threshold: float = THRESHOLD):
        self.mod, self.p, self.threshold = mod, p, threshold
        self.rows, self.cols = np.asarray(mod.JAC_ROWS), np.asarray(mod.JAC_COLS)
        self.buf = np.zeros(len(self.rows))
        self.enabled = mod.N <= MAX_SIZE
        self.worst = 1.0

    def ratio(self, t, y, yp, h) -> tuple[float, np.ndarray]:
        n = self.mod.N
        self.mod.jacobian(t, y, yp, self.p, 1.0 / max(h, 1e-300), self.buf)
        J = np.zeros((n, n))
        J[self.rows, self.cols] = self.buf
        for _ in range(2):  # equilibrate rows and columns
            r = np.abs(J).max(axis=1)
            J /= np.where(r > 0, r, 1.0)[:, None]
            c = np.abs(J).max(axis=0)
            J /= np.where(c > 0, c, 1.0)[None, :]
        s = sla.svdvals(J)  # singular values only: the vectors are computed when needed
        ratio = float(s[-1] / s[0]) if s[0] > 0 else 0.0
        if ratio >= self.threshold:
            return ratio, None
        u, _, _ = np.linalg.svd(J)
        return ratio, u[:, -1]

    def check(self, t, y, yp, h) -> Optional[str]:
        """A message if the iteration matrix is nearly singular, else None."""
        if not self.enabled or h <= 0:
            return None
        ratio, u = self.ratio(t, y, yp, h)
        self.worst = min(self.worst, ratio)
        if ratio >= self.threshold:
            return None
        culprits = [self.mod.EQUATIONS[i] for i in np.argsort(-np.abs(u))[:4] if abs(u[i]) > 0.1]
        return (f"stopped at t = {t:.6g} near a singular configuration: the equations "
                f"{', '.join(f'`{c}`' for c in culprits)} become dependent (σ_min/σ_max = {ratio:.1e}); "
                "the interconnection loses surjectivity here, so the model is not a port-Hamiltonian "
                "system at this state (run `phc check` for the coupling certificate); results up to this time "
                "are kept")
