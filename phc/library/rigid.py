"""Rigid multibody components (``type: rigid``), the paper's Section 3, eq. (3).

State ``x_r = (q, p)`` with ``p = M(q) v`` and ``H = ½ pᵀv + V(q)``. The rows, derived from the
body's description (the paper's kernel representation, :func:`_describe`), are::

    q̇ − Z(q) v                                                    = 0   (kinematics)
    ṗ + Zᵀ(∇V + c_qᵀλ − ½ vᵀ∂M/∂q v) + F_d + G(p) v + Aᵀμ + Σ B_i e_i = 0   (momentum)
    c_q(q, t) Z(q) v + c_t(q, t) = 0,   A(q, t) v = 0                       (velocity level)
    f_i = B_i(q)ᵀ v                                                     (port flows)

and the position constraints ``c(q, t) = 0`` are registered as invariants; assembly keeps
them by Gear–Gupta–Leimkuhler stabilization (the kinematics row becomes
``q̇ − Zv + c_qᵀη = 0``), which gives an index-2 system whose position constraints do
not drift. The term ``−½ vᵀ∂M/∂q v`` is ``∂H/∂q`` at fixed p for configuration-dependent
mass matrices (joint-coordinate models); it vanishes for the paper's constant M.

Time (docs/constraints.md): a constraint c(q, t) that moves with time (rheonomic) has the
velocity form ``c_q Z v + c_t = 0``; it does work on the body, ``dH/dt = λᵀc_t`` from its
rows, which is booked as a port power ``−λᵀc_t`` (the model delivers it to whatever moves
the constraint), so the energy balance ``H(t) − H(0) + E(t)`` closes. ``A(q, t) v = 0``
stays homogeneous (an ideal constraint does no work: ``vᵀAᵀμ = 0`` for every t). ``M``,
``V``, ``Z``, ``B``, ``damping`` and ``G`` may depend on t; an explicit time dependence of
H (``M(t)``, ``V(q, t)``) is accounted for by assembly (``−∂H/∂t`` in the balance). Port
positions r(q) may not depend on t, and every field is checked for the variables it may
depend on (a velocity in ``V`` would drop ``∂V/∂p``): anything else is a located error
(PHC-E126).
"""

from __future__ import annotations

import numpy as np
import sympy as sp

from phc.ir.dae import T
from phc.frontend.effects import is_on, summed_terms
from phc.library.dirac import DiracBuilder, emit
from phc.library.phs import local_scope, numeric_defaults
from phc.library.timing import sample_times


