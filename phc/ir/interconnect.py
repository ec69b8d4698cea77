"""The interconnection graph (networkx): components, ports, connections — one graph for
scene pruning, the port-compatibility check and the certificate.

Input: the components and connections of a model, either as written
(a :class:`~phc.spec.ModelSpec`, before anything is lowered: what a scene prunes) or as
assembled (a :class:`~phc.ir.dae.Topology`: what ``phc check`` certifies and ``phc graph``
draws). Output: an ``nx.MultiGraph`` built by :func:`build_interconnection_graph` for
both, and the views derived from it (:func:`component_graph`, :func:`kinematic_loops`,
:func:`independent_parts`, :func:`traversal_order`, :func:`connected_to`, :func:`to_dot`).

Nodes are typed tuples: ``("component", name)``, ``("port", full_name)`` and
``("external", name)`` for ports exposed by the top-level model. Edges carry ``kind`` =
``has`` (component–port), ``connection`` (port–port, the paper's eq. (2), with the
connection's ``index`` in the order written), ``exposed``, or ``reads`` (component →
component whose states it reads: a ``modulation``'s ``K(x)``). From a spec, port nodes are
the ports the connections and ``ports:`` name (their owner is the top-level component);
what they are (domain, dimension, frame) is only known once components are lowered.

:func:`check_connections` is the wiring check between lowering and assembly: each port
used once, connected ports compatible (domain, dimension, frame), no port left dangling.
The connections it returns are the connection edges of the assembled topology.
"""

from __future__ import annotations

import sys
from dataclasses import dataclass
from types import MappingProxyType
from typing import TYPE_CHECKING, Mapping, Optional, Union

from phc.ir.dae import Topology
from phc.diagnostics import Diagnostic, DiagnosticList
from phc.library.registry import FieldView, find
from phc.spec.expressions import ExpressionError, validate_syntax

if TYPE_CHECKING:
    import networkx as nx

    from phc.spec.model import ModelSpec

__all__ = ["Interconnection", "interconnect", "build_interconnection_graph", "check_connections", "component_graph", "component_of",
           "connected_to", "independent_parts", "kinematic_loops", "reading_order", "reads_of", "short_cycle_basis",
           "to_dot", "traversal_order"]


# -- the one builder ----------------------------------------------------------------------
def _owner(ref: str) -> str:
    return ref.split(".", 1)[0]


MODULATED = FieldView("state_reads", lambda entry: True if entry.state_reads.modulated else None)
"""Component types whose matrix may read other components' states (lowered last): the
registry's ``state_reads.modulated`` (:mod:`phc.library.registry`)."""


def reads_of(spec: ModelSpec) -> list[tuple[str, str]]:
    """(reader, read) for each component of `spec` whose matrix reads another's states.

    Read from the free symbols of the parsed entries of a ``modulation``'s ``K`` or a
    ``transformer``'s or ``gyrator``'s ``ratio`` (names
    are written in full, ``wheel.theta``). An entry that does not parse (its error is
    reported when the component is lowered) counts as reading every component, so that
    pruning keeps whatever the error concerns.
    """
    found = []
    order: Optional[dict] = None  # component -> its place in the file, made when first needed
    for cname, comp in spec.components.items():
        read = state_reads(comp)
        if read is None:
            found.extend((cname, other) for other in spec.components if other != cname)
        elif read:  # in the order written (scanning all components for each one was quadratic)
            order = order if order is not None else {name: i for i, name in enumerate(spec.components)}
            found.extend((cname, other) for other in sorted(read & order.keys(), key=order.get) if other != cname)
    return found


def state_reads(comp) -> Optional[set]:
    """The components whose states a component's expressions read (names written in full,
    ``wheel.theta``): a modulation's `K`, a transformer's or gyrator's `ratio`, a source's
    `value` (feedback): the fields the type's registry entry names in ``state_reads``. None
    when an expression does not parse (its error is reported when the component is lowered)."""
    entry = find(getattr(comp, "type", None))
    read: set = set()
    for name in entry.state_reads.fields if entry is not None else ():
        found = _reads_of_value(getattr(comp, name)) if getattr(comp, name) is not None else set()
        if found is None:
            return None
        read |= found
    return read


