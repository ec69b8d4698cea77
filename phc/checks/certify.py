"""Certificates: Dirac property of every component and surjectivity of every coupling.

Input: an assembled :class:`~phc.ir.dae.Dae`. Output: a :class:`Certificate` (with the
comparison of each component's rows with its description, :mod:`phc.checks.rows`).

This is section 2 of T. Berger, R. Hochdahl, T. Reis, R. Seifried, "Port-Hamiltonian
modelling of coupled rigid/flexible multibody systems", done numerically, at sampled
states:

* **Dirac property** (Definition 1 "Dirac structure", Remark 1 on finite dimensions): in kernel
  form ``F f + E e + G λ = 0`` the structure is ``D = {(f, e) : ∃λ …}``; it is Dirac iff
  ``dim D = dim Z`` and it is power-isotropic, ``⟨f₁, e₂⟩ + ⟨f₂, e₁⟩ = 0`` on a basis.
* **Coupling map Γ** (Proposition 3 "Interconnection through a finite-dimensional
  coupling space"): the components are interconnected one connection at a time in breadth-first
  order (Remark 4 "Associativity of interconnection"); at each step
  ``Γ(d₁, d₂) = (f_c1 − f_c2, e_c1 + e_c2)`` must be onto ``Z_c × Z_c`` (for a wire,
  :mod:`phc.ir.wires`, ``(f_c1 + f_c2, e_c1 − e_c2)``: the bond with one port's variables
  negated, of the same rank). Γ only sees the
  coupling components, so each component is represented by the projection of its Dirac
  structure onto its ports — the cost grows linearly with the number of components.
* rigid components: ``c'(q)`` and ``A(q)`` of full row rank at the initial
  configuration (dependent rows are named); resistive laws passive (``f·e ≥ 0``), except
  those declared controlled sources (``kind: source``), whose power is supplied power.

Rank decisions use singular values relative to the largest one: a singular value
counts when ``σ > RANK_RTOL · σ_max`` (with an absolute floor for all-zero blocks).
With entries of order one this separates rank from round-off by several orders of
magnitude; a coupling that is merely ill-conditioned (``σ_min/σ_max`` below
``WARN_RTOL``) is reported as a warning.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Optional

import numpy as np
import sympy as sp

from phc.checks.rows import placeholder
from phc.checks.graph import component_graph, component_of, independent_parts, kinematic_loops, traversal_order
from phc.ir.dae import T, Dae, DiracRelations
from phc.diagnostics import Diagnostic, DiagnosticList
from phc.inert import inert
from phc.library.phs import CONTROLLED_SOURCE

RANK_RTOL = 1e-9
"""Relative singular-value threshold for numerical rank."""
WARN_RTOL = 1e-6
"""Couplings with σ_min/σ_max below this are flagged as ill-conditioned."""
ISOTROPY_TOL = 1e-9
"""Largest allowed |⟨f₁,e₂⟩ + ⟨f₂,e₁⟩| on an orthonormal basis of D."""

SIGNAL_NOTE = ("signal block: outside the port-Hamiltonian certificate (no ports, no energy; it acts through "
               "the sources that read it, whose power is counted as supplied power)")
"""How ``phc check`` lists a signal block (:mod:`phc.library.signal`)."""


def _signal_blocks(top) -> set[str]:
    """The components of `top` that are signal blocks (:attr:`phc.library.registry.ComponentType.signal`)."""
    from phc.library import registry

    return {name for name, kind, _ in top.components
            if (entry := registry.find(kind)) is not None and entry.signal}


def _contact_bodies(top, dae) -> dict[str, set[str]]:
    """Each `contact` component (:mod:`phc.library.contact`) and the components whose momenta
    its impacts and friction act on (its outputs ``<contact>.normal.<component>.<momentum>``,
    ``<contact>.tangent.…``)."""
    names = {name for name, _, _ in top.components}
    out: dict[str, set[str]] = {}
    for name, kind, _ in top.components:
        if kind != "contact":
            continue
        heads = (f"{name}.normal.", f"{name}.tangent.")
        momenta = [o[len(h):] for o, _ in dae.outputs for h in heads if o.startswith(h)]
        out[name] = {n for n in names for m in momenta if m.startswith(n + ".")}
    return out


@dataclass
class ComponentCertificate:
    name: str
    kind: str
    dim_z: int
    dim_d: Optional[int] = None
    isotropy: Optional[float] = None
    dirac: Optional[bool] = None
    note: str = ""

    def to_dict(self) -> dict:
        return {"name": self.name, "kind": self.kind, "dim_z": self.dim_z, "dim_d": self.dim_d,
                "isotropy_error": self.isotropy, "dirac": self.dirac, "note": self.note}


@dataclass
class ConnectionCertificate:
    label: str
    port_a: str
    port_b: str
    needed: int
    achieved: int = -1
    conditioning: float = 1.0
    failing_samples: list = field(default_factory=list)
    span: object = None
    condition: Optional[str] = None
    """Symbolic failure set (where all maximal minors of Γ vanish), when it was computed."""

    @property
    def surjective(self) -> bool:
        return self.achieved == self.needed

    def to_dict(self) -> dict:
        return {"label": self.label, "ports": [self.port_a, self.port_b], "rank_needed": self.needed,
                "rank_achieved": self.achieved, "surjective": self.surjective,
                "sigma_ratio": self.conditioning, "failing_samples": self.failing_samples,
                "failure_condition": self.condition}


@dataclass
class Certificate:
    model: str
    components: list[ComponentCertificate]
    connections: list[ConnectionCertificate]
    loops: list[list[str]]
    parts: list[list[str]]
    diagnostics: DiagnosticList
    n_samples: int
    rows: Optional[object] = None
    """The comparison of each component's compiled rows with its description
    (:class:`phc.checks.rows.RowsCertificate`)."""
    loop_verdicts: list = field(default_factory=list)
    """Whether each of `loops` constrains the motion (:class:`phc.checks.loops.LoopVerdict`,
    same order)."""

    @property
    def certified(self) -> bool:
        return (not self.diagnostics.has_errors and all(c.dirac is not False for c in self.components)
                and all(c.surjective for c in self.connections))

    def to_dict(self) -> dict:
        return {"model": self.model, "certified": self.certified, "samples": self.n_samples,
                "components": [c.to_dict() for c in self.components],
                "connections": [c.to_dict() for c in self.connections],
                "loops": self.loops, "loop_constraints": [v.to_dict() for v in self.loop_verdicts],
                "independent_parts": self.parts,
                "rows": None if self.rows is None else {
                    "compared": self.rows.compared,
                    "energy_balance_only": [{"component": c, "why": w} for c, w in self.rows.not_compared],
                    "inconclusive": [{"component": c, "why": w} for c, w in self.rows.inconclusive]},
                "diagnostics": self.diagnostics.to_json()}

    def render_text(self) -> str:
        lines = [f"{self.model}: {'certified' if self.certified else 'NOT certified'} "
                 f"({self.n_samples} sampled states)", "components"]
        width = max([len(c.name) for c in self.components] + [4])
        kind_width = max([len(c.kind) for c in self.components] + [20])
        for c in self.components:
            if c.dirac is None:
                status = c.note if c.note == SIGNAL_NOTE else f"ports only: {c.note}"
            else:
                status = (f"Dirac {'ok' if c.dirac else 'FAILED'}: dim D {c.dim_d} / dim Z {c.dim_z}, "
                          f"isotropy {c.isotropy:.1e}")
                # a controller or a controlled source: what the certificate does not cover
                if c.note.startswith(("feedback", CONTROLLED_SOURCE)):
                    status += f"; {c.note}"
            lines.append(f"  {c.name:<{width}}  {c.kind:<{kind_width}} {status}")
        lines.append("connections (breadth-first; rank of Γ achieved / needed)")
        label_width = max([len(c.label) for c in self.connections] + [16])  # nested labels are longer
        for c in self.connections:
            fail = f", fails at {len(c.failing_samples)} sample(s)" if c.failing_samples else ""
            cond = f"; loses rank where {c.condition}" if c.condition else ""
            lines.append(f"  {c.label:<{label_width}} {c.port_a} — {c.port_b}: rank {c.achieved}/{c.needed}"
                         f"{' surjective' if c.surjective else ' NOT surjective'} "
                         f"(σ_min/σ_max {c.conditioning:.1e}){fail}{cond}")
        if not self.loops:
            lines.append("kinematic loops: none")
        else:
            lines.append(f"kinematic loops: {len(self.loops)}")
            verdicts = self.loop_verdicts if len(self.loop_verdicts) == len(self.loops) else [None] * len(self.loops)
            for loop, verdict in zip(self.loops, verdicts):
                lines.append("  " + " – ".join(loop) + (f": {verdict.describe()}" if verdict is not None else ""))
        if self.rows is not None:
            r = self.rows
            lines.append(f"rows against descriptions: {len(r.compared)} component(s) match"
                         + (f"; {len(r.not_compared)} not compared, certified by the energy balance ("
                            + ", ".join(f"{c}: {w}" for c, w in r.not_compared) + ")" if r.not_compared else "")
                         + ("; inconclusive: " + ", ".join(f"{c} ({w})" for c, w in r.inconclusive)
                            if r.inconclusive else ""))
        if len(self.parts) > 1:
            lines.append(f"independent parts: {len(self.parts)}: "
                         + "; ".join("{" + ", ".join(p) + "}" for p in self.parts))
        for d in self.diagnostics:
            lines.append(d.render())
        return "\n".join(inert(line) for line in lines)  # model and component names (phc.inert)


def _rank(s: np.ndarray) -> int:
    if not len(s) or s[0] <= 1e-300:
        return 0
    return int(np.sum(s > RANK_RTOL * s[0]))


def _orth(matrix: np.ndarray) -> np.ndarray:
    if matrix.size == 0:
        return matrix.reshape(matrix.shape[0], 0)
    u, s, _ = np.linalg.svd(matrix, full_matrices=False)
    return u[:, :_rank(s)]


def _null(matrix: np.ndarray, n_cols: int) -> np.ndarray:
    if matrix.shape[0] == 0:
        return np.eye(n_cols)
    _, s, vh = np.linalg.svd(matrix, full_matrices=True)
    return vh[_rank(s):].T


class _Component:
    """Numeric evaluation of one component's kernel representation.

    Components whose relations are the same up to the names of their variables and states
    (the masses of a chain) share the work through `shared`: the Jacobian is taken once and
    renamed, and a constant one (no state, no time) is evaluated, and its structure found,
    once."""

    def __init__(self, rel: DiracRelations, defaults: dict, shared: Optional[dict] = None):
        self.rel = rel
        variables = list(rel.flows) + list(rel.efforts) + list(rel.multipliers)
        self.n = len(rel.flows)
        self._constant: Optional[list] = None
        self.key: Optional[tuple] = None
        """The relations up to the names of their variables and states (equal keys: equal
        Jacobians once renamed); None when not shared."""
        if shared is None or not rel.relations:
            self.K = self._jacobian(list(rel.relations), variables, defaults)
            return
        # by position, with the same assumptions (a derivative of |x| depends on them); a space
        # keeps these names apart from every name a model can have
        canon = {v: placeholder(f"phc variable {k}", frozenset(v.assumptions0.items()))
                 for k, v in enumerate(dict.fromkeys((*variables, *rel.states)))}
        key = (len(rel.flows), len(rel.efforts), len(rel.multipliers), len(rel.states),
               tuple(r.xreplace(canon) for r in rel.relations))
        self.key = key
        entry = shared.get(key)
        if entry is None:
            K = self._jacobian([r.xreplace(canon) for r in rel.relations], [canon[v] for v in variables], defaults)
            entry = shared[key] = (K, None if K.free_symbols else [None])
        K, self._constant = entry
        self.K = K.xreplace({c: v for v, c in canon.items()}) if self._constant is None else K

    @staticmethod
    def _jacobian(relations: list, variables: list, defaults: dict):
        K = sp.Matrix(relations).jacobian(variables) if relations else sp.zeros(0, len(variables))
        return K.xreplace(defaults)

    def matrix(self, point: dict) -> np.ndarray:
        K = self.K.xreplace(point) if point and self._constant is None else self.K
        return np.array(K.evalf(), dtype=float).reshape(self.K.shape)

    def structure(self, point):
        """Orthonormal basis of D (rows: flows then efforts)."""
        if self._constant is not None and self._constant[0] is not None:
            return self._constant[0]
        K = self.matrix(point)
        N = _null(K, K.shape[1])
        D = _orth(N[:2 * self.n])
        if self._constant is not None:
            self._constant[0] = D
        return D

    @property
    def is_constant(self) -> bool:
        """The structure depends on no state and no time: :meth:`structure` returns one array,
        shared by the components alike up to names (the same :attr:`key`)."""
        return self._constant is not None

    def port_rows(self) -> tuple[list[str], dict]:
        rows, order = {}, []
        for pname, (fi, ei) in self.rel.ports.items():
            order.append(pname)
            rows[pname] = (list(fi), [self.n + i for i in ei])
        return order, rows


def _samples(dae: Dae, n_random: int, seed: int) -> list[dict]:
    top = dae.topology
    states = {s for rel in top.dirac for s in rel.states}
    rng = np.random.default_rng(seed)
    states = sorted(states, key=str)  # deterministic order (reports list states in it)
    first = {s: sp.Float(float(top.initial.get(s, 0.3))) for s in states}
    # Time-dependent structures (a rheonomic constraint, a modulation in t) are certified at
    # the start and at random times of the simulation interval.
    t0 = float(dae.options.get("t_start", 0.0) or 0.0)
    t1 = float(dae.options.get("t_end", t0 + 1.0) or t0 + 1.0)
    first[T] = sp.Float(t0)
    samples = [first]
    for _ in range(n_random):
        point = {s: sp.Float(float(x)) for s, x in zip(states, rng.uniform(-1, 1, len(states)))}
        point[T] = sp.Float(float(t0 + (t1 - t0) * rng.uniform(0, 1)))
        samples.append(point)
    return samples


def certify(dae: Dae, n_random: int = 2, seed: int = 0) -> Certificate:
    """Certify the Dirac structures and couplings of an assembled model.

    Parameters
    ----------
    dae : Dae
        From :func:`phc.build_dae`.
    n_random : int
        Random states sampled besides the initial one.

    Returns
    -------
    Certificate
        ``certified`` is True when every check passed; problems are located diagnostics.
    """
    top = dae.topology
    diags = DiagnosticList()
    samples = _samples(dae, n_random, seed)
    shared: dict = {}
    comps = {rel.component: _Component(rel, top.parameter_defaults, shared) for rel in top.dirac}
    comp_certs = []
    projections: list[dict] = [{} for _ in samples]
    # A constant structure (no state, no time: the masses and springs of a chain) is one array
    # shared by every sample and every component alike up to names; its isotropy and its
    # projection on the ports are computed once per array and port selection.
    constant: dict = {}
    for rel in top.dirac:
        comp = comps[rel.component]
        cert = ComponentCertificate(rel.component, rel.kind, comp.n, note=rel.note)
        order, rows = comp.port_rows()
        sel = [i for pname in order for i in rows[pname][0] + rows[pname][1]]
        for k, point in enumerate(samples):
            # its own states only (a scan of every state of the model per component was quadratic)
            local = {s: point[s] for s in (*rel.states, T) if s in point}
            D = comp.structure(local)
            done = constant.get((id(D), tuple(sel))) if comp.is_constant else None
            if done is None:
                iso = None
                if rel.kind != "port_projection":
                    f, e = D[:comp.n], D[comp.n:]
                    S = f.T @ e + e.T @ f
                    iso = float(np.abs(np.linalg.eigvalsh(S)).max(initial=0.0)) if S.size else 0.0
                done = (iso, _orth(D[sel]) if sel else np.zeros((0, 0)))
                if comp.is_constant:
                    constant[(id(D), tuple(sel))] = done
            iso, P = done
            if rel.kind != "port_projection":
                cert.dim_d = D.shape[1] if cert.dim_d is None else min(cert.dim_d, D.shape[1])
                cert.isotropy = iso if cert.isotropy is None else max(cert.isotropy, iso)
            offset, rmap = 0, {}
            for pname in order:
                d = len(rows[pname][0])
                rmap[f"{rel.component}.{pname}"] = (list(range(offset, offset + d)),
                                                   list(range(offset + d, offset + 2 * d)))
                offset += 2 * d
            projections[k][rel.component] = (P, rmap)
        if rel.kind != "port_projection":
            cert.dirac = cert.dim_d == comp.n and cert.isotropy <= ISOTROPY_TOL
            if not cert.dirac:
                why = (f"its relations define a subspace of dimension {cert.dim_d}, but a Dirac structure on "
                       f"{comp.n} flow/effort pairs has dimension {comp.n}" if cert.dim_d != comp.n else
                       f"it is not power-isotropic (|⟨f₁,e₂⟩ + ⟨f₂,e₁⟩| up to {cert.isotropy:.2g})")
                diags.append(Diagnostic("PHC-E420", f"component `{rel.component}` is not a Dirac structure: {why}",
                                        span=rel.span, path=rel.component,
                                        hint="check the relations: one per flow/effort pair, power conserving"))
        comp_certs.append(cert)
    signal = _signal_blocks(top)
    comp_certs.extend(ComponentCertificate(name, kind, 0, note=SIGNAL_NOTE) for name, kind, _ in top.components
                      if name in signal)
    graph = component_graph(top)  # built once: the traversal, the loops and the parts read it
    # with no structure depending on a state or on time, every sample gives the same couplings
    constant_only = all(c.is_constant for c in comps.values())
    conn_certs = _couplings(top, projections, samples, diags, graph, constant_only)
    _rigid_ranks(top, samples[0], diags)
    _passivity(top, diags, seed)
    from phc.checks.rows import check_rows

    rows = check_rows(dae, samples=max(1, n_random), seed=seed)
    diags.extend(rows.diagnostics)
    spans = {name: span for name, _, span in top.components}
    for name, why in rows.inconclusive:
        # its own solve failed (a steep law, an exponential that overflows from a random start):
        # no verdict at this sample, not a mismatch (PHC-E452)
        diags.append(Diagnostic("PHC-W453", f"the comparison of the equations compiled for `{name}` with its "
                                f"description is inconclusive at these samples: {why}; other starts were tried",
                                span=spans.get(name), path=name, severity="warning",
                                hint="not a fault found in the model or in phc; the compiled energy balance still "
                                "certifies the component, and `--samples N` tries more states"))
    loops = kinematic_loops(graph)
    from phc.checks.loops import classify

    # one state where the structure is generic: a random one (the initial state is often special)
    verdicts = classify(graph, comps, samples[1] if len(samples) > 1 else samples[0])
    # a signal block has no port: it acts through the sources that read it, not a connection
    # a contact has no port either: it couples the bodies its gap names (at impacts)
    contacts = _contact_bodies(top, dae)
    parts = [p for p in ([n for n in part if n not in signal and n not in contacts] for part in
                         independent_parts(graph)) if p]
    for bodies in contacts.values():
        joined = [p for p in parts if set(p) & bodies]
        if len(joined) > 1:
            parts = [p for p in parts if p not in joined] + [[n for p in joined for n in p]]
    if len(parts) > 1:
        spans = {name: span for name, _, span in top.components}
        diags.append(Diagnostic("PHC-W201", f"the model has {len(parts)} independent parts with no connection "
                                "between them: " + "; ".join("{" + ", ".join(p) + "}" for p in parts),
                                span=spans.get(parts[1][0]), path=parts[1][0], severity="warning",
                                hint="intended? each part is simulated independently"))
    return Certificate(dae.name, comp_certs, conn_certs, loops, parts, diags.sorted(), len(samples), rows, verdicts)


def _couplings(top, projections, samples, diags, graph=None, constant_only=False) -> list[ConnectionCertificate]:
    """Interconnect one coupling at a time (BFS) and test the rank of Γ at each step.

    Every connection gets its certificate, a nested file's under its own label
    (``inner.connections[0]``) and located in that file. `graph` is the component graph of
    `top` when the caller has built it. `constant_only`: no component's structure depends on a
    state or on time, so the first sample's ranks hold at every sample (computed once)."""
    owner = component_of(top)
    order = traversal_order(top if graph is None else graph)
    spans = {label: span for _, _, label, span in top.connections}
    dims = {p.name: p.dimension for p in top.ports}
    certs = [ConnectionCertificate(label, a, b, 2 * dims[a], span=spans.get(label)) for a, b, label in order]
    wires = top.wires
    for k, point in enumerate(samples[:1] if constant_only else samples):
        cluster_of = {name: name for name in projections[k]}
        members = {name: [name] for name in projections[k]}
        clusters = {name: projections[k][name] for name in projections[k]}
        for cert, (a, b, label) in zip(certs, order):
            ca, cb = cluster_of.get(owner[a]), cluster_of.get(owner[b])
            if ca is None or cb is None:
                continue
            Va, ma = clusters[ca]
            if ca == cb:
                V, rmap = Va, dict(ma)
            else:
                Vb, mb = clusters[cb]
                V = np.zeros((Va.shape[0] + Vb.shape[0], Va.shape[1] + Vb.shape[1]))
                V[:Va.shape[0], :Va.shape[1]] = Va
                V[Va.shape[0]:, Va.shape[1]:] = Vb
                shift = Va.shape[0]
                rmap = dict(ma)
                rmap.update({p: ([i + shift for i in f], [i + shift for i in e]) for p, (f, e) in mb.items()})
            fa, ea = rmap[a]
            fb, eb = rmap[b]
            # Γ V: the rows (f_a − f_b, e_a + e_b) of V, without forming the selection matrix;
            # (f_a + f_b, e_a − e_b) for a wire (phc.ir.wires)
            GV = (np.concatenate((V[fa] + V[fb], V[ea] - V[eb])) if label in wires
                  else np.concatenate((V[fa] - V[fb], V[ea] + V[eb])))
            if GV.size:  # one SVD gives the rank and the kernel of Γ V
                _, s, vh = np.linalg.svd(GV, full_matrices=True)
            else:
                s, vh = np.zeros(0), np.eye(V.shape[1])
            rank = _rank(s)
            ratio = float(s[-1] / s[0]) if len(s) >= cert.needed and s[0] > 0 else 0.0
            cert.achieved = rank if cert.achieved < 0 else min(cert.achieved, rank)
            cert.conditioning = min(cert.conditioning, ratio)
            if rank < cert.needed:  # the states of the two components (`inner.wheel.th` of `inner.wheel`)
                for failed in (samples if constant_only else [point]):
                    cert.failing_samples.append({str(sym): float(v) for sym, v in failed.items()
                                                 if str(sym).startswith((owner[a] + ".", owner[b] + "."))})
            # The interconnected structure: ker(ΓV), coupling rows removed.
            W = V @ vh[rank:].T
            coupled = set(fa + ea + fb + eb)
            keep = [i for i in range(V.shape[0]) if i not in coupled]
            new_rows, pos = {}, {i: n for n, i in enumerate(keep)}
            for p, (f, e) in rmap.items():
                if p not in (a, b):
                    new_rows[p] = ([pos[i] for i in f], [pos[i] for i in e])
            merged = (_orth(W[keep]) if keep else np.zeros((0, 0)), new_rows)
            clusters[_merge(ca, cb, cluster_of, members, clusters)] = merged
    for cert, condition in zip(certs, _symbolic_conditions(top, order, owner, certs)):
        cert.condition = condition
    for cert in certs:
        if not cert.surjective:
            where = ("at every sampled state" if len(cert.failing_samples) == len(samples)
                     else f"at {len(cert.failing_samples)} of {len(samples)} sampled states, e.g. "
                     + ", ".join(f"{k} = {v:.3g}" for k, v in list(cert.failing_samples[0].items())[:6]))
            diags.append(Diagnostic(
                "PHC-E421", f"connection `{cert.port_a}` — `{cert.port_b}` is not surjective: rank of the coupling "
                f"map Γ is {cert.achieved}, needs {cert.needed} ({where})"
                + (f"; it fails where {cert.condition}" if cert.condition else "")
                + "; the interconnection is not a Dirac structure there", span=cert.span, path=cert.label,
                hint="both sides impose the same flow or effort (e.g. two sources, two terminations, or a "
                "constraint that removes the port's freedom)"))
        elif cert.conditioning < WARN_RTOL:
            diags.append(Diagnostic(
                "PHC-W221", f"connection `{cert.port_a}` — `{cert.port_b}` is nearly singular (σ_min/σ_max = "
                f"{cert.conditioning:.1e} at a sampled state)", span=cert.span, path=cert.label, severity="warning"))
    return certs


