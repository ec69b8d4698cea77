"""Strings and beams: 1-D pH PDEs (the paper's eq. (7), Example 1) discretized by a
partitioned mixed finite element method that keeps the boundary ports.

The state is split into two groups coupled by the highest-order operator:
"velocity-like" variables (momentum densities, space ``S_A``) whose equations are
integrated by parts N times, and "strain-like" variables (space ``S_B``). For a string
(N = 1) with co-energies ``e_p = p/ρ`` and ``e_ε = Tε``::

    ∫ φ ṗ = −∫ φ' e_ε + [φ e_ε]₀ᴸ,        ∫ ψ ε̇ = ∫ ψ ∂e_p,
    ∫ φ e_p = ∫ φ p/ρ,                    ∫ ψ e_ε = ∫ ψ T ε,

so in matrix form ``M_A ṗ = −Dᵀ e_ε − B_∂ e_∂``, ``M_B ε̇ = D e_p``, ``M_A e_A = M_A^{1/ρ} p``,
``M_B e_B = M_B^{T} ε``. The interconnection matrix ``[[0, −Dᵀ], [D, 0]]`` is skew for any
mesh and the energy ``H = ½ pᵀM_A^{1/ρ}p + ½ εᵀM_B^{T}ε`` obeys
``dH/dt = −f_∂·e_∂ − e_pᵀ M^{d} e_p`` exactly: the discrete power balance holds to
round-off. The boundary efforts (reaction forces and moments, the paper's physical
choice of W_f, W_e) are the inputs and the co-located flows (end velocities and angular
velocities) are the nodal values of the velocity co-energy: no boundary port is lost.

Spaces (``phc.discretize.fem1d``): string and Timoshenko beam use P1 for momenta and P0
for strains (frequency error O(h²)); the Euler–Bernoulli beam (N = 2, integrated by
parts twice) uses C¹ Hermite cubics for the momentum and discontinuous P1 for the
curvature (frequency error O(h⁴)).

All blocks stay sparse (:class:`~phc.ir.dae.LinearTerm`); constant coefficients stay
run-time parameters, coefficients that vary with ``xi`` are evaluated at compile time.

Besides the projection onto its ports (what the Dirac certificate uses), each component
registers its complete description (:class:`Structure`): the same semi-discrete system as
a pH system in kernel form, storage ``f = ẋ``, ``e = ∂H/∂x = Qx = Mλ`` over the co-energy
coefficients λ, ``M f = Jλ − Rλ − B_∂ e_∂`` with J the skew interconnection and R the
damping (as resistive pairs), ``f_∂ = B_∂ᵀλ``. Strings, beams and ``pde1d`` write it
field by field with λ their co-energy variables (:func:`_describe_fields`), and their
rows are derived from it (:func:`phc.library.dirac.emit_sparse`), as are those of their
modal truncations (:func:`phc.library.modal._describe_reduced`) and of the moving beam,
which adds its chord frame to the same description (:mod:`phc.library.moving`).

Effects: `damping`; `modes: k` hands the same fields to :mod:`phc.library.modal`
(structure-preserving modal truncation); the Timoshenko beam's `shear` and
`rotary_inertia` drop a field's energy, which turns its rows into constraints whose
co-energy is the multiplier (both off: the Euler–Bernoulli limit of Example 1 (c)).
"""

from __future__ import annotations

import numpy as np
import scipy.sparse as sps
import sympy as sp

from phc.ir.dae import T, LinearTerm, QuadraticForm
from phc.discretize.fem1d import DP1, H3, P0, P1, Mesh, assemble
from phc.library.dirac import DiracBuilder, emit

XI = sp.Symbol("xi", real=True)


