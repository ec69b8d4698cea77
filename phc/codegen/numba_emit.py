"""LLVM IR from sympy expressions: the scalar expressions of the compiled backend as numba
intrinsics, written without numba's Python-level compiler.

:mod:`phc.codegen.numba_backend` prints the generated functions as numba-compilable Python
(:class:`~phc.codegen.numba_backend.KernelPrinter`) and builds and loads them; what each of
its intrinsics ``_X_<name>(t, y, yp, p, cj, out)`` computes is a
:class:`~phc.codegen.kernels.Kernel` (target
expressions and sparse sums), and this module writes the body: :func:`emittable` says
whether every node of an expression has a rule here, :class:`_Emitter` writes the LLVM IR
of the expressions (after the same common-subexpression elimination and in the evaluation
order of the printed Python), :func:`_emit_kernel` the whole body with the sparse sums as
loops over constant CSR arrays. The names here are importable from
:mod:`phc.codegen.numba_backend` as well; that module makes the intrinsics
(``_make_intrinsic``) and calls :func:`_emit_kernel` through its own name for it.
"""

from __future__ import annotations

import math

import numpy as np
import sympy as sp

# what each function computes (shared with the C back end), importable from here as before
from phc.codegen.kernels import _COEFFICIENT, Kernel, _canonical, _coefficient, kernel_cse, product_parts  # noqa: F401
from phc.codegen.kernels import repeated, slot
from phc.codegen.lower import ResidualIR
from phc.ir.dae import STORED_ENERGY, T
from phc.frontend.inputs import InputTable, InputTableSlope

# ---------------------------------------------------------------------------------------
# what the emitter can write

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
        b = self.b
        negative, num, den = product_parts(e, self.printer.order)
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
            if s is not None:  # None: the rate of an algebraic variable
                loaders[s] = (lambda at_, j_: lambda: builder.load(at_(j_)))(at[vec], j)
    if kernel.energy is not None:
        # the stored energy H first, as `hamiltonian` computes it, into a local: the value of
        # STORED_ENERGY in the targets (an output that uses H)
        slot = cgutils.alloca_once(builder, dbl)
        builder.store(llir.Constant(dbl, 0.0), slot)
        local = {**at, "out": lambda j: builder.gep(slot, [j if isinstance(j, llir.Value) else llir.Constant(intp, j)])}
        _emit_body(context, builder, kernel.energy, ir_, local, loaders, cj, tables, printer)
        energy = builder.load(slot)
        loaders[STORED_ENERGY] = lambda: energy
    _emit_body(context, builder, kernel, ir_, at, loaders, cj, tables, printer)


def _cse_one(template):
    """The common subexpressions of one :class:`~phc.codegen.repeat.Repeated` template."""
    from phc.codegen.printer import _cse

    return _cse([template], sp.numbered_symbols("_l", cls=sp.Dummy))


def _emit_body(context, builder, kernel: Kernel, ir_: ResidualIR, at: dict, loaders: dict, cj, tables, printer):
    """The targets and sums of `kernel` into ``at["out"]`` (pointers to its entries by index),
    its symbols read by `loaders`."""
    from llvmlite import ir as llir
    from numba.core import cgutils, types

    intp = context.get_value_type(types.intp)
    dbl = llir.DoubleType()
    i64 = llir.IntType(64)
    emitter = _Emitter(context, builder, loaders, tables, printer)
    # an expression recurring at many entries: one loop over them (phc.codegen.repeat.repeated)
    targets, loops = repeated(ir_, kernel.targets)
    replacements, reduced = kernel_cse(ir_, Kernel(targets, kernel.sums), targets)
    for sym, rhs in replacements:
        emitter.values[sym] = emitter.value(rhs)
    n_targets = len(targets)
    for (index, _, accumulate), e in zip(targets, reduced):
        v = emitter.value(e)
        ptr = at["out"](index)
        builder.store(builder.fadd(builder.load(ptr), v) if accumulate else v, ptr)

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

    def entry(values, k):
        """``values[k]`` for the loop index k: ``a + d*k`` for a progression, else a constant array's entry."""
        if len(values) > 1:
            step = int(values[1] - values[0])
            if np.array_equal(np.diff(values), np.full(len(values) - 1, step)):
                return builder.add(llir.Constant(intp, int(values[0])), builder.mul(llir.Constant(intp, step), k))
        return load(constant(values, "i"), k)

    for r in loops:
        found, (template,) = _cse_one(r.template)
        total = None
        if (r.index == r.index[0]).all():  # terms of one sum: added up, then to the entry
            total = cgutils.alloca_once(builder, dbl)
            builder.store(llir.Constant(dbl, 0.0), total)
        with cgutils.for_range(builder, llir.Constant(intp, r.count), intp=intp) as loop:
            k = loop.index
            inner = dict(loaders)
            for j, (vec, values) in enumerate(r.slots):
                inner[slot(j)] = (lambda vec_, values_: lambda: builder.load(at[vec_](entry(values_, k))))(vec, values)
            body = _Emitter(context, builder, inner, tables, printer)
            for sym, rhs in found:
                body.values[sym] = body.value(rhs)
            v = body.value(template)
            if total is not None:
                builder.store(builder.fadd(builder.load(total), v), total)
            else:
                ptr = at["out"](entry(r.index, k))
                builder.store(builder.fadd(builder.load(ptr), v) if r.accumulate else v, ptr)
        if total is not None:
            add_to(llir.Constant(intp, int(r.index[0])), builder.load(total))
    coefficients = [emitter.value(e) for e in reduced[n_targets:]]

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
