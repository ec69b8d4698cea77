"""The analyse pass: equation/variable balance and maximum matching.

Input: a :class:`~phc.ir.dae.Dae`. Output: located diagnostics (none when the DAE is
structurally solvable).

A DAE is structurally solvable only if its bipartite incidence graph (equations ×
variables, a variable incident to a row when it or its derivative occurs there) has a
perfect matching. We report counts first, then the culprits, in the style of
ModelingToolkit's structural checks.
"""

from __future__ import annotations

import heapq
from typing import TYPE_CHECKING, Optional

import numpy as np

if TYPE_CHECKING:  # the types only: bipartite_matching runs in simulations without sympy or pydantic
    import scipy.sparse as sps

    from phc.ir.dae import Dae
    from phc.diagnostics import Diagnostic

def unique_keys(keys: np.ndarray, return_index: bool = False, return_inverse: bool = False):
    """``np.unique`` of an integer array (sorted unique values; with `return_index` the
    position of each value's first occurrence, with `return_inverse` each entry's index in
    the unique values), by one sort. Recent numpy (2.4 measured) finds the unique values of
    an integer array by hashing before sorting them, about 60 times slower than a sort on the
    10⁶–10⁷ (row, column) keys of a 10⁵-element mesh (1.7 s against 0.03 s for 10⁶ keys)."""
    keys = np.asarray(keys)
    if not (return_index or return_inverse):
        s = np.sort(keys)
        new = np.ones(len(s), dtype=bool)
        np.not_equal(s[1:], s[:-1], out=new[1:])
        return s[new]
    order = np.argsort(keys, kind="stable")
    s = keys[order]
    new = np.ones(len(s), dtype=bool)
    np.not_equal(s[1:], s[:-1], out=new[1:])
    out = [s[new]]
    if return_index:
        out.append(order[new])
    if return_inverse:
        inverse = np.empty(len(keys), dtype=np.intp)
        inverse[order] = np.cumsum(new) - 1
        out.append(inverse)
    return tuple(out)


PREFER_EARLY_WORK = 50_000_000
"""Above (unmatched rows + columns) × nonzeros, the matching is not rearranged to leave the
latest rows and columns unmatched (still deterministic, just not that particular one)."""


def incidence(dae: Dae) -> tuple[np.ndarray, np.ndarray]:
    """The incidence of `dae` as (row, column) index arrays, ordered by row and, within a
    row, by column, each pair once: variable j occurs (value or derivative) in equation i.

    Rows written in sympy are read from their free symbols; the sparse rows of linear
    blocks from their matrices' stored entries, with numpy (one Python step per term, not
    per entry: a 10⁵-element mesh has about 10⁶ of them)."""
    col = {}
    for j, v in enumerate(dae.variables):
        col[v.symbol] = j
        if v.dsymbol is not None:
            col[v.dsymbol] = j
    rows, cols = [], []
    if hasattr(dae, "row_symbols"):
        found = dae.row_symbols()
    else:  # a system that is not a Dae, with `equations`
        from phc.ir.dae import equation_symbols

        found = equation_symbols(dae.equations)
    for i, symbols in enumerate(found):
        # a number has none: a row of a linear block (most rows of a mesh), read from its matrices below
        for s in symbols:
            j = col.get(s)
            if j is not None:
                rows.append(i)
                cols.append(j)
    row_parts, col_parts = [np.asarray(rows, dtype=np.int64)], [np.asarray(cols, dtype=np.int64)]
    for block in dae.linear_blocks:
        block_rows = np.asarray(block.rows, dtype=np.int64)
        for term in block.terms:
            coo = term.matrix.tocoo()
            term_cols = np.fromiter((col[s] for s in term.symbols), dtype=np.int64, count=len(term.symbols))
            row_parts.append(block_rows[coo.row])
            col_parts.append(term_cols[coo.col])
    width = max(len(dae.variables), 1)
    keys = unique_keys(np.concatenate(row_parts) * width + np.concatenate(col_parts))
    return keys // width, keys % width


