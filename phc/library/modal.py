"""Structure-preserving modal truncation of the partitioned beam discretizations
(effect `modes: k` of `string`, `euler_bernoulli_beam`, `timoshenko_beam`, `moving_beam`).

The full discretization (:func:`phc.library.beams._lower_partitioned`, the paper's eq. (7)
after N integrations by parts) reads, with the state groups A (momenta, trace-carrying)
and B (strains), mass matrices ``M``, energy matrices ``Q = M^{H}`` and the co-energies
``e`` defined by ``M e = Q x``::

    M ẋ + N e + B_∂ e_∂ = 0,      f_∂ = B_∂ᵀ e_A,      H = ½ xᵀ Q x,

where the lossless part of ``N`` is skew (the interconnection ``[[0, −sDᵀ], [sD, 0]]`` plus
the P0 terms) and its symmetric part is the damping. In co-energy variables
``x = Q⁻¹M e`` this is ``K ė + N e + B_∂ e_∂ = 0`` with ``K = M Q⁻¹ M`` ≻ 0.

**Basis (Craig–Bampton in the velocity field).** The boundary ports take efforts as
inputs and give traces of ``e_A`` as flows (the paper's eqs. (9), (12): the physical
choice of W_f, W_e in Example 1). Eliminating ``e_B`` gives the second-order
system ``K_A ë_A + S e_A = −B_∂ ė_∂`` with the stiffness ``S = N_BAᵀ K_B⁻¹ N_BA`` ⪰ 0,
whose null space holds the rigid motions. We use

* the *static boundary modes* ``Ψ``: for each trace DOF Γ (end velocities, end angular
  velocities) the field of least strain rate with that trace 1 and the others 0,
  ``e_I = −S_II⁻¹ S_IΓ e_Γ``. Their span contains every rigid-body velocity field (the
  affine fields that carry ``v0, vL`` of the moving beam are reproduced exactly), and
  the coordinates of ``Ψ`` *are* the boundary traces, so the reduced component has the
  same ports with the same port variables and connects exactly like the full one —
  including to ``zero_flow`` terminations (clamped or pinned ends), which the free–free
  modes represent badly;
* the k lowest *fixed-interface modes* ``Φ`` (``S_II φ = ω² K_II φ``, traces zero).

This choice converges for every boundary condition the component may be connected to
(Rayleigh–Ritz with a basis containing the exact static response), and is exact for the
k lowest modes of the component with all traces held at zero. The strain group is
projected on ``V_B = span K_B⁻¹ N_BA V_A`` (K_B-orthonormalized): the strain rates that
the kept velocity fields produce, so ``e_B`` stays in its space for all time.

**Projection (Petrov–Galerkin with the energy matrices).** Co-energies ``e = V z``, states
``x = Q⁻¹ M V z``, rows tested with ``Vᵀ``, each group with its own basis::

    (Vᵀ K V) ż + (Vᵀ N V) z + Vᵀ B_∂ e_∂ = 0,     f_∂ = B_∂ᵀ V_A z_A,     H = ½ zᵀ (Vᵀ K V) z.

``Vᵀ K V`` ≻ 0 and the lossless part of ``Vᵀ N V`` is skew (it is skew-symmetrized
exactly), so the reduced system is again pH and ``dH/dt = −f_∂·e_∂ − zᵀ (Vᵀ N_sym V) z``
holds to round-off, like the full discretization's. Constant coefficients stay run-time
parameters (``K = (1/s) M Q̂⁻¹ M``); the basis itself is computed at the default
parameter values — at other values the projection is still structure-preserving, only no
longer exactly modal.

The rows of a truncation are derived from its description (:func:`_describe_reduced`,
:func:`phc.library.dirac.emit_sparse`).
"""

from __future__ import annotations

import numpy as np
import scipy.linalg as sla
import scipy.sparse as sps
import sympy as sp

from phc.ir.dae import LinearTerm, QuadraticForm
from phc.discretize.fem1d import assemble