def lower_rigid(b, ctx, name, spec, path):
    n_errors = len(b.diags.errors)  # this component's own errors stop it, not another's
    scope = local_scope(b, ctx, name, spec, path)
    span = ctx.smap.locate(path)
    nq = len(spec.q)
    vnames = spec.v if spec.v is not None else [f"v_{q}" for q in spec.q]
    nv = len(vnames)
    if spec.Z is None and nv != nq:
        b.error("PHC-E120", f"`{name}` has {nq} configuration variables and {nv} velocities; give `Z` "
                f"({nq} × {nv}) with q̇ = Z v", ctx, (*path, "v"))
        return
    q, dq = [], []
    for i, qn in enumerate(spec.q):
        s, ds = b.add_state(name, qn, span)
        q.append(s)
        dq.append(ds)
        scope[qn] = s
    p, dp = [], []
    for vn in vnames:
        s, ds = b.add_state(name, f"p_{vn}", span)
        p.append(s)
        dp.append(ds)
        scope[f"p_{vn}"] = s
    v = [b.add_algebraic(name, vn, "velocity", span) for vn in vnames]
    for vn, s in zip(vnames, v):
        scope[vn] = s
    qv, pv, vv = sp.Matrix(q), sp.Matrix(p), sp.Matrix(v)

    M = b.matrix(ctx, spec.M, (*path, "M"), scope, (nv, nv), "`M`")
    Z = (b.matrix(ctx, spec.Z, (*path, "Z"), scope, (nq, nv), "`Z`") if spec.Z is not None
         else sp.eye(nq))
    V, dropped = summed_terms(b, ctx, spec, "V", path, scope)
    for term in dropped:
        b.leave_out(name, f"potential term `{term}`", f"effect `{term}` is off")
    c = sp.Matrix([b.expr(ctx, ci, (*path, "constraints", i), scope) for i, ci in enumerate(spec.constraints)])
    A = (b.matrix(ctx, spec.velocity_constraints, (*path, "velocity_constraints"), scope, (None, nv),
                  "`velocity_constraints`") if spec.velocity_constraints else sp.zeros(0, nv))
    Fd = (sp.Matrix(b.vector(ctx, spec.damping, (*path, "damping"), scope, nv, "`damping`"))
          if spec.damping is not None else sp.zeros(nv, 1))
    if spec.damping is not None and not is_on(spec, "damping"):
        b.leave_out(name, "damping force", "effect `damping` is off")
        Fd = sp.zeros(nv, 1)
    G = (b.matrix(ctx, spec.G, (*path, "G"), scope, (nv, nv), "`G`") if spec.G is not None
         else sp.zeros(nv, nv))
    if len(b.diags.errors) > n_errors:
        return
    _check_dependencies(b, ctx, name, spec, path, q, p, v, M, Z, V, c, A, Fd, G)
    if len(b.diags.errors) > n_errors:
        return
    times = sample_times(ctx, 3)
    _check_mass_matrix(b, ctx, name, path, M, q, times)

    # Velocities: explicit for constant M (the law M v = p solved, v = M⁻¹p), implicit rows
    # M(q, t) v = p otherwise.
    m_depends_on_q = bool(M.free_symbols & set(q))
    Minv = M.inv() if not m_depends_on_q and nv <= 6 else None

    lam = [b.add_algebraic(name, f"lambda[{i}]", "multiplier", span) for i in range(len(c))]
    mu = [b.add_algebraic(name, f"mu[{i}]", "multiplier", span) for i in range(A.rows)]
    gradV = sp.Matrix([sp.diff(V, qi) for qi in q])
    cq = c.jacobian(qv) if len(c) else sp.zeros(0, nq)
    ct = c.diff(T) if len(c) else sp.zeros(0, 1)  # a moving (rheonomic) constraint: c_q Z v + c_t = 0
    _check_redundant_constraints(b, ctx, name, path, cq * Z, A, q, times)
    if len(b.diags.errors) > n_errors:
        return
    # ∂H/∂q at fixed p: ∇V − ½ vᵀ∂M/∂q v (the second term for configuration-dependent M)
    grad_q = gradV - (sp.Matrix([(vv.T * sp.diff(M, qi) * vv)[0, 0] / 2 for qi in q]) if m_depends_on_q
                      else sp.zeros(nq, 1))

    ports, Bs = [], []
    for pname, pspec in spec.ports.items():
        ppath = (*path, "ports", pname)
        B = b.matrix(ctx, pspec.B, (*ppath, "B"), scope, (nv, pspec.dimension), "`B`")
        _refuse(b, ctx, name, B, (*ppath, "B"), "the port map `B`", set(q) | {T}, q, p, v)
        position = None
        if pspec.position is not None:
            position = b.vector(ctx, pspec.position, (*ppath, "position"), scope, pspec.dimension, "`position`")
            _refuse(b, ctx, name, sp.Matrix(position), (*ppath, "position"), "a port `position`", set(q), q, p, v,
                    hint="a port position r(q) moves with the body only (d/dt r = Bᵀv); prescribe a motion in "
                    "time with a constraint c(q, t) = 0 or a `flow_source` with `position`")
        ports.append(b.add_port(name, pname, pspec.domain, pspec.dimension, pspec.frame, span, position))
        Bs.append(B)
        if position is not None and len(b.diags.errors) == n_errors:
            _check_port_position(b, ctx, name, pname, ppath, sp.Matrix(position), qv, Z, B, times)

    spans = {"constraints": [ctx.smap.locate((*path, "constraints", i)) for i in range(len(c))],
             "velocity_constraints": [ctx.smap.locate((*path, "velocity_constraints", i)) for i in range(A.rows)]}
    # The rows are derived from the description (phc.library.dirac.emit).
    emit(b, _describe(b, name, span, q, dq, p, dp, v, grad_q, M, Minv, Fd, Z, cq, ct, A, G, lam, mu, ports, Bs,
                      (pv.T * vv)[0, 0] / 2 + V, spans),
         dissipation_span=ctx.smap.locate((*path, "damping")) if spec.damping is not None else span)
    if not nv:
        b.dissipation.append((name, sp.Integer(0), span))
    b.rigid_constraints.append((name, ctx, path, q, cq, A, [f"constraints[{i}]" for i in range(len(c))],
                                [f"velocity_constraints[{i}]" for i in range(A.rows)]))
    vel_c = cq * Z * vv + ct if len(c) else sp.zeros(0, 1)
    if len(c) and any(x != 0 for x in ct):
        # The moving constraint's power on the body is λᵀc_t (dH/dt from the rows above);
        # the model delivers −λᵀc_t to whatever drives it (the paper's energy balance with
        # the constraint as a port, see the module docstring).
        b.source_power.append(-sum((lam[i] * ct[i] for i in range(len(c))), sp.Integer(0)))
    for i in range(len(c)):
        cspan = spans["constraints"][i]
        b.add_invariant(c[i], name, f"constraints[{i}]", cspan)
        b.add_invariant(vel_c[i], name, f"constraints[{i}].velocity", cspan, velocity=True)
    av = A * vv if A.rows else sp.zeros(0, 1)
    for i in range(A.rows):
        b.add_invariant(av[i], name, f"velocity_constraints[{i}]", spans["velocity_constraints"][i], velocity=True)
    if T in M.free_symbols and Minv is None:
        # H = ½pᵀv + V with v an unknown of the rows M(q, t) v = p: assembly's −∂H/∂t of that
        # expression sees V_t only; the kinetic part's ∂/∂t at fixed (q, p) is −½vᵀM_t v.
        b.source_power.append((vv.T * M.diff(T) * vv)[0, 0] / 2)


