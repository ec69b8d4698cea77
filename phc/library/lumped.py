"""Library one-ports, sources, terminations, junctions and the orthogonal transform.

Every element is written in the generator sign convention of T. Berger, R. Hochdahl,
T. Reis, R. Seifried, "Port-Hamiltonian modelling of coupled rigid/flexible multibody
systems" (section 2):
``f·e`` is the power the element delivers through its port, and efforts are reaction
quantities (``e = −F_acting``). A one-port with several ports sits on an implicit
1-junction: all its ports share the element's flow and their efforts add up.

Storage elements (the paper's definition of a port-Hamiltonian system, ``e_L = ∇H``):

=========  =================  ===========================  =====================
element    state x            H(x)                         port relation
=========  =================  ===========================  =====================
mass       momentum p         |p|²/2m                      f = p/m, ṗ = −Σe
inductor   flux φ             φ²/2L                        f = φ/L, φ̇ = −Σe
spring     elongation x       k|x|²/2                      ẋ = f, Σe = −kx
capacitor  charge q           q²/2C                        q̇ = f, Σe = −q/C
=========  =================  ===========================  =====================

Resistive elements: ``Σe = −d f`` (dissipating ``d|f|² ≥ 0``).
"""

from __future__ import annotations

import numpy as np
import sympy as sp

from phc.dae import T
from phc.library.dirac import DiracBuilder, emit

DEFAULT_DOMAIN = {
    "mass": "mechanical.translational", "spring": "mechanical.translational",
    "damper": "mechanical.translational", "inductor": "electrical", "capacitor": "electrical",
    "resistor": "electrical",
}


def _scope(ctx):
    return {"t": T, **ctx.params}


def _one_port_ports(b, ctx, name, spec, path, kind):
    domain = spec.domain or DEFAULT_DOMAIN.get(kind, "generic")
    span = ctx.smap.locate(path)
    return [b.add_port(name, p, domain, spec.dimension, span=span) for p in spec.ports]


def _check_coefficient(b, ctx, name, spec, path, field, strict, meaning):
    """Storage coefficients must be positive (H bounded below), resistances ≥ 0 (passive)."""
    value = getattr(spec, field)
    n_errors = len(b.diags.errors)
    ex = b.expr(ctx, value, (*path, field), _scope(ctx))
    if len(b.diags.errors) > n_errors or ex.free_symbols & b.unset_parameters:
        return ex  # already reported (here or in a parameter it uses); its placeholder value says nothing
    try:
        num = float(ex.xreplace(b.default_values()).xreplace({T: sp.Float(0)}))
    except (TypeError, ValueError):
        return ex
    if (strict and not num > 0) or (not strict and num < 0):
        b.error("PHC-E405", f"`{field}` of `{name}` is {num:g} at the default parameters; {meaning}",
                ctx, (*path, field))
    return ex


def _suffix(dim, k):
    return "" if dim == 1 else f"[{k}]"


def lower_inertia(b, ctx, name, spec, path, coeff_field: str, state: str):
    """mass / inductor: H = |x|²/(2c), every port flow = x/c, ẋ = −Σ e."""
    c = _check_coefficient(b, ctx, name, spec, path, coeff_field, True, "it must be positive")
    ports = _one_port_ports(b, ctx, name, spec, path, spec.type)
    dim = spec.dimension
    span = ctx.smap.locate(path)
    h = sp.Integer(0)
    d = DiracBuilder(name, spec.type, span)
    for port in ports:
        d.port(port)
    for k in range(dim):
        x, dx = b.add_state(name, state + _suffix(dim, k), span)
        fx, ex = d.storage_pair(state + _suffix(dim, k), x, dx, x / c)
        for port in ports:
            d.rel(port.f[k] - ex, solve=port.f[k])
        d.rel(fx + sum(port.e[k] for port in ports), kind="storage", label=f"balance[{k}]")
        h += x**2 / (2 * c)
    d.energy(h)
    emit(b, d.register(b))


def lower_compliance(b, ctx, name, spec, path, coeff_field: str, state: str, inverse: bool):
    """spring / capacitor: H = k|x|²/2, ẋ = f (shared), Σ e = −kx."""
    c = _check_coefficient(b, ctx, name, spec, path, coeff_field, True,
                           "it must be positive for the stored energy to be bounded below")
    k_eff = 1 / c if inverse else c
    ports = _one_port_ports(b, ctx, name, spec, path, spec.type)
    dim = spec.dimension
    span = ctx.smap.locate(path)
    h = sp.Integer(0)
    d = DiracBuilder(name, spec.type, span)
    for port in ports:
        d.port(port)
    for k in range(dim):
        x, dx = b.add_state(name, state + _suffix(dim, k), span)
        fx, ex = d.storage_pair(state + _suffix(dim, k), x, dx, k_eff * x)
        d.rel(fx - ports[0].f[k], solve=ports[0].f[k])
        for port in ports[1:]:
            d.rel(port.f[k] - ports[0].f[k], solve=port.f[k])
        d.rel(sum(port.e[k] for port in ports) + ex, solve=ports[0].e[k] if len(ports) == 1 else None,
              kind="storage", label=f"force[{k}]")
        h += k_eff * x**2 / 2
    d.energy(h)
    emit(b, d.register(b))


