"""The C back end's print pass: a :class:`~phc.codegen.lower.ResidualIR` as one readable C99 file.

Input: a :class:`~phc.codegen.lower.ResidualIR`. Output: the text of a C99 translation unit
(:func:`c_source`) that :mod:`phc.codegen.c_backend` compiles into a shared library.

The file defines one function per entry point of the generated NumPy module, with the
same arguments (arrays as pointers to ``double``)::

    void   phc_residual(double t, const double *y, const double *yp, const double *p, double *out);
    void   phc_residual_t(double t, const double *y, const double *yp, const double *p, double *out);
    void   phc_jacobian(double t, const double *y, const double *yp, const double *p, double cj, double *out);
    double phc_hamiltonian(double t, const double *y, const double *p);
    double phc_energy_scale(double t, const double *y, const double *p);
    void   phc_powers(double t, const double *y, const double *yp, const double *p, double *out);  /* 2 */
    void   phc_invariants(double t, const double *y, const double *p, double *out);
    void   phc_velocity_invariants(double t, const double *y, const double *p, double *out);
    void   phc_outputs(double t, const double *y, const double *yp, const double *p, double *out);
    void   phc_events(double t, const double *y, const double *yp, const double *p, double *out);
    void   phc_sizes(long long *out);  /* the sizes it was generated for (SIZES below) */

Every function reads its arguments and writes only its `out`: no static mutable state, so
the library is re-entrant (threads may call it at once). Inside a function, each model
variable or parameter it uses is a named local (``y_spring_x``, with the model's name in a
comment), the common subexpressions are locals ``c0, c1, ...`` (the same
common-subexpression elimination and the same evaluation order as the numba back end's
emitter, :mod:`phc.codegen.numba_emit`: found once per IR with the NumPy module's,
:func:`phc.codegen.kernels.kernel_cse`; terms and factors ordered as the NumPy module's
printer orders them, ``a*b/(c*d)`` as it prints them, ``pow``/``sqrt`` and the other
``math.h`` functions CPython's ``math`` calls), and every float literal is the ``repr`` of
the double the NumPy module computes (correctly rounded when read back). The sparse linear
blocks and the quadratic energy and dissipation forms are loops over constant CSR arrays
(``static const``) of the file, and so is an expression that recurs at many entries (the
rows of identical components, the terms of their energy: :func:`phc.codegen.repeat.repeated`),
written once as a loop over the entries it reads and writes.

What the printer does not write in C yet is refused with :class:`CUnsupported`, naming the
construct and where it is used: input tables (a CSV file as a port's input), and any
function it has no rule for (none of the model language's today). Conditions (``ifelse``,
``sign``, ``heaviside``, ``abs``, ``min``, ``max`` and the switches of
:mod:`phc.codegen.nonsmooth`) are printed: C evaluates both branches of a conditional
expression's operands only where the NumPy module evaluates one, and since C does not trap
on a division by zero or ``sqrt(-1)``, a branch that is not taken cannot change the value.
"""

from __future__ import annotations

import math
from typing import Iterable, Optional

import numpy as np
import sympy as sp

from phc import __version__
from phc.codegen.kernels import (CJ, Kernel, Repeated, _canonical, events_kernel, function_kernels, kernel_cse,
                                 product_parts, repeated, slot)
from phc.codegen.repeat import is_slot, progression
from phc.codegen.lower import ResidualIR
from phc.codegen.numba_emit import _NODES, _RELATIONS, _SIMPLE, _is_switch
from phc.codegen.printer import _cse, _identifier, _Printer
from phc.ir.dae import STORED_ENERGY, T
from phc.errors import BackendUnsupported, CodegenError
from phc.frontend.inputs import InputTable, InputTableSlope

from phc.codegen.c_backend import ABI  # noqa: E402 — the loader checks it without importing sympy

SIZES = ("abi", "unknowns", "rows", "jacobian entries", "parameters", "invariants", "velocity invariants",
         "outputs")
"""What ``phc_sizes(out)`` writes into out[0..7]."""


CUnsupported = BackendUnsupported
"""The model uses something the C back end does not print yet (the message names it)."""


def comment(text: str) -> str:
    """`text` safe inside a C block comment (a model name cannot end the comment)."""
    text = "".join(ch if ch.isprintable() else " " for ch in str(text))
    return text.replace("*/", "* /").replace("/*", "/ *")