SYMBOLIC_MAX_ROWS = 24
"""Failing couplings whose composite relation matrix has at most this many independent rows
are also analysed symbolically."""


def _symbolic_conditions(top, order, owner, certs) -> list[Optional[str]]:
    """Where each coupling map loses rank, as equations in the states (when small enough).

    The interconnected structure up to a connection is kept in kernel form: the relations
    of all components of the two clusters plus the coupling rows of earlier connections,
    over all their variables (eliminated port variables stay as latent ones). With K those
    relations and S the rows ``(f_a − f_b, e_a + e_b)`` of the connection (``(f_a + f_b,
    e_a − e_b)`` for a wire), Γ is onto iff
    ``rank [K; S] = rank K + 2 dim``; rank K is constant (Dirac components), so Γ fails
    exactly where all maximal minors of ``[K; S]`` vanish. One maximal minor is computed
    exactly (rational parameters, non-polynomial sub-expressions replaced by symbols), its
    factors are candidates, and a candidate is reported only if the rank of ``[K; S]`` is
    seen to drop at random points of its zero set.
    """
    if all(cert.surjective for cert in certs):  # a condition is sought only where a coupling failed
        return [None] * len(certs)
    rels = {r.component: r for r in top.dirac}
    exact = {sym: sp.Rational(repr(float(v))) for sym, v in top.parameter_defaults.items()}
    cluster_of = {c: c for c in rels}
    members = {c: [c] for c in rels}
    # a cluster's relations and variables as a tree of lists (`_joined`): joining two clusters
    # is O(1), copying the growing lists at every connection was quadratic along a chain
    rows = {c: list(rels[c].relations) for c in rels}
    cols = {c: list(rels[c].flows) + list(rels[c].efforts) + list(rels[c].multipliers) for c in rels}
    ports = {}
    for r in rels.values():
        for pname, (fi, ei) in r.ports.items():
            ports[f"{r.component}.{pname}"] = ([r.flows[i] for i in fi], [r.efforts[i] for i in ei])
    out: list[Optional[str]] = []
    rng = np.random.default_rng(11)
    wires = top.wires
    for cert, (a, b, label) in zip(certs, order):
        ca, cb = cluster_of.get(owner[a]), cluster_of.get(owner[b])
        if ca is None or cb is None or a not in ports or b not in ports:
            out.append(None)
            continue
        K_rows = rows[ca] if ca == cb else (rows[ca], rows[cb])
        K_cols = cols[ca] if ca == cb else (cols[ca], cols[cb])
        (fa, ea), (fb, eb) = ports[a], ports[b]
        w = -1 if label in wires else 1  # a wire (phc.ir.wires): f_a + f_b, e_a − e_b
        S = [x - w * y for x, y in zip(fa, fb)] + [x + w * y for x, y in zip(ea, eb)]
        condition = None
        if not cert.surjective:  # only where the numeric certificate found a failure
            try:
                condition = _condition(_joined(K_rows), S, _joined(K_cols), exact, rng, SYMBOLIC_MAX_ROWS)
            except (ValueError, TypeError, NotImplementedError, ZeroDivisionError, sp.PolynomialError):
                condition = None
        out.append(condition)
        for data in (rows, cols):
            data.pop(cb)
            data.pop(ca, None)
        kept = _merge(ca, cb, cluster_of, members)
        rows[kept], cols[kept] = (K_rows, S), K_cols
    return out


