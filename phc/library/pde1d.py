"""Generic 1-D port-Hamiltonian PDEs (``type: pde1d``), the paper's Section 4.1.

Checks (each failure is a located error naming the identity that fails):

* ``P_k = (−1)^{k+1} P_kᵀ`` for every k, ``P_N`` invertible (eq. (7));
* ``H(ξ)`` symmetric positive definite and ``D(ξ) + D(ξ)ᵀ ⪰ 0`` at the quadrature points
  (D is discretized like the co-energy couplings, its dissipated power is the quadratic
  form of its symmetric part);
* ``W = [W_f; W_e]`` invertible and the Green identity (eq. (10))
  ``⟨z, Σ P_k z^{(k)}⟩ = −(W_f γ(z))ᵀ(W_e γ(z))`` — verified on random polynomials z,
  which determine the quadratic boundary form completely.

Discretization reuses the partitioned mixed scheme of :mod:`phc.library.beams`; it needs
``P_N`` to couple two groups of variables only (a bipartite pattern, as for strings and
beams), a diagonal H, and boundary flows that are traces of the co-energies of the
velocity-like group (the group whose equations are integrated by parts). The user's
ports are then related to the scheme's natural ones by ``f_∂ = T f_nat``,
``e_nat = Tᵀ e_∂`` — power preserving by the Green identity.
"""

from __future__ import annotations

import numpy as np
import sympy as sp

from phc.discretize.fem1d import DP1, H3, P0, P1
from phc.library.beams import _Coefficient, _end_dof, _Field, _lower_partitioned, _mesh
from phc.library.phs import local_scope


def _numbers(b, ctx, rows, path, shape, what):
    try:
        M = np.array(rows, dtype=float)
    except (TypeError, ValueError):
        b.error("PHC-E150", f"{what} must hold numbers", ctx, path)
        return None
    if M.shape != shape:
        b.error("PHC-E102", f"{what} is {'×'.join(map(str, M.shape))}, expected {shape[0]}×{shape[1]}", ctx, path)
        return None
    return M


def green_identity_error(P: list[np.ndarray], Wf: np.ndarray, We: np.ndarray, length: float, seed: int = 0) -> float:
    """Largest mismatch of the Green identity (eq. (10)) over random polynomial z (relative)."""
    N, d = len(P) - 1, P[0].shape[0]
    rng = np.random.default_rng(seed)
    s, w = np.polynomial.legendre.leggauss(2 * (2 * N + 2) + 2)
    xi = 0.5 * length * (s + 1)
    w = 0.5 * length * w
    worst, scale = 0.0, 0.0
    for _ in range(4 * (2 * N * d) ** 2 + 4):
        coeffs = rng.normal(size=(d, 2 * N + 2))  # z_i(ξ) = Σ c ξ^k
        polys = [np.polynomial.Polynomial(c) for c in coeffs]

        def z(k, x):
            return np.array([p.deriv(k)(x) if k else p(x) for p in polys])

        lhs = sum(float(np.sum(w * np.einsum("ig,ig->g", z(0, xi), P[k] @ z(k, xi)))) for k in range(N + 1))
        gamma = np.concatenate([z(k, length) for k in range(N)] + [z(k, 0.0) for k in range(N)])
        rhs = -float((Wf @ gamma) @ (We @ gamma))
        worst = max(worst, abs(lhs - rhs))
        scale = max(scale, abs(lhs), abs(rhs), 1e-300)
    return worst / scale


def pde1d_rows(spec) -> str:
    """Where the rows of a ``pde1d`` come from: ``derived`` from its description, unless
    `D` has an off-diagonal entry written other than 0 (a dissipation coupling two
    variables: the rows are then written directly and compared with the description)."""
    D = spec.D or []
    off = any(value not in (0, 0.0) for i, row in enumerate(D) for j, value in enumerate(row) if i != j)
    return "hand-written" if off else "derived"


