"""User-defined port-Hamiltonian components (``type: phs``).

Two ways to give the Dirac structure (T. Berger, R. Hochdahl, T. Reis, R. Seifried,
"Port-Hamiltonian modelling of coupled rigid/flexible multibody systems", section 2.1):

* input-state-output form with J(x) skew, R(x) ⪰ 0 and per-port B(x)::

      ẋ = (J − R)∇H − Σ_{effort_in} B e + Σ_{flow_in} B f,
      f = Bᵀ∇H  (effort_in ports),      e = −Bᵀ∇H  (flow_in ports),

  so that dH/dt = −∇HᵀR∇H − Σ f·e (the paper's remark on the energy balance);
* kernel form: linear relations ``F f + E e + G λ = 0`` among the flows ``f_*`` and
  efforts ``e_*`` of states, ports and resistive ports, with latent multipliers λ, as in
  the paper's kernel representation of a rigid body's Dirac structure (section 3) with
  its ∃μ. Storage flows are ``f_x = ẋ`` and storage
  efforts ``e_x = ∂H/∂x``; resistive ports get their own constitutive laws.
"""

from __future__ import annotations

import numpy as np
import sympy as sp

from phc.ir.dae import T, Parameter
from phc.frontend.effects import is_on, summed_terms, user_effect_scope
from phc.library.dirac import DiracBuilder, emit
from phc.spec.expressions import ExpressionError, parse_equation

CONTROLLED_SOURCE = "controlled source"
"""How the certificate's note on a `phs` with a resistive port of ``kind: source`` begins."""


def _nonlinear_term(expr, variables: set):
    """A term of `expr` that is not linear in `variables` (a product of two of them, a power,
    a function of one), or None."""
    for term in sp.Add.make_args(sp.expand(expr)):
        used = term.free_symbols & variables
        if not used:
            continue
        if len(used) > 1:
            return term
        (v,) = used
        if (sp.diff(term, v).free_symbols & variables):
            return term
    return None


def local_scope(b, ctx, name, spec, path) -> dict:
    """Scope with the model's parameters, `t` and the component's own `parameters`."""
    scope = {"t": T, **ctx.params}
    for ename, flag in user_effect_scope(spec).items():  # declared effects: 0/1 factors
        if ename in scope:
            b.error("PHC-E112", f"effect `{ename}` of `{name}` has the name of a parameter; rename one of them",
                    ctx, (*path, "effects", ename), key=True)
        scope[ename] = flag
    for pname, value in spec.parameters.items():
        ppath = (*path, "parameters", pname)
        if pname in scope and pname in ctx.params:
            b.error("PHC-E108", f"local parameter `{pname}` of `{name}` shadows a model parameter", ctx, ppath,
                    hint="rename it", severity="warning", key=True)
        ex = b.expr(ctx, value, ppath, scope)
        sym = sp.Symbol(f"{name}.{pname}", real=True)
        known = b.default_values()
        try:
            default = float(ex.xreplace(known).evalf())
        except (TypeError, ValueError):
            b.error("PHC-E104", f"local parameter `{pname}` of `{name}` must depend on parameters only", ctx, ppath)
            default = 0.0
        b.parameters[sym.name] = Parameter(sym.name, sym, default, None if ex.is_Number else ex,
                                           span=ctx.smap.locate(ppath))
        scope[pname] = sym
    return scope


def _port_scope(port) -> tuple:
    if port.dimension == 1:
        return port.f[0], port.e[0]
    return list(port.f), list(port.e)


def numeric_defaults(b, expr):
    """Value of a parameter-only expression at the default parameters (t = 0)."""
    return expr.xreplace(b.default_values()).subs(T, 0.0)


def lower_phs(b, ctx, name, spec, path):
    scope = local_scope(b, ctx, name, spec, path)
    span = ctx.smap.locate(path)
    xs, dxs = [], []
    for i, sname in enumerate(spec.states):
        if sname in scope:
            b.error("PHC-E109", f"state `{sname}` of `{name}` clashes with a parameter name", ctx,
                    (*path, "states", i))
        x, dx = b.add_state(name, sname, span)
        xs.append(x)
        dxs.append(dx)
        scope[sname] = x
    n = len(xs)
    H, dropped = summed_terms(b, ctx, spec, "hamiltonian", path, scope)
    for term in dropped:
        b.leave_out(name, f"Hamiltonian term `{term}`", f"effect `{term}` is off")
    grad = _gradient(b, ctx, name, H, xs, (*path, "hamiltonian"))
    if spec.J is not None:
        _lower_jrb(b, ctx, name, spec, path, scope, xs, dxs, grad, span, H)
    else:
        b.hamiltonian.append(H)
        _lower_kernel(b, ctx, name, spec, path, scope, xs, dxs, grad, span)


