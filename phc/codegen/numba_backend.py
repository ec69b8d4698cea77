"""The compiled backend: the generated functions as machine code (numba), optional.

Input: a :class:`~phc.codegen.lower.ResidualIR` and the NumPy module printed from it (the
reference backend: :mod:`phc.codegen.printer`, loaded by :mod:`phc.codegen.load`). Output:
a module with the reference module's constants and ``full_parameters``, and ``residual``,
``residual_t``, ``jacobian``, ``hamiltonian``, ``energy_scale``, ``powers``,
``invariants``, ``velocity_invariants`` and ``outputs`` as numba-compiled functions of
the same signatures (``REFERENCE`` is the NumPy module, ``BACKEND`` is ``"numba"``).

How the functions are built
---------------------------
:class:`KernelPrinter` (a subclass of the reference printer: the same names and literals)
prints each function as numba-compilable Python, differing from the reference where
NumPy idioms do not compile: the sparse linear blocks and quadratic forms become loops
over constant CSR arrays (coefficients evaluated in the call), input tables carry an
``int`` kind, array sizes are checked on entry (the compiled code does not check bounds).

The scalar expressions — the bulk of a model — do not go through numba's Python-level
compiler, whose time grows steeply with the number of statements (seconds for a Jacobian
of a few hundred entries). They become one numba *intrinsic* per function, whose LLVM IR
:class:`_Emitter` writes straight from the sympy expressions, after the same
common-subexpression elimination and in the evaluation order of the printed Python (terms
and factors as the printer orders them, ``a*b/(c*d)`` as printed, the same ``math``
functions): the compiled values agree with the reference module to the last bit in
most entries and to round-off in all. An expression the emitter does not know (a
function it has no rule for) leaves that function to numba's own compiler, as text.

Caching
-------
Compiled functions are cached in ``<phc cache>/numba/`` (the private directory of
:mod:`phc.codegen.load`: created 0700, refused when another user owns it or others may
write it), under names derived from the SHA-256 of everything that determines the code
(the kernel text, the reference module's text, the phc, numba and Python versions); numba
adds the CPU to its key. Numba's own ``cache=True`` is not used: it writes next to the
source file and unpickles whatever its index points to. Here every artefact is written
with an HMAC-SHA256 tag under a per-user secret key kept *outside* the cache directory
(``$PHC_STATE_DIR``, else ``$XDG_STATE_HOME/phc``, else ``~/.local/state/phc``; file
``cache-key``, mode 0600), and an artefact whose tag does not verify is never unpickled —
it is compiled again and overwritten. A cache directory restored from elsewhere (the CI
cache of another build) therefore costs a compilation, never the execution of someone
else's machine code. Set ``PHC_COMPILED_CACHE=0`` to compile in memory every time.

What a run needs once the functions are built (whether numba is usable, the signed cache,
the module assembled over the reference) is in :mod:`phc.codegen.numba_cache`, which
imports neither sympy nor the model language: the cached front end of ``phc simulate``
loads a model's compiled functions from the cache through it, from the kernel text this
module keeps as the compiled module's ``KERNEL``.
"""

from __future__ import annotations

import math
import os
import sys
import time
from dataclasses import dataclass
from pathlib import Path
from types import ModuleType
from typing import Optional

import numpy as np
import sympy as sp

from phc.codegen import numba_cache
from phc.codegen.lower import ResidualIR
# the public names of the compiled backend's light half, re-exported: callers and tests import them from here
from phc.codegen.numba_cache import (EMITTER_VERSION, FUNCTIONS, NUMBA_MIN,  # noqa: F401 — the API
                                     BackendMismatch, BackendUnavailable, CompiledBackendWarning, CompileReport,
                                     _cache_classes, _cross_check, _private_dir, _remember, assemble, available,
                                     cache_key, compile_functions, compiled_cache_dir, kernel_digest, kernel_module,
                                     why_unavailable)
from phc.codegen.printer import ModulePrinter, _array
from phc.dae import T
from phc.inputs import InputTable, InputTableSlope

_KIND = {"linear": 0, "previous": 1}


# ---------------------------------------------------------------------------------------
# the kernel text

