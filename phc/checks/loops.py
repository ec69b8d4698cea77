"""Kinematic loops: does a loop of connections constrain the motion?

Input: the component graph of an assembled model, each component's Dirac structure
(:class:`phc.checks.certify._Component`) and a sampled state. Output: one
:class:`LoopVerdict` per loop of the cycle basis (:func:`phc.interconnect.kinematic_loops`,
same order).

A connection sets the two ports' flows equal and their efforts opposite (every domain);
a storage pair's effort is a function of the state (``e = ∂H/∂x``: a mass's velocity, a
spring's force, a capacitor's voltage). The loop's components, and the components
attached to them by one connection (a mass on a junction of the loop), are interconnected
along the loop's connections and those attachments (T. Berger, R. Hochdahl, T. Reis,
R. Seifried, "Port-Hamiltonian modelling of coupled rigid/flexible multibody systems",
section 2, Proposition 3); every other port stays free. The relations this structure
imposes among the storage efforts alone are algebraic relations among the states (``v₁ = v₂``
of two rigidly joined masses, ``q₁/C₁ + q₂/C₂ = 0`` of two capacitors in a ring); their
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
import scipy.linalg as sla

from phc.checks.certify import RANK_RTOL, _null
from phc.dae import T

MAX_LOOP = 64
"""Loops with more components are named, not classified (a loop's test costs one SVD per
connection of a matrix that grows with the loop)."""

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
    """The loops of :func:`phc.interconnect.kinematic_loops` (same order, same components)
    with their connections: between consecutive components of a cycle the first connection
    written; a pair joined k times gives k − 1 loops, the first connection and each other."""

    def edges(u, v):
        data = sorted(graph.get_edge_data(u, v).values(), key=lambda d: d["index"])
        return [(*d["ports"], d["label"]) for d in data if "ports" in d]

    simple = nx.Graph(graph)
    out = []
    for cycle in nx.cycle_basis(simple):
        cycle = list(cycle)
        out.append((cycle, [edges(cycle[i], cycle[(i + 1) % len(cycle)])[0] for i in range(len(cycle))]))
    for u, v in simple.edges():
        parallel = edges(u, v)
        for other in parallel[1:]:
            out.append(([u, v], [parallel[0], other]))
    return out


def _rank(matrix: np.ndarray) -> int:
    """Rank of rows of a matrix with orthonormal columns (‖W‖₂ = 1, so its entries are
    relative to one). Its round-off is that of the SVDs that made it, about
    max(m, n)·ε·κ with κ the conditioning of the components' relations (lever arms, turns
    ratios); a singular value counts above the certificate's relative threshold
    ``RANK_RTOL`` or, for a very large matrix, 10⁴·max(m, n)·ε — an absolute floor, as a
    block that is zero in exact arithmetic has only round-off singular values and a
    threshold relative to the largest of them would count them."""
    if matrix.size == 0:
        return 0
    s = np.linalg.svd(matrix, compute_uv=False)
    tol = max(RANK_RTOL, 1e4 * max(matrix.shape) * _EPS)
    return int(np.sum(s > tol))


def classify(graph: nx.MultiGraph, comps: dict, point: dict) -> list[LoopVerdict]:
    """One verdict per loop of `graph` (the component graph), from the components'
    Dirac structures `comps` (name -> :class:`phc.checks.certify._Component`) at the
    sampled state `point`."""
    verdicts = []
    for members, loop_conns in loops_with_connections(graph):
        verdict = LoopVerdict(list(members), list(loop_conns))
        if len(members) > MAX_LOOP:
            verdict.reason = (f"{len(members)} components, more than {MAX_LOOP}: the test costs one SVD per "
                              "connection of a matrix that grows with the loop")
        else:
            missing = [m for m in members if m not in comps]
            projected = [m for m in members if m in comps and comps[m].rel.kind == "port_projection"]
            if missing:
                verdict.reason = f"`{missing[0]}` has no Dirac structure to interconnect"
            elif projected:
                verdict.reason = (f"`{projected[0]}` is seen only through its ports (a port projection), so "
                                  "relations among its states are not visible")
            else:
                verdict.constraints = max(0, min(_added_per_opening(graph, comps, members, loop_conns, point)))
        verdicts.append(verdict)
    return verdicts


def _added_per_opening(graph, comps, members, loop_conns, point) -> list[int]:
    """For each connection of the loop, the relations among the storage efforts that
    closing the loop there adds (with every connection minus without that one)."""
    inside = set(members)
    attached, base = [], []
    for m in members:  # the components hanging on the loop, one connection each
        for _, other, data in sorted(graph.edges(m, data=True), key=lambda e: e[2]["index"]):
            if other in inside or other in attached or other not in comps or "ports" not in data:
                continue
            if comps[other].rel.kind == "port_projection":
                continue  # its storage is not visible; its port stays free
            attached.append(other)
            base.append(data["ports"])
    blocks, rows, effort_rows, offset = [], {}, [], 0
    for name in list(members) + attached:
        comp = comps[name]
        local = {s: point[s] for s in (*comp.rel.states, T) if s in point}
        D = comp.structure(local)
        blocks.append(D)
        n = comp.n
        for pname, (fi, ei) in comp.rel.ports.items():
            rows[f"{name}.{pname}"] = ([offset + i for i in fi], [offset + n + i for i in ei])
        index = {e: i for i, e in enumerate(comp.rel.efforts)}
        efforts = [s.effort for s in comp.rel.storage]
        efforts += [e for vec in comp.rel.storage_vectors for e in vec.efforts]
        effort_rows += [offset + n + index[e] for e in dict.fromkeys(efforts) if e in index]
        offset += D.shape[0]
    V = sla.block_diag(*blocks) if blocks else np.zeros((0, 0))

    def relations(connections) -> int:
        """Independent relations among the storage efforts with these connections."""
        S = []
        for a, b in connections:
            (fa, ea), (fb, eb) = rows[a], rows[b]
            for i, j in zip(fa, fb):
                r = np.zeros(V.shape[0])
                r[i], r[j] = 1.0, -1.0
                S.append(r)
            for i, j in zip(ea, eb):
                r = np.zeros(V.shape[0])
                r[i], r[j] = 1.0, 1.0
                S.append(r)
        W = V if not S else V @ _null(np.array(S) @ V, V.shape[1])
        return len(effort_rows) - _rank(W[effort_rows])

    ports = [(a, b) for a, b, _ in loop_conns]
    closed = relations(base + ports)
    return [closed - relations(base + ports[:k] + ports[k + 1:]) for k in range(len(ports))]


__all__ = ["LoopVerdict", "MAX_LOOP", "classify", "loops_with_connections"]
