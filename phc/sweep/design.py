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
from collections import abc
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
    points: "Points"
    """The points, made on demand (:class:`Points`; a list works too)."""
    kinds: dict[str, str]
    """name -> `run` (run-time parameter), `compile` (compile-time parameter), `mesh`, `option`."""

    @property
    def groups(self) -> list[tuple]:
        """The compilation groups in the order their first points come."""
        return list(self.group_counts())

    def group_counts(self) -> dict[tuple, int]:
        """Compilation group -> its number of points, in the order their first points come."""
        if isinstance(self.points, Points):
            return self.points.group_counts()
        counts: dict[tuple, int] = {}
        for p in self.points:
            counts[p.group] = counts.get(p.group, 0) + 1
        return counts

    @property
    def digest(self) -> str:
        return self.points.digest if isinstance(self.points, Points) else _digest(self.axes, self.kinds, self.samples,
                                                                                   self.seed, self.sampling)


CHUNK = 4096
"""Samples of the distributions made at once (:class:`Points`)."""


def _digest(axes: Sequence[Axis], kinds: dict, samples, seed: int, sampling: str) -> str:
    """A stable hash of a design's definition (its axes, their values or distributions, the
    sampler and its seed): equal digests mean equal points, in the same order."""
    import hashlib
    import json

    definition = {"axes": [{"name": a.name, "kind": kinds.get(a.name, ""), "values": [repr(float(v)) for v in a.values],
                            "distribution": a.distribution, "a": repr(float(a.a)), "b": repr(float(a.b))}
                           for a in axes],
                  "samples": samples, "seed": seed, "sampling": sampling, "points": "grid-major, samples fastest"}
    return hashlib.sha256(json.dumps(definition, sort_keys=True).encode()).hexdigest()[:32]


class Points(abc.Sequence):
    """The points of a design, made on demand: ``len``, indexing and iteration build a
    :class:`Point` when asked, never the list of all of them.

    Point `i` is grid combination ``i // samples`` (the grid axes as mixed-radix digits, the
    last axis fastest) with sample ``i % samples``. Samples are made :data:`CHUNK` at a
    time from the seed alone: random samples by advancing the generator to the chunk,
    Latin-hypercube samples from one stored permutation per sampled axis (4 bytes per
    sample and axis) and the generator's state after it. The points are those of the eager
    construction (:func:`sample_unit`, then :func:`transform`), in the same order."""

    def __init__(self, axes: Sequence[Axis], kinds: dict, samples: Optional[int], seed: int, sampling: str) -> None:
        self.axes, self.kinds = list(axes), dict(kinds)
        self.grid = [a for a in self.axes if not a.sampled]
        self.sampled = [a for a in self.axes if a.sampled]
        self.samples = samples if self.sampled else None
        self.seed, self.sampling = seed, sampling
        self.n_draws = samples if self.sampled else 1
        self.radix = [len(a.values) for a in self.grid]
        self._len = math.prod(self.radix) * self.n_draws
        self._chunks: dict[int, np.ndarray] = {}  # the last few chunks of samples, by their first sample
        self._unit = UnitSampler(self.n_draws, len(self.sampled), seed, sampling)
        self.digest = _digest(self.axes, self.kinds, self.samples, seed, sampling)

    def __len__(self) -> int:
        return self._len

    def __getitem__(self, i):
        if isinstance(i, slice):
            return [self[k] for k in range(*i.indices(self._len))]
        i = int(i)
        if i < 0:
            i += self._len
        if not 0 <= i < self._len:
            raise IndexError(f"point {i} of a design of {self._len}")
        return self._point(i)

    def __iter__(self):
        for i in range(self._len):
            yield self._point(i)

    def __repr__(self) -> str:
        return f"Points({self._len} points, digest {self.digest})"

    # -- one point --------------------------------------------------------------------------

    def _point(self, i: int) -> Point:
        combo, k = divmod(i, self.n_draws)
        fixed = {}
        for axis, n in zip(reversed(self.grid), reversed(self.radix)):
            combo, digit = divmod(combo, n)
            fixed[axis.name] = axis.values[digit]
        draw = self._draw(k) if self.sampled else {}
        values = {a.name: (fixed if a.name in fixed else draw)[a.name] for a in self.axes}
        group, params, options = [], {}, {}
        for name, value in values.items():
            kind = self.kinds[name]
            if kind == "mesh":
                values[name] = value = int(value)
                group.append((name, value))
            elif kind == "compile":
                group.append((name, value))
            elif kind == "option":
                options[ACCURACY_OPTIONS[name]] = value
            else:
                params[name] = value
        return Point(i, values, tuple(sorted(group)), params, options)

    def _draw(self, k: int) -> dict:
        start = k - k % CHUNK
        chunk = self._chunks.get(start)
        if chunk is None:  # rows come back out of order, around the points being sent: a few chunks kept
            if len(self._chunks) >= 4:
                del self._chunks[next(iter(self._chunks))]
            chunk = self._chunks[start] = self._make_chunk(start, min(start + CHUNK, self.n_draws))
        row = chunk[k - start]
        return dict(zip([a.name for a in self.sampled], (float(v) for v in row)))

    def _make_chunk(self, start: int, stop: int) -> np.ndarray:
        """Samples `start` to `stop` of the distributions, as the eager construction makes them."""
        unit = self._unit.rows(start, stop)
        return np.column_stack([transform(a, unit[:, j]) for j, a in enumerate(self.sampled)])

    # -- compilation groups -----------------------------------------------------------------

    def group_counts(self) -> dict[tuple, int]:
        """Compilation group -> number of points, in the order of their first points: from
        the grid's compile-time axes alone (a sampled compile-time parameter makes every
        sample a group of its own: then the points are counted one by one)."""
        keyed = [a for a in self.axes if self.kinds[a.name] in ("mesh", "compile")]
        if any(a.sampled for a in keyed):
            counts: dict[tuple, int] = {}
            for p in self:
                counts[p.group] = counts.get(p.group, 0) + 1
            return counts
        per = self._len // max(1, math.prod(len(a.values) for a in keyed))
        counts = {}
        for combo in itertools.product(*(a.values for a in keyed)):
            group = tuple(sorted((a.name, int(v) if self.kinds[a.name] == "mesh" else v)
                                 for a, v in zip(keyed, combo)))
            counts[group] = counts.get(group, 0) + per
        return counts