def _sparse(A: np.ndarray, symmetric: bool = False) -> sps.csr_matrix:
    """Dense → CSR, dropping entries below 1e-13 of the largest (mask symmetric in |A|)."""
    if symmetric:
        A = (A + A.T) / 2
    big = np.abs(A).max(initial=0.0)
    out = np.where(np.abs(A) > 1e-13 * big, A, 0.0)
    return sps.csr_matrix(out)


def compute_craig_bampton(K_A, S, boundary, k):
    """``V_A = [Ψ | Φ_k]`` and the fixed-interface ω² (all of them).

    K_A, S: dense (n, n); boundary: trace DOF indices (the coordinates of Ψ, in order).
    """
    n = K_A.shape[0]
    G = np.asarray(boundary, dtype=int)
    interior = np.setdiff1d(np.arange(n), G)
    S_II, S_IG = S[np.ix_(interior, interior)], S[np.ix_(interior, G)]
    psi = np.zeros((n, len(G)))
    psi[G, np.arange(len(G))] = 1.0
    psi[interior] = -np.linalg.solve(S_II, S_IG)
    w2, phi_i = sla.eigh(S_II, K_A[np.ix_(interior, interior)])
    phi = np.zeros((n, min(k, len(interior))))
    phi[interior] = phi_i[:, :phi.shape[1]]
    return np.hstack([psi, phi]), w2


class ReducedFields:
    """The reduced component: states ``za`` (group A co-energy coordinates; the first ones
    are the boundary traces) and ``zb``; gives traces, loads and functionals of the fields
    in the same terms as :class:`phc.library.beams.FullFields`."""

    def __init__(self, b, fields, V, offsets, group_of, za, zb, rows, scale, state_map, boundary_coord,
                 structure=None):
        self.b, self.fields, self.V, self.offsets = b, fields, V, offsets
        self.group_of, self.za, self.zb, self.rows = group_of, za, zb, rows
        self.scale, self.state_map, self.boundary_coord = scale, state_map, boundary_coord
        self.structure = structure
        """The complete description (:class:`phc.library.beams.Structure`, groups "A", "B")."""

    def space(self, local):
        return self.fields[local][0]

    def _basis(self, local):
        g = self.group_of[local]
        o = self.offsets[local]
        return self.V[g][o:o + self.fields[local][0].size], (self.za if g == "A" else self.zb)

    def trace(self, local, dof) -> sp.Expr:
        Vf, z = self._basis(local)
        return _combination(Vf[dof], z)

    def load(self, local, dof, expr) -> None:
        if self.rows is None:  # derived from the description (d_load)
            return
        Vf, _ = self._basis(local)
        rows = self.rows[self.group_of[local]]
        for i, v in enumerate(Vf[dof]):
            if v:
                self.b.add_to_row(rows[i], float(v) * expr if v != 1.0 else expr)

    def load_vector(self, local, r, expr) -> None:
        if self.rows is None:
            return
        Vf, _ = self._basis(local)
        rows = self.rows[self.group_of[local]]
        for i, v in enumerate(Vf.T @ r):
            if v:
                self.b.add_to_row(rows[i], expr * float(v))

    def pair(self, local, r) -> sp.Expr:
        Vf, z = self._basis(local)
        return _combination(Vf.T @ r, z)

    def state_functional(self, local, g) -> sp.Expr:
        """``gᵀ x_local`` with ``x = (1/s) Q̂⁻¹ M V z``."""
        _, z = self._basis(local)
        return _combination(self.state_map[local].T @ g, z) / self.scale[local]

    # The same in the terms of the complete description (multipliers λ of each group).
    def d_trace(self, local, dof) -> sp.Expr:
        Vf, _ = self._basis(local)
        return _combination(Vf[dof], self.structure.lam[self.group_of[local]])

    def d_load(self, local, dof, expr) -> None:
        Vf, _ = self._basis(local)
        for i, v in enumerate(Vf[dof]):
            if v:
                self.structure.load(self.group_of[local], i, float(v) * expr if v != 1.0 else expr)

    def d_load_vector(self, local, r, expr) -> None:
        Vf, _ = self._basis(local)
        for i, v in enumerate(Vf.T @ r):
            if v:
                self.structure.load(self.group_of[local], i, expr * float(v))

    def d_pair(self, local, r) -> sp.Expr:
        Vf, _ = self._basis(local)
        return _combination(Vf.T @ r, self.structure.lam[self.group_of[local]])


