"""The moving-frame Euler–Bernoulli beam and the crank wheel (the paper's Section 5).

Moving beam (the paper's eqs. (19), (21), (22), (23), (24)), with the chord frame
``t = (q_f − q_0)/ℓ``, ``n = J t`` and ``ω = (v_nf − v_n0)/L``::

    q̇_r   = Z(q_r) (p_t/m, v_b(0), v_b(L))
    ṗ_t   = ω ∫ p_b dξ − tᵀe_0 − tᵀe_f                    (e = −F, generator convention)
    κ̇     = ∂²(ρ⁻¹p_b)
    ṗ_b   = −∂²(EIκ) − ρ ω p_t/m

The flexible part is the Euler–Bernoulli discretization of :mod:`phc.library.beams`
(Hermite cubics for p_b, discontinuous P1 for κ), whose natural boundary efforts are the
normal components ``nᵀe_0``, ``nᵀe_f`` and the moment efforts: this is the paper's
interconnection of the rigid part (eq. (25)) and the flexible part (eq. (26)) through
the coupling space R⁴ (Proposition 12). The modulation terms ``ω ∫p_b`` and ``−ρωp_t/m`` (K_r, K_f,
Proposition 11) are discretized with the same functional
``r_j = ∫ρφ_j`` on both sides, so they cancel exactly in the discrete power balance:
``e_t·ω rᵀe_p − Σ_j e_p,j ω e_t r_j = 0``.

Effect `axial` (beyond the paper; docs/crank-test-problem.md): the centerline
``q_0 + (ξ + u) t + w n`` gains the longitudinal displacement u with ``ε = ∂u/∂ξ`` and
``N = EA ε``; the tangential velocity becomes the field ``v_a = p_a/ρ`` (``p_t = ∫p_a``),
``ṗ_a = ∂(EAε) + ω p_b``, ``ε̇ = ∂(p_a/ρ)``, ``ṗ_b ∋ −ω p_a``, ω = (v_nf − v_n0)/ℓ with
the current chord length ``ℓ = L + ∫ε`` (a position invariant). P1/P0 for (p_a, ε) as
for the string; the modulation is tested with one matrix ``C_ij = ∫ρ φ_i^a φ_j^b`` on
both sides, so it cancels exactly in the discrete power balance. Only the bending is
Kelvin–Voigt damped. The flows of `m0`, `mf` are the end cross-sections' rotation rates
``ω + ∂ẇ/∂ξ = ∂e_p/∂ξ − (1/L − 1/ℓ)(v_f − v_0)`` (the slope rate alone is ``(1 + ε_mean)ω``
for a stretched beam), their moments acting through the transpose.

Effect `stiffening` (beyond the paper; docs/crank-test-problem.md#centrifugal-stiffening):
``ṗ_b ∋ ∂(N ∂w/∂ξ) + ρω²w`` with the centrifugal axial force ``N = ρω²(L² − ξ²)/2`` of a
spin about ξ = 0, as the skew modulation ``ṗ ∋ ω (a sᵀ − s aᵀ) e`` (``s = Gκ``, ``aᵀe = ω``)
with the reaction on the chord's rotation: no power for any state, the energy unchanged.
"""

from __future__ import annotations

import numpy as np
import sympy as sp

from phc.ir.dae import T
from phc.discretize.fem1d import _GAUSS_S, _GAUSS_W
from phc.discretize.fem1d import DP1, H3, P0, P1, assemble
from phc.library.beams import FullFields, _inverse, _lower_fields, prepare
from phc.library.dirac import DiracBuilder, emit
from phc.library.timing import refuse_time


def _deflection_functional(mesh, kappa_space, xi_star: float) -> np.ndarray:
    """g with w(ξ*) = Σ g_k κ_k for w'' = κ, w(0) = w(L) = 0 (Green's function)."""
    L = mesh.length
    pts = mesh.quadrature_points()  # (e, g)
    green = np.where(pts <= xi_star, pts * (xi_star - L) / L, xi_star * (pts - L) / L)
    vals = kappa_space.values(0)  # (nl, g)
    local = np.einsum("ag,eg,g->ea", vals, green, mesh.h * _GAUSS_W)
    g = np.zeros(kappa_space.size)
    np.add.at(g, kappa_space.dofs().ravel(), local.ravel())
    return g


