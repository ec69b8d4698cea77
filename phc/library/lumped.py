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

from phc.ir.dae import T
from phc.library.dirac import DiracBuilder, emit
from phc.library.timing import at_times, refuse_time, sample_times
from phc.library.registry import FieldView
from phc.spec.expressions import ExpressionError, validate_syntax

DEFAULT_DOMAIN = FieldView("default_domain")
"""Type -> the domain of its ports when the entry gives none (:mod:`phc.library.registry`)."""


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
    # A coefficient in `t` is checked over the simulation interval, not only at t = 0.
    times = sample_times(ctx, 64) if T in ex.free_symbols else [0.0]
    values = at_times(ex, times, b.default_values())
    if values is None:
        return ex
    for t, num in zip(times, values):
        if (strict and not num > 0) or (not strict and num < 0):
            when = f" at t = {t:g}" if T in ex.free_symbols else ""
            b.error("PHC-E405", f"`{field}` of `{name}` is {num:g} at the default parameters{when}; {meaning}",
                    ctx, (*path, field))
            break
    return ex


def _suffix(dim, k):
    return "" if dim == 1 else f"[{k}]"


FLOW_ACROSS = ("mechanical.translational", "mechanical.rotational")
"""Domains whose across variable is the flow (velocity): a two-terminal element there acts
on the relative flow ``f_a − f_b`` and passes its effort through (``e_b = −e_a``). In the
other domains (electrical, hydraulic, thermal) the across variable is the effort."""


class _ElementPort:
    """The variables an element acts on, per vector component: the flow `f` and effort `e`
    of its port — symbols of one port, or for a two-terminal element expressions of its
    terminals — with `solvable_f`/`solvable_e` the port symbol a relation may be solved for
    (None for a relative variable) and `links` the relations that tie the terminals
    together (``e_b = −e_a`` or ``f_b = −f_a``)."""

    def __init__(self, f, e, links=()):
        self.f, self.e, self.links = f, e, list(links)
        self.solvable_f = f if isinstance(f, sp.Symbol) else None
        self.solvable_e = e if isinstance(e, sp.Symbol) else None


def _element_ports(b, ctx, name, spec, path):
    """The element's ports, and for a one-port or two-terminal element its
    :class:`_ElementPort` per vector component (None for several ports sharing one flow)."""
    span = ctx.smap.locate(path)
    terminals = getattr(spec, "terminals", None)
    if terminals is None:
        ports = _one_port_ports(b, ctx, name, spec, path, spec.type)
        if len(ports) > 1:
            return ports, None
        return ports, [_ElementPort(ports[0].f[k], ports[0].e[k]) for k in range(spec.dimension)]
    domain = spec.domain or DEFAULT_DOMAIN.get(spec.type, "generic")
    if domain == "generic":
        b.error("PHC-E124", f"`{name}` has `terminals` but no physical domain: phc needs the domain to know "
                "whether the flow (mechanical) or the effort (electrical, hydraulic, thermal) is the relative "
                "variable", ctx, (*path, "terminals"), hint="set `domain:`")
        domain = "mechanical.translational"
    pa, pb = (b.add_port(name, t, domain, spec.dimension, span=span) for t in terminals)
    out = []
    for k in range(spec.dimension):
        if domain in FLOW_ACROSS:
            out.append(_ElementPort(pa.f[k] - pb.f[k], pa.e[k], [(pb.e[k] + pa.e[k], pb.e[k])]))
        else:
            out.append(_ElementPort(pa.f[k], pa.e[k] - pb.e[k], [(pb.f[k] + pa.f[k], pb.f[k])]))
    return [pa, pb], out


def lower_inertia(b, ctx, name, spec, path, coeff_field: str, state: str):
    """mass / inductor: H = |x|²/(2c), every port flow = x/c, ẋ = −Σ e."""
    c = _check_coefficient(b, ctx, name, spec, path, coeff_field, True, "it must be positive")
    ports, element = _element_ports(b, ctx, name, spec, path)
    dim = spec.dimension
    span = ctx.smap.locate(path)
    h = sp.Integer(0)
    d = DiracBuilder(name, spec.type, span)
    for port in ports:
        d.port(port)
    for k in range(dim):
        x, dx = b.add_state(name, state + _suffix(dim, k), span)
        fx, ex = d.storage_pair(state + _suffix(dim, k), x, dx, x / c)
        # the position (`position: true`): q̇ = p/m, and −∂H/∂q (zero: H does not depend on q)
        # in the momentum balance, the canonical pair, so the structure stays a Dirac structure
        moved = sp.Integer(0)
        if getattr(spec, "position", False):
            q, dq = b.add_state(name, "x" + _suffix(dim, k), span)
            fq, eq = d.storage_pair("x" + _suffix(dim, k), q, dq, 0)
            d.rel(fq - ex, kind="storage", label=f"position[{k}]")
            moved = eq
        if element is None:
            for port in ports:
                d.rel(port.f[k] - ex, solve=port.f[k])
            d.rel(fx + moved + sum(port.e[k] for port in ports), kind="storage", label=f"balance[{k}]")
        else:
            el = element[k]
            d.rel(el.f - ex, solve=el.solvable_f, kind="storage", label=f"flow[{k}]")
            d.rel(fx + moved + el.e, kind="storage", label=f"balance[{k}]")
            for link, solve in el.links:
                d.rel(link, solve=solve)
        h += x**2 / (2 * c)
    d.energy(h)
    emit(b, d.register(b))


