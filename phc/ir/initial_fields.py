"""Initial fields of distributed components: initial data independent of the mesh.

A distributed component's state is a vector of finite element coefficients, one per
degree of freedom (`rod.p[3]`), so values given per dof belong to one mesh. A *field*
is given as a function of the material coordinate ``xi`` instead and projected onto
whatever mesh is compiled::

    simulation:
      initial:
        rod.w: "0.001*sin(pi*xi/L)"      # deflection → strain / curvature states
        rod.velocity: "0.1*sin(pi*xi/L)" # velocity → momentum states

Which fields each component type takes (:data:`FIELDS`), and how they become dof values:

* every field is an expression in ``xi`` and the model's parameters, parsed by phc's
  whitelisting parser (never evaluated as code); derived fields are differentiated
  symbolically (``w`` → ``∂w/∂ξ`` or ``∂²w/∂ξ²``);
* a state field x (or a field that fixes one: a strain from a deflection) is projected
  onto its finite element space S by the L2 projection in the component's energy inner
  product: ``∫ c x_h φ = ∫ c x φ`` for all φ in S, where ``c(ξ)`` is the field's energy
  coefficient (``H = ½∫ c x²``: ``1/ρ`` for a momentum density, ``T``, ``EI``, ``K`` for
  strains). When c is constant this is the plain L2 projection (consistent mass matrix);
  either way it reproduces every function of S exactly, and the discrete energy of the
  projected state is the closest the mesh has to the field's energy;
* a velocity (a co-energy ``e = c x``) is turned into its momentum by the same projection:
  ``∫ c p_h φ = ∫ v φ``;
* on the continuous spaces (P1, Hermite H3) the projection keeps the field's *end traces*:
  the discrete co-energy ``e_h`` (``M e_h = M_c x_h``, what the boundary ports see: an
  end's velocity, and on Hermite elements its slope, the end's angular velocity) takes the
  field's co-energy and its slope at ξ = 0 and ξ = L exactly, and the other rows are the
  projection above (:func:`project_traces`). The accuracy is the projection's, and what the
  mechanism demands of the ends is met exactly when the field meets it: a velocity field
  that vanishes at a pinned end gives momenta whose end velocity is 0, not O(h²), so the
  consistent initialization accepts them as given instead of calling them inconsistent;
* the moving beam's ``velocity`` is its *elastic* transverse velocity relative to the
  chord's rigid motion, whose end velocities the rest of the mechanism decides at
  consistent initialization: it is projected onto the Hermite space with zero end values
  and imposed as ``e_p = rigid(v_0, v_L) + ẇ_h`` at every interior node value and every
  node slope — the relations of ``initial_shape: straight`` with a right-hand side.

Per-dof values stay valid on the mesh they were written for: the model file's
``elements`` for values in the model file, the scene's ``accuracy.mesh`` (else the model
file's) for values in a scene. Any other element count (a scene's mesh, ``--mesh``, the
refinement of ``--estimate-error`` or ``phc bench``) with per-dof values of that component
is the located error PHC-E214.
"""

from __future__ import annotations

import re
from dataclasses import dataclass
from typing import TYPE_CHECKING, Optional

import numpy as np
import sympy as sp

from phc.ir.dae import InitialValue
from phc.library.registry import FieldView, find
from phc.spec.model import InitialSpec

if TYPE_CHECKING:
    from phc.discretize.fem1d import Mesh

XI = sp.Symbol("xi", real=True)  # the same symbol as phc.library.beams.XI

FIELDS = FieldView("initial_fields", lambda entry: dict(entry.initial_fields.names) or None)
"""Fields by component type: the ``initial_fields`` of its registry entry
(:mod:`phc.library.registry`; `pde1d` takes its `variables` by name)."""

_PIN_TRACES = FieldView("initial_fields", lambda entry: dict(entry.initial_fields.pin_traces) or None)
"""The end traces a pin (`zero_flow` on the port) sets to zero, by component type and field:
(port, end, derivative) — a port's flow is the trace of the field's co-energy
(phc.library.beams: the ports of `_lower_partitioned`)."""

_SUGGEST = {"eps": "w", "kappa": "w", "gamma": "w", "theta": "w", "p": "velocity", "M": "angular_velocity"}
"""The field to suggest instead of per-dof values of a state."""

_DOF = re.compile(r"^(.*)\.([A-Za-z][A-Za-z0-9_]*)\[(\d+)\]$")


