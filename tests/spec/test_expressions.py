"""Tests for :mod:`phc.spec.expressions`, the eval-free whitelisting expression parser."""

import ast
import builtins
import cmath
import string

import pytest
import sympy as sp
import sympy.parsing.sympy_parser
from hypothesis import given, settings
from hypothesis import strategies as st

from phc.spec import expressions
from phc.spec.expressions import (
    CONSTANTS,
    FUNCTIONS,
    ExpressionError,
    parse_equation,
    parse_expression,
    validate_syntax,
)

x, y, z, m, g, k, l0, theta, t, r = sp.symbols("x y z m g k l0 theta t r")
NAMES = {
    "x": x, "y": y, "z": z, "m": m, "g": g, "k": k, "l0": l0, "theta": theta, "t": t, "r": r,
    "crank.theta": theta, "crank.arm.len": l0,
    "p": [x, y, z], "body.q": (x, y), "M": sp.Matrix([m, k]),
}


def same(a, b) -> bool:
    return a == b or sp.simplify(a - b) == 0


# -- valid input -----------------------------------------------------------------------

@pytest.mark.parametrize("text, expected", [
    ("x + 2*y", x + 2 * y),
    ("m*g*y + 0.5*k*(x - l0)**2", m * g * y + sp.Float(0.5) * k * (x - l0) ** 2),
    ("1 + 2*3**2", sp.Integer(19)),
    ("-x**2", -(x ** 2)),
    ("(-x)**2", x ** 2),
    ("2**-1", sp.Rational(1, 2)),
    ("x**y**2", x ** (y ** 2)),
    ("x - y - z", x - y - z),
    ("x / y / z", x / (y * z)),
    ("+x - -y", x + y),
    ("1/2", sp.Rational(1, 2)),
    ("2/3*x", sp.Rational(2, 3) * x),
    ("x**(1/2)", sp.sqrt(x)),
    ("2**(3*4)", sp.Integer(4096)),
    ("x**64", x ** 64),
    ("0x10 + 1_000", sp.Integer(1016)),
    ("sin(theta)**2 + cos(theta)**2", sp.Integer(1)),
    ("tan(x) + asin(x) + acos(x) + atan(x)", sp.tan(x) + sp.asin(x) + sp.acos(x) + sp.atan(x)),
    ("atan2(y, x)", sp.atan2(y, x)),
    ("sinh(x) + cosh(x) + tanh(x)", sp.sinh(x) + sp.cosh(x) + sp.tanh(x)),
    ("exp(log(x)) + sqrt(y)", x + sp.sqrt(y)),
    ("abs(x) * sign(y)", sp.Abs(x) * sp.sign(y)),
    ("min(x, y) + max(x, y, z)", sp.Min(x, y) + sp.Max(x, y, z)),
    ("heaviside(x)", sp.Heaviside(x, 1)),
    ("r*cos(theta)", r * sp.cos(theta)),
    ("crank.theta + crank.arm.len", theta + l0),
    ("crank . theta", theta),
    ("p[0] + p[-1] + body.q[1]", x + z + y),
    ("M[1]", k),
    ("pi", sp.pi),
    ("2*pi*t", 2 * sp.pi * t),
    ("  x\n  + y", x + y),
    ("(x\r\n+ y)", x + y),
])
def test_valid_expressions(text, expected):
    result = parse_expression(text, NAMES)
    assert isinstance(result, sp.Basic)
    assert same(result, expected), (result, expected)


def test_rationals_are_exact_and_floats_are_floats():
    assert parse_expression("1/2", {}) == sp.Rational(1, 2)
    assert parse_expression("1/3 + 1/6", {}) == sp.Rational(1, 2)
    assert isinstance(parse_expression("0.5", {}), sp.Float)
    assert parse_expression(3, {}) == sp.Integer(3) and isinstance(parse_expression(3, {}), sp.Integer)
    assert parse_expression(2.5, {}) == sp.Float(2.5)


