"""Whitelisting parser for the expression strings in model files.

A model file is *data*: whoever hands us a YAML file must not be able to run
code with it. Expression strings (``m*g*y + 0.5*k*(x - l0)**2``) are therefore
never given to ``eval``/``exec`` nor to ``sympy.sympify``/``parse_expr`` (which
call ``eval``). Instead the text is parsed with ``ast.parse(mode="eval")`` and
the tree is walked against a whitelist of node types, building sympy objects
directly. Anything not on the list -- attribute access, lambdas, strings,
comprehensions, unknown functions, ... -- is an :class:`ExpressionError` that
names the construct and the column where it starts.

Hostile input must not exhaust time or memory either, neither in ``ast.parse``
nor in sympy's automatic evaluation: the text length, node count, nesting depth
and constant exponents are bounded, every constant sub-expression must fit a
double (so ``9**9**9`` or ``sin(exp(exp(exp(9))))`` fail fast instead of making
sympy compute or hang), ``min``/``max`` only fold numbers, and ``ifelse`` may not
appear inside a condition (sympy would solve inequalities to simplify it).
"""

from __future__ import annotations

import ast
import re
import keyword
import cmath
import difflib
import functools
import math
import warnings
from dataclasses import dataclass
from typing import Callable, Mapping

import sympy as sp

from phc.errors import ExpressionError

__all__ = ["CONSTANTS", "FUNCTIONS", "RATE", "ExpressionError", "FunctionSpec", "named_scope",
           "parse_equation", "parse_expression", "validate_syntax"]

MAX_LENGTH = 10_000      # characters of expression text
MAX_NODES = 2_000        # AST nodes
MAX_DEPTH = 100          # nesting levels (a flat chain of + or * counts as one)
MAX_EXPONENT = 64        # |constant exponent|
MAX_DIGITS = 30          # digits of an integer literal


@dataclass(frozen=True)
class FunctionSpec:
    """A whitelisted function: positional arity range and the sympy builder."""

    min_args: int
    max_args: int | None      # None: no upper bound
    build: Callable[..., sp.Basic]


_WORD = re.compile(r"(?<![A-Za-z0-9_.])[A-Za-z_][A-Za-z0-9_]*(?:\.[A-Za-z_][A-Za-z0-9_]*)*")


def _keyword_as_name(body: str):
    """``(keyword, column)`` of a Python keyword used as (part of) a name in `body` —
    ``lambda*2``, ``osc.in.f`` — or None. Expressions are read with Python's grammar, where
    such a name is a syntax error; the message should say why. (Operators and constructs
    that are keywords, `and`, `if … else`, `lambda x: …`, have messages of their own.)"""
    constructs = {"and", "or", "not", "if", "else", "in", "is"}
    for match in _WORD.finditer(body):
        parts = match.group(0).split(".")
        for k, part in enumerate(parts):
            if not keyword.iskeyword(part):
                continue
            if len(parts) == 1:
                rest = body[match.end():].lstrip()
                if part in constructs or (part == "lambda" and (rest[:1] == ":" or rest[:1].isalpha()
                                                                or rest[:1] == "_")):
                    continue
            return part, match.start() + sum(len(q) + 1 for q in parts[:k])
    return None
    return None


def _minmax(f: Callable, args: tuple) -> sp.Expr:
    # sympy simplifies symbolic Min/Max with pairwise assumption queries, which is
    # quadratic-or-worse (seconds for a few dozen arguments): only fold numbers.
    return f(*args, evaluate=all(a.is_Number for a in args))


def _one(f: Callable) -> FunctionSpec:
    return FunctionSpec(1, 1, f)