class _Coefficient:
    """A coefficient c(ξ): a run-time parameter expression, or numbers baked at compile time."""

    def __init__(self, b, ctx, value, path):
        scope = {"t": T, "xi": XI, **ctx.params}
        self.expr = b.expr(ctx, value, path, scope)
        self.varies = XI in self.expr.free_symbols
        if T in self.expr.free_symbols:
            b.error("PHC-E140", "coefficients of a distributed component may not depend on `t`", ctx, path)
        self.defaults = b.default_values()
        self.ctx, self.path, self.b = ctx, path, b

    def scale(self) -> sp.Expr:
        return sp.Integer(1) if self.varies else self.expr

    def function(self):
        if not self.varies:
            return None
        # evaluated at the default parameters: those parameters are fixed at compile time
        self.b.compile_time_parameters |= self.expr.free_symbols - {XI}
        numeric = self.expr.xreplace(self.defaults)
        # safe: lambdify prints a sympy tree built by the whitelisting parser, whose only
        # symbol left is `xi` (parameters substituted), never user text.
        fn = sp.lambdify(XI, numeric, modules="numpy")
        return lambda xi: np.broadcast_to(np.asarray(fn(xi), dtype=float), xi.shape)

    def check_positive(self, name, what, mesh, strict: bool = True):
        # Gauss points and the nodes (which include both ends of [0, L]).
        xi = np.concatenate([mesh.quadrature_points().ravel(), mesh.nodes])
        try:
            values = (self.function()(xi) if self.varies
                      else np.full_like(xi, float(self.expr.xreplace(self.defaults))))
        except (TypeError, ValueError):
            return
        if strict and not np.all(values > 0):
            self.b.error("PHC-E141", f"`{what}` of `{name}` must be positive on [0, L] (min {values.min():.3g}); "
                         "the energy density must be positive definite (H ≻ 0 in the paper's eq. (7))", self.ctx, self.path)
        elif not strict and not np.all(values >= 0):
            self.b.error("PHC-E141", f"`{what}` of `{name}` must be non-negative on [0, L] (min {values.min():.3g}); "
                         "a negative damping generates energy (D + Dᵀ ⪰ 0 in the paper's eq. (7))", self.ctx, self.path)


def _mesh(b, ctx, name, spec, path) -> Mesh | None:
    n_errors = len(b.diags.errors)
    ex = b.expr(ctx, spec.length, (*path, "length"), dict(ctx.params))
    if len(b.diags.errors) > n_errors:
        return None  # already reported
    b.compile_time_parameters |= ex.free_symbols  # the mesh is fixed at compile time
    try:
        length = float(ex.xreplace(b.default_values()))
    except TypeError:
        b.error("PHC-E142", f"`length` of `{name}` must be a number or an expression of parameters", ctx,
                (*path, "length"))
        return None
    if not length > 0:
        b.error("PHC-E142", f"`length` of `{name}` must be positive, got {length:g}", ctx, (*path, "length"))
        return None
    return Mesh(length, spec.elements)


class _Field:
    """One state variable of the PDE: its space, state (and rate) and co-energy DOF symbols."""

    def __init__(self, b, name, local, space, span, stored: bool = True):
        self.space = space
        n = space.size
        # a field without energy (an effect off) has no state: its co-energy is a multiplier
        states = [b.add_state(name, f"{local}[{i}]", span) for i in range(n)] if stored else []
        self.x = [x for x, _ in states]
        self.dx = [dx for _, dx in states]
        self.e = [b.add_algebraic(name, f"e_{local}[{i}]", "effort", span) for i in range(n)]


def _embed(A, row: int, col: int, shape) -> sps.csr_matrix:
    """`A` placed at (`row`, `col`) of a zero matrix of `shape`."""
    A = sps.coo_matrix(A)
    return sps.csr_matrix((A.data, (A.row + row, A.col + col)), shape=shape)


class Structure:
    """The complete description of a discretized field, being built (a
    :class:`~phc.library.dirac.DiracBuilder` with sparse blocks): the semi-discrete pH
    system in kernel form over the co-energy coordinates λ (multipliers),

        e_s − Eᵀ λ = 0,     E f_s − J λ + e_R + B_∂ e_∂ = 0,     f_∂ − B_∂ᵀ λ = 0,
        f_R − λ = 0,        e_R − R f_R = 0 (law),

    with storage ``f_s = ẋ``, ``e_s = ∂H/∂x = Qx``, J skew, R + Rᵀ ⪰ 0. The dynamics block
    has one relation per coordinate (a field's or group's coordinates at their `offset`);
    boundary couplings and modulations are added to its relations with :meth:`load`.
    """

    def __init__(self, d, lam: dict, offsets: dict, dynamics):
        # `dynamics`: the number of the dynamics block, or (_describe_fields) of each field's own
        self.d, self.lam, self.offsets, self.dynamics = d, lam, offsets, dynamics

    def load(self, key, i, expr) -> None:
        block = self.dynamics[key] if isinstance(self.dynamics, dict) else self.dynamics
        self.d.add_to(block, self.offsets[key] + i, expr)