def lower_compliance(b, ctx, name, spec, path, coeff_field: str, state: str, inverse: bool):
    """spring / capacitor: H = k|x|²/2, ẋ = f (shared), Σ e = −kx."""
    c = _check_coefficient(b, ctx, name, spec, path, coeff_field, True,
                           "it must be positive for the stored energy to be bounded below")
    k_eff = 1 / c if inverse else c
    ports, element = _element_ports(b, ctx, name, spec, path)
    dim = spec.dimension
    span = ctx.smap.locate(path)
    h = sp.Integer(0)
    d = DiracBuilder(name, spec.type, span)
    for port in ports:
        d.port(port)
    for k in range(dim):
        x, dx = b.add_state(name, state + _suffix(dim, k), span)
        fx, ex = d.storage_pair(state + _suffix(dim, k), x, dx, k_eff * x)
        if element is None:
            d.rel(fx - ports[0].f[k], solve=ports[0].f[k])
            for port in ports[1:]:
                d.rel(port.f[k] - ports[0].f[k], solve=port.f[k])
            d.rel(sum(port.e[k] for port in ports) + ex, kind="storage", label=f"force[{k}]")
        else:
            el = element[k]
            d.rel(fx - el.f, solve=el.solvable_f, kind="storage", label=f"rate[{k}]")
            d.rel(el.e + ex, solve=el.solvable_e, kind="storage", label=f"force[{k}]")
            for link, solve in el.links:
                d.rel(link, solve=solve)
        h += k_eff * x**2 / 2
    d.energy(h)
    emit(b, d.register(b))


def lower_resistance(b, ctx, name, spec, path, coeff_field: str):
    """damper / resistor: Σ e = −d f, dissipation d|f|²."""
    d = _check_coefficient(b, ctx, name, spec, path, coeff_field, False,
                           "a negative resistance generates energy (it must be ≥ 0)")
    ports, element = _element_ports(b, ctx, name, spec, path)
    span = ctx.smap.locate(path)
    dr = DiracBuilder(name, spec.type, span)
    for port in ports:
        dr.port(port)
    for k in range(spec.dimension):
        fr, er = dr.resistor(f"R{_suffix(spec.dimension, k)}")
        if element is None:
            dr.rel(fr - ports[0].f[k], solve=fr)
            for port in ports[1:]:
                dr.rel(port.f[k] - ports[0].f[k], solve=port.f[k])
            dr.law(er - d * fr, solve=er)
            dr.rel(sum(port.e[k] for port in ports) + er, kind="resistive", label=f"law[{k}]")
        else:
            el = element[k]
            dr.rel(fr - el.f, solve=fr)
            dr.law(er - d * fr, solve=er)
            dr.rel(el.e + er, solve=el.solvable_e, kind="resistive", label=f"law[{k}]")
            for link, solve in el.links:
                dr.rel(link, solve=solve)
    emit(b, dr.register(b))


def lower_source(b, ctx, name, spec, path, which: str):
    """effort_source / flow_source: the named port variable is a function of t — or, for
    feedback (a controller), also of other components' states by full name."""
    ports = _one_port_ports(b, ctx, name, spec, path, spec.type)
    values = b.vector(ctx, spec.value, (*path, "value"), _reading_scope(b, ctx, name, spec.value), spec.dimension,
                      "`value`")
    register_readings(b, name, values, ctx.smap.locate((*path, "value")))
    read = sorted(set().union(*(v.free_symbols for v in values)) - {T} - set(b.default_values()), key=str)
    position = None
    if getattr(spec, "position", None) is not None:
        position = b.vector(ctx, spec.position, (*path, "position"), _scope(ctx), spec.dimension, "`position`")
        _check_source_position(b, ctx, name, path, position, values)
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
    note = f"imposes its {which} (certified as the termination {which[0]} = 0 plus an input)"
    if read:
        note = (f"feedback: imposes its {which} as a function of {', '.join(map(str, read))}; the plant is "
                "certified, the controller may inject energy (its power is counted as supplied power)")
    emit(b, d.register(b, states=tuple(read), note=note))


