"""Signal blocks: controllers with state (``state_space``, ``pi``).

A signal block is not a physical component: it has no ports, no energy and no Dirac
structure. Its input reads other components' states (by full name, as a feedback source's
`value`, :func:`phc.library.lumped.lower_source`) and the outputs of other blocks; its
states are integrated like any other state; its outputs act on the plant only through a
source whose `value` reads them. The certificate (``phc check``) covers the physical part
and lists a block as outside it; the power the driven source delivers is counted as
supplied power, so the energy balance stays exact.

The rows of a block are ``ż − (A z + B u) = 0``; its output ``y = C z + D u`` is not a
variable but an expression in the states and `t` (recorded in
:attr:`~phc.frontend.lowering.Recorder.signals` for the components lowered after it, and as an
output of the model).
"""

from __future__ import annotations

import sympy as sp

from phc.library.lumped import _check_coefficient, _reading_scope, _scope, register_readings


def _indexed(local: str, n: int) -> list[str]:
    return [local] if n == 1 else [f"{local}[{i}]" for i in range(n)]


def output_names(name: str, spec) -> list[str]:
    """The full names of a block's outputs: ``name.y``, or ``name.y[k]`` for several."""
    return [f"{name}.{local}" for local in _indexed("y", len(spec.C) if spec.type == "state_space" else 1)]


def _publish(b, name: str, y: list, span=None) -> None:
    """Make the outputs readable as ``name.y`` (``name.y[k]``) by later components and outputs.

    An output read by a component lowered before this block (blocks that read each other in
    a cycle, :meth:`phc.frontend.elaborate.Elaborator._reading_order`) is already a placeholder symbol
    of that name: it becomes an algebraic variable with the row ``y − (C z + D u) = 0``, so
    that what read it early and what reads it now see one variable; an algebraic loop among
    such outputs (feedthrough all round the cycle) is refused after assembly (PHC-E128)."""
    for local, value in zip(_indexed("y", len(y)), y):
        full = f"{name}.{local}"
        early = b.context.signals.get(full)
        if isinstance(early, sp.Symbol) and early.name == full:
            sym = b.add_algebraic(name, local, "signal", span)
            b.add_equation(sym - value, name, "signal", local, span)  # labelled as the variable
            value = sym
        b.signals[full] = value
        b.extra_outputs[full] = value


def _states(b, name: str, local: str, n: int, span) -> list:
    return [b.add_state(name, loc, span) for loc in _indexed(local, n)]


def lower_state_space(b, ctx, name, spec, path):
    """ż = A z + B u, y = C z + D u (see :class:`phc.spec.components.StateSpaceSpec`)."""
    span = ctx.smap.locate(path)
    n, p = len(spec.A), len(spec.C)
    if n == 0 or p == 0:
        b.error("PHC-E102", f"`{name}` needs at least one state (a row of `A`) and one output (a row of `C`)",
                ctx, (*path, "A" if n == 0 else "C"), hint="an integrator is `A: [[0]]`, `B: [[1]]`, `C: [[1]]`")
        b.failed.add(name)
        return
    u = b.vector(ctx, spec.input, (*path, "input"), _reading_scope(b, ctx, name, spec.input), None, "`input`")
    register_readings(b, name, u, ctx.smap.locate((*path, "input")))
    m = len(u)
    params = _scope(ctx)
    A = b.matrix(ctx, spec.A, (*path, "A"), params, (n, n), "`A`")
    B = b.matrix(ctx, spec.B, (*path, "B"), params, (n, m), "`B`")
    C = b.matrix(ctx, spec.C, (*path, "C"), params, (p, n), "`C`")
    D = (sp.zeros(p, m) if spec.D is None else b.matrix(ctx, spec.D, (*path, "D"), params, (p, m), "`D`"))
    states = _states(b, name, "z", n, span)
    z = sp.Matrix([s for s, _ in states])
    uu = sp.Matrix(u)
    rhs = A * z + B * uu
    for i, (_, dz) in enumerate(states):
        b.add_equation(dz - rhs[i], name, "signal", f"state[{i}]", span)
    _publish(b, name, list(C * z + D * uu), span)


def lower_pi(b, ctx, name, spec, path):
    """A PI/PID controller with optional output limits and conditional-integration
    anti-windup (see :class:`phc.spec.components.PiSpec`)."""
    span = ctx.smap.locate(path)
    params = _scope(ctx)
    e = b.expr(ctx, spec.input, (*path, "input"), _reading_scope(b, ctx, name, spec.input))
    register_readings(b, name, [e], ctx.smap.locate((*path, "input")))
    Kp = b.expr(ctx, spec.Kp, (*path, "Kp"), params)
    Ki = b.expr(ctx, spec.Ki, (*path, "Ki"), params)
    (z, dz), = _states(b, name, "z", 1, span)
    y = Kp * e + Ki * z
    if spec.Kd is not None:
        Kd = b.expr(ctx, spec.Kd, (*path, "Kd"), params)
        if spec.Tf is None:  # reported; lowered on with Tf = 1 so that what reads the block finds its output
            b.error("PHC-E102", f"`{name}` has a derivative gain `Kd` but no filter time constant `Tf`", ctx,
                    (*path, "Kd"), hint="add `Tf` (> 0), e.g. a tenth of the loop's fastest time constant")
            Tf = sp.Integer(1)
        else:
            Tf = _check_coefficient(b, ctx, name, spec, path, "Tf", True,
                                    "the derivative filter's time constant must be positive")
        (d, dd), = _states(b, name, "d", 1, span)
        # Kd·s/(Tf·s + 1) e = Kd (e − d)/Tf with the lag Tf ḋ = e − d
        b.add_equation(dd - (e - d) / Tf, name, "signal", "filter", span)
        y = y + Kd * (e - d) / Tf
    rate = e
    if spec.limits is not None:
        lo, hi = (b.expr(ctx, v, (*path, "limits", i), params) for i, v in enumerate(spec.limits))
        bounds = [v.xreplace(dict(b.default_values())) for v in (lo, hi)]
        if all(v.is_number for v in bounds) and not bounds[0] < bounds[1]:
            b.error("PHC-E405", f"`limits` of `{name}` are [{float(bounds[0]):g}, {float(bounds[1]):g}] at the "
                    "default parameters; the lower limit must be below the upper", ctx, (*path, "limits"))
        # conditional integration: hold the integral while the output is clamped and the
        # error would drive it further into the limit
        rate = sp.Piecewise((0, sp.And(y > hi, Ki * e > 0)), (0, sp.And(y < lo, Ki * e < 0)), (e, True))
        y = sp.Piecewise((hi, y > hi), (lo, y < lo), (y, True))
    b.add_equation(dz - rate, name, "signal", "integral", span)
    _publish(b, name, [y], span)


__all__ = ["lower_pi", "lower_state_space", "output_names"]
