"""A restricted Python → C99 translator for the step logic written once in Python.

The fixed-step methods' step logic (:mod:`phc.simulation.step_logic`) is plain Python that the
Python loop runs with NumPy and numba compiles into the compiled loop. The C back end's step loop
(``phc/codegen/c_runtime/steps.c``) gets the same functions from this module: it reads their
source with :mod:`ast` and prints C, so the logic is written once. Only a small subset of Python
is accepted, the one ``step_logic`` is written in; anything else is refused with
:class:`TranslationError` naming the function and the line, so an edit of ``step_logic`` this
translator cannot follow fails loudly (in ``tests/codegen/test_c_translate.py`` and when the C
step loop is built), never silently.

The subset:

* functions whose arguments have the C types of a signature table
  (:data:`phc.simulation.step_logic.C_SIGNATURES`): ``f`` double, ``i`` int64, ``b`` a truth
  value (C ``int``), ``v`` a vector of ``n`` doubles, ``V`` a matrix of rows of ``n`` doubles
  (row-major; its row count is the extra argument ``<name>_rows``), ``M`` an ``int8`` vector of
  ``n`` (a mask), ``F``/``I`` a double/int64 array indexed by scalars only, ``F3`` a double array
  ``[*, 3]`` and ``V3`` an array ``[*, 3, n]`` (indexed ``a[j, i]``), ``S`` a model function
  ``(t, y, p) -> double`` (C ``phc_scalar_fn``), ``P`` the port powers ``(t, y, yp, p)``
  (``phc_powers_fn``, called as ``powers(...)[k]``), ``ws`` the loop's workspace (passed through
  to the operations);
* local scalars (int64 when every value assigned is an integer expression, ``int`` for truth
  values, else double), local vectors of ``n`` (a C99 array of ``n``, assigned a vector
  expression, ``x.copy()`` or another local vector where neither is written in place, so that a
  copy is what Python's shared name would be), local matrices and buffers (``np.empty((r, n))``,
  ``np.empty(k)``) and tuples of scalars;
* ``for`` over ``range`` (a constant step of ±1), ``while True:`` (left by ``break`` or
  ``return``), ``if``/``elif``/``else``, ``break``,
  ``continue``, ``return`` (of a tuple: the first value is returned, the others written through
  pointers; a vector into the caller's array);
* arithmetic on scalars (Python's true division of integers as a double division, ``%`` of
  integers with Python's sign: the divisor's, ``**`` of a double as C's ``pow``), comparisons
  (one operator), ``and``/``or``/``not`` of truth values, conditional expressions, ``abs``,
  ``min``/``max`` of scalars (Python's choice on ties: the first), ``int``, ``np.ceil``,
  ``math.log10``, ``np.isfinite``, ``np.inf``, integer and float constants of the module (printed
  as literals, a float by its shortest round-trip text);
* whole-vector arithmetic (``+ - * /`` of vectors and scalars, ``np.where``, a comparison of a
  mask), written only into a vector: ``_copy(expression, dst)``, ``_add(dst, vector)``, a local
  vector's assignment, a vector function's ``return``, or an argument (computed into a temporary
  before the statement). Each becomes one loop over the entries in which every entry takes the
  IEEE operations NumPy does, in the same order (the expression's parentheses are kept), so
  results are bit for bit NumPy's; the C is compiled without fused multiply-adds
  (``-ffp-contract=off``);
* calls of other translated functions and of the loop's operations (``_begin``, ``_correct``, …:
  an operations table gives their C name, argument kinds and results).

The module is a little over 800 lines because the translation of a function is one pass over
its syntax tree in :class:`_Function`, whose cases (statements, scalar and vector expressions,
calls) share the function's inferred local types and temporaries and read best together; the
subset above is its specification, and the prelude at the end is the C it relies on.
"""

from __future__ import annotations

import ast
import inspect
from dataclasses import dataclass

from phc.errors import TranslationError

SCALARS = ("b", "i", "f")
_CTYPE = {"b": "int", "i": "int64_t", "f": "double"}
_JOIN = {("b", "b"): "b", ("b", "i"): "i", ("i", "b"): "i", ("i", "i"): "i"}


_PARAMETER = {
    "b": "int {name}", "i": "int64_t {name}", "f": "double {name}",
    "v": "{const}double *{name}", "F": "{const}double *{name}", "F3": "{const}double *{name}",
    "V3": "{const}double *{name}", "V": "{const}double *{name}, int64_t {name}_rows",
    "I": "{const}int64_t *{name}", "M": "const int8_t *{name}",
    "S": "phc_scalar_fn {name}", "P": "phc_powers_fn {name}", "ws": "const struct phc_steps *{name}",
}
"""The C parameter of each kind of argument (``{const}``: ``const`` unless the function writes it)."""


class _Unknown(TranslationError):
    """A name not (yet) known while the locals' kinds are inferred."""


@dataclass(frozen=True)
class Op:
    """A loop operation called from the translated functions: its C name, the kinds of its
    arguments (as in a signature) and of its results (``()`` for none; several: the first is
    returned, the others written through pointers)."""

    c_name: str
    args: tuple
    results: tuple = ()
    writes: tuple = ()  # argument positions it writes (vectors)


