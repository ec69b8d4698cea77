"""Do the rows compiled for a component say what its description says?

Input: an assembled :class:`~phc.ir.dae.Dae` (its topology keeps each component's
description and the rows its lowerer emitted, before assembly; its sparse blocks keep
their labels). Output: a :class:`RowsCertificate` with one located error per component
whose rows and description differ.

Each component with a complete description (storage bound to states, resistive pairs to
laws; see :mod:`phc.library.dirac`) is a pair of systems over the same *visible*
variables — its states x, their rates ẋ and its port flows and efforts:

* the rows: residual rows, sparse blocks (:class:`~phc.ir.dae.LinearBlock`, with the sympy
  couplings added to their rows) and definitions, with the component's other algebraic
  variables (velocities, co-energies, multipliers) as *hidden* unknowns;
* the description: its kernel relations ``F f + E e + G λ = b(t)`` and its laws, scalar
  or sparse (:class:`~phc.ir.dae.SparseRelations`), with each storage pair replaced by
  ``(ẋ, ∂H/∂x)`` (storage vectors by ``(ẋ, Qx)``) and the multipliers, resistive pairs
  and auxiliary variables hidden. A discretized PDE, a modal truncation, a matrix
  component and the moving beam register the projection of their structure onto their
  ports for the Dirac certificate; their complete description is its `structure`.

Both define a set of visible points (∃ hidden). They are the same relation iff every
point of one lies in the other and, at those points, the tangent spaces of the two sets
(projected onto the visible variables) agree. Time and every symbol foreign to the
component (another component's state read by a modulation) are fixed at random values
and the parameters at their defaults. Two ways of testing it:

* **affine** (every sparse component whose rows are linear in its unknowns: strings,
  beams, ``pde1d``, modal truncations, ``linear_phs``): both sets are affine, and a random
  point of an affine set lies in another affine set with probability 1 only if the whole
  set does. A random point of each (the nearest point to a Gaussian vector, a sparse
  saddle-point solve) is tested for membership in the other (a sparse least-squares solve
  for the other's hidden unknowns). This is exact up to round-off and costs a few sparse
  LU factorizations, so meshes of any size up to :data:`MAX_SPARSE_UNKNOWNS` are compared;
* **dense** (nonlinear rows: lumped and rigid components, the moving beam): points found
  by a minimum-norm Newton iteration from random starts, membership from both sides and
  equal tangent spaces, with dense linear algebra up to :data:`MAX_UNKNOWNS`. A relation
  that is linear at fixed states is decided by one point and its tangent space;
  nonlinear laws are sampled.

A wrong sign in any row, a dropped term, a flipped entry of a sparse block, a source
that imposes −u instead of u, or a kinematic row θ̇ = −ω where the description says
θ̇ = ω is found, whether or not it changes the energy balance.
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace
from functools import lru_cache
from typing import Optional

import numpy as np
import scipy.sparse as sps
import scipy.sparse.linalg as spla
import sympy as sp

from phc.frontend.budget import drop_deltas
from phc.checks.rows_dense import (MEMBERSHIP_TOL, RESIDUAL_TOL, RESTARTS, SETTLED_FRACTION,  # noqa: F401
                                      _member, _newton, _scaled, _visible_tangent, _worst)
from phc.ir.dae import T, ComponentDescription, ComponentRows, Dae
from phc.diagnostics import Diagnostic, DiagnosticList

MAX_UNKNOWNS = 400
"""Components with nonlinear rows and more unknowns than this are not compared (dense
linear algebra)."""
MAX_SPARSE_UNKNOWNS = 200_000
"""Components with affine rows and more unknowns than this are not compared (sparse LU)."""
ANGLE_TOL = 1e-6
"""Largest allowed distance between orthonormal bases of the two tangent spaces."""


@dataclass
class RowsCertificate:
    compared: list[str] = field(default_factory=list)
    not_compared: list[tuple[str, str]] = field(default_factory=list)
    """(component, why) for components whose rows were not compared with a description."""
    inconclusive: list[tuple[str, str]] = field(default_factory=list)
    diagnostics: DiagnosticList = field(default_factory=DiagnosticList)
    samples: int = 0
    shared: int = 0
    """How many of `compared` were the same systems (up to names) as a component compared
    before them, and share its verdict (see :func:`check_rows`)."""

    @property
    def ok(self) -> bool:
        return not self.diagnostics.has_errors

    def summary(self) -> str:
        text = f"rows match the description for {len(self.compared)} component(s)"
        if self.not_compared:
            text += f"; {len(self.not_compared)} not compared (certified by the energy balance only)"
        return text


@dataclass
class _System:
    """Rows ``F(u) = L u + g(u) = 0`` over unknowns u = (visible, hidden) at fixed time and
    foreign values: `linear` is the sparse part L (sparse blocks, parameters at their
    defaults; None if there is none), `exprs` the sympy part g, one per row."""

    labels: list[str]
    exprs: list[sp.Expr]
    unknowns: list[sp.Symbol]
    n_visible: int
    linear: Optional[sps.csr_matrix] = None
    _values: object = None

    def compile(self, fixed_symbols: list) -> None:
        """Generate g and its (sparse) Jacobian as functions of (u, values of `fixed_symbols`).

        The Jacobian of analytic expressions is evaluated by the complex step,
        ``∂g/∂u_j = Im g(u + i·h·e_j) / h`` with h = 1e-30 — exact to round-off, no
        subtraction, all columns in one vectorized call — instead of differentiating
        symbolically (whose printed derivatives of a moving frame's t = (q_f − q_0)/ℓ cost
        more than the whole comparison). Expressions with non-analytic functions (|x|,
        sign, piecewise laws) are differentiated symbolically."""
        index = {s: j for j, s in enumerate(self.unknowns)}
        unknown = set(index)
        rows = [i for i, e in enumerate(self.exprs) if e != 0]
        exprs = [self.exprs[i] for i in rows]
        used = sorted(set().union(*(e.free_symbols for e in exprs)) & unknown, key=lambda s: index[s])
        local = {s: k for k, s in enumerate(used)}
        # in the order of the unknowns, not of their names: two components that differ only in
        # their names get the same pattern (see `key`)
        pattern = [(n, local[s]) for n, e in enumerate(exprs) for s in sorted(e.free_symbols & unknown, key=local.get)]
        self._rows = np.array(rows, dtype=int)
        self._used = np.array([index[s] for s in used], dtype=int)
        self._ji = np.array([rows[n] for n, _ in pattern], dtype=int)
        self._jj = np.array([self._used[k] for _, k in pattern], dtype=int)
        self._pattern = (np.array([n for n, _ in pattern], dtype=int), np.array([k for _, k in pattern], dtype=int))
        self._n_g = len(exprs)
        self._complex = not any(e.has(*_NON_ANALYTIC) for e in exprs)
        # almost everywhere: the derivative of sign/heaviside is 0, not a Dirac delta
        derivatives = [] if self._complex else [drop_deltas(sp.diff(exprs[n], used[k])) for n, k in pattern]
        # Plain argument names: lambdify would otherwise replace each symbol whose name is
        # not an identifier (`der(x)`, `a.f`) in a pass of its own over all expressions.
        args_u = [sp.Symbol(f"_u{k}", real=True) for k in range(len(used))]
        args_p = [sp.Symbol(f"_p{k}", real=True) for k in range(len(fixed_symbols))]
        plain = {**dict(zip(used, args_u)), **dict(zip(fixed_symbols, args_p))}
        self._plain = tuple(e.xreplace(plain) for e in (*exprs, *derivatives))
        self._args = (args_u, args_p)
        self._gdg = None  # made on the first evaluation (see `_function`)
        self._cache = (None, None)
        self._affine_of = (exprs, derivatives, unknown)
        self._affine = None
        self._dense = None
        linear = None if self.linear is None else sps.csr_matrix(self.linear)
        if linear is not None:
            linear.sort_indices()
        self.key = (len(self.exprs), len(self.unknowns), self.n_visible, tuple(rows), tuple(self._used.tolist()),
                    tuple(pattern), self._complex, self._plain,
                    None if linear is None else (linear.shape, linear.indptr.tobytes(), linear.indices.tobytes(),
                                                 linear.data.tobytes()))
        """The system up to the names of its unknowns and fixed symbols: equal keys, equal systems
        once the k-th unknown of one is the k-th of the other (and likewise the fixed values)."""

    @property
    def affine(self) -> bool:
        """F is affine in u (its Jacobian depends on fixed values only); found when first asked
        (only sparse components are tested as affine systems)."""
        if self._affine is None:
            exprs, derivatives, unknown = self._affine_of
            self._affine = (all(_affine_in(e, unknown) for e in exprs) if self._complex
                            else all(not (d.free_symbols & unknown) for d in derivatives))
        return self._affine

    def _function(self):
        """g and its Jacobian entries as one function of (u, fixed values), made once per
        distinct system (:data:`_FUNCTIONS`: components of the same type and spec share it)."""
        if self._gdg is None and len(self._rows):
            key = (self._plain, len(self._args[0]), len(self._args[1]))
            self._gdg = _FUNCTIONS.get(key)
            if self._gdg is None:
                # safe: lambdify prints sympy trees built by phc's whitelisting parser and its lowerers
                self._gdg = sp.lambdify(list(self._args), list(self._plain), modules="numpy", cse=True, dummify=False)
                if len(_FUNCTIONS) >= _FUNCTIONS_KEPT:
                    _FUNCTIONS.pop(next(iter(_FUNCTIONS)))
                _FUNCTIONS[key] = self._gdg
        return self._gdg

    def fix(self, values) -> None:
        self._values = values
        self._cache = (None, None)

    def _evaluate(self, u) -> np.ndarray:
        """g at its rows, then the Jacobian entries (cached for the last u)."""
        gdg = self._function()
        if gdg is None:
            return np.zeros(0)
        args = np.asarray(u, dtype=float)[self._used]
        key, value = self._cache
        if key is not None and np.array_equal(key, args):
            return value
        if not self._complex:
            value = np.asarray([float(v) for v in gdg(args, self._values)])
        else:
            m = len(args)
            with np.errstate(all="ignore"):
                g = np.asarray([float(v) for v in gdg(args, self._values)])
                U = np.repeat(args[:, None], max(m, 1), axis=1).astype(complex)
                U[np.arange(m), np.arange(m)] += 1j * _STEP
                G = np.empty((self._n_g, max(m, 1)), dtype=complex)
                for k, v in enumerate(gdg(list(U), self._values)[:self._n_g]):
                    G[k] = v  # a constant row broadcasts
            value = np.concatenate([g, G.imag[self._pattern] / _STEP])
        self._cache = (args, value)
        return value

    def F(self, u):
        u = np.asarray(u, dtype=float)
        out = self.linear @ u if self.linear is not None else np.zeros(len(self.exprs))
        if len(self._rows):
            out = out + np.bincount(self._rows, self._evaluate(u)[:self._n_g], minlength=len(self.exprs))
        return out

    def _jacobian_values(self, u):
        return self._evaluate(u)[self._n_g:] if len(self._rows) else np.zeros(0)

    def J(self, u):
        """The dense Jacobian at u."""
        if self._dense is None:
            self._dense = (self.linear.toarray() if self.linear is not None
                           else np.zeros((len(self.exprs), len(self.unknowns))))
        J = self._dense.copy()
        J[self._ji, self._jj] += self._jacobian_values(u)
        return J

    def sparse_jacobian(self) -> sps.csr_matrix:
        """The (constant) Jacobian of an affine system, sparse."""
        shape = (len(self.exprs), len(self.unknowns))
        J = sps.csr_matrix((self._jacobian_values(np.zeros(shape[1])), (self._ji, self._jj)), shape=shape)
        return J + self.linear if self.linear is not None else J


_STEP = 1e-30
"""The complex step of :meth:`_System.compile`."""
_FUNCTIONS: dict = {}
"""Lambdified systems by their expressions in plain names (:meth:`_System._function`)."""
_FUNCTIONS_KEPT = 256
_NON_ANALYTIC = (sp.Abs, sp.sign, sp.Piecewise, sp.Heaviside, sp.Max, sp.Min, sp.floor, sp.ceiling, sp.re, sp.im,
                 sp.arg, sp.conjugate, sp.atan2, sp.Mod, sp.DiracDelta)


def _affine_in(expr, unknowns: set) -> bool:
    """Whether `expr` is affine in `unknowns` (each term free of them, or one of them times
    a factor free of them). Conservative: False sends the component to the dense test."""
    for term in sp.Add.make_args(expr):
        syms = term.free_symbols & unknowns
        if not syms:
            continue
        if len(syms) > 1:
            return False
        s = syms.pop()
        _, dependent = term.as_independent(s, as_Add=False)
        if dependent != s:
            return False
    return True


def _linear(n_rows: int, parts, unknowns: list, defaults: dict, vectors=()) -> Optional[sps.csr_matrix]:
    """The sparse part of a system: Σ over `parts` ``(rows, coeff, A, symbols)`` of
    ``coeff·A`` (parameters at their defaults) placed in `rows`, its columns mapped to the
    unknowns — each symbol an unknown, a storage vector's flow (its state's rate) or a
    storage vector's effort (its row of ``∂H/∂x = Σ coeff·A x``, from `vectors`)."""
    if not parts:
        return None
    n_u = len(unknowns)
    index = {s: j for j, s in enumerate(unknowns)}
    maps = [sps.identity(n_u, format="csr")]
    position = dict(index)
    offset = n_u
    for sv in vectors:
        rate_cols = [index[r] for r in sv.rates]
        maps.append(sps.csr_matrix((np.ones(len(rate_cols)), (np.arange(len(rate_cols)), rate_cols)),
                                   shape=(len(rate_cols), n_u)))
        state_cols = [index[x] for x in sv.states]
        select = sps.csr_matrix((np.ones(len(state_cols)), (np.arange(len(state_cols)), state_cols)),
                                shape=(len(state_cols), n_u))
        G = sps.csr_matrix((len(sv.efforts), n_u))
        where = {x: k for k, x in enumerate(sv.states)}
        for term in sv.gradient:
            G = G + _number(term.coeff, defaults) * (term.matrix @ select[[where[x] for x in term.symbols]])
        maps.append(G.tocsr())
        for k, f in enumerate(sv.flows):
            position[f] = offset + k
        offset += len(sv.flows)
        for k, e in enumerate(sv.efforts):
            position[e] = offset + k
        offset += len(sv.efforts)
    phi = sps.vstack(maps, format="csr")
    total = sps.csr_matrix((n_rows, n_u))
    for rows, coeff, matrix, symbols in parts:
        missing = [s for s in symbols if s not in position]
        if missing:
            raise ValueError(f"a sparse term refers to `{missing[0]}`, not a variable of the component")
        C = _number(coeff, defaults) * (sps.csr_matrix(matrix) @ phi[[position[s] for s in symbols]])
        C = C.tocoo()
        rows = np.asarray(rows, dtype=int)
        total = total + sps.csr_matrix((C.data, (rows[C.row], C.col)), shape=(n_rows, n_u))
    return total.tocsr()