def lower_moving_beam(b, ctx, name, spec, path):
    if not spec.effects.flexibility:
        if spec.effects.axial:
            b.leave_out(name, "axial deformation (effect `axial`)", "effect `flexibility` is off: a rigid link")
        if spec.effects.stiffening:
            b.leave_out(name, "centrifugal stiffening (effect `stiffening`)", "effect `flexibility` is off: a rigid link")
        _lower_rigid_link(b, ctx, name, spec, path)
        return
    axial = bool(spec.effects.axial)
    if axial and spec.EA is None:
        b.error("PHC-E145", f"effect `axial` of the moving beam `{name}` needs the axial stiffness `EA`; give `EA` "
                "or turn `axial` off", ctx, path)
        return
    if axial and spec.effects.modes is not None:
        b.error("PHC-E145", f"effect `axial` of the moving beam `{name}` does not work with `modes`; drop `modes` "
                "or turn `axial` off", ctx, (*path, "effects"))
        return
    stiffening = bool(spec.effects.stiffening)
    if stiffening and (axial or spec.effects.modes is not None):
        other = "`axial`" if axial else "`modes`"
        b.error("PHC-E145", f"effect `stiffening` of the moving beam `{name}` does not work with {other} yet; turn "
                f"`stiffening` off or drop {other}", ctx, (*path, "effects"))
        return
    prep = prepare(b, ctx, name, spec, path, ("rhoA", "EI", "EA") if axial else ("rhoA", "EI"))
    if prep is None:
        return
    mesh, span, coeffs = prep
    rho = coeffs["rhoA"]
    for what, c in coeffs.items():
        if c.varies:
            b.error("PHC-E143", f"`{what}` of the moving beam `{name}` must be constant along the beam", ctx,
                    (*path, what))
            return
    L = sp.Float(mesh.length)
    n_el = mesh.elements
    dof0, dofL, slope0, slopeL = 0, 2 * n_el, 1, 2 * n_el + 1
    # The four trace DOFs (v0, v0', vL, vL') carry the coupling to the rigid part; with
    # `modes` they are the static-mode coordinates of the reduced field (phc.library.modal).
    space, kappa_space = H3(mesh), DP1(mesh)
    if axial:
        # Axial deformation: the tangential velocity becomes the field v_a = p_a/ρ (P1) with
        # the strain ε = ∂u/∂ξ (P0) and N = EA ε, a string/bar of first order beside the
        # bending pair of second order; p_t = ∫p_a is no longer a state of its own.
        axial_space, eps_space = P1(mesh), P0(mesh)
        fields = _lower_fields(b, ctx, name, spec, path, mesh, span,
                               {"p": (space, _inverse(rho)), "pa": (axial_space, _inverse(rho))},
                               {"kappa": (kappa_space, coeffs["EI"]), "eps": (eps_space, coeffs["EA"])},
                               [("p", "kappa", 1, 2), ("pa", "eps", 1, 1)], [], [], order=2, kelvin_voigt=True,
                               derive=True)
    else:
        fields = _lower_fields(b, ctx, name, spec, path, mesh, span, {"p": (space, _inverse(rho))},
                               {"kappa": (kappa_space, coeffs["EI"])}, [("p", "kappa", 1)], [], [], order=2,
                               boundary=[("p", "a", 0), ("p", "a", 1), ("p", "b", 0), ("p", "b", 1)],
                               kelvin_voigt=True, derive=True)
    # Rigid part.
    q = [b.add_state(name, f"{pt}[{k}]", span) for pt in ("q0", "qf") for k in range(2)]
    (q0x, dq0x), (q0y, dq0y), (qfx, dqfx), (qfy, dqfy) = q
    mass = rho.expr * L
    chord = sp.Matrix([qfx - q0x, qfy - q0y])
    ell = sp.sqrt(chord.dot(chord))
    tv = chord / ell
    nv = sp.Matrix([-tv[1], tv[0]])
    v0, vL = fields.trace("p", dof0), fields.trace("p", dofL)
    if getattr(b.initial_fields.get(name), "fields", None):
        b.initial_fields[name].rigid = (v0, vL)  # the end normal velocities: the moving beam's `velocity` field
    if axial:
        pt = dpt = None
        dofA = axial_space.size - 1
        omega = (vL - v0) / ell  # the chord's rate of rotation; its length is L + u(L)
    else:
        pt, dpt = b.add_state(name, "p_t", span)
        omega = (vL - v0) / L
    # r_j = ∫ ρ φ_j (H3 basis): the same functional in both modulation terms.
    local = np.einsum("ag,g->a", space.values(0), mesh.h * _GAUSS_W)
    r = np.zeros(space.size)
    np.add.at(r, space.dofs().ravel(), np.broadcast_to(local, (n_el, len(local))).ravel())
    ports = {}
    for pname, pos in (("p0", [q0x, q0y]), ("pf", [qfx, qfy])):
        ports[pname] = b.add_port(name, pname, "mechanical.translational", 2, span=span, position=pos)
    for pname in ("m0", "mf"):
        ports[pname] = b.add_port(name, pname, "mechanical.rotational", 1, span=span)
    e0, ef = sp.Matrix(ports["p0"].e), sp.Matrix(ports["pf"].e)
    frame = 1 if spec.effects.moving_frame else 0
    if not frame:
        b.leave_out(name, "moving-frame terms K_r, K_f (ω∫p_b, −ρωp_t/m)" if not axial else
                    "moving-frame terms (ω p_b in the axial, −ω p_a in the transverse momentum)",
                    "effect `moving_frame` is off")
    if axial:
        # ṗ_a ∋ ω p_b, ṗ_b ∋ −ω p_a, tested with the same C_ij = ∫ρ φ_i^a φ_j^b on both sides:
        # e_aᵀ(ω C e_b) − e_bᵀ(ω Cᵀ e_a) = 0 in the discrete power balance, for any ω.
        C = assemble(axial_space, 0, space, 0).tocsr()
    if axial:
        # The chord length is L + u(L) = L + ∫ε: ℓ̇ = tᵀ(q̇_f − q̇_0) = e_a(L) − e_a(0) = Σ_k h ε̇_k.
        stretch = fields.state_functional("eps", np.full(eps_space.size, mesh.h))
        b.add_invariant(ell - (L + stretch), name, "chord_length", span)
        b.extra_outputs[f"{name}.stretch"] = stretch
    else:
        b.hamiltonian.append(pt**2 / (2 * mass))
        b.add_invariant(chord.dot(chord) - L**2, name, "chord_length", span)
    for i, frac in enumerate(spec.deflection_at):
        g = _deflection_functional(mesh, kappa_space, float(frac) * mesh.length)
        b.extra_outputs[f"{name}.w[{i}]"] = fields.state_functional("kappa", g)
    b.extra_outputs[f"{name}.omega"] = omega
    if spec.initial_shape == "straight" and not isinstance(fields, FullFields):
        # Reduced: the static modes reproduce affine fields, so a rigid start is "no
        # fixed-interface motion, end slopes (v_f − v_0)/L, no strain".
        n_static = 4
        for i, zi in enumerate(fields.za[n_static:]):
            b.initial_relations.append((f"{name}.rigid_start.mode[{i}]", {zi: 1.0}))
        for i, zi in enumerate(fields.zb):
            b.initial_relations.append((f"{name}.straight_start[{i}]", {zi: 1.0}))
        for label, zi in (("a", fields.za[1]), ("b", fields.za[3])):
            b.initial_relations.append((f"{name}.rigid_start.slope_{label}",
                                        {zi: 1.0, fields.za[2]: -1.0 / mesh.length, fields.za[0]: 1.0 / mesh.length}))
    elif spec.initial_shape == "straight":
        p, kappa = fields.fields["p"][0], fields.fields["kappa"][0]
        # At t₀ the rod moves rigidly: the velocity field e_p = ρ⁻¹p_b is affine between the
        # end normal velocities (values at the nodes, slopes (v_f − v_0)/L).
        nodes = mesh.nodes
        for i in range(1, n_el):
            frac = float(nodes[i] / mesh.length)
            b.initial_relations.append((f"{name}.rigid_start.value[{i}]",
                                        {p.e[2 * i]: 1.0, v0: -(1.0 - frac), vL: -frac}))
        for k, xk in enumerate(kappa.x):  # undeformed
            b.initial_relations.append((f"{name}.straight_start[{k}]", {xk: 1.0}))
        for i in range(n_el + 1):
            b.initial_relations.append((f"{name}.rigid_start.slope[{i}]",
                                        {p.e[2 * i + 1]: 1.0, vL: -1.0 / mesh.length, v0: 1.0 / mesh.length}))
        if axial:  # unstretched, and no axial velocity relative to the left end
            pa, eps = fields.fields["pa"][0], fields.fields["eps"][0]
            for i in range(1, n_el + 1):
                b.initial_relations.append((f"{name}.rigid_start.axial[{i}]", {pa.e[i]: 1.0, pa.e[0]: -1.0}))
            for k, xk in enumerate(eps.x):
                b.initial_relations.append((f"{name}.unstretched_start[{k}]", {xk: 1.0}))
    # The complete description, from which the rows are derived (phc.library.dirac.emit): the
    # rigid part (storage q with ∂H/∂q = 0, p_t with ∂H/∂p_t = p_t/m) interconnected with
    # the flexible part's structure (co-energies λ, traces v0, vL, slopes) through R⁴,
    # modulated by the chord frame (t, n) and by ω = (vL − v0)/L — the paper's section 5.1.
    # Its relations are written in the order of the rows: the kinematics of both ends, the
    # port flows, the tangential momentum.
    ds = fields.structure.d
    f_q, e_q = zip(*(ds.storage_pair(f"q{k}", x, dx, sp.Integer(0)) for k, (x, dx) in enumerate(q)))
    if not axial:
        f_pt, e_pt = ds.storage_pair("p_t", pt, dpt, pt / mass)
        w_t0 = w_tf = e_pt
    else:
        w_t0, w_tf = fields.d_trace("pa", 0), fields.d_trace("pa", dofA)
    for pname in ("p0", "pf", "m0", "mf"):
        ds.port(ports[pname])
    w0, wL = fields.d_trace("p", dof0), fields.d_trace("p", dofL)
    omega_d = (wL - w0) / (ell if axial else L)
    eq0, eqf = sp.Matrix(e_q[:2]), sp.Matrix(e_q[2:])
    for k in range(2):
        ds.rel(f_q[k] - (w_t0 * tv[k] + w0 * nv[k]), kind="kinematics", label=f"kinematics[{k}]")
    for k in range(2):
        ds.rel(f_q[2 + k] - (w_tf * tv[k] + wL * nv[k]), kind="kinematics", label=f"kinematics[{2 + k}]")
    for k in range(2):
        ds.rel(ports["p0"].f[k] - (w_t0 * tv[k] + w0 * nv[k]), solve=ports["p0"].f[k], label=f"p0.flow[{k}]")
        ds.rel(ports["pf"].f[k] - (w_tf * tv[k] + wL * nv[k]), solve=ports["pf"].f[k], label=f"pf.flow[{k}]")
    if axial:
        if frame:
            _modulate(fields.d_load, fields.d_trace, C, rho.expr, omega_d)
        fields.d_load("pa", 0, tv.dot(eq0 + e0))
        fields.d_load("pa", dofA, tv.dot(eqf + ef))
    else:
        ds.rel(f_pt + tv.dot(eq0 + e0) + tv.dot(eqf + ef) - frame * omega_d * rho.expr * fields.d_pair("p", r),
               kind="dynamics", label="tangential_momentum")
        if frame:
            fields.d_load_vector("p", r, omega_d * e_pt * rho.expr)
    fields.d_load("p", dof0, nv.dot(eq0 + e0))
    fields.d_load("p", dofL, nv.dot(eqf + ef))
    if stiffening:
        G = _stiffening_matrix(space, kappa_space)  # per unit ρ (constant along the beam)
        kappa_x = fields.fields["kappa"][0].x
        Gk = [rho.expr * sum((float(v) * kappa_x[k] for k, v in enumerate(row) if v), sp.Integer(0)) for row in G]
        _stiffen(fields.d_load, fields.d_trace, Gk, dof0, dofL, L, omega_d)
    if axial:
        # The end cross-sections rotate with the chord (ω = (v_f − v_0)/ℓ) plus the elastic
        # slope rate ∂ẇ/∂ξ = ∂e_p/∂ξ − (v_f − v_0)/L: the rate of the velocity field's slope
        # alone, ∂e_p/∂ξ = ωℓ/L + ∂ẇ/∂ξ, would count the chord's rotation (1 + ε_mean) times
        # and a clamp through `m0` would let the beam lag its hub by L·Ω·ε_mean. The flow is
        # ∂e_p/∂ξ − c (v_f − v_0), c = 1/L − 1/ℓ, so the moment enters as its transpose: on the
        # slope and ∓c on the two end values (the port pair's power is exact for any c). ℓ is
        # the invariant L + ∫ε, not |q_f − q_0|: at a midpoint of a rotating step the chord
        # of the averaged ends is shorter by O((ωh)²), which would read as a stretch.
        c = stretch / (L * (L + stretch))
        for pname, slope in (("m0", slope0), ("mf", slopeL)):
            rot = fields.d_trace("p", slope) - c * (wL - w0)
            ds.rel(ports[pname].f[0] - rot, solve=ports[pname].f[0], label=f"{pname}.flow")
            fields.d_load("p", slope, ports[pname].e[0])
            fields.d_load("p", dofL, -c * ports[pname].e[0])
            fields.d_load("p", dof0, c * ports[pname].e[0])
    else:
        ds.rel(ports["m0"].f[0] - fields.d_trace("p", slope0), solve=ports["m0"].f[0], label="m0.flow")
        fields.d_load("p", slope0, ports["m0"].e[0])
        ds.rel(ports["mf"].f[0] - fields.d_trace("p", slopeL), solve=ports["mf"].f[0], label="mf.flow")
        fields.d_load("p", slopeL, ports["mf"].e[0])
    structure = ds.describe(states=(q0x, q0y, qfx, qfy))
    # Certification: flows of the four ports range over (λ_t t + λ_0 n, λ_t t + λ_f n, λ_a, λ_b).
    d = DiracBuilder(name, "moving_beam", span)
    lt, l0, lf, la, lb = (d.mult(x) for x in ("lt", "l0", "lf", "la", "lb"))
    ltf = d.mult("ltf") if axial else lt  # with axial deformation the ends' tangential velocities differ
    for pname in ("p0", "pf", "m0", "mf"):
        d.port(ports[pname])
    for k in range(2):
        d.rel(ports["p0"].f[k] - (lt * tv[k] + l0 * nv[k]))
        d.rel(ports["pf"].f[k] - (ltf * tv[k] + lf * nv[k]))
    d.rel(ports["m0"].f[0] - la)
    d.rel(ports["mf"].f[0] - lb)
    d.register(b, states=(q0x, q0y, qfx, qfy), kind="port_projection",
               note="moving beam: rigid part ⊕ flexible part through R⁴ (the paper's section 5.1)",
               structure=structure)
    emit(b, structure)