@dataclass
class FieldSet:
    """What a distributed component registers when it is lowered with its full discretization."""

    component: str
    type: str
    mesh: Mesh
    fields: Optional[dict]
    """local → (space, state names, co-energy symbols, energy coefficient or None); None when
    the component is modally reduced (effect `modes`)."""
    variables: tuple = ()
    """pde1d: the variable names (its fields)."""
    rigid: Optional[tuple] = None
    """Moving beam: (v0, vL) symbols, the end normal velocities."""


def _splu(matrix):
    """scipy's sparse LU of `matrix`. scipy and :mod:`phc.discretize.fem1d` are imported
    when a field is projected: a model without meshes is validated without them."""
    import scipy.sparse.linalg as spla

    return spla.splu(matrix)


def _assemble(*args, **kwargs):
    """:func:`phc.discretize.fem1d.assemble` (imported on first use, see :func:`_splu`)."""
    from phc.discretize.fem1d import assemble as fem_assemble

    return fem_assemble(*args, **kwargs)


def register(b, name: str, spec, mesh: Mesh, fields: Optional[dict], rigid=None) -> None:
    """Called by the lowerers of distributed components (`fields` from
    :func:`phc.library.beams._lower_partitioned`, None for a modally reduced component)."""
    flat = None
    if fields is not None:
        flat = {local: (fld.space, tuple(x.name for x in fld.x), tuple(fld.e), coeff)
                for local, (fld, coeff) in fields.items()}
    variables = tuple(getattr(spec, "variables", ()) or ())
    b.initial_fields[name] = FieldSet(name, spec.type, mesh, flat, variables, rigid)


def field_names(fs: FieldSet) -> dict[str, str]:
    entry = find(fs.type)
    if entry is not None and entry.initial_fields.from_variables:
        return {v: f"energy variable `{v}`" for v in fs.variables}
    return FIELDS.get(fs.type, {})


# -- numerics ---------------------------------------------------------------------------

def _load(space, values: np.ndarray) -> np.ndarray:
    """``∫ g φ_i`` for g given at the Gauss points (elements × gauss)."""
    mesh = space.mesh
    from phc.discretize.fem1d import _GAUSS_W

    local = np.einsum("ag,eg,g->ea", space.values(0), values, mesh.h * _GAUSS_W)
    out = np.zeros(space.size)
    np.add.at(out, space.dofs().ravel(), local.ravel())
    return out


def project(space, g, weight=None, keep: Optional[np.ndarray] = None) -> np.ndarray:
    """Coefficients x of the L2 projection of ``g`` onto `space` in the inner product
    weighted by ``weight(ξ)`` (None: 1): ``∫ w x_h φ = ∫ w g φ``. `g` and `weight` are
    vectorized functions of ξ. `keep`: the dofs that may be non-zero (the others are 0:
    the projection onto that subspace)."""
    xq = space.mesh.quadrature_points()
    values = np.broadcast_to(np.asarray(g(xq), dtype=float), xq.shape)
    w = None if weight is None else np.broadcast_to(np.asarray(weight(xq), dtype=float), xq.shape)
    rhs = _load(space, values if w is None else w * values)
    M = _assemble(space, 0, space, 0, weight).tocsc()
    x = np.zeros(space.size)
    idx = np.arange(space.size) if keep is None else keep
    x[idx] = _splu(M[idx][:, idx].tocsc()).solve(rhs[idx])
    return x


def trace_dofs(space) -> list[tuple[int, float, int]]:
    """The dofs that are the traces of a continuous space at the ends: (dof, ξ, derivative);
    none for the discontinuous spaces (P0, DP1), whose values are not what a port sees."""
    from phc.discretize.fem1d import H3

    L, n = space.mesh.length, space.mesh.elements
    if isinstance(space, H3):
        return [(0, 0.0, 0), (1, 0.0, 1), (2 * n, L, 0), (2 * n + 1, L, 1)]
    if type(space).__name__ == "P1":
        return [(0, 0.0, 0), (n, L, 0)]
    return []