def _number(coeff, defaults: dict) -> float:
    value = sp.sympify(coeff).xreplace(defaults)  # safe: a LinearTerm's coefficient, a sympy expression or number
    if value.free_symbols:
        raise ValueError(f"the coefficient {coeff} of a sparse term depends on {sorted(map(str, value.free_symbols))}")
    return float(value)


def _systems(desc: ComponentDescription, rows: ComponentRows, defaults: Optional[dict] = None,
             blocks=()) -> tuple[_System, _System]:
    """The rows and the (complete) description of one component as systems over the same
    visible unknowns; `blocks` are the component's sparse blocks (:class:`~phc.ir.dae.LinearBlock`,
    whose rows are found in `rows` by their labels)."""
    defaults = defaults or {}
    states = [s for s, ds, _ in rows.variables if ds is not None]
    rates = [ds for _, ds, _ in rows.variables if ds is not None]
    rate_of = dict(zip(states, rates))
    port_vars = [x for idx, _ in desc.ports.values() for i in idx for x in (desc.flows[i], desc.efforts[i])]
    visible = [*states, *rates, *port_vars]
    own = {s for s, _, _ in rows.variables}
    pv = set(port_vars)
    hidden_rows = [s for s, ds, _ in rows.variables if ds is None and s not in pv]
    r_labels = [label for label, _ in rows.equations] + [f"definition of {s}" for s, _ in rows.definitions]
    r_exprs = [e for _, e in rows.equations] + [s - e for s, e in rows.definitions]
    r_unknowns = visible + hidden_rows
    where = {label: i for i, (label, _) in enumerate(rows.equations)}
    r_parts = []
    for blk in blocks:
        idx = [where[f"{blk.label}[{k}]"] for k in range(len(blk.rows))]
        for term in blk.terms:
            symbols = [rate_of[s] for s in term.symbols] if term.derivative else list(term.symbols)
            r_parts.append((idx, term.coeff, term.matrix, symbols))
    sys_rows = _System(r_labels, r_exprs, r_unknowns, len(visible),
                       _linear(len(r_exprs), r_parts, r_unknowns, defaults))

    sigma = {}
    for st in desc.storage:
        sigma[st.flow] = st.rate
        sigma[st.effort] = st.gradient
    vector_symbols = set()
    for sv in desc.storage_vectors:
        vector_symbols.update(sv.flows)
        vector_symbols.update(sv.efforts)
    d_exprs = [e.xreplace(sigma) for e in (*desc.relations, *desc.laws)]
    labels = {(which, i): label for which, i, _, _, label, *_ in desc.order if label}
    d_labels = ([labels.get(("rel", i)) or _Label(f"relation {i}", e) for i, e in enumerate(desc.relations)]
                + [labels.get(("law", i)) or _Label(f"law {i}", e) for i, e in enumerate(desc.laws)])
    d_parts = []
    for blk in desc.blocks:
        start = len(d_exprs)
        d_exprs.extend(sp.Integer(0) for _ in range(blk.n))
        d_labels.extend(f"{blk.label}[{i}]" for i in range(blk.n))
        for i, expr in blk.extra:
            d_exprs[start + i] += expr.xreplace(sigma)
        for term in blk.terms:
            d_parts.append((range(start, start + blk.n), term.coeff, term.matrix, list(term.symbols)))
    used = set().union(*(e.free_symbols for e in d_exprs)) if d_exprs else set()
    if used & vector_symbols:
        d_exprs = [e.xreplace(_vector_substitution(desc, used & vector_symbols, defaults)) for e in d_exprs]
        used = set().union(*(e.free_symbols for e in d_exprs))
    for _, _, _, symbols in d_parts:
        used.update(symbols)
    internal = set(desc.flows) | set(desc.efforts) | set(desc.multipliers)
    hidden_desc = sorted((used & (internal | own)) - set(visible) - set(sigma) - vector_symbols, key=str)
    d_unknowns = visible + hidden_desc
    sys_desc = _System(d_labels, d_exprs, d_unknowns, len(visible),
                       _linear(len(d_exprs), d_parts, d_unknowns, defaults, desc.storage_vectors))
    return sys_rows, sys_desc


