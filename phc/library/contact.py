"""Unilateral contacts with Newton's restitution law (``contact``): impacts.

A contact has no ports and no energy of its own. It names a gap g(x) ≥ 0 in the
positions of masses with ``position: true`` (lowered before it); what it adds to the model
are outputs the simulation driver reads (:mod:`phc.simulation.impacts`):

* ``<name>.gap`` — g, watched as a state event (the run stops where it falls through 0);
* ``<name>.gap_rate`` — ġ = Σ ∂g/∂x_j ẋ_j, from the solution's rates;
* ``<name>.restitution`` — Newton's coefficient e ∈ [0, 1];
* ``<name>.normal.<mass>.x[k]`` — ∂g/∂x_j for every position x_j the gap depends on: the
  impulse acts on the momentum ``<mass>.p[k]`` paired with x_j along this normal;
* ``<name>.rest_speed`` — only when given.

At an impact the momenta jump, p_j⁺ = p_j⁻ + λ ∂g/∂x_j with λ such that ġ⁺ = −e ġ⁻; the
positions are continuous. The kinetic energy lost, (1 − e²)·½ m_eff ġ⁻² with
1/m_eff = Σ_j (∂g/∂x_j)²/m_j, is added to the dissipated energy, so the run's energy
balance H(t) − H(0) + E(t) stays exact through the jump.

Persistent contact: one variable, the contact force ``<name>.force`` = λ, and one row,
``<name>.closure``: λ = 0 while the contact is open, ġ = 0 while it is closed — its mode is
the parameter ``<name>.closed`` (0 by default), which the simulation driver sets. Assembly
(:func:`phc.ir.assemble._contact_forces`) adds λ ∂g/∂x_j to the balance of each momentum
p_j and writes ġ in the closure row with the velocities the masses' rows give (ẋ = p/m),
so the closed row is a velocity constraint and λ its multiplier. The force does no work in
either mode (λ ġ = 0): H(t) − H(0) + E(t) stays exact while the contact is closed.
"""

from __future__ import annotations

import re

import sympy as sp

from phc.ir.dae import T, Parameter
from phc.library.dirac import DiracBuilder, emit
from phc.library.lumped import _scope, _state_scope

_POSITION = re.compile(r"^(?P<body>.+)\.x(?P<index>\[\d+\])?$")


def _momentum(ctx, state: str) -> tuple:
    """The momentum paired with a position state, or (None, why not): ``<mass>.p[k]`` for
    ``<mass>.x[k]``; for a coordinate q_i of a rigid body with q̇ = v (no `Z`) and no
    position constraints, its momentum ``<body>.p_<v_i>`` (the impulse along ∂g/∂q is then
    Newton's; with Z or constraints it is not, and is refused)."""
    body, _, local = state.rpartition(".")
    spec = ctx.spec.components.get(body[len(ctx.prefix):]) if body.startswith(ctx.prefix) else None
    kind = getattr(spec, "type", None)
    match = _POSITION.match(state)
    if kind == "mass" and match:
        return f"{match['body']}.p{match['index'] or ''}", None
    if kind == "rigid" and local in spec.q:
        if spec.Z is not None or spec.constraints or spec.velocity_constraints:
            return None, (f"a coordinate of the rigid body `{body}`, which has `Z` or constraints: an impact there "
                          "needs the constraint impulses too, which phc does not compute yet")
        vnames = spec.v if spec.v is not None else [f"v_{q}" for q in spec.q]
        return f"{body}.p_{vnames[spec.q.index(local)]}", None
    return None, None


def lower_contact(b, ctx, name, spec, path):
    """The outputs of a contact (see the module docstring); errors are located at its fields."""
    n_errors = len(b.diags.errors)
    gap = b.expr(ctx, spec.gap, (*path, "gap"), _state_scope(b, ctx))
    e = b.expr(ctx, spec.restitution, (*path, "restitution"), _scope(ctx))
    rest = (None if spec.rest_speed is None
            else b.expr(ctx, spec.rest_speed, (*path, "rest_speed"), _scope(ctx)))
    mu = None if spec.friction is None else b.expr(ctx, spec.friction, (*path, "friction"), _scope(ctx))
    tangent = None if spec.tangent is None else b.expr(ctx, spec.tangent, (*path, "tangent"), _state_scope(b, ctx))
    if len(b.diags.errors) > n_errors:
        b.failed.add(name)
        return
    if (mu is None) != (tangent is None):
        field, other = ("friction", "tangent") if mu is not None else ("tangent", "friction")
        b.error("PHC-E126", f"contact `{name}` has `{field}` but no `{other}`: friction needs both", ctx,
                (*path, field), hint="give `friction: mu` (Coulomb's coefficient) and `tangent:` the coordinate "
                "along the surface whose rate is the slip rate, e.g. `block.x` for a floor `block.y`")
        b.failed.add(name)
        return
    states = {v.symbol: v for v in b.known_variables() if v.differential}
    positions = _positions(b, ctx, name, "gap", gap, states, path)
    slides = [] if tangent is None else _positions(b, ctx, name, "tangent", tangent, states, path)
    if positions is None or slides is None:
        b.failed.add(name)
        return
    for field, value, ok, meaning in (("restitution", e, lambda v: 0 <= v <= 1, "it must lie in [0, 1]"),
                                      ("rest_speed", rest, lambda v: v >= 0, "it must be ≥ 0"),
                                      ("friction", mu, lambda v: v >= 0, "it must be ≥ 0")):
        if value is None:
            continue
        if value.free_symbols - set(ctx.params.values()):
            b.error("PHC-E126", f"`{field}` of contact `{name}` must be written in parameters only", ctx,
                    (*path, field))
            b.failed.add(name)
            return
        number = value.xreplace(b.default_values())
        if number.is_number and not ok(float(number)):
            b.error("PHC-E405", f"`{field}` of contact `{name}` is {float(number):g} at the default parameters; "
                    f"{meaning}", ctx, (*path, field))
            b.failed.add(name)
            return
    rate = _rate(b, f"{name}.normal", gap, positions, states)
    b.extra_outputs[f"{name}.gap"] = gap
    b.extra_outputs[f"{name}.gap_rate"] = rate
    b.extra_outputs[f"{name}.restitution"] = e
    if rest is not None:
        b.extra_outputs[f"{name}.rest_speed"] = rest
    # persistent contact: the force λ (a multiplier, zero while open), its mode and its row
    span = ctx.smap.locate(path)
    force = b.add_algebraic(name, "force", "multiplier", span)
    closed = sp.Symbol(f"{name}.closed", real=True)
    b.parameters[closed.name] = Parameter(closed.name, closed, 0.0, description=(
        f"mode of contact `{name}`: 1 while it is closed, set by the simulation driver"), span=span)
    # its description: no port, no storage, the multiplier λ and one relation, the row
    d = DiracBuilder(name, "contact", span)
    d.multipliers.append(force)
    d.rel(sp.Piecewise((rate, sp.Gt(closed, 0)), (force, True)), kind="contact", label="closure")
    slip = None if mu is None else _friction(b, d, name, mu, tangent, slides, states, closed, force, span)
    emit(b, d.register(b))
    if slip is not None:  # the friction power −λ_t ṡ ≥ 0 is dissipated (λ_t = 0 open, ṡ = 0 sticking)
        b.dissipation.append((name, -slip[0] * slip[1], span))


