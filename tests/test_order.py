"""phc.analysis.order: the dependency order the compile path uses instead of networkx's."""

import random

import networkx as nx

from phc.analysis.order import topological_order


def test_the_order_is_networkx_topological_sort_on_random_dags():
    """Same nodes, then the same edges (some repeated, some naming nodes not listed): the very
    list networkx gives, since the generated code orders derived parameters by it."""
    rng = random.Random(7)
    for _ in range(200):
        n = rng.randint(0, 12)
        nodes = rng.sample(range(20), n)
        edges = []
        for _ in range(rng.randint(0, 25)):
            a, b = rng.sample(range(22), 2)
            edges.append((min(a, b), max(a, b)))  # low to high: acyclic
        edges += edges[: len(edges) // 3]
        graph = nx.DiGraph()
        graph.add_nodes_from(nodes)
        graph.add_edges_from(edges)
        assert topological_order(nodes, edges) == list(nx.topological_sort(graph))


def test_a_cycle_gives_none():
    assert topological_order("abc", [("a", "b"), ("b", "c"), ("c", "a")]) is None
    assert topological_order("ab", [("a", "a")]) is None
    assert topological_order("abc", [("a", "b")]) == ["a", "c", "b"]