def number(x: float) -> str:
    """The C literal of the double `x` (``repr``: read back correctly rounded, exactly `x`)."""
    if math.isnan(x):
        return "NAN"
    if math.isinf(x):
        return "INFINITY" if x > 0 else "(-INFINITY)"
    text = repr(float(x))
    return f"({text})" if text.startswith("-") else text


_HELPERS = r"""
/* ---- helpers: pure functions of their arguments ------------------------------------ */

/* sign(x): 0 at 0, else +-1 (as math.copysign(1, x)) */
static double phc_sign(double x) { return x == 0.0 ? 0.0 : copysign(1.0, x); }

/* heaviside(x) with value h0 at 0 */
static double phc_heaviside(double x, double h0) { return x > 0.0 ? 1.0 : (x < 0.0 ? 0.0 : h0); }

/* min and max as Python's builtins: the first argument unless the second compares below (above) it */
static double phc_min(double a, double b) { return b < a ? b : a; }
static double phc_max(double a, double b) { return b > a ? b : a; }

/* a switching condition's boundary value: g while its mode is 0 (free), else the frozen mode +-1 */
static double phc_switch(double mode, double g) { return mode == 0.0 ? g : mode; }

/* out[rows[i]] += c * sum_k A[i, k] v[cols[k]] for a constant CSR matrix A, whose column indices
 * come composed with the block's columns (idx = cols[indices]: one load an entry, not two
 * dependent ones; about 0.8x the residual's time on the flexible slider-crank) */
static void phc_matvec_add(int nrows, const int *indptr, const int *idx, const double *data,
                           const int *rows, const double *v, double c, double *out)
{
    for (int i = 0; i < nrows; ++i) {
        double acc = 0.0;
        for (int k = indptr[i]; k < indptr[i + 1]; ++k)
            acc += data[k] * v[idx[k]];
        out[rows[i]] += c * acc;
    }
}

/* out[pos[k]] += c * data[k]: the Jacobian entries of a linear term */
static void phc_scatter_add(int n, const int *pos, const double *data, double c, double *out)
{
    for (int k = 0; k < n; ++k)
        out[pos[k]] += c * data[k];
}

/* x^T A x with x = y[cols] */
static double phc_quadratic(int n, const int *indptr, const int *indices, const double *data,
                            const int *cols, const double *y)
{
    double total = 0.0;
    for (int i = 0; i < n; ++i) {
        double acc = 0.0;
        for (int k = indptr[i]; k < indptr[i + 1]; ++k)
            acc += data[k] * y[cols[indices[k]]];
        total += y[cols[i]] * acc;
    }
    return total;
}

/* out[pos[i]] += c * (A x)_i with x = y[cols] */
static void phc_gradient_add(int n, const int *indptr, const int *indices, const double *data,
                             const int *cols, const double *y, double c, const int *pos, double *out)
{
    for (int i = 0; i < n; ++i) {
        double acc = 0.0;
        for (int k = indptr[i]; k < indptr[i + 1]; ++k)
            acc += data[k] * y[cols[indices[k]]];
        out[pos[i]] += c * acc;
    }
}
"""

# precedence of what an expression's text is, for parentheses
_ATOM, _MUL, _ADD, _COND = 3, 2, 1, 0


