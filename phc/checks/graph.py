"""The interconnection graph (networkx): components, ports, connections.

Nodes are typed tuples: ``("component", name)``, ``("port", full_name)`` and
``("external", name)`` for ports exposed by the top-level model. Edges carry
``kind`` = ``has`` (component–port), ``connection`` (port–port, seed eq. couplcond)
or ``exposed``.
"""

from __future__ import annotations

import networkx as nx

from phc.dae import Topology


def build_interconnection_graph(top: Topology) -> nx.MultiGraph:
    """Components, ports and connections as one multigraph."""
    graph = nx.MultiGraph()
    for name, type_, span in top.components:
        graph.add_node(("component", name), type=type_, span=span)
    for port in top.ports:
        graph.add_node(("port", port.name), domain=port.domain, dimension=port.dimension, frame=port.frame)
        graph.add_edge(("component", port.component), ("port", port.name), kind="has")
    for a, b, label, span in top.connections:
        graph.add_edge(("port", a), ("port", b), kind="connection", label=label, span=span)
    for pname, full in top.exposed:
        graph.add_node(("external", pname))
        graph.add_edge(("port", full), ("external", pname), kind="exposed")
    return graph


def component_of(top: Topology) -> dict[str, str]:
    return {p.name: p.component for p in top.ports}


def component_graph(top: Topology) -> nx.MultiGraph:
    """Components as nodes, one edge per connection (labelled)."""
    owner = component_of(top)
    graph = nx.MultiGraph()
    graph.add_nodes_from(name for name, _, _ in top.components)
    for a, b, label, span in top.connections:
        graph.add_edge(owner[a], owner[b], label=label, ports=(a, b), span=span)
    return graph


def kinematic_loops(top: Topology) -> list[list[str]]:
    """A cycle basis of the component graph; parallel connections count as loops.

    Loops of connections imply algebraic constraints among the components' flows
    (information, not an error).
    """
    graph = component_graph(top)
    simple = nx.Graph(graph)
    loops = [list(c) for c in nx.cycle_basis(simple)]
    for u, v in simple.edges():
        if graph.number_of_edges(u, v) > 1:
            loops.extend([[u, v]] * (graph.number_of_edges(u, v) - 1))
    return loops


def independent_parts(top: Topology) -> list[list[str]]:
    """Sets of components with no connection between them (sorted, largest first)."""
    parts = [sorted(c) for c in nx.connected_components(component_graph(top))]
    return sorted(parts, key=lambda c: (-len(c), c))


def traversal_order(top: Topology) -> list[tuple[str, str, str]]:
    """Connections as (port_a, port_b, label) in breadth-first order from each part's
    first component: tree edges before the loop-closing ones (any order gives the same
    interconnection by the seed's Remark "Associativity of interconnection")."""
    graph = component_graph(top)
    order, seen = [], set()
    for part in independent_parts(top):
        root = part[0]
        for u, v, key in nx.edge_bfs(graph, root):
            data = graph.get_edge_data(u, v, key)
            if data["label"] not in seen:
                seen.add(data["label"])
                order.append((*data["ports"], data["label"]))
    return order


def to_dot(top: Topology, name: str = "model") -> str:
    """Graphviz DOT text: one cluster per component with its ports, edges for connections."""
    def q(text):
        return '"' + str(text).replace('"', r"\"") + '"'

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
