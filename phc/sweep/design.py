"""The design of a sweep: swept names, their points, and the compilation groups.

:func:`sweep_axes` reads the swept values (a scene's ``sweep:`` section, then the command
line's ``NAME=SPEC``), :func:`make_design` checks the names against the compiled model
and makes the points (a grid, Latin-hypercube or random samples), and
:func:`compile_group` compiles each group of points that needs other compile-time values
(a mesh, a compile-time parameter) once.
"""

from __future__ import annotations

import itertools
import math
import time
from dataclasses import dataclass
from typing import Any, Optional, Sequence

import numpy as np

from phc.diagnostics import Diagnostic, DiagnosticList
from phc.errors import ModelError, SweepSetupError
from phc.spec.sweep import Axis, SpecError, parse_spec

ACCURACY_OPTIONS = {"accuracy.rtol": "rtol", "accuracy.atol": "atol", "accuracy.step": "step"}
MESH_PREFIX = "accuracy.mesh."
MAX_POINTS = 1_000_000
MAX_SEED = 2**32 - 1
"""The largest seed of the sampler (`--seed`, a scene's `sweep: seed:`)."""


# ---------------------------------------------------------------------------------------
# the design: swept names, points, compilation groups


@dataclass(frozen=True)
class Point:
    index: int
    values: dict
    """Every swept name -> its value at this point (the row's parameter columns)."""
    group: tuple
    """Compilation key: sorted ((name, value), ...) of compile-time parameters and meshes."""
    params: dict
    """Run-time model parameters."""
    options: dict
    """Run-time accuracy options (rtol, atol, step)."""


@dataclass
class Design:
    axes: list[Axis]
    samples: Optional[int]
    seed: int
    sampling: str
    points: list[Point]
    kinds: dict[str, str]
    """name -> `run` (run-time parameter), `compile` (compile-time parameter), `mesh`, `option`."""

    @property
    def groups(self) -> list[tuple]:
        return list(dict.fromkeys(p.group for p in self.points))


def sample_unit(n: int, dims: int, seed: int, sampling: str) -> np.ndarray:
    """`n` points in the unit cube [0, 1)^dims: Latin hypercube (each of the n strata of
    every coordinate holds exactly one point, at a uniformly random place in it) or plain
    uniform random."""
    rng = np.random.default_rng(seed)
    if sampling == "random":
        return rng.random((n, dims))
    u = np.empty((n, dims))
    for j in range(dims):
        u[:, j] = (rng.permutation(n) + rng.random(n)) / n
    return u


def transform(axis: Axis, u: np.ndarray) -> np.ndarray:
    """Unit samples mapped to the axis' distribution (inverse CDF)."""
    if axis.distribution == "uniform":
        return axis.a + (axis.b - axis.a) * u
    if axis.distribution == "loguniform":
        return np.exp(math.log(axis.a) + (math.log(axis.b) - math.log(axis.a)) * u)
    from scipy.special import ndtri

    return axis.a + axis.b * ndtri(np.clip(u, 1e-16, 1 - 1e-16))