def reading_order(components: list, cut=None) -> tuple[list[str], dict[str, list[str]], set[str]]:
    """Names of `components` ((name, spec) pairs of one file, each reading others' states:
    :func:`state_reads`) ordered so that each comes after those of them it reads (a source
    after the signal block whose output it reads), otherwise as given; for each one on a
    cycle of reads, the sorted names of the components on or reached from that cycle
    (those and the ones reading them are left out of the order); and the components read
    before they come in the order.

    `cut(reader, read)` says which reads may come before what they read (a signal block
    reading another block's output: the output is then a variable of the model, and an
    algebraic loop among such outputs is found once the model is assembled). Those reads
    are cut only where nothing else can be ordered (on cycles), one component at a time:
    the first pending one, as written, whose remaining reads are all cuttable."""
    names = {name for name, _ in components}
    reads = {name: (state_reads(comp) or set()) & names - {name} for name, comp in components}
    done: set = set()
    order: list[str] = []
    early: set = set()
    pending = [name for name, _ in components]
    while pending:
        ready = [name for name in pending if reads[name] <= done]
        if not ready and cut is not None:
            ready = [name for name in pending if all(r in done or cut(name, r) for r in reads[name])][:1]
            early.update(r for name in ready for r in reads[name] - done)
        if not ready:
            break
        done.update(ready)
        order.extend(ready)
        pending = [name for name in pending if name not in done]
    cycles = {}
    for name in pending:
        seen, todo = set(), list(reads[name] - done)
        while todo:  # what it reads, directly or through the others left
            r = todo.pop()
            if r not in seen:
                seen.add(r)
                todo.extend(reads[r] - done)
        if name in seen:
            cycles[name] = sorted(seen)
    return order, cycles, early


def _reads_of_value(matrix) -> Optional[set]:
    entries = ([e for row in matrix for e in (row if isinstance(row, list) else [row])]
               if isinstance(matrix, list) else [matrix])
    try:
        names = {str(s) for entry in entries if isinstance(entry, (str, int, float))
                 for s in validate_syntax(entry).free_symbols}
    except ExpressionError:
        return None
    return {_owner(n) for n in names if "." in n}


def _topology_reads(top: Topology) -> list[tuple[str, str]]:
    """(reader, read) for each Dirac structure that depends on another component's states."""
    names = {name for name, _, _ in top.components}
    found = {}
    for rel in top.dirac:
        for state in rel.states:
            name = str(state)
            # a reading (phc.library.lumped.reading_name) reads its port's owner
            if ".reads(" in name and name.endswith(")"):
                name = name[name.index(".reads(") + len(".reads("):-1]
            parts = name.split(".")
            owners = (".".join(parts[:k]) for k in range(len(parts) - 1, 0, -1))  # longest first
            owner = next((o for o in owners if o in names), None)
            if owner is not None and owner != rel.component:
                found[rel.component, owner] = None
    return list(found)


def _elements(source: Topology | ModelSpec) -> tuple[list, list, list, list, list]:
    """Components, ports, connections, exposed ports and reads of a spec or a topology."""
    if isinstance(source, Topology):
        ports = [(p.name, p.component, {"domain": p.domain, "dimension": p.dimension, "frame": p.frame})
                 for p in source.ports]
        return (list(source.components), ports, list(source.connections), list(source.exposed),
                _topology_reads(source))
    components = [(name, comp.type, None) for name, comp in source.components.items()]
    connections = [(*conn.between, f"connections[{i}]", None) for i, conn in enumerate(source.connections)]
    exposed = [(pname, exp.port) for pname, exp in source.ports.items()]
    refs = [ref for a, b, _, _ in connections for ref in (a, b)] + [full for _, full in exposed]
    ports = [(ref, _owner(ref), {}) for ref in dict.fromkeys(refs)]
    known = {name for name, _, _ in components}
    components += [(owner, None, None) for owner in dict.fromkeys(o for _, o, _ in ports) if owner not in known]
    return components, ports, connections, exposed, reads_of(source)