_HELPERS = '''
def _csr_add(indptr, indices, data, rows, cols, v, c, out):
    """out[rows] += c * (A @ v[cols]) for a constant CSR matrix A."""
    for i in range(indptr.shape[0] - 1):
        acc = 0.0
        for k in range(indptr[i], indptr[i + 1]):
            acc += data[k] * v[cols[indices[k]]]
        out[rows[i]] += c * acc


def _scatter_add(pos, data, c, out):
    """out[pos] += c * data (the Jacobian entries of a linear term)."""
    for k in range(pos.shape[0]):
        out[pos[k]] += c * data[k]


def _csr_quad(indptr, indices, data, cols, y):
    """x @ A @ x with x = y[cols]."""
    total = 0.0
    for i in range(indptr.shape[0] - 1):
        acc = 0.0
        for k in range(indptr[i], indptr[i + 1]):
            acc += data[k] * y[cols[indices[k]]]
        total += y[cols[i]] * acc
    return total


def _csr_grad_add(indptr, indices, data, cols, y, c, pos, out):
    """out[pos] += c * (A @ x) with x = y[cols]."""
    for i in range(indptr.shape[0] - 1):
        acc = 0.0
        for k in range(indptr[i], indptr[i + 1]):
            acc += data[k] * y[cols[indices[k]]]
        out[pos[i]] += c * acc


def _table(times, values, kind, t):
    """Value of an input table at t: linear (kind 0) or zero-order hold (1); end values hold outside."""
    if kind == 1:
        return float(values[max(int(np.searchsorted(times, t, side="right")) - 1, 0)])
    return float(np.interp(t, times, values))


def _table_slope(times, values, kind, t):
    """d/dt of the table's interpolant (0 for a zero-order hold and outside the table)."""
    if kind == 1 or t < times[0] or t >= times[-1]:
        return 0.0
    i = int(np.searchsorted(times, t, side="right")) - 1
    return float((values[i + 1] - values[i]) / (times[i + 1] - times[i]))
'''


_SIMPLE = {sp.sin: "sin", sp.cos: "cos", sp.tan: "tan", sp.asin: "asin", sp.acos: "acos", sp.atan: "atan",
           sp.sinh: "sinh", sp.cosh: "cosh", sp.tanh: "tanh", sp.asinh: "asinh", sp.acosh: "acosh",
           sp.atanh: "atanh", sp.exp: "exp"}
"""Functions of one argument the emitter calls as numba's ``math`` implementations."""

_RELATIONS = {sp.StrictLessThan: "<", sp.LessThan: "<=", sp.StrictGreaterThan: ">", sp.GreaterThan: ">=",
              sp.Equality: "==", sp.Unequality: "!="}


_NODES = (sp.Add, sp.Mul, sp.Pow, sp.Abs, sp.sign, sp.Min, sp.Max, sp.Heaviside, sp.atan2, sp.Piecewise, sp.And, sp.Or,
          sp.Not, sp.ITE, sp.Xor)
"""Nodes the emitter has a rule for (besides symbols, numbers, _SIMPLE, _RELATIONS, tables, switches)."""


def _is_switch(e) -> bool:
    """``Switch(mode, g)`` of :mod:`phc.codegen.nonsmooth` (matched by name: printed as
    ``((g) if mode == 0.0 else mode)``)."""
    return type(e).__name__ == "Switch" and isinstance(e, sp.Function) and len(e.args) == 2


def emittable(expr: sp.Basic, known: set) -> bool:
    """Whether :class:`_Emitter` can write `expr` (every node has a rule, every symbol a slot)."""
    stack = [expr]
    seen = set()
    while stack:
        e = stack.pop()
        if e in seen:
            continue
        seen.add(e)
        if e.is_Symbol:
            if e not in known:
                return False
            continue
        if e.is_Number or e in (sp.pi, sp.E, sp.true, sp.false) or isinstance(e, sp.core.numbers.NaN):
            continue
        if isinstance(e, (InputTable, InputTableSlope)):
            if not e.args[0].is_Integer:
                return False
            stack.append(e.args[1])
            continue
        if isinstance(e, _NODES) or type(e) in _SIMPLE or type(e) in _RELATIONS or _is_switch(e):
            stack.extend(e.args)
            continue
        if isinstance(e, sp.log) and len(e.args) == 1:
            stack.extend(e.args)
            continue
        if isinstance(e, sp.functions.elementary.piecewise.ExprCondPair):
            stack.extend(e.args)
            continue
        return False
    return True


@dataclass(frozen=True)
class Kernel:
    """What the intrinsic ``_X_<name>(t, y, yp, p, cj, out)`` computes: `targets` are
    ``(index, expression, accumulate)`` written (or added) into ``out``, then `sums` are
    added: ``("matvec", A, rows, cols, "y"|"yp", coeff)`` adds ``coeff·A v[cols]`` to
    ``out[rows]``; ``("scatter", pos, data, coeff, times_cj)`` adds ``coeff·data`` (times
    cj) to ``out[pos]``; ``("quad", A, cols, coeff, index, absolute)`` adds ``coeff·xᵀAx``
    (its absolute value) to ``out[index]``; ``("grad", A, cols, pos, coeff)`` adds
    ``coeff·A x`` to ``out[pos]`` (x = y[cols], A a CSR matrix)."""

    targets: tuple
    sums: tuple = ()

    def expressions(self) -> list:
        """The target expressions, then the coefficient of each sum."""
        return [e for _, e, _ in self.targets] + [_coefficient(op) for op in self.sums]


_COEFFICIENT = {"matvec": 5, "scatter": 3, "quad": 3, "grad": 4}


def _coefficient(op):
    """The coefficient expression of a :class:`Kernel` sum."""
    return op[_COEFFICIENT[op[0]]]