def _vector_substitution(desc: ComponentDescription, symbols: set, defaults: dict) -> dict:
    """Storage-vector symbols used in sympy expressions: flows by their rates, efforts by
    their gradient rows."""
    out = {}
    for sv in desc.storage_vectors:
        for f, r in zip(sv.flows, sv.rates):
            if f in symbols:
                out[f] = r
        wanted = [k for k, e in enumerate(sv.efforts) if e in symbols]
        for k in wanted:
            expr = sp.Integer(0)
            for term in sv.gradient:
                row = sps.csr_matrix(term.matrix)[k].tocoo()
                expr += term.coeff * sp.Add(*[float(v) * term.symbols[j] for j, v in zip(row.col, row.data)])
            out[sv.efforts[k]] = expr
    return out


class _Label:
    """An unlabelled relation's label, ``relation 3 (its expression)``, printed only when a
    message names it (printing every relation of every component cost a tenth of the check)."""

    __slots__ = ("head", "expr")

    def __init__(self, head: str, expr) -> None:
        self.head, self.expr = head, expr

    def __str__(self) -> str:
        return f"{self.head} ({_short(self.expr)})"


def _short(expr, limit: int = 60) -> str:
    text = str(expr)
    return text if len(text) <= limit else text[:limit - 1] + "…"