def _friction(b, d, name, mu, tangent, slides, states, closed, force, span) -> tuple:
    """Coulomb friction at the closed contact (docs/events.md): the slip rate
    ``<name>.slip_rate`` v_t = ṡ (row ``<name>.slip``, written with the masses' velocities at
    assembly, as the closure row) and the friction force ``<name>.friction_force`` λ_t, which
    assembly adds to the momenta as λ_t ∂s/∂x_j (outputs ``<name>.tangent.<momentum>``). Row
    ``<name>.friction``: λ_t = 0 while open; while closed, by the mode ``<name>.sliding`` σ
    (set by the driver, :mod:`phc.simulation.friction`): λ_t = −μ σ λ sliding (σ = ±1, the
    sign of v_t), v_t = 0 sticking (σ = 0; λ_t its multiplier). Returns (λ_t, v_t)."""
    rate = _rate(b, f"{name}.tangent", tangent, slides, states)
    b.extra_outputs[f"{name}.friction"] = mu
    slip = b.add_algebraic(name, "slip_rate", "flow", span)
    lam_t = b.add_algebraic(name, "friction_force", "multiplier", span)
    sliding = sp.Symbol(f"{name}.sliding", real=True)
    b.parameters[sliding.name] = Parameter(sliding.name, sliding, 0.0, description=(
        f"friction mode of contact `{name}`: ±1 sliding (the sign of its slip rate), 0 sticking, set by the "
        "simulation driver"), span=span)
    d.multipliers.extend((slip, lam_t))
    d.rel(slip - rate, kind="contact", label="slip")
    d.rel(sp.Piecewise((lam_t, sp.Le(closed, 0)), (lam_t + mu * force, sp.Gt(sliding, 0)),
                       (lam_t - mu * force, sp.Lt(sliding, 0)), (slip, True)), kind="contact", label="friction")
    return lam_t, slip


def _rate(b, head, expr, positions, states):
    """Σ ∂expr/∂x_j ẋ_j, the rate of a gap or tangent; each ∂expr/∂x_j is the output
    ``<head>.<momentum>`` (the direction its impulse or force acts along on that momentum)."""
    rate = sp.Integer(0)
    for x, momentum in positions:
        direction = sp.diff(expr, x)
        b.extra_outputs[f"{head}.{momentum}"] = direction
        rate += direction * states[x].dsymbol
    return rate


def _positions(b, ctx, name, field, expr, states, path):
    """The positions `expr` (the gap or the tangent) is written in, with their momenta; None
    after a located error."""
    if T in expr.free_symbols:
        b.error("PHC-E126", f"the `{field}` of contact `{name}` depends on `t`: phc moves only the masses at an "
                "impact", ctx, (*path, field), hint="write it in the positions of masses (a moving wall is a mass "
                "driven by a `flow_source`)")
        return None
    positions = []
    for sym in sorted(expr.free_symbols & set(states), key=lambda s: s.name):
        momentum, why = _momentum(ctx, sym.name)
        if momentum is None or not any(v.name == momentum for v in states.values()):
            why = why or "which is not the position of a mass or of a rigid body"
            b.error("PHC-E126", f"the `{field}` of contact `{name}` uses `{sym.name}`, {why}", ctx, (*path, field),
                    hint=f"a {field} is written in positions `<mass>.x` of masses with `position: true`, or in "
                    "the coordinates q of `rigid` bodies without `Z` and `constraints`, declared before the contact")
            return None
        positions.append((sym, momentum))
    if not positions:
        b.error("PHC-E126", f"the `{field}` of contact `{name}` uses no position of a mass, so nothing can "
                f"{'hit' if field == 'gap' else 'slide'}", ctx, (*path, field),
                hint="write it in positions `<mass>.x` of masses with `position: true`, e.g. `ball.x - h0`")
        return None
    return positions
