"""``expr.xreplace(rule)`` of many expressions that differ only in their symbols' names,
with one sympy rebuild per shape (issue 38).

Assembly substitutes, in every row of a model, each port variable by what it is joined
to (:func:`phc.ir.assemble._assemble`): ``der(k2.x) - k2.a.f + k2.b.f`` becomes
``der(k2.x) - m1.p/m + m2.p/m``, and the next spring of a chain the same with the names
of the next cell. sympy rebuilds each row through its constructors (flattening and
sorting the arguments of every sum and product, in Python): about 0.1 ms a row, a second
for a chain of 10⁴ components. :class:`AlikeReplacer` rebuilds the first row of a shape
with sympy and every later row of that shape from it, by putting the new symbols in the
old ones' places: sums and products from their arguments in the order the first one's
have (``_from_args``), which is sympy's canonical order as long as the new names are in
the same relative order as the old ones (sympy orders arguments by their class, their
numbers and their symbols' names, :meth:`sympy.core.basic.Basic.compare`); when they are
not, the row is rebuilt by sympy, and its rebuild becomes the plan of its shape for rows
whose names sort as its own do (:data:`MAX_ORDERS`). The principle, and the check, are
those of the renamed lowerings of :class:`phc.frontend.lowering.SharedLowerings`.

The shape of a row is its tree with each symbol replaced by its place among the row's
symbols (first occurrence first) and, where the rule replaces it, by the shape of what
replaces it: two rows of one shape are the same expression up to an injective renaming
of symbols, so sympy would build the same result up to that renaming (equal symbols in
one row, which could cancel, are one place, so a row where two of them coincide has
another shape). Only symbols made as ``Symbol(name, real=True)`` (as phc makes its
variables and parameters, :func:`phc.ir.dae.real_symbol`) are places; a row holding any
other symbol (other assumptions, a Dummy) is rebuilt by sympy. A row in which the rule
replaces nothing (an energy term in states) is returned as it is, as ``xreplace`` returns it.
"""

from __future__ import annotations

from typing import Mapping

import sympy as sp

_REAL = sp.Symbol("x", real=True).assumptions0
_EXPR_NEW = sp.Expr.__new__
_SLOT, _ASSOC, _POW, _FUNC = range(4)


class _Opaque(Exception):
    """Something in the row that :class:`AlikeReplacer` does not rename (then sympy rebuilds it)."""


def unevaluated_pow(base, exp, commutative):
    """``sp.Pow(base, exp, evaluate=False)`` of sympy objects, as sympy makes it (a rebuild's power:
    here and in the lowering templates, :mod:`phc.frontend.lowering`)."""
    obj = _EXPR_NEW(sp.Pow, base, exp)
    obj = sp.Pow._exec_constructor_postprocessors(obj)
    if type(obj) is sp.Pow:
        obj.is_commutative = commutative
    return obj


def _order(places: list) -> tuple:
    """The places' indices with their names in sorted order (sympy's order of symbols)."""
    return tuple(sorted(range(len(places)), key=lambda i: places[i].name))


MAX_ORDERS = 4096
"""Plans kept for rows whose names sort otherwise than their shape's first row's (one per
shape and order of names): the rows of a grid's masses name their neighbours `h9_10`,
`m9_9`, `v10_9`..., whose order changes as the indices gain digits (the grid of
bench_components.py had a third of its rows rebuilt by sympy without them)."""


