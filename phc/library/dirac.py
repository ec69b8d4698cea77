"""Component descriptions, and the rows derived from them.

A lowerer describes its component once, with a :class:`DiracBuilder`: ports, storage
pairs bound to states (``f = ẋ``, ``e = ∂H/∂x``), resistive pairs with their laws, the
Dirac structure in kernel form ``F f + E e + G λ = b(t)`` (T. Berger, R. Hochdahl,
T. Reis, R. Seifried, "Port-Hamiltonian modelling of coupled rigid/flexible multibody
systems", section 2, the kernel representation with its ∃λ) and the Hamiltonian. The
result is one immutable :class:`~phc.ir.dae.ComponentDescription`.

:func:`emit` derives the component's equation rows from that description — the same
relations, with every storage pair replaced by ``(ẋ, ∂H/∂x)`` and every internal pair
eliminated — so the equations that are compiled and the structure that is certified are
one thing. A relation may name the symbol it is solved for (``solve=``): a port variable
solved for becomes an explicit definition (assembly substitutes it, alias elimination), an
internal pair symbol is eliminated, anything else stays a residual row.

Rigid bodies and kernel-form ``phs`` components use the model's own multipliers (λ, μ of
a rigid body, a ``phs``'s `multipliers`) and resistive variables in their descriptions; a
relation carries the kind, label and place of the row derived from it (``rel(...,
kind=, label=, span=)``).

Large components whose rows are sparse matrix blocks (discretized PDEs, modal
truncations, matrix components, the moving beam's flexible part) register the projection
of their structure onto their ports (``kind="port_projection"``: what the Dirac and
coupling certificate works with) and, as its `structure`, the complete semi-discrete pH
system, kept sparse: relations over symbol vectors (:meth:`DiracBuilder.block`, a
:class:`~phc.ir.dae.LinearTerm` per matrix), storage vectors ``f = ẋ``, ``e = Qx``
(:meth:`DiracBuilder.storage_vector`) and resistive vectors with sparse laws. A block
may be solved for a vector (``solve=``): :func:`emit_sparse` derives sparse rows from such
a structure by composing the matrices of the vectors it eliminates (``linear_phs``,
strings, beams, ``pde1d``, modal truncations, the moving beam, whose scalar storage and
relations — the chord frame's — are emitted as the scalar ones are). Only a ``pde1d``
whose damping couples two variables writes its rows directly
(:func:`phc.library.pde1d.pde1d_rows`); :mod:`phc.checks.rows` compares them with its
structure whenever it is compiled.
"""

from __future__ import annotations

from typing import Optional

import numpy as np
import sympy as sp

from phc.ir.dae import Chained, ComponentDescription, LinearTerm, SparseRelations, Storage, StorageVector, SymbolVector


