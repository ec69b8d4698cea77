"""Consistent initialization (pipeline stage 7, "analyse", run at t₀).

Given fixed initial values for some states and guesses for the rest, find ``(y₀, ẏ₀)``
with ``F(t₀, y₀, ẏ₀) = 0`` that also satisfies the hidden constraints of the index-2
formulation. Those come from one differentiation of the rows,
``D = F_y ẏ + F_ẏ ÿ + F_t = 0``, with the second derivatives ÿ and the derivatives of
algebraic variables as extra (nuisance) unknowns — the numeric counterpart of one
Pantelides step. Rows whose derivative can always be satisfied by a nuisance unknown of
their own (found by a maximum matching of rows to ÿ on the pattern of F_ẏ) are dropped
with that unknown, so an ODE-like block adds nothing.

The system ``[F; D] = 0`` is solved by Gauss–Newton with weighted minimum-norm steps.
Stage 1 holds all states at their values; stage 2 (only if stage 1 fails) lets the guessed
states move, and its steps minimize the change of the guesses alone — in the energy norm
when the guesses store energy (:meth:`_Problem.energy_metric`), else relative to their
nominal scales — with the nuisance unknowns (rates, algebraic variables) free
(:func:`_nested_min_norm`): guesses change only as much as the constraints demand, the
same in every unit system. Up to :data:`DENSE_LIMIT` Newton-matrix entries (about 290
elements of a string) that step is solved dense, beyond by one sparse LU of its
optimality system (:meth:`_Problem._sparse_nested_step`); where that fails, the step is
the sparse solvers' weighted minimum-norm step, which prices the nuisance unknowns at
:data:`CHEAP` times their scale and can trade a guess against them.
Fixed values are never moved: if the
equations cannot hold with them, the rows that fail are reported with the variables
they involve — never a silent snap onto the constraint manifold.

The module is over 800 lines because the problem's weighted unknowns, its two stages and
the dense and sparse forms of the nested least-norm step share one state (:class:`_Problem`);
the sparse optimality system is the part to move out next.
"""

from __future__ import annotations

import weakref
from dataclasses import dataclass, field

import numpy as np
import scipy.linalg as sla
import scipy.sparse as sps

from phc.analysis.matching import bipartite_matching
from phc.errors import InconsistentInitialError
from phc.simulation.chord import max_norm as _norm
from phc.simulation.sparse_lu import sparse_lu
from phc.simulation.gauss_newton import gauss_newton, least_squares
from phc.simulation.guard import ModelEvaluationError
from phc.simulation.minnorm import (CONSISTENT, DENSE_SOLVE_LIMIT, LeastNorm, dense_min_norm, lsmr_min_norm, min_norm_solve,
                                    one_blas_thread)

CHEAP = 1e4
"""Weight of unknowns that may change freely (derivatives, algebraic variables)."""

DENSE_LIMIT = 4_000_000
"""Problems with at most this many Jacobian entries use dense least squares."""

SCALED_CHECK = True
"""Check a start found in the model's units in the scaled variables, and solve again scaled
if it fails there (:func:`consistent_initial_conditions`)."""
SCALED_MISS = 1e-6
"""A row missed by more than this fraction of its largest term (scaled variables) is an
inconsistent start however small it looks in the model's units."""

ENERGY_METRIC_LIMIT = 300
"""Up to this many guessed states their change is measured in the energy norm (its Hessian
costs n²/2 evaluations of H); beyond, in their nominal scales."""

POLISH_STEPS = 3
"""Gauss–Newton steps after convergence that refine the solution to round-off."""


STRUCTURE_CACHE = 32
"""Most structures kept per module (:func:`_structures`)."""
STRUCTURE_ENTRIES = 20_000
"""Modules with more Jacobian entries keep none (a mesh's index arrays would stay in memory
for the module's lifetime; one consistent initialization at the start builds them once)."""

_STRUCTURES: weakref.WeakKeyDictionary = weakref.WeakKeyDictionary()


def _structures(mod):
    """The structures of :class:`_Problem` already built for `mod`, by the patterns they
    depend on (the kept rows by the pattern of F_ẏ, the Newton matrix's index arrays by the
    kept rows and the unknowns): a run with events restarts from a consistent state at every
    event, in a few modes, and these depend on the patterns alone. None where `mod` cannot
    be weakly referenced or is large (:data:`STRUCTURE_ENTRIES`): nothing is cached then."""
    if len(getattr(mod, "JAC_ROWS", ())) > STRUCTURE_ENTRIES:
        return None
    try:
        cache = _STRUCTURES.get(mod)
        if cache is None:
            cache = _STRUCTURES[mod] = {}
    except TypeError:
        return None
    if len(cache) > STRUCTURE_CACHE:
        cache.clear()
    return cache


def _diagonal(w: np.ndarray):
    """The diagonal matrix of `w`, in CSR (``sps.diags`` checks its offsets with
    ``np.unique``, which loads ``numpy.ma``: 10 ms of start-up)."""
    n = len(w)
    return sps.csr_matrix((np.asarray(w, dtype=float), np.arange(n), np.arange(n + 1)), shape=(n, n))


@dataclass
class InitialResult:
    y0: np.ndarray
    yp0: np.ndarray
    chosen: dict[str, float] = field(default_factory=dict)
    residual: float = 0.0
    iterations: int = 0


