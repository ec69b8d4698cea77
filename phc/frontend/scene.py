"""Scenes: read a scene file and apply it to its model before elaboration.

A scene (:class:`~phc.spec.scene.SceneSpec`) changes what is compiled, not the model file:

* parameter overrides of the model's top-level parameters;
* effects per component and mesh sizes (applied when each component is lowered by the
  elaborate pass, :mod:`phc.frontend.elaborate`);
* the simulation settings — time span, initial values and inputs (merged over the
  model's), outputs (replacing the model's), tolerances, step and solver;
* pruning: components that cannot influence the requested outputs are not lowered at
  all. The interconnection graph (:mod:`phc.ir.interconnect`) has the top-level components
  as nodes and an edge per connection (and from a modulation to each component whose
  states it reads); a component is kept when its connected part contains a component an
  output refers to. Power ports couple both ways, so a part with no path to an output
  cannot change it.
  Outputs that use `H` (the total energy) keep everything.

Diagnostics about what the scene wrote point into the scene file: the model's source map
is overlaid by the scene's for the entries the scene provides.
"""

from __future__ import annotations

import os
import re
from dataclasses import dataclass, field
from pathlib import Path
from types import MappingProxyType
from typing import Any, Mapping, Optional

import pydantic

from phc.diagnostics import Diagnostic, DiagnosticList, allowed_keys_from_model, from_pydantic
from phc.ir.interconnect import connected_to
from phc.frontend.source import SourceMap, SourceSpan, _read_parsed, read_yaml_file
from phc.frontend.source_map import path_text
from phc.spec.scene import SceneSpec

_ALLOWED_KEYS = allowed_keys_from_model(SceneSpec)
_REFERENCE = re.compile(r"(?<![\w.])([A-Za-z][A-Za-z0-9_]*)\.[A-Za-z_]")
_NAME = re.compile(r"(?<![\w.])([A-Za-z][A-Za-z0-9_]*)(?![\w.(])")


def is_scene_file(path: str | os.PathLike) -> bool:
    """True when the YAML file is a scene (it names a `model` and has no `components`)."""
    data, _, problems = _read_parsed(path)  # read only: shared with the run's other reads of the file
    return not problems and isinstance(data, dict) and "model" in data and "components" not in data


@dataclass(frozen=True)
class SceneApplication:
    """What applying a scene to its model gives the elaborate pass (:meth:`Scene.apply`)."""

    spec: Any
    """The model's spec with the scene's simulation settings (and pruned exposed ports)."""
    smap: Any
    """The model's source map overlaid by the scene's for the entries the scene provides."""
    effects: Mapping[str, tuple[dict, Optional[SourceSpan]]] = field(default_factory=dict)
    """Component -> (its effects as the scene sets them, where)."""
    meshes: Mapping[str, tuple[int, Optional[SourceSpan]]] = field(default_factory=dict)
    """Distributed component -> (`elements` from the scene's `accuracy.mesh`, where)."""
    shapes: Mapping[str, tuple[str, Optional[SourceSpan]]] = field(default_factory=dict)
    """Moving beam -> (the scene's `initial_shape`, where)."""
    skip: frozenset = frozenset()
    """Top-level components pruned (not lowered)."""
    left_out: tuple[tuple[str, str, str], ...] = ()
    """(component, what, why) of what is pruned."""
    diagnostics: tuple[Diagnostic, ...] = ()