class DiracBuilder:
    """Collects one component's description (see the module docstring)."""

    def __init__(self, component: str, kind: str, span=None):
        self.component, self.kind, self.span = component, kind, span
        # flows, efforts and internal symbols: symbols, or whole vectors (:meth:`vector`)
        self.flows: list = []
        self.efforts: list = []
        self.multipliers: list[sp.Symbol] = []
        self.relations: list[sp.Expr] = []
        self.laws: list[sp.Expr] = []
        self.ports: dict[str, tuple[list[int], list[int]]] = {}
        self.storage: list[Storage] = []
        self.resistive: list[tuple[sp.Symbol, sp.Symbol]] = []
        self.internal: list = []
        self.hamiltonian: Optional[sp.Expr] = None
        # (relation or law, index, solved-for symbol, row kind, row label) in declaration order
        self.order: list[tuple[str, int, Optional[sp.Symbol], str, str]] = []
        self.blocks: list[list] = []  # [label, n, terms, extra, law] (frozen by describe)
        self.storage_vectors: list[StorageVector] = []
        self._bound: set = set()  # internal vectors bound as storage or resistive vectors

    def pair(self, local: str) -> tuple[sp.Symbol, sp.Symbol]:
        """A fresh internal flow/effort pair (not bound: the description is then not
        complete unless it is bound by :meth:`storage` or :meth:`resistor`)."""
        f = sp.Symbol(f"cert:{self.component}.f_{local}", real=True)
        e = sp.Symbol(f"cert:{self.component}.e_{local}", real=True)
        self.flows.append(f)
        self.efforts.append(e)
        self.internal.extend((f, e))
        return f, e

    def storage_pair(self, local: str, state: sp.Symbol, rate: sp.Symbol, gradient: sp.Expr
                     ) -> tuple[sp.Symbol, sp.Symbol]:
        """A storage pair bound to `state`: ``f = ẋ`` (`rate`), ``e = ∂H/∂x`` (`gradient`)."""
        f, e = self.pair(local)
        self.storage.append(Storage(f, e, state, rate, sp.sympify(gradient)))  # safe: a sympy expression or number
        return f, e

    def resistor(self, local: str) -> tuple[sp.Symbol, sp.Symbol]:
        """A resistive pair; its law goes in with :meth:`law` (dissipation ``f·e ≥ 0``)."""
        f, e = self.pair(local)
        self.resistive.append((f, e))
        return f, e

    def vector(self, local: str, n: int) -> tuple[tuple[sp.Symbol, ...], tuple[sp.Symbol, ...]]:
        """`n` fresh internal flow/effort pairs, as two vectors (see :meth:`pair`), each a
        :class:`~phc.ir.dae.SymbolVector` (its symbols are made when one is read: a vector
        :func:`emit_sparse` eliminates is never spelled out)."""
        f = SymbolVector(f"cert:{self.component}.f_{local}", n)
        e = SymbolVector(f"cert:{self.component}.e_{local}", n)
        self.flows.append(f)
        self.efforts.append(e)
        self.internal.extend((f, e))
        return f, e

    def storage_vector(self, local: str, states, rates, gradient) -> tuple[tuple, tuple]:
        """Storage pairs bound to `states`, as vectors: ``f = ẋ`` (`rates`) and
        ``e = Σ gradient`` (:class:`~phc.ir.dae.LinearTerm` over the states: ∂H/∂x of a
        quadratic energy)."""
        f, e = self.vector(local, len(states))
        self.storage_vectors.append(StorageVector(f, e, tuple(states), tuple(rates), tuple(gradient)))
        self._bound.update((f, e))
        return f, e

    def resistor_vector(self, local: str, n: int) -> tuple[tuple, tuple]:
        """`n` resistive pairs; their law goes in with :meth:`block` (``law=True``)."""
        f, e = self.vector(local, n)
        self.resistive.extend(zip(f, e))
        self._bound.update((f, e))
        return f, e

    def mults(self, local: str, n: int) -> tuple[sp.Symbol, ...]:
        """`n` multipliers ``local[i]``."""
        lam = tuple(sp.Symbol(f"cert:{self.component}.{local}[{i}]", real=True) for i in range(n))
        self.multipliers.extend(lam)
        return lam

    def block(self, label: str, n: int, terms, law: bool = False, solve=None) -> int:
        """`n` relations ``Σ terms = 0`` kept sparse (each term a :class:`~phc.ir.dae.LinearTerm`
        over symbols of this description); returns the block's number for :meth:`add_to`.
        `solve`: the vector they are solved for (its term is the identity): :func:`emit`
        eliminates it, or defines it when it is a port's flows or efforts."""
        terms = [t if isinstance(t, LinearTerm) else LinearTerm(*t) for t in terms]
        for t in terms:
            if t.derivative or t.matrix.shape != (n, len(t.symbols)):
                raise ValueError(f"{self.component}: block {label}: a term of shape {t.matrix.shape} over "
                                 f"{len(t.symbols)} symbols in {n} relations")
        solve = solve if solve is None or isinstance(solve, SymbolVector) else tuple(solve)
        self.blocks.append([label, n, terms, [], law, solve])
        return len(self.blocks) - 1

    def add_to(self, block: int, i: int, expr) -> None:
        """Add a sympy term to relation `i` of `block` (a boundary coupling, a modulation)."""
        if expr != 0:
            self.blocks[block][3].append((i, sp.sympify(expr)))  # safe: a sympy expression or number

    def port(self, port) -> None:
        start = _length(self.flows)
        self.flows.extend(port.f)
        self.efforts.extend(port.e)
        idx = list(range(start, start + port.dimension))
        self.ports[port.name.rsplit(".", 1)[-1]] = (idx, idx)

    def mult(self, local: str) -> sp.Symbol:
        lam = sp.Symbol(f"cert:{self.component}.{local}", real=True)
        self.multipliers.append(lam)
        return lam

    def rel(self, expr, solve: Optional[sp.Symbol] = None, kind: str = "dirac", label: str = "",
            span=None) -> None:
        """A relation of the Dirac structure ``= 0`` (linear in flows, efforts, multipliers;
        an affine part in t is a source's value). `kind`, `label` and `span` are those of
        the row :func:`emit` derives from it (the component's span by default)."""
        self.order.append(("rel", len(self.relations), solve, kind, label, span))
        self.relations.append(expr if isinstance(expr, sp.Basic) else sp.Integer(expr))

    def law(self, expr, solve: Optional[sp.Symbol] = None, kind: str = "resistive", label: str = "",
            span=None) -> None:
        """A resistive or constitutive law ``= 0`` (may be nonlinear)."""
        self.order.append(("law", len(self.laws), solve, kind, label, span))
        self.laws.append(expr if isinstance(expr, sp.Basic) else sp.Integer(expr))

    def energy(self, hamiltonian: sp.Expr) -> None:
        self.hamiltonian = sp.sympify(hamiltonian)  # safe: a sympy expression or number

    def describe(self, states=(), note: str = "", kind: Optional[str] = None,
                 structure: Optional[ComponentDescription] = None) -> ComponentDescription:
        """The description. With ``kind="port_projection"`` it is not complete; `structure`
        is then the complete description it projects (see the module docstring)."""
        kind = kind or self.kind
        _distinct(self.component, (*self.flows, *self.efforts, *self.multipliers))
        bound = {s.flow for s in self.storage} | {s.effort for s in self.storage} | self._bound
        resistive = {x for pair in self.resistive for x in pair}
        complete = kind != "port_projection" and all(s in bound or s in resistive for s in self.internal)
        blocks = tuple(SparseRelations(label, n, tuple(terms), tuple(extra), law, solve)
                       for label, n, terms, extra, law, solve in self.blocks)
        return ComponentDescription(
            self.component, kind, _sequence(self.flows), _sequence(self.efforts), tuple(self.multipliers),
            tuple(self.relations), dict(self.ports), tuple(states), self.span, note,
            storage=tuple(self.storage), laws=tuple(self.laws), hamiltonian=self.hamiltonian,
            resistive=tuple(self.resistive), complete=complete, order=tuple(self.order),
            blocks=blocks, storage_vectors=tuple(self.storage_vectors), structure=structure,
            internal=_sequence(self.internal))

    def register(self, b, states=(), note: str = "", kind: Optional[str] = None,
                 structure: Optional[ComponentDescription] = None) -> ComponentDescription:
        """Record the description with the lowering recorder `b` (certification reads it) and return it."""
        desc = self.describe(states, note, kind, structure)
        b.dirac.append(desc)
        return desc


