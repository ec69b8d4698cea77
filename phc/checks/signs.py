"""The sign hint of ``phc check``: connections that turn the sign of a voltage (PHC-W230).

In the electrical, hydraulic and thermal domains the *effort* is the across variable (the
voltage, pressure, temperature of a node), and a connection writes ``e_x = −e_y``
(docs/signs.md). Every port therefore reads its node's across variable ``v`` with one of
two orientations: ``e = −v`` with ``f`` the flow *into* the element (how a capacitor,
inductor or resistor reads it: ``e = −q/C``, the power-in view) or ``e = +v`` with ``f``
the flow *out of* the element (how a source reads it: ``e = V``). A connection joins the
two orientations: one port of each. Textbook signs — a capacitor's ``q/C`` is its node's
voltage, an inductor's ``φ/L`` the current from terminal `a` to `b`, a source's value the
voltage it puts on its node — hold when

* every storage and resistive element (one port, or both terminals of a two-terminal
  element) reads power-in, ``e = −v``;
* every source reads ``e = +v``;
* a common-effort junction reads the same orientation on all its ports (its efforts are
  equal), the orientation opposite to its neighbours'.

This module propagates these orientations along the connections of effort-across ports
and reports each connection whose two ends read the same orientation: two power-in ends
(two two-terminal elements in series joined directly, a terminal joined to a capacitor)
or two power-out ends (a source feeding a common-effort junction). Past such a connection
the circuit is mirrored: voltages and flows read with the opposite sign, which is still a
power-conserving model but not the one the user drew when a source or an output sits on
the far side. The number of sign changes along a path is the number of such connections
on it, so along a series chain of two-terminal elements the sign of a node voltage depends
on the number of connections in between — the trap docs/signs.md describes.

Components of other types (common-flow junctions, transformers, gyrators, `phs`,
distributed components) stop the propagation: no hint is drawn across them.
"""

from __future__ import annotations

from phc.diagnostics import Diagnostic

EFFORT_ACROSS = {"electrical": ("voltage", "current"), "hydraulic": ("pressure", "volume flow"),
                 "thermal": ("temperature", "heat flow")}
ELEMENTS = ("capacitor", "inductor", "resistor", "spring", "mass", "damper")
SOURCES = ("effort_source", "flow_source")
IN, OUT = -1, 1


def _classes(top):
    """Union of ports that must read the same orientation, with the orientation of the
    natural signs where the component fixes it (None: free, a junction)."""
    by_component: dict[str, list] = {}
    for port in top.ports:
        if port.domain in EFFORT_ACROSS and port.dimension == 1:
            by_component.setdefault(port.component, []).append(port.name)
    types = {name: kind for name, kind, _ in top.components}
    cls, fixed, what = {}, {}, {}
    for comp, ports in by_component.items():
        kind, spec = types.get(comp), top.specs.get(comp)
        terminals = getattr(spec, "terminals", None)
        if kind in ELEMENTS and (len(ports) == 1 or terminals):
            orientation, role = IN, ("a terminal of two-terminal" if terminals else "the port of") + f" `{comp}`"
        elif kind in SOURCES and len(ports) == 1:
            orientation, role = OUT, f"the source `{comp}`"
        elif kind == "junction" and getattr(spec, "kind", None) == "common_effort":
            orientation, role = None, f"the common-effort junction `{comp}`"
        else:
            continue
        for p in ports:
            cls[p] = comp
            what[p] = role
        fixed[comp] = orientation
    return cls, fixed, what


def sign_hints(top) -> list[Diagnostic]:
    """PHC-W230 warnings for the connections of `top` (a :class:`phc.dae.Topology`) whose
    ends read the across effort with the same orientation (see the module docstring)."""
    if top is None:
        return []
    cls, fixed, what = _classes(top)
    domain = {p.name: p.domain for p in top.ports}
    edges: dict[str, list] = {}
    for a, b, label, span in top.connections:
        if a in cls and b in cls and cls[a] != cls[b]:
            for x, y in ((a, b), (b, a)):
                edges.setdefault(cls[x], []).append((x, y, label, span))
    orientation = {c: o for c, o in fixed.items() if o is not None}
    # A junction takes the orientation most of its oriented neighbours ask for (ties: that
    # of a node feeding elements, so a source on the node is what reads reversed), round
    # by round outwards from the elements and sources.
    while True:
        votes = {}
        for c in sorted(set(fixed) - set(orientation)):
            asked = [-orientation[cls[y]] for _, y, _, _ in edges.get(c, []) if cls[y] in orientation]
            if asked:
                votes[c] = OUT if sum(asked) >= 0 else IN
        if not votes:
            break
        orientation.update(votes)
    out, seen = [], set()
    for a, b, label, span in top.connections:
        if a in cls and b in cls and cls[a] != cls[b] and label not in seen:
            seen.add(label)
            oa, ob = orientation.get(cls[a]), orientation.get(cls[b])
            if oa is not None and oa == ob:
                out.append(_hint(a, b, label, span, oa, what, domain[a]))
    return out


def _hint(x, y, label, span, orientation, what, dom) -> Diagnostic:
    across, through = EFFORT_ACROSS[dom]
    view = "power-in, e = −v" if orientation == IN else "power-out, e = +v"
    message = (f"`{x}` and `{y}` both read the {across} {view} ({what[x]}, {what[y]}), so e_x = −e_y turns "
               f"its sign: past this connection {across}s and {through}s read negated (states, outputs, a "
               "source's polarity)")
    node = f"`{{type: junction, kind: common_effort, domain: {dom}, ports: [x, y]}}`"
    source = next((what[p][len("the source "):] for p in (x, y) if what[p].startswith("the source ")), None)
    if orientation == OUT and source is not None:
        hint = (f"if unintended, negate the value of {source}, or put a node {node} between them (one "
                "connection more turns the sign back); see docs/signs.md")
    else:
        hint = (f"if unintended, put a node {node} between them (one connection more turns the sign back); "
                "see docs/signs.md")
    return Diagnostic("PHC-W230", message, span=span, hint=hint, severity="warning", path=label)
