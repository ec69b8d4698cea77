"""The lower pass: a :class:`~phc.ir.dae.Dae` to a :class:`ResidualIR`.

Input: a :class:`~phc.ir.dae.Dae` (assembled, analysed). Output: a :class:`ResidualIR`.

The IR is everything the printer needs and nothing else: the ordered variables and
parameters, the residual rows, the analytic Jacobian ``dF/dy + cj·dF/dẏ`` as a sparse
pattern in compressed-sparse-column order (the order SUNDIALS' sparse solver expects),
and the auxiliary functions (Hamiltonian, powers, invariants, outputs). No analysis
happens in the printer; no printing happens here.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Optional

import numpy as np
import scipy.sparse as sps
import sympy as sp

from phc.analysis.matching import unique_keys
from phc.analysis.order import topological_order
from phc.frontend import budget
from phc.ir.dae import T, Dae
from phc.diagnostics import Diagnostic, DiagnosticList
from phc.errors import ModelError
from phc.codegen.nonsmooth import StickInfo, SwitchInfo, plain, switching, with_origins


@dataclass(frozen=True, eq=False)
class LinearTermIR:
    """``out[rows] += coeff · A @ v[cols]`` with v = y or ẏ; `pos` are the CSC positions
    of A's entries (in A.data order) in the Jacobian data."""

    coeff: sp.Expr
    matrix: sps.csr_matrix
    rows: np.ndarray
    cols: np.ndarray
    derivative: bool
    pos: np.ndarray


@dataclass(frozen=True, eq=False)
class QuadraticIR:
    """``coeff · xᵀAx`` with x = y[cols]; for dissipation forms, `pos` are the Jacobian
    data positions of the energy-balance row at `cols` (its gradient is 2·coeff·A x)."""

    coeff: sp.Expr
    matrix: sps.csr_matrix
    cols: np.ndarray
    pos: np.ndarray = None


@dataclass(frozen=True)
class ResidualIR:
    name: str
    variables: tuple[str, ...]
    differential: tuple[bool, ...]
    roles: tuple[str, ...]
    equation_labels: tuple[str, ...]
    y_symbols: tuple[sp.Symbol, ...]
    yp_symbols: tuple[Optional[sp.Symbol], ...]
    """The rates of the differential variables; None for an algebraic variable (no symbol:
    nothing can use the rate of a variable that has none)."""
    parameters: tuple[str, ...]
    base_parameters: tuple[int, ...]
    parameter_defaults: tuple[float, ...]
    p_symbols: tuple[sp.Symbol, ...]
    derived: tuple[tuple[int, sp.Expr], ...]
    residual: tuple[sp.Expr, ...]
    jac_rows: np.ndarray
    jac_cols: np.ndarray
    """The Jacobian pattern in CSC order (int64, read-only): arrays, not tuples of Python ints
    (36 bytes an entry each; a beam of 10⁵ elements has 5.4·10⁶ entries)."""
    jac_symbolic: tuple[tuple[int, sp.Expr, sp.Expr], ...]
    """The Jacobian entries with a symbolic part, as ``(k, dF/dy, dF/dẏ)`` with k their
    position in the pattern (ascending): every other entry of (`jac_rows`, `jac_cols`) is 0
    there and filled by the linear blocks alone (a mesh of 10⁵ elements has 5.4·10⁶ entries
    and a few dozen of these)."""
    hamiltonian: sp.Expr
    port_power: sp.Expr
    dissipation: sp.Expr
    invariants: tuple[sp.Expr, ...]
    invariant_labels: tuple[str, ...]
    velocity_invariants: tuple[sp.Expr, ...]
    velocity_invariant_labels: tuple[str, ...]
    outputs: tuple[tuple[str, sp.Expr], ...]
    sources: tuple[str, ...]
    linear_terms: tuple[LinearTermIR, ...] = ()
    quadratic_energy: tuple[QuadraticIR, ...] = ()
    quadratic_dissipation: tuple[QuadraticIR, ...] = ()
    energy_row: int = -1
    initial_rows: tuple = ()
    initial_cols: tuple = ()
    initial_data: tuple = ()
    initial_labels: tuple = ()
    initial_rhs: tuple = ()
    compile_time_parameters: tuple = ()
    input_tables: tuple = ()
    breakpoints: tuple = ()
    switches: tuple[SwitchInfo, ...] = ()
    """Switching conditions of the rows (:mod:`phc.codegen.nonsmooth`); their modes are
    the last entries of the parameter vector (derived parameters fixed at 0: free)."""
    sticks: tuple[StickInfo, ...] = ()
    """Set-valued ``sign`` terms and their stick modes."""
    common_subexpressions: dict = field(default_factory=dict, compare=False, repr=False)
    templates: dict = field(default_factory=dict, compare=False, repr=False)
    """Each expression's template up to the entries it reads, by the expression: found once for
    every printer (:func:`phc.codegen.repeat.repeated`); and, by the name ``"energy scale"``,
    the expression of ``energy_scale`` (:func:`phc.codegen.printer.energy_scale_expression`)."""
    """The common subexpressions of lists of these expressions, by the list: found once for the
    NumPy module and the compiled back end's printer (:func:`phc.codegen.printer.shared_cse`)."""

    @property
    def events(self) -> tuple[sp.Expr, ...]:
        """The switching functions, in the order ``events(t, y, yp, p, out)`` writes them: each switch's
        g_k (its boundary), then each set-valued sign's value while sticking (its exit). The one list
        the NumPy module's ``events`` and the C library's ``phc_events`` are printed from."""
        return tuple(s.boundary for s in self.switches) + tuple(s.exit for s in self.sticks)

    @property
    def jac_dy(self) -> tuple[sp.Expr, ...]:
        """dF/dy at every entry of the pattern (sympy's zero where only a block fills it)."""
        return self._full_jacobian(1)

    @property
    def jac_dyp(self) -> tuple[sp.Expr, ...]:
        """dF/dẏ at every entry of the pattern (sympy's zero where only a block fills it)."""
        return self._full_jacobian(2)

    def _full_jacobian(self, part: int) -> tuple[sp.Expr, ...]:
        full = [sp.S.Zero] * len(self.jac_rows)
        for entry in self.jac_symbolic:
            full[entry[0]] = entry[part]
        return tuple(full)