def _combination(c, z) -> sp.Expr:
    big = np.abs(c).max(initial=0.0)
    return sum((float(ci) * zi for ci, zi in zip(c, z) if abs(ci) > 1e-13 * big), sp.Integer(0))


def lower_modal(b, ctx, name, spec, path, mesh, fields_a, fields_b, couplings, skew, ports, order, k,
                boundary=None, kelvin_voigt=False, derive=False):
    """The reduced counterpart of ``_lower_partitioned`` (same arguments, but fields are
    ``{local: (space, coefficient)}``; `boundary` lists extra trace DOFs ``(a_local, end,
    derivative)`` when the caller adds the ports itself). Returns a :class:`ReducedFields`.
    `derive`: the rows are derived from the description (:func:`_describe_reduced`) once
    the ports are added (by :func:`~phc.library.beams._boundary_ports`, or by a caller that
    adds its own)."""
    from phc.library.beams import _boundary_ports, _describe, _end_dof
    from phc.library.dirac import emit

    span = ctx.smap.locate(path)
    defaults = b.default_values()
    fields = {**fields_a, **fields_b}
    group_of = {**{l: "A" for l in fields_a}, **{l: "B" for l in fields_b}}
    offsets, sizes = {}, {"A": 0, "B": 0}
    for local, (space, _) in fields.items():
        g = group_of[local]
        offsets[local] = sizes[g]
        sizes[g] += space.size
    nA, nB = sizes["A"], sizes["B"]
    mass = {l: assemble(s, 0, s, 0) for l, (s, _) in fields.items()}
    qhat = {l: assemble(s, 0, s, 0, c.function()) for l, (s, c) in fields.items()}
    scale = {l: c.scale() for l, (_, c) in fields.items()}
    # K̂ = M Q̂⁻¹ M per field (dense), and the state map Q̂⁻¹ M.
    qinv_m = {l: np.linalg.solve(qhat[l].toarray(), mass[l].toarray()) for l in fields}
    khat = {l: mass[l].toarray() @ qinv_m[l] for l in fields}
    s_num = {l: float(scale[l].xreplace(defaults)) for l in fields}  # scale() is a sympy expression

    def idx(local):
        o = offsets[local]
        return slice(o, o + fields[local][0].size)

    K = {"A": np.zeros((nA, nA)), "B": np.zeros((nB, nB))}
    for l in fields:
        K[group_of[l]][idx(l), idx(l)] = khat[l] / s_num[l]
    # The lossless part N of the residual rows (numbers: couplings and P0 entries).
    n_all = nA + nB
    glob = {l: (offsets[l] if group_of[l] == "A" else nA + offsets[l]) for l in fields}
    N = np.zeros((n_all, n_all))
    for a_local, b_local, sign in couplings:
        Dm = assemble(fields_b[b_local][0], 0, fields_a[a_local][0], order).toarray()
        ia, ib = glob[a_local], glob[b_local]
        N[ib:ib + Dm.shape[0], ia:ia + Dm.shape[1]] += -float(sign) * Dm
        N[ia:ia + Dm.shape[1], ib:ib + Dm.shape[0]] += float(sign) * Dm.T
    for row_local, col_local, value in skew:
        A = assemble(fields[row_local][0], 0, fields[col_local][0], 0).toarray()
        ir, ic = glob[row_local], glob[col_local]
        N[ir:ir + A.shape[0], ic:ic + A.shape[1]] += -float(value) * A
    N = (N - N.T) / 2
    N_BA = N[nA:, :nA]
    S = N_BA.T @ np.linalg.solve(K["B"], N_BA)
    S = (S + S.T) / 2
    if boundary is None:
        boundary = [(a, end, der) for _, a, end, der, _ in ports]
    gamma = [offsets[a] + _end_dof(fields[a][0], end, der) for a, end, der in boundary]
    V_A, w2 = compute_craig_bampton(K["A"], S, gamma, k)
    n_fixed, n_kept = len(w2), V_A.shape[1] - len(gamma)
    C = np.linalg.solve(K["B"], N_BA @ V_A)
    lam, U = np.linalg.eigh(C.T @ K["B"] @ C)
    keep = lam > 1e-10 * lam.max()
    V_B = C @ U[:, keep] / np.sqrt(lam[keep])
    V = {"A": V_A, "B": V_B}
    if n_fixed > n_kept:
        b.leave_out(name, f"{n_fixed - n_kept} modes above mode {n_kept}", f"effect `modes` = {k}")
    za = [b.add_state(name, f"za[{i}]", span) for i in range(V_A.shape[1])]
    zb = [b.add_state(name, f"zb[{i}]", span) for i in range(V_B.shape[1])]
    z = {"A": tuple(s for s, _ in za), "B": tuple(s for s, _ in zb)}
    dz = {"A": tuple(d for _, d in za), "B": tuple(d for _, d in zb)}
    terms = {"A": [], "B": []}
    energy = {"A": [], "B": []}  # (1/s, Vᵀ K̂ V) per field: E = ∂²H/∂z² of each group
    for l in fields:
        g = group_of[l]
        Vf = V[g][idx(l)]
        kr = _sparse(Vf.T @ khat[l] @ Vf, symmetric=True)
        terms[g].append(LinearTerm(1 / scale[l], kr, z[g], derivative=True))
        energy[g].append((1 / scale[l], kr))
        # the energy ½ xᵀQx = ½ (1/s) zᵀ Vᵀ K̂ V z
        b.quadratic_energy.append(QuadraticForm(1 / (2 * scale[l]), kr, z[g]))
    Vblk = np.zeros((n_all, V_A.shape[1] + V_B.shape[1]))
    Vblk[:nA, :V_A.shape[1]] = V_A
    Vblk[nA:, V_A.shape[1]:] = V_B
    Jr = Vblk.T @ N @ Vblk
    Jr = _sparse((Jr - Jr.T) / 2).toarray()  # exactly skew (symmetric drop mask)
    mA = V_A.shape[1]
    blocks = {("A", "A"): Jr[:mA, :mA], ("A", "B"): Jr[:mA, mA:], ("B", "A"): Jr[mA:, :mA],
              ("B", "B"): Jr[mA:, mA:]}
    for (gr, gc), blk in blocks.items():
        if blk.size and np.abs(blk).max() > 0:
            terms[gr].append(LinearTerm(sp.Integer(1), sps.csr_matrix(blk), z[gc]))
    losses, lossy = [], None
    damping = getattr(spec, "damping", None)
    if damping is not None and not spec.effects.damping:
        b.leave_out(name, "distributed damping", "effect `damping` is off")
    elif damping is not None:
        from phc.library.beams import _Coefficient

        coeff = _Coefficient(b, ctx, damping, (*path, "damping"))
        coeff.check_positive(name, "damping", mesh, strict=False)
        a_local = next(iter(fields_a))
        space = fields_a[a_local][0]
        kk = order if kelvin_voigt else 0
        Md = assemble(space, kk, space, kk, coeff.function()).toarray()
        Vf = V_A[idx(a_local)]
        dr = _sparse(Vf.T @ Md @ Vf, symmetric=True)
        terms["A"].append(LinearTerm(coeff.scale(), dr, z["A"]))
        lossy = id(terms["A"][-1])
        b.quadratic_dissipation.append(QuadraticForm(coeff.scale(), dr, z["A"], component=name, span=span))
        mB = V_B.shape[1]
        losses.append((coeff.scale(), sps.block_diag([dr, sps.csr_matrix((mB, mB))], format="csr") if mB else dr))
    rows = None
    if not derive:
        rows = {g: b.add_linear_rows(name, f"modal_{g.lower()}.dynamics", V[g].shape[1], terms[g], span)
                for g in ("A", "B") if V[g].shape[1]}
        rows.setdefault("B", [])
    state_map = {l: qinv_m[l] @ V[group_of[l]][idx(l)] for l in fields}
    boundary_coord = {(a, end, der): z["A"][i] for i, (a, end, der) in enumerate(boundary)}
    # The complete description: K f_s = −Jr λ − R λ − Vᵀ B_∂ e_∂ with e_s = K λ = ∂H/∂z (the
    # reduced pH system in the co-energy coordinates; rows K ż + Jr z + … = 0 say λ = z).
    groups = [g for g in ("A", "B") if V[g].shape[1]]
    storage = {g: (z[g], dz[g], energy[g], [LinearTerm(c, A, z[g]) for c, A in energy[g]]) for g in groups}
    if derive:
        structure = _describe_reduced(name, spec.type, span, groups, z, dz, terms, energy, lossy)
    else:
        structure = _describe(name, spec.type, span, groups, [V[g].shape[1] for g in groups],
                              [f"lambda_{g.lower()}" for g in groups], storage, -sps.csr_matrix(Jr), losses)
    handle = ReducedFields(b, {l: (s,) for l, (s, _) in fields.items()}, V, offsets, group_of, z["A"], z["B"],
                           rows, scale, state_map, boundary_coord, structure)
    described = _boundary_ports(b, name, span, handle, ports, "modal truncation of the discretized PDE "
                                "(Petrov–Galerkin with the energy matrices): skew interconnection by construction; "
                                "ports certified through traces")
    if derive and described is not None:
        emit(b, described)
    return handle