def _stiffening_matrix(space, kappa_space) -> np.ndarray:
    """G (H3 DOFs × curvature DOFs), per unit ρ, with ``(Gκ)_j = ∫ n w' φ_j' dξ − ∫ w φ_j dξ``,
    ``n = (L² − ξ²)/2``, where w is the chord-frame deflection of the curvature κ
    (w'' = κ, w(0) = w(L) = 0): −ρω² Gκ is the weak form of ∂(N ∂w/∂ξ) + ρω²w with the
    centrifugal axial force N = ρω² n of a spin about ξ = 0 (unloaded at ξ = L).

    κ is linear on each element, so w' (quadratic) and w (cubic) are exact at the Gauss
    points, and the integrands (degree 6) are integrated exactly by the 5-point rule."""
    mesh = space.mesh
    h, L, n_el = mesh.h, mesh.length, mesh.elements
    s = _GAUSS_S
    nk = kappa_space.size
    # I1_k(ξ) = ∫₀^ξ κ_k, I2_k(ξ) = ∫₀^ξ (ξ − η) κ_k(η) dη for the DP1 basis (DOF 2e: 1 − σ,
    # DOF 2e + 1: σ on element e), at the Gauss points of every element.
    I1 = np.zeros((n_el, len(s), nk))
    I2 = np.zeros((n_el, len(s), nk))
    pts = mesh.quadrature_points()
    for e2 in range(n_el):  # the element of the basis function
        x0 = e2 * h
        for loc, (full1, moment, in1, in2) in enumerate((
                (h / 2, h * (x0 / 2 + h / 6), h * (s - s**2 / 2), h**2 * (s**2 / 2 - s**3 / 6)),
                (h / 2, h * (x0 / 2 + h / 3), h * s**2 / 2, h**2 * s**3 / 6))):
            k = 2 * e2 + loc
            I1[e2, :, k], I2[e2, :, k] = in1, in2
            for e in range(e2 + 1, n_el):  # ∫ over the whole element: I2 = ξ ∫κ_k − ∫ η κ_k
                I1[e, :, k] = full1
                I2[e, :, k] = pts[e] * full1 - moment
    # w'(0) = −∫(L − η) κ dη / L = −I2(L)/L
    I2_end = np.array([h / 2 * L - h * ((k // 2) * h / 2 + h * (1 / 6 if k % 2 == 0 else 1 / 3)) for k in range(nk)])
    slope0 = -I2_end / L
    wp = slope0[None, None, :] + I1
    w = slope0[None, None, :] * pts[:, :, None] + I2
    n = (L**2 - pts**2) / 2
    weights = h * _GAUSS_W
    v0, v1 = space.values(0), space.values(1)  # (4, g)
    local = (np.einsum("eg,egk,ag,g->eak", n, wp, v1, weights)
             - np.einsum("egk,ag,g->eak", w, v0, weights))
    G = np.zeros((space.size, nk))
    for e in range(n_el):
        np.add.at(G, space.dofs()[e], local[e])
    return G


def _stiffen(load, trace, Gk, dof0, dofL, L, omega) -> None:
    """The centrifugal stiffening as a skew modulation: ``ṗ ∋ ω (a sᵀ − s aᵀ) e`` with
    ``s = Gκ`` and ``aᵀe = ω = (e_L − e_0)/L``: the transverse momentum gets −ω² Gκ
    (∂(N w') + ρω²w), the chord's rotation the reaction ω·(Gκ)ᵀe, and the pair supplies no
    power, e·ω(a sᵀ − s aᵀ)e = 0 for every state (rows are residuals: the signs flip)."""
    power = sum((gj * trace("p", j) for j, gj in enumerate(Gk) if gj != 0), sp.Integer(0))
    for j, gj in enumerate(Gk):
        if gj != 0:
            load("p", j, omega * omega * gj)
    load("p", dofL, -omega * power / L)
    load("p", dof0, omega * power / L)


def _modulate(load, trace, C, rho, omega) -> None:
    """The moving-frame modulation with axial deformation, in the rows (``load``/``trace``
    of the fields) or the description (``d_load``/``d_trace``): ``ṗ_a ∋ ω ρ C e_b``,
    ``ṗ_b ∋ −ω ρ Cᵀ e_a`` with ``C_ij = ∫ φ_i^a φ_j^b`` (rows are residuals, so the signs flip)."""
    for i in range(C.shape[0]):
        lo, hi = C.indptr[i], C.indptr[i + 1]
        pair = sum((float(v) * trace("p", int(j)) for j, v in zip(C.indices[lo:hi], C.data[lo:hi])), sp.Integer(0))
        load("pa", i, -omega * rho * pair)
    CT = C.T.tocsr()
    for j in range(CT.shape[0]):
        lo, hi = CT.indptr[j], CT.indptr[j + 1]
        pair = sum((float(v) * trace("pa", int(i)) for i, v in zip(CT.indices[lo:hi], CT.data[lo:hi])), sp.Integer(0))
        load("p", j, omega * rho * pair)


def _lower_rigid_link(b, ctx, name, spec, path):
    """The moving beam with `flexibility` off: a rigid uniform link with the same mass and
    rigid-body inertia (m = ρL, J = mL²/12 about the centre).

    Endpoint coordinates q = (q0, qf) with the kinetic energy of a uniform bar,
    ``T = (m/6)(|v0|² + v0·vf + |vf|²)``, i.e. the constant mass matrix
    ``M = (m/6)[[2I, I], [I, 2I]]`` (the paper's eq. (3) with Z = I), and the chord constraint
    ``|qf − q0|² = L²`` kept at position level (GGL, like every rigid constraint). Ports as
    the flexible beam: `p0`, `pf` (end velocities, positions q0, qf) and `m0`, `mf` (both
    carry the link's angular velocity ω = nᵀ(vf − v0)/L). States keep the flexible beam's
    names (`q0[k]`, `qf[k]`), so scenes switch the effect without renaming anything.
    """
    span = ctx.smap.locate(path)
    scope = {"t": T, **ctx.params}
    n_errors = len(b.diags.errors)
    rho = b.expr(ctx, spec.rhoA, (*path, "rhoA"), scope)
    length = b.expr(ctx, spec.length, (*path, "length"), scope)
    # As with flexibility on (where `t` is refused too): a chord length in t would need the
    # constraint's c_t, a mass in t is not a beam.
    why = "the beam's length and mass are constant (with flexibility on or off)"
    refuse_time(b, ctx, name, rho, (*path, "rhoA"), "`rhoA`", why)
    refuse_time(b, ctx, name, length, (*path, "length"), "the `length`", why)
    if len(b.diags.errors) > n_errors:
        return
    b.leave_out(name, f"elastic deformation ({spec.elements} elements: curvature and transverse momentum)",
                "effect `flexibility` is off: a rigid link with the same mass and inertia")
    for i in range(len(spec.deflection_at)):
        b.unavailable[f"{name}.w[{i}]"] = f"the deflection of `{name}` needs effect `flexibility`, which is off"
    mass = rho * length
    q = [b.add_state(name, f"{pt}[{k}]", span) for pt in ("q0", "qf") for k in range(2)]
    qv = sp.Matrix([s for s, _ in q])
    mom = [b.add_state(name, f"p[{k}]", span) for k in range(4)]
    pv = sp.Matrix([s for s, _ in mom])
    # v = M⁻¹p with M⁻¹ = (2/m)[[2I, −I], [−I, 2I]]
    Minv = (2 / mass) * sp.Matrix([[2, 0, -1, 0], [0, 2, 0, -1], [-1, 0, 2, 0], [0, -1, 0, 2]])
    v = Minv * pv
    chord = sp.Matrix([qv[2] - qv[0], qv[3] - qv[1]])
    c = chord.dot(chord) - length**2
    cq = sp.Matrix([[sp.diff(c, x) for x in qv]])
    nvec = sp.Matrix([-chord[1], chord[0]]) / length
    Bm = sp.Matrix([-nvec[0], -nvec[1], nvec[0], nvec[1]]) / length  # ω = Bmᵀ v
    lam = b.add_algebraic(name, "lambda[0]", "multiplier", span)
    ports = {}
    for pname, pos in (("p0", [qv[0], qv[1]]), ("pf", [qv[2], qv[3]])):
        ports[pname] = b.add_port(name, pname, "mechanical.translational", 2, span=span, position=pos)
    for pname in ("m0", "mf"):
        ports[pname] = b.add_port(name, pname, "mechanical.rotational", 1, span=span)
    Bp0 = sp.Matrix([[1, 0], [0, 1], [0, 0], [0, 0]])
    Bpf = sp.Matrix([[0, 0], [0, 0], [1, 0], [0, 1]])
    omega = (Bm.T * v)[0, 0]
    vel_c = (cq * v)[0, 0]
    b.add_invariant(c, name, "chord_length", span)
    b.add_invariant(vel_c, name, "chord_length.velocity", span, velocity=True)
    b.rigid_constraints.append((name, ctx, path, list(qv), cq, sp.zeros(0, 4), ["chord_length"], []))
    b.hamiltonian.append((pv.T * v)[0, 0] / 2)
    b.extra_outputs[f"{name}.omega"] = omega
    # The complete description, from which the rows are derived (phc.library.dirac.emit):
    # the paper's section 3 kernel representation with Z = I, storage q (∂H/∂q = 0) and p
    # (∂H/∂p = v = M⁻¹p), the chord constraint in velocity form with its multiplier λ.
    ds = DiracBuilder(name, "moving_beam", span)
    f_q, e_q = zip(*(ds.storage_pair(f"q{k}", x, dx, sp.Integer(0)) for k, (x, dx) in enumerate(q)))
    f_p, e_p = zip(*(ds.storage_pair(f"p{k}", pk, dpk, v[k]) for k, (pk, dpk) in enumerate(mom)))
    ds.multipliers.append(lam)
    for pname in ("p0", "pf", "m0", "mf"):
        ds.port(ports[pname])
    vel = sp.Matrix(e_p)
    balance = (sp.Matrix(f_p) + sp.Matrix(e_q) + cq.T * lam + Bp0 * sp.Matrix(ports["p0"].e)
               + Bpf * sp.Matrix(ports["pf"].e) + Bm * (ports["m0"].e[0] + ports["mf"].e[0]))
    for k in range(4):
        ds.rel(f_q[k] - vel[k], kind="kinematics", label=f"kinematics[{k}]")
        ds.rel(balance[k], kind="dynamics", label=f"momentum[{k}]")
    ds.rel((cq * vel)[0, 0], kind="velocity_constraint", label="chord_length.velocity")
    for k in range(2):
        ds.rel(ports["p0"].f[k] - vel[k], solve=ports["p0"].f[k], label=f"p0.flow[{k}]")
        ds.rel(ports["pf"].f[k] - vel[2 + k], solve=ports["pf"].f[k], label=f"pf.flow[{k}]")
    ds.rel(ports["m0"].f[0] - (Bm.T * vel)[0, 0], solve=ports["m0"].f[0], label="m0.flow")
    ds.rel(ports["mf"].f[0] - (Bm.T * vel)[0, 0], solve=ports["mf"].f[0], label="mf.flow")
    structure = ds.describe(states=tuple(qv))
    d = DiracBuilder(name, "moving_beam", span)
    l0x, l0y, lfx, lfy = (d.mult(x) for x in ("l0x", "l0y", "lfx", "lfy"))
    for pname in ("p0", "pf", "m0", "mf"):
        d.port(ports[pname])
    lv = sp.Matrix([l0x, l0y, lfx, lfy])
    d.rel((cq * lv)[0, 0])
    for k, lk in enumerate((l0x, l0y)):
        d.rel(ports["p0"].f[k] - lk)
    for k, lk in enumerate((lfx, lfy)):
        d.rel(ports["pf"].f[k] - lk)
    d.rel(ports["m0"].f[0] - (Bm.T * lv)[0, 0])
    d.rel(ports["mf"].f[0] - (Bm.T * lv)[0, 0])
    d.register(b, states=tuple(qv), kind="port_projection",
               note="moving beam with flexibility off: a rigid link (the paper's section 3, with the chord constraint)",
               structure=structure)
    emit(b, structure)


def lower_crank_wheel(b, ctx, name, spec, path):
    """The paper's eq. (28): θ̇ = e_p, 0 = ṗ_θ + e_τ + r a⊥(θ)ᵀ e_c."""
    span = ctx.smap.locate(path)
    scope = {"t": T, **ctx.params}
    radius = b.expr(ctx, spec.radius, (*path, "radius"), scope)
    inertia = b.expr(ctx, spec.inertia, (*path, "inertia"), scope)
    center = b.vector(ctx, spec.center, (*path, "center"), scope, 2, "`center`")
    # The pin's position q_O + r a(θ) must have the pin flow r a⊥ θ̇ as its rate: a radius or
    # center moving in time would be kept at position level but not in the flows.
    why = "the wheel's geometry is fixed; move the wheel with a `rigid` body and a constraint c(q, t) instead"
    refuse_time(b, ctx, name, radius, (*path, "radius"), "the `radius`", why)
    refuse_time(b, ctx, name, center, (*path, "center"), "the `center`", why)
    theta, dtheta = b.add_state(name, "theta", span)
    ptheta, dptheta = b.add_state(name, "p_theta", span)
    a = sp.Matrix([sp.cos(theta), sp.sin(theta)])
    a_perp = sp.Matrix([-sp.sin(theta), sp.cos(theta)])
    ep = ptheta / inertia
    drive = b.add_port(name, "drive", "mechanical.rotational", 1, span=span, position=[theta])
    pin = b.add_port(name, "pin", "mechanical.translational", 2, span=span,
                     position=[center[0] + radius * a[0], center[1] + radius * a[1]])
    d = DiracBuilder(name, "crank_wheel", span)
    f_th, e_th = d.storage_pair("theta", theta, dtheta, sp.Integer(0))
    f_p, e_p = d.storage_pair("p_theta", ptheta, dptheta, ep)
    d.port(drive)
    d.port(pin)
    d.rel(f_th - e_p, kind="kinematics", label="kinematics")
    d.rel(drive.f[0] - e_p, solve=drive.f[0])
    for k in range(2):
        d.rel(pin.f[k] - radius * a_perp[k] * e_p, solve=pin.f[k])
    d.rel(f_p + e_th + drive.e[0] + radius * a_perp.dot(sp.Matrix(pin.e)), kind="dynamics", label="momentum")
    d.energy(ptheta**2 / (2 * inertia))
    emit(b, d.register(b, states=(theta,), note="the five-dimensional Dirac structure of the slider–crank's "
                       "wheel (the paper's section 5)"))
