"""A dependency order of hashable nodes, without networkx.

What the compile path sorts (derived parameters by the parameters their values use) is small,
and networkx costs about 0.3 s CPU to import and to look up its backends on the first call: a
compile imports it only where a graph is drawn or analysed (:mod:`phc.ir.interconnect`).
:func:`topological_order` gives exactly the order of ``networkx.topological_sort`` on a
``DiGraph`` built with the same nodes and then the same edges (generation by generation, each
in the order its nodes became free), so generated code does not change with it.
"""

from __future__ import annotations

from typing import Hashable, Iterable, Optional


def topological_order(nodes: Iterable[Hashable], edges: Iterable[tuple[Hashable, Hashable]]) -> Optional[list]:
    """The nodes ordered so that each edge ``(a, b)`` has `a` before `b`, or None when the
    edges make a cycle. Nodes an edge names that are not in `nodes` are added after them, as
    ``DiGraph.add_edge`` adds them; an edge given twice counts once."""
    children: dict = {node: {} for node in nodes}
    for a, b in edges:
        children.setdefault(a, {})
        children.setdefault(b, {})
        children[a][b] = None
    indegree = dict.fromkeys(children, 0)
    for targets in children.values():
        for child in targets:
            indegree[child] += 1
    waiting = {node: d for node, d in indegree.items() if d > 0}
    generation = [node for node, d in indegree.items() if d == 0]
    order: list = []
    while generation:
        order.extend(generation)
        freed = []
        for node in generation:
            for child in children[node]:
                waiting[child] -= 1
                if waiting[child] == 0:
                    freed.append(child)
                    del waiting[child]
        generation = freed
    return None if waiting else order


__all__ = ["topological_order"]