class UnitSampler:
    """The `n` points of a design in the unit cube [0, 1)^dims, any rows of them made alone:
    Latin hypercube (each of the n strata of every coordinate holds exactly one point, at a
    uniformly random place in it: per coordinate, a random permutation of the strata plus a
    uniform offset, drawn one coordinate after the other from the seed) or plain uniform
    random (rows of `dims` draws, row after row).

    Rows `start` to `stop` are made without the rows before them: the uniform draws by
    advancing the generator past them (one 64-bit draw per double), the Latin hypercube
    from one stored permutation per coordinate and the generator's state after it (4 bytes
    per point and coordinate)."""

    def __init__(self, n: int, dims: int, seed: int, sampling: str) -> None:
        self.n, self.dims, self.seed, self.sampling = n, dims, seed, sampling
        self._lhs: Optional[list] = None

    def rows(self, start: int, stop: int) -> np.ndarray:
        n, dims = self.n, self.dims
        if self.sampling == "random":
            rng = np.random.default_rng(self.seed)
            rng.bit_generator.advance(start * dims)
            return rng.random((stop - start, dims))
        if self._lhs is None:  # per coordinate: its permutation, the generator's state after it
            rng = np.random.default_rng(self.seed)
            self._lhs = []
            for _ in range(dims):
                perm = rng.permutation(n).astype(np.int32 if n < 2**31 else np.int64)
                state = rng.bit_generator.state
                self._lhs.append((perm, state))
                rng.bit_generator.advance(n)  # rng.random(n): n doubles, one 64-bit draw each
                after = rng.bit_generator.state  # advance() drops a buffered 32-bit half; doubles keep it
                after.update(has_uint32=state["has_uint32"], uinteger=state["uinteger"])
                rng.bit_generator.state = after
        unit = np.empty((stop - start, dims))
        for j, (perm, state) in enumerate(self._lhs):
            rng = np.random.Generator(np.random.PCG64())
            rng.bit_generator.state = state
            rng.bit_generator.advance(start)
            unit[:, j] = (perm[start:stop].astype(np.int64) + rng.random(stop - start)) / n
        return unit


def sample_unit(n: int, dims: int, seed: int, sampling: str) -> np.ndarray:
    """All `n` points of :class:`UnitSampler` at once."""
    return UnitSampler(n, dims, seed, sampling).rows(0, n)


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
    return Design(list(axes), samples if sampled else None, seed, sampling,
                  Points(axes, kinds, samples if sampled else None, seed, sampling), kinds)


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
    from phc.frontend.scene import scene_variant

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


__all__ = ["ACCURACY_OPTIONS", "Design", "MAX_POINTS", "MAX_SEED", "MESH_PREFIX", "Point", "Points", "UnitSampler",
           "compile_group", "group_label", "make_design", "recompile_for", "sample_unit", "sweep_axes", "transform"]