class KernelPrinter(ModulePrinter):
    """The generated functions as numba-compilable Python (see the module docstring).

    After :meth:`print`, ``kernels[name]`` is the :class:`Kernel` of the intrinsic
    ``_X_<name>`` the text calls (absent when an expression of the function has no
    emitter rule: then the function is printed as Python for numba's own compiler)."""

    bulk_unpack = False  # numba compiles ``y[j]``, not ``y.tolist()``

    def __init__(self, ir: ResidualIR):
        super().__init__(ir)
        self.kernels: dict[str, Kernel] = {}
        self.trivial: set[str] = set()
        """Functions with nothing to compute (the reference module's are used)."""
        self.known = set(ir.y_symbols) | set(ir.yp_symbols) | set(ir.p_symbols) | {T, sp.Symbol("cj")}
        self.n_parameters = len(ir.p_symbols)
        self._text_constants: list[str] = []

    # -- pieces ---------------------------------------------------------------------------
    def _csr_constants(self, name: str, matrix, **extra) -> None:
        """Module constants of a CSR matrix (for the Python text of a function that is not emitted)."""
        if any(line.startswith(f"{name}_INDPTR ") for line in self._text_constants):
            return
        m = _canonical(matrix)
        self._text_constants += [f"{name}_INDPTR = {_array(m.indptr.tolist(), 'np.int64')}",
                                 f"{name}_INDICES = {_array(m.indices.tolist(), 'np.int64')}",
                                 f"{name}_DATA = {_array(m.data.tolist(), 'float')}"]
        for key, values in extra.items():
            self._text_constants.append(f"{name}_{key} = {_array(list(values), 'np.int64')}")

    @staticmethod
    def _csr_args(name: str) -> str:
        return f"{name}_INDPTR, {name}_INDICES, {name}_DATA"

    def _size_check(self, name: str, arrays: list[tuple[str, str]]) -> list[str]:
        cond = " or ".join(f"{a}.shape[0] < {n}" for a, n in arrays)
        return [f"if {cond}:", f"    raise ValueError(\"{name}: an array is shorter than the model needs\")"]

    def _sum_text(self, op, out: str, c: str) -> list[str]:
        """Python text of a Kernel sum whose coefficient is the local `c` (for a function
        that is not emitted)."""
        kind = op[0]
        ident = f"_S{len(self._text_constants)}"
        if kind == "matvec":
            _, A, rows, cols, vec, _ = op
            self._csr_constants(ident, A, ROWS=rows.tolist(), COLS=cols.tolist())
            return [f"_csr_add({self._csr_args(ident)}, {ident}_ROWS, {ident}_COLS, {vec}, float({c}), {out})"]
        if kind == "scatter":
            _, pos, data, _, times_cj = op
            self._text_constants += [f"{ident}_POS = {_array(list(pos), 'np.int64')}",
                                     f"{ident}_DATA = {_array(list(data), 'float')}"]
            return [f"_scatter_add({ident}_POS, {ident}_DATA, {'cj * ' if times_cj else ''}float({c}), {out})"]
        if kind == "quad":
            _, A, cols, _, index, absolute = op
            self._csr_constants(ident, A, COLS=cols.tolist())
            value = f"{c} * _csr_quad({self._csr_args(ident)}, {ident}_COLS, y)"
            return [f"{out}[{index}] += {'abs(' + value + ')' if absolute else value}"]
        _, A, cols, pos, _ = op
        self._csr_constants(ident, A, COLS=cols.tolist(), POS=pos.tolist())
        return [f"_csr_grad_add({self._csr_args(ident)}, {ident}_COLS, y, float({c}), {ident}_POS, {out})"]

    def _function(self, name: str, signature: str, arrays, kernel: Kernel, out: str, *, zero=False, scratch=None,
                  tail=()) -> str:
        """A function computing `kernel` into `out` (zeroed first when `zero`; a new array of
        `scratch` entries when given), then `tail`."""
        targets = tuple((i, e, acc) for i, e, acc in kernel.targets if not (e == 0 and acc))
        kernel = Kernel(targets, kernel.sums)
        if not targets and not kernel.sums:
            self.trivial.add(name)
        lines = self._size_check(name, arrays)
        if scratch is not None:
            lines.append(f"{out} = np.{'zeros' if zero else 'empty'}({scratch})")
        elif zero:
            lines.append(f"{out}[:] = 0.0")
        if all(emittable(e, self.known) for e in kernel.expressions()):
            if targets or kernel.sums:
                self.kernels[name] = kernel
                yp = "yp" if "yp" in signature else "y"
                cj = "cj" if "cj" in signature else "0.0"
                lines.append(f"_X_{name}(t, y, {yp}, p, {cj}, {out})")
        else:
            saved = self.accumulate
            self.accumulate = set(saved) | {f"{out}[{i}]" for i, _, acc in targets if acc}
            coefficients = [f"_k{j}" for j in range(len(kernel.sums))]
            lines += ModulePrinter._body(self, [e for _, e, _ in targets] + [_coefficient(op) for op in kernel.sums],
                                         [f"{out}[{i}]" for i, _, _ in targets] + coefficients)
            self.accumulate = saved
            for op, c in zip(kernel.sums, coefficients):
                lines += self._sum_text(op, out, c)
        lines += list(tail)
        return "\n".join([f"def {signature}:"] + ["    " + line for line in lines]) + "\n"

    # -- the module -----------------------------------------------------------------------
    def print(self) -> str:
        ir = self.ir
        n, m, npar = len(ir.variables), len(ir.residual), self.n_parameters
        njac = len(ir.jac_rows)
        self.names[sp.Symbol("cj")] = "cj"
        head = [
            '"""Compiled-backend functions of a residual module (generated by phc): numba compiles\n'
            'them; the intrinsics _X_* are written as LLVM IR from the same expressions."""\n',
            "import base64\nimport math\n\nimport numpy as np\n\n\n"
            "def _unpack(text, dtype):\n"
            "    return np.frombuffer(base64.b64decode(text), dtype=dtype).copy()\n",
            f"N = {n}",
        ]
        for k, (times, values, kind) in enumerate(ir.input_tables):
            head += [f"_TABLE{k}_T = {_array([float(x) for x in times], 'float')}",
                     f"_TABLE{k}_V = {_array([float(x) for x in values], 'float')}",
                     f"_TABLE{k}_KIND = {_KIND.get(kind, 0)}"]
        parts = [_HELPERS]
        for k in range(len(ir.input_tables)):  # called by the emitted code (compile_internal)
            parts.append(f"def _table{k}_at(t):\n    return _table(_TABLE{k}_T, _TABLE{k}_V, _TABLE{k}_KIND, t)\n\n\n"
                         f"def _table{k}_slope_at(t):\n"
                         f"    return _table_slope(_TABLE{k}_T, _TABLE{k}_V, _TABLE{k}_KIND, t)\n")
        lin = ir.linear_terms
        qd = ir.quadratic_dissipation
        qe = ir.quadratic_energy
        sums = bool(lin or qd)
        yyp = [("y", "N"), ("p", str(npar)), ("yp", "N")]
        y_p = [("y", "N"), ("p", str(npar))]

        res_sums = tuple(("matvec", t.matrix, t.rows, t.cols, "yp" if t.derivative else "y", t.coeff) for t in lin)
        res_sums += tuple(("quad", f.matrix, f.cols, -f.coeff, ir.energy_row, False) for f in qd)
        rows = [(i, e) for i, e in enumerate(ir.residual) if e != 0] if sums else list(enumerate(ir.residual))
        parts.append(self._function("residual", "residual(t, y, yp, p, out)", yyp + [("out", str(m))],
                                    Kernel(tuple((i, e, False) for i, e in rows), res_sums), "out", zero=sums))
        dt_rows = [(i, sp.diff(e, T)) for i, e in enumerate(ir.residual)]
        parts.append(self._function("residual_t", "residual_t(t, y, yp, p, out)", yyp + [("out", str(m))],
                                    Kernel(tuple((i, e, False) for i, e in dt_rows if e != 0)), "out", zero=True))
        jac = [dy + sp.Symbol("cj") * dyp if dyp != 0 else dy for dy, dyp in zip(ir.jac_dy, ir.jac_dyp)]
        if sums:
            jac_sums = tuple(("scatter", t.pos, _canonical(t.matrix).data, t.coeff, t.derivative) for t in lin)
            jac_sums += tuple(("grad", f.matrix, f.cols, f.pos, -2 * f.coeff) for f in qd)
            kernel = Kernel(tuple((k, e, True) for k, e in enumerate(jac) if e != 0), jac_sums)
        else:
            kernel = Kernel(tuple((k, e, False) for k, e in enumerate(jac)))
        parts.append(self._function("jacobian", "jacobian(t, y, yp, p, cj, out)", yyp + [("out", str(njac))],
                                    kernel, "out", zero=sums))
        parts.append(self._function(
            "hamiltonian", "hamiltonian(t, y, p)", y_p,
            Kernel(((0, ir.hamiltonian, False),), tuple(("quad", f.matrix, f.cols, f.coeff, 0, False) for f in qe)),
            "_o", scratch=1, tail=["return _o[0]"]))
        scale = sum((sp.Abs(term) for term in sp.Add.make_args(ir.hamiltonian)), sp.Integer(0))
        parts.append(self._function(
            "energy_scale", "energy_scale(t, y, p)", y_p,
            Kernel(((0, scale, False),), tuple(("quad", f.matrix, f.cols, f.coeff, 0, True) for f in qe)),
            "_o", scratch=1, tail=["return _o[0]"]))
        parts.append(self._function(
            "powers", "powers(t, y, yp, p)", yyp,
            Kernel(((0, ir.port_power, False), (1, ir.dissipation, False)),
                   tuple(("quad", f.matrix, f.cols, f.coeff, 1, False) for f in qd)),
            "_o", scratch=2, tail=["return _o[0], _o[1]"]))
        for fname, exprs in (("invariants", ir.invariants), ("velocity_invariants", ir.velocity_invariants)):
            parts.append(self._function(fname, f"{fname}(t, y, p)", y_p,
                                        Kernel(tuple((i, e, False) for i, e in enumerate(exprs))), "out",
                                        scratch=len(exprs), tail=["return out"]))
        parts.append(self._function("outputs", "outputs(t, y, yp, p)", yyp,
                                    Kernel(tuple((i, e, False) for i, (_, e) in enumerate(ir.outputs))), "out",
                                    scratch=len(ir.outputs), tail=["return out"]))
        return "\n\n".join(head + self._text_constants + parts)