def _describe_reduced(name, kind, span, groups, z, dz, terms, energy, lossy):
    """The complete description of the reduced system written group by group, from which
    its rows are derived (:func:`phc.library.dirac.emit_sparse`): storage ``f_s = ż``,
    ``e_s = ∂H/∂z = K z`` (K = Σ (1/s) Vᵀ K̂ V of the group's fields), the co-energy
    coordinates λ with ``e_s = Kᵀλ`` and the law ``λ = z`` (K ≻ 0: the two say the same),
    each group's dynamics ``K f_s + Jr λ + e_R + Vᵀ B_∂ e_∂ = 0`` with the terms of the
    rows (`terms`, over λ instead of z) and the damping (the term `lossy`) through a
    resistive pair ``f_R = λ_A``, ``e_R = c Vᵀ M_d V f_R``."""
    from phc.library.beams import Structure
    from phc.library.dirac import DiracBuilder

    d = DiracBuilder(name, kind, span)
    one = sp.Integer(1)
    lam = {g: d.mults(f"lambda_{g.lower()}", len(z[g])) for g in groups}
    coordinate = {z[g]: lam[g] for g in groups}
    storage = {g: d.storage_vector(g, z[g], dz[g], [LinearTerm(c, A, z[g]) for c, A in energy[g]]) for g in groups}
    dynamics = {}
    for g in groups:
        n = len(z[g])
        eye = sps.identity(n, format="csr")
        d.block(f"modal_{g.lower()}.coordinates", n, [LinearTerm(one, eye, lam[g]), LinearTerm(-one, eye, z[g])],
                law=True, solve=lam[g])
        dyn = []
        for t in terms[g]:
            if t.derivative:
                dyn.append(LinearTerm(t.coeff, t.matrix, storage[g][0]))
            elif id(t) == lossy:
                f_r, e_r = d.resistor_vector("R", n)
                d.block("resistive.flow", n, [LinearTerm(one, eye, f_r), LinearTerm(-one, eye, lam[g])], solve=f_r)
                d.block("resistive.law", n, [LinearTerm(one, eye, e_r), LinearTerm(-t.coeff, t.matrix, f_r)],
                        law=True, solve=e_r)
                dyn.append(LinearTerm(one, eye, e_r))
            else:
                dyn.append(LinearTerm(t.coeff, t.matrix, coordinate[t.symbols]))
        dynamics[g] = d.block(f"modal_{g.lower()}.dynamics", n, dyn)
    for g in groups:
        d.block(f"modal_{g.lower()}.coenergy", len(z[g]), [LinearTerm(one, sps.identity(len(z[g]), format="csr"),
                                                                       storage[g][1])]
                + [LinearTerm(-c, A.T.tocsr(), lam[g]) for c, A in energy[g]])
    return Structure(d, lam, {g: 0 for g in groups}, dynamics)