def _merge(ca, cb, cluster_of: dict, members: dict, data: Optional[dict] = None):
    """Join clusters `ca` and `cb` (union by size: the smaller one's members are relabelled,
    linear overall whichever side a connection names first); returns the label kept. The
    entry of the other label in `data` is dropped (the caller stores the joined value)."""
    if ca == cb:
        return ca
    keep, gone = (ca, cb) if len(members[ca]) >= len(members[cb]) else (cb, ca)
    for name in members[gone]:
        cluster_of[name] = keep
    members[keep].extend(members.pop(gone))
    if data is not None:
        data.pop(gone, None)
    return keep


def _joined(tree) -> list:
    """The items of a tree of lists (a list, or a pair of trees: left before right), in order."""
    out, stack = [], [tree]
    while stack:
        node = stack.pop()
        if isinstance(node, list):
            out.extend(node)
        else:
            stack.extend(reversed(node))
    return out


def _condition(K_rows, S, variables, exact, rng, limit) -> Optional[str]:
    full = sp.Matrix(K_rows + S).jacobian(variables).xreplace(exact)
    states = sorted(full.free_symbols, key=str)
    if not states:
        return None  # constant: the numeric rank is exact
    point = {s: sp.Float(float(x)) for s, x in zip(states, rng.uniform(-1, 1, len(states)))}
    Fn = np.array(full.xreplace(point).evalf(), dtype=float)
    r1 = int(np.linalg.matrix_rank(Fn))
    if r1 > limit:
        return None
    pick_rows, rank = [], 0
    for i in range(Fn.shape[0]):
        if np.linalg.matrix_rank(Fn[pick_rows + [i]]) > rank:
            pick_rows.append(i)
            rank += 1
    pick_cols, rank = [], 0
    for j in rng.permutation(Fn.shape[1]).tolist():
        if np.linalg.matrix_rank(Fn[np.ix_(pick_rows, pick_cols + [j])]) > rank:
            pick_cols.append(j)
            rank += 1
    atoms: dict = {}

    def atomize(e):
        return e.replace(lambda x: x.is_Function or (x.is_Pow and not x.exp.is_Integer),
                         lambda x: atoms.setdefault(x, sp.Dummy(f"a{len(atoms)}")))

    minor = full.extract(pick_rows, pick_cols).applyfunc(atomize).det(method="berkowitz")
    back = {v: k for k, v in atoms.items()}
    factors = [f.xreplace(back) for f, _ in sp.factor_list(sp.expand(minor))[1] if f.free_symbols]
    # Keep the factors on whose zero set the rank of [K; S] really drops.
    kept = [f for f in factors if not (f.is_Pow and f.exp < 0) and _rank_drops_on(full, f, states, rng, r1)]
    return " or ".join(f"{sp.sstr(sp.simplify(f))} = 0" for f in kept) or None