class _Problem:
    """``G(u) = [F; D_kept]`` over the unknowns ``u = [y_free, ẏ_diff, z, w]``."""

    def __init__(self, mod, p, t0, y, fixed, initial_relations=True, like=None, scales=None):
        """`like`: a problem of another stage at the same start (t0, y): its Jacobian there,
        row scaling and kept rows are this one's too. `scales`: nominal scales of the
        variables (:mod:`phc.simulation.scaling`): the rows are equilibrated in the scaled
        variables (D_r J D_c), and the weights of the minimum-norm steps and the
        finite-difference steps are relative to them (without them, to 1: the rows are
        equilibrated in the model's units)."""
        self.scaled = scales is not None
        self.mod, self.p, self.t0 = mod, p, t0
        n = mod.N
        self.s = np.ones(n) if scales is None else np.asarray(scales, dtype=float)
        self.m = len(mod.EQUATIONS)
        self.rows, self.cols = np.asarray(mod.JAC_ROWS), np.asarray(mod.JAC_COLS)
        self.buf = np.zeros(len(self.rows))
        diff = np.asarray(mod.DIFFERENTIAL, dtype=bool)
        self.dif = np.flatnonzero(diff)
        held = np.zeros(n, dtype=bool)
        held[np.fromiter(fixed, dtype=np.int64, count=len(fixed))] = True
        self.free = np.flatnonzero(~held)  # ascending, as the held indices are not
        self.y = y.copy()
        self.yp = np.zeros(n)
        if like is not None:
            self.row_scale, self.kept = like.row_scale, like.kept
            self.zc, self.wc = like.zc, like.wc
        else:
            # on the module's flat Jacobian data (no sparse matrices beside it: a mesh of 10⁵
            # elements has 5·10⁶ entries)
            jy, jyp = self._jac_data(self.y, self.yp)
            rows, cols = self.rows, self.cols
            # Row equilibration: Hermite slope rows of a beam scale like h³; without it their
            # residuals look tiny while the states they determine are still off (and IDA's
            # first error test then sees a jump).
            mags = np.zeros(self.m)
            np.maximum.at(mags, rows, np.abs(jy) * self.s[cols])
            np.maximum.at(mags, rows, np.abs(jyp) * self.s[cols])
            self.row_scale = np.where(mags > 0, 1.0 / np.where(mags > 0, mags, 1.0), 1.0)
            del mags
            pattern = jyp != 0  # the pattern of F_ẏ (what the matching reads of it)
            cache = _structures(mod)
            key = ("kept", np.packbits(pattern).tobytes())
            self.kept = None if cache is None else cache.get(key)
            if self.kept is None:
                nz = np.flatnonzero(pattern)
                self.kept = self._kept_rows(sps.csc_matrix((jyp[nz], (rows[nz], cols[nz])), shape=(self.m, n)))
                if cache is not None:
                    cache[key] = self.kept
                del nz
            del pattern
            in_kept = np.zeros(self.m, dtype=bool)
            in_kept[self.kept] = True
            sel = np.flatnonzero(in_kept[rows])
            # columns with an entry of nonzero magnitude in a kept row (the sums are of
            # magnitudes: NaN stays NaN, which is not > 0, in any order of summation)
            used_y = np.bincount(cols[sel], weights=np.abs(jy[sel]), minlength=n) > 0
            used_yp = np.bincount(cols[sel], weights=np.abs(jyp[sel]), minlength=n) > 0
            self.zc = np.flatnonzero(~diff & used_y)
            self.wc = np.flatnonzero(diff & used_yp)
            del jy, jyp, sel
        self.z = np.zeros(n)
        self.w = np.zeros(n)
        # the columns whose Jacobian entries vary, among the free states and the rates (as
        # arrays: a mesh of 10⁵ elements has 8·10⁵ unknowns, none of them varying)
        depends_y = np.zeros(n, dtype=bool)
        depends_y[np.asarray(getattr(mod, "JAC_DEPENDS_ON_Y", np.arange(n)), dtype=np.int64)] = True
        depends_yp = np.zeros(n, dtype=bool)
        depends_yp[np.asarray(getattr(mod, "JAC_DEPENDS_ON_YP", np.arange(n)), dtype=np.int64)] = True
        none = np.zeros(0, dtype=np.int64)
        self.fd_y = self.free[depends_y[self.free]] if len(self.kept) else none
        self.fd_yp = self.dif[depends_yp[self.dif]] if len(self.kept) else none
        s = self.s  # a step of one nominal scale costs the same in every variable
        weights = np.concatenate([np.where(diff[self.free], 1.0, CHEAP) * s[self.free], CHEAP * s[self.dif],
                                  CHEAP * s[self.zc], CHEAP * s[self.wc]])
        self.weights = weights
        self.sizes = (len(self.free), len(self.dif), len(self.zc), len(self.wc))
        self.guess_columns = np.flatnonzero(diff[self.free])  # guessed states (stage 2)
        self._metric = False  # energy_metric(), computed on first use
        self._hessian = None  # its K
        self._kkt_failed = False  # the sparse nested step failed once (step())
        cache = _structures(mod)
        relations = None if cache is None else cache.get(("initial relations", bool(initial_relations)))
        if relations is None:
            n_init = len(getattr(mod, "INITIAL", ()))
            relations = (sps.csr_matrix((np.asarray(getattr(mod, "INITIAL_DATA", [])),
                                         (np.asarray(getattr(mod, "INITIAL_ROWS", []), dtype=np.int64),
                                          np.asarray(getattr(mod, "INITIAL_COLS", []), dtype=np.int64))),
                                        shape=(n_init, n)),
                         np.asarray(getattr(mod, "INITIAL_RHS", np.zeros(n_init)), dtype=float))
            if not initial_relations:
                relations = (sps.csr_matrix((0, n)), np.zeros(0))
            if cache is not None:
                cache[("initial relations", bool(initial_relations))] = relations
        self.C, self.c = relations  # C y = c (shared: read only)
        self._prepared = False  # _prepare() on first use: a hopeless stage never needs it
        self._d_ent = None  # _prepare_d() on the first evaluation of D: a start that is
        # already consistent (a mesh at rest) never needs the Jacobian's structure
        self.solver = LeastNorm()  # the Newton steps' least-norm solves (one rank decision)

    def _prepare_d(self):
        """Index arrays for evaluating D, built once: D's entries in CSR order (row, then
        column), so the sums of jy[k] @ ẏ and jyp[k] @ w are accumulated in the order of a
        CSR mat-vec."""
        rows, cols = self.rows, self.cols
        kpos = np.full(self.m, -1, dtype=np.int64)
        kpos[self.kept] = np.arange(len(self.kept))
        d_ent = np.flatnonzero(kpos[rows] >= 0)
        d_ent = d_ent[np.lexsort((cols[d_ent], rows[d_ent]))]  # only the kept rows' entries sorted
        self._d_ent, self._d_row, self._d_col = d_ent, kpos[rows[d_ent]], cols[d_ent]

    _STRUCTURE = ("_d_ent", "_d_row", "_d_col", "_exact_entries", "_group_entries", "_c_data", "_shape", "_csr_perm",
                  "_csr_indices", "_csr_indptr", "_nnz", "_dense_index")

    def _prepare(self):
        """The index arrays of :meth:`_build` (those of an earlier problem of the module with
        the same kept rows and unknowns, :func:`_structures`), then the row scaling of this
        start applied to them."""
        cache = _structures(self.mod)
        key = None
        if cache is not None:
            key = ("prepare", self.free.tobytes(), self.dif.tobytes(), self.zc.tobytes(), self.wc.tobytes(),
                   self.kept.tobytes(), np.asarray(self.fd_y).tobytes(), np.asarray(self.fd_yp).tobytes(),
                   self.C.shape, self.C.indptr.tobytes(), self.C.indices.tobytes(), self.C.data.tobytes())
        known = None if cache is None else cache.get(key)
        if known is None:
            self._build()
            if cache is not None:
                cache[key] = tuple(getattr(self, name) for name in self._STRUCTURE)
        else:
            for name, value in zip(self._STRUCTURE, known):
                setattr(self, name, value)
        rows = self.rows
        self._exact = [(e, part, self.row_scale[rows[e]]) for e, part in self._exact_entries]
        self._groups = [(ycols, ypcols, ent_row, ent_h, self.row_scale[self.kept[ent_row]])
                        for ycols, ypcols, ent_row, ent_h in self._group_entries]
        self._prepared = True

    def _build(self):
        """Index arrays for assembling the Jacobian of G, built once (on the first Newton
        step: a consistent start needs none).

        Every evaluation then works on the flat Jacobian data of the module (no sparse
        matrices are built per call), and the finite-difference columns of dD/dy and
        dD/dẏ are grouped: a row of D involves only the variables of its row of the
        Jacobian pattern, so columns whose patterns share no kept row are perturbed
        together and one evaluation of D yields them all."""
        n, m = self.mod.N, self.m
        rows, cols = self.rows, self.cols
        nf, nd, nz, nw = self.sizes
        nk = len(self.kept)
        kpos = np.full(m, -1, dtype=np.int64)
        kpos[self.kept] = np.arange(nk)

        def position(idx):
            out = np.full(n, -1, dtype=np.int64)
            out[np.asarray(idx, dtype=np.int64)] = np.arange(len(idx))
            return out

        pf, pd, pz, pw = position(self.free), position(self.dif), position(self.zc), position(self.wc)
        if self._d_ent is None:
            self._prepare_d()
        fd_yp = np.zeros(n, dtype=bool)
        fd_yp[np.asarray(self.fd_yp, dtype=np.int64)] = True
        # Exact blocks of J = [F; D; C] (before row scaling): (Jacobian entries, y or ẏ part,
        # row of J, column of J). The rows of D with finite differences follow below.
        r_d = m + kpos[rows]
        blocks = []
        for sel, part, jr, jc in (
                (pf[cols] >= 0, 0, rows, pf[cols]),                           # F_y[:, free]
                (pd[cols] >= 0, 1, rows, nf + pd[cols]),                      # F_ẏ[:, dif]
                ((kpos[rows] >= 0) & (pd[cols] >= 0) & ~fd_yp[cols], 0,       # dD/dẏ = F_y where
                 r_d, nf + pd[cols]),                                         # F_y does not vary
                ((kpos[rows] >= 0) & (pz[cols] >= 0), 0, r_d, nf + nd + pz[cols]),        # dD/dz
                ((kpos[rows] >= 0) & (pw[cols] >= 0), 1, r_d, nf + nd + nz + pw[cols])):  # dD/dw
            e = np.flatnonzero(sel)
            blocks.append((e, part, jr[e], jc[e]))
        self._exact_entries = [(e, part) for e, part, _, _ in blocks]
        # Finite-difference columns (y and ẏ), each with the kept rows of its pattern, and a
        # greedy coloring of their intersection graph.
        kept_ent = np.flatnonzero(kpos[rows] >= 0)
        by_col = sps.csc_matrix((np.ones(len(kept_ent)), (kpos[rows[kept_ent]], cols[kept_ent])), shape=(nk, n))
        by_col.sum_duplicates()
        fd_cols = [(0, j) for j in self.fd_y] + [(1, j) for j in self.fd_yp]
        occupied: list[list[int]] = [[] for _ in range(nk)]  # groups already perturbing the row
        members: list[list] = []
        for kind, j in fd_cols:
            s = by_col.indices[by_col.indptr[j]:by_col.indptr[j + 1]]
            if not len(s):
                continue  # D does not depend on it: a zero column
            taken = set()
            for r in s.tolist():
                taken.update(occupied[r])
            c = next(c for c in range(len(members) + 1) if c not in taken)
            if c == len(members):
                members.append([])
            for r in s.tolist():
                occupied[r].append(c)
            members[c].append((kind, j, s))
        self._group_entries = []
        fd_rows, fd_cols_out = [], []
        for group in members:
            ycols = np.array([j for kind, j, _ in group if kind == 0], dtype=np.int64)
            ypcols = np.array([j for kind, j, _ in group if kind == 1], dtype=np.int64)
            ent_row = np.concatenate([s for _, _, s in group])
            ent_h = np.concatenate([np.full(len(s), i) for i, (_, _, s) in enumerate(group)])
            # position of each member's step in [h(ycols), h(ypcols)]
            slot = np.array([i for i, (kind, _, _) in enumerate(group) if kind == 0]
                            + [i for i, (kind, _, _) in enumerate(group) if kind == 1], dtype=np.int64)
            inv = np.empty(len(group), dtype=np.int64)
            inv[slot] = np.arange(len(group))
            self._group_entries.append((ycols, ypcols, ent_row, inv[ent_h]))
            fd_rows.append(m + ent_row)
            fd_cols_out.append(np.array([pf[j] if kind == 0 else nf + pd[j] for kind, j, s in group
                                         for _ in range(len(s))], dtype=np.int64))
        C = self.C.tocoo()
        c_sel = np.flatnonzero(pf[C.col] >= 0)
        self._c_data = C.data[c_sel]
        all_rows = np.concatenate([b[2] for b in blocks] + fd_rows + [m + nk + C.row[c_sel]]).astype(np.int64)
        all_cols = np.concatenate([b[3] for b in blocks] + fd_cols_out + [pf[C.col[c_sel]]]).astype(np.int64)
        # CSR structure of J, fixed: each evaluation only fills the data in this order.
        self._shape = (m + nk + self.C.shape[0], nf + nd + nz + nw)
        csr_order = np.lexsort((all_cols, all_rows))
        self._csr_perm = csr_order
        self._csr_indices = all_cols[csr_order]
        self._csr_indptr = np.concatenate([[0], np.cumsum(np.bincount(all_rows, minlength=self._shape[0]))])
        self._nnz = len(all_rows)
        # position of each entry in the flat dense matrix (dense_jacobian: small problems)
        csr_rows = np.repeat(np.arange(self._shape[0], dtype=np.int64), np.diff(self._csr_indptr))
        self._dense_index = csr_rows * self._shape[1] + self._csr_indices

    def _jac_data(self, y, yp):
        """Data of (F_y, F_ẏ) in the module's CSC order."""
        mod = self.mod
        mod.jacobian(self.t0, y, yp, self.p, 0.0, self.buf)
        jy = self.buf.copy()
        mod.jacobian(self.t0, y, yp, self.p, 1.0, self.buf)
        return jy, self.buf - jy

    def _kept_rows(self, jyp) -> np.ndarray:
        """Rows whose time derivative carries information (not absorbed by a private ÿ)."""
        # scipy's matching: no recursion (a long string or beam is a long alternating
        # chain) and no dependence on hashing.
        return np.flatnonzero(bipartite_matching(jyp) < 0).astype(np.int64)

    def hopeless(self, bound: float) -> bool:
        """True when rows of G that are affine in the unknowns cannot all come within `bound`:
        then no iterate of this stage passes its acceptance test (which bounds every row).

        A row is taken as affine in the unknowns ``[y_free, ẏ]`` when its derivatives by
        them are the same at the start and at a random far-away point of the unknowns (held
        values unchanged): a derivative that varies with an unknown differs there but on a
        set of measure zero. The initial relations C y are linear. On these rows
        G = g₀ + A Δu (A their Jacobian at the start); if even the least-squares Δu leaves
        ‖g₀ + A Δu‖₂ above √(rows) · bound — some row above `bound` — with a margin for
        rounding, the stage cannot succeed. The common cases: held states that violate a
        position constraint g(q) = 0 (a row with A = 0), and a beam's mass rows M e = p
        whose guessed momenta do not fit the motion of its ends. When anything is in doubt
        (a point where the model cannot be evaluated, a rank-deficient problem too large for
        a dense solve) the answer is False and the stage runs as always."""
        nf, nd = len(self.free), len(self.dif)
        if not nf + nd:
            return False
        rng = np.random.default_rng(0)
        y1, yp1 = self.y.copy(), self.yp.copy()
        y1[self.free] += (self.s[self.free] + np.abs(y1[self.free])) * rng.uniform(0.5, 1.5, nf)
        yp1[self.dif] += self.s[self.dif] * rng.uniform(0.5, 1.5, nd)
        try:
            f0 = self.F(self.y, self.yp)
            jy0, jyp0 = self._jac_data(self.y, self.yp)
            jy0 = jy0.copy()
            jy1, jyp1 = self._jac_data(y1, yp1)
        except (ModelEvaluationError, ArithmeticError, ValueError, TypeError):
            return False
        # A = [F_y[:, free] F_ẏ[:, dif]; C[:, free] 0] and g₀ = [F; C y], rows scaled as in G
        n, m, rows, cols = self.mod.N, self.m, self.rows, self.cols
        position = np.full(n, -1, dtype=np.int64)
        position[self.free] = np.arange(nf)
        dpos = np.full(n, -1, dtype=np.int64)
        dpos[self.dif] = np.arange(nd)
        if self.C.shape[0]:
            C = self.C.tocoo()
            c_row, c_col, c_data, cy = C.row, C.col, C.data, self.C @ self.y - self.c
        else:  # no initial relations (a restart at an event): no sparse matrices for nothing
            c_row = c_col = np.zeros(0, dtype=np.int64)
            c_data = cy = np.zeros(0)
        ey = np.flatnonzero((position[cols] >= 0) & (jy0 != 0))
        eyp = np.flatnonzero((dpos[cols] >= 0) & (jyp0 != 0))
        ec = np.flatnonzero((position[c_col] >= 0) & (c_data != 0))
        curved = np.zeros(m, dtype=bool)  # a derivative by an unknown varies
        curved[rows[((position[cols] >= 0) & (jy0 != jy1)) | (jyp0 != jyp1)]] = True
        keep = np.concatenate([~curved, np.ones(len(cy), dtype=bool)])
        g0 = np.concatenate([self.row_scale * f0, cy])
        touched = np.zeros(len(g0), dtype=bool)  # rows with an unknown
        touched[np.concatenate([rows[ey], rows[eyp], m + c_row[ec]])] = True
        if not np.all(np.isfinite(g0[keep])):
            return False
        if _norm(g0[keep & ~touched]) > bound:
            return True  # a row of held values only that misses the bound
        at = np.where(keep, np.cumsum(keep) - 1, -1)  # row of A of each row of G
        scale = np.concatenate([self.row_scale, np.ones(len(cy))])
        ar, ac, av = [], [], []
        for r, c, v in ((rows[ey], position[cols[ey]], jy0[ey]), (rows[eyp], nf + dpos[cols[eyp]], jyp0[eyp]),
                        (m + c_row[ec], position[c_col[ec]], c_data[ec])):
            k = at[r] >= 0
            ar.append(at[r[k]])
            ac.append(c[k])
            av.append(scale[r[k]] * v[k])
        shape = (int(keep.sum()), nf + nd)
        ar, ac, av = np.concatenate(ar), np.concatenate(ac), np.concatenate(av)
        if shape[0] * shape[1] <= DENSE_SOLVE_LIMIT:  # solved dense anyway: no sparse matrix (a restart at an event)
            A = np.bincount(ar * shape[1] + ac, weights=av, minlength=shape[0] * shape[1]).reshape(shape)
            values = A.ravel()
        else:
            A = sps.csr_matrix((av, (ar, ac)), shape=shape)  # duplicates are summed
            values = A.data
        g0 = g0[keep]
        if not len(g0) or not np.all(np.isfinite(values)):
            return False

        # a residual ‖g₀ + A Δu‖₂ above `enough` is hopeless (some row above the bound, with a
        # margin for rounding)
        norm_g0 = float(np.linalg.norm(g0))
        enough = max(10 * np.sqrt(len(g0)) * bound, 1e-8 * norm_g0)
        if norm_g0 <= enough:
            return False

        def hopeless_after(du):
            return float(np.linalg.norm(g0 + A @ du)) > enough

        # Any Δu bounds the least residual from above, so an LSMR answer that is not hopeless
        # is final: no factorization, and LSMR stops as soon as its residual (decreasing at
        # each step) is below `enough` (btol), or after min(m, n) steps, where it ends in exact
        # arithmetic. "Hopeless" is decided only by an exact solve.
        if A.shape[0] * A.shape[1] > DENSE_SOLVE_LIMIT:
            du = lsmr_min_norm(A, -g0, maxiter=min(A.shape), btol=enough / norm_g0)[0]
            if not hopeless_after(du):
                return False
        du = min_norm_solve(A, -g0, dense_limit=DENSE_LIMIT, iterative=False)
        if du is None:
            return False  # rank-deficient and too large for a dense solve: in doubt
        return hopeless_after(du)

    def energy_metric(self):
        """``T`` with ``Tᵀ K T = I``, K the Hessian of the stored energy H by the guessed
        states at the start, when K is positive definite (momenta and strains: a field's
        mass and stiffness matrices, a body's inverse inertia): the guesses then change as
        little as possible in the energy norm ``ΔyᵀKΔy`` — what the change does to the
        physics, the same in every unit system and on every mesh. None (the nominal scales
        are the metric) when some guessed state stores no energy (a position under gravity,
        a multiplier), when H cannot be evaluated, or beyond :data:`ENERGY_METRIC_LIMIT`
        guesses. K comes from second differences of ``hamiltonian`` (exact for the
        quadratic energies of fields up to rounding)."""
        if self._metric is not False:
            return self._metric
        self._metric = None
        cols = self.free[self.guess_columns]
        n = len(cols)
        hamiltonian = getattr(self.mod, "hamiltonian", None)
        if hamiltonian is None or not n or n > ENERGY_METRIC_LIMIT:
            return None
        y0 = self.y.copy()
        d = np.maximum(np.abs(y0[cols]), self.s[cols])
        d = np.where(d > 0, d, 1.0)
        try:
            def H(delta):
                y = y0.copy()
                y[cols] += delta
                return float(hamiltonian(self.t0, y, self.p))

            h0 = H(np.zeros(n))
            hp, hm = np.zeros(n), np.zeros(n)
            for i in range(n):
                # large enough steps that the change of H stands out of the rounding of H
                # (a pendulum in mm and g: H ~ 6e9 of potential, ½p²/m ~ 1e-3 for p = 1)
                for _ in range(16):
                    e = np.zeros(n)
                    e[i] = d[i]
                    hp[i], hm[i] = H(e), H(-e)
                    if abs(hp[i] + hm[i] - 2 * h0) > 1e-7 * (abs(h0) + abs(hp[i]) + abs(hm[i])):
                        break
                    d[i] *= 10.0
            eye = np.diag(d)
            K = np.diag((hp + hm - 2 * h0) / d**2)
            for i in range(n):
                for j in range(i + 1, n):
                    K[i, j] = K[j, i] = (H(eye[i] + eye[j]) - hp[i] - hp[j] + h0) / (d[i] * d[j])
        except (ModelEvaluationError, ArithmeticError, ValueError, TypeError):
            return None
        if not np.all(np.isfinite(K)) or not np.all(np.diag(K) > 0):
            return None
        D = np.sqrt(np.diag(K))
        Kn = K / np.outer(D, D)  # unit diagonal: what is left of an exact zero is rounding
        Kn[np.abs(Kn) < 1e-9] = 0.0
        try:
            Lc = np.linalg.cholesky(Kn)
        except np.linalg.LinAlgError:
            return None
        if np.diag(Lc).min() < 1e-6:
            return None  # (nearly) singular: some direction stores no energy
        # Δy = D⁻¹ L⁻ᵀ v: ‖v‖² = Δyᵀ K Δy
        self._metric = sla.solve_triangular(Lc.T, np.eye(n), lower=False) / D[:, None]
        self._hessian = (Lc @ Lc.T) * np.outer(D, D)  # K (rounding-level entries dropped)
        return self._metric

    def unpack(self, u):
        nf, nd, nz, nw = self.sizes
        y, yp, z, w = self.y.copy(), self.yp.copy(), self.z.copy(), self.w.copy()
        y[self.free] = u[:nf]
        yp[self.dif] = u[nf:nf + nd]
        z[self.zc] = u[nf + nd:nf + nd + nz]
        w[self.wc] = u[nf + nd + nz:]
        return y, yp, z, w

    def pack(self):
        return np.concatenate([self.y[self.free], self.yp[self.dif], self.z[self.zc], self.w[self.wc]])

    def F(self, y, yp):
        out = np.zeros(self.m)
        self.mod.residual(self.t0, y, yp, self.p, out)
        return out

    def D(self, y, yp, z, w, jy=None, jyp=None):
        """Kept rows of F_y ẏ + F_ẏ w + F_t (ẏ = ẏ on differential variables, z elsewhere);
        `jy`, `jyp`: the data of `_jac_data(y, yp)` if already at hand."""
        if not len(self.kept):
            return np.zeros(0)
        if self._d_ent is None:
            self._prepare_d()
        if jy is None:
            jy, jyp = self._jac_data(y, yp)
        ydot = z.copy()
        ydot[self.dif] = yp[self.dif]
        ft = np.zeros(self.m)
        self.mod.residual_t(self.t0, y, yp, self.p, ft)
        e, r, c, nk = self._d_ent, self._d_row, self._d_col, len(self.kept)
        return (np.bincount(r, jy[e] * ydot[c], minlength=nk) + np.bincount(r, jyp[e] * w[c], minlength=nk)
                + ft[self.kept])

    def G(self, u):
        y, yp, z, w = self.unpack(u)
        return np.concatenate([self.row_scale * self.F(y, yp), self.row_scale[self.kept] * self.D(y, yp, z, w),
                               self.C @ y - self.c if self.C.shape[0] else self.c])

    def jacobian(self, u):
        """The Newton matrix of G at u (sparse)."""
        return sps.csr_matrix((self._jacobian_data(u), self._csr_indices, self._csr_indptr), shape=self._shape)

    def dense_jacobian(self, u) -> np.ndarray:
        """The Newton matrix of G at u as a dense array (for a small problem: no sparse
        matrix is built; the same entries as :meth:`jacobian`)."""
        data = self._jacobian_data(u)  # (prepares the problem on first use)
        size = self._shape[0] * self._shape[1]
        return np.bincount(self._dense_index, weights=data, minlength=size).reshape(self._shape)

    def shape(self) -> tuple[int, int]:
        """The shape of the Newton matrix."""
        nk = len(self.kept)
        return self.m + nk + self.C.shape[0], sum(self.sizes)

    def _jacobian_data(self, u) -> np.ndarray:
        """The Newton matrix's entries at u in its CSR order."""
        if not self._prepared:
            self._prepare()
        y, yp, z, w = self.unpack(u)
        jy, jyp = self._jac_data(y, yp)
        data = np.empty(self._nnz)
        pos = 0
        for e, part, scale in self._exact:
            data[pos:pos + len(e)] = scale * (jyp if part else jy)[e]
            pos += len(e)
        if self._groups:
            base = self.D(y, yp, z, w, jy, jyp)
            # D is bilinear: exact parts plus finite differences where the Jacobian varies
            # (a ẏ column of those includes its exact F_y part), one evaluation per group.
            for ycols, ypcols, ent_row, ent_h, scale in self._groups:
                hy = 1e-7 * np.maximum(self.s[ycols], np.abs(y[ycols]))
                hyp = 1e-7 * np.maximum(self.s[ypcols], np.abs(yp[ypcols]))
                yh, yph = y.copy(), yp.copy()
                yh[ycols] += hy
                yph[ypcols] += hyp
                col = (self.D(yh, yph, z, w) - base)[ent_row] / np.concatenate([hy, hyp])[ent_h]
                data[pos:pos + len(ent_row)] = scale * col
                pos += len(ent_row)
        data[pos:] = self._c_data
        return data[self._csr_perm]

    def step(self, J, g):
        """Weighted minimum-norm solution of J Δu = −g.

        When guessed states are among the unknowns, their change is what is minimized, and
        the nuisance unknowns (ẏ, algebraic variables, the derivatives of the hidden
        constraints) are free: the step is the minimum-norm change ``Δy_g`` (relative to the
        guesses' scales) among those the other unknowns can complete, then the minimum-norm
        completion. A finite price on the nuisance unknowns would trade a guess against
        them, and they are not of the guess's size: the rates of a wave (ė = T ∂v/∂ξ, 50 m/s
        wave speed) are large where the momenta are 1e-3 kg/(m·s) in SI, so the cheapest
        step shrank a pinned string's whole momentum field by 38 % instead of moving the
        two end values the pins demand (and the answer depended on the units). Dense
        problems (at most :data:`DENSE_LIMIT` Jacobian entries) get it from
        :func:`_nested_min_norm`, larger ones from :meth:`_sparse_nested_step`; where that
        fails, the step (and every later one of this problem) is the weighted minimum-norm
        step with the nuisance priced at :data:`CHEAP` × scale. `J` is sparse, or a dense
        array (:meth:`dense_jacobian`, a small problem)."""
        dense = isinstance(J, np.ndarray)
        JW = J * self.weights[None, :] if dense else J @ _diagonal(self.weights)
        guess = self.guess_columns
        if len(guess) and JW.shape[0] * JW.shape[1] <= DENSE_LIMIT:
            A = JW if dense else JW.toarray()
            T = self.energy_metric()
            if T is None:
                return self.weights * _nested_min_norm(A, -g, guess)
            A[:, guess] = (J[:, guess] if dense else J[:, guess].toarray()) @ T
            v = _nested_min_norm(A, -g, guess)
            du = self.weights * v
            du[guess] = T @ v[guess]
            return du
        if len(guess) and not self._kkt_failed:
            v = self._sparse_nested_step(sps.csr_matrix(JW) if dense else JW, -g)
            if v is not None:
                return self.weights * v
            # as LeastNorm with a singular LU: the later Newton matrices differ by the move
            # of the iterate, not in what made this one fail; do not pay for it again
            self._kkt_failed = True
        # dense QR with column pivoting (gelsy) when small, else a sparse LU of the regular
        # system, else LSMR (phc.simulation.minnorm)
        return self.weights * self.solver.solve(JW, -g)

    def _sparse_nested_step(self, A, b):
        """The step of :func:`_nested_min_norm` for a sparse `A` (the Newton matrix in the
        weighted unknowns v), through one sparse LU of the optimality system
        ``[[E, Aᵀ], [A, 0]] [v; λ] = [0; b]`` of ``min ½vᵀEv subject to A v = b``: E is the
        guesses' metric on their columns (the energy Hessian ``S K S`` in the weighted
        guesses, S their scales, when :meth:`energy_metric` has one; else I, their nominal
        scales) and δ = :data:`KKT_REGULARIZATION` on the nuisance columns (the dense path's
        second-stage weights, scaled down), so the nuisance unknowns the equations leave
        undetermined do not make the system singular. What δ trades of the guesses' minimum
        is taken back by proximal sweeps with the same factors (the nuisance part pulled
        towards the last sweep's, at most :data:`KKT_SWEEPS`; they end when the guesses'
        part stops changing), whose limit is the nested solution. None — the caller then
        takes the weighted minimum-norm step — when the factorization fails (dependent
        rows, an inconsistent system) or a sweep misses the optimality system by more than
        its rounding, :data:`~phc.simulation.minnorm.CONSISTENT` of ``‖K‖∞‖x‖∞ + ‖rhs‖∞``
        after one step of iterative refinement."""
        guess = self.guess_columns
        n = A.shape[1]
        A = sps.csr_matrix(A)
        T = self.energy_metric()
        scale = float(np.max(np.abs(A.data))) if A.nnz else 0.0
        if scale == 0.0 or not np.all(np.isfinite(A.data)) or not np.all(np.isfinite(b)):
            return None
        prox = np.full(n, KKT_REGULARIZATION)  # δ on the nuisance columns
        prox[guess] = 0.0
        if T is None:
            E = _diagonal(np.where(prox > 0, prox, 1.0))
        else:
            sg = self.weights[guess]
            Kg = self._hessian * np.outer(sg, sg)
            Kg /= float(np.max(np.diag(Kg)))  # unit size, like the nominal metric
            rows, cols = np.nonzero(Kg)
            E = _diagonal(prox) + sps.csr_matrix((Kg[rows, cols], (guess[rows], guess[cols])), shape=(n, n))
        # λ scaled by `scale`: the blocks are of one size (no change of v)
        K = sps.bmat([[E, A.T / scale], [A / scale, None]], format="csc")
        norm_k = float(abs(K).sum(axis=1).max())  # ‖K‖∞
        try:
            lu = sparse_lu(K)
        except (RuntimeError, ValueError):
            return None
        v = np.zeros(n)
        for _ in range(KKT_SWEEPS):
            # min ½v_gᵀE v_g + ½δ‖v_n − v_n⁽ᵏ⁾‖² subject to A v = b (proximal steps on the
            # nuisance block): each sweep shrinks what δ trades of the guesses' minimum by
            # about δ times the nuisance/guess ratio (a 400-element string's end node: 1.6e5,
            # so its neighbour is off by 1.6e-5 of ρv after one sweep, round-off after three).
            rhs = np.concatenate([prox * v, b / scale])
            x = lu.solve(rhs)
            if not np.all(np.isfinite(x)):
                return None
            x += lu.solve(rhs - K @ x)
            if not np.all(np.isfinite(x)) or _norm(K @ x - rhs) > CONSISTENT * (norm_k * _norm(x) + _norm(rhs)):
                return None
            done = _norm(x[guess] - v[guess]) <= np.finfo(float).eps * _norm(x[guess])
            v = x[:n]
            if done:
                break
        return v