def _length(parts) -> int:
    """How many symbols `parts` (symbols and vectors) hold."""
    return sum(len(p) if isinstance(p, SymbolVector) else 1 for p in parts)


def _sequence(parts):
    """`parts` as one sequence of symbols: a tuple, or (with vectors) a :class:`~phc.ir.dae.Chained`
    that makes a vector's symbols only when one is read."""
    if any(isinstance(p, SymbolVector) for p in parts):
        return Chained(parts)
    return tuple(parts)


def _distinct(component: str, parts) -> None:
    """Refuse a flow, effort or multiplier declared twice: a symbol twice, a vector's stem
    twice, or a symbol named as an entry of a vector (``stem[i]``, i below its length)."""
    scalars = [p for p in parts if not isinstance(p, SymbolVector)]
    vectors = [p for p in parts if isinstance(p, SymbolVector)]
    stems = {v.stem: v.n for v in vectors}
    clash = len(set(scalars)) != len(scalars) or len(stems) != len(vectors)
    prefixes = tuple(stems)
    for s in scalars if stems and not clash else ():
        name = s.name if isinstance(s, sp.Symbol) else str(s)
        if not name.startswith(prefixes):
            continue
        stem, bracket, rest = name.rpartition("[")
        if bracket and stem in stems and rest.endswith("]") and rest[:-1].isdigit() and int(rest[:-1]) < stems[stem]:
            clash = True
            break
    if clash:
        raise ValueError(f"{component}: a flow, effort or multiplier of the description is declared twice")