def _prepare(desc, rows, defaults, blocks):
    sys_rows, sys_desc = _systems(desc, rows, defaults, blocks)
    foreign = (set().union(*(sp.sympify(e).free_symbols for e in sys_rows.exprs + sys_desc.exprs))  # safe: sympy rows
               - set(sys_rows.unknowns) - set(sys_desc.unknowns) - set(defaults) - {T})
    foreign = sorted(foreign, key=str)
    fixed_symbols = [T, *defaults, *foreign]
    sys_rows.compile(fixed_symbols)
    sys_desc.compile(fixed_symbols)
    return sys_rows, sys_desc, foreign


def compare(desc: ComponentDescription, rows: ComponentRows, defaults: dict, rng, samples: int = 2,
            t_range: tuple[float, float] = (0.0, 1.0), blocks=(), method: str = "auto"
            ) -> tuple[Optional[str], Optional[str]]:
    """Compare one component's rows with its (complete) description. Returns ``(mismatch,
    note)``: `mismatch` describes a difference found (None if none), `note` why the
    comparison was inconclusive (None if it was not). `method` is ``"dense"``,
    ``"affine"`` or ``"auto"`` (affine when both systems are affine and one has a sparse part)."""
    sys_rows, sys_desc, foreign = _prepare(desc, rows, defaults, blocks)
    affine = sys_rows.affine and sys_desc.affine
    if method == "auto":
        sparse = sys_rows.linear is not None or sys_desc.linear is not None
        method = "affine" if affine and sparse else "dense"
    if method == "affine" and not affine:
        raise ValueError("the rows or the description are not affine in the unknowns")
    run = _compare_affine if method == "affine" else _compare_dense
    return run(sys_rows, sys_desc, defaults, foreign, rng, samples, t_range)


