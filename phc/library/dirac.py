"""Kernel representations of component Dirac structures, for certification.

Each lowerer also records its Dirac structure in the seed's kernel form
``F f + E e + G λ = 0`` (eq. rigidDirac2 with its ∃μ), over fresh symbols for the
storage and resistive pairs and the component's own port symbols. The DAE does not use
these; :mod:`phc.checks.certify` does.
"""

from __future__ import annotations

import sympy as sp

from phc.dae import DiracRelations


class DiracBuilder:
    """Collects flows, efforts, multipliers and relations of one component."""

    def __init__(self, component: str, kind: str, span=None):
        self.component, self.kind, self.span = component, kind, span
        self.flows: list[sp.Symbol] = []
        self.efforts: list[sp.Symbol] = []
        self.multipliers: list[sp.Symbol] = []
        self.relations: list[sp.Expr] = []
        self.ports: dict[str, tuple[list[int], list[int]]] = {}

    def pair(self, local: str) -> tuple[sp.Symbol, sp.Symbol]:
        """A fresh internal (storage, resistive or environment) flow/effort pair."""
        f = sp.Symbol(f"cert:{self.component}.f_{local}", real=True)
        e = sp.Symbol(f"cert:{self.component}.e_{local}", real=True)
        self.flows.append(f)
        self.efforts.append(e)
        return f, e

    def port(self, port) -> None:
        start = len(self.flows)
        self.flows.extend(port.f)
        self.efforts.extend(port.e)
        idx = list(range(start, start + port.dimension))
        self.ports[port.name.rsplit(".", 1)[-1]] = (idx, idx)

    def mult(self, local: str) -> sp.Symbol:
        lam = sp.Symbol(f"cert:{self.component}.{local}", real=True)
        self.multipliers.append(lam)
        return lam

    def rel(self, expr) -> None:
        self.relations.append(expr if isinstance(expr, sp.Basic) else sp.Integer(expr))

    def register(self, b, states=(), note: str = "", kind: str | None = None) -> None:
        b.dirac.append(DiracRelations(self.component, kind or self.kind, tuple(self.flows), tuple(self.efforts),
                                      tuple(self.multipliers), tuple(self.relations), dict(self.ports),
                                      tuple(states), self.span, note))
