"""The print pass: a :class:`~phc.codegen.lower.ResidualIR` as a standalone Python module.

Input: a :class:`~phc.codegen.lower.ResidualIR`. Output: the module's source text.

The module imports only ``math`` and ``numpy``, is readable (one named local per
variable, common subexpressions as ``_c0, _c1, ...``), and exposes::

    VARIABLES, DIFFERENTIAL, ROLES, EQUATIONS, PARAMETERS, PARAMETER_DEFAULTS,
    JAC_ROWS, JAC_COLS                       (CSC order of the Jacobian pattern)
    full_parameters(base) -> p
    residual(t, y, yp, p, out)               F(t, y, ẏ, p)
    jacobian(t, y, yp, p, cj, out)           data of dF/dy + cj·dF/dẏ in CSC order
    hamiltonian(t, y, p), powers(t, y, yp, p) -> (port power, dissipation)
    invariants(t, y, p), velocity_invariants(t, y, p), outputs(t, y, yp, p)

This printer only builds strings; all analysis happened in :mod:`phc.codegen.lower`. An
expression that recurs at many entries is one vectorized statement
(:meth:`ModulePrinter._vectorized`, the split from :mod:`phc.codegen.repeat`).

The module is over 800 lines because it is one printer: the module's constant tables, its
functions and their statements (scalar, vectorized, conditional) are printed from one table
of names, which a split would have to pass around.
"""

from __future__ import annotations

import itertools
import keyword
import math
import os
import re
from typing import Sequence

import numpy as np
import sympy as sp
from sympy.printing.pycode import PythonCodePrinter

from phc import __version__
from phc.analysis.matching import unique_keys
from phc.frontend.budget import drop_deltas
from phc.codegen import packing
from phc.codegen.lower import ResidualIR
from phc.codegen.repeat import REPEAT_MIN, progression, repeated, slot
from phc.codegen.terms import ordered_terms
from phc.ir.dae import STORED_ENERGY, T
from phc.errors import CodegenError
from phc.frontend.inputs import table_arrays


class _Printer(PythonCodePrinter):
    """Python printer with exact float literals and local names for model symbols."""

    def __init__(self, names: dict):
        super().__init__({"standard": "python3", "fully_qualified_modules": True})
        self._names = names

    def _print_Symbol(self, expr):
        # Every symbol that reaches the module has a name chosen by the printer (a sanitized,
        # prefixed identifier): a name from the model file is never spliced in as written.
        try:
            return self._names[expr]
        except KeyError:
            raise CodegenError(f"no generated name for symbol `{expr}` (a phc bug: please report it)") from None

    _print_Dummy = _print_Symbol  # the modes of switches (phc.codegen.nonsmooth)

    def _as_ordered_terms(self, expr, order=None):
        # sympy's order of a sum's terms without its dense monomials (phc.codegen.terms):
        # the same text in O(n log n) instead of n² for a sum of n terms in n symbols
        if (order or self.order) is None:
            return ordered_terms(expr)
        return super()._as_ordered_terms(expr, order=order)

    def _print_Float(self, expr):
        value = float(expr)  # a sympy Float beyond double range (1/m of m = 5e-324) is ±inf here
        if math.isfinite(value):
            return repr(value)
        return "math.nan" if math.isnan(value) else ("math.inf" if value > 0 else "-math.inf")

    def _print_Rational(self, expr):
        return f"({expr.p}/{expr.q})"

    def _print_Switch(self, expr):
        # a switching condition's boundary value: g itself while the mode is 0 (free), else
        # the mode ±1 the event driver froze (phc.codegen.nonsmooth)
        mode, g = (self._print(a) for a in expr.args)
        return f"(({g}) if {mode} == 0.0 else {mode})"

    def _print_Heaviside(self, expr):
        # only inside a condition (elsewhere lower rewrote it as a Piecewise)
        x = self._print(expr.args[0])
        h0 = self._print(expr.args[1]) if len(expr.args) > 1 else "0.5"
        return f"(1.0 if ({x}) > 0 else (0.0 if ({x}) < 0 else {h0}))"

    def _print_InputTable(self, expr):
        k = int(expr.args[0])
        return f"_table(_TABLE{k}_T, _TABLE{k}_V, _TABLE{k}_KIND, {self._print(expr.args[1])})"

    def _print_InputTableSlope(self, expr):
        k = int(expr.args[0])
        return f"_table_slope(_TABLE{k}_T, _TABLE{k}_V, _TABLE{k}_KIND, {self._print(expr.args[1])})"


_ZERO = sp.S.Zero


def _nonzero(e) -> bool:
    """``e != 0``, without sympy's comparison for its zero (most rows and Jacobian entries of a
    mesh, which its linear blocks hold)."""
    return e is not _ZERO and e != 0


_NOT_IDENTIFIER = re.compile(r"[^A-Za-z0-9_]")


def _identifier(prefix: str, name: str, taken: set) -> str:
    """A Python identifier for a model name: ``prefix`` + the name with every character
    outside ``[A-Za-z0-9_]`` replaced by ``_``, made unique within ``taken``.

    The prefixes (``y_``, ``yp_``, ``p_``) form a namespace no module global or fixed local of
    the generated code uses, so no user name (``N``, ``H``, ``abs``, ``key``, ``P_ports``...)
    can shadow one.
    """
    base = prefix + (_NOT_IDENTIFIER.sub("_", name.replace("[", "_").replace("]", "")).strip("_") or "v")
    assert base.isidentifier() and not keyword.iskeyword(base)
    ident, k = base, 1
    while ident in taken:
        k += 1
        ident = f"{base}_{k}"
    taken.add(ident)
    return ident


_NOT_IDENTIFIER_LINES = re.compile(r"[^A-Za-z0-9_\n]")


def _identifiers(prefix: str, names: Sequence[str], taken: set) -> list[str]:
    """:func:`_identifier` of each of `names` in order, the characters replaced in one pass
    over all names (a mesh's 10⁵ variables: one regular-expression substitution, not 10⁵)."""
    joined = "\n".join(names)
    if joined.count("\n") != max(len(names) - 1, 0):  # a name with a line break: one by one
        return [_identifier(prefix, name, taken) for name in names]
    cleaned = _NOT_IDENTIFIER_LINES.sub("_", joined.replace("[", "_").replace("]", "")).split("\n") if names else []
    out = []
    for part in cleaned:
        ident = base = prefix + (part.strip("_") or "v")
        k = 1
        while ident in taken:
            k += 1
            ident = f"{base}_{k}"
        taken.add(ident)
        out.append(ident)
    return out