def _fix(systems, defaults, foreign, rng, t_range) -> float:
    t = float(rng.uniform(*t_range))
    values = np.array([t, *(float(v) for v in defaults.values()), *rng.normal(size=len(foreign))])
    for s in systems:
        s.fix(values)
    return t


def _compare_dense(sys_rows, sys_desc, defaults, foreign, rng, samples, t_range):
    n_vis = sys_rows.n_visible
    note = None
    for _ in range(samples):
        t = _fix((sys_rows, sys_desc), defaults, foreign, rng, t_range)
        for a, b, a_name, b_name in ((sys_rows, sys_desc, "the equations", "the description"),
                                     (sys_desc, sys_rows, "the description", "the equations")):
            for _ in range(RESTARTS):
                point, err = _newton(a, rng.normal(size=len(a.unknowns)))
                if err <= RESIDUAL_TOL:
                    break
            if not err <= RESIDUAL_TOL:
                note = f"no point of {a_name} found from a random start (residual {err:.1e})"
                continue
            w = point[:n_vis]
            other, err_b, settled = _member(b, w, rng)
            where = _where(sys_rows.unknowns[:n_vis], w, t)
            if not err_b <= MEMBERSHIP_TOL:
                if not settled:
                    # the solve for b's hidden unknowns did not converge (a steep law such as a
                    # diode's exponential from a random start): no verdict at this sample
                    note = (f"the hidden unknowns of {b_name} were not found at a point {a_name} allow "
                            f"from {RESTARTS} starts (residual {err_b:.1e}, at {where})")
                    continue
                label, value = _worst(b, other)
                return (f"{b_name} fail at a point {a_name} allow: `{label}` is off by {value:.3g} "
                        f"(at {where})"), None
            ta, tb = _visible_tangent(a, point), _visible_tangent(b, other)
            if ta.shape[1] != tb.shape[1]:
                return (f"{a_name} leave {ta.shape[1]} directions free where {b_name} leave "
                        f"{tb.shape[1]} (at {where})"), None
            if ta.shape[1] and np.abs(ta - tb @ (tb.T @ ta)).max() > ANGLE_TOL:
                return f"{a_name} and {b_name} allow different motions through the same point (at {where})", None
    return None, note


def _equilibrated(system: _System):
    """The affine system ``A u + c = 0`` in equilibrated form (Ruiz scaling: rows and
    columns scaled until each has largest entry ≈ 1): ``(Â, ĉ, s)`` with ``Â = D_r A diag(s)``,
    ``ĉ = D_r c``, so that ``u = s·û``. Modal coordinates and mesh-dependent FE matrices
    are badly scaled (entries from 1e-4 to 1e5 in one component); equilibrated, the
    saddle-point solves below are accurate to round-off.

    Not :func:`phc.simulation.equilibrate.equilibrate` (alternating max-norm scaling, a
    fixed number of rounds, dense): Ruiz's symmetric square-root scaling, iterated on the
    sparse Jacobian until rows and columns both have largest entry within 1 % of 1."""
    A = system.sparse_jacobian().tocsr()
    c = system.F(np.zeros(len(system.unknowns)))
    rows, cols = np.ones(A.shape[0]), np.ones(A.shape[1])
    for _ in range(30):
        absA = abs(A)
        r = np.asarray(absA.max(axis=1).todense()).ravel()
        k = np.asarray(absA.max(axis=0).todense()).ravel()
        r[r == 0], k[k == 0] = 1.0, 1.0
        if np.abs(r - 1).max(initial=0.0) < 1e-2 and np.abs(k - 1).max(initial=0.0) < 1e-2:
            break
        dr, dk = 1 / np.sqrt(r), 1 / np.sqrt(k)
        A = (sps.diags(dr) @ A @ sps.diags(dk)).tocsr()
        rows, cols = rows * dr, cols * dk
    return A, c * rows, cols


