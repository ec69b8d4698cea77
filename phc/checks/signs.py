"""The sign hint: connections that turn the sign of a voltage (PHC-W230). It is cheap, so
every command that reads a model prints it (``phc validate``, ``simulate``, ``check``:
:func:`phc.pipeline.elaborate_file`).

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
  equal), the orientation opposite to its neighbours';
* a common-flow junction (a series loop: one current, efforts summing to zero) reads
  power-out, ``e = +v``, at its ports toward loads and power-in, ``e = −v``, at its ports
  toward sources. Its equations ``f_k = f``, ``Σ e_k = 0`` are then Kirchhoff's voltage
  law ``Σ v_loads = Σ V_sources`` with every load reading the loop current as the current
  into it and every source as the current out of it — for every element or source joined
  to the junction directly. Reading all its ports the other way round (power-in toward
  loads) is the same circuit with the loop direction reversed, so a loop has one free
  orientation, like a node; what matters is that its branches agree. A port faces a source
  when a source lies beyond it (through nodes, two-terminal elements, other loops), a load
  when only storage and resistive elements do; common-flow junctions joined port to port
  are one loop. A two-port node between the junction and an element is the trap: the node
  turns the element's voltage and current (``e_x = e_y``, ``f_x = −f_y``), so a capacitor
  joined through it charges to ``−C·V``.
* a transformer or gyrator between two effort-across ports reads like a two-port loop: its
  equations (``f_b = N f_a``, ``e_a = −N e_b``; ``e_b = G f_a``, ``e_a = −G f_b``) give
  ``v_b = v_a/N``, ``i_b = N i_a`` (``v_b = G i_a``, ``v_a = G i_b``) with positive signs
  when its port toward the source reads power-in and the other power-out.

This module propagates these orientations along the connections of effort-across ports
and reports each bond whose two ends read the same orientation: two power-in ends (two
one-port elements joined directly) or two power-out ends (a source feeding a common-effort
junction, a node between a series loop and its capacitor). Past such a connection the
circuit is mirrored: voltages and flows read with the opposite sign, which is still a
power-conserving model but not the one the user drew when a source or an output sits on the
far side. A *wire* (:mod:`phc.ir.wires`: a terminal of a two-terminal element joined to a port
that reads power-in, ``e_x = e_y``) joins two ends that read the same orientation, so a
series chain of two-terminal elements keeps its signs; a wire is reported when its ends read
opposite orientations (port ``a`` of a transformer or gyrator whose port ``b`` faces the
source).

Components of other types (`phs`, distributed components, a transformer or gyrator to
another domain such as a motor's shaft), a branch that leaves the model through an open
port or comes back to its own loop, and a loop port with neither a source nor an element
beyond it stop the propagation: no hint is drawn across them. Where no single side holds
the sources (a loop without sources, or sources on both sides of a node between two
loops), the two loop ports next to such a node face the same kind of branch, and the node
is not reported though it turns one loop against the other.
"""

from __future__ import annotations

from phc.diagnostics import Diagnostic
from phc.library.registry import FieldView

EFFORT_ACROSS = {"electrical": ("voltage", "current"), "hydraulic": ("pressure", "volume flow"),
                 "thermal": ("temperature", "heat flow")}
ROLES = FieldView("sign_role")
"""Type -> its role in the hints (``load``, ``source``, ``series``, ``junction``): the
registry's ``sign_role`` (:mod:`phc.library.registry`); types without one take no part."""
IN, OUT = -1, 1


def _classes(top):
    """Union of ports that must read the same orientation, with the orientation of the
    natural signs where the component fixes it (None: free, a node or a series group), and
    `sign`: +1 for a port that reads its class's orientation, −1 for one that reads the
    opposite (the source side of a series group)."""
    by_component: dict[str, list] = {}
    n_ports: dict[str, int] = {}
    for port in top.ports:
        n_ports[port.component] = n_ports.get(port.component, 0) + 1
        if port.domain in EFFORT_ACROSS and port.dimension == 1:
            by_component.setdefault(port.component, []).append(port.name)
    types = {name: kind for name, kind, _ in top.components}
    role_of: dict[str, str] = {}
    cls, fixed, what, sign = {}, {}, {}, {}
    series: dict[str, list] = {}
    for comp, ports in by_component.items():
        kind, spec = types.get(comp), top.specs.get(comp)
        terminals = getattr(spec, "terminals", None)
        if len(ports) != n_ports[comp]:
            continue  # a port outside the effort-across domains (a motor's shaft, a piston's rod)
        kind_role = ROLES.get(kind)
        if kind_role == "load" and (len(ports) == 1 or terminals):
            orientation, role = IN, ("a terminal of two-terminal" if terminals else "the port of") + f" `{comp}`"
            role_of[comp] = "load"
        elif kind_role == "source" and len(ports) == 1:
            orientation, role = OUT, f"the source `{comp}`"
            role_of[comp] = "source"
        elif kind_role == "junction" and getattr(spec, "kind", None) == "common_effort":
            orientation, role = None, f"the common-effort junction `{comp}`"
            role_of[comp] = "node"
        elif (kind_role == "junction" and getattr(spec, "kind", None) == "common_flow") or \
                (kind_role == "series" and len(ports) == 2):
            series[comp] = ports
            role_of[comp] = "series"
            continue
        else:
            continue
        for p in ports:
            cls[p] = comp
            what[p] = role
        fixed[comp] = orientation
    ports_of = {comp: by_component[comp] for comp in role_of}
    owner = {p: comp for comp, ports in ports_of.items() for p in ports}
    neighbours: dict[str, list] = {}
    for a, b, _, _ in top.connections:
        neighbours.setdefault(a, []).append(b)
        neighbours.setdefault(b, []).append(a)
    # Common-flow junctions joined port to port are one series loop (one common flow).
    group = {comp: comp for comp in series}

    def find(c):
        while group[c] != c:
            group[c] = group[group[c]]
            c = group[c]
        return c

    for a, b, _, _ in top.connections:
        ca, cb = owner.get(a), owner.get(b)
        if ca in series and cb in series and types[ca] == types[cb] == "junction":
            group[find(ca)] = find(cb)
    vertex = {comp: find(comp) if comp in series else comp for comp in role_of}
    sides = _sides(top.connections, vertex, owner, ports_of, role_of, neighbours)
    for comp, ports in series.items():
        key = ("series", find(comp))
        fixed.setdefault(key, None)
        kind = "common-flow junction" if types[comp] == "junction" else types[comp]
        for p in ports:
            side = sides.get(p)
            if side is None:
                continue
            cls[p] = key
            sign[p] = 1 if side == "load" else -1
            what[p] = f"a port of the {kind} `{comp}` toward a {side}"
    return cls, fixed, what, sign