def _rank_drops_on(M, factor, states, rng, full_rank) -> bool:
    """Check numerically that M loses rank at random points of {factor = 0}."""
    syms = sorted(factor.free_symbols, key=str)
    for sym in syms:
        hits = 0
        for _ in range(3):
            others = {s: sp.Float(float(x)) for s, x in zip(states, rng.uniform(-1, 1, len(states))) if s != sym}
            try:
                roots = [r for r in sp.solve(factor.xreplace(others), sym) if r.is_real]
            except NotImplementedError:
                roots = []
            if not roots:
                break
            Mn = np.array(M.xreplace({**others, sym: roots[0]}).evalf(), dtype=float)
            if _rank(np.linalg.svd(Mn, compute_uv=False)) >= full_rank:
                return False
            hits += 1
        if hits:
            return True
    return False


def _rigid_ranks(top, point, diags) -> None:
    """c_q(q, t) and A(q, t) of full row rank at the initial configuration and time; name
    dependent rows."""
    for name, ctx, path, q, cq, A, labels_c, labels_a in top.rigid_constraints:
        for mat, labels, what in ((cq, labels_c, "position constraints c'(q)"),
                                  (A, labels_a, "velocity constraints A(q)")):
            if not mat.rows:
                continue
            values = {s: point.get(s, sp.Float(0.3)) for s in q}
            values[T] = point.get(T, sp.Float(0.0))
            M = np.array(mat.xreplace(top.parameter_defaults).xreplace(values).evalf(), dtype=float)
            dependent = []
            for i in range(M.shape[0]):
                rows = [j for j in range(i + 1) if j not in dependent]
                s = np.linalg.svd(M[rows], compute_uv=False)
                if _rank(s) < len(rows):
                    dependent.append(i)
            if dependent:
                names = ", ".join(f"`{labels[i]}`" for i in dependent)
                key = "constraints" if labels is labels_c else "velocity_constraints"
                diags.append(Diagnostic(
                    "PHC-E410", f"the {what} of `{name}` are redundant at the initial configuration: {names} "
                    "depend(s) on the rows before", span=ctx.smap.locate((*path, key, dependent[0])),
                    path=f"{name}.{labels[dependent[0]]}",
                    hint="remove the redundant constraint; its multiplier would not be unique"))