@dataclass
class Scene:
    """A validated scene file."""

    path: Path
    spec: SceneSpec
    smap: SourceMap
    left_out: list[tuple[str, str, str]] = field(default_factory=list)
    written_mesh: Optional[dict[str, int]] = None
    """The `accuracy.mesh` of the scene file as written (None: `spec.accuracy.mesh`); a
    refined variant keeps it, so per-dof initial values in the scene are known to belong
    to it (:mod:`phc.ir.initial_fields`)."""
    reference_values: Optional[Any] = None
    """The scene's `reference_values`, read and checked when the scene is applied
    (:class:`phc.frontend.reference_values.ReferenceValues`)."""

    @property
    def model_path(self) -> Path:
        """The model file, relative to the scene's directory, normalized as messages show
        it (`scenes/../m.yaml` is `m.yaml`) unless a symbolic link makes `..` lead elsewhere."""
        written = self.path.parent / self.spec.model
        normal = Path(os.path.normpath(written))
        try:  # the directories, so that a missing model file is named normalized too
            return normal if normal == written or os.path.samefile(normal.parent, written.parent) else written
        except OSError:  # a directory is missing: the path as written
            return written

    @property
    def name(self) -> str:
        return self.spec.name or self.path.stem

    def locate(self, *path) -> SourceSpan:
        return self.smap.locate(tuple(path))

    # -- application --------------------------------------------------------------------
    def apply(self, files, spec, smap) -> "SceneApplication":
        """What the elaborate pass elaborates for this scene: the model spec and source map
        with the scene's settings, the effect, mesh and shape overrides, the components
        to leave out and the problems found (:class:`SceneApplication`). `files` is the
        :class:`~phc.frontend.files.FileAccess` that the scene's reference values are read through."""
        s = self.spec
        diags: list[Diagnostic] = []
        left_out: list[tuple[str, str, str]] = []
        sim = spec.simulation
        update: dict[str, Any] = {}
        for key in ("t_start", "t_end", "n_out", "solver"):
            if getattr(s, key) is not None:
                update[key] = getattr(s, key)
        for key in ("rtol", "atol", "step", "max_order"):
            if getattr(s.accuracy, key) is not None:
                update[key] = getattr(s.accuracy, key)
        update["initial"] = {**sim.initial, **s.initial}
        update["nominal"] = {**sim.nominal, **s.nominal}
        update["inputs"] = {**sim.inputs, **s.inputs}
        outputs = dict(s.outputs or sim.outputs)
        requested = list(outputs)
        for name, expr in s.reference.items():  # closed forms ride along as outputs
            if name in requested:
                outputs[reference_name(name)] = expr
            else:
                diags.append(Diagnostic(
                    "PHC-E605", f"reference for `{name}`, which is not a requested output",
                    span=self.smap.locate_key(("reference", name)),
                    hint=f"outputs: {', '.join(requested) or 'none'}"))
        update["outputs"] = outputs
        if s.reference_values is not None:
            diags.extend(self._reference_values(files, sim, update, requested))
        effects = {comp: (dict(given), self.locate("effects", comp)) for comp, given in s.effects.items()}
        meshes = {comp: (elements, self.locate("accuracy", "mesh", comp)) for comp, elements in s.accuracy.mesh.items()}
        shapes = {comp: (shape, self.locate("initial_shape", comp)) for comp, shape in s.initial_shape.items()}
        for comp in list(s.effects) + list(s.accuracy.mesh) + list(s.initial_shape):
            top = comp.split(".", 1)[0]
            if top not in spec.components:
                where = (("effects", comp) if comp in s.effects else ("accuracy", "mesh", comp)
                         if comp in s.accuracy.mesh else ("initial_shape", comp))
                diags.append(Diagnostic(
                    "PHC-E602", f"the model has no component `{top}`", span=self.smap.locate_key(where),
                    hint=f"components: {', '.join(spec.components)}"))
        skip: set[str] = set()
        if s.prune and outputs:
            skip, reason = _prune(spec, outputs)
            left_out.extend((comp, "the whole component", reason) for comp in sorted(skip))
            diags.extend(self._unused(skip))
            update["nominal"] = {k: v for k, v in update["nominal"].items() if k.split(".", 1)[0] not in skip}
            exposed = {pname for pname, exp in spec.ports.items() if exp.port.split(".", 1)[0] in skip}
            update["inputs"] = {k: v for k, v in update["inputs"].items() if k not in exposed}
            update["initial"] = {k: v for k, v in update["initial"].items() if k.split(".", 1)[0] not in skip}
            spec = spec.model_copy(update={"ports": {k: v for k, v in spec.ports.items() if k not in exposed}})
        new_sim = type(sim).model_validate({**sim.model_dump(exclude_unset=True), **update})
        return SceneApplication(spec.model_copy(update={"simulation": new_sim}), _Overlay(smap, self.smap, s),
                                effects=MappingProxyType(effects), meshes=MappingProxyType(meshes),
                                shapes=MappingProxyType(shapes), skip=frozenset(skip), left_out=tuple(left_out),
                                diagnostics=tuple(diags))


    def _unused(self, skip: set) -> list[Diagnostic]:
        """A warning at each entry of this scene about a component it leaves out (PHC-W608):
        the entry is not used, and a typo in it could not be found."""
        found = []
        s = self.spec
        entries = [(("initial", k), k) for k in s.initial] + [(("nominal", k), k) for k in s.nominal]
        entries += [(("effects", k), k) for k in s.effects] + [(("accuracy", "mesh", k), k) for k in s.accuracy.mesh]
        entries += [(("initial_shape", k), k) for k in s.initial_shape]
        for where, name in entries:
            top = name.split(".", 1)[0]
            if top in skip:
                found.append(Diagnostic(
                    "PHC-W608", f"`{'.'.join(where[:-1])}` of `{name}` is not used: this scene leaves out `{top}`, "
                    "which cannot influence the requested outputs (nor is the entry checked)",
                    span=self.smap.locate_key(where), severity="warning",
                    hint=f"remove the entry, request an output that depends on `{top}`, or set `prune: false`"))
        return found

    def _reference_values(self, files, sim, update, requested) -> list[Diagnostic]:
        """Read and check `reference_values` (PHC-E607 at the file's row or the entry);
        returns the problems found."""
        from phc.frontend import reference_values as refs

        t0 = float(update.get("t_start", sim.t_start))
        t1 = float(update.get("t_end", sim.t_end))
        try:
            rv = refs.for_scene(self, files, requested, t0, t1)
        except refs.ReferenceValuesError as err:
            return [refs.diagnostic(err) if err.span is not None else Diagnostic(
                refs.CODE, err.message, span=self.smap.locate(("reference_values",)), hint=err.hint)]
        both = [name for name in rv.series if name in self.spec.reference]
        if both:
            return [Diagnostic(refs.CODE, f"`{both[0]}` has both a closed form (`reference`) and reference values",
                               span=rv.locations.get(both[0]), hint="give one reference per output")]
        self.reference_values = rv
        return []


