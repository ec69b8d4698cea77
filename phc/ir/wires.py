"""Wires: the connections that keep the sign of a series chain as drawn (docs/signs.md,
"Series chains keep the sign you draw").

A connection is a power bond, ``f_x = f_y``, ``e_x = −e_y`` (the coupling condition of
T. Berger, R. Hochdahl, T. Reis, R. Seifried, "Port-Hamiltonian modelling of coupled
rigid/flexible multibody systems", section 2.2). In the electrical, hydraulic and thermal
domains the across variable is the effort, and every storage or resistive element reads it
power-in: ``e = −v`` with ``f`` the flow into the element — its one port, and *both*
terminals of a two-terminal element (`terminals: [a, b]`, ``f_b = −f_a``). A bond between
two such ends mirrors the circuit beyond it, so a chain ``r.b → coil.a`` came out with the
coil's current negated.

The rule: a connection in these domains that joins a **terminal of a two-terminal element**
to a port that reads power-in — a terminal of another two-terminal element, the one port of
a storage or resistive element (capacitor, inductor, resistor, or a mass, spring, damper in
these domains), or port ``a`` of a transformer or gyrator (which takes power in at ``a`` and
gives it out at ``b``) — is a *wire*: both ends see the same node value and the flow leaving
one enters the other,

    e_x = e_y,   f_x = −f_y.

Along a chain written ``src → r.a``, ``r.b → coil.a``, ``coil.b → cap`` every element's flow
is then positive from its ``a`` to its ``b``, as drawn. A wire conserves power
(``f_x e_x + f_y e_y = 0``); it is the bond with one port's flow and effort both negated, a
change of coordinates of that port alone, so the coupling map of the structural certificate
has the rank of the bond's. Every other connection (a terminal joined to a source, a
junction, port ``b`` of a transformer; any connection without a terminal; the mechanical
domains, whose across variable is the flow that a bond does not turn) stays a bond.
"""

from __future__ import annotations

from typing import Iterable, Mapping

from phc.library.registry import FieldView

__all__ = ["EFFORT_ACROSS_DOMAINS", "WIRE", "BOND", "wire_labels", "is_terminal", "reads_power_in"]

EFFORT_ACROSS_DOMAINS = ("electrical", "hydraulic", "thermal")
ROLES = FieldView("sign_role")
BOND = (1, -1)
"""(sign of f_y, sign of e_y) in ``f_x = s_f f_y``, ``e_x = s_e e_y``: a bond."""
WIRE = (-1, 1)
"""The same for a wire."""


def _short(port) -> str:
    return port.name[len(port.component) + 1:]


def is_terminal(port, spec) -> bool:
    """A terminal of a two-terminal storage or resistive element in an effort-across domain."""
    terminals = getattr(spec, "terminals", None)
    return (port.domain in EFFORT_ACROSS_DOMAINS and bool(terminals) and _short(port) in terminals
            and ROLES.get(getattr(spec, "type", None)) == "load")


def reads_power_in(port, spec, n_ports: int) -> bool:
    """Whether `port` reads its node's across effort power-in by construction: a terminal,
    the one port of a storage or resistive element, port ``a`` of a transformer or gyrator
    (in an effort-across domain)."""
    if port.domain not in EFFORT_ACROSS_DOMAINS or spec is None:
        return False
    role = ROLES.get(getattr(spec, "type", None))
    if role == "load":
        return is_terminal(port, spec) or (getattr(spec, "terminals", None) is None and n_ports == 1)
    return role == "series" and _short(port) == "a"


def wire_labels(ports: Iterable, specs: Mapping, connections: Iterable) -> frozenset:
    """The labels of the `connections` (``(port x, port y, label)`` with port objects that
    have ``name``, ``component`` and ``domain``) joined as wires; `ports` are all the
    model's ports (to count each component's), `specs` the components' specs by full name."""
    n_ports: dict = {}
    for p in ports:
        n_ports[p.component] = n_ports.get(p.component, 0) + 1
    out = set()
    for x, y, label in connections:
        sx, sy = specs.get(x.component), specs.get(y.component)
        if ((is_terminal(x, sx) and reads_power_in(y, sy, n_ports.get(y.component, 0)))
                or (is_terminal(y, sy) and reads_power_in(x, sx, n_ports.get(x.component, 0)))):
            out.add(label)
    return frozenset(out)
