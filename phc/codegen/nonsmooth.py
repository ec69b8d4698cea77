"""Non-smooth functions and switching conditions, for the lower pass.

Input: the residual rows of a :class:`~phc.ir.dae.Dae` (sympy). Output: the rows rewritten
so that every non-smooth point is a *switch* the simulation driver controls, the
switches' boundary functions, and the set-valued `sign` terms (:class:`Switching`).

What the model language allows and what it means here (``docs/events.md``):

* ``sign``, ``heaviside``, ``abs``, ``min``, ``max`` and ``ifelse(cond, a, b)`` become
  ``Piecewise`` expressions whose conditions are comparisons ``g > 0`` (``<``, ``>=``,
  ``<=``, ``==``, ``!=``) of a *boundary function* g. Derivatives are taken branch by
  branch: the value almost everywhere (no Dirac delta ever reaches the Jacobian or dF/dt).
* A comparison whose g depends on the time or on variables of the DAE is a **switch**
  ``k``. In the generated module it reads ``Switch(m_k, g)``: the value of g when the mode
  ``m_k`` (an entry of the parameter vector, 0 by default) is 0, else ``m_k`` itself. The
  driver freezes ``m_k = ±1`` (the side of g) between switching points, so every step sees
  one smooth branch, and flips it where g crosses zero: at a breakpoint for switches in t
  only (their roots are found before the run), at a located event for the others. Called
  with the default parameters the module evaluates every condition directly, so the
  certificate and any other caller see the plain functions.
* ``sign(v)`` of a variable-dependent argument that enters the rows affinely
  (``a + b·sign(v)`` with b independent of v: a Coulomb friction force, a relay) is
  **set-valued** at v = 0: sign(0) is any value in [−1, 1]. Its *stick* mode (an entry of
  the parameter vector, 1 when sticking) replaces the row that defines the force by
  ``v = 0`` and substitutes ``sign(v) = s = −a/b`` in the other rows; the driver enters it
  where v crosses zero and leaves it where ``|s|`` reaches 1 (``s`` is an event function
  too). That is the switch model of Karnopp: sticking is exact, not a fast oscillation.
"""

from __future__ import annotations

from dataclasses import dataclass

import sympy as sp

from phc.ir.dae import T


class Switch(sp.Function):
    """``Switch(m, g)``: g where the mode m is 0, else m (the frozen side of g's sign).

    Appears only in the conditions of ``Piecewise`` expressions, never differentiated."""

    nargs = 2
    is_real = True


_NONSMOOTH = (sp.sign, sp.Heaviside, sp.Abs, sp.Min, sp.Max, sp.Piecewise)


@dataclass(frozen=True)
class SwitchInfo:
    """One switch: its boundary function g (rows switch where g changes sign)."""

    boundary: sp.Expr
    time_only: bool
    label: str
    """The condition as the model wrote it (model names), e.g. ``sign(block.fr.f)``."""
    equation: str
    """Label of the first residual row it occurs in."""
    mode: sp.Symbol
    """Its mode entry in the parameter vector."""
    sense: int = 1
    """+1 or −1: where `boundary` rises through 0, the label's comparison turns true (for a
    label ``a < b``: where ``b − a`` rises) or the argument of its function rises (``sign(x)``,
    ``abs(x)``: x; ``min(a, b)``, ``max(a, b)``: a − b) when sense is +1."""
    comparison: bool = False
    """The label is a comparison (``a < b``), not a function."""
    component: str = ""
    """The component whose own expressions hold the condition (before assembly merged its
    rows into others'), when it can be told; for locating messages."""


@dataclass(frozen=True)
class StickInfo:
    """A set-valued ``sign(v)``: `switch` is v's switch, ``sign(v) = orient·sign(g)``,
    `exit` the value s = −a/b sign(v) must take while sticking (|s| ≤ 1)."""

    switch: int
    orient: int
    exit: sp.Expr
    label: str
    equation: str
    mode: sp.Symbol


@dataclass(frozen=True)
class Switching:
    rows: tuple
    switches: tuple[SwitchInfo, ...]
    sticks: tuple[StickInfo, ...]


