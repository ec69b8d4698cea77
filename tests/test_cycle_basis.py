"""Tests of :func:`phc.ir.interconnect.short_cycle_basis`, the loops `phc check` reports and
classifies: a basis of the cycle space (checked here by an independent GF(2) rank over
edge vectors), made of cycles of the graph, and short where short cycles exist (a grid's
cells, the girth of a cubic graph)."""

from __future__ import annotations

import networkx as nx
import numpy as np
import pytest

from phc.ir.interconnect import short_cycle_basis
from phc.checks import loops as loop_checks


def _gf2_rank(rows: np.ndarray) -> int:
    """Rank over GF(2) by Gaussian elimination on a 0/1 matrix (written here, independent of
    the code under test)."""
    a = rows.copy() % 2
    rank = 0
    for col in range(a.shape[1]):
        pivot = next((r for r in range(rank, a.shape[0]) if a[r, col]), None)
        if pivot is None:
            continue
        a[[rank, pivot]] = a[[pivot, rank]]
        for r in range(a.shape[0]):
            if r != rank and a[r, col]:
                a[r] ^= a[rank]
        rank += 1
    return rank


def _check_basis(graph: nx.Graph, basis: list) -> None:
    edges = {frozenset(e): k for k, e in enumerate(graph.edges())}
    dimension = graph.number_of_edges() - graph.number_of_nodes() + nx.number_connected_components(graph)
    assert len(basis) == dimension
    vectors = np.zeros((len(basis), len(edges)), dtype=np.uint8)
    for i, cycle in enumerate(basis):
        assert len(cycle) >= 3 and len(set(cycle)) == len(cycle), cycle  # a simple cycle
        for k in range(len(cycle)):
            vectors[i, edges[frozenset((cycle[k - 1], cycle[k]))]] = 1  # consecutive nodes adjacent
    assert _gf2_rank(vectors) == dimension  # independent, so a basis


GRAPHS = {
    "grid 7x9": nx.grid_2d_graph(7, 9),
    "petersen": nx.petersen_graph(),
    "K6": nx.complete_graph(6),
    "cubic 60": nx.random_regular_graph(3, 60, seed=3),
    "wheel": nx.wheel_graph(12),
    "two parts and a tree": nx.disjoint_union_all([nx.grid_2d_graph(3, 4), nx.cycle_graph(5),
                                                   nx.balanced_tree(2, 3)]),
    "ladder of long rings": nx.circular_ladder_graph(40),
    "tree": nx.balanced_tree(3, 3),
}


@pytest.mark.parametrize("name", sorted(GRAPHS))
def test_is_a_basis_of_cycles(name):
    graph = GRAPHS[name]
    _check_basis(graph, short_cycle_basis(graph))


@pytest.mark.parametrize("name", ["grid 7x9", "petersen", "K6", "cubic 60", "wheel"])
def test_no_longer_in_total_than_a_minimum_basis_allows(name):
    """Every cycle is at most as long as the longest of a minimum-weight basis (networkx's
    exact algorithm), and on the grid, K6, the wheel and Petersen the total equals it."""
    graph = GRAPHS[name]
    ours = sorted(map(len, short_cycle_basis(graph)))
    minimum = sorted(map(len, nx.minimum_cycle_basis(graph)))
    assert ours[-1] <= max(minimum) + 2  # greedy by shortest proposal: within a step of the optimum
    if name != "cubic 60":
        assert ours == minimum


def test_a_grid_gives_its_cells():
    basis = short_cycle_basis(nx.grid_2d_graph(30, 30))
    assert len(basis) == 29 * 29 and {len(c) for c in basis} == {4}
    assert len({frozenset(c) for c in basis}) == 29 * 29  # each cell once


def test_a_ring_longer_than_the_search_is_completed_by_the_tree():
    ring = nx.cycle_graph(500)
    (cycle,) = short_cycle_basis(ring, search=8)
    assert sorted(cycle) == list(range(500))
    _check_basis(ring, [cycle])


def test_same_graph_same_basis():
    """The basis depends on the order nodes and edges were added (as the graph built from a
    model is), not on string hashing: node names here are strings."""
    edges = [(f"c{u}", f"c{v}") for u, v in nx.random_regular_graph(3, 40, seed=7).edges()]
    assert short_cycle_basis(nx.Graph(edges)) == short_cycle_basis(nx.Graph(edges))


def test_phc_check_classifies_every_cell_of_a_mesh_of_springs(tmp_path):
    """A 6 × 6 mesh of masses joined by springs: 25 loops, each a cell of four masses and four
    springs, and none constrains (every loop opens at a spring); fundamental cycles of a tree
    would give loops of up to 4·(6 + 6 − 2) components."""
    import phc
    from phc.checks.certify import certify

    r = 6
    lines = ["format_version: 1", "name: mesh", "components:"]
    conns = []
    for i in range(r):
        for j in range(r):
            ports = [p for p, ok in (("w", j > 0), ("e", j < r - 1), ("n", i > 0), ("s", i < r - 1)) if ok]
            lines.append(f"  m{i}_{j}: {{type: mass, m: 1.0, ports: [{', '.join(ports)}]}}")
            if j < r - 1:
                lines.append(f"  h{i}_{j}: {{type: spring, k: 2.0, terminals: [a, b]}}")
                conns += [f"  - [m{i}_{j}.e, h{i}_{j}.a]", f"  - [h{i}_{j}.b, m{i}_{j + 1}.w]"]
            if i < r - 1:
                lines.append(f"  v{i}_{j}: {{type: spring, k: 2.0, terminals: [a, b]}}")
                conns += [f"  - [m{i}_{j}.s, v{i}_{j}.a]", f"  - [v{i}_{j}.b, m{i + 1}_{j}.n]"]
    path = tmp_path / "mesh.yaml"
    path.write_text("\n".join(lines + ["connections:", *conns]) + "\n")
    dae, diags = phc.build_dae(path)
    assert dae is not None, "\n".join(d.render() for d in diags)
    cert = certify(dae)
    assert len(cert.loops) == (r - 1) ** 2 and {len(loop) for loop in cert.loops} == {8}
    assert [v.components for v in cert.loop_verdicts] == cert.loops
    assert all(v.constraints == 0 for v in cert.loop_verdicts)
    assert max(map(len, cert.loops)) <= loop_checks.MAX_LOOP