KKT_REGULARIZATION = 1e-10
"""Weight δ of the nuisance unknowns, relative to the guesses' metric, in the sparse nested
least-norm step (:meth:`_Problem._sparse_nested_step`)."""
KKT_SWEEPS = 4
"""Proximal sweeps of that step at most (each one solve with the same factors)."""

RANGE_TOL = 1e-12
"""Directions of the nuisance columns weaker than this, relative to the strongest, are not
taken as their range (rounding)."""


def _nested_min_norm(A, b, first) -> np.ndarray:
    """A solution v of ``A v = b`` (least squares if there is none) whose part ``v[first]``
    has the least norm among all such solutions, and whose other part then has the least
    norm: the nuisance columns N absorb what they can for free (``b`` and the columns of
    `first` are projected onto the complement of N's range), the `first` part is the
    minimum-norm solution of what is left, and N completes it. Where that misses b by
    more than rounding, one step of iterative refinement (the same split applied to what
    is left of b) restores the accuracy the projection loses when N is ill-conditioned."""
    n = A.shape[1]
    rest = np.setdiff1d(np.arange(n), first)
    G, N = A[:, first], A[:, rest]
    Q = None
    if N.shape[1]:
        Q, R, _ = sla.qr(N, mode="economic", pivoting=True)
        d = np.abs(np.diag(R))
        rank = int(np.sum(d > RANGE_TOL * d[0])) if len(d) and d[0] > 0 else 0
        Q = Q[:, :rank]
        Gp = G - Q @ (Q.T @ G)
    else:
        Gp = G

    def split(rhs):
        v = np.zeros(n)
        v[first] = dense_min_norm(Gp, rhs if Q is None else rhs - Q @ (Q.T @ rhs))
        if N.shape[1]:
            v[rest] = dense_min_norm(N, rhs - G @ v[first])
        return v

    # Where N is ill-conditioned (the stiff slope rows of a Hermite beam driven at its ends)
    # the split can leave more of b unsolved than the plain weighted minimum-norm solution:
    # then that one is the step (the guesses then move as the weights say, as before). A miss
    # within the rounding of A v itself (backward error ‖A v − b‖ ≤ ε (‖A‖_F ‖v‖ + ‖b‖), what
    # any backward-stable solve leaves) is not one. It used to be judged against 1e-14 ‖b‖,
    # below the rounding of a string's wave rows (‖A‖ ~ 1e4), so the plain step was taken,
    # which shrinks the nuisance rates at the guesses' expense: a string whose end node had
    # to follow a moving mass got a linear velocity ramp over its whole length (kinetic
    # energy ρLv²/6) instead of a change near the end node alone (at most ρhv²/6).
    norm_a, norm_b = np.linalg.norm(A), np.linalg.norm(b)
    v = split(b)
    miss = np.linalg.norm(A @ v - b)
    if miss > np.finfo(float).eps * (norm_a * np.linalg.norm(v) + norm_b):
        v += split(b - A @ v)
        miss = np.linalg.norm(A @ v - b)
    plain = dense_min_norm(A, b)
    miss_plain = np.linalg.norm(A @ plain - b)
    # the rounding allowed is that of a step of the plain step's size: a split that blows up
    # (‖v‖ ≫ ‖plain‖, the nuisance block nearly singular) has a backward error as large as
    # its size permits, and is no step to take (a Timoshenko beam's certificate samples:
    # ‖v‖ = 1e8 against 2e3, which collapsed the sampled states)
    size = min(np.linalg.norm(v), np.linalg.norm(plain))
    return v if miss <= 2 * miss_plain + np.finfo(float).eps * (norm_a * size + norm_b) else plain


