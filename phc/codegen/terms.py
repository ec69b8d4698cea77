"""The order in which a generated module writes the terms of a sum, in O(n log n).

Every back end writes a sum's terms in the order sympy's printers do (``Add.as_ordered_terms``
with the default lexicographic order), so the NumPy module, the numba kernels and the C text
add the same numbers in the same order and agree to the bit. sympy computes that order from
*dense* monomials: each term becomes a tuple with one exponent per distinct factor of the whole
sum. A sum of n terms in n different symbols (the stored energy or a power balance of a network
of n components) therefore costs n² time and memory — 1.5 GB and half a minute for the sums of a
chain of 10⁴ components.

:func:`ordered_terms` returns exactly what ``Add.as_ordered_terms()`` returns, from *sparse*
monomials. The terms, their coefficients and the factor bases are those of ``Expr.as_terms``; the
sort key compares two sparse monomials as sympy compares the negated dense ones (the first factor,
in sympy's sorted order of the bases, whose exponents differ decides, a missing factor counting as
exponent 0), then the coefficients as sympy does. Python's sort is stable, so equal keys keep the
order of ``Add.make_args``, as in sympy. Sums outside what this reproduces (non-commutative factors,
``Order`` terms, the two-term special case of ``as_ordered_terms``) are left to sympy.
"""

from __future__ import annotations

import sympy as sp
from sympy.core.exprtools import decompose_power
from sympy.core.sorting import default_sort_key

_END = (1,)
"""Key of the end of a sparse monomial: the exponent 0 of every factor after its last one."""


def ordered_terms(expr) -> list:
    """The terms of `expr` in the order of ``expr.as_ordered_terms()`` (see the module)."""
    if not isinstance(expr, sp.Add) or len(expr.args) <= 2:
        return expr.as_ordered_terms()
    terms = []
    bases = set()
    for term in sp.Add.make_args(expr):
        if term.is_Order:
            return expr.as_ordered_terms()
        # as in sympy's Expr.as_terms: the numeric coefficient as a complex number, then the
        # commutative factors as base -> exponent (a later factor of the same base wins)
        coeff, rest = term.as_coeff_Mul()
        coeff = complex(coeff)
        powers = {}
        if rest is not sp.S.One:
            for factor in sp.Mul.make_args(rest):
                if factor.is_number:
                    try:
                        coeff *= complex(factor)
                    except (TypeError, ValueError):
                        pass
                    else:
                        continue
                if not factor.is_commutative:
                    return expr.as_ordered_terms()
                base, exponent = decompose_power(factor)
                powers[base] = exponent
        bases.update(powers)
        terms.append((term, coeff, powers))
    index = {base: i for i, base in enumerate(sorted(bases, key=default_sort_key))}

    def key(item):
        _, coeff, powers = item
        monomial = []
        for i, exponent in sorted((index[b], e) for b, e in powers.items()):
            if exponent != 0:
                monomial.append(_entry(i, -exponent))
        monomial.append(_END)
        re, im = coeff.real, coeff.imag
        return tuple(monomial), ((bool(im), im), (re, im))

    return [term for term, _, _ in sorted(terms, key=key)]


def _entry(i: int, value) -> tuple:
    """Key of a nonzero negated exponent `value` at factor `i`, such that comparing the tuples
    of entries (ended by :data:`_END`) compares the dense tuples of negated exponents: at the
    first factor where two monomials differ, a negative value sorts before the 0 of a monomial
    without that factor, and a positive one after it."""
    return (0, i, value) if value < 0 else (2, -i, value)