def bipartite_matching(pattern, prefer_early: bool = False) -> np.ndarray:
    """Maximum matching of the rows of a sparse `pattern` (m × n; a row is incident to a
    column where an entry is stored and nonzero) to its columns: ``match[i]`` is the
    column of row i, or −1.

    Solved as a unit-capacity maximum flow (source → rows → columns → sink) by scipy's
    Dinic algorithm: compiled, no recursion (a chain of 2·10⁶ rows takes about 2 s), and
    polynomial. networkx's Hopcroft–Karp recursed once per link of a chain and overflowed
    Python's stack at about a thousand; scipy's own ``maximum_bipartite_matching`` never
    marks dead ends in its depth-first phase and takes exponential time on layered
    patterns such as a discretized beam's (scipy issue 26147: a 125-element cantilever
    did not finish). The result depends only on the pattern, never on hashing. With
    `prefer_early`, among all maximum matchings the one is returned whose matched rows
    are lexicographically first, and then likewise its matched columns: of redundant rows
    the latest are left unmatched, of undetermined columns the latest (a diagnosis names
    what was added last)."""
    import scipy.sparse as sps  # here: a balanced model's check needs no search (check_balance)
    from scipy.sparse.csgraph import maximum_flow

    a = sps.csr_matrix(pattern, copy=True)
    a.sum_duplicates()  # duplicates would also corrupt scipy's matching (scipy issue 26160)
    a.eliminate_zeros()
    m, n = a.shape
    if m == 0 or n == 0 or a.nnz == 0:
        return np.full(m, -1, dtype=np.int64)
    coo = a.tocoo()
    source, sink = m + n, m + n + 1
    tails = np.concatenate([np.full(m, source), coo.row, m + np.arange(n)])
    heads = np.concatenate([np.arange(m), m + coo.col, np.full(n, sink)])
    network = sps.csr_matrix((np.ones(len(tails), dtype=np.int32), (tails, heads)), shape=(m + n + 2, m + n + 2))
    del coo, tails, heads  # freed before the flow's own arrays are made (a mesh's peak, issue 35)
    flow = maximum_flow(network, source, sink, method="dinic").flow
    del network
    flow = flow.tocoo()
    used = (flow.data > 0) & (flow.row < m) & (flow.col >= m) & (flow.col < m + n)
    match = np.full(m, -1, dtype=np.int64)
    match[flow.row[used]] = flow.col[used] - m
    if prefer_early:
        a.data = np.ones_like(a.data, dtype=np.int8)
        free = int(np.count_nonzero(match < 0)) + (n - int(np.count_nonzero(match >= 0)))
        if free and free * max(a.nnz, 1) <= PREFER_EARLY_WORK:
            match = _prefer_early(a, match)
            col_of = np.full(n, -1, dtype=np.int64)
            rows = np.flatnonzero(match >= 0)
            col_of[match[rows]] = rows
            col_of = _prefer_early(a.T.tocsr(), col_of)
            match = np.full(m, -1, dtype=np.int64)
            cols = np.flatnonzero(col_of >= 0)
            match[col_of[cols]] = cols
    return match


def _prefer_early(a: sps.csr_matrix, match: np.ndarray) -> np.ndarray:
    """Rearrange a maximum matching (rows of `a` → columns) so that its set of matched rows
    is the lexicographically first one; the set of matched columns stays the same.

    The matchable row sets are the bases of a transversal matroid, and the greedy basis is
    the only one that no exchange improves: an unmatched row u can replace a matched row
    r exactly when an alternating path leads from u to r. So each unmatched row, in
    ascending order, searches its alternating paths (breadth first, iterative) for the
    latest matched row after it and takes that row's place; the row pushed out is
    examined in its turn. An exchange never opens one for a row already examined."""
    indptr, indices = a.indptr, a.indices
    row_match = [int(c) for c in match]
    col_match = [-1] * a.shape[1]
    for i, c in enumerate(row_match):
        if c >= 0:
            col_match[c] = i
    todo = [i for i, c in enumerate(row_match) if c < 0]
    heapq.heapify(todo)
    while todo:
        u = heapq.heappop(todo)
        if row_match[u] >= 0:
            continue
        parent = {u: (-1, -1)}
        queue, best, k = [u], -1, 0
        while k < len(queue):
            r = queue[k]
            k += 1
            for c in indices[indptr[r]:indptr[r + 1]].tolist():
                r2 = col_match[c]
                if r2 < 0 or r2 in parent:
                    continue  # r2 < 0 cannot happen for a maximum matching
                parent[r2] = (r, c)
                queue.append(r2)
                if r2 > best:
                    best = r2
        if best <= u:
            continue
        cur = best
        row_match[best] = -1
        while cur != u:
            prev, c = parent[cur]
            row_match[prev] = c
            col_match[c] = prev
            cur = prev
        heapq.heappush(todo, best)
    return np.asarray(row_match, dtype=np.int64)