def _expand_nonsmooth(expr: sp.Expr, labels: dict) -> sp.Expr:
    """sign, heaviside, abs, min and max as Piecewise expressions (bottom-up); `labels` maps
    each boundary function introduced to the construct it came from (for messages)."""

    def visit(e):
        if e.is_Atom or not e.has(*_NONSMOOTH):
            return e
        args = [visit(a) for a in e.args]
        if isinstance(e, sp.sign):
            (x,) = args
            labels.setdefault(x, (f"sign({x})", 1, False))
            return sp.Piecewise((1, sp.Gt(x, 0)), (-1, sp.Lt(x, 0)), (0, True))
        if isinstance(e, sp.Heaviside):
            x = args[0]
            h0 = args[1] if len(args) > 1 else sp.S.Half
            labels.setdefault(x, (f"heaviside({x})", 1, False))
            return sp.Piecewise((1, sp.Gt(x, 0)), (0, sp.Lt(x, 0)), (h0, True))
        if isinstance(e, sp.Abs):
            (x,) = args
            labels.setdefault(x, (f"abs({x})", 1, False))
            return sp.Piecewise((x, sp.Gt(x, 0)), (-x, True))
        if isinstance(e, (sp.Min, sp.Max)):
            name = "min" if isinstance(e, sp.Min) else "max"
            rel = sp.Lt if name == "min" else sp.Gt
            acc = args[0]
            for b in args[1:]:
                labels.setdefault(acc - b, (f"{name}({acc}, {b})", 1, False))
                acc = sp.Piecewise((acc, rel(acc - b, 0)), (b, True))
            return acc
        if isinstance(e, sp.Piecewise):
            return sp.Piecewise(*[(visit(x), c) for x, c in e.args])
        return e.func(*args)

    return visit(expr)


_FLIP = {sp.Gt: sp.Lt, sp.Lt: sp.Gt, sp.Ge: sp.Le, sp.Le: sp.Ge, sp.Eq: sp.Eq, sp.Ne: sp.Ne}


class _Builder:
    def __init__(self, dynamic: set, moving: set, mode_name):
        self.dynamic, self.moving = dynamic, moving
        self.mode_name = mode_name
        self.index: dict = {}
        self.switches: list[SwitchInfo] = []
        self.labels: dict = {}
        self.equation = ""

    def switch(self, g: sp.Expr) -> tuple[int, int]:
        """The switch of boundary function g (or −g): (index, orientation)."""
        neg = -g
        minus, minus_neg = g.could_extract_minus_sign(), neg.could_extract_minus_sign()
        if minus != minus_neg:
            canon, flip = (neg, -1) if minus else (g, 1)
        else:
            canon, flip = (neg, -1) if sp.default_sort_key(neg) < sp.default_sort_key(g) else (g, 1)
        k = self.index.get(canon)
        if k is None:
            k = self.index[canon] = len(self.switches)
            if g in self.labels:
                (label, sense, comparison), orient = self.labels[g], flip
            elif neg in self.labels:
                (label, sense, comparison), orient = self.labels[neg], -flip
            else:
                (label, sense, comparison), orient = (f"{g} > 0", 1, True), flip
            time_only = not (canon.free_symbols & self.moving)
            self.switches.append(SwitchInfo(canon, time_only, label, self.equation, self.mode_name("switch", k),
                                            sense * orient, comparison))
        return k, flip

    def condition(self, c):
        if c in (sp.true, sp.false) or not isinstance(c, sp.logic.boolalg.Boolean):
            return c
        if isinstance(c, sp.core.relational.Relational):
            lhs, rhs = self.rows(c.lhs), self.rows(c.rhs)
            g = lhs - rhs
            if not (g.free_symbols & self.dynamic):
                return type(c)(lhs, rhs)
            if g not in self.labels and -g not in self.labels:
                self.labels[g] = (str(c), -1 if isinstance(c, (sp.Lt, sp.Le)) else 1, True)
            k, flip = self.switch(g)
            info = self.switches[k]
            rel = type(c) if flip > 0 else _FLIP[type(c)]
            return rel(Switch(info.mode, info.boundary), 0)
        return c.func(*[self.condition(a) for a in c.args])

    def rows(self, expr):
        if expr.is_Atom or not expr.has(sp.Piecewise):
            return expr
        if isinstance(expr, sp.Piecewise):
            return sp.Piecewise(*[(self.rows(e), self.condition(c)) for e, c in expr.args])
        return expr.func(*[self.rows(a) for a in expr.args])


def _set_valued(rows, kinds, moving: set):
    """The sign atoms of variable-dependent arguments that enter every row they occur in
    affinely, with a row that defines them (b independent of the variables): for each,
    (atom, defining row, {row: (a, b)})."""
    found = {}
    for i, row in enumerate(rows):
        if row is sp.S.Zero:
            continue  # a row of a linear block (most rows of a mesh)
        for atom in row.atoms(sp.sign):
            if atom.args[0].free_symbols & moving:
                found.setdefault(atom, []).append(i)
    out = []
    used = set()
    sigma = sp.Dummy("sigma")
    for atom, where in found.items():
        forms, ok = {}, True
        for i in where:
            r = rows[i].xreplace({atom: sigma})
            b = sp.diff(r, sigma)
            if b.has(sigma) or b == 0:
                ok = False
                break
            forms[i] = (r.xreplace({sigma: 0}), b)
        if not ok:
            continue
        defining = [i for i in where if kinds[i] != "energy" and i not in used
                    and not (forms[i][1].free_symbols & moving)]
        if defining:  # each stick replaces a row of its own
            used.add(defining[0])
            out.append((atom, defining[0], forms))
    return out