def build_interconnection_graph(source: Topology | ModelSpec) -> nx.MultiGraph:
    """Components, ports and connections of a :class:`~phc.spec.ModelSpec` or a
    :class:`~phc.ir.dae.Topology` as one multigraph (see the module docstring)."""
    import networkx as nx  # here, not on import: compile needs no graph (0.3 s CPU)

    components, ports, connections, exposed, reads = _elements(source)
    graph = nx.MultiGraph()
    graph.add_nodes_from((("component", name), {"type": type_, "span": span}) for name, type_, span in components)
    graph.add_nodes_from((("port", name), info) for name, _, info in ports)
    graph.add_edges_from((("component", component), ("port", name), {"kind": "has"}) for name, component, _ in ports)
    graph.add_edges_from((("port", a), ("port", b), {"kind": "connection", "label": label, "span": span, "index": i,
                                                     "ports": (a, b)})
                         for i, (a, b, label, span) in enumerate(connections))
    graph.add_nodes_from(("external", pname) for pname, _ in exposed)
    graph.add_edges_from((("port", full), ("external", pname), {"kind": "exposed"}) for pname, full in exposed)
    graph.add_edges_from((("component", reader), ("component", read), {"kind": "reads"}) for reader, read in reads)
    return graph


Source = Union[Topology, "ModelSpec", "nx.MultiGraph"]
"""A topology, a model spec, or a graph already built from one."""


def _graph(source: Source) -> nx.MultiGraph:
    return source if _is_graph(source) else build_interconnection_graph(source)


def _is_graph(source) -> bool:
    """`source` is a networkx multigraph (there is none while networkx was never imported)."""
    nx = sys.modules.get("networkx")
    return nx is not None and isinstance(source, nx.MultiGraph)


# -- the wiring check ---------------------------------------------------------------------
@dataclass(frozen=True, eq=False)
class Interconnection:
    """The output of the interconnect pass: the valid connections as (port a, port b,
    source span, label), the top-level exposed ports (name -> (full port name, span)) and
    the wiring problems found."""

    connections: tuple
    exposed: Mapping
    diagnostics: DiagnosticList


def interconnect(elab) -> Interconnection:
    """The interconnect pass. Input: an :class:`phc.frontend.elaborate.Elaboration`. Output: an
    :class:`Interconnection` (see :func:`check_connections`)."""
    return check_connections(elab, elab.top)


def _domain_text(domain: str) -> str:
    """`electrical (effort V, flow A)`: a domain with its units (:data:`phc.frontend.units.DOMAIN_UNITS`)."""
    from phc.frontend.units import DOMAIN_UNITS

    units = DOMAIN_UNITS.get(domain)
    return f"{domain} (effort {units[0]}, flow {units[1]})" if units else domain