def project_traces(space, g, traces: dict) -> np.ndarray:
    """The L2 projection of ``g`` onto `space` whose end traces are given: the coefficients
    x with ``x_k = traces[k]`` for the trace dofs k and ``∫ x_h φ_i = ∫ g φ_i`` for all other
    basis functions φ_i. Like :func:`project` it reproduces every function of the space
    (its traces are its end dofs), with the same order of accuracy."""
    xq = space.mesh.quadrature_points()
    values = np.broadcast_to(np.asarray(g(xq), dtype=float), xq.shape)
    rhs = _load(space, values)
    M = _assemble(space, 0, space, 0).tocsc()
    x = np.zeros(space.size)
    fixed = np.array(sorted(traces), dtype=np.int64)
    x[fixed] = [traces[k] for k in fixed]
    keep = np.setdiff1d(np.arange(space.size), fixed)
    if len(keep):
        rhs = rhs - M @ x
        x[keep] = _splu(M[keep][:, keep].tocsc()).solve(rhs[keep])
    return x


# -- the pass ---------------------------------------------------------------------------

class _FieldError(Exception):
    def __init__(self, code, message, hint=None, path_suffix=()):
        super().__init__(message)
        self.code, self.message, self.hint, self.path_suffix = code, message, hint, path_suffix


