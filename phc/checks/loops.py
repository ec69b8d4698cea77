"""Kinematic loops: does a loop of connections constrain the motion?

Input: the component graph of an assembled model, each component's Dirac structure
(:class:`phc.checks.certify._Component`) and a sampled state. Output: one
:class:`LoopVerdict` per loop of the cycle basis (:func:`phc.ir.interconnect.kinematic_loops`,
same order).

A connection sets the two ports' flows equal and their efforts opposite (every domain);
a storage pair's effort is a function of the state (``e = ∂H/∂x``: a mass's velocity, a
spring's force, a capacitor's voltage). The loop's components, and the components
attached to them by one connection (a mass on a junction of the loop), are interconnected
along the loop's connections and those attachments (T. Berger, R. Hochdahl, T. Reis,
R. Seifried, "Port-Hamiltonian modelling of coupled rigid/flexible multibody systems",
section 2, Proposition 3); every other port stays free. The relations this structure
imposes among the storage efforts alone are algebraic relations among the states (``v₁ = v₂``
of two rigidly joined masses, ``q₁/C₁ + q₂/C₂ = 0`` of two capacitors in a ring, a model
phc's structural balance refuses today); their
number is ``n_e − dim π_e(D)`` with ``π_e`` the projection on the storage efforts.

Relations that involve storage flows are not counted: ``ẋ₁ = ẋ₂`` of two springs in
parallel is a conserved quantity (``x₁ − x₂``), not a constraint, and ``ẋ = v₂ − v₁`` of a
spring is its dynamics.

The loop closes a kinematic chain when closing it adds such relations *wherever it is
opened*: for each connection of the loop, the count with every connection minus the count
without that one; the verdict is the minimum. Opening the loop at one connection only is
wrong: a spring beside two rigidly joined masses adds ``v₁ = v₂`` when the loop is opened
at the rigid joint, but the joint imposes that relation without the spring; opened at the
spring, closing adds none (the spring only stretches with the motion): 0.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Optional

import networkx as nx
import numpy as np

from phc.checks.certify import RANK_RTOL
from phc.ir.dae import T
from phc.ir.interconnect import short_cycle_basis

MAX_LOOP = 64
"""Loops with more components are named, not classified: a loop that constrains is built
once per connection where it can be opened, each time one connection at a time, so its
cost grows with the square of its length (a compliant loop usually stops at the first
opening)."""

_EPS = np.finfo(float).eps


@dataclass
class LoopVerdict:
    """Whether one kinematic loop constrains the motion."""

    components: list[str]
    connections: list[tuple[str, str, str]] = field(default_factory=list)
    """The loop's connections as (port_a, port_b, label)."""
    constraints: Optional[int] = None
    """Independent algebraic relations among the states the loop adds (0: closed through
    compliant elements); None when it was not classified (`reason`)."""
    reason: str = ""

    def describe(self) -> str:
        if self.constraints is None:
            return f"not classified ({self.reason})"
        if self.constraints == 0:
            return "closed through compliant elements (no constraint)"
        plural = "" if self.constraints == 1 else "s"
        return f"closes a kinematic chain: {self.constraints} algebraic relation{plural}"

    def to_dict(self) -> dict:
        return {"components": list(self.components), "connections": [label for _, _, label in self.connections],
                "constraints": self.constraints, "reason": self.reason or None}


def loops_with_connections(graph: nx.MultiGraph) -> list[tuple[list[str], list[tuple[str, str, str]]]]:
    """The loops of :func:`phc.ir.interconnect.kinematic_loops` (same order, same components)
    with their connections: between consecutive components of a cycle the first connection
    written; a pair joined k times gives k − 1 loops, the first connection and each other."""

    def edges(u, v):
        data = sorted(graph.get_edge_data(u, v).values(), key=lambda d: d["index"])
        return [(*d["ports"], d["label"]) for d in data if "ports" in d]

    simple = nx.Graph(graph)
    out = []
    for cycle in short_cycle_basis(simple):
        out.append((cycle, [edges(cycle[i], cycle[(i + 1) % len(cycle)])[0] for i in range(len(cycle))]))
    for u, v in simple.edges():
        parallel = edges(u, v)
        for other in parallel[1:]:
            out.append(([u, v], [parallel[0], other]))
    return out


def _singular_values(matrix: np.ndarray) -> np.ndarray:
    return np.linalg.svd(matrix, compute_uv=False) if matrix.size else np.zeros(0)