def _ordered_parameters(dae: Dae):
    """Base parameters first, then derived ones in dependency order."""
    base = [p for p in dae.parameters if p.expr is None]
    derived = [p for p in dae.parameters if p.expr is not None]
    by_symbol = {p.symbol: p for p in derived}
    edges = [(dep, p.symbol) for p in derived for dep in p.expr.free_symbols & set(by_symbol)]
    order = topological_order(by_symbol, edges)
    if order is None:  # refused where they are written (PHC-E103): a fault in phc
        raise AssertionError("derived parameters depend on each other in a cycle")
    return base + [by_symbol[s] for s in order]


def _frozen(a: np.ndarray) -> np.ndarray:
    """`a` as int64, not writable (the IR is frozen)."""
    a = np.ascontiguousarray(a, dtype=np.int64)
    a.flags.writeable = False
    return a


def _sympy_zero(d):
    """A Jacobian entry as sympy (the int 0 of an entry only a linear block fills: sympy's zero)."""
    return sp.S.Zero if d == 0 else d


def _refuse(message: str, span, path=None) -> None:
    raise ModelError(DiagnosticList([Diagnostic("PHC-E702", message, span=span, path=path,
                                                hint=budget.symbolic_hint())]))


def _check_derivatives(eq, syms, col_of_y, col_of_yp, sizes: budget.SizeCache) -> None:
    """Refuse (located) a row whose derivatives — the Jacobian's, and the time derivative
    the generated module takes of every row — would exceed the symbolic budget. The
    bound over all symbols at once is cheap; only above the limit is each variable
    looked at alone."""
    if sizes.derivative_work(eq.expr) <= budget.DIFF_LIMIT:
        return
    for s in sorted(syms, key=str):
        if s in col_of_y or s in col_of_yp or s == T:
            work = budget.derivative_work(eq.expr, s)
            if work > budget.DIFF_LIMIT:
                _refuse(f"equation `{eq.label}` is too costly to differentiate: its derivative by `{s}` would take "
                        f"an estimated {work:,} nodes of symbolic work, above the limit of {budget.DIFF_LIMIT:,}",
                        eq.span)