def switching(rows, kinds, labels, y_symbols, yp_symbols, mode_symbol) -> Switching:
    """Rewrite the residual rows (see the module docstring).

    Parameters
    ----------
    rows, kinds, labels : sequences
        The residual rows, their kinds (``energy`` for the accumulator) and labels.
    y_symbols, yp_symbols : sequences of sympy symbols
        The variables and their derivatives.
    mode_symbol : callable
        ``mode_symbol(kind, k)`` returns the parameter symbol of mode ``k`` of a kind
        (``switch`` or ``stick``).
    """
    rows = list(rows)
    if not any(r.has(*_NONSMOOTH) for r in rows):
        return Switching(tuple(rows), (), ())
    moving = set(y_symbols) | {s for s in yp_symbols if s is not None}
    dynamic = moving | {T}
    builder = _Builder(dynamic, moving, mode_symbol)
    sticks_raw = _set_valued(rows, kinds, moving)
    stick_modes = []
    for j, (atom, i0, forms) in enumerate(sticks_raw):
        K = mode_symbol("stick", j)
        stick_modes.append(K)
        a0, b0 = forms[i0]
        s = -a0 / b0
        for i, (a, b) in forms.items():
            stuck = atom.args[0] if i == i0 else a + b * s
            rows[i] = sp.Piecewise((stuck, sp.Gt(K, 0)), (rows[i], True))
    expanded = []
    for i, row in enumerate(rows):
        expanded.append(_expand_nonsmooth(row, builder.labels) if row is not sp.S.Zero and row.has(*_NONSMOOTH)
                        else row)
    new_rows = []
    for row, label in zip(expanded, labels):
        builder.equation = label
        new_rows.append(builder.rows(row))
    sticks = []
    for j, (atom, i0, forms) in enumerate(sticks_raw):
        arg = _expand_nonsmooth(atom.args[0], builder.labels)
        builder.equation = labels[i0]
        k, flip = builder.switch(builder.rows(arg))
        a0, b0 = forms[i0]
        exit_ = builder.rows(_expand_nonsmooth(-a0 / b0, builder.labels))
        sticks.append(StickInfo(k, flip, exit_, f"sign({atom.args[0]})", labels[i0], stick_modes[j]))
    # the boundary functions themselves, with inner switches, as the rows see them
    return Switching(tuple(new_rows), tuple(builder.switches), tuple(sticks))


def _boundaries(expr) -> set:
    """Boundary functions of the conditions and non-smooth functions written in `expr`."""
    found = set()
    for e in sp.preorder_traversal(expr):
        if isinstance(e, sp.core.relational.Relational):
            found.add(e.lhs - e.rhs)
        elif isinstance(e, (sp.sign, sp.Heaviside, sp.Abs)):
            found.add(e.args[0])
        elif isinstance(e, (sp.Min, sp.Max)):
            found.update(a - b for a in e.args for b in e.args if a is not b)
    return found


def with_origins(switches, component_rows) -> tuple[SwitchInfo, ...]:
    """`switches` with `component` set to the first component whose rows as its lowerer
    wrote them (``ComponentRows``: equations and explicit definitions) hold the condition."""
    from dataclasses import replace

    left = {k: s for k, s in enumerate(switches) if not s.component}
    out = list(switches)
    for rows in component_rows:
        if not left:
            break
        exprs = [e for _, e in rows.equations] + [e for _, e in rows.definitions]
        if not any(isinstance(e, sp.Basic) and e.has(*_NONSMOOTH) for e in exprs):
            continue
        seen = set().union(*(_boundaries(e) for e in exprs if isinstance(e, sp.Basic)))
        for k, s in list(left.items()):
            if s.boundary in seen or -s.boundary in seen:
                out[k] = replace(s, component=rows.component)
                del left[k]
    return tuple(out)


def plain(expr: sp.Expr) -> sp.Expr:
    """An expression outside the residual (outputs, H, powers) with its non-smooth
    functions as Piecewise of direct comparisons (printable, no switches)."""
    if expr.is_Atom or not expr.has(*_NONSMOOTH):
        return expr
    return _expand_nonsmooth(expr, {})


__all__ = ["Switch", "SwitchInfo", "StickInfo", "Switching", "switching", "plain", "with_origins"]