def _existing(symbols):
    """The symbols of `symbols` (a tuple, :class:`~phc.ir.dae.SymbolVector` or
    :class:`~phc.ir.dae.Chained`) that exist: a vector whose symbols were never made has
    none in any expression."""
    parts = symbols.parts if isinstance(symbols, Chained) else (symbols,) if isinstance(symbols, SymbolVector) \
        else symbols
    for p in parts:
        if isinstance(p, SymbolVector):
            if p.made:
                yield from p
        else:
            yield p


def solve_for(expr: sp.Expr, symbol: sp.Symbol) -> sp.Expr:
    """`expr` = 0 solved for `symbol`, which must enter linearly with a coefficient free of
    it (every relation a lowerer marks as a definition is of this form)."""
    from phc.frontend.budget import derivative

    if isinstance(expr, sp.Add):  # the common row `symbol ± rest`: no derivative, no substitution
        for term, sign in ((symbol, 1), (-symbol, -1)):
            if term in expr.args:
                rest = sp.Add(*(a for a in expr.args if a != term))
                if symbol not in rest.free_symbols:
                    return -rest if sign == 1 else rest
                break
    coeff = derivative(expr, symbol)
    if symbol in coeff.free_symbols or coeff == 0:
        raise ValueError(f"{expr} = 0 cannot be solved for {symbol} without solving an equation")
    return -expr.xreplace({symbol: sp.Integer(0)}) / coeff


def emit(b, desc: ComponentDescription, dissipation_span=None) -> None:
    """Derive the component's rows from its description and add them to the lowering
    recorder `b` (:class:`phc.frontend.lowering.Recorder`): definitions, residual rows, the
    Hamiltonian and the dissipated power (located at `dissipation_span`, or the component).
    A sparse description (blocks, storage vectors) gives sparse rows (:func:`emit_sparse`)."""
    if desc.blocks or desc.storage_vectors:
        emit_sparse(b, desc)
        return
    sigma: dict = {}
    for s in desc.storage:
        sigma[s.flow] = s.rate
        sigma[s.effort] = s.gradient
    if desc.internal is not None:  # a DiracBuilder's: its internal pairs, maybe none (a phs without states)
        internal = set(desc.internal)
    else:  # a description made without a DiracBuilder: every pair that is not a port's
        internal = {x for x in (*desc.flows, *desc.efforts)} - {x for idx, _ in desc.ports.values()
                                                                 for x in (*(desc.flows[i] for i in idx),
                                                                           *(desc.efforts[i] for i in idx))}
    for which, i, solve, kind, label, *rest in desc.order:
        span = (rest[0] if rest else None) or desc.span
        expr = (desc.relations if which == "rel" else desc.laws)[i].xreplace(sigma)
        if solve is None:
            left = expr.free_symbols & internal - set(sigma)
            if left:
                raise ValueError(f"{desc.component}: row {label or i} still holds internal {sorted(map(str, left))}")
            b.add_equation(expr, desc.component, kind, label or f"{which}[{i}]", span, derived=True)
            continue
        value = solve_for(expr, solve)
        if solve in internal:
            sigma[solve] = value
            sigma = {k: v.xreplace({solve: value}) for k, v in sigma.items()}
        else:
            b.define(solve, value, derived=True)
    if desc.hamiltonian is not None:
        b.hamiltonian.append(desc.hamiltonian)
    if desc.resistive:
        power = sum((f * e for f, e in desc.resistive), sp.Integer(0)).xreplace(sigma)
        b.dissipation.append((desc.component, power, dissipation_span or desc.span))