def _clean(name: str) -> str:
    """What :func:`_identifier` makes of `name` after the prefix (before any suffix)."""
    return _NOT_IDENTIFIER.sub("_", name.replace("[", "_").replace("]", "")).strip("_") or "v"


class _Names(dict):
    """Symbol -> its name in the generated code. The names of the model's variables and
    their rates are made when first printed (``y_`` or ``yp_`` and the cleaned model name;
    :func:`_identifiers` would give each the same, the cleaned names being distinct): a mesh's
    functions print a few of its 10⁵-odd variables, and a name kept for each took 0.2 KiB per
    unknown of the compile peak (issue 35)."""

    def __init__(self, base: dict, variables: Sequence[str], y_slot: dict, yp_slot: dict):
        super().__init__(base)
        self._variables, self._y, self._yp = variables, y_slot, yp_slot

    def __missing__(self, symbol):
        j, prefix = self._y.get(symbol), "y_"
        if j is None:
            j, prefix = self._yp.get(symbol), "yp_"
        if j is None:  # neither a variable nor a rate
            raise KeyError(symbol)
        ident = self[symbol] = prefix + _clean(self._variables[j])
        return ident


def _distinct_cleaned(names: Sequence[str]) -> bool:
    """Whether :func:`_clean` of `names` are all distinct (:func:`_identifiers` adds no suffix)."""
    joined = "\n".join(names)
    if joined.count("\n") != max(len(names) - 1, 0):
        return False  # a name with a line break: the caller names them one by one
    cleaned = _NOT_IDENTIFIER_LINES.sub("_", joined.replace("[", "_").replace("]", "")).split("\n") if names else []
    del joined
    return len({part.strip("_") or "v" for part in cleaned}) == len(cleaned)


PACK_LIMIT = 256
"""Arrays longer than this are printed as periodic runs and base64 of their bytes
(:mod:`phc.codegen.packing`): a 1000-element beam's 40 000 matrix entries as float literals
take seconds for Python to compile, and a uniform mesh's stencil repeats."""


_PACKED = {"float": "<f8", "np.int64": "<i8", "np.int32": "<i4"}


def _array(values: Sequence, dtype: str) -> str:
    if len(values) > PACK_LIMIT and dtype in _PACKED:
        return packing.expression(values, _PACKED[dtype])
    if dtype == "bool" and len(values) > PACK_LIMIT:  # run lengths: a mesh's states, then its efforts
        flags = np.asarray([bool(v) for v in values] if not isinstance(values, np.ndarray) else values, dtype=bool)
        starts = [0] + (np.flatnonzero(flags[1:] != flags[:-1]) + 1).tolist()
        counts = [b - a for a, b in zip(starts, [*starts[1:], len(flags)])]
        return f"np.repeat(np.array({[bool(flags[a]) for a in starts]!r}), {counts!r})"
    values = values.tolist() if isinstance(values, np.ndarray) else list(values)  # Python numbers' repr
    body = ", ".join(repr(v) for v in values)
    return f"np.array([{body}], dtype={dtype})"


def _fuse(terms, m: int, n: int) -> dict:
    """One sparse pattern for several linear terms: global CSR structure, each term's
    positions in it, and the Jacobian data positions of the pattern entries."""
    keys, datas = [], []
    for t in terms:
        coo = t.matrix.tocoo()
        key = t.rows[coo.row] * n  # the entry (i, j) as i·n + j: sorted, the CSR order
        key += t.cols[coo.col]
        keys.append(key)
        datas.append(coo.data)
        del coo, key
    keys = np.concatenate(keys)  # (the per-term pieces freed: a mesh's millions of entries)
    unique, first, inverse = unique_keys(keys, return_index=True, return_inverse=True)
    del keys
    j = np.concatenate([t.pos for t in terms])
    ur = unique // n
    indptr = np.zeros(m + 1, dtype=np.int64)
    np.add.at(indptr, ur + 1, 1)
    indptr = np.cumsum(indptr)
    offsets = np.cumsum([0] + [len(d) for d in datas])
    return {"indptr": indptr, "indices": unique % n, "jac": j[first],
            "pos": [inverse[offsets[k]:offsets[k + 1]] for k in range(len(terms))], "data": datas}


_MATVEC_HELPERS = '''
def _matvec_add(A, x, out):
    """out += A @ x for a CSR matrix A (scipy's public product: one temporary of len(out))."""
    out += A @ x


def _axpy(a, x, out):
    """out += a * x in one BLAS pass."""
    if out.flags.c_contiguous and out.dtype == np.float64:
        z = _daxpy(x, out, a=a)
        if z is not out:  # pragma: no cover - f2py made a copy
            out[:] = z
    else:
        out += a * x
'''


_TABLE_HELPERS = '''
def _table(times, values, kind, t):
    """Value of an input table at t: linear or zero-order hold; end values hold outside."""
    if kind == "previous":
        return float(values[max(int(np.searchsorted(times, t, side="right")) - 1, 0)])
    return float(np.interp(t, times, values))


def _table_slope(times, values, kind, t):
    """d/dt of the table's interpolant (0 for a zero-order hold and outside the table)."""
    if kind == "previous" or t < times[0] or t >= times[-1]:
        return 0.0
    i = int(np.searchsorted(times, t, side="right")) - 1
    return float((values[i + 1] - values[i]) / (times[i + 1] - times[i]))
'''


def _index_type(values: Sequence) -> str:
    """The type of an index array the module's own code reads (a sparse block's structure, the
    positions of its entries): int32 where every entry fits, as SciPy stores a sparse matrix's
    indices (a module of 10⁵ mesh elements holds about 10⁷ such entries; int64 doubled them, and
    SciPy converted them to int32 copies of its own)."""
    a = np.asarray(values)
    fits = a.size == 0 or (int(a.min()) >= -2 ** 31 and int(a.max()) < 2 ** 31)
    return "np.int32" if fits else "np.int64"


def _indices(values: Sequence) -> str:
    """`values` printed as an index array of :func:`_index_type`."""
    return _array(values, _index_type(values))


def _sparse_constant(name: str, matrix) -> list[str]:
    m = matrix.tocsr()
    return [f"{name} = _sps.csr_matrix(({_array(m.data, 'float')}, "
            f"{_indices(m.indices)}, {_indices(m.indptr)}), "
            f"shape={tuple(int(x) for x in m.shape)!r})"]