class _Expressions:
    """C text of sympy expressions, in the NumPy module's evaluation order."""

    def __init__(self, names: dict, order_printer: _Printer):
        self.names = names
        self.order = order_printer  # the reference printer: the same ordering of terms and factors
        self.locals: dict = {}

    def text(self, e) -> str:
        return self._print(e)[0]

    def _wrapped(self, e, least: int) -> str:
        text, prec = self._print(e)
        return text if prec >= least else f"({text})"

    def _print(self, e) -> tuple[str, int]:
        if e.is_Symbol:
            name = self.locals.get(e) or self.names.get(e)
            if name is None:
                raise CodegenError(f"no generated name for symbol `{e}` (a phc bug: please report it)")
            return name, _ATOM
        if e.is_Integer:
            return number(float(int(e))), _ATOM
        if e.is_Rational:
            return number(int(e.p) / int(e.q)), _ATOM  # Python's correctly rounded true division, as printed
        if e.is_Float:
            return number(float(e)), _ATOM
        if e is sp.pi:
            return number(math.pi), _ATOM
        if e is sp.E:
            return number(math.e), _ATOM
        if e in (sp.oo, sp.zoo):
            return "INFINITY", _ATOM
        if e is sp.S.NegativeInfinity:
            return "(-INFINITY)", _ATOM
        if isinstance(e, sp.core.numbers.NaN):
            return "NAN", _ATOM
        if e.is_Relational or isinstance(e, (sp.And, sp.Or, sp.Not, sp.ITE, sp.Xor)) or e in (sp.true, sp.false):
            return self.cond(e), _ATOM  # a condition used as a value (named by the CSE pass): 0 or 1
        if e.is_Add:
            return self._add(e), _ADD
        if e.is_Mul:
            return self._mul(e)
        if e.is_Pow:
            return self._pow(e)
        if isinstance(e, sp.Abs):
            return f"fabs({self.text(e.args[0])})", _ATOM
        if isinstance(e, sp.sign):
            return f"phc_sign({self.text(e.args[0])})", _ATOM
        if isinstance(e, (sp.Min, sp.Max)):
            helper = "phc_min" if isinstance(e, sp.Min) else "phc_max"
            acc = self.text(e.args[0])
            for arg in e.args[1:]:
                acc = f"{helper}({acc}, {self.text(arg)})"
            return acc, _ATOM
        if isinstance(e, sp.Heaviside):
            h0 = self.text(e.args[1]) if len(e.args) > 1 else "0.5"
            return f"phc_heaviside({self.text(e.args[0])}, {h0})", _ATOM
        if _is_switch(e):
            return f"phc_switch({self.text(e.args[0])}, {self.text(e.args[1])})", _ATOM
        if isinstance(e, sp.Piecewise):
            pieces = list(e.args)
            last = pieces[-1]
            result = self.text(last.expr) if last.cond == sp.true else "NAN"
            if last.cond == sp.true:
                pieces = pieces[:-1]
            for piece in reversed(pieces):
                result = f"{self.cond(piece.cond)} ? {self.text(piece.expr)} : {result}"
            return (f"({result})" if pieces else result), _ATOM
        if isinstance(e, sp.atan2):
            return f"atan2({self.text(e.args[0])}, {self.text(e.args[1])})", _ATOM
        if isinstance(e, sp.log) and len(e.args) == 1:
            return f"log({self.text(e.args[0])})", _ATOM
        if type(e) in _SIMPLE:
            return f"{_SIMPLE[type(e)]}({self.text(e.args[0])})", _ATOM
        raise CodegenError(f"no C rule for {type(e).__name__} (a phc bug: please report it)")

    def _add(self, e) -> str:
        """``t0 + t1 - t2``: left to right as Python evaluates the printed sum (a term printed
        with a leading minus is subtracted: x - y is x + (-y) exactly)."""
        out = ""
        for k, term in enumerate(self.order._as_ordered_terms(e, order=None)):
            text = self._wrapped(term, _MUL)
            if term.is_Number and text.startswith("(-"):
                text = text[1:-1]  # a negative literal
            if text.startswith("-"):
                out = text if k == 0 else f"{out} - {text[1:]}"
            else:
                out = text if k == 0 else f"{out} + {text}"
        return out

    def _mul(self, e) -> tuple[str, int]:
        """``-a*b/(c*d)`` as the reference printer writes it (sympy's code printer)."""
        negative, num, den = product_parts(e, self.order.order)
        sign = "-" if negative else ""
        text = sign + "*".join(self._wrapped(x, _ATOM if sign and k == 0 else _MUL) for k, x in enumerate(num))
        if len(den) == 1:
            text += "/" + self._wrapped(den[0], _ATOM)
        elif den:
            text += "/(" + "*".join(self._wrapped(x, _MUL) for x in den) + ")"
        return text, _MUL

    def _pow(self, e) -> tuple[str, int]:
        base, ex = e.base, e.exp
        if ex == sp.S.Half:
            return f"sqrt({self.text(base)})", _ATOM
        if -ex is sp.S.Half:
            return f"1.0/sqrt({self.text(base)})", _MUL
        if ex is sp.S.NegativeOne:
            return f"1.0/{self._wrapped(base, _ATOM)}", _MUL
        return f"pow({self.text(base)}, {self.text(ex)})", _ATOM

    def cond(self, c) -> str:
        """A condition as a C int expression (parenthesized)."""
        if c.is_Symbol:  # a named condition, or a number used as one (Python: nonzero is true)
            return f"({self.text(c)} != 0.0)"
        if c == sp.true:
            return "1"
        if c == sp.false:
            return "0"
        if type(c) in _RELATIONS:
            return f"({self.text(c.args[0])} {_RELATIONS[type(c)]} {self.text(c.args[1])})"
        if isinstance(c, sp.And):
            return "(" + " && ".join(self.cond(a) for a in c.args) + ")"
        if isinstance(c, sp.Or):
            return "(" + " || ".join(self.cond(a) for a in c.args) + ")"
        if isinstance(c, sp.Not):
            return f"(!{self.cond(c.args[0])})"
        if isinstance(c, sp.ITE):
            return f"({self.cond(c.args[0])} ? {self.cond(c.args[1])} : {self.cond(c.args[2])})"
        if isinstance(c, sp.Xor):
            return "(" + " ^ ".join(self.cond(a) for a in c.args) + ")"
        raise CodegenError(f"no C rule for the condition {type(c).__name__} (a phc bug: please report it)")