def test_ifelse_builds_piecewise_with_chained_comparison():
    result = parse_expression("ifelse(0 <= x < 1 and not y == 2 or z != 0, x, -x)", NAMES)
    cond = sp.Or(sp.And(sp.Le(0, x), sp.Lt(x, 1), sp.Not(sp.Eq(y, 2))), sp.Ne(z, 0))
    assert result == sp.Piecewise((x, cond), (-x, True))
    assert parse_expression("ifelse(x > 0, 1, 2)", NAMES) == sp.Piecewise((1, x > 0), (2, True))
    assert parse_expression("ifelse(1 < 2, x, y)", NAMES) == x


def test_relational_top_level_only_when_allowed():
    assert parse_expression("x < y", NAMES, allow_relational=True) == sp.Lt(x, y)
    assert parse_expression("x < 1 and y >= 2", NAMES, allow_relational=True) == sp.And(x < 1, y >= 2)
    with pytest.raises(ExpressionError, match="^comparison `<` is only allowed"):
        parse_expression("x < y", NAMES)
    with pytest.raises(ExpressionError, match="^comparison `<` is only allowed"):
        parse_expression("(x < y) + 1", NAMES, allow_relational=True)
    with pytest.raises(ExpressionError, match="^boolean operator `and`"):
        parse_expression("sin(x and y)", NAMES)


def test_names_shadow_constants():
    assert parse_expression("pi + 1", {"pi": x}) == x + 1
    assert CONSTANTS["pi"] is sp.pi
    assert set(FUNCTIONS) == set("sin cos tan asin acos atan atan2 sinh cosh tanh exp log sqrt "
                                 "abs sign min max heaviside ifelse".split())


@pytest.mark.parametrize("text, expected", [
    ("x = y", x - y),
    ("m*g = k*(x - l0)", m * g - k * (x - l0)),
    ("x + y", x + y),
    ("ifelse(x <= y, x, y) = 0", sp.Piecewise((x, x <= y), (y, True))),
    ("  x==x  ", None),
])
def test_parse_equation(text, expected):
    if expected is None:
        with pytest.raises(ExpressionError, match="^comparison `==`"):
            parse_equation(text, NAMES)
        return
    assert same(parse_equation(text, NAMES), expected)


def test_parse_equation_errors_use_columns_of_the_whole_text():
    with pytest.raises(ExpressionError) as info:
        parse_equation("x = y + thetta", NAMES)
    assert info.value.col == 8 and info.value.hint.startswith("did you mean `theta`?")
    with pytest.raises(ExpressionError, match="single `=`") as info:
        parse_equation("x = y = z", NAMES)
    assert info.value.col == 6
    with pytest.raises(ExpressionError, match="^empty expression"):
        parse_equation("x = ", NAMES)


def test_validate_syntax_checks_shape_but_not_names():
    validate_syntax("anything.dotted[3] + other * sin(q)")
    validate_syntax("a < b", allow_relational=True)
    for bad in ["open(1)", "x.__class__", "x**100", "lambda: 1", "'s'", "a < b", "x +"]:
        with pytest.raises(ExpressionError):
            validate_syntax(bad)


# -- errors, messages and columns -----------------------------------------------------------