def _gradient(b, ctx, name, H, xs, hpath) -> sp.Matrix:
    """∇H within the symbolic budget (:mod:`phc.frontend.budget`).

    The gradient enters the residual and the Jacobian differentiates it once more, so the
    size of both derivatives is bounded before sympy computes them. Beyond the budget
    the Hamiltonian is reported (located) and ∇H = 0 stands in for it."""
    from phc.frontend import budget

    if not xs:
        return sp.zeros(0, 1)
    cache = budget.SizeCache()
    try:
        grad = [budget.checked_diff(H, x, "its gradient", cache) for x in xs]
        for g in grad:
            if cache.derivative_work(g) > budget.DIFF_LIMIT:
                work = max(budget.derivative_work(g, x) for x in xs)
                if work > budget.DIFF_LIMIT:
                    raise budget.SymbolicBudgetError(g, work, budget.DIFF_LIMIT,
                                                     "its second derivatives (for the Jacobian)")
    except budget.SymbolicBudgetError as err:
        b.error("PHC-E702", f"the Hamiltonian of `{name}` is too costly to differentiate: {err.what} would take an "
                f"estimated {err.work:,} nodes of symbolic work, above the limit of {err.limit:,}", ctx, hpath,
                hint=budget.symbolic_hint())
        return sp.zeros(len(xs), 1)
    return sp.Matrix(grad)


def _lower_jrb(b, ctx, name, spec, path, scope, xs, dxs, grad, span, H):
    n = len(xs)
    J = b.matrix(ctx, spec.J, (*path, "J"), scope, (n, n), "`J`")
    R = b.matrix(ctx, spec.R, (*path, "R"), scope, (n, n), "`R`") if spec.R is not None else sp.zeros(n, n)
    if spec.R is not None and not is_on(spec, "damping"):
        b.leave_out(name, "dissipation `R`", "effect `damping` is off")
        R = sp.zeros(n, n)
    _check_structure(b, ctx, name, path, J, R, xs)
    d = DiracBuilder(name, "phs", span)
    pairs = [d.storage_pair(x.name.rsplit(".", 1)[-1], x, dx, g) for x, dx, g in zip(xs, dxs, grad)]
    ex_vec = sp.Matrix([e for _, e in pairs]) if n else sp.zeros(0, 1)
    d_rows = sp.Matrix([f for f, _ in pairs]) - J * ex_vec if n else sp.zeros(0, 1)
    if spec.R is not None and n:
        # R as a resistive port: f_R = e_x, e_R = R f_R (dissipating e_xᵀ R e_x ≥ 0).
        resistive = [d.resistor(f"R[{i}]") for i in range(n)]
        f_r = sp.Matrix([f for f, _ in resistive])
        e_r = sp.Matrix([e for _, e in resistive])
        for i in range(n):
            d.rel(f_r[i] - ex_vec[i], solve=f_r[i])
        law = e_r - R * f_r
        for i in range(n):
            d.law(law[i], solve=e_r[i])
        d_rows += e_r
    for pname, pspec in spec.ports.items():
        ppath = (*path, "ports", pname)
        port = b.add_port(name, pname, pspec.domain, pspec.dimension, pspec.frame, span)
        if pspec.B is None:
            b.error("PHC-E110", f"port `{pname}` of `{name}` needs `B` (n_states × dimension) in J/R/B form",
                    ctx, ppath)
            continue
        B = b.matrix(ctx, pspec.B, (*ppath, "B"), scope, (n, pspec.dimension), "`B`")
        d.port(port)
        d_out = B.T * ex_vec
        if pspec.causality == "effort_in":
            d_rows += B * sp.Matrix(port.e)
            for k in range(pspec.dimension):
                d.rel(port.f[k] - d_out[k], solve=port.f[k])
        else:
            d_rows -= B * sp.Matrix(port.f)
            for k in range(pspec.dimension):
                d.rel(port.e[k] + d_out[k], solve=port.e[k])
    for i in range(n):
        d.rel(d_rows[i], kind="dirac", label=f"dynamics[{i}]")
    d.energy(H)
    emit(b, d.register(b, states=xs, note="J/R/B form: R as a resistive port"),
         dissipation_span=ctx.smap.locate((*path, "R")) if spec.R is not None else span)
    if spec.R is None or not n:
        b.dissipation.append((name, sp.Integer(0), span))
    if spec.relations is None and (spec.multipliers or spec.resistive):
        b.error("PHC-E111", f"`multipliers` and `resistive` belong to the kernel form (`relations`) of `{name}`",
                ctx, path)