@dataclass
class _Fn:
    name: str
    node: ast.FunctionDef
    args: list  # (name, kind)
    results: tuple = ()
    writes: tuple = ()


def _join(a, b):
    if a == b:
        return a
    if (a, b) in _JOIN:
        return _JOIN[(a, b)]
    if a in SCALARS and b in SCALARS:
        return "f"
    raise ValueError(f"{a} and {b}")


class _Function:
    """The translation of one function."""

    def __init__(self, tr: "Translator", fn: _Fn):
        self.tr, self.fn, self.name = tr, fn, fn.name
        self.env = dict(fn.args)
        self.loopvars: set = set()
        self.lines: list = []
        self.counter = 0
        self.nodes = list(ast.walk(fn.node))
        self._writes = None
        self.pre: list = []  # lines the next statement needs first (temporaries)
        self.extra: list = []  # their declarations

    # ---- errors -----------------------------------------------------------------------------
    def refuse(self, node, what, error=TranslationError):
        line = getattr(node, "lineno", self.fn.node.lineno)  # the module's own parse: its lines
        raise error(f"{self.tr.file}:{line}: in {self.name}: {what} (outside the subset "
                               f"phc.codegen.c_translate translates to C)")

    # ---- types ------------------------------------------------------------------------------
    def kind(self, e):
        """The kind of expression e: a scalar kind, 'v' (a vector of n), 'm' (a vector of truth
        values), 'row' ... (rows are 'v')."""
        if isinstance(e, ast.Constant):
            if isinstance(e.value, bool):
                return "b"
            if isinstance(e.value, int):
                return "i"
            if isinstance(e.value, float):
                return "f"
            self.refuse(e, f"the constant {e.value!r}")
        if isinstance(e, ast.Name):
            if e.id in self.env:
                k = self.env[e.id]
                if k in ("v", "vl", "vp"):
                    return "v"
                return k
            if isinstance(self.tr.globals.get(e.id), int) and not isinstance(self.tr.globals.get(e.id), bool):
                return "i"
            if isinstance(self.tr.globals.get(e.id), float):
                return "f"
            self.refuse(e, f"the name {e.id!r} (not an argument, a local or a number constant)", _Unknown)
        if isinstance(e, ast.Attribute):
            if self._is_np(e, "inf"):
                return "f"
            if isinstance(e.value, ast.Attribute) and e.value.attr == "shape":
                return "i"
            self.refuse(e, f"the attribute {ast.unparse(e)!r}")
        if isinstance(e, ast.Subscript):
            if isinstance(e.value, ast.Attribute) and e.value.attr == "shape":
                return "i"
            if isinstance(e.value, ast.Call) and self.env.get(getattr(e.value.func, "id", None)) == "P":
                return "f"  # an entry of the port powers
            base = self.env.get(getattr(e.value, "id", None))
            pair = isinstance(e.slice, ast.Tuple)
            if pair and len(e.slice.elts) != 2:
                self.refuse(e, "an index of more than two dimensions")
            if base in ("F", "v", "vl", "vp", "fb", "tf") and not pair or base == "F3" and pair:
                return "f"
            if base == "I" and not pair:
                return "i"
            if base in ("V", "Vl") and not pair or base == "V3" and pair:
                return "v"
            self.refuse(e, f"the subscript {ast.unparse(e)!r}")
        if isinstance(e, ast.BinOp):
            a, b = self.kind(e.left), self.kind(e.right)
            if "v" in (a, b):
                if isinstance(e.op, ast.Mod):
                    self.refuse(e, "the operator Mod of a vector")
                return "v"
            if a not in SCALARS or b not in SCALARS:
                self.refuse(e, f"arithmetic on {ast.unparse(e)!r}")
            if isinstance(e.op, ast.Div):
                return "f"
            if isinstance(e.op, ast.Pow):
                if "f" not in (a, b):
                    self.refuse(e, "the operator Pow of integers (a double to a power only)")
                return "f"
            if isinstance(e.op, ast.Mod):
                if "f" in (a, b):
                    self.refuse(e, "the operator Mod of doubles (integers only)")
                return "i"
            if isinstance(e.op, (ast.Add, ast.Sub, ast.Mult)):
                return "f" if "f" in (a, b) else "i"
            self.refuse(e, f"the operator {type(e.op).__name__}")
        if isinstance(e, ast.UnaryOp):
            k = self.kind(e.operand)
            if isinstance(e.op, ast.Not):
                return "b"
            if isinstance(e.op, ast.USub):
                return k
            self.refuse(e, f"the operator {type(e.op).__name__}")
        if isinstance(e, ast.BoolOp):
            for v in e.values:
                if self.kind(v) != "b":
                    self.refuse(v, f"{ast.unparse(v)!r} in and/or is not a truth value")
            return "b"
        if isinstance(e, ast.Compare):
            if len(e.ops) != 1:
                self.refuse(e, "a chained comparison")
            a = self.kind(e.left)
            if a in ("M", "v"):
                return "m"
            return "b"
        if isinstance(e, ast.IfExp):
            a, b = self.kind(e.body), self.kind(e.orelse)
            if a not in SCALARS or b not in SCALARS:
                self.refuse(e, "a conditional expression of vectors")
            return _join(a, b)
        if isinstance(e, ast.Call):
            return self.call_kind(e)
        self.refuse(e, f"the expression {type(e).__name__}")

    @staticmethod
    def _is_np(e, attr):
        return isinstance(e, ast.Attribute) and e.attr == attr and isinstance(e.value, ast.Name) and e.value.id == "np"

    @staticmethod
    def _is_math(e, attr):
        return isinstance(e, ast.Attribute) and e.attr == attr and isinstance(e.value, ast.Name) and e.value.id == "math"

    def call_kind(self, e):
        f = e.func
        if isinstance(f, ast.Name):
            if f.id == "abs":
                return self.kind(e.args[0])
            if f.id in ("min", "max"):
                if len(e.args) < 2:
                    self.refuse(e, f"{f.id} of fewer than two scalars")
                kinds = [self.kind(a) for a in e.args]
                if any(k not in SCALARS for k in kinds):
                    self.refuse(e, f"{f.id} of a vector")
                out = kinds[0]
                for k in kinds[1:]:
                    out = _join(out, k)
                return out
            if f.id == "int":
                return "i"
            if f.id in self.tr.functions:
                res = self.tr.functions[f.id].results
                return ("v" if res[0] == "v" else res[0]) if res else "none"
            if f.id in self.tr.ops:
                res = self.tr.ops[f.id].results
                return res[0] if res else "none"
        if self._is_np(f, "ceil"):
            return "f"
        if self._is_math(f, "log10"):
            if self.kind(e.args[0]) not in SCALARS:
                self.refuse(e, "math.log10 of a vector")
            return "f"
        if self._is_np(f, "isfinite"):
            if self.kind(e.args[0]) not in SCALARS:
                self.refuse(e, "np.isfinite of a vector")
            return "b"
        if self._is_np(f, "where"):
            return "v"
        if isinstance(f, ast.Attribute) and f.attr == "copy" and not e.args and self.kind(f.value) == "v":
            return "v"
        if isinstance(f, ast.Name) and self.env.get(f.id) == "S":
            return "f"
        if isinstance(f, ast.Name) and self.env.get(f.id) == "P":
            return "P"
        self.refuse(e, f"the call {ast.unparse(e.func)!r}")

    # ---- expressions ------------------------------------------------------------------------
    def expr(self, e, idx=None):
        """C text of expression e; `idx` the entry index of a vector expression."""
        if isinstance(e, (ast.BinOp, ast.Compare, ast.Call, ast.BoolOp, ast.UnaryOp)):
            self.kind(e)  # refuses what is outside the subset, naming it
        if isinstance(e, ast.Constant):
            if isinstance(e.value, bool):
                return "1" if e.value else "0"
            if isinstance(e.value, int):
                return str(e.value)
            return repr(float(e.value))
        if isinstance(e, ast.Name):
            k = self.env.get(e.id)
            if k is None:
                value = self.tr.globals[e.id]
                return f"{repr(float(value)) if isinstance(value, float) else value} /* {e.id} */"
            if k in ("v", "vl", "vp", "M"):
                if idx is None:
                    self.refuse(e, f"the vector {e.id!r} where a scalar is expected")
                return f"{e.id}[{idx}]"
            return e.id
        if isinstance(e, ast.Attribute):
            if self._is_np(e, "inf"):
                return "INFINITY"
        if isinstance(e, ast.Subscript):
            if isinstance(e.value, ast.Attribute) and e.value.attr == "shape":
                arr = e.value.value.id
                if not (isinstance(e.slice, ast.Constant) and e.slice.value == 0):
                    self.refuse(e, "a shape other than the first dimension")
                if self.env.get(arr) in ("v", "vl"):
                    return "n"
                if self.env.get(arr) != "V":
                    self.refuse(e, "a shape other than a vector's length or a matrix argument's rows")
                return f"{arr}_rows"
            self.kind(e)
            if isinstance(e.value, ast.Call):  # the port powers: computed before the statement
                return f"{self.powers(e.value)}[{self.expr(e.slice)}]"
            name = e.value.id
            k = self.env[name]
            if k in ("V", "Vl", "V3"):
                if idx is None:
                    self.refuse(e, f"the row {ast.unparse(e)!r} where a scalar is expected")
                return f"{name}[{self.row_offset(e)} + {idx}]"
            if isinstance(e.slice, ast.Tuple):  # F3
                a, b = e.slice.elts
                return f"{name}[({self.expr(a)}) * 3 + {self.expr(b)}]"
            i = self.expr(e.slice)
            if self.kind(e.slice) not in ("i", "b"):
                self.refuse(e, "an index that is not an integer")
            if k == "V":
                if idx is None:
                    self.refuse(e, f"the row {ast.unparse(e)!r} where a scalar is expected")
                return f"{name}[({i}) * n + {idx}]"
            if k in ("v", "vl", "vp") and idx is None:
                return f"{name}[{i}]"
            return f"{name}[{i}]"
        if isinstance(e, ast.BinOp):
            a, b = self.expr(e.left, idx), self.expr(e.right, idx)
            if isinstance(e.op, ast.Mod):
                return f"py_mod_i({a}, {b})"
            if isinstance(e.op, ast.Pow):  # Python's float ** number: C's pow (CPython calls it)
                return f"pow({a}, {b})"
            op = {ast.Add: "+", ast.Sub: "-", ast.Mult: "*", ast.Div: "/"}[type(e.op)]
            if isinstance(e.op, ast.Div) and self.kind(e.left) in ("i", "b") and self.kind(e.right) in ("i", "b"):
                a = f"(double)({a})"
            return f"({a} {op} {b})"
        if isinstance(e, ast.UnaryOp):
            if isinstance(e.op, ast.Not):
                return f"!({self.expr(e.operand, idx)})"
            return f"(-{self.expr(e.operand, idx)})"
        if isinstance(e, ast.BoolOp):
            op = " && " if isinstance(e.op, ast.And) else " || "
            return "(" + op.join(self.expr(v, idx) for v in e.values) + ")"
        if isinstance(e, ast.Compare):
            ops = {ast.Lt: "<", ast.LtE: "<=", ast.Gt: ">", ast.GtE: ">=", ast.Eq: "==", ast.NotEq: "!="}
            if type(e.ops[0]) not in ops:
                self.refuse(e, f"the comparison {type(e.ops[0]).__name__}")
            return f"({self.expr(e.left, idx)} {ops[type(e.ops[0])]} {self.expr(e.comparators[0], idx)})"
        if isinstance(e, ast.IfExp):
            return f"({self.expr(e.test, idx)} ? {self.expr(e.body, idx)} : {self.expr(e.orelse, idx)})"
        if isinstance(e, ast.Call):
            f = e.func
            if isinstance(f, ast.Name) and f.id == "abs":
                return f"{'fabs' if self.kind(e.args[0]) == 'f' else 'llabs'}({self.expr(e.args[0])})"
            if isinstance(f, ast.Name) and f.id in ("min", "max"):
                k = self.kind(e)
                out = self.expr(e.args[0])
                for a in e.args[1:]:  # Python's max(a, b, c): the first largest, as max(max(a, b), c)
                    out = f"py_{f.id}_{'f' if k == 'f' else 'i'}({out}, {self.expr(a)})"
                return out
            if isinstance(f, ast.Name) and f.id == "int":
                return f"(int64_t)({self.expr(e.args[0])})"
            if self._is_np(f, "ceil"):
                return f"ceil({self.expr(e.args[0])})"
            if self._is_math(f, "log10"):
                return f"log10({self.expr(e.args[0])})"
            if self._is_np(f, "isfinite"):
                return f"isfinite({self.expr(e.args[0])})"
            if isinstance(f, ast.Attribute) and f.attr == "copy":
                return self.expr(f.value, idx)
            if isinstance(f, ast.Name) and self.env.get(f.id) == "S":
                if idx is not None:
                    self.refuse(e, f"a call of {f.id} in a vector expression")
                return f"{f.id}({', '.join(self.argument(a, k) for a, k in zip(e.args, ('f', 'v', 'F')))})"
            if self._is_np(f, "where"):
                if idx is None:
                    self.refuse(e, "np.where outside a vector expression")
                c, a, b = (self.expr(x, idx) for x in e.args)
                return f"({c} ? {a} : {b})"
            if isinstance(f, ast.Name) and (f.id in self.tr.functions or f.id in self.tr.ops):
                callee = self.tr.functions.get(f.id) or self.tr.ops[f.id]
                if len(callee.results) > 1:
                    self.refuse(e, f"{f.id} returns several values: unpack them into names")
                if callee.results and callee.results[0] == "v":
                    self.refuse(e, f"{f.id} returns a vector: assign it to a local vector first")
                return self.call(e, f.id, [])
        self.refuse(e, f"the expression {ast.unparse(e)!r}")

    def call(self, e, name, outs):
        callee = self.tr.functions.get(name) or self.tr.ops[name]
        c_name = callee.c_name if isinstance(callee, Op) else name
        kinds = [k for _, k in callee.args] if isinstance(callee, _Fn) else list(callee.args)
        if len(e.args) != len(kinds) or e.keywords:
            self.refuse(e, f"{name} called with {len(e.args)} arguments ({len(kinds)} positional expected)")
        args = []
        if any(k in ("v", "V", "M") for k in kinds) or (callee.results and callee.results[0] == "v"):
            args.append("n")
        for a, k in zip(e.args, kinds):
            args.append(self.argument(a, k, name))
        return f"{c_name}({', '.join(args + outs)})"

    def argument(self, a, k, name="a function"):
        """C text of argument `a` to a parameter of kind `k`: a scalar expression, an array's name
        (a matrix with its row count), a row's address, or a vector expression computed into a
        temporary before the statement."""
        if k in SCALARS:
            if self.kind(a) not in SCALARS:
                self.refuse(a, f"a vector where {name} takes a scalar")
            return self.expr(a)
        if isinstance(a, ast.Name):
            return f"{a.id}, {a.id}_rows" if k == "V" else a.id
        if k == "v" and isinstance(a, ast.Subscript) and self.kind(a) == "v":
            return f"{a.value.id} + {self.row_offset(a)}"
        if k == "v" and self.kind(a) == "v":
            tmp = self.fresh("tmp")
            self.extra.append(f"double {tmp}[n];")
            i = self.fresh("i")
            self.pre += [f"for (int64_t {i} = 0; {i} < n; ++{i})", f"    {tmp}[{i}] = {self.expr(a, i)};"]
            return tmp
        self.refuse(a, f"{name} takes an array here: pass a name")

    def row_offset(self, e):
        """The offset of the row `e` (a matrix's ``m[j]``, a three-index array's ``a[j, i]``)."""
        k = self.env[e.value.id]
        if k == "V3":
            if not isinstance(e.slice, ast.Tuple):
                self.refuse(e, "a three-index array indexed by other than two numbers")
            a, b = e.slice.elts
            return f"(({self.expr(a)}) * 3 + {self.expr(b)}) * n"
        return f"({self.expr(e.slice)}) * n"

    def powers(self, call):
        """The port powers' call `call` (a function-pointer argument of kind P) made before the
        statement, into a temporary of two; its name."""
        tmp = self.fresh("pw")
        self.extra.append(f"double {tmp}[2];")
        args = [self.argument(a, k) for a, k in zip(call.args, ("f", "v", "v", "F"))]
        if len(call.args) != 4:
            self.refuse(call, "the port powers called with other than (t, y, yp, p)")
        self.pre.append(f"{call.func.id}({', '.join(args)}, {tmp});")
        return tmp

    # ---- statements -------------------------------------------------------------------------
    def emit(self, depth, text):
        for line in self.pre:
            self.lines.append("    " * depth + line)
        self.pre = []
        self.lines.append("    " * depth + text)

    def fresh(self, base):
        self.counter += 1
        return f"{base}{self.counter}"

    def vector_loop(self, depth, target, e, op="="):
        i = self.fresh("i")
        line = f"{self.target(target, i)} {op} {self.expr(e, i)};"
        self.emit(depth, f"for (int64_t {i} = 0; {i} < n; ++{i})")
        self.emit(depth + 1, line)

    def target(self, t, idx):
        if isinstance(t, ast.Name) and self.env.get(t.id) in ("v", "vl"):
            return f"{t.id}[{idx}]"
        if isinstance(t, ast.Subscript) and self.env.get(t.value.id) in ("V", "Vl", "V3"):
            return f"{t.value.id}[{self.row_offset(t)} + {idx}]"
        self.refuse(t, f"{ast.unparse(t)!r} is not a vector to write into")

    def body(self, stmts, depth):
        for s in stmts:
            self.stmt(s, depth)

    def stmt(self, s, depth):
        if isinstance(s, ast.Expr) and isinstance(s.value, ast.Constant) and isinstance(s.value.value, str):
            return  # a docstring
        if isinstance(s, ast.Pass):
            return
        if isinstance(s, ast.Expr) and isinstance(s.value, ast.Call):
            f = s.value.func
            name = getattr(f, "id", None)
            if name == "_copy":
                src, dst = s.value.args
                return self.vector_loop(depth, dst, src)
            if name == "_add":
                dst, src = s.value.args
                return self.vector_loop(depth, dst, src, "+=")
            if name in self.tr.functions or name in self.tr.ops:
                callee = self.tr.functions.get(name) or self.tr.ops[name]
                outs = [f"&{self.fresh('unused')}" for _ in callee.results[1:]]
                if outs:
                    self.refuse(s, f"the results of {name} are dropped")
                return self.emit(depth, self.call(s.value, name, []) + ";")
            self.refuse(s, f"the call {ast.unparse(f)!r} as a statement")
        if isinstance(s, ast.Assign):
            if len(s.targets) != 1:
                self.refuse(s, "a chained assignment")
            t = s.targets[0]
            if isinstance(t, ast.Tuple):
                return self.unpack(s, t, depth)
            if isinstance(t, ast.Name):
                k = self.env.get(t.id)
                if k in ("vl",):
                    v = s.value
                    if isinstance(v, ast.Call) and getattr(v.func, "id", None) in self.tr.functions:
                        return self.emit(depth, self.call(v, v.func.id, [t.id]) + ";")
                    if isinstance(v, ast.Name) and (t.id in self.writes() or v.id in self.writes()):
                        self.refuse(s, f"{t.id} = {v.id}: a vector named twice, one written in place (write _copy)")
                    return self.vector_loop(depth, t, v)
                if k in ("fb", "Vl"):
                    return  # declared with its length
                if k == "tf":
                    for j, x in enumerate(s.value.elts):
                        self.emit(depth, f"{t.id}[{j}] = {self.expr(x)};")
                    return
                if k in SCALARS:
                    return self.emit(depth, f"{t.id} = {self.expr(s.value)};")
                self.refuse(s, f"the assignment of {t.id}")
            if isinstance(t, ast.Subscript):
                if self.kind(s.value) not in SCALARS:
                    self.refuse(s, "a vector assigned into an entry (write _copy)")
                return self.emit(depth, f"{self.expr(t)} = {self.expr(s.value)};")
            self.refuse(s, "the assignment target")
        if isinstance(s, ast.AugAssign):
            op = {ast.Add: "+=", ast.Sub: "-=", ast.Mult: "*="}.get(type(s.op))
            if op is None:
                self.refuse(s, f"the operator {type(s.op).__name__}=")
            if self.kind(s.value) not in SCALARS:
                self.refuse(s, "a vector in an augmented assignment (write _add)")
            return self.emit(depth, f"{self.expr(s.target)} {op} {self.expr(s.value)};")
        if isinstance(s, ast.If):
            self.emit(depth, f"if ({self.expr(s.test)}) {{")
            self.body(s.body, depth + 1)
            orelse = s.orelse
            while len(orelse) == 1 and isinstance(orelse[0], ast.If):
                test = self.expr(orelse[0].test)
                if self.pre:
                    self.refuse(orelse[0], "an elif condition that needs a temporary (write else: if)")
                self.emit(depth, f"}} else if ({test}) {{")
                self.body(orelse[0].body, depth + 1)
                orelse = orelse[0].orelse
            if orelse:
                self.emit(depth, "} else {")
                self.body(orelse, depth + 1)
            return self.emit(depth, "}")
        if isinstance(s, ast.For):
            return self.for_range(s, depth)
        if isinstance(s, ast.While):
            if not (isinstance(s.test, ast.Constant) and s.test.value is True) or s.orelse:
                self.refuse(s, "the statement While other than `while True:` (left by break or return)")
            self.emit(depth, "for (;;) {")
            self.body(s.body, depth + 1)
            return self.emit(depth, "}")
        if isinstance(s, ast.Break):
            return self.emit(depth, "break;")
        if isinstance(s, ast.Continue):
            return self.emit(depth, "continue;")
        if isinstance(s, ast.Return):
            return self.ret(s, depth)
        self.refuse(s, f"the statement {type(s).__name__}")

    def for_range(self, s, depth):
        it = s.iter
        if not (isinstance(it, ast.Call) and getattr(it.func, "id", None) == "range") or s.orelse:
            self.refuse(s, "a loop other than `for name in range(...)`")
        if not isinstance(s.target, ast.Name):
            self.refuse(s, "a loop variable other than a name")
        a = it.args
        start, stop, step = (ast.Constant(0), a[0], 1) if len(a) == 1 else (a[0], a[1], 1)
        if len(a) == 3:
            st = a[2]
            if isinstance(st, ast.UnaryOp) and isinstance(st.op, ast.USub) and isinstance(st.operand, ast.Constant):
                step = -st.operand.value
            elif isinstance(st, ast.Constant):
                step = st.value
            if step not in (1, -1):
                self.refuse(s, "a range step other than 1 or -1")
        var = s.target.id if s.target.id != "_" else self.fresh("it")
        if self.kind(start) != "i" or self.kind(stop) != "i":
            self.refuse(s, "a range of other than integers")
        stop_name = self.fresh("stop")
        cmp, inc = ("<", "++") if step == 1 else (">", "--")
        self.emit(depth, f"for (int64_t {var} = {self.expr(start)}, {stop_name} = {self.expr(stop)}; "
                         f"{var} {cmp} {stop_name}; {inc}{var}) {{")
        self.body(s.body, depth + 1)
        self.emit(depth, "}")

    def unpack(self, s, t, depth):
        v = s.value
        name = getattr(getattr(v, "func", None), "id", None)
        if not (isinstance(v, ast.Call) and (name in self.tr.functions or name in self.tr.ops)):
            self.refuse(s, "a tuple assigned from other than a call of a translated function or an operation")
        callee = self.tr.functions.get(name) or self.tr.ops[name]
        names = [x.id for x in t.elts]
        if len(names) != len(callee.results):
            self.refuse(s, f"{name} returns {len(callee.results)} values, {len(names)} unpacked")
        outs = [f"&{x}" for x in names[1:]]
        self.emit(depth, f"{names[0]} = {self.call(v, name, outs)};")

    def ret(self, s, depth):
        res = self.fn.results
        v = s.value
        vals = list(v.elts) if isinstance(v, ast.Tuple) else ([] if v is None else [v])
        if len(vals) != len(res):
            self.refuse(s, f"a return of {len(vals)} values where {self.name} returns {len(res)}")
        if res and res[0] == "v":
            v0 = vals[0]
            if isinstance(v0, ast.Call) and getattr(v0.func, "id", None) in self.tr.functions:
                self.emit(depth, self.call(v0, v0.func.id, ["ret"]) + ";")
                return self.emit(depth, "return;")
            i = self.fresh("i")
            line = f"ret[{i}] = {self.expr(vals[0], i)};"
            self.emit(depth, f"for (int64_t {i} = 0; {i} < n; ++{i})")
            self.emit(depth + 1, line)
            return self.emit(depth, "return;")
        for k, (x, kind) in enumerate(zip(vals[1:], res[1:]), 1):
            if kind == "v":
                i = self.fresh("i")
                line = f"result{k}[{i}] = {self.expr(x, i)};"
                self.emit(depth, f"for (int64_t {i} = 0; {i} < n; ++{i})")
                self.emit(depth + 1, line)
            else:
                self.emit(depth, f"*result{k} = {self.expr(x)};")
        self.emit(depth, f"return {self.expr(vals[0])};" if vals else "return;")

    # ---- locals -----------------------------------------------------------------------------
    def infer_locals(self):
        """The kinds of the local names, from their assignments (int64 only when every value is an
        integer expression; a scalar assigned a double anywhere is a double)."""
        node = self.fn.node
        for _ in range(3):
            changed = False
            for s in self.nodes:
                if isinstance(s, ast.For) and isinstance(s.target, ast.Name):
                    if self.env.get(s.target.id) not in (None, "i"):
                        self.refuse(s, f"the loop variable {s.target.id} is also assigned")
                    if s.target.id not in self.env and s.target.id != "_":
                        self.env[s.target.id] = "i"
                        self.loopvars.add(s.target.id)
                        changed = True
                targets = []
                if isinstance(s, ast.Assign) and len(s.targets) == 1:
                    t = s.targets[0]
                    if isinstance(t, ast.Name):
                        targets = [(t.id, s.value, None)]
                    elif isinstance(t, ast.Tuple):
                        name = getattr(getattr(s.value, "func", None), "id", None)
                        callee = self.tr.functions.get(name) or self.tr.ops.get(name)
                        if callee is None:
                            self.refuse(s, "a tuple assigned from other than a call")
                        for x, k in zip(t.elts, callee.results):
                            if not isinstance(x, ast.Name):
                                self.refuse(s, "a tuple target other than names")
                            targets.append((x.id, None, "vp" if k == "v" else k))
                for name, value, known in targets:
                    if name in dict(self.fn.args):
                        if self.fn.args and dict(self.fn.args)[name] in SCALARS:
                            continue
                        self.refuse(s, f"the array argument {name} is assigned")
                    if name in self.loopvars:
                        self.refuse(s, f"the loop variable {name} is assigned")
                    if known is None:
                        if isinstance(value, ast.Call) and self._is_np(value.func, "empty"):
                            known = "Vl" if isinstance(value.args[0], ast.Tuple) else "fb"
                        elif isinstance(value, ast.Tuple):
                            if any(self.kind(x) not in SCALARS for x in value.elts):
                                self.refuse(s, "a tuple of other than scalars")
                            known = "tf"
                        else:
                            try:
                                known = self.kind(value)
                            except _Unknown:
                                continue  # a name not known yet: the next pass
                            if known == "v":
                                known = "vl"
                            elif known not in SCALARS:
                                self.refuse(s, f"{name} assigned {ast.unparse(value)!r}")
                    old = self.env.get(name)
                    new = known if old is None else (known if old == known else None)
                    if new is None:
                        if old in SCALARS and known in SCALARS:
                            new = _join(old, known)
                        else:
                            self.refuse(s, f"{name} is both {old} and {known}")
                    if new != old:
                        self.env[name] = new
                        changed = True
            if not changed:
                break

    def declarations(self):
        args = dict(self.fn.args)
        out = []
        for name, k in self.env.items():
            if name in args or name in self.loopvars:
                continue
            if k in SCALARS:
                out.append(f"{_CTYPE[k]} {name} = 0;")
            elif k == "vl":
                out.append(f"double {name}[n];")
            elif k == "vp":
                out.append(f"double *{name} = NULL;")
            elif k == "tf":
                out.append(f"double {name}[{len(self._value(name).elts)}];")
            elif k == "Vl":
                rows = self.expr(self._value(name).args[0].elts[0])
                out.append(f"double {name}[({rows}) * n];")
                out.append(f"const int64_t {name}_rows = {rows};")
                out.append(f"(void){name}_rows;")
            elif k == "fb":
                size = self._buffer_size(name)
                out.append(f"double {name}[{size} > 0 ? {size} : 1];")
                z = self.fresh("z")
                out.append(f"for (int64_t {z} = 0; {z} < ({size} > 0 ? {size} : 1); ++{z})")  # what a callee leaves
                out.append(f"    {name}[{z}] = 0.0;")
        return out

    def _value(self, name):
        for s in self.nodes:
            if isinstance(s, ast.Assign) and isinstance(s.targets[0], ast.Name) and s.targets[0].id == name:
                return s.value

    def _buffer_size(self, name):
        for s in self.nodes:
            if isinstance(s, ast.Assign) and isinstance(s.targets[0], ast.Name) and s.targets[0].id == name:
                return self.expr(s.value.args[0])

    # ---- the function -----------------------------------------------------------------------
    def signature(self):
        writes = self.writes()
        params = []
        res = self.fn.results
        if any(k in ("v", "V", "M") for _, k in self.fn.args) or (res and res[0] == "v"):
            params.append("int64_t n")
        for name, k in self.fn.args:
            const = "" if name in writes else "const "
            if k not in _PARAMETER:
                raise TranslationError(f"{self.tr.file}:{self.fn.node.lineno}: in {self.name}: the kind {k!r} of "
                                       f"{name} (kinds: {', '.join(_PARAMETER)})")
            params.append(_PARAMETER[k].format(const=const, name=name))
        if res and res[0] == "v":
            params.append("double *ret")
            ret = "void"
        else:
            ret = _CTYPE[res[0]] if res else "void"
            params += [f"double *result{j}" if k == "v" else f"{_CTYPE[k]} *result{j}"
                       for j, k in enumerate(res[1:], 1)]
        return f"static {ret} {self.name}({', '.join(params)})"

    def writes(self):
        """The array arguments the function writes into (the others are const)."""
        if self._writes is not None:
            return self._writes
        out = set()
        for s in self.nodes:
            if isinstance(s, ast.Call) and getattr(s.func, "id", None) in ("_copy", "_add"):
                dst = s.args[1] if s.func.id == "_copy" else s.args[0]
                out.add(getattr(dst, "id", None) or getattr(getattr(dst, "value", None), "id", None))
            if isinstance(s, (ast.Assign, ast.AugAssign)):
                for t in (s.targets if isinstance(s, ast.Assign) else [s.target]):
                    if isinstance(t, ast.Subscript):
                        out.add(t.value.id)
            if isinstance(s, ast.Call) and getattr(s.func, "id", None) in self.tr.functions:
                callee = self.tr.functions[s.func.id]
                for a, w in zip(s.args, callee.args):
                    if w[0] in callee.writes and isinstance(a, ast.Name):
                        out.add(a.id)
            if isinstance(s, ast.Call) and getattr(s.func, "id", None) in self.tr.ops:
                op = self.tr.ops[s.func.id]
                for pos in op.writes:
                    if isinstance(s.args[pos], ast.Name):
                        out.add(s.args[pos].id)
        self._writes = out
        return out

    def translate(self):
        self.infer_locals()
        self.fn.writes = tuple(self.writes())
        self.body(self.fn.node.body, 1)
        decls = ["    " + d for d in self.declarations() + self.extra]
        decls += [f"    (void){name}_rows;" for name, k in self.fn.args if k == "V"]  # not every function reads it
        return "\n".join([self.signature(), "{"] + decls + self.lines + ["}"])