def _describe(b, name, span, q, dq, p, dp, v, grad_q, M, Minv, Fd, Z, cq, ct, A, G, lam, mu, ports, Bs, H, spans):
    """The description of a rigid body, the paper's kernel representation of its Dirac
    structure (section 3), from which its rows are derived: flows (q̇, ṗ, v_R, port flows),
    efforts (∂H/∂q, v, F_R, port efforts), the multipliers λ of the position constraints
    (in velocity form, c_q Z v + c_t = 0; the affine part c_t is the prescribed motion of a
    rheonomic constraint) and μ of the velocity constraints A(q, t) v = 0. Storage is bound
    to the states (``e_p = v`` with the law ``M(q) v = p``, solved for v when M is constant),
    the resistive pair to the damping law ``F_R = F_d(q, v_R)``. The relations are written in
    the order of the rows: the momentum definitions (or v = M⁻¹p), the port flows
    f = Bᵀv, the kinematics q̇ = Z v, the momentum balance, the velocity constraints."""
    d = DiracBuilder(name, "rigid", span)
    nq, nv = len(q), len(p)
    v_lf, F_le = [], []
    for i in range(nq):
        f, e = d.storage_pair(f"q{i}", q[i], dq[i], grad_q[i])
        v_lf.append(f)
        F_le.append(e)
    F_lf, v_le = [], []
    for i in range(nv):
        f, e = d.storage_pair(f"p{i}", p[i], dp[i], v[i])
        F_lf.append(f)
        v_le.append(e)
    v_r, F_r = zip(*(d.resistor(f"R{i}") for i in range(nv))) if nv else ((), ())
    for port in ports:
        d.port(port)
    d.multipliers.extend((*lam, *mu))
    vle = sp.Matrix(v_le)
    if Minv is not None:
        vdef = Minv * sp.Matrix(p)
        for k in range(nv):
            d.law(v[k] - sp.simplify(vdef[k]), solve=v[k], kind="constitutive")
    else:
        for k, row in enumerate(M * sp.Matrix(v) - sp.Matrix(p)):
            d.law(row, kind="storage", label=f"momentum_definition[{k}]")
    for port, B in zip(ports, Bs):
        for k, row in enumerate(sp.Matrix(port.f) - B.T * vle):
            d.rel(row, solve=port.f[k])
    for i, row in enumerate(sp.Matrix(v_lf) - Z * vle):
        d.rel(row, kind="kinematics", label=f"kinematics[{i}]")
    for i in range(nv):
        d.rel(v_r[i] - v_le[i], solve=v_r[i])
    damping = Fd.xreplace(dict(zip(v, v_r)))
    for i in range(nv):
        d.law(F_r[i] - damping[i], solve=F_r[i])
    e_q = sp.Matrix(F_le) + (cq.T * sp.Matrix(lam) if len(lam) else sp.zeros(nq, 1))
    force = Z.T * e_q + sp.Matrix(F_r) + G * vle + (A.T * sp.Matrix(mu) if A.rows else sp.zeros(nv, 1))
    for port in ports:
        force += Bs[ports.index(port)] * sp.Matrix(port.e)
    for i, row in enumerate(sp.Matrix(F_lf) + force):
        d.rel(row, kind="dynamics", label=f"momentum[{i}]")
    for i, row in enumerate(cq * Z * vle + ct if len(lam) else []):
        d.rel(row, kind="velocity_constraint", label=f"constraints[{i}].velocity", span=spans["constraints"][i])
    for i, row in enumerate(A * vle if A.rows else []):
        d.rel(row, kind="velocity_constraint", label=f"velocity_constraints[{i}]",
              span=spans["velocity_constraints"][i])
    d.energy(H)
    return d.register(b, states=tuple(q) + tuple(p))