def check_connections(b, ctx) -> Interconnection:
    """Resolve and check the connections of `b` (an :class:`phc.frontend.elaborate.Elaboration`);
    `ctx` is the top-level file's context.

    Each port is used once (PHC-E202, E203), connected ports agree in domain, dimension and
    frame (PHC-E204 to E206), an exposed port is not also connected (PHC-E207), and no port
    is left dangling (PHC-E208); every problem is a located diagnostic of the result.
    """
    diags = DiagnosticList()
    exposed_top: dict = {}
    used: dict[str, str] = {}
    valid = []
    suspects = set(b.failed)  # components whose ports may be the target of a broken reference
    for a_name, b_name, span, label in b.connections:
        a_full, b_full = b.resolve_alias(a_name), b.resolve_alias(b_name)
        pa, pb = b.ports.get(a_full), b.ports.get(b_full)
        if pa is None or pb is None:
            for p, ref in ((pa, a_full), (pb, b_full)):  # the broken end is already reported
                if p is not None:
                    used.setdefault(p.name, label)
                else:
                    suspects.add(ref.rsplit(".", 1)[0] if "." in ref else ref)
            continue
        ok = True
        if a_full == b_full:
            used[a_full] = label
            diags.append(Diagnostic("PHC-E202", f"port `{a_name}` is connected to itself", span=span,
                                      path=label))
            continue
        for p, shown in ((pa, a_name), (pb, b_name)):
            if p.name in used:
                diags.append(Diagnostic(
                    "PHC-E203", f"port `{shown}` is connected twice (also in {used[p.name]})", span=span,
                    hint="use a `junction` component to join more than two ports", path=label))
                ok = False
            used[p.name] = label
        if pa.domain != pb.domain and "generic" not in (pa.domain, pb.domain):
            diags.append(Diagnostic(
                "PHC-E204", f"port `{a_name}` is {_domain_text(pa.domain)} but port `{b_name}` it connects to is "
                f"{_domain_text(pb.domain)}", span=span, path=label,
                hint="connect ports of the same physical domain; a `transformer` or `gyrator` couples two domains"))
            ok = False
        if pa.dimension != pb.dimension:
            diags.append(Diagnostic(
                "PHC-E205", f"port `{a_name}` has dimension {pa.dimension}, but port `{b_name}` it connects "
                f"to has dimension {pb.dimension}", span=span, path=label,
                hint="use an `orthogonal_transform` with `split` to connect parts of a vector port"))
            ok = False
        if pa.frame and pb.frame and pa.frame != pb.frame:
            diags.append(Diagnostic(
                "PHC-E206", f"port `{a_name}` is in frame `{pa.frame}` but port `{b_name}` is in frame "
                f"`{pb.frame}`", span=span, path=label,
                hint="insert an `orthogonal_transform` between the frames"))
            ok = False
        if ok:
            valid.append((pa, pb, span, label))
    exposed = set()
    exposed_as: dict[str, str] = {}
    for pname, exp in ctx.spec.ports.items():
        full = b.resolve_alias(exp.port)
        if full in b.ports:
            if full in exposed_as:
                diags.append(Diagnostic(
                    "PHC-E207", f"port `{exp.port}` is exposed twice, as `{exposed_as[full]}` and as `{pname}`",
                    span=ctx.smap.locate(("ports", pname)), path=f"ports.{pname}",
                    hint="expose a port once; to give it two connections outside, expose a `junction`'s port"))
                continue
            exposed_as[full] = pname
            if full in used:
                diags.append(Diagnostic(
                    "PHC-E207", f"port `{exp.port}` is both exposed as `{pname}` and connected ({used[full]})",
                    span=ctx.smap.locate(("ports", pname)), path=f"ports.{pname}",
                    hint="a port is either connected or exposed; use a `junction` to do both"))
            exposed.add(full)
            exposed_top[pname] = (full, ctx.smap.locate(("ports", pname)))
    nested_exposed = set(b.port_aliases.values())
    for name, port in b.ports.items():
        if port.component in suspects:
            continue  # do not cascade from a broken reference or a component that failed
        if name not in used and name not in exposed and name not in nested_exposed:
            diags.append(Diagnostic(
                "PHC-E208", f"port `{name}` is not connected", span=port.span, path=name,
                hint="connect it, expose it under `ports:`, or terminate it with a `zero_effort` (free) or "
                "`zero_flow` (fixed) component"))
    return Interconnection(tuple(valid), MappingProxyType(exposed_top), diags)


# -- views ----------------------------------------------------------------------------------
def component_of(top: Topology) -> dict[str, str]:
    return {p.name: p.component for p in top.ports}


def component_graph(source: Source, *, reads: bool = False) -> nx.MultiGraph:
    """Components as nodes, one edge per connection (labelled, in the order written);
    with `reads`, also an edge (``kind="reads"``) to each component whose states one reads.

    `source` may also be a component graph made here (returned as it is): build it once
    and pass it to :func:`kinematic_loops`, :func:`independent_parts` and
    :func:`traversal_order`."""
    if _is_component_graph(source):
        if source.graph["reads"] != reads:
            raise ValueError(f"a component graph made with reads={source.graph['reads']} was given where "
                             f"reads={reads} is needed")
        return source
    graph = _graph(source)
    owner, connections, read = {}, [], []
    for u, v, data in graph.edges(data=True):
        if data["kind"] == "has":
            (comp, port) = (u, v) if u[0] == "component" else (v, u)
            owner[port[1]] = comp[1]
        elif data["kind"] == "connection":
            connections.append(data)
        elif data["kind"] == "reads":
            read.append((u[1], v[1]))
    import networkx as nx

    comps = nx.MultiGraph(view="components", reads=reads)
    comps.add_nodes_from(name for kind, name in graph if kind == "component")
    for data in sorted(connections, key=lambda d: d["index"]):
        a, b = data["ports"]
        comps.add_edge(owner[a], owner[b], label=data["label"], ports=(a, b), span=data["span"],
                       index=data["index"])
    if reads:
        for u, v in read:
            comps.add_edge(u, v, kind="reads")
    return comps


