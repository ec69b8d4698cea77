"""Time in component data: where a component's expressions may depend on the time `t`.

The rule of the language (docs/constraints.md): wherever `t` may appear it is handled
correctly or refused with a located error — never dropped. Lowerers check data that
depends on t at the times :func:`sample_times` gives (the simulation interval of the file
being lowered), and refuse t with :func:`refuse_time` where the component cannot use it
(a fixed support that would move, a port position whose rate is not the port flow).
"""

from __future__ import annotations

import numpy as np
import sympy as sp

from phc.ir.dae import T

TIME_CODE = "PHC-E127"
"""A field that may not depend on `t` does."""


def sample_times(ctx, n: int = 6) -> list[float]:
    """The start, the end and `n` points in between of the file's simulation interval
    (deterministic): where time-dependent coefficients are checked."""
    sim = getattr(ctx.spec, "simulation", None)
    t0 = float(getattr(sim, "t_start", 0.0) or 0.0)
    t1 = getattr(sim, "t_end", None)
    t1 = float(t1) if t1 is not None else t0 + 1.0
    inner = t0 + (t1 - t0) * np.random.default_rng(2).uniform(0.0, 1.0, n)
    return [t0, t1, *map(float, inner)]


def refuse_time(b, ctx, name: str, expr, path, what: str, hint: str) -> bool:
    """A located error when `expr` (an expression, a list or a matrix of them) depends on
    `t`; True when it was refused."""
    items = expr if isinstance(expr, (list, tuple)) else [expr]
    if not any(T in getattr(e, "free_symbols", set()) for e in items):
        return False
    b.error(TIME_CODE, f"{what} of `{name}` depends on the time `t`, which it may not: it would be used "
            "as if it did not move", ctx, path, hint=hint)
    return True


def at_times(expr, times, defaults: dict):
    """Values of a parameter/time expression (or matrix) at the default parameters and the
    given times; None where it does not evaluate to numbers."""
    out = []
    base = expr.xreplace(defaults)
    timed = T in base.free_symbols
    for t in times:
        try:
            value = (base.xreplace({T: sp.Float(t)}) if timed else base).evalf()
            out.append(np.array(value, dtype=float) if isinstance(value, sp.MatrixBase) else float(value))
        except (TypeError, ValueError):
            return None
    return out