def _canonical(matrix):
    """`matrix` as a CSR matrix with sorted indices and no duplicates (its entry order is
    the one :class:`~phc.codegen.lower.LinearTermIR` positions refer to)."""
    import scipy.sparse as sps

    m = sps.csr_matrix(matrix)
    m.sum_duplicates()
    m.sort_indices()
    return m


def kernel_source(ir: ResidualIR) -> tuple[str, dict]:
    """The numba-compilable text of the generated functions for `ir`, and the
    :class:`Kernel` of each intrinsic it calls."""
    printer = KernelPrinter(ir)
    return printer.print(), printer.kernels


# ---------------------------------------------------------------------------------------
# LLVM IR from sympy expressions

class _Emitter:
    """Writes the LLVM IR of sympy expressions into a numba intrinsic's builder, in the
    evaluation order of the Python the reference printer writes for them."""

    def __init__(self, context, builder, loaders: dict, tables: dict, printer):
        from llvmlite import ir as llir
        from numba.core import types, typing

        self.c, self.b, self.ir = context, builder, llir
        self.dbl = llir.DoubleType()
        self.types, self.typing = types, typing
        self.loaders = loaders
        self.tables = tables
        self.printer = printer
        self.values: dict = {}

    # helpers
    def const(self, x: float):
        return self.ir.Constant(self.dbl, x)

    def _intrinsic(self, name: str, *args):
        fn = self.b.module.declare_intrinsic(name, [self.dbl])
        return self.b.call(fn, list(args))

    def _math(self, func, *args):
        f64 = self.types.float64
        impl = self.c.get_function(func, self.typing.signature(f64, *([f64] * len(args))))
        return impl(self.b, list(args))

    # values
    def value(self, e):
        v = self.values.get(e)
        if v is None:
            v = self._value(e)
            self.values[e] = v
        return v

    def _value(self, e):
        b = self.b
        if e.is_Symbol:
            return self.loaders[e]()
        if e.is_Integer:
            return self.const(float(int(e)))
        if e.is_Rational:
            return self.const(int(e.p) / int(e.q))  # Python's correctly rounded true division, as printed
        if e.is_Float:
            return self.const(float(e))
        if e is sp.pi:
            return self.const(math.pi)
        if e is sp.E:
            return self.const(math.e)
        if e in (sp.oo, sp.zoo):
            return self.const(math.inf)
        if e is sp.S.NegativeInfinity:
            return self.const(-math.inf)
        if isinstance(e, sp.core.numbers.NaN):
            return self.const(math.nan)
        if e.is_Relational or isinstance(e, (sp.And, sp.Or, sp.Not, sp.ITE, sp.Xor)) or e in (sp.true, sp.false):
            return self.cond(e)  # a condition the common-subexpression pass named: an i1 value
        if e.is_Add:
            terms = self.printer._as_ordered_terms(e, order=None)
            acc = self.value(terms[0])
            for term in terms[1:]:
                acc = b.fadd(acc, self.value(term))
            return acc
        if e.is_Mul:
            return self._mul(e)
        if e.is_Pow:
            return self._pow(e)
        if isinstance(e, sp.Abs):
            return self._intrinsic("llvm.fabs", self.value(e.args[0]))
        if isinstance(e, sp.sign):  # (0.0 if x == 0 else math.copysign(1, x))
            x = self.value(e.args[0])
            return b.select(b.fcmp_ordered("==", x, self.const(0.0)), self.const(0.0),
                            self._intrinsic("llvm.copysign", self.const(1.0), x))
        if isinstance(e, (sp.Min, sp.Max)):  # min(a, b, ...): the first, replaced by each smaller one
            op = "<" if isinstance(e, sp.Min) else ">"
            best = self.value(e.args[0])
            for arg in e.args[1:]:
                v = self.value(arg)
                best = b.select(b.fcmp_ordered(op, v, best), v, best)
            return best
        if isinstance(e, sp.Heaviside):  # (1.0 if x > 0 else (0.0 if x < 0 else h0))
            x = self.value(e.args[0])
            h0 = self.value(e.args[1]) if len(e.args) > 1 else self.const(0.5)
            below = b.select(b.fcmp_ordered("<", x, self.const(0.0)), self.const(0.0), h0)
            return b.select(b.fcmp_ordered(">", x, self.const(0.0)), self.const(1.0), below)
        if _is_switch(e):  # ((g) if m == 0.0 else m): a switching condition's frozen side
            mode, g = self.value(e.args[0]), self.value(e.args[1])
            return b.select(b.fcmp_ordered("==", mode, self.const(0.0)), g, mode)
        if isinstance(e, sp.Piecewise):
            pieces = list(e.args)
            last = pieces[-1]
            result = self.value(last.expr) if last.cond == sp.true else self.const(math.nan)
            if last.cond == sp.true:
                pieces = pieces[:-1]
            for piece in reversed(pieces):
                result = b.select(self.cond(piece.cond), self.value(piece.expr), result)
            return result
        if isinstance(e, sp.atan2):
            return self._math(math.atan2, self.value(e.args[0]), self.value(e.args[1]))
        if isinstance(e, sp.log):
            return self._math(math.log, self.value(e.args[0]))
        if type(e) in _SIMPLE:
            return self._math(getattr(math, _SIMPLE[type(e)]), self.value(e.args[0]))
        if isinstance(e, (InputTable, InputTableSlope)):
            k = int(e.args[0])
            fn = self.tables[(k, isinstance(e, InputTableSlope))]
            f64 = self.types.float64
            return self.c.compile_internal(b, fn, self.typing.signature(f64, f64), [self.value(e.args[1])])
        raise NotImplementedError(f"no rule for {type(e).__name__}")  # emittable() said otherwise: a phc bug

    def _mul(self, e):
        from sympy.core.mul import _keep_coeff

        b = self.b
        c, rest = e.as_coeff_Mul()
        negative = c < 0
        if negative:
            e = _keep_coeff(-c, rest)
        args = e.as_ordered_factors() if self.printer.order not in ("old", "none") else sp.Mul.make_args(e)
        num, den = [], []
        for item in args:
            if item.is_commutative and item.is_Pow and item.exp.is_Rational and item.exp.is_negative:
                den.append(sp.Pow(item.base, -item.exp, evaluate=False) if item.exp != -1
                           else sp.Pow(item.base, -item.exp))
            else:
                num.append(item)
        num = num or [sp.S.One]
        acc = self.value(num[0])
        for item in num[1:]:
            acc = b.fmul(acc, self.value(item))
        if den:
            d = self.value(den[0])
            for item in den[1:]:
                d = b.fmul(d, self.value(item))
            acc = b.fdiv(acc, d)
        return b.fneg(acc) if negative else acc

    def _pow(self, e):
        b = self.b
        base, ex = e.base, e.exp
        if ex == sp.S.Half:
            return self._intrinsic("llvm.sqrt", self.value(base))
        if -ex is sp.S.Half:
            return b.fdiv(self.const(1.0), self._intrinsic("llvm.sqrt", self.value(base)))
        if ex is sp.S.NegativeOne:
            return b.fdiv(self.const(1.0), self.value(base))
        if base is sp.E:
            return self._math(math.exp, self.value(ex))
        return self._intrinsic("llvm.pow", self.value(base), self.value(ex))

    # conditions (i1)
    def cond(self, c):
        b = self.b
        if c.is_Symbol:  # a named condition (i1), or a number used as one (Python: nonzero is true)
            v = self.value(c)
            return v if v.type == self.ir.IntType(1) else b.fcmp_unordered("!=", v, self.const(0.0))
        if c == sp.true:
            return self.ir.Constant(self.ir.IntType(1), 1)
        if c == sp.false:
            return self.ir.Constant(self.ir.IntType(1), 0)
        if type(c) in _RELATIONS:
            op = _RELATIONS[type(c)]
            lhs, rhs = self.value(c.args[0]), self.value(c.args[1])
            return b.fcmp_unordered(op, lhs, rhs) if op == "!=" else b.fcmp_ordered(op, lhs, rhs)
        if isinstance(c, sp.And):
            acc = self.cond(c.args[0])
            for arg in c.args[1:]:
                acc = b.and_(acc, self.cond(arg))
            return acc
        if isinstance(c, sp.Or):
            acc = self.cond(c.args[0])
            for arg in c.args[1:]:
                acc = b.or_(acc, self.cond(arg))
            return acc
        if isinstance(c, sp.Not):
            return b.not_(self.cond(c.args[0]))
        if isinstance(c, sp.ITE):  # ((then) if (test) else (otherwise)), as printed
            return b.select(self.cond(c.args[0]), self.cond(c.args[1]), self.cond(c.args[2]))
        if isinstance(c, sp.Xor):
            acc = self.cond(c.args[0])
            for arg in c.args[1:]:
                acc = b.xor(acc, self.cond(arg))
            return acc
        raise NotImplementedError(f"no rule for condition {type(c).__name__}")