def maximum_matching(dae: Dae, pattern: Optional[tuple[np.ndarray, np.ndarray]] = None) -> dict[int, int]:
    """Maximum matching equation index → variable index.

    Of several redundant equations the latest are left unmatched, of undetermined
    variables the latest (:func:`bipartite_matching` with `prefer_early`): the diagnosis
    is reproducible and names what was added last. `pattern`: ``incidence(dae)`` when
    the caller has it."""
    import scipy.sparse as sps

    m, n = len(dae.equations), len(dae.variables)
    rows, cols = incidence(dae) if pattern is None else pattern
    # The energy accumulator Ė = P is matched to its own row first: it is phc's
    # bookkeeping, and must never be reported as an undetermined unknown.
    for i, eq in enumerate(dae.equations):
        if eq.kind == "energy":
            j = next(j for j, v in enumerate(dae.variables) if v.role == "energy")
            keep = (rows != i) & (cols != j)
            rows, cols = np.append(rows[keep], i), np.append(cols[keep], j)
    pattern = sps.csr_matrix((np.ones(len(rows), dtype=np.int8), (rows, cols)), shape=(m, n))
    del rows, cols  # freed before the matching's flow network is made (a mesh's peak, issue 35)
    match = bipartite_matching(pattern, prefer_early=True)
    return {i: int(c) for i, c in enumerate(match) if c >= 0}


def check_balance(dae: Dae) -> list[Diagnostic]:
    """Counts and unmatched equations/variables as diagnostics (empty when solvable).

    A model that a matching without search (:func:`perfect_without_search`) pairs row by
    row with its unknowns is solvable, and nothing more is computed; otherwise the maximum
    matching (:func:`maximum_matching`) finds what to report."""
    n_eq, n_var = len(dae.equations), len(dae.variables)
    pattern = incidence(dae)
    if n_eq == n_var and perfect_without_search(n_eq, n_var, *pattern):
        return []
    match = maximum_matching(dae, pattern)
    if n_eq == n_var and len(match) == n_eq:
        return []
    matched_vars = set(match.values())
    free_vars = [v for j, v in enumerate(dae.variables) if j not in matched_vars]
    extra_eqs = [eq for i, eq in enumerate(dae.equations) if i not in match]
    from phc.diagnostics import Diagnostic

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


WITHOUT_SEARCH_LIMIT = 1_000_000
"""Above this many incidence entries :func:`perfect_without_search` is not tried (its loop is
Python's; a mesh that large has its rows in sparse blocks, and scipy is loaded anyway)."""


def perfect_without_search(m: int, n: int, rows: np.ndarray, cols: np.ndarray) -> bool:
    """Whether the m × n pattern (`rows`, `cols`: its entries, as :func:`incidence` gives
    them) has a perfect matching that the Karp–Sipser rule finds without search: a row or
    column left with one unmatched neighbour takes it (some maximum matching pairs them,
    so this choice is never wrong), and when none is left the first unmatched row takes its
    first unmatched column (a guess). True means every row and every column were paired
    (m = n): the structural condition :func:`check_balance` tests, shown by the matching
    found. False means only that this rule did not find one (a guess may have been wrong);
    the caller then searches (:func:`maximum_matching`). Linear in the entries; models made
    of lumped components are paired by the first rule alone, or nearly (a chain of 10⁴
    components: no guess that fails), so `phc validate` of a model without errors loads no
    graph solver (scipy's, about 0.4 s CPU to import)."""
    if m != n or len(rows) > WITHOUT_SEARCH_LIMIT:
        return False
    adj: list[list[int]] = [[] for _ in range(m + n)]  # rows 0..m−1, columns m..m+n−1
    for i, j in zip(rows.tolist(), cols.tolist()):
        adj[i].append(m + j)
        adj[m + j].append(i)
    deg = [len(a) for a in adj]  # unmatched neighbours of each vertex
    if 0 in deg:
        return False
    mate = [-1] * (m + n)
    single = [v for v in range(m + n - 1, -1, -1) if deg[v] == 1]  # popped from the end: lowest first
    first = 0  # rows before it are matched
    for _ in range(m):
        v = -1
        while single:
            v = single.pop()
            if mate[v] < 0:
                break
            v = -1
        if v < 0:
            while mate[first] >= 0:
                first += 1
            v = first
        u = next((w for w in adj[v] if mate[w] < 0), -1)
        if u < 0:
            return False
        mate[v], mate[u] = u, v
        for x in (v, u):
            for w in adj[x]:
                if mate[w] < 0:
                    deg[w] -= 1
                    if deg[w] == 1:
                        single.append(w)
                    elif deg[w] == 0:
                        return False  # left without a partner: this rule found no perfect matching
    return True