# sign, heaviside, abs, min, max and ifelse are not smooth. Their sympy forms are kept here;
# the lower pass (phc.codegen.nonsmooth) differentiates them almost everywhere and turns every
# condition on t or the model's variables into a switch that a run locates (a breakpoint or a
# state event, docs/events.md). heaviside(0) = 1; sign(0) = 0, or any value in [-1, 1] where a
# `F*sign(v)` term can stick.
FUNCTIONS: dict[str, FunctionSpec] = {
    "sin": _one(sp.sin), "cos": _one(sp.cos), "tan": _one(sp.tan),
    "asin": _one(sp.asin), "acos": _one(sp.acos), "atan": _one(sp.atan),
    "atan2": FunctionSpec(2, 2, sp.atan2),
    "sinh": _one(sp.sinh), "cosh": _one(sp.cosh), "tanh": _one(sp.tanh),
    "exp": _one(sp.exp), "log": _one(sp.log), "sqrt": _one(sp.sqrt),
    "abs": _one(sp.Abs), "sign": _one(sp.sign),
    "min": FunctionSpec(2, None, lambda *a: _minmax(sp.Min, a)),
    "max": FunctionSpec(2, None, lambda *a: _minmax(sp.Max, a)),
    "heaviside": _one(lambda x: sp.Heaviside(x, 1)),
    "ifelse": FunctionSpec(3, 3, lambda c, a, b: sp.Piecewise((a, c), (b, True))),
}
CONSTANTS: dict[str, sp.Expr] = {"pi": sp.pi}
RATE = "der"
"""``der(x)``: the rate of the state ``x`` (outputs only: :func:`parse_expression` with `rates`)."""

_ARITH = {ast.Add: "+", ast.Sub: "-", ast.Mult: "*", ast.Div: "/", ast.Pow: "**"}
_FORBIDDEN_OPS = {ast.FloorDiv: "//", ast.Mod: "%", ast.MatMult: "@", ast.LShift: "<<",
                  ast.RShift: ">>", ast.BitOr: "|", ast.BitXor: "^", ast.BitAnd: "&"}
_CHAIN = {ast.Add: "sum", ast.Sub: "sum", ast.Mult: "product", ast.Div: "product"}
_RELATIONS = {ast.Lt: ("<", sp.Lt), ast.LtE: ("<=", sp.Le), ast.Gt: (">", sp.Gt),
              ast.GtE: (">=", sp.Ge), ast.Eq: ("==", sp.Eq), ast.NotEq: ("!=", sp.Ne)}
_CONDITIONS = (ast.Compare, ast.BoolOp)
_UNDEFINED = (sp.zoo, sp.oo, -sp.oo, sp.nan)
_REJECTED = {
    ast.Lambda: "lambda expressions", ast.ListComp: "comprehensions", ast.SetComp: "comprehensions",
    ast.DictComp: "comprehensions", ast.GeneratorExp: "generator expressions",
    ast.JoinedStr: "f-strings", ast.FormattedValue: "f-strings",
    ast.NamedExpr: "assignment expressions (`:=`)", ast.Starred: "starred expressions (`*x`)",
    ast.Dict: "dict displays", ast.Set: "set displays", ast.List: "list displays",
    ast.Tuple: "tuples", ast.IfExp: "conditional expressions (`a if c else b`)",
    ast.Await: "`await` expressions", ast.Yield: "`yield` expressions",
    ast.YieldFrom: "`yield` expressions", ast.Slice: "slices",
}


def _suggest(word: str, candidates, what: str = "known names") -> str | None:
    """A did-you-mean hint, else a short list of what exists, else None."""
    candidates = sorted(set(candidates))
    close = [c for c in candidates if c.lower() == word.lower()]
    close = close or difflib.get_close_matches(word, candidates, n=1)
    if close:
        return f"did you mean `{close[0]}`?"
    if not candidates:
        return None
    more = f" (and {len(candidates) - 8} more)" if len(candidates) > 8 else ""
    return f"{what}: " + ", ".join(f"`{c}`" for c in candidates[:8]) + more


_PHC_NAMES = frozenset({"t", "H", *CONSTANTS, *FUNCTIONS})
"""Names phc defines (time, the energy, π, the functions): never offered for a name the
user forgot to define."""


def _listed(names: list[str], limit: int = 8) -> str:
    more = f" (and {len(names) - limit} more)" if len(names) > limit else ""
    return ", ".join(f"`{n}`" for n in names[:limit]) + more