HOSTILE = [
    ("__import__('os').system('echo pwned')", "unknown function `__import__`"),
    ("().__class__.__bases__", "attribute access is not allowed"),
    ("x.__dict__", "attribute access is not allowed"),
    ("(x + 1).real", "attribute access is not allowed"),
    ("lambda: 1", "lambda expressions are not allowed"),
    ("[x for x in y]", "comprehensions are not allowed"),
    ("(x for x in y)", "generator expressions are not allowed"),
    ("open('/etc/passwd')", "unknown function `open`"),
    ("getattr(x, 'a')", "unknown function `getattr`"),
    ("x.y(1)", "unknown function `x.y`"),
    ("(lambda: 1)()", "lambda expressions are not allowed"),
    ('f"{x}"', "f-strings are not allowed"),
    ("'abc'", "string literals are not allowed"),
    ("b'abc'", "bytes literals are not allowed"),
    ("(y := 1)", "assignment expressions"),
    ("*x", "invalid syntax"),
    ("sin(*p)", "starred arguments"),
    ("9**9**9", "exponent 387420489 is too large (at most 64)"),
    ("2**10000", "exponent 10000 is too large (at most 64)"),
    ("x**1000", "exponent 1000 is too large (at most 64)"),
    ("x**-65", "exponent -65 is too large"),
    ("x**(pi*30)", "exponent 30*pi is too large"),
    ("(2**64)**64", "value is too large"),
    ("1e300**64", "value is too large"),
    ("1e200 * 1e200", "value is too large"),
    ("exp(1000.0)", "value is too large"),
    ("exp(690) * exp(690)", "value is too large"),
    ("sin(exp(exp(exp(9)))) + 1.0", "value is too large"),
    ("1/sin(exp(exp(exp(9))))", "value is too large"),
    ("x**sin(exp(exp(exp(9))))", "value is too large"),
    ("ifelse(ifelse(x < 0, x, y) < 0, 1, 2)", "`ifelse` cannot be used inside a condition"),
    ("1e999", "number is not finite"),
    ("1" * 31, "integer literal has more than 30 digits"),
    ("1j", "complex numbers are not allowed"),
    ("True", "`True` is not allowed"),
    ("None", "`None` is not allowed"),
    ("...", "`Ellipsis` is not allowed"),
    ("x if y else z", "conditional expressions (`a if c else b`) are not allowed"),
    ("x // 2", "operator `//` is not allowed"),
    ("x % 2", "operator `%` is not allowed"),
    ("x @ y", "operator `@` is not allowed"),
    ("x ^ 2", "operator `^` is not allowed"),
    ("x << 2", "operator `<<` is not allowed"),
    ("~x", "operator `~` is not allowed"),
    ("x[1:2]", "slices are not allowed"),
    ("p[y]", "index must be an integer literal"),
    ("x[y]", "index must be an integer literal"),
    ("p[1, 2]", "index must be an integer literal"),
    ("x[0]", "`x` is not a vector"),
    ("(x + y)[0]", "indexing is only allowed on vector names"),
    ("p[3]", "index 3 is out of range for `p` (length 3)"),
    ("p[-4]", "index -4 is out of range"),
    ("p + 1", "`p` is a vector of length 3; index it like `p[0]`"),
    ("[x, y]", "list displays are not allowed"),
    ("(x, y)", "tuples are not allowed"),
    ("{x: y}", "dict displays are not allowed"),
    ("{x}", "set displays are not allowed"),
    ("await x", "`await` expressions are not allowed"),
    ("(yield x)", "`yield` expressions are not allowed"),
    ("sin(x=1)", "keyword arguments are not allowed"),
    ("sin(x, y)", "`sin` takes 1 argument (got 2)"),
    ("atan2(x)", "`atan2` takes 2 arguments (got 1)"),
    ("min(x)", "`min` takes 2 or more arguments (got 1)"),
    ("ifelse(x, 1, 2)", "expected a condition"),
    ("ifelse(x is y, 1, 2)", "operator `is` is not allowed"),
    ("sin + 1", "`sin` is a function"),
    ("x < 1", "comparison `<` is only allowed in the first argument of `ifelse`"),
    ("not x", "boolean operator `not`"),
    ("x or y", "boolean operator `or`"),
    ("1/0", "division by zero"),
    ("log(0)", "expression is undefined or infinite"),
    ("x # comment", "comments are not allowed"),
    ("x +* y", "invalid syntax"),
    ("(x", "invalid syntax"),
    ("x\0", "invalid syntax"),
    ("   ", "empty expression"),
    ("", "empty expression"),
    ("(" * 500 + "x" + ")" * 500, "expression is nested too deeply"),
    ("-" * 150 + "x", "expression is nested too deeply"),
    ("-" * 5000 + "x", "expression is nested too deeply"),
    ("x" + "+x" * 1500, "expression is too complex"),
    ("x" * 20000, "expression is too long (20000 characters, at most 10000)"),
]


