"""Do the rows compiled for a component say what its description says?

Input: an assembled :class:`~phc.dae.Dae` (its topology keeps each component's
description and the rows its lowerer emitted, before assembly). Output: a
:class:`RowsCertificate` with one located error per component whose rows and description
differ.

Each component with a complete description (storage bound to states, resistive pairs to
laws; see :mod:`phc.library.dirac`) is a pair of systems over the same *visible*
variables — its states x, their rates ẋ and its port flows and efforts:

* the rows: residual rows and definitions, with the component's other algebraic
  variables (velocities, multipliers) as *hidden* unknowns;
* the description: its kernel relations ``F f + E e + G λ = b(t)`` and its laws, with
  each storage pair replaced by ``(ẋ, ∂H/∂x)`` and the multipliers, resistive pairs and
  auxiliary variables hidden.

Both define a set of visible points (∃ hidden). They are the same relation iff every
point of one lies in the other and, at those points, the tangent spaces of the two sets
(projected onto the visible variables) agree. That is what is tested, from both sides,
at points found by a minimum-norm Newton iteration from random starts, with time and
every symbol foreign to the component (another component's state read by a modulation)
fixed at random values and the parameters at their defaults. A relation that is linear
at fixed states — every lumped and rigid component — is decided exactly (up to
round-off) by one point and its tangent space; nonlinear laws are sampled.

A wrong sign in any row, a dropped term, a source that imposes −u instead of u, or a
kinematic row θ̇ = −ω where the description says θ̇ = ω is found, whether or not it
changes the energy balance.

Components whose rows are sparse matrix blocks (discretized PDEs, matrix components)
describe only the projection of their structure onto their ports; they are listed as not
compared, and their rows are certified by the energy balance of the compiled equations
(:mod:`phc.checks.compiled`).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Optional

import numpy as np
import sympy as sp

from phc.budget import drop_deltas
from phc.dae import T, ComponentDescription, ComponentRows, Dae
from phc.diagnostics import Diagnostic, DiagnosticList

MAX_UNKNOWNS = 400
"""Components with more unknowns than this are not compared (dense linear algebra)."""
RESIDUAL_TOL = 1e-9
"""A point satisfies a system when every row's residual is below this, relative to the
row's largest Jacobian entry times the size of the point."""
RESTARTS = 5
"""Random starts tried before a system is reported as having no point found."""
ANGLE_TOL = 1e-6
"""Largest allowed distance between orthonormal bases of the two tangent spaces."""


@dataclass
class RowsCertificate:
    compared: list[str] = field(default_factory=list)
    not_compared: list[tuple[str, str]] = field(default_factory=list)
    """(component, why) for components whose rows were not compared with a description."""
    inconclusive: list[tuple[str, str]] = field(default_factory=list)
    diagnostics: DiagnosticList = field(default_factory=DiagnosticList)
    samples: int = 0

    @property
    def ok(self) -> bool:
        return not self.diagnostics.has_errors

    def summary(self) -> str:
        text = f"rows match the description for {len(self.compared)} component(s)"
        if self.not_compared:
            text += f"; {len(self.not_compared)} certified by the energy balance only"
        return text


@dataclass
class _System:
    """Rows ``F(u) = 0`` over unknowns u = (visible, hidden) at fixed time and foreign values."""

    labels: list[str]
    exprs: list[sp.Expr]
    unknowns: list[sp.Symbol]
    n_visible: int
    _f: object = None
    _j: object = None
    _values: object = None
    _jumps: bool = False

    def compile(self, fixed_symbols: list) -> None:
        """Generate F and its Jacobian as functions of (u, values of `fixed_symbols`)."""
        F = sp.Matrix([sp.sympify(e) for e in self.exprs])
        # almost everywhere: the derivative of sign/heaviside is 0, not a Dirac delta
        J = F.jacobian(self.unknowns).applyfunc(drop_deltas) if self.unknowns else sp.zeros(len(self.exprs), 0)
        self._jumps = any(e.has(sp.sign, sp.Heaviside, sp.Piecewise) for e in F)
        self._f = sp.lambdify([self.unknowns, fixed_symbols], list(F), modules="numpy", cse=True)
        self._j = sp.lambdify([self.unknowns, fixed_symbols], J, modules="numpy", cse=True)

    def fix(self, values) -> None:
        self._values = values

    def F(self, u):
        return np.asarray(self._f(u, self._values), dtype=float).reshape(-1)

    def J(self, u):
        return np.asarray(self._j(u, self._values), dtype=float).reshape(len(self.exprs), len(self.unknowns))