def _emit_kernel(context, builder, signature, args, kernel: Kernel, ir_: ResidualIR, tables, printer):
    """Body of the intrinsic ``_X_<name>(t, y, yp, p, cj, out)`` (see :class:`Kernel`)."""
    from llvmlite import ir as llir
    from numba.core import cgutils, types

    intp = context.get_value_type(types.intp)
    dbl = llir.DoubleType()
    i64 = llir.IntType(64)

    def array(k):
        aryty = signature.args[k]
        ary = context.make_array(aryty)(context, builder, args[k])
        shape = cgutils.unpack_tuple(builder, ary.shape, 1)
        strides = cgutils.unpack_tuple(builder, ary.strides, 1)
        return lambda j: cgutils.get_item_pointer2(context, builder, ary.data, shape, strides, aryty.layout,
                                                   [j if isinstance(j, llir.Value) else llir.Constant(intp, j)])

    at = {"y": array(1), "yp": array(2), "p": array(3), "out": array(5)}
    t = context.cast(builder, args[0], signature.args[0], types.float64)
    cj = context.cast(builder, args[4], signature.args[4], types.float64)
    loaders = {T: lambda: t, sp.Symbol("cj"): lambda: cj}
    for vec, symbols in (("y", ir_.y_symbols), ("yp", ir_.yp_symbols), ("p", ir_.p_symbols)):
        for j, s in enumerate(symbols):
            loaders[s] = (lambda at_, j_: lambda: builder.load(at_(j_)))(at[vec], j)
    emitter = _Emitter(context, builder, loaders, tables, printer)
    replacements, reduced = sp.cse(kernel.expressions(), symbols=sp.numbered_symbols("_c"), order="none")
    for sym, rhs in replacements:
        emitter.values[sym] = emitter.value(rhs)
    n_targets = len(kernel.targets)
    for (index, _, accumulate), e in zip(kernel.targets, reduced):
        v = emitter.value(e)
        ptr = at["out"](index)
        builder.store(builder.fadd(builder.load(ptr), v) if accumulate else v, ptr)
    coefficients = [emitter.value(e) for e in reduced[n_targets:]]

    def constant(values, kind):
        """Pointer to a constant array (int64 or float64) in the module."""
        values = np.ascontiguousarray(values, dtype=np.int64 if kind == "i" else np.float64)
        data = llir.Constant(llir.ArrayType(llir.IntType(8), values.nbytes), bytearray(values.tobytes()))
        g = llir.GlobalVariable(builder.module, data.type, name=builder.module.get_unique_name(".phc"))
        g.linkage, g.global_constant, g.initializer, g.align = "internal", True, data, 8
        return builder.bitcast(g, (i64 if kind == "i" else dbl).as_pointer())

    def load(ptr, index):
        return builder.load(builder.gep(ptr, [index]))

    def add_to(index_value, value):
        ptr = at["out"](index_value)
        builder.store(builder.fadd(builder.load(ptr), value), ptr)

    def row_products(A, cols, vec, each_row):
        """For every row i of A: each_row(i, Σ_k A_ik v[cols[k]])."""
        m = _canonical(A)
        indptr, indices, data = constant(m.indptr, "i"), constant(m.indices, "i"), constant(m.data, "f")
        colmap = constant(np.asarray(cols, dtype=np.int64), "i")
        acc = cgutils.alloca_once(builder, dbl)
        with cgutils.for_range(builder, llir.Constant(intp, m.shape[0]), intp=intp) as rows:
            i = rows.index
            builder.store(llir.Constant(dbl, 0.0), acc)
            start, stop = load(indptr, i), load(indptr, builder.add(i, llir.Constant(intp, 1)))
            with cgutils.for_range_slice(builder, start, stop, llir.Constant(intp, 1), intp=intp) as (k, _):
                column = load(colmap, load(indices, k))
                term = builder.fmul(load(data, k), builder.load(at[vec](column)))
                builder.store(builder.fadd(builder.load(acc), term), acc)
            each_row(i, builder.load(acc))

    for op, c in zip(kernel.sums, coefficients):
        kind = op[0]
        if kind == "matvec":
            _, A, rows, cols, vec, _ = op
            rowmap = constant(np.asarray(rows, dtype=np.int64), "i")
            row_products(A, cols, vec, lambda i, s, rowmap=rowmap, c=c: add_to(load(rowmap, i), builder.fmul(c, s)))
        elif kind == "scatter":
            _, pos, data_, _, times_cj = op
            scale = builder.fmul(cj, c) if times_cj else c
            pos_c, data_c = constant(pos, "i"), constant(data_, "f")
            with cgutils.for_range(builder, llir.Constant(intp, len(pos)), intp=intp) as loop:
                add_to(load(pos_c, loop.index), builder.fmul(scale, load(data_c, loop.index)))
        elif kind == "quad":
            _, A, cols, _, index, absolute = op
            total = cgutils.alloca_once(builder, dbl)
            builder.store(llir.Constant(dbl, 0.0), total)
            colmap = constant(np.asarray(cols, dtype=np.int64), "i")

            def row(i, s, total=total, colmap=colmap):
                x = builder.load(at["y"](load(colmap, i)))
                builder.store(builder.fadd(builder.load(total), builder.fmul(x, s)), total)

            row_products(A, cols, "y", row)
            value = builder.fmul(c, builder.load(total))
            if absolute:
                value = emitter._intrinsic("llvm.fabs", value)
            add_to(llir.Constant(intp, index), value)
        else:  # grad
            _, A, cols, pos, _ = op
            pos_c = constant(np.asarray(pos, dtype=np.int64), "i")
            row_products(A, cols, "y", lambda i, s, pos_c=pos_c, c=c: add_to(load(pos_c, i), builder.fmul(c, s)))