# -- sparse descriptions --------------------------------------------------------------------

def _is_identity(m) -> bool:
    import scipy.sparse as sps  # sparse descriptions only: lumped models never load scipy
    n = m.shape[0]
    if m.shape != (n, n) or m.nnz != n:
        return False
    c = sps.coo_matrix(m)
    return bool(np.all(c.row == c.col) and np.all(c.data == 1.0))


def _times(a, b):
    """The coefficient a·b (sympy), without a factor 1."""
    if a is sp.S.One:
        return b
    if b is sp.S.One:
        return a
    return a * b


def _product(A, B):
    """A @ B; an identity factor (a vector the description names twice, ``f_R = λ``) is
    skipped: the other matrix itself, as the rows would use it."""
    if _is_identity(B):
        return A
    if _is_identity(A):
        return B
    return (A @ B).tocsr()


def _substitute(terms, extras, values: dict, depth: int = 0):
    """`terms` (:class:`~phc.ir.dae.LinearTerm`) and `extras` (``(row, expr)``) with every term
    over a vector of `values` (``vector -> (terms, extras, rename)``) replaced by its value."""
    import scipy.sparse as sps  # sparse descriptions only: lumped models never load scipy
    if depth > 64:
        raise ValueError("the sparse description's solved vectors refer to each other in a cycle")
    out_terms, out_extras = [], list(extras)
    for t in terms:
        if t.symbols not in values:
            out_terms.append(t)
            continue
        inner, inner_extras, rename = values[t.symbols]
        if t.derivative:
            raise ValueError(f"the derivative of an eliminated vector ({t.symbols[0]}, ...)")
        if rename is not None:  # a storage vector's flows: the rates of its states
            out_terms.append(LinearTerm(t.coeff, t.matrix, rename, derivative=True))
            continue
        composed = [LinearTerm(_times(t.coeff, it.coeff), _product(t.matrix, it.matrix), it.symbols,
                               it.derivative) for it in inner]
        A = sps.csc_matrix(t.matrix)
        spread = []
        for col, expr in inner_extras:
            lo, hi = A.indptr[col], A.indptr[col + 1]
            spread += [(int(r), _times(t.coeff, float(v)) * expr) for r, v in zip(A.indices[lo:hi], A.data[lo:hi])]
        more_terms, more_extras = _substitute(composed, spread, values, depth + 1)
        out_terms += more_terms
        out_extras += more_extras
    return out_terms, out_extras


def _row_expr(terms, k: int) -> sp.Expr:
    """Row `k` of Σ terms as a sympy expression."""
    import scipy.sparse as sps  # sparse descriptions only: lumped models never load scipy
    out = sp.Integer(0)
    for t in terms:
        if t.derivative:
            raise ValueError("a port variable defined through a rate")
        row = sps.csr_matrix(t.matrix)[k]
        out += t.coeff * sum((float(v) * t.symbols[j] for j, v in zip(row.indices, row.data)), sp.Integer(0))
    return out