def _passivity(top, diags, seed) -> None:
    """f·e ≥ 0 for user resistive laws at random flows (laws solved for the efforts)."""
    rng = np.random.default_rng(seed + 1)
    for name, ports, ctx, path in top.resistive_laws:
        for f_syms, e_syms, laws in ports:
            fs = f_syms if isinstance(f_syms, list) else [f_syms]
            es = e_syms if isinstance(e_syms, list) else [e_syms]
            if len(laws) != len(es):
                continue
            for _ in range(3):
                point = {s: sp.Float(float(x)) for s, x in zip(fs, rng.uniform(-2, 2, len(fs)))}
                eqs = [law.xreplace(top.parameter_defaults).xreplace(point) for law in laws]
                try:
                    sol = sp.solve(eqs, es, dict=True)
                except NotImplementedError:
                    break
                if not sol:
                    break
                power = sum(float(point[f]) * float(sol[0].get(e, 0.0)) for f, e in zip(fs, es))
                if power < -1e-12:
                    label = str(es[0]).rsplit(".", 1)[0]
                    diags.append(Diagnostic(
                        "PHC-E406", f"resistive port `{label}` of `{name}` is not passive: f·e = {power:.3g} < 0 at "
                        f"f = {[round(float(point[f]), 3) for f in fs]}", span=ctx.smap.locate((*path, "resistive")),
                        path=name, hint="a resistive law must satisfy f·e ≥ 0 (it dissipates energy); one that "
                        "supplies power by design (a controlled source) is declared `kind: source`"))
                    break