def reference_name(output: str) -> str:
    """Name of the output that carries the closed-form reference of `output`."""
    return f"{output}_reference"


def _prune(spec, outputs: dict) -> tuple[set[str], str]:
    """Top-level components not connected to any component the outputs refer to (in the
    interconnection graph of :mod:`phc.ir.interconnect`: connections, and a modulation's
    reads of other components' states)."""
    texts = [str(getattr(v, "value", v)) for v in outputs.values()]
    if any("H" in _NAME.findall(t) for t in texts):
        return set(), ""
    wanted = {m for t in texts for m in _REFERENCE.findall(t) if m in spec.components}
    if not wanted:
        return set(), ""
    keep = connected_to(spec, wanted)
    skip = set(spec.components) - keep
    reason = ("cannot influence the requested outputs (not connected to "
              + ", ".join(f"`{c}`" for c in sorted(wanted)) + ")")
    return skip, reason


class _Overlay:
    """The model's source map, with the scene's entries located in the scene file."""

    _MOVED = {"initial": ("initial",), "nominal": ("nominal",), "inputs": ("inputs",), "outputs": ("outputs",)}

    def __init__(self, model: SourceMap, scene: SourceMap, spec: SceneSpec) -> None:
        self.model, self.scene, self.spec = model, scene, spec

    def __getattr__(self, name):
        return getattr(self.model, name)

    def _route(self, path):
        path = tuple(path)
        if len(path) >= 3 and path[0] == "simulation" and path[1] in self._MOVED:
            moved = (path[1], *path[2:])
            if self.scene.has(moved[:2]):
                return self.scene, moved
            base = str(path[2]).removesuffix("_reference")
            if path[1] == "outputs" and self.scene.has(("reference", base)):
                return self.scene, ("reference", base, *path[3:])
        return self.model, path

    def locate(self, path):
        smap, path = self._route(path)
        return smap.locate(path)

    def dotted(self, path) -> str:
        """The path as the user wrote it (scene entries without the `simulation.` prefix)."""
        smap, routed = self._route(path)
        return smap.dotted(routed)

    def locate_key(self, path):
        smap, path = self._route(path)
        return smap.locate_key(path)

    def locate_in_value(self, path, offset):
        smap, path = self._route(path)
        return smap.locate_in_value(path, offset)