def _check_structure(b, ctx, name, path, J, R, xs):
    """J skew and R symmetric PSD at a few sampled states (default parameters)."""
    rng = np.random.default_rng(0)
    for _ in range(3):
        point = {x: float(v) for x, v in zip(xs, rng.normal(size=len(xs)))}
        try:
            Jn = np.array(numeric_defaults(b, J.xreplace(point)).evalf(), dtype=float)
            Rn = np.array(numeric_defaults(b, R.xreplace(point)).evalf(), dtype=float)
        except (TypeError, ValueError):
            return
        scale = max(1.0, np.abs(Jn).max(initial=0), np.abs(Rn).max(initial=0))
        if np.abs(Jn + Jn.T).max(initial=0) > 1e-10 * scale:
            b.error("PHC-E402", f"`J` of `{name}` is not skew-symmetric (max |J + Jᵀ| = "
                    f"{np.abs(Jn + Jn.T).max():.3g}); power would not be conserved", ctx, (*path, "J"))
            return
        if np.abs(Rn - Rn.T).max(initial=0) > 1e-10 * scale:
            b.error("PHC-E403", f"`R` of `{name}` is not symmetric", ctx, (*path, "R"))
            return
        if Rn.size and np.linalg.eigvalsh(Rn).min() < -1e-10 * scale:
            b.error("PHC-E404", f"`R` of `{name}` is not positive semidefinite (smallest eigenvalue "
                    f"{np.linalg.eigvalsh(Rn).min():.3g}); it would generate energy", ctx, (*path, "R"))
            return