def _solve(prob: _Problem, tol: float, max_iter: int, rescue: bool = True):
    """Gauss–Newton (:func:`phc.simulation.gauss_newton.gauss_newton`) on ``G = 0`` from the
    problem's start, with its weighted least-norm steps (:meth:`_Problem.step`), then (with
    `rescue`) a least-squares solve from the best point where that ends above `tol`. Returns
    the point and the iterations (plus the least-squares solve's evaluations)."""
    # Full Gauss–Newton steps, no monotonicity test: D is bilinear (velocity products,
    # forces times rotation rates), so from a rough guess the residual may grow once
    # before converging quadratically (seen on the slider–crank at dead centre); the best
    # iterate is kept.
    # Converged, it refines to round-off (POLISH_STEPS). `tol` bounds the equilibrated
    # residual, but an index-2 DAE magnifies what is left: a velocity constraint off by δ makes
    # IDA's first corrector move the momenta by δ and the efforts by δ/h, so the supplied
    # energy (∫ effort·flow) jumps by O(δ) at every step size and the error test fails at t₀.
    # What one step leaves depends on the BLAS kernel's rounding (it differs between CPUs), and
    # the max-norm cannot tell: large D rows sit at their round-off while small F rows are
    # still off. So take the refining steps and keep the last iterate that stays converged.
    # a small problem (solved dense anyway) takes its Newton matrix dense: building a sparse
    # one costs more than the whole solve of a few unknowns (a restart at every event of a run)
    rows, cols = prob.shape()
    jacobian = prob.dense_jacobian if rows * cols <= DENSE_SOLVE_LIMIT else prob.jacobian
    out = gauss_newton(prob.pack(), lambda u: (prob.G(u), None), lambda u, g, _: prob.step(jacobian(u), g),
                       tol=tol, max_iter=max_iter, polish=POLISH_STEPS, keep_best=True)
    best, size, it = out
    if rescue and size > tol and len(best) * len(prob.G(best)) <= DENSE_LIMIT:
        sol = least_squares(prob.G, best, lambda x: prob.jacobian(x).toarray(), max_nfev=200)
        if _norm(sol.fun) < size:
            best = sol.x
        it += sol.nfev
    return best, it