def _saddle_solve(K: sps.spmatrix, rhs: np.ndarray, n_reg: int) -> np.ndarray:
    """Solve the saddle-point system ``K x = rhs`` (its last `n_reg` rows are the
    constraint block). If K is singular (dependent relations, undetermined hidden
    unknowns), its constraint block is regularized by δ and the solution refined
    against K itself."""
    try:
        return spla.splu(sps.csc_matrix(K)).solve(rhs)
    except RuntimeError:
        pass
    n = K.shape[0]
    reg = sps.diags(np.concatenate([np.zeros(n - n_reg), -1e-10 * np.ones(n_reg)]))
    try:
        lu = spla.splu(sps.csc_matrix(K + reg))
    except RuntimeError as err:
        raise np.linalg.LinAlgError(f"singular saddle-point system ({err})") from None
    x = lu.solve(rhs)
    for _ in range(20):
        x = x + lu.solve(rhs - K @ x)
    return x


def _random_point(A, c, rng) -> np.ndarray:
    """The point of ``A u + c = 0`` nearest to a Gaussian vector (a random point of the set)."""
    m, n = A.shape
    z = rng.normal(size=n)
    K = sps.bmat([[sps.identity(n), A.T], [A, None]], format="csc")
    return _saddle_solve(K, np.concatenate([z, -c]), m)[:n]


def _hidden_for(A, c, v, n_vis) -> np.ndarray:
    """The hidden unknowns h that bring ``A (v, h) + c`` closest to 0 (least squares)."""
    m, n = A.shape
    Av, Ah = A[:, :n_vis], A[:, n_vis:]
    r = -(Av @ v + c)
    if n == n_vis:
        return np.zeros(0)
    K = sps.bmat([[sps.identity(m), Ah], [Ah.T, None]], format="csc")
    return _saddle_solve(K, np.concatenate([r, np.zeros(n - n_vis)]), n - n_vis)[m:]


def _compare_affine(sys_rows, sys_desc, defaults, foreign, rng, samples, t_range):
    n_vis = sys_rows.n_visible
    for _ in range(samples):
        t = _fix((sys_rows, sys_desc), defaults, foreign, rng, t_range)
        scaled = {id(sys_rows): _equilibrated(sys_rows), id(sys_desc): _equilibrated(sys_desc)}
        for a, b, a_name, b_name in ((sys_rows, sys_desc, "the equations", "the description"),
                                     (sys_desc, sys_rows, "the description", "the equations")):
            (A, c, s_a), (B, d, s_b) = scaled[id(a)], scaled[id(b)]
            u = _random_point(A, c, rng)
            err = float(np.abs(A @ u + c).max(initial=0.0)) / max(1.0, float(np.abs(u).max(initial=0.0)))
            if not err <= RESIDUAL_TOL * 1e2:
                return None, f"no point of {a_name} found (residual {err:.1e}: its relations contradict each other)"
            v = (s_a * u)[:n_vis]
            v_b = v / s_b[:n_vis]
            point = np.concatenate([v_b, _hidden_for(B, d, v_b, n_vis)])
            res = (B @ point + d) / max(1.0, float(np.abs(point).max(initial=0.0)))
            i = int(np.argmax(np.abs(res))) if res.size else 0
            if res.size and not abs(res[i]) <= MEMBERSHIP_TOL:
                value = float(b.F(s_b * point)[i])
                return (f"{b_name} fail at a point {a_name} allow: `{b.labels[i]}` is off by {value:.3g} "
                        f"(at {_where(sys_rows.unknowns[:n_vis], v, t)})"), None
    return None, None


def _where(symbols, values, t) -> str:
    parts = [f"t = {t:.3g}"]
    for s, v in list(zip(symbols, values))[:3]:
        parts.append(f"{s} = {v:.3g}")
    return ", ".join(parts) + (", …" if len(symbols) > 3 else "")