def _scaled(system: _System, u):
    F, J = system.F(u), system.J(u)
    scale = np.maximum(np.abs(J).max(axis=1, initial=0.0), 1e-300) * max(1.0, float(np.abs(u).max(initial=0.0)))
    return F / scale, J / scale[:, None]


def _newton(system: _System, u, free: Optional[np.ndarray] = None, iterations: int = 60):
    """A zero of the system near `u`, moving only the unknowns in `free` (minimum-norm
    damped Gauss–Newton). Returns (point, largest scaled residual)."""
    u = np.array(u, dtype=float)
    free = np.arange(len(u)) if free is None else free
    with np.errstate(all="ignore"):
        r, J = _scaled(system, u)
        for _ in range(iterations):
            err = float(np.abs(r).max(initial=0.0))
            if not np.isfinite(err) or err <= RESIDUAL_TOL * 1e-2:
                break
            step = np.linalg.lstsq(J[:, free], r, rcond=None)[0]
            alpha, best = 1.0, None
            while alpha > 1e-4:
                trial = u.copy()
                trial[free] -= alpha * step
                rt, Jt = _scaled(system, trial)
                et = float(np.abs(rt).max(initial=0.0))
                if np.isfinite(et) and et < err:
                    best = (trial, rt, Jt)
                    break
                alpha /= 2
            if best is None and system._jumps:
                # a law with a jump (sign, heaviside, ifelse): the residual need not decrease on
                # the way across it; take the full step (the iteration count still bounds this)
                trial = u.copy()
                trial[free] -= step
                rt, Jt = _scaled(system, trial)
                best = (trial, rt, Jt) if np.all(np.isfinite(rt)) else None
            if best is None:
                break
            u, r, J = best
        return u, float(np.abs(r).max(initial=0.0))


def _visible_tangent(system: _System, u) -> np.ndarray:
    """Orthonormal basis (columns) of the solution set's tangent space at u, projected onto
    the visible unknowns."""
    _, J = _scaled(system, u)
    n = len(u)
    if J.size:
        _, s, vt = np.linalg.svd(J)
        rank = int(np.sum(s > 1e-9 * max(s.max(initial=0.0), 1e-300)))
        null = vt[rank:].T
    else:
        null = np.eye(n)
    proj = null[:system.n_visible]
    if proj.size == 0:
        return np.zeros((system.n_visible, 0))
    U, s, _ = np.linalg.svd(proj, full_matrices=False)
    return U[:, s > 1e-8 * max(s.max(initial=0.0), 1.0)]


def _worst(system: _System, u) -> tuple[str, float]:
    r, _ = _scaled(system, u)
    i = int(np.argmax(np.abs(r)))
    return system.labels[i], float(system.F(u)[i])


def _systems(desc: ComponentDescription, rows: ComponentRows) -> tuple[_System, _System]:
    states = [s for s, ds, _ in rows.variables if ds is not None]
    rates = [ds for _, ds, _ in rows.variables if ds is not None]
    port_vars = [x for idx, _ in desc.ports.values() for i in idx for x in (desc.flows[i], desc.efforts[i])]
    visible = [*states, *rates, *port_vars]
    own = {s for s, _, _ in rows.variables}
    hidden_rows = [s for s, ds, _ in rows.variables if ds is None and s not in set(port_vars)]
    r_labels = [label for label, _ in rows.equations] + [f"definition of {s}" for s, _ in rows.definitions]
    r_exprs = [e for _, e in rows.equations] + [s - e for s, e in rows.definitions]
    sigma = {}
    for st in desc.storage:
        sigma[st.flow] = st.rate
        sigma[st.effort] = st.gradient
    d_exprs = [e.xreplace(sigma) for e in (*desc.relations, *desc.laws)]
    labels = {(which, i): label for which, i, _, _, label in desc.order if label}
    d_labels = ([labels.get(("rel", i)) or f"relation {i} ({_short(e)})" for i, e in enumerate(desc.relations)]
                + [labels.get(("law", i)) or f"law {i} ({_short(e)})" for i, e in enumerate(desc.laws)])
    internal = set(desc.flows) | set(desc.efforts) | set(desc.multipliers)
    used = set().union(*(e.free_symbols for e in d_exprs)) if d_exprs else set()
    hidden_desc = sorted((used & (internal | own)) - set(visible) - set(sigma), key=str)
    return (_System(r_labels, r_exprs, visible + hidden_rows, len(visible)),
            _System(d_labels, d_exprs, visible + hidden_desc, len(visible)))


def _short(expr, limit: int = 60) -> str:
    text = str(expr)
    return text if len(text) <= limit else text[:limit - 1] + "…"