def _describe(name, kind, span, keys, sizes, lam_names, storage, J, dissipation):
    """A :class:`Structure` over coordinate groups `keys` (sizes `sizes`, multipliers named
    `lam_names`): `storage` maps a stored group to ``(states, rates, E terms, Q terms)``
    (:class:`~phc.ir.dae.LinearTerm` lists with matrices over the group's coordinates, E
    multiplying the flows and λ, Q the states); `J` is the lossless operator over all
    coordinates (numbers), `dissipation` a list of ``(coeff, matrix over all coordinates)``."""
    d = DiracBuilder(name, kind, span)
    offsets = dict(zip(keys, np.cumsum([0, *sizes[:-1]]).tolist()))
    n = int(sum(sizes))
    lam = {k: d.mults(nm, sz) for k, sz, nm in zip(keys, sizes, lam_names)}
    lam_all = tuple(x for k in keys for x in lam[k])
    dyn_terms = []
    for k, (states, rates, E_terms, Q_terms) in storage.items():
        size = len(states)
        f, e = d.storage_vector(str(k), states, rates, Q_terms)
        d.block(f"{k}.coenergy", size, [LinearTerm(sp.Integer(1), sps.identity(size, format="csr"), e)]
                + [LinearTerm(-c, A.T.tocsr(), lam[k]) for c, A in E_terms])
        dyn_terms += [LinearTerm(c, _embed(A, offsets[k], 0, (n, size)), f) for c, A in E_terms]
    dyn_terms.append(LinearTerm(sp.Integer(-1), sps.csr_matrix(J), lam_all))
    if dissipation:
        fR, eR = d.resistor_vector("R", n)
        eye = sps.identity(n, format="csr")
        d.block("resistive.flow", n, [LinearTerm(sp.Integer(1), eye, fR), LinearTerm(sp.Integer(-1), eye, lam_all)])
        d.block("resistive.law", n, [LinearTerm(sp.Integer(1), eye, eR)]
                + [LinearTerm(-c, sps.csr_matrix(A), fR) for c, A in dissipation], law=True)
        dyn_terms.append(LinearTerm(sp.Integer(1), eye, eR))
    return Structure(d, lam, offsets, d.block("dynamics", n, dyn_terms))


def _describe_fields(name, kind, span, fields, terms, lossy, stored):
    """The complete description of the full discretization written field by field, from
    which its rows are derived (:func:`phc.library.dirac.emit_sparse`): the co-energy
    coordinates λ are the fields' co-energy variables ``e``; each stored field has storage
    ``f_s = ẋ``, ``e_s = ∂H/∂x = Q x`` (`stored`: local -> (states, rates, mass, Q term))
    and the relation ``M λ − e_s = 0``; each field's dynamics ``M f_s − J λ + e_R + B_∂ e_∂
    = 0`` holds the terms of `terms` (the mass term over the rates becomes one over
    ``f_s``), each dissipative one of `lossy` (ids of terms ``c A λ`` with A square, the
    field's own damping) through a resistive pair ``f_R = λ``, ``e_R = c A f_R``."""
    d = DiracBuilder(name, kind, span)
    lam = {local: tuple(fld.e) for local, (fld, _) in fields.items()}
    for local in fields:
        d.multipliers.extend(lam[local])
    storage = {local: d.storage_vector(local, x, dx, [q_term]) for local, (x, dx, _, q_term) in stored.items()}
    dynamics = {}
    for local, (fld, _) in fields.items():
        n = fld.space.size
        eye = sps.identity(n, format="csr")
        dyn = []
        for t in terms[local]:
            if t.derivative:
                dyn.append(LinearTerm(t.coeff, t.matrix, storage[local][0]))
            elif id(t) in lossy:
                k = len(d.resistive)
                f_r, e_r = d.resistor_vector(f"R{k}", n)
                d.block(f"{local}.resistive[{k}].flow", n, [LinearTerm(sp.Integer(1), eye, f_r),
                                                             LinearTerm(sp.Integer(-1), eye, t.symbols)], solve=f_r)
                d.block(f"{local}.resistive[{k}].law", n, [LinearTerm(sp.Integer(1), eye, e_r),
                                                            LinearTerm(-t.coeff, t.matrix, f_r)], law=True, solve=e_r)
                dyn.append(LinearTerm(sp.Integer(1), eye, e_r))
            else:
                dyn.append(t)
        dynamics[local] = d.block(f"{local}.dynamics", n, dyn)
    for local, (x, _, mass, _) in stored.items():
        n = len(x)
        d.block(f"{local}.coenergy", n, [LinearTerm(sp.Integer(1), mass, lam[local]),
                                         LinearTerm(sp.Integer(-1), sps.identity(n, format="csr"), storage[local][1])])
    return Structure(d, lam, {local: 0 for local in fields}, dynamics)