def _check_source_position(b, ctx, name, path, position, values) -> None:
    """A flow source's `position` r(t) must integrate its `value` (ṙ = u): assembly keeps
    the driven port at r(t) by GGL stabilization, whose velocity form is the imposed flow."""
    times = sample_times(ctx, 8)
    defaults = b.default_values()
    for k, (r, u) in enumerate(zip(position, values)):
        rates, flows = at_times(sp.diff(r, T), times, defaults), at_times(u, times, defaults)
        if rates is None or flows is None:
            continue
        for t, rate, flow in zip(times, rates, flows):
            if abs(rate - flow) > 1e-8 * max(1.0, abs(flow)):
                b.error("PHC-E127", f"`position` of `{name}` does not integrate its `value`: at t = {t:g} "
                        f"d/dt position[{k}] = {rate:.6g} but the imposed flow is {flow:.6g}", ctx,
                        (*path, "position"), hint="give the position r(t) whose derivative is the flow value")
                return


def lower_termination(b, ctx, name, spec, path, which: str):
    """zero_effort (e = 0, the paper's pinned end) / zero_flow (f = 0, its guided end)."""
    ports = _one_port_ports(b, ctx, name, spec, path, spec.type)
    position = None
    if getattr(spec, "position", None) is not None:
        position = b.vector(ctx, spec.position, (*path, "position"), _scope(ctx), spec.dimension, "`position`")
        if refuse_time(b, ctx, name, position, (*path, "position"), "the `position`",
                       "a termination is fixed (its flow is zero); a support that moves is a `flow_source` "
                       "with `value` ṙ(t) and `position` r(t)"):
            position = None
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
    for t in (sample_times(ctx, 8) if T in Q.free_symbols else [0.0]):  # Q(t): orthogonal at every t
        try:
            qn = np.array(Q.xreplace(b.default_values()).subs(T, t).evalf(), dtype=float)
        except (TypeError, ValueError):
            break
        if not np.allclose(qn.T @ qn, np.eye(n), atol=1e-10):
            when = f" at t = {t:g}" if T in Q.free_symbols else ""
            b.error("PHC-E401", f"`Q` of `{name}` is not orthogonal at the default parameters{when} "
                    f"(|QᵀQ − I| = {np.abs(qn.T @ qn - np.eye(n)).max():.3g}); the transform would not "
                    "preserve power", ctx, (*path, "Q"),
                    hint="for a gear, lever or any ratio use a `transformer` (f_b = N f_a, e_a = −Nᵀ e_b)")
            break
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


READING_ROLES = ("flow", "effort")
"""The roles of the variables a reading (:func:`_reading_scope`) may read: port variables."""


def reading_name(reader: str, variable: str) -> str:
    """The name of the variable holding `reader`'s reading of the port variable `variable`
    (as :meth:`phc.frontend.lowering.Recorder.add_algebraic` names it)."""
    return f"{reader}.reads({variable})"


def _written_names(value, prefix: str) -> set[str]:
    """The names an expression (or a list, or a list of lists) as written uses, by full
    name (also with a nested file's `prefix`) and without an index (`beam.b.f` for
    `beam.b.f[1]`); empty when one does not parse (lowering reports it)."""
    entries = ([e for row in value for e in (row if isinstance(row, list) else [row])]
               if isinstance(value, list) else [value])
    try:
        names = {str(s) for e in entries if isinstance(e, str) for s in validate_syntax(e).free_symbols}
    except ExpressionError:
        return set()
    names |= {n.split("[", 1)[0] for n in names}
    return names | {prefix + n for n in names}


def _reading_scope(b, ctx, reader: str, value) -> dict:
    """:func:`_state_scope` and also the port variables (``coil.port.f``, ``drive.port.e``,
    ``beam.b.f[1]``) of the components lowered before `reader` that `value` (as written)
    names, by the names outputs give them. A port variable read stands for a *reading*: an
    algebraic variable of `reader` (:func:`register_readings`), so that the reading is one
    row ``r = v`` of the assembled system, never a definition substituted into the source it
    may drive: assembly refuses a reading that depends on its own reader's output (an
    algebraic loop, PHC-E129)."""
    written = _written_names(value, ctx.prefix)
    ports = []
    if written:
        ports = [(v.name, sp.Symbol(reading_name(reader, v.name), real=True)) for v in b.known_variables()
                 if v.role in READING_ROLES and (v.name in written or v.name.split("[", 1)[0] in written)]
    return _state_scope(b, ctx, ports)


