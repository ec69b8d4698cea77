"""Pictures: outputs over time and the planar mechanism frame by frame.

matplotlib is optional (the ``plot`` extra). Without it every entry point raises
:class:`PlotUnavailable`, whose message says how to install it. Figures are drawn on
an Agg canvas (non-interactive, no pyplot state), so this works on machines without a
display and does not change the backend of an interactive session.

* :func:`plot_outputs` — the requested outputs over time, one panel each (it, the palette
  and the matplotlib helpers live in :mod:`phc.study.plots`; importable from here too).
* :func:`animate` — the mechanism as a GIF; :func:`frame` draws one frame.

The mechanism is discovered from the compiled model (its components, their specs and
the states in the result):

``crank_wheel``
    the wheel (a circle of its radius about its center) and the crank arm from the
    center to the crank pin ``q_O + r a(θ)`` (the paper's eq. (28)).
``moving_beam``
    the physical centerline ``r(ξ,t) = q0 + ξ t + w(ξ,t) n`` (the paper's
    eq. (20)) with the chord frame ``t = (qf − q0)/ℓ``, ``n = J t``; the
    deflection ``w`` is reconstructed from the curvature states with ``w'' = κ``,
    ``w(0) = w(L) = 0`` (the same Green's-function functional as the component's
    ``w[i]`` outputs) and may be magnified for display.
``rigid``
    a link through the positions ``r(q)`` of its planar ports (the paper's eq. (3)); a body
    with one planar port point and one coordinate is drawn as a crank (the point moves
    on a circle: circle and arm) or as a slider (the point moves on a line: guide and
    block); a body with coordinates ``x``, ``y`` is a point with its trail, and a
    distance constraint ``(x − a)² + (y − b)² − ℓ² = 0`` is drawn as a rod from the
    pivot ``(a, b)``.
``orthogonal_transform``
    a guide: when the transform ``Q_s`` (the paper's eq. (29))
    sits on a planar port and some of its split outputs are terminated by
    ``zero_flow`` (the paper's D_guide), the free rows of ``Q_s`` give the guide
    direction; the guide is the line through the slider along it.
``zero_flow`` on a planar port with a position
    a fixed support.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from pathlib import Path
from typing import Optional

import numpy as np

from phc.errors import NothingToAnimate, PlotUnavailable
from phc.study.plots import (  # noqa: F401 (importable from phc.study.viz)
    _COLORS, _LINK_COLORS, _new_figure, _require_matplotlib, outputs_figure, plot_outputs)
from phc.spec.expressions import ExpressionError

INSTALL_HINT = 'pip install "port-hamiltonian-compiler[plot]"'


# --------------------------------------------------------------------------------------
# Mechanism geometry
# --------------------------------------------------------------------------------------

@dataclass
class _Part:
    """One drawable element, with its geometry at every output time of the run.

    kind: ``polyline`` (xy: (nt, n, 2)), ``point`` (xy: (nt, 2)), ``circle``
    (center (2,), radius), ``guide`` (xy: (nt, 2) a point, direction (nt, 2)),
    ``trail`` (xy: (nt, 2), drawn up to the current frame).
    """

    kind: str
    xy: np.ndarray
    style: dict = field(default_factory=dict)
    radius: float = 0.0
    direction: Optional[np.ndarray] = None
    z: int = 2
    label: str = ""


@dataclass
class _Mechanism:
    parts: list
    t: np.ndarray
    limits: tuple
    magnified: bool = False


class _Scope:
    """Values of states and parameters of a run, for evaluating spec expressions."""

    def __init__(self, compiled, result, params):
        from phc.simulation import parameter_vector

        mod = compiled.module
        self.params = dict(zip(mod.PARAMETERS, (float(v) for v in parameter_vector(mod, params))))
        self.index = {name: i for i, name in enumerate(result.variables)}
        self.y = np.asarray(result.y, dtype=float)
        self.t = np.asarray(result.t, dtype=float)
        self.nt = len(self.t)

    def state(self, name: str) -> Optional[np.ndarray]:
        i = self.index.get(name)
        return None if i is None else self.y[:, i]


def _load_component_specs(compiled) -> dict:
    """Component full name → (type, spec, prefix): the specs as compiled (scene overrides
    and effects applied), kept by elaboration — no model file is read again."""
    topo = compiled.dae.topology
    out = {}
    if topo is None:
        return out
    for full, ctype, _ in topo.components:
        local = full.rsplit(".", 1)[-1]
        spec = topo.specs.get(full)
        if spec is not None and getattr(spec, "type", None) != ctype:
            spec = None
        out[full] = (ctype, spec, full[: len(full) - len(local)])
    return out


def _constants(scope: _Scope, prefix: str, full: str = "", spec=None) -> dict:
    """Names visible in a component's expressions with their values: the parameters of
    its model file (prefixed when nested) and the component's own `parameters`."""
    out = {}
    for pname, val in scope.params.items():
        if pname.startswith(prefix) and "." not in pname[len(prefix):]:
            out[pname[len(prefix):]] = val
    for lname in getattr(spec, "parameters", None) or {}:
        key = f"{full}.{lname}"
        if key in scope.params:
            out[lname] = scope.params[key]
    return out