def _lower_partitioned(b, ctx, name, spec, path, mesh, fields_a, fields_b, couplings, skew, ports, order,
                       dissipation=(), kelvin_voigt=False, derive=False):
    """Assemble the partitioned mixed system; returns its :class:`FullFields`.

    fields_a / fields_b: {local: (_Field, coefficient of H)};
    couplings: (a_local, b_local, s) with ``ẋ_b ∋ s ∂^N e_a`` and hence, since
    ``P_Nᵀ = (−1)^{N+1} P_N``, ``ẋ_a ∋ s (−1)^{N+1} ∂^N e_b``; after N integrations by
    parts the residual rows are ``M ẋ_b − s D e_a`` and ``M ẋ_a + s Dᵀ e_b + boundary``
    with ``D_ji = ∫ ψ_j ∂^N φ_i``: the interconnection ``[[0, −sDᵀ], [sD, 0]]`` is skew;
    skew: (row_local, col_local, value) zero-order couplings (entries of P_0);
    dissipation: (row_local, col_local, coefficient) entries of D in ``−D H x`` (eq. (7));
    ports: (port_name, a_local, end, derivative, domain) — the flow is ``∂^derivative e_a``
    at the end; the effort enters the a-rows through the same basis function;
    kelvin_voigt: the `damping` coefficient c acts on the strain rate (``ṗ ∋ −∂^N(c ∂^N e_p)``,
    rows ``+∫ c ∂^Nφ_i ∂^Nφ_j e_j``) instead of on the velocity: rigid motion is not damped.

    derive: the rows are derived from the complete description written field by field
    (:func:`_describe_fields`), once every boundary coupling is added to it
    (:func:`_boundary_ports` emits them for the ports it adds; a caller that adds its own
    ports, ``pde1d`` and the moving beam, emits them itself); otherwise (a ``pde1d`` whose
    damping couples two variables) they are written directly as sparse blocks, and the
    complete description (:func:`_describe`: ``M f_s = J λ − R λ − B_∂ e_∂`` with
    ``e_s = M λ = Qx``) is built from the same matrices, arranged as the pH system, and
    compared with the rows by :mod:`phc.checks.rows`. ``derive`` needs every dissipative
    term to act on the co-energy of the field whose rows it enters (a square block).
    """
    span = ctx.smap.locate(path)
    fields = {**fields_a, **fields_b}
    keys = list(fields)
    sizes = [fields[k][0].space.size for k in keys]
    offsets = dict(zip(keys, np.cumsum([0, *sizes[:-1]]).tolist()))
    n_all = int(sum(sizes))
    lossless = sps.csr_matrix((n_all, n_all))  # J of the description, over all co-energies
    losses = []  # (coefficient, matrix over all co-energies) of the description's R
    mass = {local: assemble(fld.space, 0, fld.space, 0) for local, (fld, _) in fields.items()}
    terms = {local: [LinearTerm(sp.Integer(1), mass[local], tuple(fld.x), derivative=True)] if coeff is not None
             else [] for local, (fld, coeff) in fields.items()}
    for a_local, b_local, sign, *own_order in couplings:  # an optional 4th entry: this coupling's order
        fa, fb = fields_a[a_local][0], fields_b[b_local][0]
        Dm = assemble(fb.space, 0, fa.space, own_order[0] if own_order else order)
        terms[b_local].append(LinearTerm(sp.Integer(-sign), Dm, tuple(fa.e)))
        terms[a_local].append(LinearTerm(sp.Integer(sign), Dm.T.tocsr(), tuple(fb.e)))
        s_num = float(sign)
        lossless = (lossless + _embed(s_num * Dm, offsets[b_local], offsets[a_local], (n_all, n_all))
                    - _embed(s_num * Dm.T, offsets[a_local], offsets[b_local], (n_all, n_all)))
    lossy = set()  # ids of the dissipative terms (resistive pairs of the derived description)
    for row_local, col_local, value in skew:
        fr, fc = fields[row_local][0], fields[col_local][0]
        A = assemble(fr.space, 0, fc.space, 0)
        terms[row_local].append(LinearTerm(sp.Float(-value), A, tuple(fc.e)))
        lossless = lossless + _embed(float(value) * A, offsets[row_local], offsets[col_local], (n_all, n_all))
    if dissipation:
        # rows i get +∫ basis_i D_ij basis_j e_j; the dissipated power is the quadratic form
        # of the symmetric part over all co-energies (D + Dᵀ ⪰ 0 checked by the caller).
        order_e = [local for local in fields]
        offsets_e = np.cumsum([0] + [fields[l][0].space.size for l in order_e])
        blocks = {}
        for row_local, col_local, coeff in dissipation:
            fr, fc = fields[row_local][0], fields[col_local][0]
            Mrc = assemble(fr.space, 0, fc.space, 0, coeff.function())
            terms[row_local].append(LinearTerm(coeff.scale(), Mrc, tuple(fc.e)))
            if row_local != col_local and derive:
                raise ValueError(f"{name}: an off-diagonal dissipation entry cannot be derived as a resistive pair")
            lossy.add(id(terms[row_local][-1]))
            blocks[(row_local, col_local)] = (coeff.scale(), Mrc)
            losses.append((coeff.scale(), _embed(Mrc, offsets[row_local], offsets[col_local], (n_all, n_all))))
        # numeric factors go into the matrix: entries of D that are numbers, or one parameter
        # factor times numbers, share the factor left
        split = {key: sp.sympify(sc).as_coeff_Mul() for key, (sc, _) in blocks.items()}  # safe: sympy scale factors
        scales = {rest for _, rest in split.values()}
        if len(scales) == 1:
            total = sps.lil_matrix((offsets_e[-1], offsets_e[-1]))
            for (rl, cl), (_, Mrc) in blocks.items():
                i0, j0 = offsets_e[order_e.index(rl)], offsets_e[order_e.index(cl)]
                total[i0:i0 + Mrc.shape[0], j0:j0 + Mrc.shape[1]] = float(split[(rl, cl)][0]) * Mrc
            total = total.tocsr()
            b.quadratic_dissipation.append(QuadraticForm(scales.pop(), ((total + total.T) / 2).tocsr(),
                                                         tuple(e for l in order_e for e in fields[l][0].e),
                                                         component=name, span=span))
        else:
            b.error("PHC-E158", f"the entries of `D` of `{name}` must share one parameter factor (or be numbers)",
                    ctx, (*path, "D"))
    if getattr(spec, "damping", None) is not None and not spec.effects.damping:
        b.leave_out(name, "distributed damping", "effect `damping` is off")
    elif getattr(spec, "damping", None) is not None:
        coeff = _Coefficient(b, ctx, spec.damping, (*path, "damping"))
        coeff.check_positive(name, "damping", mesh, strict=False)
        a_local = next(iter(fields_a))
        fld = fields_a[a_local][0]
        k = order if kelvin_voigt else 0
        Md = assemble(fld.space, k, fld.space, k, coeff.function())
        terms[a_local].append(LinearTerm(coeff.scale(), Md, tuple(fld.e)))
        lossy.add(id(terms[a_local][-1]))
        b.quadratic_dissipation.append(QuadraticForm(coeff.scale(), Md, tuple(fld.e), component=name, span=span))
        losses.append((coeff.scale(), _embed(Md, offsets[a_local], offsets[a_local], (n_all, n_all))))
    rows = None if derive else {
        local: b.add_linear_rows(name, f"{local}.dynamics", fields[local][0].space.size, terms[local], span)
        for local in fields}
    # Constitutive rows M e − M^{H} x = 0 and the energy ½ xᵀ M^{H} x.
    storage, stored = {}, {}
    for local, (fld, coeff) in fields.items():
        if coeff is None:
            continue  # no energy: the rows of this field are constraints, e its multiplier
        MH = assemble(fld.space, 0, fld.space, 0, coeff.function())
        if not derive:
            b.add_linear_rows(name, f"{local}.coenergy", fld.space.size,
                              [LinearTerm(sp.Integer(1), mass[local], tuple(fld.e)),
                               LinearTerm(-coeff.scale(), MH, tuple(fld.x))], span)
        b.quadratic_energy.append(QuadraticForm(coeff.scale() / 2, MH, tuple(fld.x)))
        storage[local] = (fld.x, fld.dx, [(sp.Integer(1), mass[local])], [LinearTerm(coeff.scale(), MH, tuple(fld.x))])
        stored[local] = (tuple(fld.x), tuple(fld.dx), mass[local], LinearTerm(coeff.scale(), MH, tuple(fld.x)))
    if derive:
        structure = _describe_fields(name, spec.type, span, fields, terms, lossy, stored)
    else:
        structure = _describe(name, spec.type, span, keys, sizes, [f"lambda_{k}" for k in keys], storage, lossless,
                              losses)
    handle = FullFields(b, rows, fields, structure)
    from phc.ir.initial_fields import register  # what initial fields of ξ project onto (docs/how-to/initial-fields.md)

    register(b, name, spec, mesh, fields)
    described = _boundary_ports(b, name, span, handle, ports, "discretized PDE: skew interconnection by "
                                "construction; ports certified through their traces")
    if derive and described is not None:
        emit(b, described)
    return handle


