"""Equation/variable balance and maximum matching (pipeline stage 7).

A DAE is structurally solvable only if its bipartite incidence graph (equations ×
variables, a variable incident to a row when it or its derivative occurs there) has a
perfect matching. We report counts first, then the culprits, in the style of
ModelingToolkit's structural checks.
"""

from __future__ import annotations

import networkx as nx

from phc.dae import Dae
from phc.diagnostics import Diagnostic


def incidence(dae: Dae) -> list[set[int]]:
    """For each equation, the set of variable indices occurring in it (value or derivative)."""
    col = {}
    for j, v in enumerate(dae.variables):
        col[v.symbol] = j
        if v.dsymbol is not None:
            col[v.dsymbol] = j
    rows = [{col[s] for s in eq.expr.free_symbols if s in col} for eq in dae.equations]
    for block in dae.linear_blocks:
        for term in block.terms:
            coo = term.matrix.tocoo()
            for i, j in zip(coo.row, coo.col):
                rows[block.rows[i]].add(col[term.symbols[j]])
    return rows


def maximum_matching(dae: Dae) -> dict[int, int]:
    """Maximum matching equation index → variable index (networkx Hopcroft–Karp).

    Nodes are integers (equation i → i, variable j → m + j): their hashes do not depend on
    PYTHONHASHSEED, so which of several redundant rows is reported is reproducible."""
    m = len(dae.equations)
    graph = nx.Graph()
    eq_nodes = list(range(m))
    graph.add_nodes_from(eq_nodes)
    graph.add_nodes_from(m + j for j in range(len(dae.variables)))
    for i, cols in enumerate(incidence(dae)):
        graph.add_edges_from((i, m + j) for j in sorted(cols))
    # The energy accumulator Ė = P is matched to its own row first: it is phc's
    # bookkeeping, and must never be reported as an undetermined unknown.
    for i, eq in enumerate(dae.equations):
        if eq.kind == "energy":
            j = next(j for j, v in enumerate(dae.variables) if v.role == "energy")
            graph.remove_edges_from(list(graph.edges(i)))
            graph.remove_edges_from(list(graph.edges(m + j)))
            graph.add_edge(i, m + j)
    matching = nx.bipartite.hopcroft_karp_matching(graph, top_nodes=eq_nodes)
    return {i: matching[i] - m for i in eq_nodes if i in matching}


def check_balance(dae: Dae) -> list[Diagnostic]:
    """Counts and unmatched equations/variables as diagnostics (empty when solvable)."""
    n_eq, n_var = len(dae.equations), len(dae.variables)
    match = maximum_matching(dae)
    if n_eq == n_var and len(match) == n_eq:
        return []
    matched_vars = set(match.values())
    free_vars = [v for j, v in enumerate(dae.variables) if j not in matched_vars]
    extra_eqs = [eq for i, eq in enumerate(dae.equations) if i not in match]
    out = []
    head = (f"the model is {'unbalanced' if n_eq != n_var else 'structurally singular'}: "
            f"{n_eq} equations, {n_var} unknowns")
    if extra_eqs:
        names = ", ".join(f"`{eq.label}`" + (f" ({eq.span})" if eq.span else "") for eq in extra_eqs[:6])
        out.append(Diagnostic("PHC-E302", f"{head}; equation(s) with no unknown left to determine: {names}",
                              span=extra_eqs[0].span,
                              hint="two components may impose the same quantity (e.g. two flow sources on one "
                              "node); remove one or connect through a component that can absorb it"))
    if free_vars:
        names = ", ".join(f"`{v.name}`" for v in free_vars[:6])
        out.append(Diagnostic("PHC-E303", f"{head}; unknown(s) no equation determines: {names}",
                              span=free_vars[0].span,
                              hint="a port may be left without a termination, or a multiplier without a "
                              "constraint"))
    return out