class FieldInitializer:
    """Used by :func:`phc.ir.assemble._initial_values`: checks per-dof values against the mesh
    they were written for and turns fields into per-dof initial values (and, for the moving
    beam's velocity, initial relations with a right-hand side)."""

    def __init__(self, elab, reporter, ctx):
        """`elab`: the :class:`phc.frontend.elaborate.Elaboration` assembled (only read); problems go
        to `reporter` (a :class:`phc.frontend.reporter.Reporter`)."""
        self.reporter, self.ctx = reporter, ctx
        self.defaults = dict(elab.default_values)
        self.sets: dict[str, FieldSet] = dict(getattr(elab, "initial_fields", {}) or {})
        self.written: dict = dict(getattr(elab, "written_meshes", {}) or {})
        self.meshes = dict(elab.meshes)
        self.scene = elab.scene
        self.initial_relations: tuple = tuple(elab.initial_relations)
        """The elaboration's initial relations, as the fields applied change them."""
        self.compile_time_parameters: frozenset = frozenset(elab.compile_time_parameters)
        """The elaboration's compile-time parameters, with those the fields applied use."""
        self.extra_compile_time: set = set()
        self._reported: set = set()

    # -- per-dof values -------------------------------------------------------------
    def _owner(self, name: str):
        """(component, local) when `name` is a dof of a registered field, else None."""
        m = _DOF.match(name)
        if not m:
            return None
        comp, local = m.group(1), m.group(2)
        fs = self.sets.get(comp)
        if fs is None or fs.fields is None or local not in fs.fields:
            return None
        return comp, local

    def written_for(self, name: str, comp: str) -> tuple[int, str]:
        """The element count per-dof values of `comp` were written for, and where."""
        scene = self.scene
        if scene is not None and name in scene.spec.initial:
            mesh = getattr(scene, "written_mesh", None)
            mesh = scene.spec.accuracy.mesh if mesh is None else mesh
            if comp in mesh:
                return mesh[comp], "the scene's `accuracy.mesh`"
        return self.written.get(comp, self.meshes[comp][1]), "the model file"

    def check_dof(self, name: str, path) -> bool:
        """False for a per-dof value on a mesh other than its own; the first such value of
        a component gets the located PHC-E214 (naming how many there are)."""
        owner = self._owner(name)
        if owner is None or owner[0] not in self.meshes:
            return True
        comp, local = owner
        compiled = self.meshes[comp][1]
        written, where = self.written_for(name, comp)
        if written == compiled:
            return True
        if comp in self._reported:
            return False
        self._reported.add(comp)
        others = [k for k in self.ctx.spec.simulation.initial if k != name and (self._owner(k) or ("",))[0] == comp]
        more = f" (and {len(others)} more)" if others else ""
        fs = self.sets[comp]
        names = list(field_names(fs))
        suggest = local if fs.type == "moving_beam" else _SUGGEST.get(local, local)  # its `velocity` is elastic only
        example = suggest if suggest in names else (names[0] if names else local)
        self.reporter.error(
            "PHC-E214",
            f"`{name}`{more} is given per degree of freedom for the {written}-element mesh of `{comp}` in {where}, "
            f"but this run compiles `{comp}` with {compiled} elements (a scene's `accuracy.mesh`, `--mesh`, or the "
            "refinement of `--estimate-error` or `phc bench`); on another mesh the same numbers are another state",
            self.ctx, ("simulation", "initial", name), key=True,
            hint=f"give the initial state as a field of `xi` instead, e.g. `{comp}.{example}: \"...xi...\"` "
                 f"(fields of a {fs.type}: {', '.join(names)}; docs/how-to/initial-fields.md)")
        return False

    # -- fields -----------------------------------------------------------------------
    def field_key(self, name: str):
        """(FieldSet, field) when `name` is `component.field` of a registered component."""
        if "." not in name or name.endswith("]"):
            return None
        comp, field = name.rsplit(".", 1)
        fs = self.sets.get(comp)
        return None if fs is None else (fs, field)

    def apply(self, entries: list, out: list[InitialValue]) -> list[InitialValue]:
        """`entries`: (name, spec) of the field keys; `out`: the per-dof values found.
        Returns all initial values; updates :attr:`initial_relations` and
        :attr:`compile_time_parameters`."""
        by_comp: dict[str, dict] = {}
        for name, spec in entries:
            fs, field = self.field_key(name)
            path = ("simulation", "initial", name)
            known = field_names(fs)
            if field not in known:
                self.reporter.error("PHC-E215", f"`{field}` is not an initial field of the {fs.type} `{fs.component}`",
                             self.ctx, path, key=True,
                             hint=f"fields of a {fs.type}: " + ", ".join(f"`{k}`" for k in known)
                             + " (docs/how-to/initial-fields.md)")
                continue
            if fs.fields is None:
                self.reporter.error("PHC-E215", f"initial fields of `{fs.component}` need its full discretization, but "
                             "effect `modes` reduces it to modal coordinates", self.ctx, path, key=True,
                             hint=f"drop `modes` for this run, or instead of `{name}` give values of its modal "
                             f"coordinates `{fs.component}.za[i]` (the boundary dofs, then the kept modes) and "
                             f"`{fs.component}.zb[i]`, one a line in `initial:`, e.g. `{fs.component}.za[0]: 0.0`")
                continue
            by_comp.setdefault(fs.component, {})[field] = (name, spec, path)
        dof_names = {iv.name for iv in out}
        for comp, given in by_comp.items():
            fs = self.sets[comp]
            try:
                values, relations, drop = self._component(fs, given)
            except _FieldError as err:
                if not err.code:
                    continue  # reported where the expression is
                name, _, path = next(iter(given.values())) if not err.path_suffix else given[err.path_suffix[0]]
                self.reporter.error(err.code, err.message, self.ctx, path, hint=err.hint)
                continue
            for iv in values:
                if iv.name in dof_names:
                    self.reporter.error("PHC-E215", f"`{iv.name}` is given per dof and by an initial field of `{comp}`",
                                 self.ctx, ("simulation", "initial", iv.name), key=True,
                                 hint="give either the field or the values per dof")
                    continue
                out.append(iv)
            if drop or relations:
                kept = [r for r in self.initial_relations if not any(r[0].startswith(d) for d in drop)]
                self.initial_relations = tuple(kept) + tuple(relations)
        if self.extra_compile_time:
            self.compile_time_parameters = self.compile_time_parameters | self.extra_compile_time
        return out

    def _expr(self, value, path) -> Optional[sp.Expr]:
        n = len(self.reporter.diags.errors)
        ex = self.reporter.expr(self.ctx, value, path, {"xi": XI, **self.ctx.params})
        return None if len(self.reporter.diags.errors) > n else ex

    def _component(self, fs: FieldSet, given: dict):
        """Per-dof values, relations and relation-label prefixes to drop for one component."""
        exprs, guesses, spans = {}, {}, {}
        for field, (name, spec, path) in given.items():
            value, guess = (spec.value, spec.guess) if isinstance(spec, InitialSpec) else (spec, False)
            vpath = (*path, "value") if isinstance(spec, InitialSpec) else path
            ex = self._expr(value, vpath)
            if ex is None:
                raise _Silent()
            exprs[field], guesses[field], spans[field] = ex, guess, self.ctx.smap.locate(vpath)
        for field, ex in exprs.items():
            if not guesses[field]:
                self._check_pins(fs, field, ex)
        d = lambda ex, k=1: sp.diff(ex, XI, k)  # noqa: E731
        targets = []  # (field it comes from, local, kind "state"|"coenergy", expression)
        t = fs.type
        if t == "pde1d":
            targets = [(f, f, "state", ex) for f, ex in exprs.items()]
        elif t == "string":
            m = {"w": ("eps", "state", 1), "eps": ("eps", "state", 0), "velocity": ("p", "coenergy", 0),
                 "p": ("p", "state", 0)}
            targets = [(f, m[f][0], m[f][1], d(ex, m[f][2]) if m[f][2] else ex) for f, ex in exprs.items()]
        elif t == "euler_bernoulli_beam":
            m = {"w": ("kappa", "state", 2), "kappa": ("kappa", "state", 0), "velocity": ("p", "coenergy", 0),
                 "p": ("p", "state", 0)}
            targets = [(f, m[f][0], m[f][1], d(ex, m[f][2]) if m[f][2] else ex) for f, ex in exprs.items()]
        elif t == "timoshenko_beam":
            if "phi" in exprs and "w" not in exprs:
                raise _FieldError("PHC-E215", "`phi` (the rotation of the cross-sections) is given without `w`",
                                  "give the deflection `w` too (`w: 0` for none)", ("phi",))
            for f, ex in exprs.items():
                if f == "w":
                    phi = exprs.get("phi", d(ex))
                    targets += [("w", "gamma", "derived", d(ex) - phi), ("w", "theta", "state", d(phi))]
                elif f in ("p", "M", "gamma", "theta"):
                    targets.append((f, f, "state", ex))
                elif f == "velocity":
                    targets.append((f, "p", "coenergy", ex))
                elif f == "angular_velocity":
                    targets.append((f, "M", "coenergy", ex))
        elif t == "moving_beam":
            for f, ex in exprs.items():
                if f in ("w", "velocity"):
                    self._ends_vanish(fs, f, ex)
                if f == "w":
                    targets.append(("w", "kappa", "state", d(ex, 2)))
                elif f == "kappa":
                    targets.append(("kappa", "kappa", "state", ex))
                elif f == "p":
                    if "velocity" in exprs:
                        raise _FieldError("PHC-E215", f"the fields `p` and `velocity` both set `{fs.component}.p`",
                                          "give one of them: `p` the whole momentum, `velocity` the elastic part",
                                          ("velocity",))
                    targets.append(("p", "p", "state", ex))
                elif f == "u":
                    targets.append(("u", "eps", "state", d(ex)))
                elif f == "eps":
                    targets.append(("eps", "eps", "state", ex))
                elif f == "axial_velocity" and "pa" not in fs.fields:
                    raise _FieldError("PHC-E215", f"`{fs.component}` has no axial velocity field: effect `axial` "
                                      "is off", "turn `axial` on (with `EA`), or drop the field", (f,))
        seen: dict[str, str] = {}
        values: list[InitialValue] = []
        for field, local, kind, ex in targets:
            if local not in fs.fields or fs.fields[local][3] is None:
                if kind == "derived":
                    continue  # e.g. the shear strain of a beam whose shear is off: no state
                raise _FieldError("PHC-E215", f"`{fs.component}` has no `{local}` states here (an effect that "
                                  f"is off removed them), so the field `{field}` cannot be set",
                                  "turn the effect on, or drop the field", (field,))
            if local in seen:
                raise _FieldError("PHC-E215", f"the fields `{seen[local]}` and `{field}` both set `{fs.component}."
                                  f"{local}`", "give one of them", (field,))
            seen[local] = field
            if ex.has(sp.DiracDelta):
                raise _FieldError("PHC-E215", f"the field `{field}` of `{fs.component}` is not differentiable "
                                  f"enough: `{local}` would be a Dirac delta", "give a smooth field, or the "
                                  f"`{local}` field itself", (field,))
            values += self._project(fs, field, local, "coenergy" if kind == "coenergy" else "state", ex,
                                    guesses[field], spans[field])
        relations, drop = [], []
        if t == "moving_beam":
            if "w" in exprs or "kappa" in exprs:
                drop.append(f"{fs.component}.straight_start")
            if "velocity" in exprs or "p" in exprs:
                drop += [f"{fs.component}.rigid_start.value", f"{fs.component}.rigid_start.slope"]
            if "velocity" in exprs:
                relations = self._moving_velocity(fs, exprs["velocity"])
            if "u" in exprs or "eps" in exprs:
                drop.append(f"{fs.component}.unstretched_start")
            if "axial_velocity" in exprs:
                drop.append(f"{fs.component}.rigid_start.axial")
                relations = relations + self._axial_velocity(fs, exprs["axial_velocity"])
        return values, relations, drop

    def _check_pins(self, fs, field, ex) -> None:
        """A fixed velocity field must vanish where the component's end is pinned: a port of
        the component connected directly to a `zero_flow` source (its flow, the end's velocity
        or angular velocity, is zero). The field's end traces are kept exactly by the
        projection (:meth:`_project_with_traces`), so a field that meets the pin gives dofs
        that meet it; one that does not is this located error instead of rows the
        consistent initialization reports as violated. (Other ways of holding an end still
        reach the consistent initialization, which names the violated rows.)"""
        checks = _PIN_TRACES.get(fs.type, {}).get(field)
        if not checks:
            return
        pinned = self._pins(fs.component)
        if not pinned:
            return
        L = fs.mesh.length
        try:
            f = self._numeric(ex)
            scale = float(np.abs(f(fs.mesh.quadrature_points())).max(initial=0.0))
            df = self._numeric(sp.diff(ex, XI)) if any(der for _, _, der in checks) else None
        except (_FieldError, NameError, TypeError, ValueError, KeyError):
            return  # reported (or not checkable) elsewhere
        for port, end, der in checks:
            if port not in pinned:
                continue
            at = np.array([0.0 if end == "a" else L])
            try:
                value = float((f if der == 0 else df)(at)[0])
            except (_FieldError, TypeError, ValueError):
                continue
            ref = scale if der == 0 else scale / L
            if abs(value) > 1e-9 * max(ref, 1e-300) and abs(value) > 1e-300:
                where = "ξ = 0" if end == "a" else "ξ = L"
                what = "its slope" if der else "it"
                flow = "angular velocity" if der or field in ("angular_velocity", "M") else "velocity"
                raise _FieldError(
                    "PHC-E215", f"the initial field `{fs.component}.{field}` does not meet the pin at the end "
                    f"`{fs.component}.{port}`: {what} is {value:.3g} at {where}, but `{pinned[port]}` (a zero_flow "
                    f"source) holds the {flow} of that end at 0",
                    f"give a field {'whose slope vanishes' if der else 'that vanishes'} at {where}, or mark it a guess "
                    f"(`{fs.component}.{field}: {{value: ..., guess: true}}`): phc then changes it only where the "
                    "pin demands", (field,))

    def _pins(self, comp: str) -> dict:
        """Ports of `comp` connected directly to a `zero_flow` source: port → source."""
        spec = self.ctx.spec
        types = {name: getattr(c, "type", None) for name, c in (getattr(spec, "components", {}) or {}).items()}
        out = {}
        for conn in getattr(spec, "connections", []) or []:
            ends = [tuple(x.rsplit(".", 1)) for x in conn.between if "." in x]
            if len(ends) != 2:
                continue
            for (c1, p1), (c2, _) in (ends, ends[::-1]):
                if c1 == comp and types.get(c2) == "zero_flow":
                    out[p1] = c2
        return out

    def _ends_vanish(self, fs, field, ex, ends_checked=(0, 1)):
        f = self._numeric(ex)
        L = fs.mesh.length
        ends = np.broadcast_to(np.asarray(f(np.array([0.0, L])), dtype=float).ravel(), (2,))[list(ends_checked)]
        scale = float(np.abs(np.asarray(f(fs.mesh.quadrature_points()), dtype=float)).max(initial=0.0))
        if np.abs(ends).max() > 1e-9 * max(scale, 1e-300) and np.abs(ends).max() > 1e-300:
            if field == "axial_velocity":
                raise _FieldError(
                    "PHC-E215", f"`{fs.component}.axial_velocity` is the axial velocity relative to the end ξ = 0, "
                    f"which is zero there; this field is {ends[0]:.3g} at ξ = 0",
                    "subtract its value at ξ = 0; the mechanism decides the end's motion", (field,))
            what = "elastic deflection from the chord" if field == "w" else \
                "elastic velocity relative to the chord's rigid motion"
            raise _FieldError(
                "PHC-E215", f"`{fs.component}.{field}` is the {what}, which is zero at both ends; this field is "
                f"{ends[0]:.3g} at ξ = 0 and {ends[1]:.3g} at ξ = L",
                "subtract the rigid part (the straight line between the end values); the mechanism decides "
                "the ends' motion", (field,))

    def _numeric(self, ex: sp.Expr):
        """A vectorized numeric function of ξ: parameters at their defaults (they become
        compile-time parameters)."""
        params = ex.free_symbols - {XI}
        self.extra_compile_time |= params
        numeric = ex.xreplace(dict(self.defaults))
        if numeric.free_symbols - {XI}:
            raise _FieldError("PHC-E215", "an initial field may depend on `xi` and parameters only",
                              "remove the other names")
        # safe: lambdify prints a sympy tree built by the whitelisting parser with the
        # parameters substituted by numbers; its only symbol is `xi`, never user text.
        fn = sp.lambdify(XI, numeric, modules="numpy")

        def call(x):
            with np.errstate(all="ignore"):
                v = np.broadcast_to(np.asarray(fn(x), dtype=float), np.shape(x))
            if not np.all(np.isfinite(v)):
                bad = np.asarray(x)[~np.isfinite(v)].ravel()[0]
                raise _FieldError("PHC-E215", f"the initial field is not finite at ξ = {bad:.6g}",
                                  "give a field that is finite on [0, L]")
            return v
        return call

    def _project(self, fs, field, local, kind, ex, guess, span) -> list[InitialValue]:
        space, states, _, coeff = fs.fields[local]
        # Split into Σ a_k(parameters) g_k(ξ): the a_k stay run-time parameters.
        terms = []
        for term in sp.Add.make_args(sp.expand(ex, deep=False, mul=True, power_exp=False, power_base=False,
                                               log=False, multinomial=False)):
            a, g = term.as_independent(XI, as_Add=False)
            terms.append((a, g))
        varies = coeff is not None and coeff.varies
        weight = coeff.function() if varies else None
        scale = sp.Integer(1)
        if kind == "coenergy" and not varies:
            scale = 1 / coeff.scale()  # ∫ c p φ = ∫ v φ with c constant: p = M⁻¹∫vφ / c
        defaults = dict(self.defaults)
        total_num = np.zeros(space.size)
        symbolic: list = []
        ends = trace_dofs(space)
        for a, g in terms:
            f = self._numeric(g)
            if ends:
                x = self._project_with_traces(space, ends, g, f, kind, coeff if varies else None)
            elif kind == "coenergy" and varies:
                x = _project_coenergy(space, f, weight)
            else:
                x = project(space, f, weight=weight)
            coef = a * scale
            try:
                c_num = float(coef.xreplace(defaults))
            except TypeError:
                raise _FieldError("PHC-E215", f"the field `{field}` must be a function of `xi` and parameters",
                                  None, (field,)) from None
            total_num += c_num * x
            symbolic.append((coef, x))
        run_time = any(not c.is_Number for c, _ in symbolic)
        out = []
        for i, name in enumerate(states):
            expr = None
            if run_time:  # unevaluated: sympy's Mul would spend ~1 ms per dof on assumptions
                parts = [sp.Mul(sp.Float(float(x[i])), c, evaluate=False) for c, x in symbolic]
                expr = parts[0] if len(parts) == 1 else sp.Add(*parts, evaluate=False)
            out.append(InitialValue(name, float(total_num[i]), guess, span, expr))
        return out

    def _project_with_traces(self, space, ends, g, f, kind, coeff) -> np.ndarray:
        """The coefficients x of the field term `g` (numeric `f`) on a continuous space whose
        discrete co-energy ``e_h`` has the field's end traces (:func:`project_traces`).

        The co-energy density of the term is ``q = g`` for a velocity (`kind` "coenergy") and
        ``q = c g`` for a state (c the energy coefficient; 1 when it is constant: its factor
        is applied by the caller); ``e_h`` is the trace-keeping projection of q, and
        ``x = M_c⁻¹ M e_h`` (x = e_h when c is constant). Without varying c this is
        ``∫ c x_h φ = ∫ q φ`` on the interior test functions, as :func:`project`."""
        weight = None if coeff is None else coeff.function()
        dg = None
        if any(d for _, _, d in ends):
            try:
                dg = self._numeric(sp.diff(g, XI))
            except (_FieldError, NameError, TypeError, ValueError, KeyError):
                dg = None  # a slope that is not finite at some ξ: keep the plain projection there
        dw = None
        if weight is not None and kind == "state" and any(d for _, _, d in ends):
            dw_ex = sp.diff(coeff.expr.xreplace(dict(self.defaults)), XI)
            dw_fn = sp.lambdify(XI, dw_ex, modules="numpy")  # safe: a derivative of a parsed coefficient
            dw = lambda x: np.broadcast_to(np.asarray(dw_fn(x), dtype=float), np.shape(x))  # noqa: E731

        def q(x):
            v = f(x)
            return v if weight is None or kind == "coenergy" else weight(np.asarray(x, dtype=float)) * v

        traces = {}
        for dof, at, der in ends:
            pt = np.array([at])
            try:
                if der == 0:
                    value = float(q(pt)[0])
                elif dg is None:
                    continue
                elif weight is None or kind == "coenergy":
                    value = float(dg(pt)[0])
                else:
                    value = float(dw(pt)[0] * f(pt)[0] + weight(pt)[0] * dg(pt)[0])
            except (_FieldError, NameError, TypeError, ValueError, ZeroDivisionError):
                continue
            if np.isfinite(value):
                traces[dof] = value
        e = project_traces(space, q, traces)
        if weight is None:
            return e
        M = _assemble(space, 0, space, 0).tocsc()
        return _splu(_assemble(space, 0, space, 0, weight).tocsc()).solve(M @ e)

    def _axial_velocity(self, fs, ex) -> list:
        """Relations ``e_a(ξ_i) − e_a(0) = u̇_h(ξ_i)`` (axial velocity relative to the end ξ = 0)."""
        self._ends_vanish(fs, "axial_velocity", ex, ends_checked=(0,))
        space, _, e, _ = fs.fields["pa"]
        c = project(space, self._numeric(ex), keep=np.arange(1, space.size))
        return [(f"{fs.component}.axial_velocity[{i}]", {e[i]: 1.0, e[0]: -1.0}, float(c[i]))
                for i in range(1, space.size)]

    def _moving_velocity(self, fs, ex) -> list:
        """Relations ``e_p = rigid(v0, vL) + ẇ_h`` (interior node values, all node slopes)."""
        space, _, e, _ = fs.fields["p"]
        n = fs.mesh.elements
        L = fs.mesh.length
        keep = np.array([j for j in range(space.size) if j not in (0, 2 * n)])
        c = project(space, self._numeric(ex), keep=keep)
        v0, vL = fs.rigid
        comp = fs.component
        rel = []
        for i in range(1, n):
            frac = float(fs.mesh.nodes[i] / L)
            rel.append((f"{comp}.elastic_velocity.value[{i}]", {e[2 * i]: 1.0, v0: -(1.0 - frac), vL: -frac},
                        float(c[2 * i])))
        for i in range(n + 1):
            rel.append((f"{comp}.elastic_velocity.slope[{i}]", {e[2 * i + 1]: 1.0, vL: -1.0 / L, v0: 1.0 / L},
                        float(c[2 * i + 1])))
        return rel