def _has_rule(e) -> bool:
    """Whether the printer has a rule for the node `e` itself (its arguments aside)."""
    return bool(e.is_Symbol or e.is_Number or e in (sp.pi, sp.E, sp.true, sp.false)
                or isinstance(e, sp.core.numbers.NaN) or isinstance(e, _NODES) or type(e) in _SIMPLE
                or type(e) in _RELATIONS or _is_switch(e) or (isinstance(e, sp.log) and len(e.args) == 1)
                or isinstance(e, sp.functions.elementary.piecewise.ExprCondPair))


def unsupported(expr, known: set) -> Optional[str]:
    """What in `expr` the C printer has no rule for (a phrase), or None."""
    for e in sp.preorder_traversal(expr):
        if isinstance(e, (InputTable, InputTableSlope)):
            return "input tables (a CSV file as a port's input)"
        if e.is_Symbol and e not in known:
            return f"the symbol `{e}`, which has no value in the generated code (a phc bug: please report it)"
        if not _has_rule(e):
            return f"the function `{type(e).__name__}`"
    return None


class _Slotted:
    """The symbols of `known` and the slots of a :class:`~phc.codegen.repeat.Repeated` template."""

    def __init__(self, known) -> None:
        self._known = known

    def __contains__(self, s) -> bool:
        return s in self._known or is_slot(s)


class _Labels:
    """``index -> label`` of a function's entries, read from its sequence of labels when asked
    (no dictionary of every entry: a mesh's Jacobian has millions)."""

    def __init__(self, labels) -> None:
        self._labels = labels

    def get(self, index, default=None):
        return self._labels[index] if isinstance(index, (int, np.integer)) and 0 <= index < len(self._labels) else default