def _boundary_ports(b, name, span, fields, ports, note):
    """Boundary ports of a field (full or reduced): the flow is a trace of a co-energy, the
    effort enters the rows through the same basis function. Registers the projection of
    the structure onto the ports (the Dirac certificate's view: traces and efforts free)
    with the complete `fields.structure` it projects, and returns that complete
    description (None without ports)."""
    d = DiracBuilder(name, "port_projection", span)
    ds = fields.structure.d
    for pname, a_local, end, derivative, domain in ports:
        port = b.add_port(name, pname, domain, 1, span=span)
        dof = _end_dof(fields.space(a_local), end, derivative)
        if fields.rows is not None:  # rows written directly (otherwise derived from the description)
            b.define(port.f[0], fields.trace(a_local, dof))
        fields.load(a_local, dof, port.e[0])
        d.port(port)  # certification: both the trace and the boundary effort are free
        d.rel(port.f[0] - d.mult(f"trace_{pname}"))
        ds.port(port)
        ds.rel(port.f[0] - fields.d_trace(a_local, dof), solve=port.f[0], label=f"{pname}.flow")
        fields.d_load(a_local, dof, port.e[0])
    if not ports:
        return None
    described = ds.describe()
    d.register(b, kind="port_projection", note=note, structure=described)
    return described