def _make_intrinsic(name: str, kernel: Kernel, ir_: ResidualIR, tables: dict, printer):
    from numba.core import types
    from numba.extending import intrinsic

    def kernel_typer(typingctx, t, y, yp, p, cj, out):
        arrays = (y, yp, p, out)
        if not all(isinstance(a, types.Array) and a.ndim == 1 and a.dtype == types.float64 for a in arrays):
            return None
        if not out.mutable or not all(isinstance(s, (types.Float, types.Integer)) for s in (t, cj)):
            return None

        def codegen(context, builder, signature, args):
            _emit_kernel(context, builder, signature, args, kernel, ir_, tables, printer)
            return context.get_dummy_value()

        return types.none(t, y, yp, p, cj, out), codegen

    kernel_typer.__name__ = kernel_typer.__qualname__ = f"_X_{name}"
    return intrinsic(kernel_typer)


# ---------------------------------------------------------------------------------------
# loading

def _build(ir: ResidualIR, text: str, kernels: dict, trivial: set, printer, digest: str, folder: Optional[Path],
           signer: Optional[bytes], classes) -> tuple[dict, int, int]:
    """Execute the kernel text, make the intrinsics, and compile (or load) each function for
    its one signature (:func:`~phc.codegen.numba_cache.compile_functions`); returns
    (dispatchers, hits, misses)."""
    module = kernel_module(text, digest, folder)
    try:
        return _compile_all(ir, kernels, trivial, printer, module, signer, classes)
    except BaseException:
        sys.modules.pop(module.__name__, None)
        raise