def _is_component_graph(source) -> bool:
    return _is_graph(source) and source.graph.get("view") == "components"


def connected_to(source: Source, names) -> set[str]:
    """Components with a path to one of `names` through connections and reads: the only
    ones that can influence them (power ports couple both ways)."""
    import networkx as nx

    graph = component_graph(source, reads=True)
    return set().union(*(nx.node_connected_component(graph, name) for name in names))


def kinematic_loops(source: Source) -> list[list[str]]:
    """A cycle basis of the component graph (:func:`short_cycle_basis`); parallel
    connections count as loops.

    Loops of connections imply algebraic constraints among the components' flows
    (information, not an error).
    """
    import networkx as nx

    graph = component_graph(source)
    simple = nx.Graph(graph)
    loops = short_cycle_basis(simple)
    for u, v in simple.edges():
        if graph.number_of_edges(u, v) > 1:
            loops.extend([[u, v]] * (graph.number_of_edges(u, v) - 1))
    return loops


def short_cycle_basis(graph: nx.Graph, search: int = 64) -> list[list]:
    """A basis of the cycle space of the simple graph `graph` made of short cycles, each a
    list of nodes in the order met along it.

    A spanning tree's fundamental cycles (``nx.cycle_basis``) are a basis too, but on a
    mesh they run around ever larger parts of it (on a 30 × 30 grid of cells, up to 120
    components), and a loop's test in ``phc check`` grows with its length. Here every edge
    on a cycle proposes the shortest cycle through it, found by a breadth-first search of at
    most `search` levels; the proposals are taken shortest first (ties in edge order) while
    they are independent, and fundamental cycles of a breadth-first tree complete the basis
    where the proposals do not span it. On a grid every basis cycle is a cell.

    Independence is decided exactly, over GF(2), on the cycles' *chord* coordinates: a
    cycle is the sum of the fundamental cycles of the tree's chords it uses, so the map to
    its set of chords is one-to-one on the cycle space. Vectors are Python integers (bit k:
    chord k), reduced against pivots at their highest bit. The fundamental cycles that
    complete the basis are those of the chords that are no pivot, independent of the rest
    because their highest bits differ. The number of cycles is ``m − n + c`` (edges, nodes,
    connected parts) as for any basis. Deterministic for a given graph: nodes and edges are
    taken in the graph's order."""
    order = {node: k for k, node in enumerate(graph)}
    parent, depth, chords = {}, {}, {}
    for root in graph:  # a breadth-first tree per connected part
        if root in parent:
            continue
        parent[root], depth[root] = None, 0
        frontier = [root]
        while frontier:
            nxt = []
            for u in frontier:
                for v in graph[u]:
                    if v not in parent:
                        parent[v], depth[v] = u, depth[u] + 1
                        nxt.append(v)
            frontier = nxt
    for u, v in graph.edges():
        if parent.get(v) != u and parent.get(u) != v:
            chords[_edge(u, v, order)] = len(chords)
    if not chords:
        return []

    def bits(cycle):
        vector = 0
        for k in range(len(cycle)):
            chord = chords.get(_edge(cycle[k], cycle[k - 1], order))
            if chord is not None:
                vector |= 1 << chord
        return vector

    import networkx as nx

    bridges = {_edge(*bridge, order) for bridge in nx.bridges(graph)}  # edges on no cycle
    candidates = {}  # one per cycle (several edges propose the same one)
    for u, v in graph.edges():
        if _edge(u, v, order) not in bridges:
            cycle = _shortest_cycle_through(graph, u, v, search)
            if cycle is not None:
                candidates.setdefault(frozenset(_edge(cycle[k], cycle[k - 1], order) for k in range(len(cycle))), cycle)
    pivots, basis = {}, []
    for cycle in sorted(candidates.values(), key=len):
        vector = bits(cycle)
        while vector:
            top = vector.bit_length() - 1
            if top not in pivots:
                pivots[top] = vector
                basis.append(cycle)
                break
            vector ^= pivots[top]
        if len(basis) == len(chords):
            break
    if len(basis) < len(chords):
        for (u, v), k in chords.items():
            if k not in pivots:
                basis.append(_tree_cycle(u, v, parent, depth))
    return basis


