"""Component descriptions, and the rows derived from them.

A lowerer describes its component once, with a :class:`DiracBuilder`: ports, storage
pairs bound to states (``f = ẋ``, ``e = ∂H/∂x``), resistive pairs with their laws, the
Dirac structure in kernel form ``F f + E e + G λ = b(t)`` (T. Berger, R. Hochdahl,
T. Reis, R. Seifried, "Port-Hamiltonian modelling of coupled rigid/flexible multibody
systems", section 2, the kernel representation with its ∃λ) and the Hamiltonian. The
result is one immutable :class:`~phc.dae.ComponentDescription`.

:func:`emit` derives the component's equation rows from that description — the same
relations, with every storage pair replaced by ``(ẋ, ∂H/∂x)`` and every internal pair
eliminated — so the equations that are compiled and the structure that is certified are
one thing. A relation may name the symbol it is solved for (``solve=``): a port variable
solved for becomes an explicit definition (assembly substitutes it, alias elimination), an
internal pair symbol is eliminated, anything else stays a residual row.

Lowerers that write nonlinear rows directly (rigid bodies) bind their storage so that
:mod:`phc.checks.rows` compares their rows with their description at sampled states.

Large components whose rows are sparse matrix blocks (discretized PDEs, modal
truncations, matrix components, the moving beam's flexible part) register the projection
of their structure onto their ports (``kind="port_projection"``: what the Dirac and
coupling certificate works with) and, as its `structure`, the complete semi-discrete pH
system, kept sparse: relations over symbol vectors (:meth:`DiracBuilder.block`, a
:class:`~phc.dae.LinearTerm` per matrix), storage vectors ``f = ẋ``, ``e = Qx``
(:meth:`DiracBuilder.storage_vector`) and resistive vectors with sparse laws. Their rows
are written directly and compared with that structure by :mod:`phc.checks.rows`.
"""

from __future__ import annotations

from typing import Optional

import sympy as sp

from phc.dae import ComponentDescription, LinearTerm, SparseRelations, Storage, StorageVector


