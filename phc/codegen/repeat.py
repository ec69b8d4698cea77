"""Repeated components generated once: which targets of a generated function are one
expression recurring at many entries (:func:`repeated`).

Input: a :class:`~phc.codegen.lower.ResidualIR` and the targets ``(index, expression,
accumulate)`` of one function. Output: the targets left to be written one by one, and the
:class:`Repeated` expressions, each a template written (or added) at an index array with the
y, ẏ and p entries it reads as index arrays. The C back end (:mod:`phc.codegen.c_printer`) and
the numba back end (:mod:`phc.codegen.numba_emit`) write each as a loop; the NumPy module
(:mod:`phc.codegen.printer`) as one vectorized statement. A network of 10⁴ identical cells then
prints, compiles and loads as a handful of statements instead of one per entry.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from typing import Optional

import numpy as np
import sympy as sp

REPEAT_MIN = 16
"""A compiled back end writes an expression that recurs, up to which entries of ``y``, ``ẏ``
and ``p`` it reads, in at least this many targets (or terms of one long sum) once, as a loop
over index arrays (:func:`repeated`). A network of 10⁴ identical cells then compiles as a
handful of loops: straight-line code of one statement per entry makes the C compiler's time
grow faster than the code (register allocation over one huge function: 468 s of gcc for
the chain of 10⁴ springs and masses)."""


@dataclass(frozen=True)
class Repeated:
    """`template` at `count` instances: instance k adds (``accumulate``) or writes its value
    into ``out[index[k]]``, its :func:`slot` j read as ``vector[at[k]]`` for the j-th pair
    ``(vector, at)`` of `slots` (``vector`` one of ``"y"``, ``"yp"``, ``"p"``)."""

    template: sp.Expr
    index: np.ndarray
    slots: tuple
    accumulate: bool

    @property
    def count(self) -> int:
        return len(self.index)


_SLOTS: list = []


def slot(j: int) -> sp.Symbol:
    """The j-th placeholder of a :class:`Repeated` template (one name for every template, so
    equal templates are equal expressions; no model symbol has this name)."""
    while len(_SLOTS) <= j:
        _SLOTS.append(sp.Symbol(f"phc·slot{len(_SLOTS)}"))
    return _SLOTS[j]


def _template(e, where: dict):
    """(`e` with the y, ẏ and p entries it reads as slots, those entries in slot order), or
    None when `e` reads a symbol of neither (a model time, cj, H: the same in every instance
    and kept as they are). The slots are numbered by first appearance in a preorder walk, and
    again in the walk of the result: two instances whose terms sort differently (the names
    of their symbols order them) mostly end up the same template."""
    if e.is_Number:
        return e, ()
    if e.is_Symbol:
        at = where.get(e)
        return (slot(0), (at,)) if at is not None else (e, ())
    order: dict = {}
    for node in sp.preorder_traversal(e):
        if node.is_Symbol and node in where and node not in order:
            order[node] = slot(len(order))
    if not order:
        return e, ()
    first = e.xreplace(order)
    renumber: dict = {}
    for node in sp.preorder_traversal(first):
        if node in _SLOT_SET and node not in renumber:
            renumber[node] = slot(len(renumber))
    if all(a == b for a, b in renumber.items()):
        entries = tuple(where[s] for s in order)
        return first, entries
    back = {v: k for k, v in order.items()}  # slot -> symbol
    second = first.xreplace({a: b for a, b in renumber.items()})
    entries = [None] * len(renumber)
    for a, b in renumber.items():
        entries[int(b.name[len("phc·slot"):])] = where[back[a]]
    return second, tuple(entries)


def is_slot(s) -> bool:
    """Whether `s` is a :func:`slot` placeholder."""
    return s.is_Symbol and s.name.startswith("phc·slot")


def progression(at: np.ndarray) -> Optional[tuple[int, int]]:
    """``(start, step)`` when the entries `at` are ``start + step·k`` (two or more), else None:
    the index a loop computes, or a slice, instead of a constant array."""
    if len(at) < 2:
        return None
    step = int(at[1] - at[0])
    if not np.array_equal(np.diff(at), np.full(len(at) - 1, step)):
        return None
    return int(at[0]), step


class _SlotSet:
    def __contains__(self, s) -> bool:
        return is_slot(s)


_SLOT_SET = _SlotSet()
_NONE = object()


def repeated(ir, targets: tuple, minimum: int = REPEAT_MIN,
             accept: Optional[Callable[[sp.Expr, list], bool]] = None) -> tuple[tuple, tuple]:
    """`targets` (``(index, expression, accumulate)``) split into those written one by one and
    the :class:`Repeated` loops that write the others: an expression recurring in `minimum`
    targets or more up to the y, ẏ and p entries it reads, or a term recurring as often in one
    long sum (the sum keeps its other terms; the loop adds the rest). The loops write after the
    targets (a long sum's loops add to what its target wrote). `accept(template, positions)`,
    where given, says whether a group of targets (their positions in `targets`) may be looped
    (the NumPy module vectorizes only some templates and targets)."""
    where = {}
    for vector, symbols in (("y", ir.y_symbols), ("yp", ir.yp_symbols), ("p", ir.p_symbols)):
        for j, s in enumerate(symbols):
            if s is not None:
                where[s] = (vector, j)
    items = []  # (target position, out index, expression, accumulate, part of a long sum)
    for k, (i, e, acc) in enumerate(targets):
        if e.is_Add and len(e.args) >= minimum:
            items += [(k, i, term, True, True) for term in e.args]
        else:
            items.append((k, i, e, acc, False))
    groups: dict = {}
    memo = getattr(ir, "templates", {})  # (the NumPy module's and a compiled back end's split)
    for item in items:
        found = memo.get(item[2], _NONE)
        if found is _NONE:
            found = memo[item[2]] = _template(item[2], where)
        if found is None:
            continue
        template, entries = found
        groups.setdefault((template, item[3], tuple(v for v, _ in entries)), []).append((item, entries))
    looped = set()
    loops = []
    for (template, acc, vectors), members in groups.items():
        if len(members) < minimum:
            continue
        if accept is not None and not accept(template, [item[0] for item, _ in members]):
            continue
        if all(item[4] and item[0] == members[0][0][0] for item, _ in members):
            # terms of one sum: added in the order of the entries they read (an index array
            # that is often a progression; sympy orders them by name: k1, k10, k100, ...)
            members.sort(key=lambda member: tuple(at for _, at in member[1]))
        index = np.array([item[1] for item, _ in members], dtype=np.int64)
        slots = tuple((vector, np.array([entries[j][1] for _, entries in members], dtype=np.int64))
                      for j, vector in enumerate(vectors))
        loops.append(Repeated(template, index, slots, acc))
        looped.update(id(item) for item, _ in members)
    if not loops:
        return tuple(targets), ()
    left = []
    terms: dict = {}
    for item in items:
        k, i, e, acc, part = item
        if part:
            terms.setdefault(k, [])
            if id(item) not in looped:
                terms[k].append(e)
        elif id(item) not in looped:
            left.append((k, (i, e, acc)))
    for k, rest in terms.items():
        i, _, acc = targets[k]
        left.append((k, (i, sp.Add(*rest), acc)))
    left.sort(key=lambda pair: pair[0])
    return tuple(t for _, t in left), tuple(loops)


__all__ = ["REPEAT_MIN", "Repeated", "is_slot", "progression", "repeated", "slot"]