def _rank(s: np.ndarray, scale: float, shape: tuple) -> int:
    """Rank from singular values `s` of a matrix of `shape` whose entries are of the order of
    `scale` (its largest singular value, or of the matrix it is a part of). The rows are
    orthonormal annihilators of the components' Dirac structures and connection rows of
    ±1, so round-off is about max(m, n)·ε·scale·κ with κ the conditioning of the
    components' relations (lever arms, turns ratios); a singular value counts above the
    certificate's relative threshold ``RANK_RTOL`` or, for a very large matrix,
    10⁴·max(m, n)·ε, times `scale`. The scale is that of the whole matrix also for a part of
    it: a part that is zero in exact arithmetic has only round-off singular values, and a
    threshold relative to the largest of them would count them."""
    tol = max(RANK_RTOL, 1e4 * max(shape, default=0) * _EPS) * scale
    return int(np.count_nonzero(s > tol))


def _minimum(counts) -> int:
    """The smallest count; stops at the first 0 (most loops: one opening at a compliant element)."""
    best = None
    for count in counts:
        best = count if best is None else min(best, count)
        if best <= 0:
            return 0
    return best


def _orth(matrix: np.ndarray) -> np.ndarray:
    """Orthonormal basis of the columns of `matrix`, whose entries are relative to one (rows of
    a matrix with orthonormal columns): the absolute floor of :func:`_rank` keeps a block that
    is zero up to round-off from being normalized into a spurious direction."""
    if matrix.size == 0:
        return matrix.reshape(matrix.shape[0], 0)
    u, s, _ = np.linalg.svd(matrix, full_matrices=False)
    return u[:, :_rank(s, 1.0, matrix.shape)]


def _null(matrix: np.ndarray, n_cols: int) -> np.ndarray:
    """Orthonormal basis of the kernel of `matrix` (coupling rows of ±1 times a matrix with
    orthonormal columns: entries of order one, so the scale is at least one)."""
    if matrix.shape[0] == 0:
        return np.eye(n_cols)
    _, s, vh = np.linalg.svd(matrix, full_matrices=True)
    return vh[_rank(s, max(1.0, float(s[0]) if len(s) else 0.0), matrix.shape):].T


def classify(graph: nx.MultiGraph, comps: dict, point: dict) -> list[LoopVerdict]:
    """One verdict per loop of `graph` (the component graph), from the components'
    Dirac structures `comps` (name -> :class:`phc.checks.certify._Component`) at the
    sampled state `point`.

    Loops alike up to names (the cells of a grid of masses and springs) are classified once:
    when every component of a loop and of its attachments has a constant structure (no
    state, no time), the verdict depends only on those structures and on which of their
    ports are joined in which order (:func:`_shape_key`), so a loop with the key of one
    classified before takes its verdict."""
    verdicts, cache, alike, memo = [], {}, {}, {}
    for members, loop_conns in loops_with_connections(graph):
        verdict = LoopVerdict(list(members), list(loop_conns))
        if len(members) > MAX_LOOP:
            verdict.reason = (f"{len(members)} components, more than {MAX_LOOP}: the test builds the loop "
                              "once per connection, its cost grows with the square of its length")
        else:
            missing = [m for m in members if m not in comps]
            projected = [m for m in members if m in comps and comps[m].rel.kind == "port_projection"]
            if missing:
                verdict.reason = f"`{missing[0]}` has no Dirac structure to interconnect"
            elif projected:
                verdict.reason = (f"`{projected[0]}` is seen only through its ports (a port projection), so "
                                  "relations among its states are not visible")
            else:
                key = _shape_key(graph, comps, members, loop_conns, memo)
                if key is None or key not in alike:
                    found = _minimum(_added_per_opening(graph, comps, members, loop_conns, point, cache))
                    if key is not None:
                        alike[key] = found
                verdict.constraints = found if key is None else alike[key]
        verdicts.append(verdict)
    return verdicts


def _owner(port: str) -> str:
    return port.rsplit(".", 1)[0]


def _attachments(graph, comps, members, memo=None) -> tuple[list[str], list[tuple[str, str]]]:
    """The components hanging on the loop `members` by one connection each (a mass on a
    junction of the loop; port projections left out: their storage is not visible) and
    those connections, in the order the loop's components and their connections come.
    `memo` keeps each component's neighbours in that order between loops."""
    memo = {} if memo is None else memo
    inside = set(members)
    attached, seen, base = [], set(), []
    for m in members:
        around = memo.get(m)
        if around is None:
            around = memo[m] = [(other, data["ports"]) for _, other, data in
                                sorted(graph.edges(m, data=True), key=lambda e: e[2]["index"])
                                if other in comps and "ports" in data
                                and comps[other].rel.kind != "port_projection"]  # storage not visible
        for other, ports in around:
            if other in inside or other in seen:
                continue
            attached.append(other)
            seen.add(other)
            base.append(ports)
    return attached, base