def make_design(compiled, axes: Sequence[Axis], samples: Optional[int] = None, seed: int = 0,
                sampling: str = "lhs", locate=None) -> Design:
    """The points of a sweep over `axes` for a compiled base model.

    `locate(name)` gives a span for a name from a scene's ``sweep:`` section (its problems
    are then located diagnostics, raised as ModelError); others raise SweepSetupError.
    """
    mod = compiled.module
    base_names = [mod.PARAMETERS[i] for i in mod.BASE_PARAMETERS]
    compile_time = set(getattr(mod, "COMPILE_TIME_PARAMETERS", ()))
    kinds: dict[str, str] = {}
    problems: list[tuple[str, str, str]] = []
    for axis in axes:
        name = axis.name
        if name in ACCURACY_OPTIONS:
            kinds[name] = "option"
            if any(v <= 0 for v in axis.values) or (axis.sampled and axis.distribution == "normal"):
                problems.append((name, f"`{name}` must be positive (give a grid, a list or a uniform or "
                                       "log-uniform distribution of positive values)", ""))
        elif name.startswith(MESH_PREFIX):
            kinds[name] = "mesh"
            comp = name[len(MESH_PREFIX):]
            meshes = getattr(compiled.dae, "meshes", {}) or {}
            if axis.sampled:
                problems.append((name, "element counts are swept on a grid or a list, not sampled", ""))
            elif any(v != int(v) or not 1 <= v <= 200_000 for v in axis.values):
                problems.append((name, "element counts must be whole numbers from 1 to 200000", ""))
            elif comp not in meshes:
                problems.append((name, f"`{comp}` is not a distributed component of the model",
                                 f"meshed components: {', '.join(sorted(meshes))}" if meshes else
                                 "the model has no distributed component"))
        elif name in base_names:
            kinds[name] = "compile" if name in compile_time else "run"
            if name in compile_time and "." in name:
                problems.append((name, f"`{name}` is used at compile time inside a nested model; only top-level "
                                       "compile-time parameters can be swept", "sweep a top-level parameter it is "
                                       "derived from, or change it in the model"))
        elif name in mod.PARAMETERS:
            problems.append((name, f"parameter `{name}` is derived from other parameters", "sweep those instead"))
        else:
            import difflib

            close = difflib.get_close_matches(name, base_names + list(ACCURACY_OPTIONS), n=1)
            problems.append((name, f"unknown parameter `{name}`",
                             f"did you mean `{close[0]}`?" if close else
                             f"the model's parameters are {', '.join(base_names) or 'none'}; also "
                             "accuracy.rtol, accuracy.atol, accuracy.step, accuracy.mesh.COMPONENT"))
    problems.extend(_column_clashes(compiled, [a for a in axes if a.name in kinds]))
    if len({a.name for a in axes}) != len(axes):
        dup = next(a.name for a in axes if sum(b.name == a.name for b in axes) > 1)
        problems.append((dup, f"`{dup}` is swept twice", "give each name once"))
    sampled = [a for a in axes if a.sampled]
    if sampled and not samples:
        problems.append((sampled[0].name, f"`{sampled[0].name}` is a distribution but no number of samples is given",
                         "add --samples N (or `samples:` in the scene's sweep section)"))
    if samples and not sampled:
        problems.append(("", "--samples is given but no parameter is a distribution",
                         "write e.g. NAME=uniform:A:B, NAME=normal:MEAN:STD or NAME=loguniform:A:B"))
    if not (isinstance(seed, int) and 0 <= seed <= MAX_SEED):
        problems.append(("", f"the sampler's seed must be a whole number from 0 to {MAX_SEED}, got {seed}",
                         "--seed N, or `seed:` in the scene's sweep section"))
    if sampling not in ("lhs", "random"):
        problems.append(("", f"unknown sampling `{sampling}`", "choose lhs or random"))
    grid = [a for a in axes if not a.sampled]
    total = math.prod(len(a.values) for a in grid) * ((samples or 1) if sampled else 1)
    if not problems and total > MAX_POINTS:
        problems.append(("", f"the sweep has {total} points, more than {MAX_POINTS}", "split it"))
    if problems:
        _raise(problems, locate)
    if sampled:
        unit = sample_unit(samples, len(sampled), seed, sampling)
        draws = [dict(zip([a.name for a in sampled], (float(v) for v in row)))
                 for row in np.column_stack([transform(a, unit[:, j]) for j, a in enumerate(sampled)])]
    else:
        draws = [{}]
    points = []
    for combo in itertools.product(*(a.values for a in grid)):
        fixed = dict(zip([a.name for a in grid], combo))
        for draw in draws:
            values = {a.name: (fixed if a.name in fixed else draw)[a.name] for a in axes}
            group, params, options = [], {}, {}
            for name, value in values.items():
                kind = kinds[name]
                if kind == "mesh":
                    values[name] = value = int(value)
                    group.append((name, value))
                elif kind == "compile":
                    group.append((name, value))
                elif kind == "option":
                    options[ACCURACY_OPTIONS[name]] = value
                else:
                    params[name] = value
            points.append(Point(len(points), values, tuple(sorted(group)), params, options))
    return Design(list(axes), samples if sampled else None, seed, sampling, points, kinds)


def _column_clashes(compiled, axes: Sequence[Axis]) -> list[tuple]:
    """A swept name that is also a column of every row (``steps``, ``worker``; ``x.max`` of
    an output ``x``): refused, located at the model's parameter when the model says where it
    is (a scene's sweep entry is located by the caller)."""
    from phc.sweep.results import result_columns

    outputs = list(compiled.module.OUTPUTS)
    columns = result_columns(outputs)
    spans = {p.name: p.span for p in (compiled.dae.parameters if compiled.dae is not None else ())}
    out = []
    for axis in axes:
        what = columns.get(axis.name)
        if what is None:
            continue
        output = axis.name.rpartition(".")[0] in outputs
        out.append((axis.name, f"swept parameter `{axis.name}` has the name of a result column ({what}); a row "
                    "cannot have two columns of one name",
                    "rename the output in the scene's or the model's `outputs`" if output else
                    "rename the parameter in the model file: the result columns of `phc sweep` are fixed",
                    spans.get(axis.name)))
    return out