def _sample_points(q, n=3, times=(0.0,)):
    rng = np.random.default_rng(1)
    out = []
    for k in range(max(n, len(times))):
        point = {qi: float(x) for qi, x in zip(q, rng.uniform(-1.0, 1.0, len(q)))}
        point[T] = float(times[k % len(times)])
        out.append(point)
    return out


_ALLOWED = {
    # field: (the variables it may depend on besides parameters, its name in messages, its form)
    "M": ("qt", "the mass matrix `M`", "M(q, t)"),
    "Z": ("qt", "the kinematics matrix `Z`", "Z(q, t)"),
    "V": ("qt", "the potential `V`", "V(q, t)"),
    "constraints": ("qt", "a position constraint", "c(q, t)"),
    "velocity_constraints": ("qt", "the velocity constraint matrix `velocity_constraints`", "A(q, t)"),
    "damping": ("qpvt", "the damping force `damping`", "F_d(q, v, t)"),
    "G": ("qpvt", "the gyroscopic matrix `G`", "G(q, p, t)"),
}


def _refuse(b, ctx, name, expr, path, what, allowed, q, p, v, hint=None) -> bool:
    """A located error (PHC-E126) when `expr` depends on a variable outside `allowed`
    (this component's q, p, v, or t); True when it was refused."""
    syms = getattr(expr, "free_symbols", set())
    labels = {**{s: f"the velocity `{s.name.rsplit('.', 1)[-1]}`" for s in v},
              **{s: f"the momentum `{s.name.rsplit('.', 1)[-1]}`" for s in p},
              **{s: f"the configuration variable `{s.name.rsplit('.', 1)[-1]}`" for s in q},
              T: "the time `t`"}
    bad = sorted((s for s in syms if s in labels and s not in allowed), key=str)
    if not bad:
        return False
    b.error("PHC-E126", f"{what} of `{name}` depends on {labels[bad[0]]}, which it may not: it would be "
            "dropped from the equations, not handled", ctx, path,
            hint=hint or "see docs/constraints.md for what each field of a `rigid` component may depend on")
    return True


def _check_dependencies(b, ctx, name, spec, path, q, p, v, M, Z, V, c, A, Fd, G) -> None:
    """Every field depends only on what it may (docs/constraints.md): a term that would be
    silently dropped is refused instead."""
    sets = {"q": set(q), "p": set(p), "v": set(v), "t": {T}}
    fields = {"M": M, "Z": Z, "V": V, "velocity_constraints": A, "damping": Fd, "G": G}
    for key, expr in fields.items():
        letters, what, form = _ALLOWED[key]
        allowed = set().union(*(sets[x] for x in letters))
        _refuse(b, ctx, name, expr, (*path, key), what, allowed, q, p, v,
                hint=f"{form}: write it in those variables" + (
                    " (a potential of the momenta is not a potential: put kinetic energy in `M`)"
                    if key == "V" else ""))
    for i, ci in enumerate(c):
        _refuse(b, ctx, name, ci, (*path, "constraints", i), _ALLOWED["constraints"][1], set(q) | {T}, q, p, v,
                hint="a position constraint c(q, t) = 0 may not use velocities or momenta; velocity-level "
                "constraints A(q, t) v = 0 go under `velocity_constraints` (as rows of A)")