class FullFields:
    """Traces, loads and functionals of the full discretization's fields (the interface
    :class:`phc.library.modal.ReducedFields` shares, so callers such as the moving beam
    work on either). The ``d_*`` methods say the same in the terms of the component's
    complete description (`structure`: co-energy multipliers λ instead of the co-energy
    variables, relations of its dynamics block instead of rows)."""

    def __init__(self, b, rows, fields, structure: Structure):
        # `rows`: the rows of each field, or None when they are derived from `structure` (then
        # load and load_vector leave the rows to the description)
        self.b, self.rows, self.fields, self.structure = b, rows, fields, structure

    def space(self, local):
        return self.fields[local][0].space

    def trace(self, local, dof) -> sp.Expr:
        return self.fields[local][0].e[dof]

    def load(self, local, dof, expr) -> None:
        if self.rows is not None:
            self.b.add_to_row(self.rows[local][dof], expr)

    def load_vector(self, local, r, expr) -> None:
        if self.rows is None:
            return
        for j, rj in enumerate(r):
            if rj:
                self.b.add_to_row(self.rows[local][j], expr * float(rj))

    def pair(self, local, r) -> sp.Expr:
        return sum((float(rj) * ej for rj, ej in zip(r, self.fields[local][0].e) if rj), sp.Integer(0))

    def state_functional(self, local, g) -> sp.Expr:
        return sum((float(gk) * xk for gk, xk in zip(g, self.fields[local][0].x) if gk), sp.Integer(0))

    def d_trace(self, local, dof) -> sp.Expr:
        return self.structure.lam[local][dof]

    def d_load(self, local, dof, expr) -> None:
        self.structure.load(local, dof, expr)

    def d_load_vector(self, local, r, expr) -> None:
        for j, rj in enumerate(r):
            if rj:
                self.structure.load(local, j, expr * float(rj))

    def d_pair(self, local, r) -> sp.Expr:
        return sum((float(rj) * lj for rj, lj in zip(r, self.structure.lam[local]) if rj), sp.Integer(0))