RUN_LENGTH = 8
"""A run of at least this many names `stem[i]tail` with consecutive i, or of one repeated
name, is printed as one line (``*_indexed(...)``, ``*(name,) * k``): a per-unknown tuple of
a 10⁴-element mesh written one name a line made Python's compiler of the module peak at
about 0.9 KiB per name (106 MiB for the 120 000 names of a string's VARIABLES, ROLES and
EQUATIONS), more than the rest of the module together."""

_INDEXED = re.compile(r"(.*)\[([0-9]+)\](.*)", re.S)


def _runs(values: Sequence[str]) -> list[tuple]:
    """`values` as runs: ("same", name, k), ("indexed", stem, start, stop, tail) or ("one", name)."""
    out: list[tuple] = []
    i, n = 0, len(values)
    while i < n:
        v = values[i]
        j = i + 1
        while j < n and values[j] == v:
            j += 1
        if j - i >= RUN_LENGTH:
            out.append(("same", v, j - i))
            i = j
            continue
        m = _INDEXED.fullmatch(v) if isinstance(v, str) else None
        if m is not None:
            stem, start, tail = m.group(1), int(m.group(2)), m.group(3)
            j = i + 1
            while j < n and isinstance(values[j], str) and values[j] == f"{stem}[{start + j - i}]{tail}":
                j += 1
            if j - i >= RUN_LENGTH and str(start) == m.group(2):
                out.append(("indexed", stem, start, start + j - i, tail))
                i = j
                continue
        out.append(("one", v))
        i += 1
    return out


def _tuple(values: Sequence[str]) -> str:
    """A tuple of names, one a line; long runs (a mesh's entries, a repeated role) one line
    each through ``_indexed`` (:data:`RUN_LENGTH`)."""
    if not values:
        return "()"
    lines = []
    for run in _runs(list(values)):
        if run[0] == "same":
            lines.append(f"    *({run[1]!r},) * {run[2]},\n")
        elif run[0] == "indexed":
            _, stem, start, stop, tail = run
            lines.append(f"    *_indexed({stem!r}, {start}, {stop}{f', {tail!r}' if tail else ''}),\n")
        else:
            lines.append(f"    {run[1]!r},\n")
    return "(\n" + "".join(lines) + ")"


BULK_SHARE = 4
"""A function reads y (yp, p) through one ``tolist()`` when it uses at least 1/BULK_SHARE of
its entries (a long vector of which a few entries are used is indexed instead)."""


CSE_BLOCK = 2000
"""The expressions of one function are searched for common subexpressions in blocks of this
many. sympy's search pairs up the sums and products that share arguments (a parameter, a
sign), quadratic in their number: the residual of 10⁴ springs ``-k·x_i`` was one such
search. A function of fewer expressions is searched as a whole, as before."""


LONG_SUM = 256
"""A sum of more terms is printed as several statements of at most this many terms each,
``_cN = t1 + … + tK`` then ``_cN = _cN + tK+1 + …``: Python compiles ``a + b + c + …`` into
a tree as deep as the sum is long, and its compiler refuses a tree a few thousand levels
deep (the energy of a chain of 3000 springs and masses). The statements add the terms in
the order the one-line sum would (left to right), so every value is the same to the bit."""


def _cse(exprs: list, symbols) -> tuple[list, list]:
    """``sympy.cse`` of `exprs` (numbered by the iterator `symbols`), block by block
    (:data:`CSE_BLOCK`): the replacements of all blocks, then the reduced expressions."""
    if len(exprs) <= CSE_BLOCK:
        return sp.cse(exprs, symbols=symbols, order="none")
    replacements, reduced = [], []
    for start in range(0, len(exprs), CSE_BLOCK):
        found, rest = sp.cse(exprs[start:start + CSE_BLOCK], symbols=symbols, order="none")
        replacements += found
        reduced += rest
    return replacements, reduced


def shared_cse(ir: ResidualIR, exprs: Sequence) -> tuple[list, list]:
    """:func:`_cse` of `exprs` (expressions of `ir`), once per IR: the result the NumPy module's
    printer found for the same list (it prints first; it records every search), else a new
    search, recorded. A C build searched the residual's and Jacobian's expressions twice. The
    replacement symbols are named by whoever searched (``_c0``, or ``_c24`` after a function's
    switch blocks): a compiled back end names its locals by their position."""
    key = tuple(exprs)
    found = ir.common_subexpressions.get(key)
    if found is None:
        found = ir.common_subexpressions[key] = _cse(list(exprs), sp.numbered_symbols("_c"))
    return found


_OUT_ENTRY = re.compile(r"out\[(\d+)\]")
"""A target that is an entry of the output array (its index the group)."""


def _vectorizable(node) -> bool:
    """Whether `node` is evaluated by NumPy on arrays as Python evaluates it on floats: a
    number, a symbol, a sum, a product, an integer power or ``abs`` (``math`` functions raise
    on a domain error; NumPy's return nan)."""
    if node.is_Atom:
        return node.is_Symbol or node.is_Number
    if node.is_Pow:
        return node.exp.is_Integer
    return node.is_Add or node.is_Mul or isinstance(node, sp.Abs)


def energy_scale_expression(ir: ResidualIR) -> sp.Expr:
    """The sum of the absolute values of the terms of H, the scale of relative energy errors
    (``energy_scale``). Each ``abs`` is left as written: sympy's evaluation of ``Abs`` (taking
    out factors of known sign) took 3 s for the 6000 terms of a chain of 3000 cells."""
    memo = ir.templates  # (built once for the NumPy module and a compiled back end)
    if "energy scale" not in memo:
        memo["energy scale"] = sp.Add(*[sp.Abs(term, evaluate=False) for term in sp.Add.make_args(ir.hamiltonian)])
    return memo["energy scale"]


def _complex_prone(expr) -> bool:
    """Whether `expr` has a power that is complex for a negative Python float (``x**(1/3)``:
    NumPy scalars give nan, which the guard reports; a complex value could be made real
    again by ``abs``). Square roots are printed as ``math.sqrt``, which refuses."""
    half = sp.Rational(1, 2)
    return any(not (a.exp.is_integer or a.exp in (half, -half)) for a in expr.atoms(sp.Pow))


