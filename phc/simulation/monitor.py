"""Watch the conditioning of the DAE iteration matrix during a run.

Near a configuration where an interconnection loses surjectivity (the paper's
Proposition 3 "Interconnection through a finite-dimensional coupling space";
e.g. a slider–crank
whose guide direction becomes orthogonal to the rod) the constraint Jacobian becomes
rank deficient and so does the iteration matrix ``J = F_y + c_j F_ẏ`` for every step
size. A BDF code may then take tiny steps or return garbage. We evaluate J (with
``c_j = 1/h`` of the last step), equilibrate its rows and columns, and compute the
ratio of its extreme singular values; below :data:`THRESHOLD` — at the step h *and* at a
step :data:`STEP_SPREAD` times longer — the run stops with a message naming the time and the
equations that become dependent.

Why two steps: a rank drop of the coupling makes J singular for every step size, but J can
also be ill-conditioned only because of the step. A stiff circuit in SI units (the transistor
amplifier of the Bari test set for IVP solvers: conductances of 1e-4 S against C/h = 3e-6 F /
1e-8 s) gives σ_min/σ_max ∝ h — 5e-13 at h = 1e-8 s, 5e-10 at 1e-5 s — and the same circuit in
ms, kΩ, µF and mA is equilibrated differently and passed: a verdict that depended on the
units. The folding slider–crank's ratio stays 6e-9 from h = 1e-10 to 1e-4 s.

The module is over 800 lines because the diagnosis of a failed run (:func:`diagnose_failure`,
from the module's second half on) asks the monitor's own questions — the two-step ratio, the
golden-section search, the message that names the dependent equations — at the failure point
and ahead of it (:func:`singular_ahead`); kept together, there is one definition of a singular
configuration for the run and for its diagnosis.
"""

from __future__ import annotations

import math
from collections import deque
from typing import Optional

import numpy as np
import scipy.linalg as sla
import scipy.sparse as sps

from phc.errors import ModelEvaluationError
from phc.simulation.equilibrate import equilibrate
from phc.simulation.sparse_lu import csc_structure, inverse_norm_estimate, sparse_lu
from phc.simulation.look_cadence import (MINIMUM_XTOL, SEARCH_ITERATIONS, LookWork, brackets_minimum, hermite,  # noqa: F401
                                       run_golden_search)

HISTORY = 64
"""Most looks the monitor keeps for a failure's diagnosis."""
HISTORY_BYTES = 64 * 2**20
"""Most memory the kept looks take (each a copy of y and ẏ): a large model keeps fewer of them,
at least :data:`HISTORY_MIN` (a mesh of 8·10⁵ unknowns kept 64 looks of 12.8 MB each, 820 MB
more than its run needs; up to 65 536 unknowns the 64 looks fit)."""
HISTORY_MIN = 4
"""Fewest looks kept: the diagnosis compares the conditioning at four of them (:func:`phc.simulation.ida._approaching_singularity`)."""