def modes_of(spec):
    """The `modes` effect of a component (None: keep all)."""
    return getattr(getattr(spec, "effects", None), "modes", None)


def _lower_fields(b, ctx, name, spec, path, mesh, span, spaces_a, spaces_b, couplings, skew, ports, order,
                  boundary=None, kelvin_voigt=False, derive=False):
    """Full or modally truncated (effect `modes`) lowering of fields ``{local: (space, coefficient)}``;
    returns a :class:`FullFields` or :class:`~phc.library.modal.ReducedFields`. `derive`:
    the rows are derived from the description (see :func:`_lower_partitioned`)."""
    k = modes_of(spec)
    if k is not None and any(c is None for _, c in (*spaces_a.values(), *spaces_b.values())):
        b.error("PHC-E144", f"effect `modes` of `{name}` needs every field to store energy; turn `shear` and "
                "`rotary_inertia` on, or drop `modes`", ctx, path)
        return None
    if k is not None:
        from phc.ir.initial_fields import register
        from phc.library.modal import lower_modal

        register(b, name, spec, mesh, None)  # modal coordinates: initial fields are refused, per dof stays
        return lower_modal(b, ctx, name, spec, path, mesh, spaces_a, spaces_b, couplings, skew, ports, order, k,
                           boundary=boundary, kelvin_voigt=kelvin_voigt, derive=derive)
    fields_a = {l: (_Field(b, name, l, s, span, c is not None), c) for l, (s, c) in spaces_a.items()}
    fields_b = {l: (_Field(b, name, l, s, span, c is not None), c) for l, (s, c) in spaces_b.items()}
    return _lower_partitioned(b, ctx, name, spec, path, mesh, fields_a, fields_b, couplings, skew, ports, order,
                              kelvin_voigt=kelvin_voigt, derive=derive)


def _end_dof(space, end: str, derivative: int) -> int:
    n = space.mesh.elements
    if isinstance(space, H3):
        node = 0 if end == "a" else n
        return 2 * node + derivative
    if derivative:
        raise ValueError("slope DOFs need Hermite elements")
    return 0 if end == "a" else space.size - 1


def prepare(b, ctx, name, spec, path, fields: tuple[str, ...]):
    """Mesh, source span and the checked positive coefficients ``fields`` of a component."""
    mesh = _mesh(b, ctx, name, spec, path)
    if mesh is None:
        return None
    n_errors = len(b.diags.errors)
    coeffs = {k: _Coefficient(b, ctx, getattr(spec, k), (*path, k)) for k in fields}
    if len(b.diags.errors) > n_errors or any(c.expr.free_symbols & b.unset_parameters for c in coeffs.values()):
        b.failed.add(name)  # its ports are missing: connections to them are not reported again
        return None  # reported (here, or in a parameter a coefficient uses): no values to discretize with
    for k, c in coeffs.items():
        c.check_positive(name, k, mesh)
    if len(b.diags.errors) > n_errors:
        return None  # a coefficient that is not positive would make the discretization singular
    return mesh, ctx.smap.locate(path), coeffs