def lower_resistance(b, ctx, name, spec, path, coeff_field: str):
    """damper / resistor: Σ e = −d f, dissipation d|f|²."""
    d = _check_coefficient(b, ctx, name, spec, path, coeff_field, False,
                           "a negative resistance generates energy (it must be ≥ 0)")
    ports = _one_port_ports(b, ctx, name, spec, path, spec.type)
    span = ctx.smap.locate(path)
    dr = DiracBuilder(name, spec.type, span)
    for port in ports:
        dr.port(port)
    for k in range(spec.dimension):
        fr, er = dr.resistor(f"R{_suffix(spec.dimension, k)}")
        dr.rel(fr - ports[0].f[k], solve=fr)
        for port in ports[1:]:
            dr.rel(port.f[k] - ports[0].f[k], solve=port.f[k])
        dr.law(er - d * fr, solve=er)
        dr.rel(sum(port.e[k] for port in ports) + er, solve=ports[0].e[k] if len(ports) == 1 else None,
               kind="resistive", label=f"law[{k}]")
    emit(b, dr.register(b))


def lower_source(b, ctx, name, spec, path, which: str):
    """effort_source / flow_source: the named port variable is a function of t."""
    ports = _one_port_ports(b, ctx, name, spec, path, spec.type)
    values = b.vector(ctx, spec.value, (*path, "value"), _scope(ctx), spec.dimension, "`value`")
    position = None
    if getattr(spec, "position", None) is not None:
        position = b.vector(ctx, spec.position, (*path, "position"), _scope(ctx), spec.dimension, "`position`")
    # The relation e = u(t) (f = u(t)) is affine: its linear part, the termination e = 0
    # (f = 0), is the Dirac structure the certificate checks, so a source that cannot
    # drive its neighbour (a port whose flow map loses rank) shows up as a coupling that
    # is not surjective; the rows carry the value.
    d = DiracBuilder(name, spec.type, ctx.smap.locate(path))
    for port in ports:
        port.position = position
        d.port(port)
        imposed = port.e if which == "effort" else port.f
        for k in range(spec.dimension):
            d.rel(imposed[k] - values[k], solve=imposed[k])
        # A source is the environment: the power it delivers, f·e, is supplied to the
        # model, i.e. −f·e is delivered by the model (the paper's remark on the energy balance).
        b.source_power.append(-sum(fk * ek for fk, ek in zip(port.f, port.e)))
    if len(ports) > 1:
        # Several ports of one source share the imposed variable; the other adds up to zero power.
        other = "f" if which == "effort" else "e"
        for k in range(spec.dimension):
            d.law(sum(getattr(p, other)[k] for p in ports[1:]) - getattr(ports[0], other)[k],
                  kind="dirac", label=f"share[{k}]")
    emit(b, d.register(b, note=f"imposes its {which} (certified as the termination {which[0]} = 0 plus an input)"))


def lower_termination(b, ctx, name, spec, path, which: str):
    """zero_effort (e = 0, the paper's pinned end) / zero_flow (f = 0, its guided end)."""
    ports = _one_port_ports(b, ctx, name, spec, path, spec.type)
    position = None
    if getattr(spec, "position", None) is not None:
        position = b.vector(ctx, spec.position, (*path, "position"), _scope(ctx), spec.dimension, "`position`")
    d = DiracBuilder(name, spec.type, ctx.smap.locate(path))
    for port in ports:
        port.position = position
        d.port(port)
        imposed = port.e if which == "effort" else port.f
        for k in range(spec.dimension):
            d.rel(imposed[k], solve=imposed[k])
    emit(b, d.register(b))