def _check_cse_input(dae: Dae, entries: dict, sizes: budget.SizeCache) -> None:
    """Refuse a module whose expressions are too large in total for common-subexpression
    elimination (superlinear in sympy), naming the largest contributor."""
    per_row = [sizes.tree_size(eq.expr) if eq.expr.args else 1 for eq in dae.equations]
    for (i, _), pair in entries.items():
        per_row[i] += sum(sizes.tree_size(d) for d in pair if isinstance(d, sp.Basic) and d.args)
    outputs = [(name, sizes.tree_size(expr)) for name, expr in dae.outputs]
    others = sum(sizes.tree_size(e) for e in (dae.hamiltonian, dae.dissipation, dae.port_power))
    others += sum(sizes.tree_size(inv.expr) for inv in (*dae.invariants, *dae.velocity_invariants))
    total = sum(per_row) + sum(n for _, n in outputs) + others
    if total <= budget.CSE_LIMIT:
        return
    head = (f"the generated module would hold {total:,} expression nodes, above the limit of {budget.CSE_LIMIT:,} "
            "for common-subexpression elimination")
    worst_row = max(range(len(per_row)), key=per_row.__getitem__) if per_row else None
    worst_out = max(outputs, key=lambda o: o[1]) if outputs else None
    if worst_out is not None and (worst_row is None or worst_out[1] > per_row[worst_row]):
        _refuse(f"{head}; the largest is output `{worst_out[0]}` ({worst_out[1]:,} nodes)", None,
                f"simulation.outputs.{worst_out[0]}")
    eq = dae.equations[worst_row]
    _refuse(f"{head}; the largest is equation `{eq.label}` with its Jacobian entries ({per_row[worst_row]:,} nodes)",
            eq.span)


WIDE_SUM = 16
"""Rows that are sums of more terms than this are differentiated term by term (see
:func:`_differentiator`)."""


def _differentiator(row: sp.Expr):
    """``s -> d row / d s`` for the symbols of `row`. A sum of many terms (the energy
    balance Ė − P_ports − P_diss, a junction of many ports) is differentiated term by term,
    only the terms that hold `s`: sympy's ``diff`` of a sum visits every term for every
    symbol, quadratic in the terms of the row. The result is the same expression (an
    ``Add`` of the same nonzero derivatives, canonically ordered)."""
    if not (row.is_Add and len(row.args) > WIDE_SUM):
        return lambda s: budget.derivative(row, s)
    holding: dict = {}
    for term in row.args:
        for s in term.free_symbols:
            holding.setdefault(s, []).append(term)
    return lambda s: sp.Add(*[budget.derivative(term, s) for term in holding.get(s, ())])