class _Plan:
    """The rebuild of one shape's result from the symbols in their places."""

    def __init__(self, result, places: list) -> None:
        slot_of = {s: i for i, s in enumerate(places)}
        self.steps: list = []  # (kind, data) in the order they are computed; values appended after the places
        memo: dict = {}
        n_places = len(places)

        def visit(e):
            """(index of `e`'s value, whether it depends on the places) — its value is at
            ``vals[index]`` once the steps ran (constants: index < 0, ``~index`` into consts)."""
            hit = memo.get(id(e))
            if hit is not None:
                return hit
            if type(e) is sp.Symbol and e in slot_of:
                out = (slot_of[e], True)
            elif not e.args:
                out = (self._const(e), False)
            else:
                args = [visit(a) for a in e.args]
                if not any(dep for _, dep in args):
                    out = (self._const(e), False)
                else:
                    t = type(e)
                    kind = _ASSOC if t is sp.Add or t is sp.Mul else _POW if t is sp.Pow else _FUNC
                    self.steps.append((kind, t if kind != _FUNC else e.func, tuple(i for i, _ in args),
                                       e.is_commutative))
                    out = (n_places + len(self.steps) - 1, True)
            memo[id(e)] = out
            return out

        self.consts: list = []
        self.root = visit(result)[0]
        # the places' names in sympy's order: a new row is built only if its names sort alike
        self.order = _order(places)

    def _const(self, e) -> int:
        self.consts.append(e)
        return -len(self.consts)

    def build(self, places: list):
        names = [places[i].name for i in self.order]
        if any(a >= b for a, b in zip(names, names[1:])):
            return None  # renaming would change sympy's order: rebuilt by sympy
        vals = list(places)
        consts = self.consts

        def get(i):
            return vals[i] if i >= 0 else consts[-i - 1]

        for kind, cls, args, comm in self.steps:
            items = [get(i) for i in args]
            if kind == _ASSOC:
                vals.append(cls._from_args(items, comm))
            elif kind == _POW:
                vals.append(unevaluated_pow(items[0], items[1], comm))
            else:
                vals.append(cls(*items))
        return get(self.root)


class AlikeReplacer:
    """``expr.xreplace(rule)`` for many `expr` alike but for their symbols' names (see the
    module's docstring). The rule maps symbols to expressions; it may differ from call to
    call (the shape holds what it replaces). Results equal sympy's, argument order included."""

    def __init__(self, rule: Mapping | None = None) -> None:
        self.rule = rule  # None: each call gives its own
        self.plans: dict = {}
        self.ordered: dict = {}  # (shape, order of its names) -> plan, for names sorting otherwise (MAX_ORDERS)
        self._plain: dict = {}  # symbol -> whether it is Symbol(name, real=True), renamed
        self.rebuilt = 0  # rows rebuilt by sympy (first of their shape, or refused): for tests
        self.renamed = 0  # rows built from their shape's plan
        self.unchanged = 0  # rows the rule does not touch, returned as they are (as xreplace does)

    def __call__(self, expr, rule: Mapping | None = None):
        """``expr.xreplace(rule)`` (by default the replacer's rule), whose keys are symbols."""
        if rule is None:
            rule = self.rule if self.rule is not None else {}
        places: list = []
        index: dict = {}
        plain = self._plain
        Symbol = sp.Symbol
        replaces = []  # a symbol of the row that the rule replaces (one is enough to know)

        def shape(e, replaced):
            """`e`'s shape; `replaced`: `e` is (part of) a replacement, which xreplace leaves as it is."""
            if type(e) is Symbol:
                i = index.get(e)
                if i is None:
                    ok = plain.get(e)
                    if ok is None:
                        ok = plain[e] = e.assumptions0 == _REAL
                    if not ok:
                        raise _Opaque
                    i = index[e] = len(places)
                    places.append(e)
                if replaced:
                    return i
                new = rule.get(e)
                if new is None or new is e:
                    return i
                if not replaces:
                    replaces.append(e)
                return (i, shape(new, True))
            args = e.args
            if not args:
                if isinstance(e, Symbol):
                    raise _Opaque  # a Dummy, a Wild: not renamed
                return (type(e), e)
            out = [e.func]
            for a in args:
                out.append(shape(a, replaced))
            return tuple(out)

        def by_sympy():
            return expr.xreplace(rule)

        try:
            key = shape(expr, False)
        except _Opaque:
            self.rebuilt += 1
            return by_sympy()
        if not replaces:  # nothing to replace: xreplace gives the row itself
            self.unchanged += 1
            return expr
        plan = self.plans.get(key)
        order = None
        if plan is not None:
            out = plan.build(places)
            if out is None:  # names in another order: the plan made for that order, if any
                order = _order(places)
                other = self.ordered.get((key, order))
                out = None if other is None else other.build(places)
            if out is not None:
                self.renamed += 1
                return out
        self.rebuilt += 1
        out = by_sympy()
        if plan is None:
            self.plans[key] = _Plan(out, places)
        elif len(self.ordered) < MAX_ORDERS:
            self.ordered[(key, order)] = _Plan(out, places)
        return out