def compare(desc: ComponentDescription, rows: ComponentRows, defaults: dict, rng, samples: int = 2,
            t_range: tuple[float, float] = (0.0, 1.0)) -> tuple[Optional[str], Optional[str]]:
    """Compare one component's rows with its description. Returns ``(mismatch, note)``:
    `mismatch` describes a difference found (None if none), `note` why the comparison was
    inconclusive (None if it was not)."""
    sys_rows, sys_desc = _systems(desc, rows)
    n_vis = sys_rows.n_visible
    foreign = (set().union(*(sp.sympify(e).free_symbols for e in sys_rows.exprs + sys_desc.exprs))
               - set(sys_rows.unknowns) - set(sys_desc.unknowns) - set(defaults) - {T})
    note = None
    foreign = sorted(foreign, key=str)
    fixed_symbols = [T, *defaults, *foreign]
    sys_rows.compile(fixed_symbols)
    sys_desc.compile(fixed_symbols)
    for k in range(samples):
        t = float(rng.uniform(*t_range))
        values = np.array([t, *(float(v) for v in defaults.values()), *rng.normal(size=len(foreign))])
        sys_rows.fix(values)
        sys_desc.fix(values)
        for a, b, a_name, b_name in ((sys_rows, sys_desc, "the equations", "the description"),
                                     (sys_desc, sys_rows, "the description", "the equations")):
            for _ in range(RESTARTS):
                point, err = _newton(a, rng.normal(size=len(a.unknowns)))
                if err <= RESIDUAL_TOL:
                    break
            if not err <= RESIDUAL_TOL:
                note = f"no point of {a_name} found from a random start (residual {err:.1e})"
                continue
            w = point[:n_vis]
            start = np.concatenate([w, rng.normal(size=len(b.unknowns) - n_vis)])
            other, err_b = _newton(b, start, free=np.arange(n_vis, len(b.unknowns)))
            where = _where(sys_rows.unknowns[:n_vis], w, t)
            if not err_b <= RESIDUAL_TOL * 1e3:
                label, value = _worst(b, other)
                return (f"{b_name} fail at a point {a_name} allow: `{label}` is off by {value:.3g} "
                        f"(at {where})"), None
            ta, tb = _visible_tangent(a, point), _visible_tangent(b, other)
            if ta.shape[1] != tb.shape[1]:
                return (f"{a_name} leave {ta.shape[1]} directions free where {b_name} leave "
                        f"{tb.shape[1]} (at {where})"), None
            if ta.shape[1] and np.abs(ta - tb @ (tb.T @ ta)).max() > ANGLE_TOL:
                return f"{a_name} and {b_name} allow different motions through the same point (at {where})", None
    return None, note


def _where(symbols, values, t) -> str:
    parts = [f"t = {t:.3g}"]
    for s, v in list(zip(symbols, values))[:3]:
        parts.append(f"{s} = {v:.3g}")
    return ", ".join(parts) + (", …" if len(symbols) > 3 else "")


def check_rows(dae: Dae, samples: int = 2, seed: int = 0, max_unknowns: int = MAX_UNKNOWNS) -> RowsCertificate:
    """Compare every component's rows with its description (see the module docstring)."""
    cert = RowsCertificate(samples=samples)
    top = dae.topology
    if top is None:
        return cert
    rows = {r.component: r for r in top.rows}
    defaults = {p.symbol: sp.Float(p.default) for p in dae.parameters}
    t_end = float(dae.options.get("t_end", 1.0) or 1.0) if isinstance(dae.options, dict) else 1.0
    rng = np.random.default_rng(seed)
    for desc in top.dirac:
        r = rows.get(desc.component)
        if r is None:
            continue
        if not desc.complete or r.sparse:
            cert.not_compared.append((desc.component, "described by its ports only (sparse rows)"))
            continue
        size = len(r.variables) + sum(1 for _, ds, _ in r.variables if ds is not None)
        if size > max_unknowns:
            cert.not_compared.append((desc.component, f"{size} unknowns (above {max_unknowns})"))
            continue
        try:
            mismatch, note = compare(desc, r, defaults, rng, samples, (0.0, t_end))
        except (TypeError, ValueError, ZeroDivisionError, OverflowError, np.linalg.LinAlgError) as err:
            cert.inconclusive.append((desc.component, f"{type(err).__name__}: {err}"))
            continue
        if mismatch is not None:
            cert.diagnostics.append(Diagnostic(
                "PHC-E452", f"the equations compiled for `{desc.component}` ({desc.kind}) do not say what its "
                f"description says: {mismatch}", span=desc.span,
                hint="this is a fault in phc's lowering of this component type, not in the model; please report it"))
        elif note is not None:
            cert.inconclusive.append((desc.component, note))
        else:
            cert.compared.append(desc.component)
    return cert


__all__ = ["RowsCertificate", "check_rows", "compare", "MAX_UNKNOWNS"]