def _unknown_name_hint(word: str, names) -> str:
    """The hint of an unknown name: every close name the model defines (not phc's `t`, `pi`,
    ...; for `body.x` none of another kind such as the momentum `body.p`,
    :mod:`phc.frontend.state_hints`), and for a plain name where a new one is defined (`parameters:`)."""
    from phc.frontend.state_hints import word_kind

    candidates = sorted({n for n in names if n not in _PHC_NAMES})
    if "." in word:
        want = word_kind(word.rpartition(".")[2])
        candidates = [c for c in candidates if want is None or word_kind(c.rpartition(".")[2]) in (want, None)]
    close = [c for c in candidates if c.lower() == word.lower()]
    close = close or difflib.get_close_matches(word, candidates, n=5, cutoff=0.6)
    mean = ""
    if close:
        quoted = [f"`{c}`" for c in close]
        mean = f"did you mean {quoted[0] if len(quoted) == 1 else ', '.join(quoted[:-1]) + ' or ' + quoted[-1]}?"
    if "." not in word:
        if mean:
            return f"{mean} Or add it under `parameters:`"
        return "add it under `parameters:`" + (f"; defined here: {_listed(candidates)}" if candidates else "")
    return mean or (f"known names: {_listed(candidates)}" if candidates else "nothing of that name is defined")


def _to_complex(value: sp.Basic) -> complex:
    """`complex(value)`, with overflow mapped to infinity."""
    try:
        return complex(value)
    except OverflowError:
        return complex(math.inf)


def _is_cond(node: ast.AST) -> bool:
    return isinstance(node, _CONDITIONS) or (isinstance(node, ast.UnaryOp) and isinstance(node.op, ast.Not))


def _literal(value: object, col: int) -> sp.Expr:
    """Turn an int/float literal into a sympy number; everything else is an error."""
    if isinstance(value, bool) or value is None or value is Ellipsis:
        raise ExpressionError(f"`{value!r}` is not allowed in an expression", col)
    if isinstance(value, int):
        if abs(value) >= 10 ** MAX_DIGITS:
            raise ExpressionError(f"integer literal has more than {MAX_DIGITS} digits", col)
        return sp.Integer(value)
    if isinstance(value, float):
        if not math.isfinite(value):
            raise ExpressionError("number is not finite", col)
        return sp.Float(value)
    kind = {str: "string literals", bytes: "bytes literals", complex: "complex numbers"}
    raise ExpressionError(f"{kind.get(type(value), type(value).__name__ + ' values')} are not allowed", col)