def _edge(u, v, order) -> tuple:
    return (u, v) if order[u] <= order[v] else (v, u)


def _shortest_cycle_through(graph: nx.Graph, u, v, levels: int) -> Optional[list]:
    """The shortest cycle through edge (u, v): a breadth-first path from u to v that does not
    use the edge, as [u, …, v]; None when none is found within `levels` levels."""
    previous = {u: None}
    frontier = [u]
    for _ in range(levels):
        nxt = []
        for a in frontier:
            for b in graph[a]:
                if b in previous or (a == u and b == v):
                    continue
                previous[b] = a
                if b == v:
                    path = [v]
                    while previous[path[-1]] is not None:
                        path.append(previous[path[-1]])
                    return path[::-1]
                nxt.append(b)
        frontier = nxt
        if not frontier:
            break
    return None


def _tree_cycle(u, v, parent, depth) -> list:
    """The fundamental cycle of chord (u, v): the tree path from u up to the common ancestor
    and down to v."""
    up, down = [u], [v]
    while depth[up[-1]] > depth[down[-1]]:
        up.append(parent[up[-1]])
    while depth[down[-1]] > depth[up[-1]]:
        down.append(parent[down[-1]])
    while up[-1] != down[-1]:
        up.append(parent[up[-1]])
        down.append(parent[down[-1]])
    return up + down[-2::-1]


def independent_parts(source: Source) -> list[list[str]]:
    """Sets of components with no connection between them (sorted, largest first)."""
    return _parts(component_graph(source))


def _parts(graph: nx.MultiGraph) -> list[list[str]]:
    import networkx as nx

    parts = [sorted(c) for c in nx.connected_components(graph)]
    return sorted(parts, key=lambda c: (-len(c), c))


def traversal_order(source: Source) -> list[tuple[str, str, str]]:
    """Connections as (port_a, port_b, label) in breadth-first order from each part's
    first component: tree edges before the loop-closing ones (any order gives the same
    interconnection by the paper's Remark 4 "Associativity of interconnection"). Every
    connection appears once, told apart by its place in the model (not by its label)."""
    import networkx as nx

    graph = component_graph(source)
    order, seen = [], set()
    for part in _parts(graph):
        root = part[0]
        for u, v, key in nx.edge_bfs(graph, root):
            data = graph.get_edge_data(u, v, key)
            if data["index"] not in seen:
                seen.add(data["index"])
                order.append((*data["ports"], data["label"]))
    return order


def to_dot(top: Topology, name: str = "model") -> str:
    """Graphviz DOT text: one cluster per component with its ports, edges for connections."""
    from phc.inert import inert

    def q(text):  # a quoted DOT string of one line, without control characters (phc.inert)
        return '"' + inert(text).replace('"', r"\"") + '"'

    lines = [f"graph {q(name)} {{", "  rankdir=LR;", "  node [fontsize=10];"]
    by_comp: dict[str, list] = {}
    for port in top.ports:
        by_comp.setdefault(port.component, []).append(port)
    for i, (comp, type_, _) in enumerate(top.components):
        lines.append(f"  subgraph cluster_{i} {{")
        lines.append(f"    label={q(f'{comp} ({type_})')}; style=rounded;")
        for port in by_comp.get(comp, []):
            lines.append(f"    {q(port.name)} [label={q(port.name.rsplit('.', 1)[-1] + f' [{port.dimension}]')}, "
                         "shape=box];")
        lines.append("  }")
    for a, b, label, _ in top.connections:
        lines.append(f"  {q(a)} -- {q(b)} [label={q(label)}];")
    for pname, full in top.exposed:
        lines.append(f"  {q('ext:' + pname)} [label={q(pname)}, shape=doublecircle];")
        lines.append(f"  {q(full)} -- {q('ext:' + pname)} [style=dashed];")
    lines.append("}")
    return "\n".join(lines) + "\n"
