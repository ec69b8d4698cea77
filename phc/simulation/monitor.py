"""Watch the conditioning of the DAE iteration matrix during a run.

Near a configuration where an interconnection loses surjectivity (the paper's
Proposition 3 "Interconnection through a finite-dimensional coupling space";
e.g. a slider–crank
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


def describe_equations(compiled) -> dict[str, str]:
    """Readable names of the equations a monitor message may cite: a coupling row
    ``connections[k]…`` becomes the connection `a — b` with its place in the model file."""
    names = {}
    topology = getattr(compiled.dae, "topology", None)
    where = {}
    for a, b, label, span in getattr(topology, "connections", ()) or ():
        loc = f" ({span.file}:{span.line})" if span is not None else ""
        where[label] = f"connection `{a} — {b}`{loc}"
    for eq in compiled.dae.equations:
        head = eq.label.rsplit(".", 1)[0]  # `inner.connections[0]` of `inner.connections[0].f[0]`
        if head in where:
            names[eq.label] = f"{where[head]} row `{eq.label}`"
    return names


class SingularityMonitor:
    """Stops a run where the iteration matrix becomes numerically singular.

    ``check(t, y, yp, h)`` returns None or a message naming the time, the equations that
    become dependent (with the connections they belong to, from ``names``) and the
    condition that fails."""

    def __init__(self, mod, p, threshold: float = THRESHOLD, names: Optional[dict] = None):
        self.mod, self.p, self.threshold = mod, p, threshold
        self.names = dict(names or {})
        self.h_floor = 0.0
        """Steps shorter than this are looked at as if they were this long: an index-2
        iteration matrix is conditioned like h² however regular the configuration, and a
        BDF code starts (and restarts) with tiny steps. Integrators set it from the span."""
        self.rows, self.cols = np.asarray(mod.JAC_ROWS), np.asarray(mod.JAC_COLS)
        self.buf = np.zeros(len(self.rows))
        self.enabled = mod.N <= MAX_SIZE
        self.worst = 1.0
        self.stop_time: Optional[float] = None
        """Time of the configuration a warning is about (may precede the last look)."""
        self._looks: list[tuple] = []

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

    def check(self, t, y, yp, h, threshold: Optional[float] = None) -> Optional[str]:
        """A message if the iteration matrix is nearly singular, else None.

        `threshold` overrides :data:`THRESHOLD` for this look (a fixed-step solver whose
        Newton iteration already failed near the state uses a looser one)."""
        if not self.enabled or h <= 0:
            return None
        threshold = self.threshold if threshold is None else threshold
        h = max(h, self.h_floor)
        saved, self.threshold = self.threshold, threshold
        try:
            ratio, u = self.ratio(t, y, yp, h)
        finally:
            self.threshold = saved
        self.worst = min(self.worst, ratio)
        self._looks = [*self._looks[-2:], (t, np.array(y, dtype=float), np.array(yp, dtype=float), h, ratio)]
        if ratio >= threshold:
            return None
        return self._message(t, ratio, u, threshold)

    def watch(self, t, y, yp, h) -> Optional[str]:
        """:meth:`check` at a step of a variable-step solver, and between its looks.

        A solver whose steps stay smooth can step over a singular configuration: the
        singular set has measure zero and the conditioning near it falls off like a power
        of the distance, so a look lands close enough only by chance (in practice, when
        round-off in the initial state made the solver struggle there). When the last
        three looks bracket a local minimum of the conditioning, it is located along the
        cubic Hermite interpolant of the looked-at states (golden-section search) and
        checked there; the message then gives the time of the minimum (`stop_time`)."""
        warning = self.check(t, y, yp, h)
        if warning is not None or len(self._looks) < 3:
            self.stop_time = t if warning is not None else None
            return warning
        (t0, *_, r0), (t1, *_, r1), (t2, *_, r2) = self._looks
        if not (r1 < r0 and r1 < r2 and t0 < t1 < t2):
            return None
        best = self._minimize(t0, t2)
        if best is None:
            return None
        tm, ratio, u = best
        self.worst = min(self.worst, ratio)
        self.stop_time = tm
        return self._message(tm, ratio, u, self.threshold)

    def _state_at(self, t):
        """Cubic Hermite interpolation of (y, ẏ) between the last looks."""
        looks = self._looks
        i = 0 if t <= looks[1][0] else 1
        (ta, ya, ypa, _, _), (tb, yb, ypb, hb, _) = looks[i], looks[i + 1]
        d = tb - ta
        s = (t - ta) / d
        h00, h10, h01, h11 = 2 * s**3 - 3 * s**2 + 1, s**3 - 2 * s**2 + s, -2 * s**3 + 3 * s**2, s**3 - s**2
        y = h00 * ya + h10 * d * ypa + h01 * yb + h11 * d * ypb
        dh00, dh10, dh01, dh11 = 6 * s**2 - 6 * s, 3 * s**2 - 4 * s + 1, -6 * s**2 + 6 * s, 3 * s**2 - 2 * s
        yp = (dh00 * ya + dh01 * yb) / d + dh10 * ypa + dh11 * ypb
        return y, yp, hb

    def _minimize(self, a, b, iterations: int = 80):
        """(t, ratio, left singular vector) where the ratio falls below the threshold on
        [a, b], searching for its minimum; None if it stays above."""
        def f(t):
            y, yp, h = self._state_at(t)
            return self.ratio(t, y, yp, h)
        g = 0.5 * (np.sqrt(5.0) - 1.0)
        c, d = b - g * (b - a), a + g * (b - a)
        (fc, uc), (fd, ud) = f(c), f(d)
        for _ in range(iterations):
            for t, r, u in ((c, fc, uc), (d, fd, ud)):
                if u is not None:
                    return t, r, u
            if b - a <= 4 * np.finfo(float).eps * max(abs(a), abs(b)):
                break
            if fc < fd:
                b, d, fd, ud = d, c, fc, uc
                c = b - g * (b - a)
                fc, uc = f(c)
            else:
                a, c, fc, uc = c, d, fd, ud
                d = a + g * (b - a)
                fd, ud = f(d)
        return None

    def _message(self, t, ratio, u, threshold) -> str:
        culprits = [self.mod.EQUATIONS[i] for i in np.argsort(-np.abs(u))[:4] if abs(u[i]) > 0.1]
        connections = sorted({self.names[c].split(" row ")[0] for c in culprits if c in self.names})
        where = f" at {', '.join(connections)}" if connections else ""
        positional = [c for c in culprits if c in set(getattr(self.mod, "INVARIANTS", ()))]
        condition = (f"the gradients of the position constraints {', '.join(f'`{c}`' for c in positional)} are "
                     "linearly dependent" if len(positional) >= 2 else "their Jacobian rows are linearly dependent")
        return (f"stopped at t = {t:.6g} near a singular configuration: the equations "
                f"{', '.join(f'`{c}`' for c in culprits)} become dependent{where}. Condition: {condition} "
                f"(σ_min/σ_max of the equilibrated iteration matrix = {ratio:.1e} < {threshold:.0e}), so the "
                "coupling map loses surjectivity (e.g. a guide with a_s·t = 0: the rod perpendicular to the guide) "
                "and the model is not a port-Hamiltonian system at this state (run `phc check` for the coupling "
                "certificate); results up to this time are kept")


SMALL_STATE = 1e2
"""A state whose size is below this times `atol` is resolved to fewer than ~2 digits."""
ROUND_OFF = 1e4 * np.finfo(float).eps
"""States smaller than this times the largest one count as zero (round-off)."""
SPREAD = 1e8
"""States spanning more orders of magnitude than this strain a scalar `rtol`."""


def check_scales(mod, y0, yp0, span, rtol, atol, failed: bool = False) -> Optional[str]:
    """A conditioning warning when the model's states are badly scaled for the tolerances.

    The size of a differential variable is ``max(|y0|, |ẏ0|·span)``. States far below
    `atol` (a mass of 1e-9 kg moving at mm/s has momenta ~1e-12) are integrated without
    relative accuracy; states spanning many orders of magnitude, or an `rtol` close to
    machine precision, make the error test fail; these two are reported only with
    ``failed`` (a successful run was accurate despite them). None when nothing is found."""
    diff = np.asarray(mod.DIFFERENTIAL, dtype=bool).copy()
    names = list(mod.VARIABLES)
    if "energy.supplied" in names:
        diff[names.index("energy.supplied")] = False
    size = np.maximum(np.abs(y0), np.abs(yp0) * span)[diff]
    labels = [names[j] for j in np.flatnonzero(diff)]
    if not (size > 0).any():
        return None
    # values at round-off level of the largest state are zeros computed inexactly (a beam
    # starting straight has curvatures ~1e-12), not small states
    nonzero = size > ROUND_OFF * size.max()
    notes = []
    small = [(labels[i], size[i]) for i in np.flatnonzero(nonzero) if size[i] < SMALL_STATE * atol]
    if small:
        listed = ", ".join(f"`{n}` (~{s:.0e})" for n, s in small[:3])
        notes.append(f"states {listed} are below {SMALL_STATE:g}×atol = {SMALL_STATE * atol:.0e}, so they are "
                     "integrated without relative accuracy")
    big, tiny = size[nonzero].max(), size[nonzero].min()
    if failed and big > SPREAD * tiny:
        i_big, i_tiny = int(np.argmax(np.where(nonzero, size, -1))), int(np.argmin(np.where(nonzero, size, np.inf)))
        notes.append(f"the states span {big / tiny:.0e} in size (`{labels[i_big]}` ~{big:.0e}, "
                     f"`{labels[i_tiny]}` ~{tiny:.0e})")
    if failed and rtol < 1e-11:
        notes.append(f"rtol = {rtol:g} is close to machine precision")
    if not notes:
        return None
    return ("conditioning warning: " + "; ".join(notes) + ". Nondimensionalize the model (choose units in "
            "which the states are of order one) or set `atol` below the smallest state and `rtol` ≥ 1e-10")