@pytest.mark.parametrize("text, message", HOSTILE, ids=[text[:30] for text, _ in HOSTILE])
def test_rejected_expressions_name_the_construct(text, message):
    with pytest.raises(ExpressionError) as info:
        parse_expression(text, NAMES)
    assert info.value.message.startswith(message), info.value.message
    assert 0 <= info.value.col <= len(text)


@pytest.mark.parametrize("text, col", [
    ("x // 2", 2),
    ("x.__dict__", 2),
    ("().__class__", 3),
    ("9**9**9", 3),
    ("x + thetta", 4),
    ("θ + thetta", 4),      # columns count characters, not UTF-8 bytes
    ("x +* y", 3),
    ("   x +* y", 6),      # leading whitespace is accounted for
    ("sin(x) + open(1)", 9),
    ("1 + p[7]", 6),
    ("x + y if z else 0", 0),
    ("x + 'a'", 4),
])
def test_error_columns(text, col):
    with pytest.raises(ExpressionError) as info:
        parse_expression(text, {**NAMES, "θ": theta})
    assert info.value.col == col, info.value


def test_unknown_name_hints():
    with pytest.raises(ExpressionError) as info:
        parse_expression("thetta", NAMES)
    assert info.value.message == "unknown name `thetta`"
    assert info.value.hint == "did you mean `theta`? Or add it under `parameters:`"
    assert "did you mean" in str(info.value)
    with pytest.raises(ExpressionError) as info:
        parse_expression("crank.thetaa", NAMES)
    assert info.value.hint == "did you mean `crank.theta`?"
    with pytest.raises(ExpressionError) as info:
        parse_expression("qqq", {"a": x, "b": y})
    assert info.value.hint == "add it under `parameters:`; defined here: `a`, `b`"
    with pytest.raises(ExpressionError) as info:
        parse_expression("qqq", {f"v{i}": x for i in range(20)})
    assert info.value.hint.startswith("add it under `parameters:`; defined here: `v0`, `v1`")
    assert info.value.hint.endswith("(and 12 more)")
    with pytest.raises(ExpressionError) as info:
        parse_expression("sinn(x)", NAMES)
    assert info.value.message == "unknown function `sinn`" and info.value.hint == "did you mean `sin`?"
    with pytest.raises(ExpressionError) as info:
        parse_expression("Max(x, y)", NAMES)
    assert info.value.hint == "did you mean `max`?"
    with pytest.raises(ExpressionError) as info:
        parse_expression("x if y else z", NAMES)
    assert info.value.hint == "use `ifelse(c, a, b)`"


@pytest.mark.parametrize("value", [float("inf"), float("nan"), True, None, [1, 2], 10 ** 40])
def test_non_text_values(value):
    with pytest.raises(ExpressionError):
        parse_expression(value, NAMES)


def test_absurd_powers_fail_fast(monkeypatch):
    """Each bomb is refused at the first sub-expression beyond the limits, counted rather than timed:
    sympy builds at most one object per syntax node, is never asked for a power beyond
    MAX_EXPONENT, never gets an operand that overflows a double, and never gets an `ifelse`
    (Piecewise) inside a relation (it would solve inequalities: exponential time)."""
    converter = expressions._Converter
    relations = tuple(rel for _, rel in expressions._RELATIONS.values())
    built = []   # every sympy constructor call; checked before sympy runs, so a regression fails, not hangs
    real_build = converter.build

    def checked_build(self, node, func, *args):
        built.append(func)
        values = [self.approx(a) for a in args]
        assert all(v is None or cmath.isfinite(v) for v in values), f"operand beyond a double: {func}{args}"
        if func is sp.Pow and values[1] is not None:
            assert abs(values[1]) <= expressions.MAX_EXPONENT, f"exponent beyond the limit: {args}"
        if func in relations:
            assert not any(a.has(sp.Piecewise) for a in args), f"ifelse inside a condition: {func}"
        return real_build(self, node, func, *args)

    monkeypatch.setattr(converter, "build", checked_build)
    bombs = ["9**9**9", "9**9**9**9", "2**10000", "((2**64)**64)**64", "(1e300**64)**64", "10**10**10",
             "sin(exp(exp(exp(9)))) + 1.0", "heaviside(sin(exp(exp(exp(exp(9))))))",
             "ifelse(" + " * ".join(f"ifelse(x < {i}, x, y)" for i in range(30)) + " < 0, 1, 2)"]
    for text in bombs:
        built.clear()
        with pytest.raises(ExpressionError):
            parse_expression(text, NAMES)
        nodes = sum(1 for _ in ast.walk(ast.parse(text, mode="eval")))
        assert len(built) <= nodes, (text, len(built), nodes)