def consistent_initial_conditions(mod, p, t0: float, values: dict[int, float], fixed: set[int],
                                  tol: float = 1e-11, max_iter: int = 25,
                                  initial_relations: bool = True, rescue: bool = True) -> InitialResult:
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
    initial_relations : bool
        Impose the module's INITIAL relations (true at the start of a run, false when
        restarting at an input breakpoint).
    rescue : bool
        Where Gauss–Newton ends above the tolerance, try SciPy's least-squares solve from its
        best point (dense, up to 200 evaluations: minutes for a system of a thousand
        unknowns). A caller that can do without this point (a certificate's random sample)
        passes false.

    Raises
    ------
    InconsistentInitialError
        When the fixed values violate an equation; the message names the equation(s).
    """
    # its dense solves with one BLAS thread (phc.simulation.minnorm.one_blas_thread)
    with one_blas_thread():
        return _initial_conditions(mod, p, t0, values, fixed, tol, max_iter, initial_relations, rescue)


def _initial_conditions(mod, p, t0, values, fixed, tol, max_iter, initial_relations, rescue=True) -> InitialResult:
    n = mod.N
    y = np.zeros(n)
    for j, v in values.items():
        y[j] = v
    # Solved in the model's units first (rows equilibrated, tolerance relative to the largest
    # value). That start is then checked in the scaled variables (nominal scales from the
    # given values and the rows, phc.simulation.scaling): each row against its largest term.
    # A mechanism whose momenta are 1e-11 kg·m/s in SI passes the first test with all momenta
    # 0 and a GGL multiplier absorbing the velocity constraint; it fails the second and is
    # solved again in the scaled variables (kept if that succeeds).
    # The scales are computed only when used (their energy sizes cost an evaluation of H per
    # state, batched): a restart at a breakpoint or an event that solves in the model's units
    # never needs them.
    from phc.simulation.scaling import nominal_scales

    def scales():
        return nominal_scales(mod, p, y, np.zeros(n), t0=t0, probe=False, residual=True)

    try:
        result = _consistent(mod, p, t0, y, values, fixed, tol, max_iter, initial_relations, None, rescue)
    except InconsistentInitialError as err:
        try:
            return _consistent(mod, p, t0, y, values, fixed, tol, max_iter, initial_relations, scales(), rescue)
        except (InconsistentInitialError, ModelEvaluationError):
            raise err from None
    # (at the start of a run only: a restart at a breakpoint or an event continues a run whose
    # states were computed in the model's units)
    if not SCALED_CHECK or not initial_relations:
        return result
    s = scales()
    if _scaled_residual(mod, p, t0, result, s) <= SCALED_MISS:
        return result
    try:
        return _consistent(mod, p, t0, y, values, fixed, tol, max_iter, initial_relations, s, rescue)
    except (InconsistentInitialError, ModelEvaluationError):
        return result


def _scaled_residual(mod, p, t0, result: InitialResult, s) -> float:
    """max_i |F_i| / r_i at the start found, r_i the largest term of row i in the scaled
    variables (``max_k |∂F_i/∂y_k| s_k`` and the same for ẏ)."""
    rows, cols = np.asarray(mod.JAC_ROWS), np.asarray(mod.JAC_COLS)
    m = len(mod.EQUATIONS)
    f = np.zeros(m)
    buf = np.zeros(len(rows))
    try:
        mod.residual(t0, result.y0, result.yp0, p, f)
        mod.jacobian(t0, result.y0, result.yp0, p, 0.0, buf)
        jy = buf.copy()
        mod.jacobian(t0, result.y0, result.yp0, p, 1.0, buf)
    except ModelEvaluationError:
        return 0.0
    r = np.zeros(m)
    np.maximum.at(r, rows, np.abs(jy) * s[cols])
    np.maximum.at(r, rows, np.abs(buf - jy) * s[cols])
    ok = r > 0
    if not ok.any() or not np.all(np.isfinite(f)):
        return 0.0
    return float(np.max(np.abs(f[ok]) / r[ok]))


def _chosen(mod, y1, dif, fixed, values, scale, s) -> dict:
    """The states the initialization chose: not fixed, not the energy accumulator, moved from
    the value given (0 where none) by more than 1e-12 of their scale (vectorized: a
    10⁵-element string has 200 002 states)."""
    idx = np.array(sorted(dif), dtype=np.int64)
    if not len(idx):
        return {}
    given = np.zeros(mod.N)
    for j, v in values.items():
        given[j] = v
    size = 1e-12 * (scale if s is None else np.asarray(s, dtype=float)[idx])
    moved = np.abs(y1[idx] - given[idx]) > size
    moved &= ~np.isin(idx, np.fromiter(fixed, dtype=np.int64, count=len(fixed)))
    moved &= np.asarray(mod.ROLES, dtype=object)[idx] != "energy"
    return {mod.VARIABLES[j]: float(y1[j]) for j in idx[moved].tolist()}


def _consistent(mod, p, t0, y, values, fixed, tol, max_iter, initial_relations, s, rescue) -> InitialResult:
    """One consistent initialization, in the model's units (`s` None) or in the variables
    scaled by `s`."""
    n = mod.N
    scale = max(1.0, float(np.abs(y).max(initial=0))) if s is None else 1.0
    dif = set(np.flatnonzero(np.asarray(mod.DIFFERENTIAL)).tolist())
    stages = [fixed | dif] if fixed >= dif else [fixed | dif, fixed]
    total = 0
    prob = None
    for k, stage_fixed in enumerate(stages):
        prob = _Problem(mod, p, t0, y, stage_fixed, initial_relations, like=prob, scales=s)
        if k < len(stages) - 1 and prob.hopeless(10 * tol * scale):
            continue  # this stage cannot succeed: the next one starts from the same values
        u, it = _solve(prob, tol * scale, max_iter, rescue)
        total += it
        y1, yp1, _, _ = prob.unpack(u)
        g = prob.G(u)
        # Accept only a solution IDA will accept too: its first error test would otherwise
        # see the remaining mismatch as a jump of the states.
        if _norm(g) <= 10 * tol * scale:
            return InitialResult(y1, yp1, _chosen(mod, y1, dif, fixed, values, scale, s), _norm(g), total)
    f_final = g[:prob.m] / prob.row_scale
    d_final = np.zeros(prob.m)
    d_final[prob.kept] = g[prob.m:prob.m + len(prob.kept)] / prob.row_scale[prob.kept]
    if s is None:
        bad = np.flatnonzero(np.abs(f_final) > 10 * tol * scale)
        bad_d = np.flatnonzero(np.abs(d_final) > 1e-6 * scale)
    else:  # judged in the scaled rows, reported in the model's units
        bad = np.flatnonzero(np.abs(g[:prob.m]) > 10 * tol)
        bad_d = np.flatnonzero(np.abs(d_final * prob.row_scale) > 1e-6)
    raise InconsistentInitialError(_explain(mod, f_final, d_final, bad, bad_d, fixed))


def _explain(mod, f, d, bad, bad_d, fixed) -> list[str]:
    jrows, jcols = np.asarray(mod.JAC_ROWS), np.asarray(mod.JAC_COLS)
    lines = []
    for rows, res, what in ((bad, f, "is violated"), (bad_d, d, "cannot hold: its time derivative is violated")):
        for i in rows[:8]:
            involved = sorted({mod.VARIABLES[j] for j in jcols[jrows == i] if j in fixed})
            fixed_txt = f" (fixed values involved: {', '.join(f'`{v}`' for v in involved)})" if involved else ""
            lines.append(f"equation `{mod.EQUATIONS[i]}` {what} by {res[i]:.3g} at t0{fixed_txt}")
    return lines or ["the initialization did not converge; give better initial values or guesses"]