TRANSLATIONAL, ROTATIONAL = "mechanical.translational", "mechanical.rotational"


def lower_string(b, ctx, name, spec, path):
    prep = prepare(b, ctx, name, spec, path, ("rho", "T"))
    if prep is None:
        return
    mesh, span, c = prep
    _lower_fields(b, ctx, name, spec, path, mesh, span, {"p": (P1(mesh), _inverse(c["rho"]))},
                  {"eps": (P0(mesh), c["T"])}, [("p", "eps", 1)], [],
                  [("a", "p", "a", 0, TRANSLATIONAL), ("b", "p", "b", 0, TRANSLATIONAL)], order=1, derive=True)


def lower_timoshenko(b, ctx, name, spec, path):
    prep = prepare(b, ctx, name, spec, path, ("rho", "I_rho", "EI", "K"))
    if prep is None:
        return
    mesh, span, c = prep
    # Effects (the paper's Example 1 (c): both off → Euler–Bernoulli). `rotary_inertia`
    # off: the energy ½∫M²/I_ρ is dropped, so the M rows become the algebraic moment balance
    # 0 = ∂(EIθ) + Kγ (eq. (17) without I_ρ φ̈) and e_M = φ̇ is a multiplier. `shear`
    # off (K → ∞): the energy ½∫Kγ² is dropped, the γ rows become the constraint
    # γ̇ = ∂e_p − e_M = 0 (tested with P0: ∂w − φ = 0 per element) and e_γ = Kγ, the shear
    # force, is its Lagrange multiplier.
    inertia = _inverse(c["I_rho"]) if spec.effects.rotary_inertia else None
    shear = c["K"] if spec.effects.shear else None
    if inertia is None:
        b.leave_out(name, "rotary inertia (the energy ½∫M²/I_ρ; M rows become the moment balance)",
                    "effect `rotary_inertia` is off")
    if shear is None:
        b.leave_out(name, "shear deformation (the energy ½∫Kγ²; γ̇ = ∂e_p − e_M = 0 is a constraint)",
                    "effect `shear` is off")
    _lower_fields(
        b, ctx, name, spec, path, mesh, span,
        {"p": (P1(mesh), _inverse(c["rho"])), "M": (P1(mesh), inertia)},
        {"gamma": (P0(mesh), shear), "theta": (P0(mesh), c["EI"])},
        [("p", "gamma", 1), ("M", "theta", 1)],
        [("M", "gamma", 1.0), ("gamma", "M", -1.0)],  # P0 of Example 1 (b)
        [("a", "p", "a", 0, TRANSLATIONAL), ("b", "p", "b", 0, TRANSLATIONAL),
         ("a_rot", "M", "a", 0, ROTATIONAL), ("b_rot", "M", "b", 0, ROTATIONAL)],
        order=1, derive=True)


def lower_euler_bernoulli(b, ctx, name, spec, path):
    prep = prepare(b, ctx, name, spec, path, ("rhoA", "EI"))
    if prep is None:
        return
    mesh, span, c = prep
    # P_2 = [[0, 1], [-1, 0]] on (κ, p): ṗ = −∂²e_κ, κ̇ = ∂²e_p.
    _lower_fields(
        b, ctx, name, spec, path, mesh, span, {"p": (H3(mesh), _inverse(c["rhoA"]))},
        {"kappa": (DP1(mesh), c["EI"])}, [("p", "kappa", 1)], [],
        [("a", "p", "a", 0, TRANSLATIONAL), ("b", "p", "b", 0, TRANSLATIONAL),
         ("a_rot", "p", "a", 1, ROTATIONAL), ("b_rot", "p", "b", 1, ROTATIONAL)],
        order=2, derive=True)


def _inverse(coeff):
    """The coefficient 1/c (for momentum densities: e_p = p/ρ)."""
    inv = _Coefficient.__new__(_Coefficient)
    inv.__dict__.update(coeff.__dict__)
    inv.expr = 1 / coeff.expr
    return inv