def _evaluator(texts, scope: _Scope, constants: dict, states: dict):
    """Evaluate expressions of a spec over the run: list of arrays over time, or None when
    a state is missing. `states` maps local names (configuration variables) to state names."""
    import sympy as sp

    from phc.ir.dae import T
    from phc.spec.expressions import parse_expression

    names = {k: sp.Float(v) for k, v in constants.items()}
    names["t"] = T
    values = {T: scope.t}
    for lname, state in states.items():
        arr = scope.state(state)
        if arr is None:
            return None
        sym = sp.Symbol(f"_q{len(values)}", real=True)
        names[lname] = sym
        values[sym] = arr
    exprs = [parse_expression(tx, names) for tx in texts]
    syms = list(values)
    fn = sp.lambdify(syms, exprs, modules="numpy")
    out = fn(*(values[s] for s in syms))
    return [np.broadcast_to(np.asarray(o, dtype=float), (scope.nt,)).copy() for o in out]


@dataclass
class DrawContext:
    """What a registry entry's :class:`~phc.library.registry.Drawing` sees, ``draw(ctx, full, spec,
    prefix)``: the run, the planar points placed so far by port, each port's neighbour, every
    component's (type, spec, prefix); it sets `magnified` and counts rigid bodies (colours)."""

    scope: _Scope
    points: dict
    neighbour: dict
    specs: dict
    magnify: float = 1.0
    magnified: bool = False
    n_rigid: int = 0


def _build(compiled, result, magnify: float = 1.0, params: Optional[dict] = None) -> _Mechanism:
    from phc.library.registry import find

    scope = _Scope(compiled, result, params)
    specs = _load_component_specs(compiled)
    topo = compiled.dae.topology
    neighbour = {}
    if topo is not None:
        for a, b, *_ in topo.connections:
            neighbour[a], neighbour[b] = b, a
    ctx = DrawContext(scope, {}, neighbour, specs, magnify)
    parts: list[_Part] = []
    # bodies first: they place the planar points that guides and supports are drawn at
    for stage in ("body", "attachment"):
        for full, (ctype, spec, prefix) in specs.items():
            entry = find(ctype)
            drawing = entry.drawing if entry is not None else None
            if drawing is None or drawing.stage != stage:
                continue
            try:
                parts.extend(drawing.draw(ctx, full, spec, prefix))
            except ExpressionError:  # the model file changed since it was compiled: skip the part
                continue
    limits = _limits(parts)
    return _Mechanism(parts, scope.t, limits, ctx.magnified)


def draw_crank_wheel(ctx: DrawContext, full, spec, prefix) -> list:
    return _crank_wheel(full, spec, prefix, ctx.scope, ctx.points)


def draw_moving_beam(ctx: DrawContext, full, spec, prefix) -> list:
    parts, magnified = _moving_beam(full, spec, prefix, ctx.scope, ctx.points, ctx.magnify)
    ctx.magnified |= magnified
    return parts


def draw_rigid(ctx: DrawContext, full, spec, prefix) -> list:
    if spec is None:
        return []
    color = _LINK_COLORS[ctx.n_rigid % len(_LINK_COLORS)]
    ctx.n_rigid += 1
    return _rigid(full, spec, prefix, ctx.scope, ctx.points, color)


def draw_guide(ctx: DrawContext, full, spec, prefix) -> list:
    """An orthogonal transform on a planar port: its guide and slider, or a support."""
    return [] if spec is None else _guide(full, spec, prefix, ctx.scope, ctx.points, ctx.neighbour, ctx.specs)


