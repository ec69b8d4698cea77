"""The order of a sum's terms in generated code (phc.codegen.terms) is sympy's, without its
dense monomials: compared with ``Add.as_ordered_terms`` on sums of every kind of term the
printers see, and a long sum never asks sympy for the dense form."""

from __future__ import annotations

import random

import pytest
import sympy as sp

from phc.codegen.printer import _Printer
from phc.codegen.terms import ordered_terms

X = sp.symbols("x0:12")
Y = sp.Symbol("y", positive=True)


def _factor(rng: random.Random):
    x = rng.choice(X)
    kind = rng.randrange(9)
    if kind == 0:
        return x ** rng.choice([-3, -2, -1, 2, 3])
    if kind == 1:
        return x ** sp.Rational(rng.choice([1, -1, 3]), rng.choice([2, 3]))
    if kind == 2:
        return sp.sin(x)
    if kind == 3:
        return sp.cos(rng.choice(X)) ** rng.choice([1, 2, -1])
    if kind == 4:
        return x ** Y  # a symbolic exponent
    if kind == 5:
        return sp.exp(x) * sp.sqrt(2)  # a number that is not a Rational
    if kind == 6:
        return sp.Abs(x - rng.choice(X))
    return x


def _term(rng: random.Random):
    coeff = rng.choice([1, -1, 2, sp.Rational(-3, 7), sp.Float(0.125), -sp.Float(2.5), sp.I, 1 - 2 * sp.I, sp.pi])
    factors = [_factor(rng) for _ in range(rng.randrange(0, 4))]
    return sp.Mul(coeff, *factors)


@pytest.mark.parametrize("seed", range(60))
def test_same_order_as_sympy(seed):
    rng = random.Random(seed)
    expr = sp.Add(*[_term(rng) for _ in range(rng.randrange(1, 40))])
    assert ordered_terms(expr) == expr.as_ordered_terms()


@pytest.mark.parametrize("expr", [
    X[0] + X[1] + X[2],
    3 + X[0] - 2 * X[1],
    1 - 2 * X[0],  # the two-term special case of as_ordered_terms
    X[0] / X[1] + X[1] / X[0] + 1 / (X[0] * X[1]) + X[0] * X[1],
    X[0] ** 2 + X[0] + X[0] ** -1 + X[0] ** sp.Rational(1, 2) + 5,
    sp.Add(*[(i % 3 - 1) * X[i % 12] ** (i % 4 - 1) * X[(i * 5) % 12] for i in range(50)]),
    sp.Symbol("a") + sp.Symbol("A") + sp.Symbol("_c1") + sp.Symbol("_c10") + sp.Symbol("_c2"),
    sp.Add(*[sp.Float(i) * X[i % 12] * X[(i + 1) % 12] ** 2 for i in range(40)]),
])
def test_same_order_on_chosen_sums(expr):
    assert ordered_terms(expr) == expr.as_ordered_terms()


def test_non_commutative_and_non_sums_left_to_sympy():
    a, b = sp.symbols("a b", commutative=False)
    expr = a * b + b * a + X[0] + 1
    assert ordered_terms(expr) == expr.as_ordered_terms()
    assert ordered_terms(X[0] * X[1]) == [X[0] * X[1]]


class _SympyOrder(_Printer):
    """The module printer with sympy's own ordering of terms."""

    def _as_ordered_terms(self, expr, order=None):
        return expr.as_ordered_terms()


def test_long_sum_prints_without_dense_monomials(monkeypatch):
    """A sum of n terms in n symbols: sympy's as_terms builds n tuples of n exponents; the
    printer must not call it (nor as_ordered_terms, which does), and prints the same text."""
    symbols = sp.symbols("s0:3000")
    expr = sp.Add(*[(i + 1) * s ** 2 / 2 for i, s in enumerate(symbols)])
    names = {s: s.name for s in symbols}
    expected = _SympyOrder(names).doprint(expr)

    def refuse(self, *args, **kwargs):
        raise AssertionError("dense monomials built")

    monkeypatch.setattr(sp.Add, "as_terms", refuse)
    monkeypatch.setattr(sp.Add, "as_ordered_terms", refuse)
    assert _Printer(names).doprint(expr) == expected