class _Converter:
    """Walks a parsed tree, checking every node and building the sympy result.

    `names` is None in syntax-only mode: every name then becomes a fresh Symbol.
    """

    def __init__(self, text: str, names: Mapping[str, object] | None, rates: Mapping[str, object] | None = None):
        self.text, self.names, self.rates = text, names, rates
        self._bytes = None if text.isascii() else text.encode("utf-8")
        self._approx: dict[sp.Basic, complex | None] = {}

    # -- positions and errors ------------------------------------------------
    def col(self, node: ast.AST, end: bool = False) -> int:
        col = node.end_col_offset if end else node.col_offset
        if self._bytes is not None:   # ast offsets are UTF-8 byte offsets
            col = len(self._bytes[:col].decode("utf-8", errors="ignore"))
        return col

    def fail(self, message: str, node: ast.AST, hint: str | None = None) -> None:
        raise ExpressionError(message, self.col(node), hint)

    def op_col(self, node: ast.BinOp) -> int:
        """Column of the operator symbol between the operands of `node`."""
        start, stop = self.col(node.left, end=True), self.col(node.right)
        symbol = _ARITH.get(type(node.op)) or _FORBIDDEN_OPS.get(type(node.op), "")
        found = self.text.find(symbol, start, stop) if symbol else -1
        return found if found >= 0 else self.col(node)

    def build(self, node: ast.AST, func: Callable, *args) -> sp.Basic:
        """Call a sympy constructor, turning sympy's complaints into ExpressionErrors."""
        try:
            result = func(*args)
        except (TypeError, ValueError, ArithmeticError, NotImplementedError) as exc:
            raise ExpressionError(f"cannot build expression: {exc}", self.col(node)) from None
        if result in _UNDEFINED:
            self.fail("expression is undefined or infinite here", node)
        value = self.approx(result)
        if value is not None and not cmath.isfinite(value):
            self.fail("value is too large (it overflows double precision)", node)
        return result

    def approx(self, expr: sp.Basic) -> complex | None:
        """Double-precision value of a constant sub-expression, None if it has symbols.

        Every constant built so far is checked to fit a double, so sympy's own
        numeric evaluation (which assumption queries trigger) stays cheap; without
        this, ``sin(exp(exp(exp(9))))`` makes sympy hang or overflow. Values are
        memoized and computed from the arguments' approximations, not re-evaluated.
        """
        if expr in self._approx:
            return self._approx[expr]
        value = None
        if isinstance(expr, sp.Piecewise):   # bounded by its largest branch
            values = [self.approx(branch) for branch, _ in expr.args]
            value = None if None in values else max(values, key=abs)
        elif not isinstance(expr, sp.Expr):
            pass
        elif not expr.args:
            value = _to_complex(expr.evalf(17)) if expr.is_number else None
        else:
            args = [self.approx(arg) for arg in expr.args]
            if None not in args:
                numbers = [sp.Float(a.real) if not a.imag else sp.Float(a.real) + sp.Float(a.imag) * sp.I
                           for a in args]
                try:
                    value = _to_complex(expr.func(*numbers))
                except (TypeError, ValueError, ArithmeticError, NotImplementedError):
                    value = None
        self._approx[expr] = value
        return value

    def check_depth(self, tree: ast.Expression) -> None:
        """Reject trees nested deeper than MAX_DEPTH (iteratively; flat +/* chains count once)."""
        stack = [(tree.body, 1)]
        while stack:
            node, depth = stack.pop()
            if depth > MAX_DEPTH:
                self.fail("expression is nested too deeply", node)
            for child in ast.iter_child_nodes(node):
                flat = (isinstance(node, ast.BinOp) and child is node.left and isinstance(child, ast.BinOp)
                        and _CHAIN.get(type(child.op), 0) == _CHAIN.get(type(node.op), 1))
                if isinstance(child, ast.expr):
                    stack.append((child, depth if flat else depth + 1))

    # -- dispatch --------------------------------------------------------------
    def visit(self, node: ast.AST) -> sp.Expr:
        method = getattr(self, "visit_" + type(node).__name__, None)
        if method is None:
            self.reject(node)
        return method(node)

    def reject(self, node: ast.AST) -> None:
        if isinstance(node, ast.Compare):
            symbol = _RELATIONS.get(type(node.ops[0]), (type(node.ops[0]).__name__,))[0]
            self.fail(f"comparison `{symbol}` is only allowed in the first argument of `ifelse`", node,
                      "write e.g. `ifelse(x < 0, a, b)`; an equation uses a single `=`")
        if _is_cond(node):
            op = {ast.And: "and", ast.Or: "or"}.get(type(getattr(node, "op", None)), "not")
            self.fail(f"boolean operator `{op}` is only allowed in the first argument of `ifelse`", node)
        what = _REJECTED.get(type(node), f"{type(node).__name__} expressions")
        hint = "use `ifelse(c, a, b)`" if isinstance(node, ast.IfExp) else None
        self.fail(f"{what} are not allowed", node, hint)

    def visit_Constant(self, node: ast.Constant) -> sp.Expr:
        return _literal(node.value, self.col(node))

    # -- names -----------------------------------------------------------------
    def dotted(self, node: ast.AST) -> str | None:
        """`a.b.c` for an Attribute chain rooted at a Name, None for other roots."""
        parts = []
        while isinstance(node, ast.Attribute):
            if node.attr.startswith("_"):
                col = self.col(node, end=True) - len(node.attr)
                raise ExpressionError("attribute access is not allowed", col)
            parts.append(node.attr)
            node = node.value
        if not isinstance(node, ast.Name):
            return None
        return ".".join([node.id, *reversed(parts)])

    def lookup(self, name: str, node: ast.AST) -> object:
        if self.names is None:
            return CONSTANTS.get(name) or sp.Symbol(name)
        if name in self.names:
            return self.names[name]
        if name in CONSTANTS:
            return CONSTANTS[name]
        if name in FUNCTIONS:
            self.fail(f"`{name}` is a function; call it like `{name}(x)`", node)
        self.fail(f"unknown name `{name}`", node, _unknown_name_hint(name, self.names))

    def visit_Name(self, node: ast.AST) -> sp.Expr:
        name = self.dotted(node)
        if name is None:   # attribute on a non-name, e.g. `(x + 1).real`
            self.visit(node.value)
            raise ExpressionError("attribute access is not allowed", self.col(node, end=True) - len(node.attr))
        value = self.lookup(name, node)
        if isinstance(value, (list, tuple, sp.MatrixBase)):
            self.fail(f"`{name}` is a vector of length {len(value)}; index it like `{name}[0]`", node)
        if isinstance(value, bool) or not isinstance(value, (sp.Basic, int, float)):
            raise TypeError(f"names[{name!r}] must be a sympy expression or a sequence of them, "
                            f"not {type(value).__name__}")
        return value if isinstance(value, sp.Basic) else _literal(value, self.col(node))

    visit_Attribute = visit_Name

    def visit_Subscript(self, node: ast.Subscript) -> sp.Expr:
        index = node.slice
        if isinstance(index, ast.Slice):
            self.fail("slices are not allowed", index)
        sign = 1
        if isinstance(index, ast.UnaryOp) and isinstance(index.op, (ast.USub, ast.UAdd)):
            sign = -1 if isinstance(index.op, ast.USub) else 1
            index = index.operand
        if not (isinstance(index, ast.Constant) and type(index.value) is int):
            self.fail("index must be an integer literal, like `p[0]`", node.slice)
        i = sign * index.value
        name = self.dotted(node.value) if isinstance(node.value, (ast.Name, ast.Attribute)) else None
        if name is None:
            self.fail("indexing is only allowed on vector names, like `p[0]`", node)
        if self.names is None:
            return sp.Symbol(f"{name}[{i}]")
        value = self.lookup(name, node.value)
        if not isinstance(value, (list, tuple, sp.MatrixBase)):
            self.fail(f"`{name}` is not a vector and cannot be indexed", node)
        if not -len(value) <= i < len(value):
            self.fail(f"index {i} is out of range for `{name}` (length {len(value)})", node.slice)
        item = value[i]
        return item if isinstance(item, sp.Basic) else _literal(item, self.col(node))

    # -- arithmetic ------------------------------------------------------------
    def visit_UnaryOp(self, node: ast.UnaryOp) -> sp.Expr:
        if isinstance(node.op, ast.Not):
            self.reject(node)
        if isinstance(node.op, ast.Invert):
            self.fail("operator `~` is not allowed", node)
        operand = self.visit(node.operand)
        return operand if isinstance(node.op, ast.UAdd) else self.build(node, sp.Mul, sp.Integer(-1), operand)

    def visit_BinOp(self, node: ast.BinOp) -> sp.Expr:
        kind = _CHAIN.get(type(node.op))
        if kind is None:
            if isinstance(node.op, ast.Pow):
                return self.power(node)
            symbol = _FORBIDDEN_OPS.get(type(node.op), type(node.op).__name__)
            hint = "use `**` for powers" if symbol == "^" else None
            raise ExpressionError(f"operator `{symbol}` is not allowed", self.op_col(node), hint)
        chain = []   # flatten the left-nested chain iteratively: a + b - c + ...
        while isinstance(node, ast.BinOp) and _CHAIN.get(type(node.op)) == kind:
            chain.append(node)
            node = node.left
        result = self.visit(node)
        for link in reversed(chain):
            rhs = self.visit(link.right)
            if isinstance(link.op, ast.Sub):
                rhs = self.build(link.right, sp.Mul, sp.Integer(-1), rhs)
            elif isinstance(link.op, ast.Div):
                if rhs.is_Number and rhs.is_zero:
                    raise ExpressionError("division by zero", self.op_col(link))
                rhs = self.checked_pow(link.right, rhs, sp.Integer(-1), link.right)
            result = self.build(link, sp.Add if kind == "sum" else sp.Mul, result, rhs)
        return result

    def power(self, node: ast.BinOp) -> sp.Expr:
        return self.checked_pow(node, self.visit(node.left), self.visit(node.right), node.right)

    def checked_pow(self, node: ast.AST, base: sp.Expr, exponent: sp.Expr, exp_node: ast.AST) -> sp.Expr:
        """Build ``base**exponent`` unless the exponent is a constant beyond MAX_EXPONENT."""
        size = self.approx(exponent)
        if size is not None and not abs(size) <= MAX_EXPONENT:
            self.fail(f"exponent {exponent} is too large (at most {MAX_EXPONENT})", exp_node)
        return self.build(node, sp.Pow, base, exponent)

    # -- functions and conditions ---------------------------------------------
    def visit_Call(self, node: ast.Call) -> sp.Expr:
        func = node.func
        if not isinstance(func, ast.Name):
            name = self.dotted(func) if isinstance(func, ast.Attribute) else None
            if name is not None:
                self.fail(f"unknown function `{name}`", func, _suggest(name, FUNCTIONS, "functions"))
            self.visit(func.value if isinstance(func, ast.Attribute) else func)
            self.fail("only the built-in functions can be called, by name", func)
        if func.id == RATE and func.id not in FUNCTIONS:
            return self.rate(node)
        spec = FUNCTIONS.get(func.id)
        if spec is None:
            self.fail(f"unknown function `{func.id}`", func, _suggest(func.id, FUNCTIONS, "functions"))
        if node.keywords:
            self.fail("keyword arguments are not allowed", node.keywords[0])
        for arg in node.args:
            if isinstance(arg, ast.Starred):
                self.fail("starred arguments (`*x`) are not allowed", arg)
        n = len(node.args)
        if n < spec.min_args or (spec.max_args is not None and n > spec.max_args):
            want = (f"{spec.min_args} or more" if spec.max_args is None else
                    str(spec.min_args) if spec.min_args == spec.max_args else f"{spec.min_args} to {spec.max_args}")
            self.fail(f"`{func.id}` takes {want} argument{'s' if want != '1' else ''} (got {n})", node)
        if func.id == "ifelse":
            args = [self.condition(node.args[0]), *map(self.visit, node.args[1:])]
        else:
            args = [self.visit(arg) for arg in node.args]
        return self.build(node, spec.build, *args)

    def rate(self, node: ast.Call) -> sp.Expr:
        """``der(x)``: the rate ẋ of a state, where the caller allows rates (outputs)."""
        if self.rates is None:
            self.fail(f"`{RATE}(...)`, the rate of a state, can be used in outputs only", node.func)
        if len(node.args) != 1 or node.keywords:
            self.fail(f"`{RATE}` takes one state, like `{RATE}(mass.p)`", node)
        arg = node.args[0]
        if not isinstance(arg, (ast.Name, ast.Attribute, ast.Subscript)):
            self.fail(f"`{RATE}` takes the name of a state, like `{RATE}(mass.p)`; write the rate of an expression "
                      "as a sum of rates", arg)
        inner = _Converter(self.text, self.rates)
        inner._bytes = self._bytes
        try:
            return inner.visit(arg)
        except ExpressionError as err:
            if not err.message.startswith("unknown name"):
                raise
        name = self.dotted(arg.value if isinstance(arg, ast.Subscript) else arg) or ""
        known = self.names is not None and (name in self.names or name in CONSTANTS)
        what = "is not a state" if known else "is not a known name"
        self.fail(f"`{RATE}({name})`: `{name}` {what}; `{RATE}` takes a state, whose rate is part of the solution",
                  arg, _suggest(name, self.rates, "states"))

    def condition(self, node: ast.AST) -> sp.Basic:
        """A comparison (chains allowed) possibly combined with and/or/not."""
        if isinstance(node, ast.BoolOp):
            parts = [self.condition(v) for v in node.values]
            return self.build(node, sp.And if isinstance(node.op, ast.And) else sp.Or, *parts)
        if isinstance(node, ast.UnaryOp) and isinstance(node.op, ast.Not):
            return self.build(node, sp.Not, self.condition(node.operand))
        if not isinstance(node, ast.Compare):
            self.fail("expected a condition such as `x < 0` (comparisons combined with and/or/not)", node)
        relations, left = [], self.visit(node.left)
        for op, comparator in zip(node.ops, node.comparators):
            if type(op) not in _RELATIONS:
                symbol = {ast.Is: "is", ast.IsNot: "is not", ast.In: "in", ast.NotIn: "not in"}[type(op)]
                self.fail(f"operator `{symbol}` is not allowed", comparator)
            right = self.visit(comparator)
            if left.has(sp.Piecewise) or right.has(sp.Piecewise):
                # sympy rewrites such conditions by solving inequalities: exponential time
                self.fail("`ifelse` cannot be used inside a condition", node)
            relations.append(self.build(node, _RELATIONS[type(op)][1], left, right))
            left = right
        return relations[0] if len(relations) == 1 else self.build(node, sp.And, *relations)