LOOP_ROLES = ("reading", "signal")
"""Variables that must not depend on themselves within an instant (:func:`reading_loops`)."""


def reading_loops(dae: Dae) -> list[tuple[int, list[int]]]:
    """The readings of port variables (variables of role ``reading``, each with its row
    ``r − v = 0``, labelled with its name: :func:`phc.library.lumped.register_readings`)
    and the outputs of signal blocks that are variables (role ``signal``, the row
    ``y − (C z + D u) = 0``: blocks read before they are lowered) that depend on themselves
    through the algebraic part of the system: for each, (its variable index, the rows on the
    loop).

    The states are known at every instant; the unknowns are the algebraic variables and the
    states' rates. With a maximum matching of the rows to those unknowns, the unknown a row
    is matched to depends on the other unknowns in that row; a reading on a cycle of this
    dependency (a strongly connected component of more than one unknown, the block of a
    block-lower-triangular ordering) is a value that can only be had by solving an equation
    in which the reading itself occurs — the source it drives acts back on the variable it
    reads within the same instant, an algebraic loop. A reading whose variable is a function
    of the states (a coil's current, a mass's velocity, a capacitor's voltage) or of
    unknowns computed before it is on no cycle. Where assembly's definitions already
    resolved the port variable into an expression of the reading itself, the loop is in
    the reading's own row; those rows are then the loop (the source's definition is
    among them, substituted)."""
    readings = [j for j, v in enumerate(dae.variables) if v.role in LOOP_ROLES]
    if not readings:
        return []
    import scipy.sparse as sps
    from scipy.sparse.csgraph import connected_components

    col = {}
    for j, v in enumerate(dae.variables):
        col[v.dsymbol if v.differential else v.symbol] = j
    rows = [{col[s] for s in eq.expr.free_symbols if s in col} for eq in dae.equations]
    for block in dae.linear_blocks:
        for term in block.terms:
            coo = term.matrix.tocoo()
            for i, j in zip(coo.row, coo.col):
                if term.symbols[j] in col:
                    rows[block.rows[i]].add(col[term.symbols[j]])
    m, n = len(rows), len(dae.variables)
    ri = np.asarray([i for i, found in enumerate(rows) for _ in found], dtype=np.int64)
    ci = np.asarray([j for found in rows for j in sorted(found)], dtype=np.int64)
    match = bipartite_matching(sps.csr_matrix((np.ones(len(ri), dtype=np.int8), (ri, ci)), shape=(m, n)))
    matched = match[ri]
    keep = (matched >= 0) & (matched != ci)
    graph = sps.csr_matrix((np.ones(int(keep.sum()), dtype=np.int8), (matched[keep], ci[keep])), shape=(n, n))
    _, labels = connected_components(graph, directed=True, connection="strong")
    row_of = {int(c): i for i, c in enumerate(match) if c >= 0}
    reading_row = {eq.label: i for i, eq in enumerate(dae.equations) if eq.kind in ("reading", "signal")}
    out = []
    for j in readings:
        v = dae.variables[j]
        own = reading_row.get(v.name)
        members = np.flatnonzero(labels == labels[j])
        if len(members) > 1:
            out.append((j, sorted(row_of[int(c)] for c in members if int(c) in row_of)))
        elif own is not None and (dae.equations[own].expr - v.symbol).has(v.symbol):
            # the port variable was resolved (by the definitions of assembly) into an
            # expression of the reading itself: the loop closed inside one row
            out.append((j, [own]))
    return out