def _lower_kernel(b, ctx, name, spec, path, scope, xs, dxs, grad, span):
    def bind(key, value, what):
        if key in scope:
            b.error("PHC-E115", f"the name `{key}` ({what}) clashes with another name of `{name}`", ctx, path,
                    hint="`f_x`/`e_x` are generated for every state, port and resistive port `x`; rename one")
        scope[key] = value

    for i, (x, dx) in enumerate(zip(xs, dxs)):
        local = x.name.rsplit(".", 1)[-1]
        bind(f"f_{local}", dx, f"flow of state `{local}`")
        bind(f"e_{local}", grad[i], f"effort of state `{local}`")
    dim_z = len(xs)
    for pname, pspec in spec.ports.items():
        if pspec.B is not None:
            b.error("PHC-E112", f"port `{pname}` of `{name}` has `B`, which only applies to the J/R/B form",
                    ctx, (*path, "ports", pname, "B"))
        port = b.add_port(name, pname, pspec.domain, pspec.dimension, pspec.frame, span)
        fp, ep = _port_scope(port)
        bind(f"f_{pname}", fp, f"flow of port `{pname}`")
        bind(f"e_{pname}", ep, f"effort of port `{pname}`")
        dim_z += pspec.dimension
    diss = sp.Integer(0)
    laws = []
    sources = []  # (port, f·e): controlled sources, whose power is supplied, not dissipated
    for rname, rspec in spec.resistive.items():
        d = rspec.dimension
        fs = [b.add_algebraic(name, f"{rname}.f" + ("" if d == 1 else f"[{k}]"), "resistive", span)
              for k in range(d)]
        es = [b.add_algebraic(name, f"{rname}.e" + ("" if d == 1 else f"[{k}]"), "resistive", span)
              for k in range(d)]
        bind(f"f_{rname}", fs[0] if d == 1 else fs, f"flow of resistive port `{rname}`")
        bind(f"e_{rname}", es[0] if d == 1 else es, f"effort of resistive port `{rname}`")
        power = sum(f * e for f, e in zip(fs, es))
        if rspec.kind == "source":
            sources.append((rname, power))
        else:
            diss += power
        dim_z += d
        laws.append((rname, rspec))
    for mname in spec.multipliers:
        bind(mname, b.add_algebraic(name, mname, "multiplier", span), f"multiplier `{mname}`")
    relations = spec.relations or []
    expected = dim_z + len(spec.multipliers)
    if len(relations) != expected:
        b.error("PHC-E113", f"`{name}` has {len(relations)} Dirac relations, but a Dirac structure on its "
                f"{dim_z} flow/effort pairs with {len(spec.multipliers)} multiplier(s) needs {expected}",
                ctx, (*path, "relations"),
                hint="one relation per state, port component and resistive component, plus one per multiplier")
    d = DiracBuilder(name, "phs", span)
    cert_scope = dict(scope)
    for i, (x, dx) in enumerate(zip(xs, dxs)):
        local = x.name.rsplit(".", 1)[-1]
        cert_scope[f"f_{local}"], cert_scope[f"e_{local}"] = d.storage_pair(local, x, dx, grad[i])
    for pname in spec.ports:
        d.port(b.ports[f"{name}.{pname}"])
    for rname, rspec in laws:
        fr, er = cert_scope[f"f_{rname}"], cert_scope[f"e_{rname}"]
        for fk, ek in zip(fr if isinstance(fr, list) else [fr], er if isinstance(er, list) else [er]):
            d.flows.append(fk)
            d.efforts.append(ek)
    for mname in spec.multipliers:
        d.multipliers.append(scope[mname])
    port_symbols = set(d.flows) | set(d.efforts) | set(d.multipliers)
    for i, rel in enumerate(relations):
        b.expr(ctx, rel, (*path, "relations", i), scope, equation=True)  # reports what is wrong, located
        try:
            rel_ex = parse_equation(rel, cert_scope)
        except ExpressionError:
            continue  # reported above
        product = _nonlinear_term(rel_ex, port_symbols)
        if product is not None:
            product = product.xreplace({v: sp.Symbol(v.name.rsplit(".", 1)[-1])
                                        for v in product.free_symbols & port_symbols})
            b.error("PHC-E118", f"relation `{rel}` of `{name}` is not linear in the flows, efforts and multipliers "
                    f"(`{product}`): a Dirac structure is a linear subspace of them; its coefficients may depend "
                    "on the states (a modulated structure), not on flows or efforts", ctx, (*path, "relations", i),
                    hint="put the nonlinearity into the Hamiltonian or a resistive law, or write the coefficient "
                    "with the state (`x`) instead of its effort (`e_x`)")
            continue
        d.rel(rel_ex, kind="dirac", label=f"relations[{i}]", span=ctx.smap.locate((*path, "relations", i)))
    law_exprs: dict[str, list] = {}
    for rname, rspec in laws:
        law_exprs[rname] = []
        if len(rspec.law) != rspec.dimension:
            b.error("PHC-E114", f"resistive port `{rname}` of `{name}` has dimension {rspec.dimension} but "
                    f"{len(rspec.law)} law equation(s)", ctx, (*path, "resistive", rname, "law"))
        for k, law in enumerate(rspec.law):
            lpath = (*path, "resistive", rname, "law", k)
            ex = b.expr(ctx, law, lpath, scope, equation=True)
            law_exprs[rname].append(ex)
            d.law(ex, kind="resistive", label=f"{rname}.law[{k}]", span=ctx.smap.locate(lpath))
    b.dissipation.append((name, diss, span))
    for rname, power in sources:
        # A controlled source is the environment at this port (like an `effort_source`): the
        # power f·e the model delivers to it is port power, its opposite the energy supplied.
        b.source_power.append(power)
        b.supplied.append((name, rname, power, ctx.smap.locate((*path, "resistive", rname))))
    note = ""
    if sources:
        note = (f"{CONTROLLED_SOURCE} {', '.join(f'`{r}`' for r, _ in sources)} (`kind: source`): its power is "
                "counted as supplied power, not checked for passivity")
    emit(b, d.register(b, states=xs, note=note))
    b.resistive_laws.append((name, [(scope[f"f_{r}"], scope[f"e_{r}"], law_exprs[r]) for r, rspec in laws
                                    if rspec.kind != "source"], ctx, path))