def register_readings(b, reader: str, exprs, span) -> None:
    """Add the reading variables that `exprs` (parsed in :func:`_reading_scope`) use, each
    with its row ``reading − port variable = 0``. The row is a measurement, not a relation
    of the reader's Dirac structure (so it is not compared with its description)."""
    head = reading_name(reader, "")[:-1]
    used = set().union(*(getattr(e, "free_symbols", set()) for e in exprs)) if exprs else set()
    for sym in sorted(used, key=str):
        if sym.name.startswith(head) and sym.name.endswith(")"):
            port = sym.name[len(head):-1]
            b.add_algebraic(reader, f"reads({port})", "reading", span)
            b.add_equation(sym - sp.Symbol(port, real=True), reader, "reading", f"reads({port})", span,
                           derived=True)


def _state_scope(b, ctx, ports=()) -> dict:
    """Names a modulated component may read: `t`, parameters, the states of the
    components lowered before it and the outputs of the signal blocks lowered before it
    (:mod:`phc.library.signal`), by full name (vectors also as lists); in a nested file
    also by the name written there (`body.p` for `plant.body.p`). `ports`: (name, value)
    pairs of port variables to add (:func:`_reading_scope`)."""
    scope = {"t": T, **ctx.params}
    vectors: dict = {}
    named = [(v.name, v.symbol) for v in b.known_variables() if v.differential] + list(ports)
    for name, value in (*named, *b.context.signals.items()):
        if name.endswith("]"):
            base, idx = name[:-1].rsplit("[", 1)
            vectors.setdefault(base, {})[int(idx)] = value
        else:
            scope[name] = value
    for base, items in vectors.items():
        scope[base] = [items[i] for i in sorted(items)]
    if ctx.prefix:  # in a nested file, its own components also by the names written there
        n = len(ctx.prefix)
        scope.update([(name[n:], value) for name, value in scope.items() if "." in name and name.startswith(ctx.prefix)])
    return scope


def _ratio(b, ctx, name, spec, path) -> sp.Matrix:
    """A transformer's or gyrator's ratio as an m × n matrix (a number is 1 × 1)."""
    scope = _state_scope(b, ctx)
    if isinstance(spec.ratio, list):
        rows = spec.ratio if spec.ratio and isinstance(spec.ratio[0], list) else [spec.ratio]
        width = max((len(r) for r in rows), default=0)
        return b.matrix(ctx, rows, (*path, "ratio"), scope, (len(rows), width), "`ratio`")
    return sp.Matrix([[b.expr(ctx, spec.ratio, (*path, "ratio"), scope)]])


def _two_port(b, ctx, name, spec, path, N: sp.Matrix):
    span = ctx.smap.locate(path)
    domain_a = spec.domain_a or "generic"
    pa = b.add_port(name, "a", domain_a, N.cols, span=span)
    pb = b.add_port(name, "b", spec.domain_b or domain_a, N.rows, span=span)
    return pa, pb, span


def _modulating_states(b, N: sp.Matrix) -> tuple:
    return tuple(sorted(N.free_symbols - {T} - set(b.default_values()), key=str))


def lower_transformer(b, ctx, name, spec, path):
    """transformer: f_b = N f_a, e_a = −Nᵀ e_b (power-conserving for every N)."""
    _lower_ratio(b, ctx, name, spec, path, gyrator=False)


def lower_gyrator(b, ctx, name, spec, path):
    """gyrator: e_b = G f_a, e_a = −Gᵀ f_b (power-conserving for every G)."""
    _lower_ratio(b, ctx, name, spec, path, gyrator=True)


def _lower_ratio(b, ctx, name, spec, path, gyrator: bool):
    """The two ideal two-ports: port b's flow (transformer) or effort (gyrator) is N f_a,
    and e_a = −Nᵀ times b's other variable, so f_a·e_a + f_b·e_b = 0 for every N."""
    N = _ratio(b, ctx, name, spec, path)
    if N.rows == 0 or N.cols == 0:
        return
    pa, pb, span = _two_port(b, ctx, name, spec, path, N)
    driven, other = (pb.e, pb.f) if gyrator else (pb.f, pb.e)
    out = N * sp.Matrix(pa.f)
    back = -N.T * sp.Matrix(other)
    d = DiracBuilder(name, spec.type, span)
    d.port(pa)
    d.port(pb)
    for k in range(N.rows):
        d.rel(driven[k] - out[k], solve=driven[k])
    for k in range(N.cols):
        d.rel(pa.e[k] - back[k], solve=pa.e[k])
    note = ("ideal gyrator: e_b = G f_a, e_a = −Gᵀ f_b" if gyrator else
            "ideal transformer: f_b = N f_a, e_a = −Nᵀ e_b")
    emit(b, d.register(b, states=_modulating_states(b, N), note=note))


def lower_modulation(b, ctx, name, spec, path):
    """The paper's section 4.2: f_b = f_a, e_b = −e_a + K(x) f_a with K(x) skew.

    Lowered after all other components, so K may use their states by full name.
    """
    n = len(spec.K)
    K = b.matrix(ctx, spec.K, (*path, "K"), _state_scope(b, ctx), (n, n), "`K`")
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