def draw_support(ctx: DrawContext, full, spec, prefix) -> list:
    """A zero flow on a planar point: a support."""
    other = ctx.neighbour.get(f"{full}.port")
    if other not in ctx.points:
        return []
    return [_Part("point", ctx.points[other], dict(marker="^", ms=11, color=_COLORS["ground"]), z=1,
                  label=f"{full}: support")]


def _crank_wheel(full, spec, prefix, scope, points):
    theta = scope.state(f"{full}.theta")
    if theta is None:
        return []
    if spec is not None:
        vals = _evaluator([spec.radius, *spec.center], scope, _constants(scope, prefix), {})
        radius, cx, cy = (float(v[0]) for v in vals)
    else:
        radius, cx, cy = 1.0, 0.0, 0.0
    center = np.array([cx, cy])
    pin = center[None, :] + radius * np.stack([np.cos(theta), np.sin(theta)], axis=1)
    points[f"{full}.pin"] = pin
    arm = np.stack([np.broadcast_to(center, pin.shape), pin], axis=1)
    return [
        _Part("circle", center, dict(facecolor=_COLORS["wheel"], edgecolor=_COLORS["wheel_edge"], lw=1.2),
              radius=radius, z=0, label=f"{full}: wheel"),
        _Part("polyline", arm, dict(color=_COLORS["link"], lw=3.0, solid_capstyle="round"), label=f"{full}: crank"),
        _Part("point", np.broadcast_to(center, pin.shape), dict(marker="o", ms=6, color=_COLORS["ground"]), z=3),
        _Part("point", pin, dict(marker="o", ms=5, color="white", mec=_COLORS["link"]), z=4),
    ]