def lower_transform(b, ctx, name, spec, path):
    """orthogonal_transform: f_b = Q f_a, e_a = −Qᵀ e_b (power preserving since QᵀQ = I)."""
    n = len(spec.Q)
    Q = b.matrix(ctx, spec.Q, (*path, "Q"), _scope(ctx), (n, n), "`Q`")
    numeric = Q.xreplace(b.default_values()).subs(T, 0.0)
    try:
        qn = np.array(numeric.evalf(), dtype=float)
        if not np.allclose(qn.T @ qn, np.eye(n), atol=1e-10):
            b.error("PHC-E401", f"`Q` of `{name}` is not orthogonal at the default parameters "
                    f"(|QᵀQ − I| = {np.abs(qn.T @ qn - np.eye(n)).max():.3g}); the transform would not "
                    "preserve power", ctx, (*path, "Q"))
    except (TypeError, ValueError):
        pass
    domain = spec.domain or "generic"
    span = ctx.smap.locate(path)
    a = b.add_port(name, "a", domain, n, span=span)
    if spec.split:
        total = sum(spec.split.values())
        if total != n:
            b.error("PHC-E102", f"`split` dimensions add up to {total}, but `Q` is {n} × {n}", ctx, (*path, "split"))
            return
        outs = [b.add_port(name, pname, domain, dim, span=span) for pname, dim in spec.split.items()]
        fb = [s for p in outs for s in p.f]
        eb = [s for p in outs for s in p.e]
    else:
        out = b.add_port(name, "b", domain, n, span=span)
        fb, eb = out.f, out.e
    # Positions follow the flows: if the neighbour of `a` has a position r, the output
    # ports have position Q r (assembly fills it in once connections are known).
    offsets, start = [], 0
    for p in (outs if spec.split else [out]):
        offsets.append((p.name, start, start + p.dimension))
        start += p.dimension
    b.position_maps.append((a.name, offsets, Q))
    fa = sp.Matrix(a.f)
    ebm = sp.Matrix(eb)
    qf = Q * fa
    qte = -Q.T * ebm
    d = DiracBuilder(name, spec.type, span)
    d.port(a)
    for p in (outs if spec.split else [out]):
        d.port(p)
    for k in range(n):
        d.rel(fb[k] - qf[k], solve=fb[k])
        d.rel(a.e[k] - qte[k], solve=a.e[k])
    emit(b, d.register(b))


def lower_junction(b, ctx, name, spec, path):
    """junction: common_flow (1-junction) or common_effort (0-junction); power Σ f·e = 0."""
    domain = spec.domain or "generic"
    span = ctx.smap.locate(path)
    ports = [b.add_port(name, p, domain, spec.dimension, span=span) for p in spec.ports]
    shared, summed = ("f", "e") if spec.kind == "common_flow" else ("e", "f")
    d = DiracBuilder(name, spec.type, span)
    for port in ports:
        d.port(port)
    for k in range(spec.dimension):
        first = getattr(ports[0], shared)[k]
        for port in ports[1:]:
            d.rel(getattr(port, shared)[k] - first, solve=getattr(port, shared)[k])
        d.rel(sum(getattr(p, summed)[k] for p in ports), kind="dirac", label=f"sum[{k}]")
    emit(b, d.register(b))


def lower_modulation(b, ctx, name, spec, path):
    """The paper's section 4.2: f_b = f_a, e_b = −e_a + K(x) f_a with K(x) skew.

    Lowered after all other components, so K may use their states by full name.
    """
    n = len(spec.K)
    scope = {"t": T, **ctx.params}
    vectors: dict = {}
    for v in b.variables:
        if v.differential:
            if v.name.endswith("]"):
                base, idx = v.name[:-1].rsplit("[", 1)
                vectors.setdefault(base, {})[int(idx)] = v.symbol
            else:
                scope[v.name] = v.symbol
    for base, items in vectors.items():
        scope[base] = [items[i] for i in sorted(items)]
    K = b.matrix(ctx, spec.K, (*path, "K"), scope, (n, n), "`K`")
    states = sorted(K.free_symbols - {T} - set(b.default_values()), key=str)
    rng = np.random.default_rng(0)
    for _ in range(3):
        point = {s: sp.Float(float(x)) for s, x in zip(states, rng.uniform(-1, 1, len(states)))}
        try:
            Kn = np.array(K.xreplace(b.default_values()).xreplace(point).subs(T, 0.3).evalf(), dtype=float)
        except (TypeError, ValueError):
            break
        if np.abs(Kn + Kn.T).max(initial=0) > 1e-10 * max(1.0, np.abs(Kn).max(initial=0)):
            b.error("PHC-E402", f"`K` of `{name}` is not skew-symmetric (max |K + Kᵀ| = {np.abs(Kn + Kn.T).max():.3g}); "
                    "the modulation would not preserve power (Berger, Hochdahl, Reis, Seifried, \"Port-Hamiltonian modelling of coupled rigid/flexible multibody systems\", section 4.2)", ctx, (*path, "K"))
            return
    domain = spec.domain or "generic"
    span = ctx.smap.locate(path)
    a = b.add_port(name, "a", domain, n, span=span)
    out = b.add_port(name, "b", domain, n, span=span)
    Kf = K * sp.Matrix(a.f)
    d = DiracBuilder(name, spec.type, span)
    d.port(a)
    d.port(out)
    for k in range(n):
        d.rel(out.f[k] - a.f[k], solve=out.f[k])
        d.rel(a.e[k] + out.e[k] - Kf[k], solve=a.e[k])
    emit(b, d.register(b, states=tuple(states), note="the power-preserving modulation of the paper's section 4.2"))