def _check_mass_matrix(b, ctx, name, path, M, q, times=(0.0,)):
    for point in _sample_points(q, times=times):
        try:
            Mn = np.array(numeric_defaults(b, M.xreplace(point)).evalf(), dtype=float)
        except (TypeError, ValueError):
            return
        if np.abs(Mn - Mn.T).max(initial=0) > 1e-12 * max(1.0, np.abs(Mn).max(initial=0)):
            b.error("PHC-E121", f"mass matrix `M` of `{name}` is not symmetric", ctx, (*path, "M"))
            return
        if Mn.size and np.linalg.eigvalsh(Mn).min() <= 0:
            b.error("PHC-E122", f"mass matrix `M` of `{name}` is not positive definite at the default "
                    f"parameters (smallest eigenvalue {np.linalg.eigvalsh(Mn).min():.3g})", ctx, (*path, "M"))
            return


# A constraint row whose distance from the span of the rows before is below the certificate's
# rank threshold (phc.checks.certify.RANK_RTOL) times the largest singular value, at every
# sampled configuration, is redundant (round-off of rows of size one: 1e-16; a
# configuration-dependent rank drop is seen at no more than a measure-zero set of
# configurations, not at three random ones).


def _check_redundant_constraints(b, ctx, name, path, cqZ, A, q, times=(0.0,)):
    """Refuse constraints whose velocity rows [c_q Z; A] are dependent at every configuration
    (a constraint written twice, or one implied by the others): their multipliers are not
    unique anywhere and no solver can integrate the model. A rank drop at particular
    configurations only (a mechanism's singular position) is left to the solvers and to
    `phc check` (PHC-E410 at the initial configuration, PHC-W422 along the motion)."""
    from phc.checks.certify import RANK_RTOL  # here: the certificate's modules load scipy's linear algebra
    rows = cqZ.col_join(A) if A.rows else cqZ
    if rows.rows < 2:
        return
    always = None
    for point in _sample_points(q, times=times):
        try:
            R = np.array(numeric_defaults(b, rows.xreplace(point)).evalf(), dtype=float)
        except (TypeError, ValueError):
            return
        if not np.all(np.isfinite(R)):
            return
        top = np.linalg.norm(R, 2)
        if top == 0.0:
            return
        dependent, kept = set(), []
        for i in range(R.shape[0]):
            trial = R[kept + [i]]
            s = np.linalg.svd(trial, compute_uv=False)
            if len(s) < len(kept) + 1 or s[-1] <= RANK_RTOL * top:
                dependent.add(i)
            else:
                kept.append(i)
        always = dependent if always is None else always & dependent
        if not always:
            return
    first = min(always)
    if first < cqZ.rows:
        key, label, index = "constraints", "position constraint", first
    else:
        key, label, index = "velocity_constraints", "velocity constraint", first - cqZ.rows
    b.error("PHC-E410", f"{label} `{key}[{index}]` of `{name}` is redundant at every configuration: its velocity "
            "row (c_q·Z for a position constraint) depends on the rows before it at random configurations, so "
            "its multiplier is never unique and no solver can integrate the model",
            ctx, (*path, key, index),
            hint="remove it (a constraint written twice, or one the others imply)")


def _check_port_position(b, ctx, name, pname, ppath, r, qv, Z, B, times=(0.0,)):
    """d/dt r(q) must equal the port flow Bᵀv, i.e. ∂r/∂q · Z = Bᵀ, at sampled (q, t)."""
    D = r.jacobian(qv) * Z - B.T
    for point in _sample_points(list(qv), times=times):
        try:
            Dn = np.array(numeric_defaults(b, D.xreplace(point)).evalf(), dtype=float)
        except (TypeError, ValueError):
            return
        if np.abs(Dn).max(initial=0) > 1e-9:
            b.error("PHC-E123", f"`position` of port `{pname}` of `{name}` does not match its velocity map: "
                    f"∂r/∂q·Z − Bᵀ ≠ 0 (max {np.abs(Dn).max():.3g}); its time derivative must be the port flow "
                    "Bᵀv", ctx, (*ppath, "position"))
            return