# -- nothing is ever executed ---------------------------------------------------------------

def test_nothing_is_evaluated(monkeypatch, tmp_path):
    def forbidden(*args, **kwargs):
        raise AssertionError("string evaluation must never be used")

    monkeypatch.setattr(sp, "sympify", forbidden)
    monkeypatch.setattr(sp, "S", forbidden)
    monkeypatch.setattr(sympy.parsing.sympy_parser, "parse_expr", forbidden)
    monkeypatch.setattr(builtins, "eval", forbidden)
    monkeypatch.setattr(builtins, "exec", forbidden)
    marker = tmp_path / "pwned"
    valid = ["m*g*y + 0.5*k*(x - l0)**2", "ifelse(x < 1, sin(x), 1/2)", "p[-1] + crank.theta", "pi*2**0.5"]
    for text in valid:
        assert isinstance(parse_expression(text, NAMES), sp.Basic)
    assert parse_equation("x = 1/2", NAMES) == x - sp.Rational(1, 2)
    hostile = [text for text, _ in HOSTILE] + [
        f"__import__('os').system('touch {marker}')",
        f"open('{marker}', 'w')",
        f"().__class__.__base__.__subclasses__()[0]('{marker}')",
    ]
    for text in hostile:
        with pytest.raises(ExpressionError):
            parse_expression(text, NAMES)
        with pytest.raises(ExpressionError):
            parse_equation(text, NAMES)
    assert not marker.exists()


# -- fuzzing -------------------------------------------------------------------------------

ALPHABET = string.ascii_letters[:26] + string.digits + " +-*/().,<>=!_[]%@^&|~:'\"#e"
FUZZ_NAMES = {"x": x, "y": y, "e": z, "p": [x, y], "a.b": theta}


def _never_crashes(text):
    try:
        result = parse_expression(text, FUZZ_NAMES)
    except ExpressionError as err:
        assert isinstance(err.message, str) and isinstance(err.col, int)
        assert 0 <= err.col <= len(text)
    else:
        assert isinstance(result, sp.Expr)
    try:
        parse_equation(text, FUZZ_NAMES)
        validate_syntax(text)
    except ExpressionError:
        pass


@settings(max_examples=300, deadline=None)
@given(st.text(alphabet=ALPHABET, max_size=60))
def test_fuzz_random_text(text):
    _never_crashes(text)


TOKENS = ["x", "y", "e", "p", "a.b", "p[0]", "p[-3]", "pi", "0", "1", "2", "9", "0.5", "1e300", "64",
          "+", "-", "*", "/", "**", "(", ")", ",", " < ", " == ", " and ", "not ", "=",
          "sin(", "log(", "sqrt(", "exp(", "atan2(", "min(", "heaviside(", "ifelse(", "tan("]


@settings(max_examples=300, deadline=None)
@given(st.lists(st.sampled_from(TOKENS), max_size=25).map("".join))
def test_fuzz_token_soup(text):
    _never_crashes(text)


@pytest.mark.parametrize("text, word, col", [("Tru*class", "class", 4), ("osc.in.f*2", "in", 4),
                                             ("lambda*2", "lambda", 0), ("2 + def.x", "def", 4)])
def test_a_keyword_used_as_a_name_is_named_in_the_error(text, word, col):
    """A parameter, component or port named like a keyword of the syntax (`lambda`, `in`)
    cannot appear in an expression: the error says so instead of 'invalid syntax'."""
    with pytest.raises(ExpressionError) as info:
        parse_expression(text, {})
    assert f"`{word}` is a keyword of the expression syntax" in str(info.value)
    assert info.value.col == col