def _sides(connections, vertex, owner, ports_of, role_of, neighbours) -> dict:
    """What each port of a series loop faces: "source" if a source is beyond it, "load" if
    only storage and resistive elements are; absent where the branch leaves the
    effort-across components, ends in an open port, comes back to the loop, or holds
    neither.

    The components are the vertices of a graph (the junctions of one loop one vertex), the
    connections its edges. A branch beyond a loop port does not come back to the loop
    exactly when the port's edge is a bridge, and then it is the far side of the bridge: a
    subtree of a depth-first search. One search finds the bridges and the sources, loads
    and open ends of every subtree, so the sides of all ports cost linear time."""
    own: dict = {}
    for comp, v in vertex.items():
        tally = own.setdefault(v, [0, 0, 0])  # sources, loads, open ends
        role = role_of[comp]
        tally[0] += role == "source"
        tally[1] += role == "load"
        tally[2] += sum(1 for p in ports_of[comp] if not neighbours.get(p)
                        or any(q not in owner for q in neighbours[p]))
    adj: dict = {v: [] for v in own}
    edge_of: dict = {}
    for eid, (a, b, _, _) in enumerate(connections):
        if a in owner and b in owner:
            u, w = vertex[owner[a]], vertex[owner[b]]
            edge_of.setdefault(a, []).append(eid)
            edge_of.setdefault(b, []).append(eid)
            if u != w:
                adj[u].append((w, eid))
                adj[w].append((u, eid))
    disc, low, sub, root, child_of = {}, {}, {}, {}, {}
    for start in adj:
        if start in disc:
            continue
        disc[start] = low[start] = len(disc)
        root[start], sub[start] = start, list(own[start])
        stack = [(start, -1, iter(adj[start]))]
        while stack:
            v, parent_edge, it = stack[-1]
            for w, eid in it:
                if eid == parent_edge:
                    continue
                if w in disc:
                    low[v] = min(low[v], disc[w])
                else:
                    disc[w] = low[w] = len(disc)
                    root[w], sub[w] = start, list(own[w])
                    stack.append((w, eid, iter(adj[w])))
                    break
            else:
                stack.pop()
                if stack:
                    u = stack[-1][0]
                    low[u] = min(low[u], low[v])
                    sub[u] = [x + y for x, y in zip(sub[u], sub[v])]
                    if low[v] > disc[u]:
                        child_of[parent_edge] = v  # a bridge, and the vertex below it
    out = {}
    for comp, v in vertex.items():
        if role_of[comp] != "series":
            continue
        for p in ports_of[comp]:
            eids = edge_of.get(p, [])
            if len(eids) != 1 or len(neighbours.get(p, [])) != 1 or eids[0] not in child_of:
                continue
            below = child_of[eids[0]]
            if below != v:
                beyond = sub[below]
            else:
                beyond = [x - y for x, y in zip(sub[root[v]], sub[v])]
            sources, loads, open_ends = beyond
            if not open_ends and (sources or loads):
                out[p] = "source" if sources else "load"
    return out