class DiracBuilder:
    """Collects one component's description (see the module docstring)."""

    def __init__(self, component: str, kind: str, span=None):
        self.component, self.kind, self.span = component, kind, span
        self.flows: list[sp.Symbol] = []
        self.efforts: list[sp.Symbol] = []
        self.multipliers: list[sp.Symbol] = []
        self.relations: list[sp.Expr] = []
        self.laws: list[sp.Expr] = []
        self.ports: dict[str, tuple[list[int], list[int]]] = {}
        self.storage: list[Storage] = []
        self.resistive: list[tuple[sp.Symbol, sp.Symbol]] = []
        self.internal: list[sp.Symbol] = []
        self.hamiltonian: Optional[sp.Expr] = None
        # (relation or law, index, solved-for symbol, row kind, row label) in declaration order
        self.order: list[tuple[str, int, Optional[sp.Symbol], str, str]] = []
        self.blocks: list[list] = []  # [label, n, terms, extra, law] (frozen by describe)
        self.storage_vectors: list[StorageVector] = []
        self._bound: set = set()  # internal symbols bound by storage or resistive vectors

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
        """`n` fresh internal flow/effort pairs, as two vectors (see :meth:`pair`)."""
        f = tuple(sp.Symbol(f"cert:{self.component}.f_{local}[{i}]", real=True) for i in range(n))
        e = tuple(sp.Symbol(f"cert:{self.component}.e_{local}[{i}]", real=True) for i in range(n))
        self.flows.extend(f)
        self.efforts.extend(e)
        self.internal.extend(f)
        self.internal.extend(e)
        return f, e

    def storage_vector(self, local: str, states, rates, gradient) -> tuple[tuple, tuple]:
        """Storage pairs bound to `states`, as vectors: ``f = ẋ`` (`rates`) and
        ``e = Σ gradient`` (:class:`~phc.dae.LinearTerm` over the states: ∂H/∂x of a
        quadratic energy)."""
        f, e = self.vector(local, len(states))
        self.storage_vectors.append(StorageVector(f, e, tuple(states), tuple(rates), tuple(gradient)))
        self._bound.update(f)
        self._bound.update(e)
        return f, e

    def resistor_vector(self, local: str, n: int) -> tuple[tuple, tuple]:
        """`n` resistive pairs; their law goes in with :meth:`block` (``law=True``)."""
        f, e = self.vector(local, n)
        self.resistive.extend(zip(f, e))
        self._bound.update(f)
        self._bound.update(e)
        return f, e

    def mults(self, local: str, n: int) -> tuple[sp.Symbol, ...]:
        """`n` multipliers ``local[i]``."""
        lam = tuple(sp.Symbol(f"cert:{self.component}.{local}[{i}]", real=True) for i in range(n))
        self.multipliers.extend(lam)
        return lam

    def block(self, label: str, n: int, terms, law: bool = False) -> int:
        """`n` relations ``Σ terms = 0`` kept sparse (each term a :class:`~phc.dae.LinearTerm`
        over symbols of this description); returns the block's number for :meth:`add_to`."""
        terms = [t if isinstance(t, LinearTerm) else LinearTerm(*t) for t in terms]
        for t in terms:
            if t.derivative or t.matrix.shape != (n, len(t.symbols)):
                raise ValueError(f"{self.component}: block {label}: a term of shape {t.matrix.shape} over "
                                 f"{len(t.symbols)} symbols in {n} relations")
        self.blocks.append([label, n, terms, [], law])
        return len(self.blocks) - 1

    def add_to(self, block: int, i: int, expr) -> None:
        """Add a sympy term to relation `i` of `block` (a boundary coupling, a modulation)."""
        if expr != 0:
            self.blocks[block][3].append((i, sp.sympify(expr)))  # safe: a sympy expression or number

    def port(self, port) -> None:
        start = len(self.flows)
        self.flows.extend(port.f)
        self.efforts.extend(port.e)
        idx = list(range(start, start + port.dimension))
        self.ports[port.name.rsplit(".", 1)[-1]] = (idx, idx)

    def mult(self, local: str) -> sp.Symbol:
        lam = sp.Symbol(f"cert:{self.component}.{local}", real=True)
        self.multipliers.append(lam)
        return lam

    def rel(self, expr, solve: Optional[sp.Symbol] = None, kind: str = "dirac", label: str = "") -> None:
        """A relation of the Dirac structure ``= 0`` (linear in flows, efforts, multipliers;
        an affine part in t is a source's value)."""
        self.order.append(("rel", len(self.relations), solve, kind, label))
        self.relations.append(expr if isinstance(expr, sp.Basic) else sp.Integer(expr))

    def law(self, expr, solve: Optional[sp.Symbol] = None, kind: str = "resistive", label: str = "") -> None:
        """A resistive or constitutive law ``= 0`` (may be nonlinear)."""
        self.order.append(("law", len(self.laws), solve, kind, label))
        self.laws.append(expr if isinstance(expr, sp.Basic) else sp.Integer(expr))

    def energy(self, hamiltonian: sp.Expr) -> None:
        self.hamiltonian = sp.sympify(hamiltonian)  # safe: a sympy expression or number

    def describe(self, states=(), note: str = "", kind: Optional[str] = None,
                 structure: Optional[ComponentDescription] = None) -> ComponentDescription:
        """The description. With ``kind="port_projection"`` it is not complete; `structure`
        is then the complete description it projects (see the module docstring)."""
        kind = kind or self.kind
        symbols = (*self.flows, *self.efforts, *self.multipliers)
        if len(set(symbols)) != len(symbols):
            raise ValueError(f"{self.component}: a flow, effort or multiplier of the description is declared twice")
        bound = {s.flow for s in self.storage} | {s.effort for s in self.storage} | self._bound
        resistive = {x for pair in self.resistive for x in pair}
        complete = kind != "port_projection" and all(s in bound or s in resistive for s in self.internal)
        blocks = tuple(SparseRelations(label, n, tuple(terms), tuple(extra), law)
                       for label, n, terms, extra, law in self.blocks)
        return ComponentDescription(
            self.component, kind, tuple(self.flows), tuple(self.efforts), tuple(self.multipliers),
            tuple(self.relations), dict(self.ports), tuple(states), self.span, note,
            storage=tuple(self.storage), laws=tuple(self.laws), hamiltonian=self.hamiltonian,
            resistive=tuple(self.resistive), complete=complete, order=tuple(self.order),
            blocks=blocks, storage_vectors=tuple(self.storage_vectors), structure=structure)

    def register(self, b, states=(), note: str = "", kind: Optional[str] = None,
                 structure: Optional[ComponentDescription] = None) -> ComponentDescription:
        """Record the description with the lowering recorder `b` (certification reads it) and return it."""
        desc = self.describe(states, note, kind, structure)
        b.dirac.append(desc)
        return desc


def solve_for(expr: sp.Expr, symbol: sp.Symbol) -> sp.Expr:
    """`expr` = 0 solved for `symbol`, which must enter linearly with a coefficient free of
    it (every relation a lowerer marks as a definition is of this form)."""
    coeff = sp.diff(expr, symbol)
    if symbol in coeff.free_symbols or coeff == 0:
        raise ValueError(f"{expr} = 0 cannot be solved for {symbol} without solving an equation")
    return -expr.xreplace({symbol: sp.Integer(0)}) / coeff


def emit(b, desc: ComponentDescription, dissipation_span=None) -> None:
    """Derive the component's rows from its description and add them to the lowering
    recorder `b` (:class:`phc.lowering.Recorder`): definitions, residual rows, the
    Hamiltonian and the dissipated power (located at `dissipation_span`, or the component)."""
    if desc.blocks or desc.storage_vectors:
        raise ValueError(f"{desc.component}: a sparse description is compared with rows written directly, "
                         "not emitted")
    sigma: dict = {}
    for s in desc.storage:
        sigma[s.flow] = s.rate
        sigma[s.effort] = s.gradient
    internal = {x for x in (*desc.flows, *desc.efforts)} - {x for idx, _ in desc.ports.values()
                                                             for x in (*(desc.flows[i] for i in idx),
                                                                       *(desc.efforts[i] for i in idx))}
    for which, i, solve, kind, label in desc.order:
        expr = (desc.relations if which == "rel" else desc.laws)[i].xreplace(sigma)
        if solve is None:
            left = expr.free_symbols & internal - set(sigma)
            if left:
                raise ValueError(f"{desc.component}: row {label or i} still holds internal {sorted(map(str, left))}")
            b.add_equation(expr, desc.component, kind, label or f"{which}[{i}]", desc.span, derived=True)
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