def _compile_all(ir, kernels, trivial, printer, kernel_module, signer, classes):
    namespace = kernel_module.__dict__
    tables = {}
    for k in range(len(ir.input_tables)):
        tables[(k, False)] = namespace[f"_table{k}_at"]
        tables[(k, True)] = namespace[f"_table{k}_slope_at"]
    for name, kernel in kernels.items():
        namespace[f"_X_{name}"] = _make_intrinsic(name, kernel, ir, tables, printer)
    return compile_functions(namespace, trivial, signer, classes)


def load_compiled(ir: ResidualIR, reference: ModuleType, reference_source: str,
                  cache: Optional[bool] = None) -> tuple[ModuleType, CompileReport]:
    """The compiled module for `ir` (see the module docstring) and how it was obtained.

    Raises
    ------
    BackendUnavailable
        numba cannot be imported.
    BackendMismatch
        The compiled residual or Jacobian disagrees with the reference at a sample point
        (a phc bug; the caller falls back to the reference module).
    """
    ok, why = available()
    if not ok:
        raise BackendUnavailable(why)
    start, cpu = time.perf_counter(), time.process_time()
    kernel_printer = KernelPrinter(ir)
    text, kernels = kernel_printer.print(), kernel_printer.kernels
    digest = kernel_digest(text, reference_source)
    if cache is None:
        cache = os.environ.get("PHC_COMPILED_CACHE", "1").strip().lower() not in ("0", "no", "false", "off")
    note = ""
    signer = None
    folder = None
    classes = _cache_classes() if cache else None
    if not cache:
        note = "disk cache off (PHC_COMPILED_CACHE=0)"
    elif classes is None:
        note = "disk cache unavailable with this numba version"
    else:
        folder = compiled_cache_dir()
        problem = _private_dir(folder)
        key, why_not = cache_key()
        if problem:
            note, folder = f"cache directory {folder} {problem}", None
        elif key is None:
            note, folder = why_not, None
        else:
            signer = key
    loaded = numba_cache._LOADED.get(digest)
    if loaded is not None:
        _remember(digest, loaded)
        dispatchers, state, note = loaded, "memory", "compiled earlier in this process"
        hits = misses = 0
    else:
        dispatchers, hits, misses = _build(ir, text, kernels, kernel_printer.trivial, kernel_printer.printer,
                                           digest, folder, signer, classes)
        _remember(digest, dispatchers)
        if signer is None:
            state = "off"
        else:
            state = "warm" if misses == 0 else ("cold" if hits == 0 else "partial")
            try:
                from phc.codegen.load import enforce_cap
                enforce_cap()
            except OSError:
                pass
    report = CompileReport(time.perf_counter() - start, time.process_time() - cpu, state, digest,
                           tuple(sorted(kernels)), note, hits, misses)
    module = assemble(reference, dispatchers, report)
    # what the cached front end needs to load these functions again without the IR (phc.fastpath)
    module.KERNEL = {"text": text, "emitted": sorted(kernels), "trivial": sorted(kernel_printer.trivial)}
    mismatch = _cross_check(module, reference)
    if mismatch:
        raise BackendMismatch(f"the compiled functions disagree with the reference module ({mismatch})")
    return module, report


__all__ = ["BackendMismatch", "BackendUnavailable", "CompileReport", "CompiledBackendWarning", "FUNCTIONS",
           "KernelPrinter", "available", "cache_key", "compiled_cache_dir", "emittable", "kernel_source",
           "load_compiled"]