def lower_pde1d(b, ctx, name, spec, path):
    n_errors = len(b.diags.errors)  # this component's own errors stop it, not another's
    scope = local_scope(b, ctx, name, spec, path)
    del scope
    N, d = spec.order, len(spec.variables)
    if len(spec.P) != N + 1:
        b.error("PHC-E150", f"`P` of `{name}` must list P_0 … P_{N} ({N + 1} matrices), got {len(spec.P)}", ctx,
                (*path, "P"))
        return
    P = [_numbers(b, ctx, Pk, (*path, "P", k), (d, d), f"`P[{k}]`") for k, Pk in enumerate(spec.P)]
    Wf = _numbers(b, ctx, spec.W_f, (*path, "W_f"), (N * d, 2 * N * d), "`W_f`")
    We = _numbers(b, ctx, spec.W_e, (*path, "W_e"), (N * d, 2 * N * d), "`W_e`")
    if any(x is None for x in P) or Wf is None or We is None:
        return
    for k, Pk in enumerate(P):
        if np.abs(Pk - (-1) ** (k + 1) * Pk.T).max() > 1e-12:
            b.error("PHC-E151", f"`P[{k}]` of `{name}` must be {'skew-symmetric' if k % 2 == 0 else 'symmetric'} "
                    f"(P_k = (−1)^(k+1) P_kᵀ, the paper's eq. (7))", ctx, (*path, "P", k))
    if abs(np.linalg.det(P[N])) < 1e-12:
        b.error("PHC-E152", f"`P[{N}]` of `{name}` must be invertible", ctx, (*path, "P", N))
    W = np.vstack([Wf, We])
    if np.linalg.matrix_rank(W) < W.shape[0]:
        b.error("PHC-E154", f"`[W_f; W_e]` of `{name}` is not invertible: the boundary variables do not "
                "determine the boundary traces", ctx, (*path, "W_f"))
    if len(spec.ports) != N * d:
        b.error("PHC-E156", f"`{name}` needs {N * d} boundary port names (N·d), got {len(spec.ports)}", ctx,
                (*path, "ports"))
    mesh = _mesh(b, ctx, name, spec, path)
    if len(b.diags.errors) > n_errors or mesh is None:
        return
    err = green_identity_error(P, Wf, We, mesh.length)
    if err > 1e-9:
        b.error("PHC-E155", f"`W_f`, `W_e` of `{name}` violate the Green identity (the paper's eq. (10)): "
                f"⟨z, Σ P_k z^(k)⟩ ≠ −f_∂ᵀe_∂ (relative mismatch {err:.2g}); the boundary ports would not carry "
                "the power that enters the domain", ctx, (*path, "W_e"),
                hint="for a string, f_∂ = (v(a), v(b)) needs e_∂ = (Tε(a), −Tε(b))")
        return
    # H and D: symmetric positive (semi)definite at the quadrature points.
    Hc = [[_Coefficient(b, ctx, spec.H[i][j], (*path, "H", i, j)) for j in range(d)] for i in range(d)]
    xi = mesh.quadrature_points().ravel()

    def values(c):
        return c.function()(xi) if c.varies else np.full_like(xi, float(c.expr.xreplace(c.defaults)))

    Hv = np.array([[values(Hc[i][j]) for j in range(d)] for i in range(d)])  # (d, d, n)
    off = [(i, j) for i in range(d) for j in range(d) if i != j and np.abs(Hv[i, j]).max() > 0]
    if np.any(np.linalg.eigvalsh(np.moveaxis(Hv, 2, 0)) <= 0) or np.abs(Hv - Hv.transpose(1, 0, 2)).max() > 1e-12:
        b.error("PHC-E152", f"`H` of `{name}` must be symmetric positive definite on [0, L]", ctx, (*path, "H"))
        return
    if off:
        b.error("PHC-E157", f"`H` of `{name}` has off-diagonal entries; the mixed scheme needs a diagonal H", ctx,
                (*path, "H"))
        return
    if spec.D is not None:
        Dc = [[_Coefficient(b, ctx, spec.D[i][j], (*path, "D", i, j)) for j in range(d)] for i in range(d)]
        Dv = np.array([[values(Dc[i][j]) for j in range(d)] for i in range(d)])
        sym = Dv + Dv.transpose(1, 0, 2)
        if np.any(np.linalg.eigvalsh(np.moveaxis(sym, 2, 0)) < -1e-12):
            b.error("PHC-E153", f"`D + Dᵀ` of `{name}` must be positive semidefinite (the PDE would generate energy)",
                    ctx, (*path, "D"))
            return
    dissipation = []
    if spec.D is not None:
        # −D e in eq. (7): rows of variable i get +∫ basis_i D_ij basis_j e_j.
        dissipation = [(spec.variables[i], spec.variables[j], Dc[i][j]) for i in range(d) for j in range(d)
                       if np.abs(Dv[i, j]).max() > 0]
    # Partition of the variables by the pattern of P_N (a bipartite graph).
    import networkx as nx  # here, not on import (0.3 s CPU)

    graph = nx.Graph()
    graph.add_nodes_from(range(d))
    graph.add_edges_from((i, j) for i in range(d) for j in range(d) if abs(P[N][i, j]) > 0 and i != j)
    if any(abs(P[N][i, i]) > 0 for i in range(d)) or not nx.is_bipartite(graph):
        b.error("PHC-E159", f"`P[{N}]` of `{name}` does not couple two groups of variables; the partitioned "
                "scheme needs P_N = [[0, S], [±Sᵀ, 0]] after reordering", ctx, (*path, "P", N))
        return
    color = nx.bipartite.color(graph)
    # The velocity-like group (integrated by parts) is the one the boundary flows are traces of.
    group = {0: [i for i in range(d) if color[i] == 0], 1: [i for i in range(d) if color[i] == 1]}
    nd = N * d

    def trace_columns(vars_):
        return [blk * d + i for blk in range(2 * N) for i in vars_]

    a_group = next((g for g in (0, 1) if np.abs(Wf[:, trace_columns(group[1 - g])]).max(initial=0) == 0), None)
    if a_group is None:
        b.error("PHC-E160", f"the boundary flows of `{name}` mix both groups of variables; the scheme needs flows "
                "that are traces of the velocity-like group only", ctx, (*path, "W_f"))
        return
    A, B = group[a_group], group[1 - a_group]
    space_a, space_b = (P1, P0) if N == 1 else (H3, DP1)
    span = ctx.smap.locate(path)
    fields_a = {spec.variables[i]: (_Field(b, name, spec.variables[i], space_a(mesh), span), Hc[i][i]) for i in A}
    fields_b = {spec.variables[j]: (_Field(b, name, spec.variables[j], space_b(mesh), span), Hc[j][j]) for j in B}
    # ẋ_b ∋ s ∂^N e_a with s = P_N[b, a].
    couplings = [(spec.variables[i], spec.variables[j], float(P[N][j, i])) for i in A for j in B
                 if abs(P[N][j, i]) > 0]
    if any(abs(s) != 1.0 for *_, s in couplings):
        couplings = [(a, bb, s) for a, bb, s in couplings]
    skew = [(spec.variables[i], spec.variables[j], float(P[0][i, j])) for i in range(d) for j in range(d)
            if abs(P[0][i, j]) > 0]
    if N == 2 and np.abs(P[1]).max(initial=0) > 0:
        b.error("PHC-E159", f"`P[1]` of `{name}` must vanish for the N = 2 scheme", ctx, (*path, "P", 1))
        return
    derive = pde1d_rows(spec) == "derived"
    handle = _lower_partitioned(b, ctx, name, spec, path, mesh, fields_a, fields_b,
                                [(a, bb, sp.Integer(int(s)) if float(s).is_integer() else sp.Float(s))
                                 for a, bb, s in couplings], skew, [], order=N, dissipation=dissipation,
                                derive=derive)
    # Natural flows: traces of e_a (and slopes for N = 2) in the order of γ.
    nat = [(spec.variables[i], "b" if blk < N else "a", blk % N) for blk in range(2 * N) for i in range(d)]
    cols = [c for c, (var, _, _) in enumerate(nat) if var in fields_a]
    T = Wf[:, cols]  # f_∂ = T f_nat
    domains = spec.port_domains or ["generic"] * nd
    ports = [b.add_port(name, pname, domains[k] if k < len(domains) else "generic", 1, span=span)
             for k, pname in enumerate(spec.ports)]
    for k, port in enumerate(ports if not derive else ()):  # derived: from the description's port relations
        flow = sp.Integer(0)
        for c_idx, c in enumerate(cols):
            var, end, deriv = nat[c]
            fld = fields_a[var][0]
            if T[k, c_idx]:
                flow += float(T[k, c_idx]) * fld.e[_end_dof(fld.space, end, deriv)]
        b.define(port.f[0], flow)
    from phc.library.dirac import DiracBuilder, emit

    d = DiracBuilder(name, "pde1d", span)
    ds = handle.structure.d  # the complete description: the same port relations on its co-energies λ
    for port in ports:
        d.port(port)
        ds.port(port)
    lam = {c: d.mult(f"trace[{c}]") for c in cols}
    for k, port in enumerate(ports):
        d.rel(port.f[0] - sum((float(T[k, i]) * lam[c] for i, c in enumerate(cols) if T[k, i]), sp.Integer(0)))
        ds.rel(port.f[0] - sum((float(T[k, i]) * handle.d_trace(nat[c][0], _end_dof(fields_a[nat[c][0]][0].space,
                                                                                       nat[c][1], nat[c][2]))
                                for i, c in enumerate(cols) if T[k, i]), sp.Integer(0)), solve=port.f[0],
               label=f"{spec.ports[k]}.flow")
    # e_nat = Tᵀ e_∂ enters the row of each natural trace DOF.
    for c_idx, c in enumerate(cols):
        var, end, deriv = nat[c]
        fld = fields_a[var][0]
        dof = _end_dof(fld.space, end, deriv)
        contribution = sum((float(T[k, c_idx]) * ports[k].e[0] for k in range(nd) if T[k, c_idx]), sp.Integer(0))
        if contribution != 0:
            handle.load(var, dof, contribution)
            handle.d_load(var, dof, contribution)
    structure = ds.describe()
    d.register(b, kind="port_projection", note="discretized PDE: ports certified through im W_f on the traces",
               structure=structure)
    if derive:
        emit(b, structure)