class ModulePrinter:
    bulk_unpack = True
    """Whether the per-step functions (residual, Jacobian) unpack their arguments in bulk."""

    def __init__(self, ir: ResidualIR):
        self.ir = ir
        self._jac_symbols = None  # free symbols of the Jacobian entries (computed once)
        taken: set = set()
        # symbol -> its position in y, yp or p, in the order of the positions; the unpacking
        # line ``name = y[j]`` is written only for the symbols a function uses (a line per
        # unknown kept here took 0.15 KiB per unknown of a mesh's compile peak, issue 35)
        n = len(ir.y_symbols)
        self.unpack_y = dict(zip(ir.y_symbols, range(n)))
        self.unpack_yp = {s: j for j, s in enumerate(ir.yp_symbols) if s is not None}
        self.unpack_p = {}
        if _distinct_cleaned(ir.variables):
            # the prefixes y_, yp_ and p_ keep the three kinds of names apart: no suffix anywhere
            self.names: dict = _Names({T: "t"}, ir.variables, self.unpack_y, self.unpack_yp)
        else:  # some names clean to the same identifier: all named now, the later ones suffixed
            self.names = {T: "t"}
            for s, ident in zip(ir.y_symbols, _identifiers("y_", ir.variables, taken)):
                self.names[s] = ident
            # reserved for an algebraic variable too (no rate): the same names as with one
            for s, ident in zip(ir.yp_symbols, _identifiers("yp_", ir.variables, taken)):
                if s is not None:
                    self.names[s] = ident
        for j, (s, name) in enumerate(zip(ir.p_symbols, ir.parameters)):
            self.names[s] = _identifier("p_", name, taken)
            self.unpack_p[s] = j
        self.printer = _Printer(self.names)
        self.accumulate: set = set()  # targets that add to a precomputed value
        self.vector_constants: list = []  # the index arrays of vectorized statements (_vectorized)
        self.bulk = False
        """Unpack y, yp and p with one ``tolist()`` (the functions called in every step)."""

    def _switch_constants(self) -> list[str]:
        """Switching conditions (phc.codegen.nonsmooth, docs/events.md): labels in model names,
        the row each occurs in first, whether it depends on t only, and the parameter
        entries of the modes the simulation driver sets (0: evaluate directly)."""
        ir = self.ir
        slot = {s: j for j, s in enumerate(ir.p_symbols)}
        return [
            "# Switching conditions: g_k changes sign where a row switches branch (events(); a mode of 0\n"
            "# in p evaluates the condition directly, +-1 freezes the side). STICKS: set-valued sign terms.",
            f"SWITCHES = {_tuple([s.label for s in ir.switches])}",
            f"SWITCH_EQUATIONS = {_tuple([s.equation for s in ir.switches])}",
            f"SWITCH_COMPONENTS = {_tuple([s.component for s in ir.switches])}",
            f"SWITCH_TIME_ONLY = {_array([s.time_only for s in ir.switches], 'bool')}",
            f"SWITCH_SLOTS = {_array([slot[s.mode] for s in ir.switches], 'np.int64')}",
            "# +1: where g_k rises, the comparison SWITCHES[k] turns true (or its function's argument rises)",
            f"SWITCH_SENSE = {_array([float(s.sense) for s in ir.switches], 'float')}",
            f"SWITCH_COMPARISON = {_array([s.comparison for s in ir.switches], 'bool')}",
            f"STICKS = {_tuple([s.label for s in ir.sticks])}",
            f"STICK_EQUATIONS = {_tuple([s.equation for s in ir.sticks])}",
            f"STICK_SWITCH = {_array([s.switch for s in ir.sticks], 'np.int64')}",
            f"STICK_ORIENT = {_array([float(s.orient) for s in ir.sticks], 'float')}",
            f"STICK_SLOTS = {_array([slot[s.mode] for s in ir.sticks], 'np.int64')}",
        ]

    def _linear_function(self, m: int, n: int) -> str:
        """`_linear(p)`: the fused sparse matrices of all linear blocks, computed once per
        parameter vector (their coefficients depend on parameters only)."""
        exprs, targets, lines = [], [], []
        for wrt, (terms, fused) in self.fused.items():
            lines.append(f"_d{wrt} = np.zeros({len(fused['indices'])})")
            for k, t in enumerate(terms):
                exprs.append(t.coeff)
                targets.append(f"_c{wrt}{k}")
                lines.append(f"np.add.at(_d{wrt}, _L{wrt}{k}_POS, _c{wrt}{k} * _L{wrt}{k}_DATA)")
            lines.append(f"_A{wrt} = _sps.csr_matrix((_d{wrt}, _L{wrt}_INDICES, _L{wrt}_INDPTR), shape=({m}, {n}))")
        # The matrices A_y and A_ẏ (each applied by one mat-vec), and the linear part of the
        # Jacobian data as two full-length arrays (one copy and one axpy).
        for wrt in ("Y", "YP"):
            lines.append(f"_J{wrt} = np.zeros(len(JAC_ROWS))")
            if wrt in self.fused:
                lines.append(f"_J{wrt}[_L{wrt}_JAC] = _d{wrt}")
            else:
                lines.append(f"_A{wrt} = None")
        # A memo of one entry for the last parameter vector: an immutable tuple, replaced as a
        # whole (one reference assignment), so threads calling with different p at once each
        # get matrices of their own p — the module keeps no scratch state between calls.
        lines += ["_value = (_AY, _AYP, _JY, _JYP)", "_LINEAR_LAST = (key, _value)",
                  "return _value"]
        body = self._function("_linear(p)", "Fused sparse linear blocks (A_y, A_ẏ and their Jacobian data), "
                              "memoized for the last p.", exprs, targets,
                              prologue=["global _LINEAR_LAST", "key = p.tobytes()", "_last = _LINEAR_LAST", "if _last[0] == key:",
                                        "    return _last[1]"], epilogue=lines)
        return "_LINEAR_LAST = (None, None)\n\n\n" + body

    def _jac_dependencies(self, symbols) -> list[int]:
        """Indices of the variables (or derivatives) the Jacobian entries depend on."""
        used = self._jac_symbols
        if used is None:
            used = set()
            for e in itertools.chain.from_iterable(entry[1:] for entry in self.ir.jac_symbolic):
                # numbers have none (the entries only a block fills are not among these)
                if e is not _ZERO and not getattr(e, "is_Number", True):
                    used |= e.free_symbols
            self._jac_symbols = used
        return [j for j, s in enumerate(symbols) if s in used]

    def _statements(self, exprs, targets, symbols, printed: list, top: bool) -> list[str]:
        """Common subexpressions, then one assignment per target. A Piecewise (``ifelse``, a
        switch) becomes an ``if``/``elif``/``else`` block assigning a local of its own, each
        branch with its own common subexpressions: a branch its condition discards is never
        evaluated. (Common subexpressions across all rows would hoist a ``1/x`` or ``sqrt(x)``
        out of ``ifelse(x > 0, ...)``: a division by zero or a domain error where the model
        is well defined.) `printed` collects every expression printed."""
        pieces: dict = {}

        def outermost(e):
            if isinstance(e, sp.Piecewise):
                if e not in pieces:
                    pieces[e] = next(symbols)
                return
            for a in e.args:
                if isinstance(a, sp.Basic) and a.has(sp.Piecewise):
                    outermost(a)

        for e in exprs:
            if isinstance(e, sp.Basic) and e.has(sp.Piecewise):
                outermost(e)
        groups: dict = {}  # Piecewises with the same conditions: one block, shared subexpressions
        for pw, sym in pieces.items():
            self.names[sym] = sym.name
            groups.setdefault(tuple(c for _, c in pw.args), []).append((pw, sym))
        lines = []
        for conditions, group in groups.items():
            for k, c in enumerate(conditions):
                branch = self._statements([pw.args[k].expr for pw, _ in group], [sym.name for _, sym in group],
                                          symbols, printed, False)
                if c == sp.true and k == 0:
                    lines += branch
                    break
                if c == sp.true:
                    lines.append("else:")
                else:
                    printed.append(c)
                    lines.append(f"{'elif' if k else 'if'} {self.printer.doprint(c)}:")
                lines += ["    " + line for line in branch]
                if c == sp.true:
                    break
            else:
                lines += ["else:"] + [f"    {sym.name} = math.nan" for _, sym in group]
        exprs = [e.xreplace(pieces) if isinstance(e, sp.Basic) and pieces else e for e in exprs]
        replacements, reduced = _cse(list(exprs), symbols)
        self.ir.common_subexpressions[tuple(exprs)] = (replacements, reduced)  # for the compiled back end
        for sym, rhs in replacements:
            self.names[sym] = sym.name  # _c0, _c1, ...: generated here
            rhs = self._short_sums(rhs, symbols, printed, lines)
            printed.append(rhs)
            lines.append(f"{sym} = {self.printer.doprint(rhs)}")
        for target, e in zip(targets, reduced):
            e = self._short_sums(e, symbols, printed, lines)
            printed.append(e)
            op = "+=" if top and target in self.accumulate else "="
            lines.append(f"{target} {op} {self.printer.doprint(e)}")
        return lines

    def _short_sums(self, e, symbols, printed: list, lines: list):
        """`e` with every sum of more than :data:`LONG_SUM` terms replaced by a local that
        statements appended to `lines` compute, :data:`LONG_SUM` terms at a time, in the
        printed order of the terms (innermost sums first)."""
        if not isinstance(e, sp.Basic) or e.is_Atom:
            return e
        if not any(isinstance(a, sp.Add) and len(a.args) > LONG_SUM for a in sp.preorder_traversal(e)):
            return e
        args = [self._short_sums(a, symbols, printed, lines) for a in e.args]
        if not (isinstance(e, sp.Add) and len(args) > LONG_SUM):
            return e.func(*args)
        terms = ordered_terms(sp.Add(*args))  # the order the printer writes a sum in
        sym = next(symbols)
        self.names[sym] = sym.name
        for k in range(0, len(terms), LONG_SUM):
            chunk = sp.Add(*terms[k:k + LONG_SUM])
            printed.append(chunk)
            text = self.printer.doprint(chunk)
            lines.append(f"{sym} = {text}" if k == 0 else f"{sym} = {sym} + {text}")
        return sym

    def _vectorized(self, exprs: list, targets: list) -> tuple[list, list, list]:
        """(`exprs`, `targets`) without the ones that an expression recurring at
        :data:`~phc.codegen.repeat.REPEAT_MIN` entries or more writes (or adds: the terms of a
        long sum), and the vectorized statements that write those: the expression once, on the
        index arrays of its entries (:func:`phc.codegen.repeat.repeated`). Only a rational
        expression (sums, products, integer powers, ``abs``) is vectorized: NumPy's elementwise
        arithmetic then rounds as Python's does, and a division by zero or an overflow raises
        as Python's does where the function reads floats (the statements run under
        ``np.errstate``, see :meth:`_body`). Only entries of ``out``, or a scalar that a long sum
        is written into, are vectorized targets."""
        if len(exprs) < REPEAT_MIN and not any(isinstance(e, sp.Add) and len(e.args) >= REPEAT_MIN for e in exprs):
            return exprs, targets, []
        if not all(isinstance(e, sp.Basic) for e in exprs):
            return exprs, targets, []
        index = [_OUT_ENTRY.fullmatch(t) for t in targets]

        def accept(template, positions) -> bool:
            if not all(_vectorizable(node) for node in sp.preorder_traversal(template)):
                return False
            if all(index[k] is not None for k in positions):
                return True
            return all(k == positions[0] for k in positions)  # the terms of one long sum

        items = tuple((k, e, targets[k] in self.accumulate) for k, e in enumerate(exprs))
        left, loops = repeated(self.ir, items, accept=accept)
        if not loops:
            return exprs, targets, []
        lines = []
        for r in loops:
            n = len(self.vector_constants)
            self.vector_constants.append("")  # (its index arrays: filled below)
            constants = []
            names = dict(self.names)
            varying = False
            for j, (vector, at) in enumerate(r.slots):
                if (at == at[0]).all():
                    names[slot(j)] = f"{vector}[{int(at[0])}]"
                else:
                    names[slot(j)] = f"{vector}[{self._entries(f'_V{n}_{j}', at, constants)}]"
                    varying = True
            replacements, (value,) = _cse([r.template], sp.numbered_symbols(f"_v{n}w"))
            body = []
            printer = _Printer(names)
            for symbol, rhs in replacements:
                names[symbol] = symbol.name
                body.append(f"{symbol.name} = {printer.doprint(rhs)}")
            text = printer.doprint(value)
            positions = r.index.tolist()
            first = targets[positions[0]]
            if index[positions[0]] is None or (r.index == r.index[0]).all():  # the terms of one sum
                total = f"np.sum({text})" if varying else f"{r.count} * ({text})"
                body.append(f"{first} = {first} + {total}")
                what = f"{r.count} terms of {first}: one expression"
            else:
                out = np.array([int(index[k].group(1)) for k in positions], dtype=np.int64)
                if r.accumulate and len(np.unique(out)) < len(out):
                    body.append(f"np.add.at(out, {self._entries(f'_V{n}_out', out, constants, slices=False)}, {text})")
                else:
                    op = "+=" if r.accumulate else "="
                    body.append(f"out[{self._entries(f'_V{n}_out', out, constants)}] {op} {text}")
                what = f"{first} ... {targets[positions[-1]]}: one expression at {r.count} entries"
            self.vector_constants[n] = "\n".join(constants)
            lines += [f"# {what}, on the arrays of the entries it reads"] + body
        kept = [(e, targets[i]) for i, e, _ in left]
        return [e for e, _ in kept], [t for _, t in kept], lines

    def _entries(self, name: str, at: np.ndarray, constants: list, slices: bool = True) -> str:
        """A subscript for the entries `at`: a slice where they are an increasing progression
        (a view, no copy), else the module constant `name` (appended to `constants`)."""
        found = progression(at) if slices else None
        if found is not None and found[1] > 0:
            start, step = found
            stop = int(at[-1]) + 1
            return f"{start}:{stop}" if step == 1 else f"{start}:{stop}:{step}"
        constants.append(f"{name} = {_array(at, 'np.int64')}")
        return name

    def _body(self, exprs: Sequence[sp.Expr], targets: Sequence[str]) -> list[str]:
        """Unpack used symbols, common subexpressions, then one assignment per target; then the
        vectorized statements of expressions that recur at many entries (:meth:`_vectorized`),
        which raise on a division by zero, an overflow or an invalid operation where the
        function reads its arguments as Python floats (the call is then evaluated again on
        NumPy scalars, see :meth:`_function`), as the scalar statements do."""
        printed: list = []
        exprs, targets, vector = self._vectorized(list(exprs), list(targets))
        statements = self._statements(exprs, targets, sp.numbered_symbols("_c"), printed, True)
        used = set()
        for e in printed:
            if isinstance(e, sp.Basic):
                used |= e.free_symbols
        lines = []
        bulk = self.bulk and not any(_complex_prone(e) for e in printed if isinstance(e, sp.Basic))
        for name, table in (("y", self.unpack_y), ("yp", self.unpack_yp), ("p", self.unpack_p)):
            taken = self._unpack_lines(name, table, used)
            if bulk and taken and BULK_SHARE * len(taken) >= (len(table) if name != "yp" else len(self.ir.variables)):
                # the values as Python floats: arithmetic on them costs a third of NumPy scalars'
                lines.append(f"_{name} = _read({name})")
                taken = [line.replace(f" = {name}[", f" = _{name}[", 1) for line in taken]
            lines += taken
        if vector and any(" = _read(" in line for line in lines):
            statements += ["with np.errstate(**(_RAISE if _read is _floats else {})):"] + ["    " + v for v in vector]
        else:
            statements += vector
        return lines + statements

    def _unpack_lines(self, name: str, table: dict, used: set) -> list[str]:
        """The unpacking lines ``ident = name[j]`` of the symbols of `table` (symbol -> position
        j, in the order of the positions) that are in `used`, in the table's order. Walks `used`
        when it is the smaller (a mesh's functions use a few of its many thousand variables: no
        pass over every variable for each function)."""
        if len(used) >= len(table):
            slots = [(j, s) for s, j in table.items() if s in used]
        else:
            slots = sorted(((table[s], s) for s in used if s in table), key=lambda js: js[0])
        return [f"{self.names[s]} = {name}[{j}]" for j, s in slots]

    def _function(self, signature: str, doc: str, exprs, targets, prologue=(), epilogue=()) -> str:
        body = list(prologue) + self._body(exprs, targets) + list(epilogue)
        if not any(line.startswith("_") and " = _read(" in line for line in body):
            lines = [f"def {signature}:", f'    """{doc}"""']
            lines += ["    " + line for line in body] or ["    pass"]
            return "\n".join(lines) + "\n"
        # The arguments read as Python floats (a third of the cost of NumPy scalars), which
        # raise where IEEE arithmetic gives inf or nan (1/0, an overflowing power); such a call
        # is evaluated again on NumPy scalars, so every value is what NumPy gives.
        name, args = signature.split("(", 1)
        args = args.rstrip(")")
        inner = [f"def _{name}({args}, _read):",
                 f'    """`{name}` on the arguments read by `_read`: as Python floats, or NumPy scalars (`list`)."""']
        inner += ["    " + line for line in body]
        outer = [f"def {signature}:", f'    """{doc}"""', "    try:", f"        return _{name}({args}, _floats)",
                 "    except ArithmeticError:  # as NumPy computes it (inf, nan), for the checks to judge",
                 f"        return _{name}({args}, list)"]
        return "\n".join(inner) + "\n\n\n" + "\n".join(outer) + "\n"

    def print(self) -> str:
        ir = self.ir
        n = len(ir.variables)
        parts = [
            # Nothing from the model file is spliced into source text: the model's name and
            # its files are data (MODEL, SOURCES below, printed with repr).
            f'"""Residual module for the port-Hamiltonian model named in MODEL.\n\n'
            f"Generated by phc {__version__} from the model files in SOURCES.\n"
            "Do not edit: regenerate with `phc compile`.\n\n"
            "The DAE is F(t, y, yp, p) = 0 with the variables in VARIABLES (DIFFERENTIAL marks\n"
            "the energy states), parameters p = full_parameters(base) with base values in the\n"
            "order of PARAMETERS[i] for i in BASE_PARAMETERS. The Jacobian dF/dy + cj*dF/dyp is\n"
            "returned as data in compressed-sparse-column order of (JAC_ROWS, JAC_COLS).\n"
            '"""\n',
            "import base64\nimport math\n\nimport numpy as np\n\n\n"
            + packing.decoder_source() + "\n\n"
            "_floats = np.ndarray.tolist  # an array's entries as Python floats\n"
            "# vectorized statements raise where Python floats would (division by zero, overflow)\n"
            "_RAISE = {'divide': 'raise', 'over': 'raise', 'invalid': 'raise'}\n\n\n"
            "def _indexed(_stem, _start, _stop, _tail=''):\n"
            "    \"\"\"The names `_stem[i]_tail` for i from _start to _stop - 1 (a mesh's entries).\"\"\"\n"
            "    return tuple(f'{_stem}[{_i}]{_tail}' for _i in range(_start, _stop))\n",
            f"MODEL = {str(ir.name)!r}",
            f"SOURCES = {_tuple([os.path.basename(s) for s in ir.sources])}",
            f"N = {n}",
            f"VARIABLES = {_tuple(ir.variables)}",
            f"DIFFERENTIAL = {_array(ir.differential, 'bool')}",
            f"ROLES = {_tuple(ir.roles)}",
            f"EQUATIONS = {_tuple(ir.equation_labels)}",
            f"PARAMETERS = {_tuple(ir.parameters)}",
            f"BASE_PARAMETERS = {tuple(ir.base_parameters)!r}",
            f"PARAMETER_DEFAULTS = {_array(ir.parameter_defaults, 'float')}",
            "# Parameters fixed at compile time (mesh length, ξ-dependent coefficients): recompile to change.",
            f"COMPILE_TIME_PARAMETERS = {_tuple(ir.compile_time_parameters)}",
            f"INVARIANTS = {_tuple(ir.invariant_labels)}",
            f"VELOCITY_INVARIANTS = {_tuple(ir.velocity_invariant_labels)}",
            "# Linear relations C y = 0 that hold at the initial time only (INITIAL[i] is row i).",
            f"INITIAL = {_tuple(ir.initial_labels)}",
            f"INITIAL_ROWS = {_array(ir.initial_rows, 'np.int64')}",
            f"INITIAL_COLS = {_array(ir.initial_cols, 'np.int64')}",
            f"INITIAL_DATA = {_array(ir.initial_data, 'float')}",
            *([f"INITIAL_RHS = {_array(ir.initial_rhs, 'float')}  # C y = INITIAL_RHS (an initial field)"]
              if any(ir.initial_rhs) else []),
            f"OUTPUTS = {_tuple([name for name, _ in ir.outputs])}",
            f"JAC_ROWS = {_array(ir.jac_rows, 'np.int64')}",
            f"JAC_COLS = {_array(ir.jac_cols, 'np.int64')}",
            f"JAC_DEPENDS_ON_Y = {_array(self._jac_dependencies(ir.y_symbols), 'np.int64')}",
            f"JAC_DEPENDS_ON_YP = {_array(self._jac_dependencies(ir.yp_symbols), 'np.int64')}",
            "# Times where an input is not smooth (ends of pieces, table rows): integrate up to each.",
            f"BREAKPOINTS = {tuple(float(x) for x in ir.breakpoints)!r}",
            *self._switch_constants(),
            "",
        ]
        if ir.input_tables:
            parts += ["# Input tables (CSV) and their interpolation.", *table_arrays(ir.input_tables), "",
                      _TABLE_HELPERS]
        sparse_consts = []
        self.fused = {}
        for wrt, derivative in (("Y", False), ("YP", True)):
            terms = [t for t in ir.linear_terms if t.derivative == derivative]
            if not terms:
                continue
            fused = _fuse(terms, len(ir.residual), n)
            self.fused[wrt] = (terms, fused)
            sparse_consts += [f"_L{wrt}_INDPTR = {_indices(fused['indptr'])}",
                              f"_L{wrt}_INDICES = {_indices(fused['indices'])}",
                              f"_L{wrt}_JAC = {_indices(fused['jac'])}"]
            for k, (pos, data) in enumerate(zip(fused["pos"], fused["data"])):
                sparse_consts += [f"_L{wrt}{k}_POS = {_indices(pos)}",
                                  f"_L{wrt}{k}_DATA = {_array(data, 'float')}"]
        for prefix, forms in (("QE", ir.quadratic_energy), ("QD", ir.quadratic_dissipation)):
            for k, f in enumerate(forms):
                sparse_consts += _sparse_constant(f"_{prefix}{k}", f.matrix)
                sparse_consts.append(f"_{prefix}{k}_COLS = {_indices(f.cols)}")
                if f.pos is not None:
                    sparse_consts.append(f"_{prefix}{k}_POS = {_indices(f.pos)}")
        if sparse_consts:
            parts[1] = parts[1].replace("import numpy as np\n", "import numpy as np\nimport scipy.sparse as _sps\n"
                                        "from scipy.linalg.blas import daxpy as _daxpy\n", 1)
            parts.append(_MATVEC_HELPERS)
            parts += ["# Sparse linear parts (discretized PDEs, matrix-defined components).",
                      *sparse_consts, ""]
        # Derived parameters are computed once per run, not in every residual call.
        derived_lines = ["p = np.array(PARAMETER_DEFAULTS, dtype=float)",
                         "p[list(BASE_PARAMETERS)] = base"]
        for i, expr in ir.derived:
            used = expr.free_symbols
            derived_lines += self._unpack_lines("p", self.unpack_p, used)
            derived_lines.append(f"p[{i}] = {self.printer.doprint(expr)}")
        derived_lines.append("return p")
        constants_at = len(parts)  # the vectorized statements' index arrays go here (below)
        parts.append("def full_parameters(base=None):\n"
                     '    """Full parameter vector (derived parameters appended) from base values."""\n'
                     "    if base is None:\n"
                     "        base = PARAMETER_DEFAULTS[list(BASE_PARAMETERS)]\n"
                     + "".join(f"    {line}\n" for line in derived_lines))
        lin = ir.linear_terms
        if lin:
            parts.append(self._linear_function(len(ir.residual), n))
        qd_coeffs = [f.coeff for f in ir.quadratic_dissipation]
        qd_targets = [f"_qQD{k}" for k in range(len(qd_coeffs))]
        qd_res = [f"out[{ir.energy_row}] -= _qQD{k} * (y[_QD{k}_COLS] @ (_QD{k} @ y[_QD{k}_COLS]))"
                  for k in range(len(qd_coeffs))]
        qd_jac = [f"out[_QD{k}_POS] -= 2.0 * _qQD{k} * (_QD{k} @ y[_QD{k}_COLS])" for k in range(len(qd_coeffs))]
        self.bulk = self.bulk_unpack
        if lin or qd_coeffs:
            rows = [(i, e) for i, e in enumerate(ir.residual) if _nonzero(e)]
            lin_lines = (["_AY, _AYP, _JY, _JYP = _linear(p)",
                          "if _AY is not None:", "    _matvec_add(_AY, y, out)",
                          "if _AYP is not None:", "    _matvec_add(_AYP, yp, out)"] if lin else [])
            parts.append(self._function(
                "residual(t, y, yp, p, out)", "Residual F(t, y, yp, p) written into `out`.",
                [e for _, e in rows] + qd_coeffs, [f"out[{i}]" for i, _ in rows] + qd_targets,
                prologue=["out[:] = 0.0"], epilogue=lin_lines + qd_res))
        else:
            parts.append(self._function(
                "residual(t, y, yp, p, out)", "Residual F(t, y, yp, p) written into `out`.",
                ir.residual, [f"out[{i}]" for i in range(len(ir.residual))]))
        dt_rows = [(i, drop_deltas(sp.diff(e, T))) for i, e in enumerate(ir.residual)
               if _nonzero(e) and e.has(T)]  # most rows of a mesh are 0 (linear blocks): no diff
        dt_rows = [(i, e) for i, e in dt_rows if _nonzero(e)]
        parts.append(self._function(
            "residual_t(t, y, yp, p, out)", "Explicit time derivative dF/dt (consistent initialization).",
            [e for _, e in dt_rows], [f"out[{i}]" for i, _ in dt_rows], prologue=["out[:] = 0.0"]))
        # dF/dy + cj·dF/dẏ at the entries with a symbolic part (the others are 0 but for the blocks)
        jac_symbolic = [(k, dy + sp.Symbol("cj") * dyp if _nonzero(dyp) else dy) for k, dy, dyp in ir.jac_symbolic]
        self.names[sp.Symbol("cj")] = "cj"
        jdoc = "Data of dF/dy + cj*dF/dyp in CSC order of (JAC_ROWS, JAC_COLS), written into `out`."
        if lin or qd_coeffs:
            nz = [(k, e) for k, e in jac_symbolic if _nonzero(e)]
            prologue = (["_AY, _AYP, _JY, _JYP = _linear(p)", "out[:] = _JY", "_axpy(cj, _JYP, out)"] if lin
                        else ["out[:] = 0.0"])
            self.accumulate = {f"out[{k}]" for k, _ in nz}
            parts.append(self._function(
                "jacobian(t, y, yp, p, cj, out)", jdoc, [e for _, e in nz] + qd_coeffs,
                [f"out[{k}]" for k, _ in nz] + qd_targets, prologue=prologue, epilogue=qd_jac))
            self.accumulate = set()
        else:
            jac = [_ZERO] * len(ir.jac_rows)
            for k, e in jac_symbolic:
                jac[k] = e
            parts.append(self._function("jacobian(t, y, yp, p, cj, out)", jdoc, jac,
                                        [f"out[{k}]" for k in range(len(jac))]))
        self.bulk = False

        def quadratic(forms, prefix, target, absolute=False):
            lines = []
            for k, _ in enumerate(forms):
                value = f"_q{prefix}{k} * (y[_{prefix}{k}_COLS] @ (_{prefix}{k} @ y[_{prefix}{k}_COLS]))"
                lines.append(f"{target} += {'abs(' + value + ')' if absolute else value}")
            return [f.coeff for f in forms], [f"_q{prefix}{k}" for k in range(len(forms))], lines

        qe, qe_t, qe_lines = quadratic(ir.quadratic_energy, "QE", "H")
        parts.append(self._function("hamiltonian(t, y, p)", "Total stored energy H.",
                                    [ir.hamiltonian] + qe, ["H"] + qe_t, epilogue=qe_lines + ["return H"]))
        qe, qe_t, qe_lines = quadratic(ir.quadratic_energy, "QE", "S", absolute=True)
        parts.append(self._function(
            "energy_scale(t, y, p)",
            "Sum of |terms| of H: the scale for relative energy errors (H itself may be ~0).",
            [energy_scale_expression(ir)] + qe, ["S"] + qe_t,
            epilogue=qe_lines + ["return S"]))
        qd, qd_t, qd_lines = quadratic(ir.quadratic_dissipation, "QD", "P_diss")
        parts.append(self._function(
            "powers(t, y, yp, p)",
            "(power delivered through the external ports, power dissipated): the terms of the energy balance dH/dt = -P_ports - P_diss.",
            [ir.port_power, ir.dissipation] + qd, ["P_ports", "P_diss"] + qd_t,
            epilogue=qd_lines + ["return P_ports, P_diss"]))
        for fname, exprs, doc in (
            ("invariants", ir.invariants, "Position-level invariants g(t, y) (zero on exact solutions)."),
            ("velocity_invariants", ir.velocity_invariants, "Velocity-level constraints (zero on exact solutions)."),
        ):
            parts.append(self._function(
                f"{fname}(t, y, p)", doc, exprs, [f"out[{i}]" for i in range(len(exprs))],
                prologue=[f"out = np.empty({len(exprs)})"], epilogue=["return out"]))
        n_sw = len(ir.switches)
        parts.append(self._function(
            "events(t, y, yp, p, out)",
            "Switching functions: out[k] = g_k (SWITCHES[k] switches where g_k changes sign), then for each "
            "set-valued sign STICKS[j] out[len(SWITCHES) + j] = the value s_j it takes while sticking.",
            list(ir.events),
            [f"out[{k}]" for k in range(n_sw + len(ir.sticks))]))
        prologue = [f"out = np.empty({len(ir.outputs)})"]
        if any(e.has(STORED_ENERGY) for _, e in ir.outputs):
            # an output that uses H: the value of `hamiltonian` (sparse forms), once, not H written out
            self.names[STORED_ENERGY] = "_H"
            prologue.append("_H = hamiltonian(t, y, p)")
        parts.append(self._function(
            "outputs(t, y, yp, p)", "Requested outputs, in the order of OUTPUTS.",
            [e for _, e in ir.outputs], [f"out[{i}]" for i in range(len(ir.outputs))],
            prologue=prologue, epilogue=["return out"]))
        constants = [c for c in self.vector_constants if c]
        if constants:
            parts.insert(constants_at, "# The entries of expressions that recur at many entries (one vectorized statement each).\n"
                         + "\n".join(constants) + "\n")
        return "\n\n".join(parts)


def print_module(ir: ResidualIR) -> str:
    """Return the Python source of the residual module for `ir`."""
    return ModulePrinter(ir).print()