class CPrinter:
    """Prints the C file of a model (see the module docstring)."""

    def __init__(self, ir: ResidualIR):
        self.ir = ir
        taken: set = set()
        self.names: dict = {T: "t", CJ: "cj"}
        self.loads: dict = {}  # symbol -> (declaration, model name)
        self.entries: dict = {}  # (vector, index) -> symbol
        for vec, symbols, prefix in (("y", ir.y_symbols, "y_"), ("yp", ir.yp_symbols, "yp_"),
                                     ("p", ir.p_symbols, "p_")):
            labels = ir.variables if vec != "p" else ir.parameters
            for j, (s, label) in enumerate(zip(symbols, labels)):
                ident = _identifier(prefix, label, taken)  # reserved for an algebraic rate too: the same names
                if s is None:
                    continue
                self.names[s] = ident
                self.entries[(vec, j)] = s
                what = f"der({label})" if vec == "yp" else label
                self.loads[s] = (f"const double {ident} = {vec}[{j}];", what)
        # an output that uses H: the value of phc_hamiltonian (defined above phc_outputs), once
        self.names[STORED_ENERGY] = "energy_H"
        self.loads[STORED_ENERGY] = ("const double energy_H = phc_hamiltonian(t, y, p);", "the stored energy H")
        self.order = _Printer(self.names)
        self.known = set(ir.y_symbols) | set(ir.yp_symbols) | set(ir.p_symbols) | {T, CJ, STORED_ENERGY}
        self.constants: list[str] = []
        self._constant_names: dict = {}

    # -- constant arrays ------------------------------------------------------------------
    def array(self, stem: str, values, kind: str) -> str:
        """The name of a ``static const`` array of `values` (``int`` or ``double``), written once."""
        values = np.ascontiguousarray(values, dtype=np.int64 if kind == "int" else np.float64).ravel()
        key = (kind, values.tobytes())
        name = self._constant_names.get(key)
        if name is not None:
            return name
        if kind == "int" and len(values) and (values.min() < 0 or values.max() >= 2**31):
            raise CUnsupported("a sparse block too large for 32-bit indices")
        name = f"{stem}{len(self._constant_names)}"
        self._constant_names[key] = name
        items = [str(int(v)) for v in values] if kind == "int" else [number(float(v)) for v in values]
        per_line = 16 if kind == "int" else 6
        body = ",\n".join("    " + ", ".join(items[i:i + per_line]) for i in range(0, len(items), per_line))
        size = max(len(items), 1)
        self.constants.append(f"static const {'int' if kind == 'int' else 'double'} {name}[{size}] = {{\n"
                              f"{body or '    0'}\n}};")
        return name

    def csr(self, matrix) -> tuple[int, str, str, str]:
        m = _canonical(matrix)
        return (m.shape[0], self.array("indptr", m.indptr, "int"), self.array("indices", m.indices, "int"),
                self.array("data", m.data, "double"))

    # -- one function ---------------------------------------------------------------------
    def function(self, name: str, head: str, doc: str, kernel: Kernel, labels: dict, *, zero: int = 0,
                 local_out: int = 0, tail: Iterable[str] = ()) -> str:
        """The C function `head` computing `kernel` into ``out`` (zeroed first when `zero` > 0;
        a local array of `local_out` entries when given); `labels` name the targets in comments."""
        targets = tuple((i, e, acc) for i, e, acc in kernel.targets if not (e == 0 and acc))
        targets, loops = repeated(self.ir, targets)
        # what the printer has no rule for: each expression written one by one, each template once
        checks = [(e, self.known, i) for i, e, _ in targets]
        checks += [(r.template, _Slotted(self.known), int(r.index[0])) for r in loops]
        for e, known, i in checks:
            what = unsupported(e, known)
            if what:
                raise CUnsupported(f"the C backend does not support {what} yet (in {name}, {labels.get(i, i)})")
        for op in kernel.sums:
            what = unsupported(Kernel((), (op,)).expressions()[0], self.known)
            if what:
                raise CUnsupported(f"the C backend does not support {what} yet (in {name}, a linear block)")
        replacements, reduced = kernel_cse(self.ir, Kernel(targets, kernel.sums), targets)
        printer = _Expressions(self.names, self.order)
        used = set()
        for e in [rhs for _, rhs in replacements] + list(reduced):
            used |= e.free_symbols if isinstance(e, sp.Basic) else set()
        loop_text = [line for r in loops for line in self._loop(r, labels, used)]
        body = [f"/* {comment(doc)} */"] if doc else []
        if local_out:
            body.append(f"double out[{local_out}] = {{{', '.join(['0.0'] * local_out)}}};")
        for s, (decl, what) in self.loads.items():
            if s in used:
                body.append(f"{decl}  /* {comment(what)} */")
        if zero:
            # memset, not a loop: all-zero bytes are +0.0, and at -O1 (phc.codegen.c_backend.FLAGS) gcc
            # leaves a loop a loop, which cost the Jacobian of the flexible slider-crank (612 entries) 40 %
            body.append(f"memset(out, 0, {zero} * sizeof(double));")
        for k, (sym, rhs) in enumerate(replacements):
            printer.locals[sym] = f"c{k}"
            body.append(f"const double c{k} = {printer.text(rhs)};")
        for (index, _, accumulate), e in zip(targets, reduced):
            label = labels.get(index)
            note = f"  /* {comment(label)} */" if label else ""
            body.append(f"out[{index}] {'+=' if accumulate else '='} {printer.text(e)};{note}")
        body += loop_text
        coefficients = [printer.text(e) for e in reduced[len(targets):]]
        for op, c in zip(kernel.sums, coefficients):
            body += self._sum(op, c)
        body += list(tail)
        return head + "\n{\n" + "".join(f"    {line}\n" for line in body) + "}\n"

    def _subscript(self, at: np.ndarray, stem: str) -> str:
        """The C index of ``at[k]`` in a loop over k: ``a + d*k`` for an arithmetic progression,
        else a constant array's entry."""
        found = progression(at)
        if found is not None:
            start, step = found
            term = "k" if step == 1 else f"{step}*k"
            return term if start == 0 else f"{start} + {term}"
        return f"{self.array(stem, at, 'int')}[k]"

    def _loop(self, r: Repeated, labels, used: set) -> list[str]:
        """One :class:`~phc.codegen.repeat.Repeated` expression as a loop over its instances; an
        entry every instance reads is the function's named local (added to `used`)."""
        names = dict(self.names)
        loads = []
        for j, (vector, at) in enumerate(r.slots):
            if (at == at[0]).all():
                symbol = self.entries[(vector, int(at[0]))]
                names[slot(j)] = self.names[symbol]
                used.add(symbol)
            else:
                names[slot(j)] = f"s{j}"
                loads.append(f"const double s{j} = {vector}[{self._subscript(at, 'at')}];")
        inner = _Expressions(names, self.order)
        replacements, (value,) = _cse([r.template], sp.numbered_symbols("_l", cls=sp.Dummy))
        for m, (symbol, rhs) in enumerate(replacements):
            inner.locals[symbol] = f"l{m}"
            loads.append(f"const double l{m} = {inner.text(rhs)};")
        used |= {s for s in r.template.free_symbols if s in self.loads}
        first, last = labels.get(int(r.index[0])), labels.get(int(r.index[-1]))
        text = inner.text(value)
        if (r.index == r.index[0]).all():  # terms of one sum: added up, then to the entry
            what = f" of {comment(first)}" if first else ""
            head = f"/* {r.count} terms{what} of one form: a loop over the entries they read */"
            return [head, "{", "    double sum = 0.0;", f"    for (int k = 0; k < {r.count}; ++k) {{",
                    *(f"        {line}" for line in loads), f"        sum += {text};", "    }",
                    f"    out[{int(r.index[0])}] += sum;", "}"]
        what = f" ({comment(first)} ... {comment(last)})" if first and last else ""
        head = f"/* one expression at {r.count} entries{what}: a loop over the entries it reads */"
        target = f"out[{self._subscript(r.index, 'at')}] {'+=' if r.accumulate else '='}"
        return [head, f"for (int k = 0; k < {r.count}; ++k) {{", *(f"    {line}" for line in loads),
                f"    {target} {text};", "}"]

    def _sum(self, op, c: str) -> list[str]:
        kind = op[0]
        if kind == "matvec":
            _, A, rows, cols, vec, _ = op
            m = _canonical(A)
            n, indptr, data = m.shape[0], self.array("indptr", m.indptr, "int"), self.array("data", m.data, "double")
            idx = self.array("idx", np.asarray(cols, dtype=np.int64)[m.indices], "int")
            r = self.array("rows", rows, "int")
            return [f"/* linear block: out[{r}] += coefficient * A {vec}[cols] (A: {n} rows, {len(m.data)} "
                    f"entries; {idx}: the columns of its entries) */",
                    f"phc_matvec_add({n}, {indptr}, {idx}, {data}, {r}, {vec}, {c}, out);"]
        if kind == "scatter":
            _, pos, data_, _, times_cj = op
            pos_name, data_name = self.array("pos", pos, "int"), self.array("data", data_, "double")
            scale = f"cj * ({c})" if times_cj else c
            return [f"/* a linear block's Jacobian entries ({len(pos)}) */",
                    f"phc_scatter_add({len(pos)}, {pos_name}, {data_name}, {scale}, out);"]
        if kind == "quad":
            _, A, cols, _, index, absolute = op
            n, indptr, indices, data = self.csr(A)
            k = self.array("cols", cols, "int")
            value = f"({c}) * phc_quadratic({n}, {indptr}, {indices}, {data}, {k}, y)"
            return [f"/* a quadratic form x^T A x, x = y[{k}] */",
                    f"out[{index}] += {'fabs(' + value + ')' if absolute else value};"]
        _, A, cols, pos, _ = op  # grad
        n, indptr, indices, data = self.csr(A)
        k, pos_name = self.array("cols", cols, "int"), self.array("pos", pos, "int")
        return [f"/* the gradient of a quadratic dissipation form, x = y[{k}] */",
                f"phc_gradient_add({n}, {indptr}, {indices}, {data}, {k}, y, {c}, {pos_name}, out);"]

    # -- the file -------------------------------------------------------------------------
    _HEADS = {"yyp": "double t, const double *y, const double *yp, const double *p",
              "yyp_cj": "double t, const double *y, const double *yp, const double *p, double cj",
              "y": "double t, const double *y, const double *p"}
    _DOCS = {
        "residual": "Residual F(t, y, yp, p), one entry per equation.",
        "residual_t": "Explicit time derivative dF/dt (consistent initialization).",
        "jacobian": "Data of dF/dy + cj*dF/dyp in compressed-sparse-column order of the pattern (JAC_ROWS, "
                    "JAC_COLS of the NumPy module).",
        "hamiltonian": "Total stored energy H.",
        "energy_scale": "Sum of |terms| of H: the scale of relative energy errors.",
        "powers": "out[0]: power delivered through the external ports, out[1]: power dissipated "
                  "(dH/dt = -out[0] - out[1]).",
        "invariants": "Position-level invariants g(t, y).",
        "velocity_invariants": "Velocity-level constraints.",
        "outputs": "Requested outputs, in the order of OUTPUTS.",
        "events": "Switching functions: out[k] = g_k of SWITCHES[k], then the value of each set-valued sign of "
                  "STICKS while it sticks (the C step loop watches them).",
    }

    def print(self) -> str:
        ir = self.ir
        parts = []
        for f in function_kernels(ir) + [events_kernel(ir)]:  # what each function computes (phc.codegen.kernels)
            args = self._HEADS[f.args]
            labels = _Labels(f.labels)
            if f.returns == "scalar":  # the value returned, computed in a local vector of one entry
                parts.append(self.function(f.name, f"double phc_{f.name}({args})", self._DOCS[f.name], f.kernel,
                                           labels, local_out=1, tail=["return out[0];"]))
            else:  # written into the caller's out (a new vector or a pair in the Python wrapper)
                parts.append(self.function(f.name, f"void phc_{f.name}({args}, double *out)", self._DOCS[f.name],
                                           f.kernel, labels, zero=f.size if f.zero else 0))
        n, npar = len(ir.variables), len(ir.p_symbols)
        sizes = [ABI, n, len(ir.residual), len(ir.jac_rows), npar, len(ir.invariants), len(ir.velocity_invariants),
                 len(ir.outputs)]
        parts.append("void phc_sizes(long long *out)\n{\n    /* " + comment(", ".join(SIZES)) + " */\n"
                     + "".join(f"    out[{k}] = {v};\n" for k, v in enumerate(sizes)) + "}\n")
        return self._header(n, npar) + "\n" + "\n\n".join(self.constants) + "\n\n" + "\n".join(parts)

    def _header(self, n: int, npar: int) -> str:
        ir = self.ir
        lines = [
            f"/* Residual functions of the port-Hamiltonian model `{comment(ir.name)}`, generated by phc "
            f"{comment(__version__)}",
            " * from the same intermediate representation as the NumPy module (the reference back end).",
            " * Do not edit: regenerate with `phc compile`.",
            " *",
            " * The DAE is F(t, y, yp, p) = 0. p is the full parameter vector of the NumPy module's",
            " * full_parameters(base). The Jacobian dF/dy + cj*dF/dyp is returned as data in",
            " * compressed-sparse-column order. Every function is re-entrant (no static mutable state).",
            " *",
            f" * {n} unknowns y[j] (D: differential):",
        ]
        lines += [f" *   y[{j}]  {comment(v)}{'  (D)' if d else ''}" for j, (v, d) in
                  enumerate(zip(ir.variables, ir.differential))]
        lines += [" *", f" * {npar} parameters p[k]:"]
        lines += [f" *   p[{k}]  {comment(name)}" for k, name in enumerate(ir.parameters)]
        lines += [" */", "", "#include <math.h>", "#include <string.h>", "", f"#define PHC_ABI {ABI}", _HELPERS,
                  "/* ---- constant arrays: sparse linear blocks and quadratic forms (CSR) ---------- */"]
        return "\n".join(lines) + "\n"


def c_source(ir: ResidualIR) -> str:
    """The C99 text of the model's functions (see the module docstring).

    Raises
    ------
    CUnsupported
        The model uses something the C back end does not print yet.
    """
    return CPrinter(ir).print()


__all__ = ["ABI", "CPrinter", "CUnsupported", "SIZES", "c_source", "comment", "number", "unsupported"]