def lower_residual(dae: Dae) -> ResidualIR:
    """Differentiate the residual and order everything for printing.

    Parameters
    ----------
    dae : Dae
        The assembled system.

    Returns
    -------
    ResidualIR
    """
    params = _ordered_parameters(dae)
    y = [v.symbol for v in dae.variables]
    yp = [v.dsymbol if v.differential else None for v in dae.variables]
    col_of_y = {s: j for j, s in enumerate(y)}
    col_of_yp = {s: j for j, s in enumerate(yp) if s is not None}
    entries: dict[tuple[int, int], list] = {}
    sizes = budget.SizeCache()
    # Non-smooth functions and conditions: Piecewise rows whose conditions are switches with
    # modes in the parameter vector, differentiated branch by branch (phc.codegen.nonsmooth).
    modes: list[tuple[str, sp.Symbol]] = []

    def mode_symbol(kind: str, k: int) -> sp.Symbol:
        symbol = sp.Dummy(f"{kind}{k}", real=True)
        modes.append((f"{kind}[{k}]", symbol))
        return symbol

    switched = switching([eq.expr for eq in dae.equations], [eq.kind for eq in dae.equations],
                         [eq.label for eq in dae.equations], y, yp, mode_symbol)
    rows_expr = switched.rows
    for i, eq in enumerate(dae.equations):
        if eq.expr is sp.S.Zero and rows_expr[i] is sp.S.Zero:
            continue  # a row of a linear block (most rows of a mesh): its entries come from the block
        syms = eq.expr.free_symbols
        _check_derivatives(eq, syms, col_of_y, col_of_yp, sizes)
        row = rows_expr[i]
        derivative = _differentiator(row)
        for s in row.free_symbols:
            if s in col_of_y:
                entries.setdefault((i, col_of_y[s]), [0, 0])[0] = budget.drop_deltas(derivative(s))
            elif s in col_of_yp:
                entries.setdefault((i, col_of_yp[s]), [0, 0])[1] = budget.drop_deltas(derivative(s))
    # The entries of the linear blocks (most of a mesh's Jacobian) stay arrays: each entry
    # (i, j) is the code j·m + i, so the sorted codes are the CSC order of (row, col) pairs.
    m_rows = max(len(dae.equations), 1)
    raw_terms, codes = [], []
    for block in dae.linear_blocks:
        rows = np.asarray(block.rows, dtype=np.int64)
        for term in block.terms:
            A = sps.csr_matrix(term.matrix)
            A.sum_duplicates()
            A.sort_indices()
            cols = np.array([col_of_y[sym] for sym in term.symbols], dtype=np.int64)
            coo = A.tocoo()  # same entry order as A.data for a canonical CSR
            code = cols[coo.col] * m_rows + rows[coo.row]
            codes.append(code)
            raw_terms.append((term, A, rows, cols, code))
    # The energy accumulator row Ė − P_ports − P_diss depends on every state of a
    # quadratic dissipation form (a dense row, one per model).
    energy_row = next(i for i, eq in enumerate(dae.equations) if eq.kind == "energy")
    for form in dae.quadratic_dissipation:
        for sym in form.symbols:
            entries.setdefault((energy_row, col_of_y[sym]), [0, 0])
    symbolic = np.array([j * m_rows + i for i, j in entries], dtype=np.int64)
    keys = unique_keys(np.concatenate([symbolic, *codes]))  # sorted by (column, row)
    linear_terms = tuple(
        LinearTermIR(term.coeff, A, rows, cols, term.derivative, np.searchsorted(keys, code).astype(np.int64))
        for term, A, rows, cols, code in raw_terms)
    # the entries with a symbolic part only (an entry only a block fills is 0 there)
    jac_symbolic = sorted([(k, _sympy_zero(dy), _sympy_zero(dyp))
                           for k, (dy, dyp) in zip(np.searchsorted(keys, symbolic).tolist(), entries.values())],
                          key=lambda entry: entry[0])

    def quadratic(forms, with_pos=False):
        out = []
        for f in forms:
            cols = np.array([col_of_y[sym] for sym in f.symbols], dtype=np.int64)
            pos = np.searchsorted(keys, cols * m_rows + energy_row).astype(np.int64) if with_pos else None
            out.append(QuadraticIR(f.coeff, sps.csr_matrix(f.matrix), cols, pos))
        return tuple(out)

    _check_cse_input(dae, entries, sizes)
    return ResidualIR(
        name=dae.name,
        variables=tuple(v.name for v in dae.variables),
        differential=tuple(v.differential for v in dae.variables),
        roles=tuple(v.role for v in dae.variables),
        equation_labels=tuple(eq.label for eq in dae.equations),
        y_symbols=tuple(y),
        yp_symbols=tuple(yp),
        parameters=tuple(p.name for p in params) + tuple(name for name, _ in modes),
        base_parameters=tuple(i for i, p in enumerate(params) if p.expr is None),
        parameter_defaults=tuple(p.default for p in params) + (0.0,) * len(modes),
        p_symbols=tuple(p.symbol for p in params) + tuple(s for _, s in modes),
        derived=(tuple((i, p.expr) for i, p in enumerate(params) if p.expr is not None)
                 + tuple((len(params) + k, sp.Integer(0)) for k in range(len(modes)))),
        residual=tuple(rows_expr),
        jac_rows=_frozen(keys % m_rows),
        jac_cols=_frozen(keys // m_rows),
        jac_symbolic=tuple(jac_symbolic),
        hamiltonian=plain(dae.hamiltonian),
        port_power=plain(dae.port_power),
        dissipation=plain(dae.dissipation),
        invariants=tuple(plain(inv.expr) for inv in dae.invariants),
        invariant_labels=tuple(inv.label for inv in dae.invariants),
        velocity_invariants=tuple(plain(inv.expr) for inv in dae.velocity_invariants),
        velocity_invariant_labels=tuple(inv.label for inv in dae.velocity_invariants),
        outputs=tuple((name, plain(expr)) for name, expr in dae.outputs),
        sources=dae.sources,
        linear_terms=linear_terms,
        quadratic_energy=quadratic(dae.quadratic_energy),
        quadratic_dissipation=quadratic(dae.quadratic_dissipation, with_pos=True),
        energy_row=energy_row,
        initial_rows=tuple(i for i, (_, rel, *_) in enumerate(dae.initial_relations) for _ in rel),
        initial_cols=tuple(col_of_y[s] for _, rel, *_ in dae.initial_relations for s in rel),
        initial_data=tuple(float(c) for _, rel, *_ in dae.initial_relations for c in rel.values()),
        initial_labels=tuple(label for label, *_ in dae.initial_relations),
        initial_rhs=tuple(float(rhs[0]) if rhs else 0.0 for _, _, *rhs in dae.initial_relations),
        compile_time_parameters=dae.compile_time_parameters,
        input_tables=dae.input_tables,
        breakpoints=dae.breakpoints,
        switches=with_origins(switched.switches, dae.topology.rows if dae.topology is not None else ()),
        sticks=switched.sticks,
    )