class Translator:
    """Translate functions of one module: ``signatures`` maps each function's name to
    ``(arguments, results)``, its arguments' kinds (one per parameter) and its results' kinds;
    ``ops`` the operations the functions may call (:class:`Op`)."""

    def __init__(self, module, signatures: dict, ops: dict):
        self.module = module
        self.globals = vars(module)
        self.file = inspect.getsourcefile(module)
        self.ops = ops
        self.functions: dict = {}
        self._signatures = signatures

    def translate(self, names) -> str:
        """C text of the functions `names` (in this order: each may call those before it)."""
        out = []
        with open(self.file, encoding="utf-8") as f:
            tree = ast.parse(f.read(), self.file)
        defs = {node.name: node for node in tree.body if isinstance(node, ast.FunctionDef)}
        for name in names:
            node = defs.get(name)
            if node is None or not inspect.isfunction(self.globals.get(name)):
                raise TranslationError(f"{self.file}: {name} is not a function of {self.module.__name__}")
            first = node.lineno
            if name not in self._signatures:
                raise TranslationError(f"{self.file}:{first}: in {name}: no C signature (add one to C_SIGNATURES)")
            args, results = self._signatures[name]
            params = [a.arg for a in node.args.args]
            if len(params) != len(args) or node.args.vararg or node.args.kwonlyargs or node.args.defaults:
                raise TranslationError(f"{self.file}:{first}: in {name}: the parameters {params} do not match "
                                       f"the C signature's {len(args)} kinds")
            record = _Fn(name, node, list(zip(params, args)), tuple(results))
            self.functions[name] = record
            text = _Function(self, record).translate()
            out.append(f"/* {self.module.__name__}.{name} (translated by phc.codegen.c_translate) */\n{text}")
        return "\n\n".join(out) + "\n"


PRELUDE = """\
/* Python's min(a, b) and max(a, b): the second only where it is smaller (larger) */
static inline double py_min_f(double a, double b) { return b < a ? b : a; }
static inline double py_max_f(double a, double b) { return b > a ? b : a; }
static inline int64_t py_min_i(int64_t a, int64_t b) { return b < a ? b : a; }
static inline int64_t py_max_i(int64_t a, int64_t b) { return b > a ? b : a; }
/* Python's a % b of integers: the sign of b (C's % takes a's); b is not 0 (Python raises) */
static inline int64_t py_mod_i(int64_t a, int64_t b) { const int64_t r = a % b; return (r != 0 && ((r < 0) != (b < 0))) ? r + b : r; }
"""
"""What the translated functions need besides ``<math.h>`` and ``<stdint.h>``."""


__all__ = ["Op", "PRELUDE", "TranslationError", "Translator"]