def _vanishes(terms, extras) -> bool:
    """Whether Σ terms + extras is identically zero: for each symbol vector, the matrices of
    the terms whose coefficients differ by a rational factor cancel to round-off (a
    relation that the storage and the laws already imply, e.g. ``e = Eᵀz`` with
    ``z = Qx``, ``e = EᵀQx``)."""
    import scipy.sparse as sps  # sparse descriptions only: lumped models never load scipy
    if any(e != 0 for _, e in extras):
        return False
    groups: dict = {}
    for t in terms:
        r, rest = sp.sympify(t.coeff).as_coeff_Mul()  # safe: a LinearTerm's coefficient, a sympy expression
        groups.setdefault((t.symbols, t.derivative, rest), []).append((float(r), sps.csr_matrix(t.matrix)))
    for parts in groups.values():
        total = sum((r * A for r, A in parts), sps.csr_matrix(parts[0][1].shape))
        scale = max(abs(r) * (abs(A).max() if A.nnz else 0.0) for r, A in parts)
        if total.nnz and abs(total).max() > 1e-12 * max(scale, 1e-300):
            return False
    return True


def emit_sparse(b, desc: ComponentDescription) -> None:
    """The rows of a sparse description: storage vectors' flows become the rates of their
    states, their efforts the gradient ``Σ coeff·A x``; each block solved for a vector
    (``solve``) gives that vector's value, substituted wherever it is used (composed
    matrices), or, for a port's flows or efforts, their definitions; every other block
    becomes sparse rows (:meth:`~phc.frontend.lowering.Recorder.add_linear_rows`) — its terms over
    port variables, which assembly may substitute, and its sympy parts (boundary
    couplings) added to the rows as sympy expressions — unless it vanishes identically
    (:func:`_vanishes`). Scalar relations (over the model's own variables and the ports)
    come last: a definition where solved for a symbol, a row otherwise; scalar storage pairs
    (a moving frame's) are replaced by ``(ẋ, ∂H/∂x)`` wherever they appear."""
    import scipy.sparse as sps  # sparse descriptions only: lumped models never load scipy
    sigma = {**{st.flow: st.rate for st in desc.storage}, **{st.effort: st.gradient for st in desc.storage}}
    ports = {x for idx, _ in desc.ports.values() for i in idx for x in (desc.flows[i], desc.efforts[i])}
    values: dict = {}
    for sv in desc.storage_vectors:
        values[_key(sv.flows)] = ((), (), tuple(sv.states))
        values[_key(sv.efforts)] = (tuple(sv.gradient), (), None)
        if not isinstance(sv.flows, SymbolVector) or sv.flows.made:
            sigma.update(zip(sv.flows, sv.rates))  # in sympy parts: the rates themselves
    residual, definitions = [], []
    for blk in desc.blocks:
        if blk.solve is None:
            residual.append(blk)
            continue
        own = [t for t in blk.terms if t.symbols == blk.solve]
        if len(own) != 1 or not _is_identity(own[0].matrix) or own[0].coeff == 0:
            raise ValueError(f"{desc.component}: block {blk.label} is not solved for its vector (one identity term)")
        c0 = own[0].coeff
        scale = ((lambda c: -c) if c0 is sp.S.One else (lambda c: c) if c0 is sp.S.NegativeOne
                 else (lambda c: -c / c0))
        terms = tuple(LinearTerm(scale(t.coeff), t.matrix, t.symbols, t.derivative)
                      for t in blk.terms if t is not own[0])
        extras = tuple((i, scale(e)) for i, e in blk.extra)
        internal_vector = isinstance(blk.solve, SymbolVector)  # never a port's or the model's
        if not internal_vector and set(blk.solve) <= ports:
            definitions.append((blk.solve, terms, extras))
        elif not internal_vector and set(blk.solve) & (ports | {s for s, _, _ in _variables(b)}):
            raise ValueError(f"{desc.component}: block {blk.label} solves for variables of the model")
        else:
            values[_key(blk.solve)] = (terms, extras, None)

    def scalar(expr):
        """A sympy part with scalar storage pairs and eliminated vectors replaced."""
        expr = expr.xreplace(sigma) if sigma else expr
        known = _scalar_values(values, expr.free_symbols)
        return expr.xreplace(known) if known else expr

    for blk in residual:
        terms, extras = _substitute(blk.terms, blk.extra, values)
        if _vanishes(terms, extras):
            continue
        sparse, coupling = [], [(i, scalar(e)) for i, e in extras]
        for t in terms:
            if not set(t.symbols) & ports:
                sparse.append(t)
                continue
            if t.derivative:
                raise ValueError(f"{desc.component}: block {blk.label} holds the rate of a port variable")
            coo = sps.coo_matrix(t.matrix)
            coupling += [(int(i), _times(t.coeff, float(v)) * t.symbols[k])
                         for i, k, v in zip(coo.row, coo.col, coo.data)]
        rows = b.add_linear_rows(desc.component, blk.label, blk.n, sparse, desc.span, derived=True)
        for i, expr in coupling:
            b.add_to_row(rows[i], expr, derived=True)
    for vector, terms, extras in definitions:
        terms, extras = _substitute(terms, extras, values)
        if any(set(t.symbols) & ports for t in terms):
            raise ValueError(f"{desc.component}: a port variable defined through another port variable")
        for k, sym in enumerate(vector):
            b.define(sym, _row_expr(terms, k) + sum((scalar(e) for i, e in extras if i == k), sp.Integer(0)),
                     derived=True)
    # scalar relations and laws (a boundary port's flow, a trace of the co-energies, a
    # moving frame's kinematics), with scalar storage pairs replaced by (ẋ, ∂H/∂x)
    eliminated = {x for vector in values for x in _existing(vector)} | set(_existing(desc.internal or ()))
    for which, i, solve, kind, label, *rest in desc.order:
        expr = scalar((desc.relations if which == "rel" else desc.laws)[i])
        if expr.free_symbols & eliminated or solve in eliminated:
            raise ValueError(f"{desc.component}: relation {label or i} of a sparse description uses an "
                             "eliminated symbol")
        if solve is None:
            b.add_equation(expr, desc.component, kind, label or f"{which}[{i}]", (rest[0] if rest else None)
                           or desc.span, derived=True)
        else:
            b.define(solve, solve_for(expr, solve), derived=True)