@functools.lru_cache(maxsize=4096)
def _parse_tree(text: str) -> tuple[ast.Expression, str, int]:
    """Check limits and parse; return the tree, the parsed text and its offset in `text`.
    Cached by text (the trees are only read): a model of 10⁴ springs writes `k` 10⁴ times."""
    if len(text) > MAX_LENGTH:
        raise ExpressionError(f"expression is too long ({len(text)} characters, at most {MAX_LENGTH})")
    body = text.lstrip()
    offset = len(text) - len(body)
    if not body.strip():
        raise ExpressionError("empty expression", len(text))
    if "#" in body:
        raise ExpressionError("comments are not allowed in expressions", offset + body.index("#"))
    body = body.replace("\r", " ").replace("\n", " ")   # newlines are plain whitespace
    try:
        with warnings.catch_warnings():   # e.g. SyntaxWarning "invalid decimal literal"
            warnings.simplefilter("ignore")
            tree = ast.parse(body, mode="eval")
    except SyntaxError as exc:
        col = offset + min(max((exc.offset or 1) - 1, 0), len(body))
        if "too many nested parentheses" in str(exc.msg):
            raise ExpressionError("expression is nested too deeply", col) from None
        named = _keyword_as_name(body)
        if named is not None:
            raise ExpressionError(f"`{named[0]}` is a keyword of the expression syntax and cannot be used as a "
                                  "name in an expression; rename what is called so", offset + named[1]) from None
        detail = "" if exc.msg == "invalid syntax" else f": {exc.msg}"
        raise ExpressionError(f"invalid syntax{detail}", col) from None
    except (RecursionError, MemoryError):
        raise ExpressionError("expression is nested too deeply", offset) from None
    except ValueError as exc:   # e.g. null bytes on some Python versions
        raise ExpressionError(f"invalid syntax: {exc}", offset) from None
    count = sum(1 for _ in ast.walk(tree))
    if count > MAX_NODES:
        raise ExpressionError(f"expression is too complex ({count} syntax nodes, at most {MAX_NODES})", offset)
    return tree, body, offset