def _shape(comp) -> Optional[tuple]:
    """A component's structure up to names (None unless constant): its relations
    (:attr:`phc.checks.certify._Component.key`), its ports' rows, its storage efforts' positions."""
    if not comp.is_constant or comp.key is None:
        return None
    rel = comp.rel
    index = {e: i for i, e in enumerate(rel.efforts)}
    efforts = [s.effort for s in rel.storage] + [e for vec in rel.storage_vectors for e in vec.efforts]
    return (comp.key, tuple((p, tuple(fi), tuple(ei)) for p, (fi, ei) in rel.ports.items()),
            tuple(index.get(e) for e in dict.fromkeys(efforts)))


def _shape_key(graph, comps, members, loop_conns, memo=None) -> Optional[tuple]:
    """The loop up to the names of its components, or None when some structure depends on a
    state or on time: per component (loop, then attachments) its relations up to names
    (:attr:`phc.checks.certify._Component.key`), its ports' rows and its storage efforts'
    positions, and the joined ports as (position in that list, port name), in order."""
    memo = {} if memo is None else memo
    shapes = memo.setdefault("shapes", {})
    attached, base = _attachments(graph, comps, members, memo.setdefault("around", {}))
    names = list(members) + attached
    for name in names:
        if name not in shapes:
            shapes[name] = _shape(comps[name])
        if shapes[name] is None:
            return None
    position = {name: k for k, name in enumerate(names)}

    def local(port: str) -> tuple[int, str]:
        return position[_owner(port)], port.rsplit(".", 1)[1]

    joined = tuple((local(a), local(b)) for a, b in [*base, *((a, b) for a, b, _ in loop_conns)])
    return tuple(shapes[name] for name in names), joined


def _added_per_opening(graph, comps, members, loop_conns, point, cache=None):
    """For each connection of the loop in turn, the relations among the storage efforts that
    closing the loop there adds (the count with every connection minus without that one); a
    generator, so that the caller stops at the first 0.

    The structure is built one connection at a time as the coupling certificate builds it
    (:func:`phc.checks.certify._couplings`, Remark 4 "Associativity of interconnection"),
    kept compact (:func:`_compact`): the ports still to connect, and the storage efforts
    only through what later connections can still change; every other variable (storage
    flows, resistive pairs, ports connected or left free) is free and projected out. The
    relations among the storage efforts alone are ``n_e − rank`` of the structure's
    projection on them."""
    cache = {} if cache is None else cache
    attached, base = _attachments(graph, comps, members, cache.setdefault(("around",), {}))
    names = list(members) + attached
    loop_ports = [(a, b) for a, b, _ in loop_conns]
    used = {p for conn in base + loop_ports for p in conn}
    start, n_efforts = {}, 0
    for name in names:
        key = (name, tuple(sorted(p for p in used if p.rsplit(".", 1)[0] == name)))
        if key not in cache:
            if name not in cache:  # its structure at the point, whatever ports a loop uses
                local = {s: point[s] for s in (*comps[name].rel.states, T) if s in point}
                cache[name] = comps[name].structure(local)
            cache[key] = _projected(comps[name], cache[name], set(key[1]))
        start[name], n = cache[key]
        n_efforts += n

    def build(connections) -> dict:
        clusters = dict(start)
        cluster_of = {name: name for name in names}
        for a, b in connections:
            ca, cb = cluster_of[a.rsplit(".", 1)[0]], cluster_of[b.rsplit(".", 1)[0]]
            if ca != cb:
                for name, c in cluster_of.items():
                    if c == cb:
                        cluster_of[name] = ca
                clusters[ca] = _couple(clusters[ca], clusters.pop(cb), a, b)
            else:
                clusters[ca] = _couple(clusters[ca], None, a, b)
        return clusters

    def relations(clusters: dict) -> int:
        rank = 0
        for V, _, efforts, frozen in clusters.values():
            block = V[efforts]
            rank += frozen + _rank(_singular_values(block), 1.0, block.shape)  # ‖V‖₂ = 1
        return n_efforts - rank

    closed = None
    for k in range(len(loop_ports)):
        opened = build(base + loop_ports[:k] + loop_ports[k + 1:])
        if closed is None:
            a, b = loop_ports[k]
            owner = next(c for c, (_, ports, _, _) in opened.items() if a in ports)
            closed = relations({**opened, owner: _couple(opened[owner], None, a, b)})
        yield closed - relations(opened)