def _scalar_values(values: dict, symbols: set) -> dict:
    """The eliminated `symbols` as sympy expressions of what remains: a vector solved as a
    plain copy of another (``λ = z``) that one's symbols, any other its row of the composed
    terms (a storage vector's flows are left to the caller: their rates)."""
    out = {}
    for vector, (terms, extras, rename) in values.items():
        if isinstance(vector, SymbolVector) and not vector.made:
            continue  # its symbols were never made: no expression holds them
        hit = [k for k, s in enumerate(vector) if s in symbols]
        if not hit:
            continue
        if rename is not None:
            continue  # a storage vector's flows: their rates (emit_sparse's sigma)
        terms, extras = _substitute(terms, extras, values)
        if (len(terms) == 1 and not extras and terms[0].coeff is sp.S.One and not terms[0].derivative
                and _is_identity(terms[0].matrix)):
            out.update({vector[k]: terms[0].symbols[k] for k in hit})
            continue
        for k in hit:
            out[vector[k]] = _row_expr(terms, k) + sum((e for i, e in extras if i == k), sp.Integer(0))
    return out


def _key(symbols):
    """The key of a vector in :func:`emit_sparse`'s values: a :class:`~phc.ir.dae.SymbolVector`
    itself (by identity, as the terms over it hold it), any other the tuple of its symbols."""
    return symbols if isinstance(symbols, SymbolVector) else tuple(symbols)


def _variables(b):
    return ((v.symbol, v.dsymbol, v.role) for v in getattr(b, "variables", ()))