def _convert(text: object, names: Mapping[str, object] | None, allow_relational: bool,
             rates: Mapping[str, object] | None = None) -> sp.Basic:
    if isinstance(text, (int, float)) and not isinstance(text, bool):
        return _literal(text, 0)
    if not isinstance(text, str):
        raise ExpressionError(f"expected an expression (text or number), got {type(text).__name__}")
    tree, body, offset = _parse_tree(text)
    try:
        converter = _Converter(body, names, rates)
        converter.check_depth(tree)
        if allow_relational and _is_cond(tree.body):
            result = converter.condition(tree.body)
        else:
            result = converter.visit(tree.body)
        if result.has(*_UNDEFINED):
            raise ExpressionError("expression is undefined or infinite (division by zero?)", 0)
    except ExpressionError as err:
        raise err.shifted(offset) from None
    except RecursionError:
        raise ExpressionError("expression is nested too deeply", offset) from None
    return result


def named_scope(pairs) -> dict:
    """A scope of an expression from ``(name, value)`` pairs: ``rod.w[3]`` entries become one
    vector ``rod.w`` (a list in index order), other names stay as they are."""
    scope: dict = {}
    vectors: dict[str, dict[int, sp.Expr]] = {}
    for name, value in pairs:
        if name.endswith("]"):
            base, idx = name[:-1].rsplit("[", 1)
            vectors.setdefault(base, {})[int(idx)] = value
        else:
            scope[name] = value
    for base, items in vectors.items():
        scope[base] = [items[i] for i in sorted(items)]
    return scope