def _couple(one, other, a, b):
    """Connect ports `a` and `b` of the cluster `one` (and `other`, a second cluster joined to
    it): f_a = f_b, e_a = −e_b. A wire (:mod:`phc.ir.wires`, e_a = e_b, f_a = −f_b) is coupled
    as this bond too: it is the bond with port b's flow and effort negated, a change of
    coordinates of a port that is used once and then projected out, so the storage efforts'
    relations counted here are the same. A cluster is (V, port rows, effort rows, frozen rank)."""
    V, ports, efforts, frozen = one
    ports = dict(ports)
    if other is not None:
        Vb, pb, eb, fb_ = other
        shift = V.shape[0]
        joined = np.zeros((V.shape[0] + Vb.shape[0], V.shape[1] + Vb.shape[1]))
        joined[:V.shape[0], :V.shape[1]] = V
        joined[V.shape[0]:, V.shape[1]:] = Vb
        V = joined
        ports.update({p: ([i + shift for i in f], [i + shift for i in e]) for p, (f, e) in pb.items()})
        efforts = list(efforts) + [i + shift for i in eb]
        frozen += fb_
    (fa, ea), (fb, eb) = ports.pop(a), ports.pop(b)
    S = np.zeros((len(fa) + len(ea), V.shape[0]))
    for r, (i, j) in enumerate(zip(fa, fb)):
        S[r, i], S[r, j] = 1.0, -1.0
    for r, (i, j) in enumerate(zip(ea, eb), start=len(fa)):
        S[r, i], S[r, j] = 1.0, 1.0
    W = V @ _null(S @ V, V.shape[1])
    gone = set(fa + ea + fb + eb)
    keep = [i for i in range(V.shape[0]) if i not in gone]
    pos = {i: k for k, i in enumerate(keep)}
    return _compact(W[keep], {p: ([pos[i] for i in f], [pos[i] for i in e]) for p, (f, e) in ports.items()},
                    [pos[i] for i in efforts], frozen)


def _compact(V, ports: dict, efforts: list, frozen: int):
    """A cluster with as many columns as its open port rows allow.

    Connections only act on port rows, so the directions of the structure with no port
    component (V₂ = V·ker P) stay in it whatever is connected later: their effort rows
    are counted once (`frozen`, the rank of E V₂) and projected out of the rest
    (rank [F, X] = rank F + rank (I − F Fᵀ) X, F a basis of E V₂). The remaining effort rows
    are replaced by an orthonormal change of coordinates of themselves (the SVD's Σ Vᵀ),
    which keeps the rank of every later projection; at most as many as the columns left."""
    prow = [i for f, e in ports.values() for i in (*f, *e)]
    P, E = V[prow], V[efforts]
    if P.size:
        _, s, vh = np.linalg.svd(P, full_matrices=True)
        r = _rank(s, 1.0, P.shape)
    else:
        r, vh = 0, np.eye(V.shape[1])
    V1, V2 = vh[:r].T, vh[r:].T
    F = _orth(E @ V2) if E.size and V2.size else np.zeros((len(efforts), 0))
    X = E @ V1 if E.size else np.zeros((0, r))
    X = X - F @ (F.T @ X)
    if X.size:
        _, s2, vh2 = np.linalg.svd(X, full_matrices=False)
        k = _rank(s2, 1.0, X.shape)
        X = s2[:k, None] * vh2[:k]
    else:
        X = np.zeros((0, r))
    A = _orth(np.vstack([P @ V1, X])) if r else np.zeros((len(prow) + X.shape[0], 0))
    out, row = {}, 0
    for p, (f, e) in ports.items():
        out[p] = (list(range(row, row + len(f))), list(range(row + len(f), row + len(f) + len(e))))
        row += len(f) + len(e)
    return A, out, list(range(row, row + X.shape[0])), frozen + F.shape[1]


def _projected(comp, D, used: set):
    """A component's Dirac structure `D` (an orthonormal basis, flows then efforts)
    projected on its ports in `used` and its storage efforts (its other ports are free),
    as a compact cluster; and its number of storage efforts."""
    n = comp.n
    index = {e: i for i, e in enumerate(comp.rel.efforts)}
    efforts = [s.effort for s in comp.rel.storage]
    efforts += [e for vec in comp.rel.storage_vectors for e in vec.efforts]
    effort_idx = [n + index[e] for e in dict.fromkeys(efforts) if e in index]
    sel, ports = [], {}
    for pname, (fi, ei) in comp.rel.ports.items():
        full = f"{comp.rel.component}.{pname}"
        if full not in used:
            continue
        start = len(sel)
        sel += list(fi) + [n + i for i in ei]
        ports[full] = (list(range(start, start + len(fi))), list(range(start + len(fi), len(sel))))
    rows = list(range(len(sel), len(sel) + len(effort_idx)))
    sel += effort_idx
    V = _orth(D[sel]) if sel else np.zeros((0, 0))
    return _compact(V, ports, rows, 0), len(effort_idx)


__all__ = ["LoopVerdict", "MAX_LOOP", "classify", "loops_with_connections"]