def history_length(n: int) -> int:
    """How many looks a monitor of `n` unknowns keeps (:data:`HISTORY`, :data:`HISTORY_BYTES`)."""
    return int(min(HISTORY, max(HISTORY_MIN, HISTORY_BYTES // (16 * max(n, 1)))))
THRESHOLD = 1e-11
"""σ_min/σ_max of the equilibrated iteration matrix below which a run stops."""
STEP_SPREAD = 1e3
"""A look that finds the iteration matrix nearly singular at the step h looks again at
``STEP_SPREAD·h``: a singular configuration is singular at both, an ill-conditioning that the
step makes (∝ h, or h² for index 2) is gone at the longer one."""
MAX_SIZE = 10**7
"""Systems larger than this are not monitored (a switch: tests and benchmarks set it to 0 to run
without the monitor)."""
DENSE_SIZE = 120
"""Systems up to this size are looked at with dense linear algebra (LAPACK's condition estimate,
then the SVD); larger ones through a sparse LU of the same equilibrated matrix
(:func:`_sparse_ratio`), whose cost grows with its nonzeros and fill rather than with N³: the
dense look of the N four-bar with 40 loops (643 unknowns) cost more than the steps between two
looks, and the passages of models above this size went unchecked (docs/hard-cases.md)."""
INVERSE_STEPS = 40
"""Most steps of the inverse iteration of :func:`_sparse_ratio` (σ_min and its left singular vector)."""
INVERSE_RTOL = 1e-3
"""The inverse iteration stops once its estimate of σ_min changes by less than this fraction in a
step (it decides against thresholds orders of magnitude apart)."""
POWER_STEPS = 30
"""Most steps of the power iteration of :func:`_sparse_ratio` for σ_max (of an equilibrated matrix:
between 1 and the square root of its nonzeros, found to 1e-3 in a few steps)."""
RCOND_MARGIN = 1e3
"""A look computes singular values only when LAPACK's 1-norm condition estimate (``dgecon``
on an LU, a fraction of the SVD's cost) is within this factor (times N) of the threshold:
σ_max/σ_min ≤ N·κ₁, and the estimate is within a small factor of κ₁ in practice. Farther
out the look returns the estimate's bound ``1/(N·κ₁)`` (as the compiled step loop does)."""


def state_mask(mod) -> np.ndarray:
    """The differential variables that are states of the model: all but the energy supplied
    (``energy.supplied``, which integrates the ports' power and is no state of any component)."""
    return np.asarray(mod.DIFFERENTIAL, dtype=bool) & (np.asarray(mod.VARIABLES) != "energy.supplied")


def describe_equations(compiled) -> dict[str, str]:
    """Readable names of the equations a monitor message may cite: a coupling row
    ``connections[k]…`` becomes the connection `a — b` with its place in the model file."""
    names = {}
    where = {}
    for c in compiled.description.connections:
        loc = f" ({c.span.file}:{c.span.line})" if c.span is not None else ""
        where[c.label] = f"connection `{c.a} — {c.b}`{loc}"
    for eq in compiled.description.equations:
        head = eq.label.rsplit(".", 1)[0]  # `inner.connections[0]` of `inner.connections[0].f[0]`
        if head in where:
            names[eq.label] = f"{where[head]} row `{eq.label}`"
    return names


def _equilibrate(J: np.ndarray) -> np.ndarray:
    """J with rows, then columns, scaled to largest entry 1, twice
    (:func:`phc.simulation.equilibrate.equilibrate`, LAPACK's ``dgeequ``); a zero row or
    column keeps its scale 1."""
    return equilibrate(J, rounds=2)[0]


def _far_from_singular(J: np.ndarray, threshold: float, lu=None, solve=None) -> Optional[float]:
    """``1/(n·κ̂₁)`` of the equilibrated matrix J from LAPACK's condition estimate when that is
    :data:`RCOND_MARGIN`·n times above `threshold` (about a lower bound of σ_min/σ_max there);
    None when the singular values must decide. For a sparse J, `lu` is its sparse LU
    (``scipy.sparse.linalg.splu``) and ‖J⁻¹‖₁ is estimated on it by Higham's block 1-norm
    estimator (:func:`phc.simulation.sparse_lu.inverse_norm_estimate`, with its own seeded
    generator; ``dgecon`` runs Hager's and Higham's
    estimator on the dense LU): a few solves with the LU and its transpose (`solve`, ``lu.solve``
    or one that counts them)."""
    n = J.shape[0]
    if lu is not None:
        import scipy.sparse.linalg as spla

        solve = solve or lu.solve
        inverse = spla.LinearOperator((n, n), matvec=solve, rmatvec=lambda x: solve(x, trans="T"),
                                      dtype=float)
        with np.errstate(all="ignore"):
            estimate = inverse_norm_estimate(inverse)  # the same in every process
            rcond = 1.0 / (float(abs(J).sum(axis=0).max()) * estimate) if estimate > 0 else math.nan
    else:
        lu, _, info = sla.lapack.dgetrf(J)
        if info != 0:
            return None
        rcond, info = sla.lapack.dgecon(lu, float(np.abs(J).sum(axis=0).max()), norm="1")
        if info != 0:
            return None
    return clear_ratio(rcond, threshold, n)


def clear_ratio(rcond: float, threshold: float, n: int) -> Optional[float]:
    """``rcond/n`` where the condition estimate `rcond` clears a look (:data:`RCOND_MARGIN`·n times
    above `threshold`), else None: the singular values must decide."""
    if not np.isfinite(rcond) or rcond < threshold * n * RCOND_MARGIN:
        return None
    return float(rcond) / n


def _sparse_ratio(J, threshold: float, vectors: bool = True,
                  tally: Optional[LookWork] = None) -> tuple[float, Optional[np.ndarray]]:
    """``(σ_min/σ_max, u)`` of the equilibrated sparse matrix J (CSC), as the dense look computes
    them (:meth:`SingularityMonitor._ratio_at`) but from one sparse LU: the condition estimate
    first (:func:`_far_from_singular`), then σ_min by inverse iteration on ``(J Jᵀ)⁻¹`` (two
    solves with the LU a step, from a fixed start; its estimate ``1/‖J⁻¹x‖`` is never below
    σ_min, and near a rank drop, where σ_min is far below the next singular value, it converges
    in a few steps) and σ_max by power iteration on ``JᵀJ``. `u` (the iterate: the left singular
    vector of σ_min, or of the cluster of small ones where a rank drop loses several at once)
    where the ratio is below `threshold`, else None; an empty array without `vectors`. A matrix
    SuperLU finds exactly singular has ratio 0 and u from a dense SVD (where
    :data:`DIAGNOSE_MAX` allows; else a zero vector, which names no rows). `tally` counts the
    look's work (:class:`~phc.simulation.look_cadence.LookWork`: the LU, its solves, the products)."""
    import scipy.sparse.linalg as spla

    n = J.shape[0]
    J = sps.csc_matrix(J)
    work = {"solves": 0, "products": 0, "lu": None}
    try:
        return _sparse_look(J, n, threshold, vectors, work, spla)
    finally:
        if tally is not None:
            tally.sparse(J.nnz, lu=work["lu"], solves=work["solves"], products=work["products"])


def _sparse_look(J, n, threshold, vectors, work, spla):
    """:func:`_sparse_ratio`'s look, its LU, solves and products counted in `work`."""
    try:
        if not np.all(np.isfinite(J.data)):
            raise ValueError("not finite")
        lu = sparse_lu(J)
    except (RuntimeError, ValueError):
        if not vectors:
            return 0.0, np.empty(0)
        if n <= DIAGNOSE_MAX and np.all(np.isfinite(J.data)):
            u, _, _ = np.linalg.svd(J.toarray())
            return 0.0, u[:, -1]
        return 0.0, np.zeros(n)
    work["lu"] = lu

    def solve(x, trans="N"):
        work["solves"] += 1
        return lu.solve(x, trans=trans)

    rough = _far_from_singular(J, threshold, lu, solve)
    if rough is not None:
        return rough, None
    rng = np.random.default_rng(0)  # the same look every time
    v = rng.standard_normal(n)
    v /= np.linalg.norm(v)
    big = 0.0
    for _ in range(POWER_STEPS):
        work["products"] += 2
        w = J.T @ (J @ v)
        norm = float(np.linalg.norm(w))
        if not norm > 0:
            break
        v, before, big = w / norm, big, math.sqrt(norm)
        if abs(big - before) <= INVERSE_RTOL * big:
            break
    x = rng.standard_normal(n)
    x /= np.linalg.norm(x)
    small = math.inf
    with np.errstate(all="ignore"):
        for _ in range(INVERSE_STEPS):
            w = solve(x)  # J w = x: ‖w‖ ≤ 1/σ_min
            norm = float(np.linalg.norm(w))
            if not np.isfinite(norm):
                break
            before, small = small, (1.0 / norm if norm > 0 else math.inf)
            z = solve(w, trans="T")  # Jᵀ z = w: z = (J Jᵀ)⁻¹ x
            norm = float(np.linalg.norm(z))
            if not (np.isfinite(norm) and norm > 0):
                break
            x = z / norm
            if abs(small - before) <= INVERSE_RTOL * small:
                break
    ratio = small / big if big > 0 and np.isfinite(small) else 0.0
    if ratio >= threshold:
        return ratio, None
    return ratio, (x if vectors else np.empty(0))


def _search_below(f, a, b, threshold, iterations: int = SEARCH_ITERATIONS, fa=None, fb=None,
                  minimum: bool = False):
    """(t, ratio, u) where ``f: t -> (ratio, u)`` (u None while the ratio is at or above
    `threshold`) falls below `threshold` on [a, b], by golden-section search for its minimum;
    None if it stays above. The first point found below is returned, or with `minimum` the
    least point found once the bracket is :data:`MINIMUM_XTOL` of its place (where a rank
    drop lies, not only that one does).

    The search stops early at a smooth minimum well above the threshold: near a
    singular configuration the ratio falls to zero like a power (≥ 1) of the distance,
    so below the two inner points it can fall by at most the bracket's width times the
    steepest slope between the four points (`fa`, `fb`: the ratios at `a` and `b`);
    when twice that still leaves the smaller inner value above the threshold, it does
    not fall below it (a smooth minimum flattens as the bracket shrinks, a V does not).
    The search itself is :func:`phc.simulation.look_cadence.golden_search` (which the native IDA
    driver runs in C)."""
    vectors = {}

    def ratio_at_time(ws, t):
        ratio, u = f(t)
        if u is not None:
            vectors[t] = u
        return ratio, u is not None, False

    found, t, ratio = run_golden_search(ratio_at_time, a, b, threshold, iterations,
                                        math.nan if fa is None else fa, math.nan if fb is None else fb, minimum)
    return (t, ratio, vectors[t]) if found == 1 else None


class SingularityMonitor:
    """Stops a run where the iteration matrix becomes numerically singular.

    ``check(t, y, yp, h)`` returns None or a message naming the time, the equations that
    become dependent (with the connections they belong to, from ``names``) and the
    condition that fails."""

    def __init__(self, mod, p, threshold: float = THRESHOLD, names: Optional[dict] = None, scales=None,
                 count_factors: bool = False):
        self.mod, self.p, self.threshold = mod, p, threshold
        self.scales = None if scales is None else np.asarray(scales, dtype=float)
        """Nominal scales of the variables (:mod:`phc.simulation.scaling`), kept for the
        failure diagnosis. The rank test itself equilibrates rows and columns (D_r J D_c with
        D_c found from J, not from the scales: a state at rest has only its unit as a scale,
        and prescaling its column by it made a straight beam at rest look singular)."""
        self.names = dict(names or {})
        self.h_floor = 0.0
        """Steps shorter than this are looked at as if they were this long: an index-2
        iteration matrix is conditioned like h² however regular the configuration, and a
        BDF code starts (and restarts) with tiny steps. Integrators set it from the span."""
        self.rows, self.cols = np.asarray(mod.JAC_ROWS), np.asarray(mod.JAC_COLS)
        self.buf = np.zeros(len(self.rows)) if mod.N <= DENSE_SIZE else None
        """The Jacobian's entries of a dense look (a sparse look hands its own array to its matrix)."""
        self._csc: Optional[tuple] = None
        """The iteration matrix's CSC structure (:func:`~phc.simulation.sparse_lu.csc_structure`),
        made at the first sparse look."""
        self.enabled = mod.N <= MAX_SIZE
        self.worst = 1.0
        self.stop_time: Optional[float] = None
        """Time of the configuration a warning is about (may precede the last look)."""
        self.start: Optional[tuple] = None
        """(t₀, y₀, ẏ₀) of the run, kept for the failure diagnosis (:func:`unbounded_growth`);
        the integrators set it."""
        self.positional = False
        """Whether the last warning is a rank drop of the position constraints' gradients (two or
        more of the rows that become dependent are position invariants): the case a fixed-step
        solver may pass through (:func:`phc.simulation.midpoint.passes_rank_drop`)."""
        self._looks: list[tuple] = []
        self.rcond = None
        """``rcond(t, y, ẏ, h)``, the condition estimate of the equilibrated iteration matrix made
        elsewhere, or None: the native IDA driver's, in C (:mod:`phc.simulation.ida_native`), which a
        dense look asks first (:meth:`_ratio_at`: where it clears the look, no LU or SVD here)."""
        self.tally = LookWork(factors=count_factors)
        """The work of the looks, counted (what the IDA step hook's cadence weighs against the steps':
        :mod:`phc.simulation.look_cadence`; with `count_factors` the sparse LU's fill and operations
        as well, which only that hook reads)."""
        self.history: deque = deque(maxlen=history_length(mod.N))
        """(t, y, ẏ) of the last :func:`history_length` looks (a failure's diagnosis: is the
        conditioning falling toward a singular configuration?)."""

    def forget(self) -> None:
        """Drop the looks (the run starts again from its start)."""
        self._looks = []
        self.history.clear()
        self.stop_time = None

    def ratio(self, t, y, yp, h, vectors: bool = True) -> tuple[float, np.ndarray]:
        """σ_min/σ_max of the equilibrated iteration matrix at the step h; when that is below
        the threshold, the larger of it and its value at :data:`STEP_SPREAD`·h (a singular
        configuration is singular at both). With it the left singular vector of the smallest
        singular value at h when both are below the threshold, else None (without `vectors`:
        an empty array instead of the vector, which a dense SVD with vectors costs)."""
        ratio, u = self._ratio_at(t, y, yp, h, vectors)
        if u is None:
            return ratio, None
        longer, _ = self._ratio_at(t, y, yp, STEP_SPREAD * h, vectors=False)
        if longer >= self.threshold:
            return longer, None
        return max(ratio, longer), u

    def _equilibrated(self, t, y, yp, h) -> np.ndarray:
        """The iteration matrix ``F_y + F_ẏ/h`` at (t, y, ẏ), equilibrated (:func:`_equilibrate`)."""
        n = self.mod.N
        self.mod.jacobian(t, y, yp, self.p, 1.0 / max(h, 1e-300), self.buf)
        J = np.zeros((n, n))
        J[self.rows, self.cols] = self.buf
        return _equilibrate(J)

    def _equilibrated_sparse(self, t, y, yp, h):
        """:meth:`_equilibrated` as a sparse (CSC) matrix."""
        n = self.mod.N
        if self._csc is None:
            self._csc = csc_structure(self.rows, self.cols, n)
        indices, indptr, col_of = self._csc
        data = np.empty(len(self.rows))  # the matrix's own: nothing of a mesh's size kept between looks
        self.mod.jacobian(t, y, yp, self.p, 1.0 / max(h, 1e-300), data)
        J = sps.csc_matrix((data, indices, indptr), shape=(n, n))
        return equilibrate(J, rounds=2, overwrite=True, col_of=col_of)[0]

    def _ratio_at(self, t, y, yp, h, vectors: bool = True) -> tuple[float, np.ndarray]:
        n = self.mod.N
        if n > DENSE_SIZE:
            return _sparse_ratio(self._equilibrated_sparse(t, y, yp, h), self.threshold, vectors, self.tally)
        if self.rcond is not None:
            rough = clear_ratio(self.rcond(t, y, yp, h), self.threshold, n)
            if rough is not None:
                self.tally.dense(n)
                return rough, None
        J = self._equilibrated(t, y, yp, h)
        rough = _far_from_singular(J, self.threshold)
        if rough is not None:
            self.tally.dense(n)
            return rough, None
        s = np.linalg.svd(J, compute_uv=False)  # singular values only: the vectors are computed when needed
        ratio = float(s[-1] / s[0]) if s[0] > 0 else 0.0
        if ratio >= self.threshold or not vectors:
            self.tally.dense(n, svd=1)
            return ratio, (None if ratio >= self.threshold else np.empty(0))
        self.tally.dense(n, svd=1, vectors=True)
        u, _, _ = np.linalg.svd(J)
        return ratio, u[:, -1]

    def weakest(self, t, y, yp, h, threshold: float):
        """``(ratio, u)`` of the iteration matrix at this state and step, `u` the left singular
        vector of its smallest singular value where the ratio is below `threshold` (else None);
        None where the equations cannot be evaluated there. What the IDA driver asks near a rank
        drop (:mod:`phc.simulation.ida`, :mod:`phc.simulation.ida_bridge`)."""
        saved, self.threshold = self.threshold, threshold
        try:
            return self._ratio_at(t, y, yp, h)
        except (ArithmeticError, ValueError, TypeError, np.linalg.LinAlgError, ModelEvaluationError):
            return None
        finally:
            self.threshold = saved

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
        self._record(t, np.array(y, dtype=float), np.array(yp, dtype=float), h, ratio)
        if ratio >= threshold:
            return None
        return self._message(t, ratio, u, threshold)

    def _record(self, t, y, yp, h, ratio) -> None:
        """Keep a look: the worst ratio, the last three looks, the history."""
        self.worst = min(self.worst, ratio)
        self._looks = [*self._looks[-2:], (t, y, yp, h, ratio)]
        self._remember(self._looks[-1][:3])

    def routine_looks(self, ts, ys, yps, hs, ratios) -> None:
        """Looks made elsewhere that found the matrix clearly far from singular — the native IDA
        driver's routine looks in C (:mod:`phc.simulation.ida_native`): at times `ts`, states `ys`,
        `yps` (rows, kept: not copied), steps `hs` (the floor applied) and ratios `ratios`
        (``1/(n κ̂₁)``, as :func:`_far_from_singular` gives), kept as :meth:`watch` keeps its own
        looks that find nothing."""
        n = self.mod.N
        for i, t in enumerate(ts):
            self.tally.dense(n)
            self._record(t, ys[i], yps[i], hs[i], ratios[i])
        if len(self._looks) < 3:
            self.stop_time = None

    @property
    def last_ratio(self) -> float:
        """σ_min/σ_max of the last look (``inf`` before the first)."""
        return self._looks[-1][4] if self._looks else math.inf

    def _remember(self, look) -> None:
        """Add a look to :attr:`history`, which keeps its reach into the past: once full, a look
        less than a quarter of the window's mean spacing after the look before the last
        replaces the last (a solver crawling toward a failure with ever shorter steps otherwise
        fills the window with the last microseconds, and the fall of the conditioning on the
        way there, which the failure's diagnosis reads, is lost). Looks that come steadily
        often fill the window at their own pace, so it always ends at the newest look."""
        history = self.history
        if len(history) == history.maxlen:
            spacing = (look[0] - history[0][0]) / history.maxlen
            # measured from the look before the last: measured from the last one (which each
            # replacement moves along), a solver looking often for long froze the window
            # where its looks became dense, and its end, the approach, was lost
            if look[0] - history[-2][0] < 0.25 * spacing:
                history[-1] = look
                return
        history.append(look)

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
        if not brackets_minimum(t0, r0, t1, r1, t2, r2):
            return None
        best = self._minimize(t0, t2, fa=r0, fb=r2)
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
        y, yp = np.empty(len(ya)), np.empty(len(ya))
        hermite(ta, ya, ypa, tb, yb, ypb, t, y, yp)  # (phc.simulation.look_cadence: the native driver's too)
        return y, yp, hb

    def _minimize(self, a, b, iterations: int = SEARCH_ITERATIONS, fa=None, fb=None):
        """(t, ratio, left singular vector) where :meth:`ratio` along the cubic Hermite
        interpolant of the last looks (:meth:`_state_at`) falls below the threshold on [a, b]
        (:func:`_search_below`); None if it stays above."""
        def f(t):
            y, yp, h = self._state_at(t)
            return self.ratio(t, y, yp, h)
        return _search_below(f, a, b, self.threshold, iterations, fa, fb)

    def dependent(self, u) -> tuple[list, list]:
        """(equations, connections) that become dependent along the left singular vector `u` of
        the smallest singular value: the rows with the largest weights in it, and the connections
        they belong to (from ``names``)."""
        culprits = [self.mod.EQUATIONS[i] for i in np.argsort(-np.abs(u))[:4] if abs(u[i]) > 0.1]
        connections = sorted({self.names[c].split(" row ")[0] for c in culprits if c in self.names})
        return culprits, connections

    def _dependence(self, u) -> tuple[str, str, str]:
        """(the equations of the weak direction u, the connections they belong to, the
        condition that fails) as a message says them; sets :attr:`positional`."""
        culprits, connections = self.dependent(u)
        where = f" at {', '.join(connections)}" if connections else ""
        positional = [c for c in culprits if c in set(getattr(self.mod, "INVARIANTS", ()))]
        self.positional = len(positional) >= 2
        condition = (f"the gradients of the position constraints {', '.join(f'`{c}`' for c in positional)} are "
                     "linearly dependent" if len(positional) >= 2 else "their Jacobian rows are linearly dependent")
        return ", ".join(f"`{c}`" for c in culprits), where, condition

    def _message(self, t, ratio, u, threshold) -> str:
        equations, where, condition = self._dependence(u)
        return (f"stopped at t = {t:.6g} near a singular configuration: the equations "
                f"{equations} become dependent{where}. Condition: {condition} "
                f"(σ_min/σ_max of the equilibrated iteration matrix = {ratio:.1e} < {threshold:.0e}), so the "
                f"{SURJECTIVITY} at this state (run `phc check` for the coupling certificate); results up to this "
                "time are kept")


SURJECTIVITY = ("coupling map loses surjectivity (e.g. a guide with a_s·t = 0: the rod perpendicular to the guide) "
                "and the model is not a port-Hamiltonian system")
"""What a rank drop of the coupling means (the paper's Proposition 3), as messages say it."""


SMALL_STATE = 1e2
"""A state whose size is below this times `atol` is resolved to fewer than ~2 digits."""
ROUND_OFF = 1e4 * np.finfo(float).eps
"""States smaller than this times the largest one count as zero (round-off)."""
SPREAD = 1e8
"""States spanning more orders of magnitude than this strain a scalar `rtol`."""


def check_scales(mod, y0, yp0, span, rtol, atol, failed: bool = False, scales=None) -> Optional[str]:
    """A conditioning warning when the model's states are badly scaled for the tolerances.

    `y0`, `yp0` are the start, or the states computed so far (one row per output time):
    the check runs on the whole run, so a system at rest at t₀ whose states grow later is
    not reported as tiny. The size of a differential variable is ``max(max_t |y|, |ẏ0|·span)``
    (the rate at the start stands in for the motion a short run has not shown). States far below
    `atol` (a mass of 1e-9 kg moving at mm/s has momenta ~1e-12) are integrated without
    relative accuracy; states spanning many orders of magnitude, or an `rtol` close to
    machine precision, make the error test fail; these two are reported only with
    ``failed`` (a successful run was accurate despite them). None when nothing is found.

    With nominal `scales` (:mod:`phc.simulation.scaling`) the absolute tolerance of state j
    is ``atol·s_j``: a state is small only against its own scale (a nominal set far above
    what the state reaches), and states of different sizes no longer strain the error test,
    so the spread is not reported."""
    diff = state_mask(mod)
    names = list(mod.VARIABLES)
    ys, yps = np.atleast_2d(np.asarray(y0, dtype=float)), np.atleast_2d(np.asarray(yp0, dtype=float))
    size = np.maximum(np.abs(ys).max(axis=0), np.abs(yps[0]) * span)[diff]
    labels = [names[j] for j in np.flatnonzero(diff)]
    if not (size > 0).any():
        return None
    # values at round-off level of the largest state are zeros computed inexactly (a beam
    # starting straight has curvatures ~1e-12), not small states
    nonzero = size > ROUND_OFF * size.max()
    notes = []
    if scales is not None:
        tol = atol * np.asarray(scales, dtype=float)[diff]
        # scales the round-off floor set (phc.simulation.scaling, step 9) are as fine as
        # double precision allows: a state below them (a clamped end's momentum) is not news
        floored = getattr(scales, "floored", None)
        floored = np.zeros(len(diff), dtype=bool) if floored is None else np.asarray(floored, dtype=bool)
        nonzero = nonzero & ~floored[diff]
        small = [(labels[i], size[i], tol[i]) for i in np.flatnonzero(nonzero) if size[i] < SMALL_STATE * tol[i]]
        if small:
            listed = ", ".join(f"`{n}` (~{s:.0e}, nominal scale {t / atol:.0e})" for n, s, t in small[:3])
            notes.append(f"states {listed} stay below {SMALL_STATE:g}×atol times their nominal scale, so they are "
                         "integrated without relative accuracy")
    else:
        small = [(labels[i], size[i]) for i in np.flatnonzero(nonzero) if size[i] < SMALL_STATE * atol]
        if small:
            listed = ", ".join(f"`{n}` (~{s:.0e})" for n, s in small[:3])
            notes.append(f"states {listed} are below {SMALL_STATE:g}×atol = {SMALL_STATE * atol:.0e}, so they are "
                         "integrated without relative accuracy")
    big, tiny = (size[nonzero].max(), size[nonzero].min()) if nonzero.any() else (0.0, 0.0)
    if failed and scales is None and big > SPREAD * tiny:
        i_big, i_tiny = int(np.argmax(np.where(nonzero, size, -1))), int(np.argmin(np.where(nonzero, size, np.inf)))
        notes.append(f"the states span {big / tiny:.0e} in size (`{labels[i_big]}` ~{big:.0e}, "
                     f"`{labels[i_tiny]}` ~{tiny:.0e})")
    if failed and rtol < 1e-11:
        notes.append(f"rtol = {rtol:g} is close to machine precision")
    if not notes:
        return None
    if scales is not None:
        return ("conditioning warning: " + "; ".join(notes) + ". Set `simulation.nominal` of these states to "
                "their typical size (or lower `atol`, which is relative to the nominal scales), and `rtol` ≥ 1e-10")
    return ("conditioning warning: " + "; ".join(notes) + ". Nondimensionalize the model (choose units in "
            "which the states are of order one) or set `atol` below the smallest state and `rtol` ≥ 1e-10")


# ---------------------------------------------------------------------------------------
# Why a variable-step run failed: diagnosed at the failure point before anything is blamed.

DIAGNOSE_MAX = 1500
"""Largest system whose iteration matrix is analysed (dense SVD) when a run fails."""
MODES_MAX = 600
"""Largest system whose linearized modes are computed (dense QZ) when a run fails."""
LIGHT_DAMPING = 0.02
"""Modes with damping ratio |Re λ|/|λ| below this count as undamped."""
UNRESOLVED = 0.05
"""ω·h above which an undamped mode is not resolved by the steps (BDF of order 3–5 is then
not stable for it: its stability region leaves out part of the imaginary axis)."""


def undamped_modes(mod, p, t, y, yp) -> Optional[np.ndarray]:
    """Angular frequencies of the lightly damped modes of the DAE linearized at (t, y, ẏ):
    the finite eigenvalues λ of ``F_ẏ λ v = −F_y v`` with ``|Re λ| < LIGHT_DAMPING·|λ|``.
    None when the system is too large (:data:`MODES_MAX`)."""
    n = mod.N
    if n > MODES_MAX:
        return None
    Fy, Fyp = _dense_split(mod, p, t, y, yp)
    try:
        lam = sla.eigvals(-Fy, Fyp)
    except (np.linalg.LinAlgError, ValueError):
        return None
    lam = lam[np.isfinite(lam)]
    scale = np.abs(Fy).max(initial=1.0) / max(np.abs(Fyp).max(initial=0.0), 1e-300)
    lam = lam[np.abs(lam) < 1e8 * max(scale, 1.0)]  # infinite eigenvalues computed inexactly
    light = lam[(np.abs(lam.imag) > 0) & (np.abs(lam.real) < LIGHT_DAMPING * np.abs(lam))]
    return np.sort(np.abs(light.imag))[::-1]


MODES_NEAR = 4
"""Eigenvalues the sparse search of a large system computes (:func:`undamped_modes_near`)."""
NEAR_TOL = 1e-2
"""Relative accuracy of the sparse search's eigenvalues: it decides whether ω·h exceeds
:data:`UNRESOLVED`, for which a percent is plenty."""
NEAR_RESTARTS = 200
"""Most implicit restarts of the sparse search (ARPACK's ``maxiter``): a search that has not
converged by then returns what converged."""


def undamped_modes_near(mod, p, t, y, yp, omega: float) -> Optional[np.ndarray]:
    """Angular frequencies of the lightly damped modes (as :func:`undamped_modes`) among the
    :data:`MODES_NEAR` eigenvalues λ of ``F_ẏ λ v = −F_y v`` nearest to ``iω``, for systems too
    large for the dense QZ: ARPACK on ``(−F_y − iω F_ẏ)⁻¹ F_ẏ``, whose eigenvalues are
    ``1/(λ − iω)`` (those of the algebraic rows, infinite, map to 0), with one sparse LU of
    the sparse Jacobian. On the Euler–Bernoulli beam of 1 000 elements (8 007 unknowns) it
    takes under a second. Near ``iω`` with ``ω = 1/h`` it finds the modes a BDF step of size
    h leaves unresolved, wherever the spectrum along the imaginary axis reaches that far
    without a gap; modes far above ``1/h`` behind such a gap it may miss. None when the
    search fails."""
    import scipy.sparse as sps
    import scipy.sparse.linalg as spla

    n = mod.N
    if not (omega > 0 and math.isfinite(omega)) or n <= MODES_NEAR + 2:
        return None
    rows, cols = np.asarray(mod.JAC_ROWS), np.asarray(mod.JAC_COLS)
    buf = np.zeros(len(rows))
    mod.jacobian(t, y, yp, p, 0.0, buf)
    Fy = sps.csc_matrix((buf.copy(), (rows, cols)), shape=(n, n))
    mod.jacobian(t, y, yp, p, 1.0, buf)
    Fyp = (sps.csc_matrix((buf.copy(), (rows, cols)), shape=(n, n)) - Fy).tocsc()
    if not (np.isfinite(Fy.data).all() and np.isfinite(Fyp.data).all()):
        return None
    sigma = 1j * omega
    try:
        lu = spla.splu((-Fy - sigma * Fyp).tocsc().astype(complex))
    except (RuntimeError, ValueError):  # iω is an eigenvalue (exactly singular), or no LU
        return None
    op = spla.LinearOperator((n, n), matvec=lambda v: lu.solve(np.asarray(Fyp @ v, dtype=complex)),
                             dtype=complex)
    start = np.random.default_rng(0).standard_normal(n).astype(complex)  # the same search every time
    try:
        nu = spla.eigs(op, k=MODES_NEAR, which="LM", v0=start, tol=NEAR_TOL, maxiter=NEAR_RESTARTS,
                       return_eigenvectors=False)
    except spla.ArpackNoConvergence as err:
        nu = np.asarray(err.eigenvalues)
    except (spla.ArpackError, ValueError, RuntimeError):
        return None
    nu = nu[np.isfinite(nu) & (np.abs(nu) > 0)]
    lam = sigma + 1.0 / nu
    scale = np.abs(Fy.data).max(initial=1.0) / max(np.abs(Fyp.data).max(initial=0.0), 1e-300)
    lam = lam[np.abs(lam) < 1e8 * max(scale, 1.0)]  # infinite eigenvalues computed inexactly
    light = lam[(np.abs(lam.imag) > 0) & (np.abs(lam.real) < LIGHT_DAMPING * np.abs(lam))]
    return np.sort(np.abs(light.imag))[::-1]


def _fastest_undamped(mod, p, t, y, yp, h: float) -> tuple[Optional[np.ndarray], bool]:
    """(:func:`undamped_modes`, False), or for a system too large for it the sparse search
    near ``ω = 1/h`` (:func:`undamped_modes_near`, True); (None, …) when neither answers."""
    omegas = undamped_modes(mod, p, t, y, yp)
    if omegas is not None or not h > 0:
        return omegas, False
    return undamped_modes_near(mod, p, t, y, yp, 1.0 / h), True


def many_steps_hint(mod, p, t, y, yp, *, steps: int, span: float, max_order: int, rtol: float, atol: float,
                    stopped: bool = False) -> str:
    """What a successful IDA run of very many `steps` over `span` (or one `stopped` at
    ``max_steps``) may have cost them, said only where it holds: lightly damped modes
    (:func:`undamped_modes`, at each state of `t`, `y`, `ẏ`; above :data:`MODES_MAX` unknowns
    those near ``1/h``, :func:`undamped_modes_near`) that the mean step leaves unresolved
    (ω·h above :data:`UNRESOLVED`) at BDF order 3 or 4, which is not stable for them, or at
    order 5 where they hold its step (ω·h above :data:`phc.simulation.order.HELD`) — then
    `max_order: 2` is the advice; otherwise the error test at the tolerances, which at order
    5 may follow undamped modes of ω·h between the two (BDF5 is stable there, and BDF2 would
    take more steps: the advice is a fixed-step solver or looser tolerances). A loudspeaker with modes of damping ratio
    0.78 and 1 was told of "stiff undamped modes" it does not have, when an index-1
    variable's tolerance was the cause (issue 33); the Euler–Bernoulli beam of 1 000
    elements (modes up to 7.7e9 rad/s) was told it had none, because no mode of its 8 007
    unknowns had been computed (issue 38). There, at order 5, IDA holds the step where
    ω_max·h ≈ 0.6, inside BDF5's stable interval of the imaginary axis (ω·h < 0.71),
    whatever the tolerances (7.5e-11 s at rtol 1e-8, 6.2e-11 s at 1e-5); at max_order 2 its
    steps were 3 500 times longer."""
    h = span / max(steps, 1)
    head = f"IDA {'took' if stopped else 'needed'} {steps} steps (mean step {h:.2g})"
    omegas, searched, looked = [], False, False
    for ti, yi, ypi in zip(t, y, yp):
        try:
            w, near = _fastest_undamped(mod, p, ti, yi, ypi, h)
        except (ArithmeticError, ValueError, TypeError, np.linalg.LinAlgError, ModelEvaluationError):
            w, near = None, False
        searched |= near
        looked |= w is not None
        if w is not None and len(w):
            omegas.append(float(w[0]))
    w = max(omegas, default=0.0)
    beyond = " or beyond" if searched else ""  # the sparse search sees the modes near 1/h, not the fastest
    from phc.simulation.order import DEFAULT_ORDER, HELD  # order.py imports this module

    # BDF3 and BDF4 amplify an undamped mode at every ωh > 0; BDF5 only above BDF5_IMAGINARY,
    # and IDA can double a step while ωh ≤ HELD: below that the steps are the error test's,
    # and max_order 2 would shorten them (a 16-element cantilever with a tip mass: 978 824
    # steps at order 5, 10⁶ steps for its first 0.0047 s of 0.05 s at order 2)
    stable5 = max_order >= DEFAULT_ORDER and w * h <= HELD
    if w * h > UNRESOLVED and max_order > 2 and not stable5:
        return (f"{head}: the model has undamped oscillations up to ω ≈ {w:.2g} rad/s{beyond} that steps of this "
                f"size do not resolve (ωh ≈ {w * h:.2g}), and BDF of order 3–5 is not stable for them; `max_order: "
                "2` or a fixed-step solver (`--solver midpoint --step …`) steps over them (docs/how-to/solvers.md)")
    if w * h > UNRESOLVED and max_order > 2:  # BDF5 stable for them, its step not held: the error test's
        return (f"{head}: the steps follow undamped oscillations up to ω ≈ {w:.2g} rad/s{beyond} (ωh ≈ "
                f"{w * h:.2g}); BDF5 is stable for them at this ωh (below {HELD:.2f}, where IDA can still double "
                f"its step), so the steps are what the error test asks for at rtol = {rtol:g}, atol = {atol:g} "
                "(atol relative to each variable's nominal scale, docs/tolerances.md) and `max_order: 2` would "
                "make them shorter (BDF2 is second order); a fixed-step solver (`--solver midpoint --step …`) "
                "steps over the oscillations, or looser tolerances cost fewer steps (docs/how-to/solvers.md)")
    if w * h > UNRESOLVED:  # at max_order 2: A-stable, the modes are damped numerically, not a limit
        modes = (f"the undamped oscillations up to ω ≈ {w:.2g} rad/s{beyond} (ωh ≈ {w * h:.2g}) are not resolved, "
                 f"but BDF at max_order {max_order} is stable for them")
    elif not looked:  # neither the dense nor the sparse search answered: claim nothing about the modes
        modes = "the linearized modes could not be computed"
    elif searched:
        modes = (f"no lightly damped mode was found near ω = 1/h ≈ {1 / h:.2g} rad/s (a sparse search of the "
                 f"{mod.N} unknowns" + (f"; the nearest, ω ≈ {w:.2g} rad/s, has ωh ≈ {w * h:.2g})" if w > 0 else ")"))
    else:
        modes = ("no undamped mode is left unresolved by such steps"
                 + (f" (the fastest, ω ≈ {w:.2g} rad/s, has ωh ≈ {w * h:.2g})" if w > 0 else ""))
    return (f"{head}: {modes}, so the steps are what the error test asks for at rtol = {rtol:g}, atol = "
            f"{atol:g} (atol relative to each variable's nominal scale, docs/tolerances.md): looser tolerances, or "
            "a larger `nominal` for a variable you need less precisely, cost fewer")


def _dense_split(mod, p, t, y, yp) -> tuple[np.ndarray, np.ndarray]:
    """(F_y, F_ẏ) at (t, y, ẏ) as dense matrices, from two Jacobian evaluations."""
    n = mod.N
    rows, cols = np.asarray(mod.JAC_ROWS), np.asarray(mod.JAC_COLS)
    buf = np.zeros(len(rows))
    mod.jacobian(t, y, yp, p, 0.0, buf)
    Fy = np.zeros((n, n))
    Fy[rows, cols] = buf
    mod.jacobian(t, y, yp, p, 1.0, buf)
    Fyp = -Fy.copy()
    Fyp[rows, cols] += buf
    return Fy, Fyp


AHEAD_MOTION = 0.1
""":func:`singular_ahead` looks along the rates, at y + τẏ, as far as no state moves by more than
this fraction of its size (the larger of |y| and its nominal scale): there the linear
extrapolation of the run is accurate to first order."""
AHEAD_RESIDUAL = 1e-2
"""The extrapolated state of :func:`singular_ahead` must meet every algebraic equation (a row
without ẏ) to this fraction of the row's largest term at the failure (``max_k |∂F_i/∂y_k| s_k``,
s_k the size of y_k): a linear extrapolation of a solution misses them by O(τ²), ½(τ/T)² of
the row's size over a time τ = :data:`AHEAD_MOTION`·T, 5e-3. A model that is nonlinear on a finer
scale than its states' sizes fails it (the transistor amplifier: its diode laws change e-fold per
26 mV of 6 V node voltages), and the extrapolation says nothing there."""
AHEAD_GRID = 16
"""Points at which :func:`singular_ahead` looks first; golden-section search refines the least."""
AHEAD_MAX = 400
"""Largest system :func:`singular_ahead` searches (some 40 looks of the monitor, each an LU and
at times a dense SVD)."""


def singular_ahead(monitor, t, y, yp, h, scales=None) -> Optional[tuple[float, float, np.ndarray]]:
    """``(τ, ratio, u)`` of a singular configuration a run at (t, y, ẏ) is heading for: the
    monitor (:meth:`SingularityMonitor.ratio`: the equilibrated iteration matrix singular at
    the step `h` and at a :data:`STEP_SPREAD` times longer one, a rank drop whatever the step)
    finds one at the extrapolated state ``y + τẏ`` within the reach of :data:`AHEAD_MOTION`; u
    the weak direction there. None when there is none, or the system is larger than
    :data:`AHEAD_MAX`.

    A BDF code fails *before* such a configuration: the conditioning falls like a power of the
    distance to it, and the Newton iteration fails on amplified round-off (the tighter the
    tolerances, the earlier) while the iteration matrix is still regular at the failure point
    — the folding slider–crank failed 1.4e-5 s before its rod stood perpendicular to the guide,
    at σ_min/σ_max = 1.6e-9. Along a line through it the ratio falls to (nearly) zero in a V, so
    a grid of :data:`AHEAD_GRID` points and a golden-section search around its least value
    find it (:func:`_search_below`). The line need not pass through the singular set exactly:
    there, along the run's rates, the equilibrated rows of the algebraic equations alone
    bottom out at σ_min/σ_max = 2.5e-11, the iteration matrix at 4e-14."""
    mod = monitor.mod
    if mod.N > AHEAD_MAX or not h > 0:
        return None
    y, yp = np.asarray(y, dtype=float), np.asarray(yp, dtype=float)
    size = np.abs(y) if scales is None else np.maximum(np.abs(y), np.abs(np.asarray(scales, dtype=float)))
    rate = np.abs(yp)
    moving = state_mask(mod) & (rate > 0) & (size > 0) & np.isfinite(rate)
    if not moving.any():
        return None
    reach = AHEAD_MOTION * float(np.min(size[moving] / rate[moving]))

    def f(tau):
        return monitor.ratio(t + tau, y + tau * yp, yp, h, vectors=False)

    taus = reach * np.arange(AHEAD_GRID + 1) / AHEAD_GRID
    looks = [f(tau) for tau in taus]
    i = int(np.argmin([r for r, _ in looks]))
    a, b = max(i - 1, 0), min(i + 1, AHEAD_GRID)
    found = _search_below(f, float(taus[a]), float(taus[b]), monitor.threshold, fa=looks[a][0], fb=looks[b][0],
                          minimum=True)
    if found is None:
        return None
    tau = float(found[0])
    if not _meets_algebraic_rows(mod, monitor.p, t, y, yp, tau, size):
        return None
    ratio, u = monitor.ratio(t + tau, y + tau * yp, yp, h)
    return None if u is None else (tau, ratio, u)


def _meets_algebraic_rows(mod, p, t, y, yp, tau, size) -> bool:
    """Whether ``y + τẏ`` meets the algebraic equations to :data:`AHEAD_RESIDUAL` of each
    row's largest term at (t, y, ẏ) (`size`: the variables' sizes)."""
    Fy, Fyp = _dense_split(mod, p, t, y, yp)
    algebraic = ~np.abs(Fyp).any(axis=1)
    scale = (np.abs(Fy) * size[None, :]).max(axis=1)
    out = np.zeros(mod.N)
    mod.residual(t + tau, y + tau * yp, yp, p, out)
    return bool(np.all(np.abs(out[algebraic]) <= AHEAD_RESIDUAL * scale[algebraic]))


ROUND_OFF_WRMS = 0.2
"""Weighted RMS norm of the round-off part of a Newton correction above which the
tolerances ask for more than double precision gives (IDA's Newton test needs the
correction's norm well below 0.33)."""


def roundoff_correction(mod, p, t, y, yp, h, rtol, atol, samples: int = 2, scales=None, deflate: int = 0):
    """How far round-off alone moves a Newton correction of a BDF step of size `h` at
    (t, y, ẏ), in IDA's error weights ``1/(rtol|y| + atol)`` of the differential variables:
    ``(wrms, name, noise, tolerance)`` of the worst variable, or None when the system is
    too large. The residual's round-off is modelled as ε times the size of each row's
    terms (``|F_y||y| + |F_ẏ||ẏ|``) with random signs, and solved with the iteration matrix.

    `deflate` > 0: solved without the `deflate` weakest directions of the equilibrated
    iteration matrix (its smallest singular values left out: a pseudo-inverse in the
    equilibrated units) — how far round-off would move the correction without a near rank
    drop there. The random signs are the same as without (the same seed)."""
    n = mod.N
    if n > DIAGNOSE_MAX or h <= 0:
        return None
    Fy, Fyp = _dense_split(mod, p, t, y, yp)
    size = np.abs(Fy) @ np.abs(y) + np.abs(Fyp) @ np.abs(yp)
    diff = state_mask(mod)
    tol = rtol * np.abs(y) + atol * (1.0 if scales is None else np.asarray(scales, dtype=float))
    rng = np.random.default_rng(0)
    try:
        if deflate > 0:
            Je, r, c = equilibrate(Fy + Fyp / h, rounds=2)
            U, S, Vt = np.linalg.svd(Je)
            keep = max(n - int(deflate), 0)

            def solve(b):
                return c * (Vt[:keep].T @ ((U[:, :keep].T @ (r * b)) / S[:keep]))
        else:
            lu = sla.lu_factor(Fy + Fyp / h, check_finite=True)

            def solve(b):
                return sla.lu_solve(lu, b)
    except (ValueError, np.linalg.LinAlgError):
        return None
    worst = None
    for _ in range(samples):
        delta = solve(np.finfo(float).eps * size * rng.choice([-1.0, 1.0], n))
        weighted = np.where(diff, np.abs(delta) / tol, 0.0)
        wrms = float(np.sqrt(np.mean(weighted[diff] ** 2))) if diff.any() else 0.0
        j = int(np.argmax(weighted))
        if worst is None or wrms > worst[0]:
            worst = (wrms, str(mod.VARIABLES[j]), float(abs(delta[j])), float(tol[j]))
    return worst


AHEAD_ROUND_OFF = ("Newton's iteration failed on the round-off that this near rank drop amplifies, so no tolerance is "
                   "the remedy: looser ones only let IDA come closer to it")
AHEAD_PASS = ("`midpoint` and `discrete_gradient` can integrate through an isolated rank drop of the position "
              "constraints (they stop where they cannot)")


def _heading_for_singularity(monitor, t, y, yp, h, ratio, floor, rtol, atol, scales) -> Optional[str]:
    """The singular configuration a run that failed at (t, y, ẏ) was heading for, said as the
    monitor says one (:meth:`SingularityMonitor._dependence`), when it explains the failure:
    the monitor finds one ahead at the step `h` (:func:`singular_ahead`), and the round-off
    `floor` of the Newton correction (:func:`roundoff_correction`) falls below
    :data:`ROUND_OFF_WRMS` without the directions that become singular there (as many as the
    iteration matrix there has singular values below the threshold). `ratio`: the iteration
    matrix's σ_min/σ_max at the failure. None otherwise."""
    mod, p = monitor.mod, monitor.p
    try:
        ahead = singular_ahead(monitor, t, y, yp, h, scales=scales)
        if ahead is None:
            return None
        tau, then, u = ahead
        s = np.linalg.svd(monitor._equilibrated(t + tau, y + tau * yp, yp, h), compute_uv=False)
        deficiency = max(1, int(np.count_nonzero(s < monitor.threshold * s[0])))
        without = roundoff_correction(mod, p, t, y, yp, h, rtol, atol, scales=scales, deflate=deficiency)
    except (ArithmeticError, ValueError, np.linalg.LinAlgError, ModelEvaluationError):
        return None
    if without is None or without[0] > ROUND_OFF_WRMS:
        return None
    equations, where, condition = monitor._dependence(u)
    return (f"stopped at t = {t:.6g} near a singular configuration: the equations {equations} become "
            f"dependent{where} at t ≈ {t + tau:.6g}, {tau:.1e} s ahead along the run's rates (σ_min/σ_max of the "
            f"equilibrated iteration matrix {ratio:.1e} at the step h = {h:.1e} here, {then:.1e} < "
            f"{monitor.threshold:.0e} there). Condition: {condition}, so the {SURJECTIVITY} there (run `phc check` "
            f"for the coupling certificate). Round-off moves a Newton correction of `{floor[1]}` by ~{floor[2]:.0e}, "
            f"more than its tolerance {floor[3]:.0e} (weighted norm {floor[0]:.2g}; {without[0]:.2g} without the "
            f"{deficiency} direction{'s' if deficiency > 1 else ''} that become{'' if deficiency > 1 else 's'} "
            "singular)")


def diagnose_failure(mod, p, t, y, yp, *, status: int, h_typical: float, h_fail: float, max_order: int,
                     rtol: float, atol: float, names: Optional[dict] = None, scales=None,
                     local: float = 1.0) -> str:
    """What to tell the user when the integrator gave up at (t, y, ẏ).

    A singular configuration is named only when the equilibrated iteration matrix
    ``F_y + F_ẏ/h`` is numerically singular at the step size the run was taking before it
    collapsed (`h_typical`): an index-2 iteration matrix is conditioned like h², so at the
    collapsed step (`h_fail`) every configuration looks singular — or when the run was heading
    for one (:func:`singular_ahead`: the constraint Jacobian loses rank a little ahead along
    ẏ, the iteration matrix is singular there at both steps of :meth:`SingularityMonitor.ratio`)
    and the round-off that stopped the Newton iteration (:func:`roundoff_correction`) is the
    near rank drop's: without the directions that become singular it is within what Newton
    needs. No tolerance is then the remedy (a looser one only lets IDA come closer).
    Otherwise the cause is looked for in the linearized modes (undamped stiff modes at BDF
    order > 2), then the step and the tolerances, and the remedy is named. `local`: the factor
    between the tolerances asked for and those IDA's error test uses (:data:`phc.simulation.
    ida.LOCAL_TOLERANCE`); remedies are stated in the former."""
    n = mod.N
    h = max(h_typical, h_fail)
    regular = ""
    monitor = None
    if n <= DIAGNOSE_MAX and h > 0:
        monitor = SingularityMonitor(mod, p, names=names, scales=scales)
        try:
            ratio, u = monitor.ratio(t, y, yp, h)
        except (ArithmeticError, ValueError, np.linalg.LinAlgError):
            ratio, u = float("nan"), None
        if u is not None:
            return monitor._message(t, ratio, u, monitor.threshold).replace("stopped at", "failed at", 1)
        if np.isfinite(ratio):
            regular = (f"the iteration matrix F_y + F_ẏ/h is regular there (σ_min/σ_max = {ratio:.1e} at the "
                       f"step h = {h:.1e} the run was taking), so this is not a singular configuration")
    collapse = f"IDA cut the step from h ≈ {h_typical:.1e} to h ≈ {h_fail:.0e}"
    floor = (roundoff_correction(mod, p, t, y, yp, h_typical, rtol * local, atol * local, scales=scales)
             if h_typical > 0 else None)
    if monitor is not None and regular and floor is not None and floor[0] > ROUND_OFF_WRMS:
        ahead = _heading_for_singularity(monitor, t, y, yp, h_typical, ratio, floor, rtol * local, atol * local,
                                         scales)
        if ahead is not None:
            return f"{ahead}. {collapse}: {AHEAD_ROUND_OFF}" + (
                f"; {AHEAD_PASS}" if monitor.positional else "") + "; results up to this time are kept"
    try:
        omegas, near = _fastest_undamped(mod, p, t, y, yp, h_typical)
    except (ArithmeticError, ValueError, TypeError, np.linalg.LinAlgError, ModelEvaluationError):
        omegas, near = None, False
    stiff = (omegas is not None and len(omegas) and omegas[0] * h_typical > UNRESOLVED and max_order > 2)
    modes = ""
    if stiff:
        w = omegas[0]
        modes = (f"the model has undamped oscillations up to ω ≈ {w:.2g} rad/s{' or beyond' if near else ''} "
                 f"(period {2 * np.pi / w:.1e} s) that "
                 f"steps of h ≈ {h_typical:.1e} do not resolve (ωh ≈ {w * h_typical:.2g}), and BDF of order 3–5 "
                 f"(max_order {max_order}) is not stable for such modes near the imaginary axis")
        modes_remedy = ("`max_order: 2` (A-stable BDF2 keeps undamped modes bounded at any step; in a scene "
                        "`accuracy: {max_order: 2}`), or `solver: midpoint` (structure preserving), or damp or "
                        "remove the high modes (a `damping` coefficient, a coarser mesh, `modes: k`)")
    if floor is not None and floor[0] > ROUND_OFF_WRMS:
        wrms, name, noise, tol = floor
        s_name = 1.0 if scales is None else float(scales[list(mod.VARIABLES).index(name)])
        cause = (f"{collapse}: the tolerances ask for more than double precision gives here — round-off alone "
                 f"moves a Newton correction of `{name}` by ~{noise:.0e}, more than its tolerance "
                 + ("" if local == 1.0 else f"in IDA's error test, {local:g}·") +
                 f"(rtol·|y| + atol) = {tol:.0e} (weighted norm of the round-off {wrms:.2g}; Newton needs it well "
                 f"below 0.33), and a smaller step only makes the iteration matrix worse conditioned. Remedy: "
                 + (f"atol ≥ {10 * noise / local:.0e} (or a looser rtol), or units in which `{name}` is of order one"
                    if scales is None else
                    f"atol ≥ {10 * noise / (s_name * local):.0e} (relative to the nominal scale {s_name:.1e} of "
                    f"`{name}`), a nominal scale of `{name}` ≥ {10 * noise / (atol * local):.0e} if you set one, "
                    "or a looser rtol"))
        if stiff:
            cause += f". Besides, {modes}, which makes steps small and costly: {modes_remedy}"
    elif stiff:
        cause = f"{collapse}: {modes}; the step collapsed until the Newton iteration failed. Remedy: {modes_remedy}"
    elif status == -3:
        cause = (f"{collapse}: the error test failed repeatedly, so the solution is not smooth here (a jump "
                 "or kink of an input or expression: make it a breakpoint) or rtol = "
                 f"{rtol:g}, atol = {atol:g} ask for more than double precision gives; loosen them")
    elif status == -4:
        cause = (f"{collapse}: the Newton iteration failed repeatedly although the iteration matrix is "
                 "regular: the residual is not smooth here (a kink or a non-smooth function), or rtol = "
                 f"{rtol:g}, atol = {atol:g} are too tight for the conditioning of the model; loosen them "
                 "or nondimensionalize the model")
    else:
        cause = f"{collapse}; try looser tolerances (rtol = {rtol:g}, atol = {atol:g}) or check the model"
    return f"{regular}; {cause}" if regular else cause


GROWTH = 1e2
"""A failed run is diagnosed as unbounded growth when a state ends at least this many times its
scale (the larger of its nominal scale and its initial size): beyond anything the start of the
run or the model's parameters made of its size..."""
GROWTH_FAST = 0.05
"""...and when it then grows by a factor e in less than this fraction of the time run so far:
the growth outruns the run's time scale (a slow drift of a state is not a failure's cause)."""
FINITE_TIME = 1e-2
"""The e-folding time |x/ẋ| fell below this fraction of its value at the start (its scale over
its initial rate): the solution grows ever faster as it grows, a finite-time blow-up
(x ~ (t* − t)^(−α) has |x/ẋ| = (t* − t)/α); an exponential growth keeps it constant."""
GROWTH_BLOW_UP = 10.0
"""The size over its scale a state needs for a finite-time blow-up (with :data:`FINITE_TIME`):
one order of magnitude. A fixed step h fails once the e-folding time nears h, before the state
is large: the midpoint rule on ẋ = x² has no real solution beyond h·x ≈ 2 (from x₀ = 2 at
h = 1e-3, some 300 times the scale), on ẋ = 5 − x + 20x³ beyond h·60x² ≈ 1 (from 0 at h = 1e-3,
about 100 times its scale 1.76)."""


def unbounded_growth(mod, t, y, yp, *, start=None, scales=None) -> Optional[str]:
    """Why a run that failed at (t, y, ẏ) failed, if its solution grows without bound: the
    differential state that grew most over its scale, if it grows fast (:data:`GROWTH_FAST`) and
    either its e-folding time |x/ẋ| fell by :data:`FINITE_TIME` from `start` = (t₀, y₀, ẏ₀) with
    the state :data:`GROWTH_BLOW_UP` times its scale (a finite-time blow-up) or the state is
    :data:`GROWTH` times its scale (an exponential growth); named with the time, its size and
    its e-folding time. None otherwise. `scales`: the variables' nominal scales
    (:mod:`phc.simulation.scaling`). A solver cannot follow such a solution (its steps collapse,
    or its Newton iteration fails once a step multiplies the state's size): the remedy is in the
    model, not in the solver's settings."""
    y, yp = np.asarray(y, dtype=float), np.asarray(yp, dtype=float)
    diff = state_mask(mod)
    n = len(y)
    ref = np.ones(n) if scales is None else np.abs(np.asarray(scales, dtype=float))
    t0, y0, yp0 = (None, np.zeros(n), np.zeros(n)) if start is None else (
        float(start[0]), np.asarray(start[1], dtype=float), np.asarray(start[2], dtype=float))
    ref = np.maximum(ref, np.abs(y0))
    size = np.where(np.isfinite(y), np.abs(y), np.inf)
    with np.errstate(divide="ignore", invalid="ignore"):
        grown = np.where(diff & (ref > 0), size / ref, 0.0)
    i = int(np.argmax(grown))
    if not grown[i] >= GROWTH_BLOW_UP:
        return None
    rate = abs(float(yp[i])) if np.isfinite(yp[i]) else math.inf
    tau = size[i] / rate if rate > 0 else math.inf
    elapsed = (t - t0) if t0 is not None else math.inf
    rate0 = abs(float(yp0[i]))
    # its e-folding time at the start (a state starting at 0: its scale over its initial rate)
    tau0 = (abs(float(y0[i])) or ref[i]) / rate0 if rate0 > 0 else math.inf
    if math.isfinite(size[i]) and not (tau <= GROWTH_FAST * elapsed
                                       and (grown[i] >= GROWTH or tau <= FINITE_TIME * tau0)):
        return None
    name = str(mod.VARIABLES[i])
    where = (f"`{name}` grows without bound: it reached {y[i]:.3g} at t = {t:.10g}, {grown[i]:.1e} times its "
             f"scale {ref[i]:.2g}")
    if not math.isfinite(size[i]):
        return f"{where}: the solution escapes to infinity. " + _GROWTH_REMEDY
    if tau <= FINITE_TIME * tau0:
        return (f"{where}, and grows by a factor e in {tau:.1e} s (in {tau0:.1e} s at the start): a finite-time "
                f"blow-up: the solution reaches infinity within about {tau:.0e} s; no step size can follow it. "
                + _GROWTH_REMEDY)
    return (f"{where}, and grows by a factor e every {tau:.1e} s: an unbounded (exponential) growth, an unstable "
            f"model. " + _GROWTH_REMEDY)


_GROWTH_REMEDY = ("Check the model: the signs of its terms (a feedback of a state onto its own rate with a "
                  "positive sign, such as +x³ or +x², runs away), its parameters, an energy source that "
                  "feeds the state without limit")