def parse_expression(text: str | int | float, names: Mapping[str, object], *,
                     allow_relational: bool = False, rates: Mapping[str, object] | None = None) -> sp.Expr:
    """Parse an expression string (or a plain number) into a sympy expression.

    Parameters
    ----------
    text : str, int or float
        The expression, e.g. ``"m*g*y + 0.5*k*(x - l0)**2"``. Numbers are
        converted directly (floats must be finite).
    names : Mapping[str, object]
        Identifiers in scope: a (possibly dotted, ``"crank.theta"``) name maps to
        a sympy expression, or to a list/tuple/Matrix of them that the text
        must index with an integer literal (``p[0]``, ``p[-1]``). Names shadow
        :data:`CONSTANTS`.
    allow_relational : bool, optional
        Also accept a top-level condition (comparison, ``and``/``or``/``not``).
        Otherwise conditions are only allowed as the first argument of ``ifelse``.
    rates : Mapping[str, object], optional
        The states' rates by state name (as in `names`): ``der(x)`` is then ``rates["x"]``
        (outputs). Without it, ``der`` is refused with a located error.

    Returns
    -------
    sympy.Expr
        The expression (a sympy Boolean for a top-level condition).

    Raises
    ------
    ExpressionError
        For syntax errors, constructs outside the whitelist, unknown names or
        functions, wrong arities, and values or sizes beyond the limits.
    """
    return _convert(text, names, allow_relational, rates)