def check_rows(dae: Dae, samples: int = 2, seed: int = 0, max_unknowns: int = MAX_UNKNOWNS,
               max_sparse_unknowns: int = MAX_SPARSE_UNKNOWNS, components=None) -> RowsCertificate:
    """Compare every component's rows with its description (see the module docstring), or
    only those named in `components`."""
    cert = RowsCertificate(samples=samples)
    top = dae.topology
    if top is None:
        return cert
    wanted = None if components is None else set(components)
    rows = {r.component: r for r in top.rows}
    blocks: dict[str, list] = {}
    for blk in dae.linear_blocks:
        blocks.setdefault(blk.component, []).append(blk)
    defaults = {p.symbol: sp.Float(p.default) for p in dae.parameters}
    t_end = float(dae.options.get("t_end", 1.0) or 1.0)
    rng = np.random.default_rng(seed)
    # Components whose rows and description are the same systems up to the names of their
    # unknowns (the masses of a chain) are the same comparison: its verdict, when it found
    # the two equal, holds for each of them (random points and times are drawn for the first
    # one; every point of these systems is as random as any other). A mismatch or an
    # inconclusive test is never shared: each such component is compared on its own and
    # gets its own located message.
    matched: set = set()
    for desc in top.dirac:
        r = rows.get(desc.component)
        if r is None or (wanted is not None and desc.component not in wanted):
            continue
        full = desc if desc.complete else desc.structure
        if full is None or not full.complete:
            cert.not_compared.append((desc.component, "described by its ports only"))
            continue
        size = len(r.variables) + sum(1 for _, ds, _ in r.variables if ds is not None)
        sparse = bool(blocks.get(desc.component)) or bool(full.blocks)
        limit = max_sparse_unknowns if sparse else max_unknowns
        if size > limit:
            cert.not_compared.append((desc.component, f"{size} unknowns (above {limit})"))
            continue
        try:
            canonical = None if sparse else _canonical_key(full, r)
            if canonical is not None and canonical in matched:
                cert.compared.append(desc.component)
                cert.shared += 1
                continue
            sys_rows, sys_desc, foreign = _prepare(full, r, defaults, blocks.get(desc.component, ()))
            key = (sys_rows.key, sys_desc.key, len(foreign))
            if key in matched:
                cert.compared.append(desc.component)
                cert.shared += 1
                continue
            if sparse and sys_rows.affine and sys_desc.affine:
                run = _compare_affine
            elif max(len(sys_rows.unknowns), len(sys_desc.unknowns)) <= max_unknowns:
                run = _compare_dense
            else:
                cert.not_compared.append((desc.component,
                                          f"{size} unknowns with nonlinear rows (above {max_unknowns})"))
                continue
            mismatch, note = run(sys_rows, sys_desc, defaults, foreign, rng, samples, (0.0, t_end))
        except (TypeError, ValueError, KeyError, ZeroDivisionError, OverflowError, np.linalg.LinAlgError) as err:
            cert.inconclusive.append((desc.component, f"{type(err).__name__}: {err}"))
            continue
        if mismatch is not None:
            cert.diagnostics.append(Diagnostic(
                "PHC-E452", f"the equations compiled for `{desc.component}` ({full.kind}) do not say what its "
                f"description says: {mismatch}", span=desc.span,
                hint="this is a fault in phc's lowering of this component type, not in the model; please report it"))
        elif note is not None:
            cert.inconclusive.append((desc.component, note))
        else:
            cert.compared.append(desc.component)
            matched.add(key)
            if canonical is not None:
                matched.add(canonical)
    return cert


@lru_cache(maxsize=4096)
def placeholder(name: str, assumptions: frozenset) -> sp.Symbol:
    """The placeholder symbol `name` with `assumptions` (``frozenset(v.assumptions0.items())``):
    the same symbol as ``sp.Symbol(name, **assumptions)``, made once. The canonical keys of
    many equal components (:func:`_canonical_key`, :class:`phc.checks.certify._Component`)
    use the same few placeholders, and sympy checks a symbol's name and assumptions each
    time it makes one."""
    return sp.Symbol(name, **dict(assumptions))


def _canonical_key(desc: ComponentDescription, rows: ComponentRows):
    """The component's rows and description up to the names of its own symbols, or None when
    it has vector storage (compared by the sparse path): the component's variables, rates,
    flows, efforts and multipliers replaced by placeholders in the order the two structures
    list them (not by name), every expression and the ports' indices kept.

    Equal keys mean the two components' systems (:func:`_systems`) are the same up to a
    one-to-one renaming of their own symbols, so a comparison that found one pair equal holds
    for the other. Found with one pass over the expressions, before the systems are built and
    compiled (a chain of 10⁴ equal cells spent most of this check building systems only to
    find their keys equal); symbols that are not the component's own (parameters, time,
    other components' states) stay as they are, so they must be the same symbols."""
    if desc.storage_vectors or desc.blocks or rows.sparse:
        return None
    own = [s for s, _, _ in rows.variables]
    own += [ds for _, ds, _ in rows.variables if ds is not None]
    own += [*desc.flows, *desc.efforts, *desc.multipliers, *desc.states]
    for st in desc.storage:
        own += [st.flow, st.effort]
    canon = {v: placeholder(f"phc own {k}", frozenset(v.assumptions0.items()))
             for k, v in enumerate(dict.fromkeys(own))}
    return ("canonical",
            tuple((canon[s], canon.get(ds), role) for s, ds, role in rows.variables),
            tuple(e.xreplace(canon) for _, e in rows.equations),
            tuple((canon.get(s, s), e.xreplace(canon)) for s, e in rows.definitions),
            tuple(canon[x] for x in (*desc.flows, *desc.efforts, *desc.multipliers)),
            tuple((canon[st.flow], canon[st.effort],
                   sp.sympify(st.rate).xreplace(canon),  # safe: a description's rate, a sympy expression
                   sp.sympify(st.gradient).xreplace(canon))  # safe: a description's gradient, a sympy expression
                  for st in desc.storage),
            tuple(e.xreplace(canon) for e in (*desc.relations, *desc.laws)),
            tuple((tuple(idx), tuple(rest) if isinstance(rest, (list, tuple)) else rest)
                  for idx, rest in desc.ports.values()))