def load_scene(path: str | os.PathLike) -> tuple[Optional[Scene], DiagnosticList]:
    """Read and validate a scene file (its model is read later, by elaboration)."""
    diags = DiagnosticList()
    data, smap, problems = read_yaml_file(path)
    diags.extend(problems)
    if diags.has_errors or smap is None:
        return None, diags
    if not isinstance(data, dict):
        diags.append(Diagnostic("PHC-E013", "a scene file must be a mapping with `model`, `outputs`, ...",
                                span=smap.locate(())))
        return None, diags
    try:
        spec = SceneSpec.model_validate(data)
    except pydantic.ValidationError as err:
        diags.extend(from_pydantic(err, smap, allowed_keys=_ALLOWED_KEYS))
        return None, diags
    scene = Scene(Path(path), spec, smap)
    from phc.frontend.files import FileAccess, FileRefused

    # The scene's model is a referenced file like any other; it may lie in the scene's
    # directory or the one above it (the layout models/scenes/x.yaml -> models/y.yaml).
    here = Path(path).resolve().parent
    try:
        FileAccess([here, here.parent]).resolve(path, spec.model, "model")
    except FileRefused as err:
        if err.reason != "missing":
            message = err.message.replace("nested model file", "model file", 1).replace(
                "the directory of the top-level file", "the scene's directory and the one above it", 1)
            diags.append(Diagnostic("PHC-E116", message, span=smap.locate(("model",)), hint=err.hint))
            return None, diags
    if not scene.model_path.is_file():
        diags.append(Diagnostic("PHC-E107", f"model file `{spec.model}` not found (looked for `{scene.model_path}`)",
                                span=smap.locate(("model",)), hint="the path is relative to the scene file"))
        return None, diags
    return scene, diags


def scene_variant(base: Scene | str | os.PathLike, *, mesh: Optional[dict[str, int]] = None,
                  max_order: Optional[int] = None, parameters: Optional[dict[str, float]] = None) -> Scene:
    """An in-memory variant of a scene, or of a plain model file (wrapped in a scene that
    changes nothing else and prunes nothing): `mesh` merged over its ``accuracy.mesh`` (a
    count here wins), `parameters` over its parameter overrides (for the compile-time
    parameters of ``phc sweep`` and ``phc simulate --param``) and, when given,
    ``accuracy.max_order`` set. Nothing is written; the
    variant keeps the base's path and source map, so its model is found and read as the
    base's is. Compile it with ``compile_model(variant.model_path, scene=variant)``.

    The one way phc refines a mesh: the spatial error estimate
    (:func:`phc.study.accuracy.spatial_estimate`) and the mesh sweep of ``phc bench`` both use it.

    Raises
    ------
    ModelError
        When an element count or the order is out of range (located at the base's
        ``accuracy`` entry).
    """
    from phc.errors import ModelError

    if isinstance(base, Scene):
        path, spec, smap = base.path, base.spec, base.smap
        written = dict(base.spec.accuracy.mesh if base.written_mesh is None else base.written_mesh)
    else:
        path = Path(base)
        spec, smap = SceneSpec(model=path.name, prune=False), SourceMap(str(path), None)
        written = {}
    update: dict[str, Any] = {"mesh": {**spec.accuracy.mesh, **(mesh or {})}}
    if max_order is not None:
        update["max_order"] = max_order
    try:
        accuracy = type(spec.accuracy).model_validate({**spec.accuracy.model_dump(exclude_unset=True), **update})
    except pydantic.ValidationError as err:
        diags = DiagnosticList()
        for e in err.errors(include_url=False):
            entry = path_text(["accuracy", *e["loc"]])
            why = e["msg"][:1].lower() + e["msg"][1:]
            diags.append(Diagnostic(
                "PHC-E019", f"the refined or swept value {e['input']!r} is out of range: {why}",
                span=smap.locate(("accuracy",)), path=entry,
                hint="ask for element counts and an order within the bounds a scene file allows"))
        raise ModelError(diags) from None
    changes: dict[str, Any] = {"accuracy": accuracy}
    if parameters:
        changes["parameters"] = {**spec.parameters, **{k: float(v) for k, v in parameters.items()}}
    return Scene(path, spec.model_copy(update=changes), smap, written_mesh=written)