def _split_equation(text: str) -> int | None:
    """Index of the single top-level `=` of `text`, or None if there is none."""
    found, depth = [], 0
    for i, ch in enumerate(text):
        if ch in "([{":
            depth += 1
        elif ch in ")]}":
            depth -= 1
        elif (ch == "=" and depth == 0 and (i == 0 or text[i - 1] not in "=<>!:")
              and text[i + 1:i + 2] != "="):
            found.append(i)
    if len(found) > 1:
        raise ExpressionError("an equation must contain a single `=`", found[1])
    return found[0] if found else None


def parse_equation(text: str, names: Mapping[str, object]) -> sp.Expr:
    """Parse ``"lhs = rhs"`` into the residual ``lhs - rhs``.

    Parameters
    ----------
    text : str
        An equation with one top-level ``=`` (not part of ``==``, ``<=``,
        ``>=``, ``!=``). Text without ``=`` is read as ``"text = 0"``; a plain
        number is accepted likewise.
    names : Mapping[str, object]
        Identifiers in scope, as for :func:`parse_expression`.

    Returns
    -------
    sympy.Expr
        ``lhs - rhs``.

    Raises
    ------
    ExpressionError
        As :func:`parse_expression`; columns refer to the whole equation text.
    """
    if not isinstance(text, str):
        return parse_expression(text, names)
    if len(text) > MAX_LENGTH:
        raise ExpressionError(f"expression is too long ({len(text)} characters, at most {MAX_LENGTH})")
    eq = _split_equation(text)
    if eq is None:
        return parse_expression(text, names)
    lhs = parse_expression(text[:eq], names)
    try:
        rhs = parse_expression(text[eq + 1:], names)
    except ExpressionError as err:
        raise err.shifted(eq + 1) from None
    return sp.Add(lhs, sp.Mul(sp.Integer(-1), rhs))


def validate_syntax(text: str, *, allow_relational: bool = False) -> sp.Basic:
    """Check an expression against the whitelist without resolving names.

    Every identifier (``x``, ``a.b``, ``p[2]``) is accepted as a free symbol;
    everything else is checked as in :func:`parse_expression` (node types,
    functions and arities, literals, limits). Returns the expression, so its
    ``free_symbols`` are the names it reads (``a.b``, ``p[2]`` one symbol each).

    Parameters
    ----------
    text : str
        The expression text.
    allow_relational : bool, optional
        Accept a top-level condition, as in :func:`parse_expression`.

    Returns
    -------
    sympy.Basic
        The expression, every name a free symbol.

    Raises
    ------
    ExpressionError
        If the text is not a valid, whitelisted expression.
    """
    return _convert(text, None, allow_relational)