def sign_hints(top) -> list[Diagnostic]:
    """PHC-W230 warnings for the connections of `top` (a :class:`phc.ir.dae.Topology`) whose
    ends read the across effort with the same orientation (see the module docstring)."""
    if top is None:
        return []
    cls, fixed, what, sign = _classes(top)
    domain = {p.name: p.domain for p in top.ports}
    wires = top.wires
    # how a connection passes the reading on: a bond (e_x = −e_y) joins opposite readings,
    # a wire (e_x = e_y, phc.ir.wires) equal ones
    turn = {label: 1 if label in wires else -1 for _, _, label, _ in top.connections}
    edges: dict = {}
    for a, b, label, span in top.connections:
        if a in cls and b in cls and cls[a] != cls[b]:
            for x, y in ((a, b), (b, a)):
                edges.setdefault(cls[x], []).append((x, y, label, span))
    orientation = {c: o for c, o in fixed.items() if o is not None}

    def reads(p):
        o = orientation.get(cls[p])
        return None if o is None else o * sign.get(p, 1)

    # A node or a series loop takes the orientation most of its oriented neighbours ask for
    # (ties: that of a node feeding elements, so a source on the node is what reads
    # reversed; that of a loop reading power-out toward its loads), round by round outwards
    # from the elements and sources.
    # Only the neighbours of the classes oriented in a round can vote in the next (any other
    # would have voted before): a look at every open class per round was quadratic along a
    # ladder of nodes.
    open_classes = set(fixed) - set(orientation)
    while True:
        votes = {}
        for c in sorted(open_classes, key=str):
            asked = [turn[label] * sign.get(x, 1) * reads(y) for x, y, label, _ in edges.get(c, [])
                     if cls[y] in orientation]
            if asked:
                votes[c] = OUT if sum(asked) >= 0 else IN
        if not votes:
            break
        orientation.update(votes)
        open_classes = {cls[y] for c in votes for _, y, _, _ in edges.get(c, [])
                        if cls[y] in fixed and cls[y] not in orientation}
    out, seen = [], set()
    n_ports: dict = {}
    for p, c in cls.items():
        n_ports[c] = n_ports.get(c, 0) + 1
    two_port_nodes = {c for c, _, _ in top.components if fixed.get(c, 0) is None and n_ports.get(c) == 2}
    types = {name: kind for name, kind, _ in top.components}
    for a, b, label, span in top.connections:
        if a in cls and b in cls and cls[a] != cls[b] and label not in seen:
            seen.add(label)
            oa, ob = reads(a), reads(b)
            if oa is not None and ob is not None and oa == -turn[label] * ob:
                if label in wires:
                    out.append(_wire_hint(a, b, label, span, oa, ob, what, domain[a], types))
                else:
                    out.append(_hint(a, b, label, span, oa, what, domain[a], cls, two_port_nodes))
    return out


def _view(orientation) -> str:
    return "power-in, e = −v" if orientation == IN else "power-out, e = +v"


def _wire_hint(x, y, label, span, ox, oy, what, dom, types) -> Diagnostic:
    """A wire (phc.ir.wires) between ends that read the across effort the opposite ways: a
    terminal joined to port `a` of a transformer or gyrator whose port `b` faces the source."""
    across, through = EFFORT_ACROSS[dom]
    message = (f"`{x}` reads the {across} {_view(ox)} ({what[x]}) and `{y}` {_view(oy)} ({what[y]}), so the wire "
               f"e_x = e_y (a terminal joined to a port that reads power-in) turns its sign: past this connection "
               f"{across}s and {through}s read negated (states, outputs, a source's polarity)")
    owners = (p.rsplit(".", 1)[0] for p in (x, y))
    two_port = next((c for c in owners if types.get(c) in ("transformer", "gyrator")), None)
    hint = "if unintended, "
    if two_port is not None:
        hint += (f"turn `{two_port}` round so that its port `a` faces the source (it takes power in at `a`; "
                 "a transformer's ratio inverts), or ")
    node = f"`{{type: junction, kind: common_effort, domain: {dom}, ports: [x, y]}}`"
    hint += f"put two nodes {node} in a row between them; see docs/signs.md"
    return Diagnostic("PHC-W230", message, span=span, hint=hint, severity="warning", path=label)


def _hint(x, y, label, span, orientation, what, dom, cls, two_port_nodes) -> Diagnostic:
    across, through = EFFORT_ACROSS[dom]
    view = _view(orientation)
    message = (f"`{x}` and `{y}` both read the {across} {view} ({what[x]}, {what[y]}), so e_x = −e_y turns "
               f"its sign: past this connection {across}s and {through}s read negated (states, outputs, a "
               "source's polarity)")
    node = f"`{{type: junction, kind: common_effort, domain: {dom}, ports: [x, y]}}`"
    source = next((what[p][len("the source "):] for p in (x, y) if what[p].startswith("the source ")), None)
    if orientation == OUT and source is not None:
        hint = (f"if unintended, negate the value of {source}, or put a node {node} between them (one "
                "connection more turns the sign back); see docs/signs.md")
    else:
        hint = f"if unintended, put a node {node} between them (one connection more turns the sign back)"
        loop_end = any(isinstance(cls[p], tuple) for p in (x, y))
        extra = next((cls[p] for p in (x, y) if cls[p] in two_port_nodes), None) if loop_end else None
        if extra is not None:
            hint += f", or leave out the two-port node `{extra}` (join its two neighbours directly)"
        hint += "; see docs/signs.md"
    return Diagnostic("PHC-W230", message, span=span, hint=hint, severity="warning", path=label)