def _beam_deflection(full, spec, prefix, scope, n_kappa: int, chord0: float):
    """ξ samples and the matrix G with w(ξ_i) = Σ_k G_ik κ_k (the paper's eq. (20))."""
    from phc.discretize.fem1d import DP1, Mesh
    from phc.library.moving import _deflection_functional

    length = None
    elements = n_kappa // 2
    if spec is not None:
        try:
            length = float(_evaluator([spec.length], scope, _constants(scope, prefix), {})[0][0])
        except Exception:
            length = None
        if spec.elements * 2 == n_kappa:
            elements = spec.elements
    if not length or not length > 0:
        length = chord0
    mesh = Mesh(length, elements)
    space = DP1(mesh)
    # Nodal values by the component's own functional (exact at nodes: the Green's function
    # is linear on each element there), then the exact cubic of w'' = κ inside each element.
    nodal = np.stack([_deflection_functional(mesh, space, float(x)) for x in mesh.nodes])
    per = max(1, min(8, 240 // elements))
    h = mesh.h
    xi, rows = [0.0], [nodal[0]]
    for e in range(elements):
        for j in range(1, per + 1):
            s = h * j / per
            row = (1 - s / h) * nodal[e] + (s / h) * nodal[e + 1]
            row[2 * e] += -s * h / 3 + s**2 / 2 - s**3 / (6 * h)
            row[2 * e + 1] += -s * h / 6 + s**3 / (6 * h)
            xi.append(mesh.nodes[e] + s)
            rows.append(row)
    return np.array(xi), np.stack(rows)


def _moving_beam(full, spec, prefix, scope, points, magnify):
    q = [scope.state(f"{full}.{pt}[{k}]") for pt in ("q0", "qf") for k in range(2)]
    if any(v is None for v in q):
        return [], False
    q0 = np.stack(q[:2], axis=1)
    qf = np.stack(q[2:], axis=1)
    points[f"{full}.p0"], points[f"{full}.pf"] = q0, qf
    chord = qf - q0
    ell = np.linalg.norm(chord, axis=1)
    ell = np.where(ell > 0, ell, 1.0)
    tv = chord / ell[:, None]
    nv = np.stack([-tv[:, 1], tv[:, 0]], axis=1)
    kappa = []
    while (col := scope.state(f"{full}.kappa[{len(kappa)}]")) is not None:
        kappa.append(col)
    parts = [_Part("polyline", np.stack([q0, qf], axis=1), dict(color=_COLORS["chord"], lw=0.8, ls=":"), z=1)]
    magnified = False
    if kappa and len(kappa) % 2 == 0:
        xi, G = _beam_deflection(full, spec, prefix, scope, len(kappa), float(ell[0]))
        w = np.stack(kappa, axis=1) @ G.T * magnify  # (nt, nξ)
        # r(ξ,t) = q0 + ξ t + w(ξ,t) n  (the paper's eq. (20))
        r = q0[:, None, :] + xi[None, :, None] * tv[:, None, :] + w[:, :, None] * nv[:, None, :]
        magnified = magnify != 1.0
    else:  # no curvature states (a rigid rod): the chord
        r = np.stack([q0, qf], axis=1)
    parts.append(_Part("polyline", r, dict(color=_COLORS["beam"], lw=2.5, solid_capstyle="round"),
                       label=f"{full}: centerline"))
    for end in (q0, qf):
        parts.append(_Part("point", end, dict(marker="o", ms=5, color="white", mec=_COLORS["beam"]), z=4))
    return parts, magnified


def _rigid(full, spec, prefix, scope, points, color):
    states = {qn: f"{full}.{qn}" for qn in spec.q}
    if any(scope.state(s) is None for s in states.values()):
        return []
    parts = []
    names, texts = [], []
    for pname, pspec in spec.ports.items():
        if (pspec.position is not None and pspec.dimension == 2
                and pspec.domain == "mechanical.translational"):
            names.append(pname)
            texts.extend(pspec.position)
    body_pts = []
    if texts:
        vals = _evaluator(texts, scope, _constants(scope, prefix, full, spec), states)
        if vals is None:
            return []
        for i, pname in enumerate(names):
            xy = np.stack([vals[2 * i], vals[2 * i + 1]], axis=1)
            points[f"{full}.{pname}"] = xy
            body_pts.append(xy)
    if len(body_pts) >= 2:
        poly = np.stack(body_pts + ([body_pts[0]] if len(body_pts) > 2 else []), axis=1)
        parts.append(_Part("polyline", poly, dict(color=color, lw=3.0, solid_capstyle="round"),
                           label=f"{full}: link"))
        for xy in body_pts:
            parts.append(_Part("point", xy, dict(marker="o", ms=5, color="white", mec=color), z=4))
    elif len(body_pts) == 1 and len(spec.q) == 1:
        parts.extend(_one_point_body(full, spec, prefix, scope, states, texts, body_pts[0], color))
    elif len(body_pts) == 1:
        parts.append(_Part("point", body_pts[0], dict(marker="o", ms=7, color=color), z=4))
    if "x" in spec.q and "y" in spec.q:
        xy = np.stack([scope.state(states["x"]), scope.state(states["y"])], axis=1)
        if not body_pts:
            parts.append(_Part("trail", xy, dict(color=_COLORS["trail"], lw=0.8, alpha=0.6), z=0))
            parts.append(_Part("point", xy, dict(marker="o", ms=12, color=color), z=4,
                               label=f"{full}: body"))
        for pivot in _distance_pivots(spec, prefix, scope, full):
            pv = np.broadcast_to(pivot, xy.shape)
            parts.append(_Part("polyline", np.stack([pv, xy], axis=1),
                               dict(color=color, lw=2.0), z=3, label=f"{full}: rod"))
            parts.append(_Part("point", pv, dict(marker="^", ms=11, color=_COLORS["ground"]), z=1))
    return parts


def _one_point_body(full, spec, prefix, scope, states, texts, xy, color):
    """One coordinate, one planar point: a crank (circle) or a slider (line), else a point."""
    import sympy as sp

    from phc.ir.dae import T
    from phc.spec.expressions import parse_expression

    qn = spec.q[0]
    q = sp.Symbol("_q", real=True)
    names = {k: sp.Float(v) for k, v in _constants(scope, prefix, full, spec).items()}
    names.update({"t": T, qn: q})
    try:
        r = [parse_expression(tx, names) for tx in texts]
        f = sp.lambdify([q, T], r, modules="numpy")

        def at(v):
            return np.array(f(v, float(scope.t[0]) if scope.nt else 0.0), dtype=float)

        samples = [at(v) for v in (0.0, math.pi / 2, math.pi, 3 * math.pi / 2, 1.0)]
    except Exception:
        samples = None
    parts = []
    if samples is not None:
        r0, r1, r2, r3, ra = samples
        c1, c2 = (r0 + r2) / 2, (r1 + r3) / 2
        radius = float(np.linalg.norm(r0 - c1))
        scale = max(radius, float(np.abs(r0).max()), 1e-12)
        if (radius > 0 and np.linalg.norm(c1 - c2) < 1e-9 * scale
                and abs(np.linalg.norm(r1 - c1) - radius) < 1e-9 * scale
                and abs(np.linalg.norm(ra - c1) - radius) < 1e-9 * scale):
            center = np.broadcast_to(c1, xy.shape)
            parts += [
                _Part("circle", c1, dict(facecolor=_COLORS["wheel"], edgecolor=_COLORS["wheel_edge"], lw=1.0),
                      radius=radius, z=0, label=f"{full}: crank circle"),
                _Part("polyline", np.stack([center, xy], axis=1),
                      dict(color=color, lw=3.0, solid_capstyle="round"), label=f"{full}: crank"),
                _Part("point", center, dict(marker="o", ms=6, color=_COLORS["ground"]), z=3),
            ]
            return parts
        d1 = at(2.0) - 2 * ra + r0
        if np.linalg.norm(ra - r0) > 0 and np.linalg.norm(d1) < 1e-9 * max(scale, np.linalg.norm(ra - r0)):
            direction = (ra - r0) / np.linalg.norm(ra - r0)
            return [_Part("guide", xy, dict(color=_COLORS["guide"], lw=1.0, ls="--"),
                          direction=np.broadcast_to(direction, xy.shape), z=0, label=f"{full}: guide"),
                    _Part("point", xy, dict(marker="s", ms=13, color=_COLORS["slider"], mec="black"), z=3,
                          label=f"{full}: slider")]
    return [_Part("point", xy, dict(marker="o", ms=7, color=color), z=4)]


def _distance_pivots(spec, prefix, scope, full):
    """Pivots (a, b) of constraints (x − a)² + (y − b)² − ℓ² = 0 on the body's x, y."""
    import sympy as sp

    from phc.ir.dae import T
    from phc.spec.expressions import parse_expression

    x, y = sp.symbols("_x _y", real=True)
    names = {k: sp.Float(v) for k, v in _constants(scope, prefix, full, spec).items()}
    names.update({"x": x, "y": y, "t": T})
    pivots = []
    for text in spec.constraints:
        try:
            c = sp.Poly(sp.expand(parse_expression(text, names)), x, y)
        except Exception:
            continue
        if c.total_degree() != 2:
            continue
        a = float(c.coeff_monomial(x**2))
        if a == 0 or float(c.coeff_monomial(y**2)) != a or float(c.coeff_monomial(x * y)) != 0:
            continue
        pivots.append(np.array([-float(c.coeff_monomial(x)) / (2 * a), -float(c.coeff_monomial(y)) / (2 * a)]))
    return pivots


def _guide(full, spec, prefix, scope, points, neighbour, specs):
    """Guide of an orthogonal transform Q_s on a planar port (the
    paper's eq. (29)): the free rows of Q_s, through the slider."""
    other = neighbour.get(f"{full}.a")
    if other not in points or len(spec.Q) != 2 or not spec.split:
        return []
    texts = [e for row in spec.Q for e in row]
    try:
        vals = _evaluator(texts, scope, _constants(scope, prefix), {})
    except Exception:
        return []
    Q = np.stack(vals, axis=1).reshape(-1, 2, 2)  # (nt, 2, 2)
    free, fixed, row = [], [], 0
    for sub, dim in spec.split.items():
        nb = neighbour.get(f"{full}.{sub}")
        is_fixed = nb is not None and specs.get(nb.rsplit(".", 1)[0], ("",))[0] == "zero_flow"
        (fixed if is_fixed else free).extend(range(row, row + dim))
        row += dim
    xy = points[other]
    if len(free) == 1 and len(fixed) == 1:
        direction = Q[:, free[0], :]
        return [_Part("guide", xy, dict(color=_COLORS["guide"], lw=1.0, ls="--"), direction=direction, z=0,
                      label=f"{full}: guide"),
                _Part("point", xy, dict(marker="s", ms=13, color=_COLORS["slider"], mec="black"), z=3,
                      label=f"{full}: slider")]
    if len(fixed) == 2:
        return [_Part("point", xy, dict(marker="^", ms=11, color=_COLORS["ground"]), z=1, label=f"{full}: support")]
    return []


def _limits(parts) -> tuple:
    xs, ys = [], []
    for p in parts:
        if p.kind == "circle":
            c = np.asarray(p.xy, dtype=float)
            xs += [c[0] - p.radius, c[0] + p.radius]
            ys += [c[1] - p.radius, c[1] + p.radius]
        elif p.kind in ("point", "trail", "guide"):
            a = np.asarray(p.xy, dtype=float).reshape(-1, 2)
            xs.append(a[:, 0])
            ys.append(a[:, 1])
        elif p.kind == "polyline":
            a = np.asarray(p.xy, dtype=float).reshape(-1, 2)
            xs.append(a[:, 0])
            ys.append(a[:, 1])
    if not xs:
        return (-1.0, 1.0, -1.0, 1.0)
    x = np.concatenate([np.atleast_1d(v) for v in xs])
    y = np.concatenate([np.atleast_1d(v) for v in ys])
    x, y = x[np.isfinite(x)], y[np.isfinite(y)]
    if not len(x) or not len(y):
        return (-1.0, 1.0, -1.0, 1.0)
    x0, x1, y0, y1 = x.min(), x.max(), y.min(), y.max()
    span = max(x1 - x0, y1 - y0, 1e-9)
    pad = 0.08 * span
    return (x0 - pad, x1 + pad, y0 - pad, y1 + pad)


def _draw(ax, mech: _Mechanism, k: int, title: str | None = "") -> list:
    """Draw frame k of a mechanism on `ax` (cleared first); return the artists drawn.

    ``ax._phc_handles`` keeps (part, artist) pairs so :func:`_update` can move them."""
    from matplotlib.patches import Circle

    ax.clear()
    handles = []
    for p in mech.parts:
        if p.kind == "circle":
            art = ax.add_patch(Circle(tuple(np.asarray(p.xy, dtype=float)), p.radius, zorder=p.z, label=p.label,
                                      **p.style))
        elif p.kind in ("polyline", "point", "trail"):
            (art,) = ax.plot([], [], zorder=p.z, label=p.label, **({"ls": "none"} if p.kind == "point" else {}),
                             **p.style)
        else:  # guide: re-created per frame (an infinite line through the slider)
            art = None
        handles.append((p, art))
    x0, x1, y0, y1 = mech.limits
    ax.set_xlim(x0, x1)
    ax.set_ylim(y0, y1)
    ax.set_aspect("equal", adjustable="box")
    ax.grid(True, alpha=0.25)
    ax.set_xlabel("x [m]")
    ax.set_ylabel("y [m]")
    ax._phc_handles = handles
    return _update(ax, mech, k, title)


def _update(ax, mech: _Mechanism, k: int, title: str | None = None, animated: bool = False) -> list:
    """Move the artists made by :func:`_draw` to frame k; return those that move."""
    artists = []
    handles = ax._phc_handles
    for i, (p, art) in enumerate(handles):
        if p.kind == "polyline":
            pts = p.xy[k]
            art.set_data(pts[:, 0], pts[:, 1])
        elif p.kind == "point":
            art.set_data([p.xy[k][0]], [p.xy[k][1]])
        elif p.kind == "trail":
            art.set_data(p.xy[: k + 1, 0], p.xy[: k + 1, 1])
        elif p.kind == "guide":
            if art is not None:
                art.remove()
                art = None
            pt, d = p.xy[k], p.direction[k]
            if np.all(np.isfinite(pt)) and np.all(np.isfinite(d)) and np.linalg.norm(d) > 0:
                art = ax.axline(tuple(pt), tuple(pt + d), zorder=p.z, animated=animated, label=p.label,
                                **p.style)
            handles[i] = (p, art)
        if art is not None and p.kind != "circle":
            artists.append(art)
    if title is not None:
        ax.set_title(title, fontsize=10)
    return artists


def _title(compiled, result, mech, k, magnify) -> str:
    t = float(mech.t[k]) if len(mech.t) else 0.0
    text = f"{compiled.name}   t = {t:.5g} s"
    if mech.magnified:
        text += f"   (deflection ×{magnify:g})"
    if not result.success:
        text += "   [run failed]"
    return text


def _mechanism(compiled, result, magnify, params):
    mech = _build(compiled, result, magnify, params)
    if not mech.parts:
        raise NothingToAnimate(
            f"model `{compiled.name}` has nothing planar to draw: animate draws crank_wheel, moving_beam, "
            "rigid bodies with planar port positions or coordinates x, y, and guides")
    if not len(mech.t):
        raise NothingToAnimate(f"the run of `{compiled.name}` has no output times to draw")
    return mech


def frame(compiled, result, k: int, ax, magnify: float = 1.0, *, params: Optional[dict] = None) -> list:
    """Draw the mechanism at output time index `k` of `result` on the matplotlib axes `ax`.

    Axis limits cover every output time of the run (equal aspect), so frames of one
    run line up. The beam's centerline follows the paper's eq. (20) with the
    deflection multiplied by `magnify`. `params` are the base-parameter overrides the
    run used (geometry such as the crank radius is evaluated with them).

    Returns
    -------
    list
        The matplotlib artists drawn.

    Raises
    ------
    NothingToAnimate
        The model has no mechanism to draw.
    """
    _require_matplotlib("animation")
    mech = _mechanism(compiled, result, magnify, params)
    k = int(k) % len(mech.t)
    return _draw(ax, mech, k, _title(compiled, result, mech, k, magnify))


def frame_indices(n: int, max_frames: int) -> np.ndarray:
    """Up to `max_frames` output indices spread evenly over `n`, first and last included."""
    if n <= 0:
        return np.zeros(0, dtype=int)
    m = max(1, min(int(max_frames), n))
    return np.unique(np.round(np.linspace(0, n - 1, m)).astype(int))


def animate(compiled, result, path, magnify: float = 1.0, fps: float = 20.0, max_frames: int = 200, *,
            params: Optional[dict] = None, dpi: int = 90):
    """Write a GIF of the planar mechanism over the run (matplotlib on Agg, Pillow).

    Draws rigid links, the beam's physical centerline ``r(ξ,t) = q0 + ξ t + w(ξ,t) n``
    (the paper's eq. (20); deflection × `magnify`), guides and cranks, at up to
    `max_frames` output times spread evenly over the run, with fixed axis limits and
    equal aspect.

    Parameters
    ----------
    compiled : CompiledModel
    result : SimResult
        A run of `compiled` (a failed run is drawn up to where it stopped).
    path : str or Path
        The GIF to write.
    magnify : float
        Display factor of the beam deflection w.
    fps : float
        Frames per second of the GIF.
    max_frames : int
        At most this many frames.
    params : dict, optional
        Base-parameter overrides the run used.

    Returns
    -------
    Path
        The file written.

    Raises
    ------
    PlotUnavailable
        matplotlib (or Pillow) is not installed.
    NothingToAnimate
        The model has no mechanism to draw.
    """
    _require_matplotlib("animation")
    try:
        from PIL import Image
    except ImportError:  # pragma: no cover - Pillow is a dependency of matplotlib
        raise PlotUnavailable("animation") from None
    mech = _mechanism(compiled, result, magnify, params)
    x0, x1, y0, y1 = mech.limits
    aspect = (y1 - y0) / max(x1 - x0, 1e-12)
    width = 6.4
    fig = _new_figure((width, float(np.clip(width * aspect + 0.6, 2.6, 7.5))))
    fig.set_dpi(dpi)
    ax = fig.add_subplot(1, 1, 1)
    indices = [int(k) for k in frame_indices(len(mech.t), max_frames)]
    # Blitting: the axes, grid, ticks and fixed parts are rendered once; each frame
    # redraws only the moving artists and the title (what PillowWriter would do with a
    # full redraw per frame, several times faster).
    moving = _draw(ax, mech, indices[0], _title(compiled, result, mech, indices[0], magnify))
    fig.tight_layout()
    for art in [*moving, ax.title]:
        art.set_animated(True)
    canvas = fig.canvas
    canvas.draw()
    background = canvas.copy_from_bbox(fig.bbox)
    frames, palette = [], None
    for k in indices:
        moving = _update(ax, mech, k, _title(compiled, result, mech, k, magnify), animated=True)
        canvas.restore_region(background)
        for art in sorted(moving, key=lambda a: a.get_zorder()):
            ax.draw_artist(art)
        ax.draw_artist(ax.title)
        rgb = Image.fromarray(np.ascontiguousarray(np.asarray(canvas.buffer_rgba())[..., :3]))
        if palette is None:  # one palette for all frames: the colours do not change
            palette = rgb.quantize(colors=128, method=Image.Quantize.FASTOCTREE)
        frames.append(rgb.quantize(palette=palette, dither=Image.Dither.NONE))
    from phc.io import atomic_write

    path = Path(path)
    with atomic_write(path) as fh:  # a killed process leaves no truncated animation
        frames[0].save(fh, format="GIF", save_all=True, append_images=frames[1:],
                       duration=max(int(round(1000.0 / fps)), 10), loop=0)
    return path