def evaluate(expr: sp.Expr, by_name: dict, memo: dict) -> float:
    """The value of an initial value's parameter expression at `by_name` (parameter symbol →
    number). A field's dof is ``Σ_k x_ik · c_k(parameters)`` (unevaluated sympy, built by
    :meth:`FieldInitializer._project`) with the same ``c_k`` for all dofs of the field: each
    ``c_k`` is evaluated once per call site (`memo`), not once per dof (~0.4 ms in sympy)."""
    terms = expr.args if isinstance(expr, sp.Add) else (expr,)
    if all(isinstance(t, sp.Mul) and len(t.args) == 2 and isinstance(t.args[0], sp.Float) for t in terms):
        total = 0.0
        for t in terms:
            c = t.args[1]
            if c not in memo:
                memo[c] = float(c.xreplace(by_name))
            total += float(t.args[0]) * memo[c]
        return total
    return float(expr.xreplace(by_name))


class _Silent(_FieldError):
    """An error already reported (in the expression)."""

    def __init__(self):
        super().__init__("", "")


def _project_coenergy(space, v, weight):
    """p with ``∫ c p_h φ = ∫ v φ`` (c = `weight`, the energy coefficient of p)."""
    xq = space.mesh.quadrature_points()
    rhs = _load(space, np.broadcast_to(np.asarray(v(xq), dtype=float), xq.shape))
    M = _assemble(space, 0, space, 0, weight).tocsc()
    return _splu(M).solve(rhs)


__all__ = ["FIELDS", "FieldSet", "FieldInitializer", "evaluate", "project", "project_traces", "register",
           "trace_dofs"]