def _raise(problems, locate) -> None:
    problems = [(p[0], p[1], p[2], p[3] if len(p) > 3 else None) for p in problems]
    where = []
    for name, _, _, span in problems:
        scene = locate(name) if locate is not None and name else None
        where.append((scene, f"sweep.parameters.{name}") if scene is not None else
                     (span, f"parameters.{name}") if span is not None else None)
    if all(w is not None for w in where):
        diags = DiagnosticList(Diagnostic("PHC-E606", message, span=span, hint=hint or None, path=path)
                               for (_, message, hint, _), (span, path) in zip(problems, where))
        raise ModelError(diags.sorted())
    name, message, hint, _ = problems[0]
    text = f"--param {name}: {message}" if name and not message.startswith("--") else message
    raise SweepSetupError(text + (f"; {hint}" if hint else ""))


def group_label(group: tuple) -> str:
    return ",".join(f"{name}={value:g}" for name, value in group) or "base"


def compile_group(compiled, path, group: tuple, certify: bool = True):
    """The compiled model of one compilation group: the base for the empty group, else an
    in-memory variant of the scene (or of the model file) with the compile-time parameters
    and meshes of `group`. Raises ModelError."""
    mod = compiled.module
    defaults = dict(zip(mod.PARAMETERS, (float(v) for v in mod.PARAMETER_DEFAULTS)))
    meshes = {comp: spec[-1] for comp, spec in (getattr(compiled.dae, "meshes", None) or {}).items()}
    if all(defaults.get(name) == value if not name.startswith(MESH_PREFIX) else
           meshes.get(name[len(MESH_PREFIX):]) == value for name, value in group):
        return compiled  # the values it was compiled with
    from phc.pipeline import compile_model
    from phc.scene import scene_variant

    params = {name: value for name, value in group if not name.startswith(MESH_PREFIX)}
    mesh = {name[len(MESH_PREFIX):]: int(value) for name, value in group if name.startswith(MESH_PREFIX)}
    variant = scene_variant(compiled.scene if compiled.scene is not None else path, mesh=mesh, parameters=params)
    # the group runs on what the base model runs on (numba or numpy), not on the default choice
    return compile_model(variant.model_path, scene=variant, certify=certify, backend=compiled.backend)


def recompile_for(compiled, path, params: dict, certify: bool = True):
    """`phc simulate --param` of compile-time parameters: ``(compiled, note)`` — the model
    recompiled with those values (a scene variant, nothing written) and a note saying so,
    or the model as it is and None when no compile-time parameter changes.

    Raises SweepSetupError for a nested compile-time parameter, ModelError when the new
    values do not compile."""
    mod = compiled.module
    fixed = set(getattr(mod, "COMPILE_TIME_PARAMETERS", ()))
    base = np.asarray(mod.PARAMETER_DEFAULTS, dtype=float)
    changed = {k: float(v) for k, v in params.items()
               if k in fixed and float(v) != float(base[mod.PARAMETERS.index(k)])}
    if not changed:
        return compiled, None
    nested = [k for k in changed if "." in k]
    if nested:
        raise SweepSetupError(f"parameter `{nested[0]}` is used at compile time inside a nested model; change it "
                              "in the model file")
    t = time.perf_counter()
    new = compile_group(compiled, path, tuple(sorted(changed.items())), certify=certify)
    values = ", ".join(f"{k} = {v:g}" for k, v in changed.items())
    what = "parameter" if len(changed) == 1 else "parameters"
    return new, (f"{what} {', '.join(f'`{k}`' for k in changed)} {'is' if len(changed) == 1 else 'are'} used at "
                 f"compile time (a mesh length or a coefficient varying along a distributed component): recompiled "
                 f"with {values} ({time.perf_counter() - t:.2f} s)")


def sweep_axes(compiled, cli: Sequence[tuple[str, str]]) -> tuple[list[Axis], Any, Any]:
    """The axes of a sweep: the scene's ``sweep.parameters`` (in its order), then the
    command line's (a name given there replaces the scene's entry). Also returns the
    scene's sweep spec (or None) and a locator of its entries."""
    spec = compiled.scene.spec.sweep if compiled.scene is not None else None
    axes: dict[str, Axis] = {}
    locate = None
    if spec is not None:
        smap = compiled.scene.smap
        for name, value in spec.parameters.items():
            axes[name] = parse_spec(name, value)

        def locate(name):
            if name not in spec.parameters or name in dict(cli):
                return None
            return smap.locate_key(("sweep", "parameters", name))
    for name, text in cli:
        try:
            axes[name] = parse_spec(name, text)
        except SpecError as err:
            raise SweepSetupError(f"--param {name}: {err}") from None
    return list(axes.values()), spec, locate


__all__ = ["ACCURACY_OPTIONS", "Design", "MAX_POINTS", "MAX_SEED", "MESH_PREFIX", "Point", "compile_group",
           "group_label", "make_design", "recompile_for", "sample_unit", "sweep_axes", "transform"]