def hand_written(dae: Dae) -> list[str]:
    """The components whose rows are not all derived from their description: those whose
    lowerer wrote a row itself (recorded by the elaborate pass,
    :attr:`~phc.ir.dae.ComponentRows.derived`) and those whose registry entry declares its rows
    hand-written for their spec (:attr:`phc.library.registry.ComponentType.rows`). Signal blocks
    (:attr:`phc.library.registry.ComponentType.signal`) have no description and are left out."""
    from phc.library import registry

    top = dae.topology
    if top is None:
        return []
    types = {name: kind for name, kind, _ in top.components}
    out = []
    for r in top.rows:
        entry = registry.find(types.get(r.component))
        spec = top.specs.get(r.component)
        declared = entry.rows_of(spec) if entry is not None and spec is not None else None
        if entry is not None and entry.signal:  # a signal block has no description to compare with
            continue
        if not r.derived or declared == "hand-written":
            out.append(r.component)
    return out


COMPILE_MAX_UNKNOWNS = 160
"""In every compilation, a meshed component with hand-written nonlinear rows (no built-in
type has them since the moving beam derives its rows; a registered type may) and more
unknowns than this is compared on a coarse mesh (:data:`COARSE_ELEMENTS`): the dense test
of a moving beam cost about 0.5 s of CPU at 8 elements (124 unknowns) and 7 s at 16 (220
unknowns) on a shared 2-core machine, and is refused above :data:`MAX_UNKNOWNS`."""
COARSE_ELEMENTS = 4
"""Elements of the coarse mesh on which a large meshed component's rows are compared."""


def _size(rows: ComponentRows) -> int:
    return len(rows.variables) + sum(1 for _, ds, _ in rows.variables if ds is not None)


def check_hand_written(dae: Dae, seed: int = 0, rebuild=None) -> RowsCertificate:
    """The rows check run by every compilation (:func:`phc.compile_model`): the rows of each
    component whose lowerer writes them itself (:func:`hand_written`) compared with its
    description at one sampled time, as ``phc check`` compares every component's.

    Rows derived from the description (:func:`phc.library.dirac.emit`) are not compared:
    they are the description by construction. A mismatch is ``PHC-E452`` at the component:
    a fault in phc's lowering of that component type, never in the model.

    A representative subset for large meshes: a meshed component (one with ``elements``)
    whose comparison would be costly — nonlinear rows with more than
    :data:`COMPILE_MAX_UNKNOWNS` unknowns (dense linear algebra, cubic in the size), or
    affine rows above :data:`MAX_SPARSE_UNKNOWNS` — is compared on the same component with
    :data:`COARSE_ELEMENTS` elements, everything else as written: `rebuild(mesh)` assembles
    the model with ``{component: elements}`` overriding its meshes (None if it cannot). Each
    element's rows are written by the same code whatever the mesh, both ends included, so
    a wrong sign, a dropped term or a wrong block entry is wrong on the coarse mesh too;
    what the coarse mesh cannot show is a fault in code that only runs for many elements.
    The affine test of strings and beams stays cheap up to that limit (about 2.5 s of CPU
    for 40 000 unknowns, a fifth of compiling them). A component not compared at all
    (no rebuild, a coarse model that does not assemble, a component without a mesh above
    the limits, an inconclusive test) stays in `not_compared`/`inconclusive`, and the
    caller reports it (``PHC-W452``): nothing is skipped silently.
    """
    wanted = hand_written(dae)
    top = dae.topology
    if not wanted or top is None:
        return RowsCertificate(samples=1)
    rows = {r.component: r for r in top.rows}
    meshed = {c for c in wanted if "elements" in getattr(type(top.specs.get(c)), "model_fields", {})}
    cert = check_rows(dae, samples=1, seed=seed, components=[c for c in wanted if c not in meshed])
    if not meshed:
        return cert
    part = check_rows(dae, samples=1, seed=seed, components=sorted(meshed), max_unknowns=COMPILE_MAX_UNKNOWNS)
    cert.compared += part.compared
    cert.inconclusive += part.inconclusive
    cert.diagnostics.extend(part.diagnostics)
    for name, why in part.not_compared:
        coarse = None
        if name in rows and _size(rows[name]) > COMPILE_MAX_UNKNOWNS and rebuild is not None:  # too large
            coarse = rebuild({name: COARSE_ELEMENTS})
        if coarse is None:
            cert.not_compared.append((name, why + (" and no coarse mesh to compare on" if rebuild else "")))
            continue
        small = check_rows(coarse, samples=1, seed=seed, components=[name])
        cert.compared += [f"{c} (on {COARSE_ELEMENTS} elements)" for c in small.compared]
        cert.not_compared += [(c, f"{why}; on {COARSE_ELEMENTS} elements: {w}") for c, w in small.not_compared]
        cert.inconclusive += small.inconclusive
        for d in small.diagnostics:
            cert.diagnostics.append(replace(
                d, message=d.message + f" (compared on the same component with {COARSE_ELEMENTS} elements: its "
                f"{_size(rows[name])} unknowns are too many to compare when compiling)"))
    return cert


__all__ = ["RowsCertificate", "check_hand_written", "check_rows", "compare", "hand_written", "COARSE_ELEMENTS",
           "COMPILE_MAX_UNKNOWNS", "MAX_UNKNOWNS", "MAX_SPARSE_UNKNOWNS"]
