"""`phc bench SCENE.yaml`: a work-precision study of a scene.

:func:`run_bench` sweeps

    solvers × (relative tolerances for the error-controlled `ida` | steps for the fixed-step
    `midpoint`, `discrete_gradient` and `midpoint4`) × mesh sizes of the distributed components,

and, as peers given the same residual, scipy's ``Radau``, ``BDF`` and ``DOP853`` (the solvers
``scipy_Radau``, ``scipy_BDF``, ``scipy_DOP853`` of :func:`run_bench`, over the tolerances;
:mod:`phc.study.ode_form`: the model as ẋ = f(t, x) where it is one — a constrained DAE gets one
failed row per method saying it is not an ODE), runs each point on the scene's output grid
(``t_start … t_end`` with ``n_out`` points) and measures, per point:

* the **error** of every requested output against a reference, ``max_t |y(t) − y_ref(t)|``
  over the output grid (absolute), and the same divided by the range ``max y_ref − min
  y_ref`` of the reference (relative); the row's ``error`` / ``error_relative`` are the
  maxima over the outputs;
* the **CPU time** (process time of :func:`phc.simulate`, consistent initialization
  included; the minimum over ``repeats`` runs, the median is kept as a noise figure; each
  solver first runs once untimed on each mesh — a fixed-step one at its finest step — so
  the process's one-time costs — imports, the first calls, building a compiled step loop,
  which `auto` then uses for every step of that model — are in no row),
  the steps, residual and Jacobian evaluations;
* the **structure figures**: the relative energy-balance residual and the position
  constraint drift;
* success and the solver's message — a failed run is a row, never an exception.

Two readings of the rows are written with them:

* the **Pareto front**: a successful row that no other successful row beats in both CPU
  time and error (``front`` in the table) — the settings worth choosing;
* the **work check** (:func:`work_flags`): a looser setting of one solver and mesh that
  took more steps than a tighter one (beyond :data:`STEPS_NOISE`), or more CPU time (beyond
  :data:`CPU_NOISE` and :data:`CPU_FLOOR_S`) — the promise that a looser tolerance is never
  slower (docs/tolerances.md), checked on every sweep.

The reference of an output is

* its **reference values** when the scene gives them (``reference_values:``, a CSV file or
  inline; :mod:`phc.frontend.reference_values`) or ``reference=FILE.csv`` does (``phc bench
  --reference``, replacing the scene's): published values at given times. The error is then
  ``max_i |y(t_i) − y_ref,i|`` over that output's reference times, and the relative error
  that divided by ``max_i |y_ref,i|``. The reference times are added to every run's output
  times (exact output, no interpolation; a fixed-step solver shortens the steps of an
  output interval to land on them, see :func:`phc.simulation.midpoint.integrate_fixed_step`);
  the reported kind is ``published reference (FILE, N points)``;
* else its **closed form** when the scene gives one under ``reference:`` — the compiled scene
  then carries it as the extra output ``<output>_reference`` (:func:`phc.frontend.scene.reference_name`)
  and every run evaluates it on its own grid;
* otherwise a **reference run**: IDA at a tight tolerance (``min(1e-10, tightest swept
  tolerance / 100)``, ``atol = rtol / 100``, BDF orders up to 5 whatever the scene caps
  them at, up to 10⁷ steps) — or, with ``reference_solver`` a fixed-step solver such as
  ``midpoint4``, that solver at ``reference_step`` (default: the finest swept step / 16) —
  on the finest mesh swept (the largest element
  count of each swept component), on the same output grid. The spatial error of that mesh
  itself is therefore not part of the measured error — the error of a coarse mesh is
  measured relative to the finest one. The run is cached on disk (``$PHC_CACHE_DIR/bench``,
  default ``~/.cache/phc/bench``) under the SHA-256 of the scene file, the model file, the
  phc version and the reference settings, so a repeated bench does not recompute it.
  With ``cross_check`` a second reference run by the other kind of method (the fixed-step
  one when the reference is IDA, IDA when it is fixed-step) is compared with the first: their
  largest relative difference per output (``reference_gap``) bounds what the reference
  resolves — a row's error below it is not measured.

Mesh variants are in-memory copies of the scene (of a plain model file: a scene around
it) whose ``accuracy.mesh`` has the swept element counts merged in
(:func:`phc.frontend.scene.scene_variant`, the same refinement as the spatial error estimate);
nothing is written. Each variant is compiled once and serves all its solver settings.

The results are written to ``out_dir`` as ``bench.csv``, ``bench.md`` (a Markdown table) and,
when matplotlib is installed (the ``plot`` extra), ``bench.png``: the work-precision plot,
error against CPU time on log–log axes, one line per solver and mesh. A Ctrl-C during the
sweep stops it; the rows finished so far are written and the report says it was
interrupted.

The module is over 800 lines because the sweep, the measurement of a row (phc's solvers and
scipy's) and the report (text, Markdown, CSV, plot) share the row type, the reference and the
formatting helpers; the report's writers are the part to move out next.
"""

from __future__ import annotations

import csv
import hashlib
import itertools
import json
import math
import os
import statistics
import sys
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Optional, Union

import numpy as np

import phc
from phc.frontend import reference_values as refs
from phc.diagnostics import DiagnosticList
from phc.errors import ModelError, SimulationSetupError
from phc.inert import inert
from phc.io import atomic_write, write_text
from phc.frontend.scene import reference_name, scene_variant
from phc.simulation import BACKENDS, FIXED_STEP

DEFAULT_TOLERANCES = (1e-4, 1e-6, 1e-8)
STEP_DIVISORS = (1, 4, 16)
"""Default steps of the fixed-step solvers: the output interval divided by these (or, when
the scene or model sets a `step`, that step times 4, 2 and 1)."""
REFERENCE_RTOL = 1e-10
"""Relative tolerance of the reference run (tighter when the sweep goes below 1e-8)."""
REFERENCE_MAX_ORDER = 5
"""BDF order limit of the reference run. A scene may cap IDA's order for efficiency at loose
tolerances (BDF2 is A-stable for undamped high modes); at the reference's tight tolerance
the high orders are far cheaper (BDF2 at rtol 1e-10 needs millions of steps)."""
REFERENCE_MAX_STEPS = 10_000_000
REFERENCE_STEP_DIVISOR = 16
"""A fixed-step reference run's default step: the finest swept step divided by this."""
CROSS_CHECK_SOLVER = "midpoint4"
"""The fixed-step method of a cross-check of an IDA reference (order 4, symplectic)."""
STEPS_NOISE = 1.10
"""A looser setting may take this factor more steps than a tighter one before the work
check flags it: at equal work IDA's step sequence still differs with the tolerances (where
a step is rejected, which order it takes), by a few percent (the factor of
tests/simulation/test_tolerance_budget.py); a trap costs 2 to 100 times more."""
CPU_NOISE = 1.5
"""…and this factor more CPU time (process time of runs well under a second varies by tens
of percent between repeats on a loaded machine)…"""
CPU_FLOOR_S = 0.02
"""…when the difference is at least this long (below, timer and start-up noise)."""
INSTALL_HINT = 'pip install "port-hamiltonian-compiler[plot]"'
SCIPY_PREFIX = "scipy_"
"""A solver ``scipy_Radau``, ``scipy_BDF``, ``scipy_DOP853`` in a sweep: scipy's method on the
ODE form of the model's residual (:mod:`phc.study.ode_form`; a model that has none gets one row per
method saying why)."""


# ---------------------------------------------------------------------------------------
# results


@dataclass
class BenchRow:
    """One point of the sweep."""

    solver: str
    mesh: dict[str, int]
    rtol: Optional[float] = None
    atol: Optional[float] = None
    step: Optional[float] = None
    success: bool = False
    message: str = ""
    cpu_time_s: float = math.nan
    """Minimum CPU time over the repeats."""
    cpu_time_median_s: float = math.nan
    repeats: int = 0
    steps: int = 0
    n_residual_evals: int = 0
    n_jacobian_evals: int = 0
    energy_balance_relative: float = math.nan
    constraint_drift: float = math.nan
    errors: dict[str, float] = field(default_factory=dict)
    """max_t |y − y_ref| per output."""
    relative_errors: dict[str, float] = field(default_factory=dict)
    """errors divided by the range of the reference output."""
    pareto: bool = False
    """On the Pareto front of the sweep: no other successful row is at once faster and
    more accurate (:func:`pareto_front`)."""

    @property
    def fixed_step(self) -> bool:
        return self.step is not None

    @property
    def setting(self) -> str:
        """`rtol 1e-06` or `step 2.5e-04`."""
        return f"step {self.step:.3g}" if self.fixed_step else f"rtol {self.rtol:.3g}"

    @property
    def mesh_label(self) -> str:
        return mesh_label(self.mesh)

    @property
    def error(self) -> float:
        """Largest absolute error over the outputs (nan when any is unknown)."""
        return _max_or_nan(self.errors.values())

    @property
    def error_relative(self) -> float:
        return _max_or_nan(self.relative_errors.values())

    def as_dict(self, outputs) -> dict:
        row = {
            "solver": self.solver, "mesh": self.mesh_label,
            "rtol": _blank(self.rtol), "atol": _blank(self.atol), "step": _blank(self.step),
            "success": self.success, "cpu_time_s": self.cpu_time_s, "cpu_time_median_s": self.cpu_time_median_s,
            "repeats": self.repeats, "steps": self.steps, "n_residual_evals": self.n_residual_evals,
            "n_jacobian_evals": self.n_jacobian_evals, "error": self.error, "error_relative": self.error_relative,
            "pareto": self.pareto,
        }
        for name in outputs:
            row[f"error_{name}"] = self.errors.get(name, math.nan)
        for name in outputs:
            row[f"error_relative_{name}"] = self.relative_errors.get(name, math.nan)
        row.update(energy_balance_relative=self.energy_balance_relative, constraint_drift=self.constraint_drift,
                   message=self.message)
        return row


@dataclass
class BenchReport:
    """What :func:`run_bench` measured and wrote."""

    scene: Path
    name: str
    outputs: list[str]
    rows: list[BenchRow] = field(default_factory=list)
    planned: int = 0
    """Number of sweep points asked for (rows ≤ planned when interrupted)."""
    reference: dict[str, str] = field(default_factory=dict)
    """Per output: `closed form`, `reference run` or `published reference (FILE, N points)`."""
    reference_source: str = ""
    """Where the published reference values come from (their `source`), if given."""
    reference_settings: dict = field(default_factory=dict)
    """Solver, tolerances and mesh of the reference run (empty when only closed forms)."""
    reference_cache_hit: bool = False
    reference_cache_path: Optional[Path] = None
    reference_message: str = ""
    """Why the reference run failed (empty when it did not)."""
    reference_check: dict = field(default_factory=dict)
    """Settings of the cross-check reference run (empty without `cross_check`)."""
    reference_gap: dict[str, float] = field(default_factory=dict)
    """Per output: the largest difference of the two reference runs, relative to the
    reference's range (what the reference resolves)."""
    reference_check_message: str = ""
    """Why the cross-check reference run failed (empty when it did not)."""
    flags: list = field(default_factory=list)
    """:class:`WorkFlag` s: looser settings that cost more than tighter ones."""
    paths: dict[str, Path] = field(default_factory=dict)
    """`csv`, `md` and (with matplotlib) `png`."""
    plot_skipped: str = ""
    """Why no PNG was written (empty when it was)."""
    interrupted: bool = False
    elapsed_s: float = 0.0

    @property
    def success(self) -> bool:
        return not self.interrupted and all(r.success for r in self.rows) and not self.reference_message

    def render_text(self) -> str:
        """A short summary: the sweep, the reference, the best point per solver, the files."""
        lines = [f"{self.name}: work-precision sweep, {len(self.rows)} of {self.planned} runs"
                 + (" — INTERRUPTED, finished rows kept" if self.interrupted else "")
                 + f" ({self.elapsed_s:.1f} s)"]
        kinds = {}
        for out, kind in self.reference.items():
            kinds.setdefault(kind, []).append(out)
        for kind, outs in kinds.items():
            what = kind
            if kind == "reference run" and self.reference_settings:
                s = self.reference_settings
                what += (f" ({settings_label(s)}, mesh {mesh_label(s['mesh'])}, "
                         f"{_fmt(s.get('cpu_time_s', math.nan), '.3g')} s CPU"
                         + ("; cached" if self.reference_cache_hit else "") + ")")
            lines.append(f"  reference  {what}: {', '.join(outs)}")
        if self.reference_source:
            lines.append(f"  source     {self.reference_source}")
        if self.reference_message:
            lines.append(f"  reference  FAILED: {self.reference_message}")
        if self.reference_check_message:
            lines.append(f"  reference  cross-check ({settings_label(self.reference_check)}) failed: "
                         f"{_short(self.reference_check_message)}")
        elif self.reference_gap:
            lines.append(f"  reference  agrees with {settings_label(self.reference_check)} within "
                         + ", ".join(f"{o} {_fmt(g)}" for o, g in self.reference_gap.items()) + " (relative)")
        failed = [r for r in self.rows if not r.success]
        lines.append(f"  runs       {len(self.rows) - len(failed)} succeeded, {len(failed)} failed")
        for r in self.rows:
            status = ("ok*" if r.pareto else "ok ") if r.success else "FAIL"
            lines.append(f"  {status} {r.solver:<17} {r.mesh_label:<12} {r.setting:<16} "
                         f"error {_fmt(r.error)} (rel {_fmt(r.error_relative)})  cpu {_fmt(r.cpu_time_s, '.3g')} s  "
                         f"steps {r.steps}  energy {_fmt(r.energy_balance_relative)}"
                         + ("" if r.success and np.isfinite(r.error) else f"  — {_short(r.message)}"))
        lines.append("  work check " + (f"{len(self.flags)} looser setting(s) cost more than a tighter one"
                                           if self.flags else "no looser setting costs more than a tighter one")
                     + "  (* = on the Pareto front)")
        for flag in self.flags:
            lines.append(f"    {flag.text()}")
        for key in ("csv", "md", "png"):
            if key in self.paths:
                lines.append(f"  wrote      {self.paths[key]}")
        if self.plot_skipped:
            lines.append(f"  plot       skipped: {self.plot_skipped}")
        return "\n".join(inert(line) for line in lines)  # names, messages and paths (phc.inert)

    def summary(self) -> dict:
        """JSON-ready form (for `--format json`)."""
        return {
            "scene": str(self.scene), "name": self.name, "outputs": self.outputs, "planned": self.planned,
            "interrupted": self.interrupted, "reference": self.reference,
            "reference_source": self.reference_source,
            "reference_settings": {k: (mesh_label(v) if k == "mesh" else v) for k, v in self.reference_settings.items()},
            "reference_cache_hit": self.reference_cache_hit, "reference_message": self.reference_message,
            "reference_check": {k: (mesh_label(v) if k == "mesh" else v) for k, v in self.reference_check.items()},
            "reference_gap": _jsonable(self.reference_gap), "reference_check_message": self.reference_check_message,
            "flags": [f.as_dict() for f in self.flags],
            "rows": [_jsonable(r.as_dict(self.outputs)) for r in self.rows],
            "paths": {k: str(v) for k, v in self.paths.items()}, "plot_skipped": self.plot_skipped,
        }


# ---------------------------------------------------------------------------------------
# the sweep


def run_bench(scene_path: Union[str, os.PathLike], *, solvers=None, tolerances=None, steps=None, meshes=None,
              repeats: Optional[int] = None, out_dir: Union[str, os.PathLike] = ".",
              reference_cache: Union[None, bool, str, os.PathLike] = None, progress: bool = True,
              plot: bool = True, outputs=None, reference_rtol: Optional[float] = None,
              stream=None, reference: Union[None, str, os.PathLike] = None, reference_solver: str = "ida",
              reference_step: Optional[float] = None, cross_check: bool = False,
              target_error: Optional[float] = None) -> BenchReport:
    """Run the work-precision study of a scene and write ``bench.csv``, ``bench.md`` and
    ``bench.png`` into `out_dir`.

    Parameters
    ----------
    scene_path
        A scene file (a plain model file works too: its `simulation` outputs are used).
    solvers, tolerances, steps, meshes, repeats : optional
        Override the scene's ``bench`` section (``None`` or empty: the scene's). `tolerances` are the relative tolerances of
        the error-controlled solvers (``atol = rtol/100``); `steps` the step sizes of the
        fixed-step ones (default: the scene's step × 4, 2, 1, else the output interval /1,
        /4, /16); `meshes` maps a distributed component to the element counts to sweep (the
        product over components is swept); `repeats` runs per point (CPU time: the minimum).
    out_dir
        Where the files go (created if missing).
    reference_cache
        Directory of the reference-run cache (default ``$PHC_CACHE_DIR/bench``); ``False``
        computes the reference every time and stores nothing.
    progress
        Draw a progress bar over the sweep on `stream` (default stderr).
    plot
        Write the PNG (skipped, and said so in the report, without matplotlib).
    outputs
        The outputs to measure (default: all the scene's requested outputs).
    reference_rtol
        Relative tolerance of the reference run (default ``min(1e-10, tightest swept
        tolerance / 100)``; ``atol = rtol / 100``).
    reference
        A CSV file of reference values (a `t` column and one column per output; see
        :mod:`phc.frontend.reference_values`), replacing the scene's ``reference_values``.
    reference_solver, reference_step
        The method of the reference run: ``ida`` (the default) at `reference_rtol`, or a
        fixed-step solver at `reference_step` (default: the finest swept step /
        :data:`REFERENCE_STEP_DIVISOR`).
    cross_check
        Run a second reference by the other kind of method (:data:`CROSS_CHECK_SOLVER` at
        the finest swept step / 16 for an IDA reference, IDA at `reference_rtol` for a
        fixed-step one) and report their difference (``reference_gap``).
    target_error
        The tightest relative error the study is after (e.g. 1e-8). A fixed-step solver whose
        finest listed step has not reached it goes on to finer steps, chosen from its measured
        convergence (:func:`next_finer_step`), until one reaches it — or twice the reference's
        gap, a stalled convergence, a failed run or the budget (:data:`EXTEND_MAX_HALVINGS`,
        :data:`EXTEND_MAX_CPU_S`) stops it. ``None``: the listed steps only.

    Returns
    -------
    BenchReport
        Rows, the files written, whether the sweep was interrupted.

    Raises
    ------
    ModelError
        When the scene itself does not compile (a mesh variant that fails is a failed row),
        or the reference values are not usable (PHC-E607, located in the file).
    SimulationSetupError
        When the `reference` file cannot be read, or an output asked for is unknown.
    """
    started = time.perf_counter()
    reference_file, reference = reference, None  # `reference` below: the reference run's outputs
    scene_path = Path(scene_path)
    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    scene = _without_reference_values(scene_path, reference_file)
    base = phc.compile_model(scene.model_path if scene else scene_path, scene=scene)
    bench_spec = base.scene.spec.bench if base.scene is not None else None
    model_path = (base.scene.model_path if base.scene is not None else scene_path).resolve()

    # -- what to sweep -----------------------------------------------------------------
    opts = dict(base.options)
    t0, t1, n_out = float(opts["t_start"]), float(opts["t_end"]), int(opts["n_out"])
    t_out = np.linspace(t0, t1, n_out)
    solvers = list(solvers or (bench_spec.solvers if bench_spec and bench_spec.solvers else BACKENDS))
    tolerances = [float(x) for x in (tolerances or (bench_spec.tolerances if bench_spec else DEFAULT_TOLERANCES))]
    if not steps:
        steps = list(bench_spec.steps) if bench_spec and bench_spec.steps else _default_steps(opts, t1 - t0, n_out)
    steps = [float(x) for x in steps]
    meshes = dict(meshes or (bench_spec.meshes if bench_spec else {}))
    repeats = int(repeats or (bench_spec.repeats if bench_spec else 1))
    mesh_points = _mesh_product(meshes)
    points = [(mesh, solver, value) for mesh in mesh_points for solver in solvers
              for value in (steps if solver in FIXED_STEP else tolerances)]

    all_outputs = [name for name in base.module.OUTPUTS if not _is_reference_output(name, base.module.OUTPUTS)]
    outputs = list(outputs) if outputs else all_outputs
    unknown = [o for o in outputs if o not in all_outputs]
    if unknown:
        raise SimulationSetupError(f"unknown output(s) {', '.join(unknown)}; "
                                   f"the scene has {', '.join(all_outputs) or 'none'}")
    published = _published(reference_file, base, all_outputs, t0, t1)
    pub = [o for o in outputs if published is not None and o in published.series]
    closed = [o for o in outputs if o not in pub and reference_name(o) in base.module.OUTPUTS]
    report = BenchReport(scene_path, base.scene.name if base.scene is not None else base.name, outputs,
                         planned=len(points),
                         reference={o: (published.kind(o) if o in pub else "closed form" if o in closed
                                        else "reference run") for o in outputs},
                         reference_source=published.source if pub else "")
    need_run = [o for o in outputs if o not in closed and o not in pub]
    # the run's output times: the grid, and the published reference times (exact output)
    t_run = _merge_times(t_out, published.times) if pub else t_out
    grid = _nearest(t_run, t_out)
    at_ref = {o: (_nearest(t_run, published.series[o][0]), published.series[o][1]) for o in pub}
    bar = _SweepBar(len(points) + ((2 if cross_check else 1) if need_run else 0), enabled=progress, stream=stream)
    compiled_cache: dict[tuple, object] = {(): base} if not meshes else {}
    reference: dict[str, np.ndarray] = {}

    def compiled_for(mesh: dict):
        key = tuple(sorted(mesh.items()))
        if key not in compiled_cache:
            try:
                # an in-memory variant of the base scene (certified above); nothing is written
                variant = scene_variant(base.scene if base.scene is not None else scene_path, mesh=mesh)
                compiled_cache[key] = phc.compile_model(variant.model_path, scene=variant, certify=False)
            except ModelError as err:
                compiled_cache[key] = err
        return compiled_cache[key]

    try:
        # -- the reference run (closed forms ride along in every run) --------------
        if need_run:
            ref_mesh = {comp: max(counts) for comp, counts in meshes.items()}
            ref_rtol = float(reference_rtol or min(REFERENCE_RTOL, min(tolerances) / 100))
            ref_step = float(reference_step or min(steps) / REFERENCE_STEP_DIVISOR)
            ida_settings = dict(solver="ida", rtol=ref_rtol, atol=ref_rtol / 100, mesh=ref_mesh,
                                max_order=REFERENCE_MAX_ORDER, max_steps=REFERENCE_MAX_STEPS)
            if reference_solver in FIXED_STEP:
                settings = dict(solver=reference_solver, step=ref_step, mesh=ref_mesh, max_steps=REFERENCE_MAX_STEPS)
                other = ida_settings
            else:
                settings = ida_settings
                other = dict(solver=CROSS_CHECK_SOLVER, step=min(steps) / REFERENCE_STEP_DIVISOR, mesh=ref_mesh,
                             max_steps=REFERENCE_MAX_STEPS)
            report.reference_settings = settings
            bar.show("reference run " + settings_label(settings))
            reference, report.reference_cache_hit, report.reference_cache_path, report.reference_message = \
                _reference_run(scene_path, model_path, settings, t_out, need_run, reference_cache,
                               lambda: compiled_for(ref_mesh))
            bar.advance()
            if cross_check and not report.reference_message:
                report.reference_check = other
                bar.show("cross-check reference " + settings_label(other))
                second, _, _, problem = _reference_run(scene_path, model_path, other, t_out, need_run,
                                                       reference_cache, lambda: compiled_for(ref_mesh))
                report.reference_check_message = problem
                report.reference_gap = {o: (_relative_gap(reference[o], second[o]) if not problem else math.nan)
                                        for o in need_run}
                bar.advance()
        # -- the sweep ----------------------------------------------------------------
        warmed = set()
        forms: dict[tuple, object] = {}
        for mesh, solver, value in points:
            bar.show(_point_label(mesh, solver, value))
            compiled = compiled_for(mesh)
            key = (tuple(sorted(mesh.items())), solver)
            method = _scipy_method(solver)
            if method is not None:  # scipy on the ODE form of the same residual (phc.study.ode_form)
                if key[0] not in forms:
                    forms[key[0]] = _scipy_form(compiled)
                form = forms[key[0]]
                if isinstance(form, str) and any(r.solver == solver and r.mesh == mesh for r in report.rows):
                    bar.advance()  # no ODE form: one row per method says why
                    continue
                if key not in warmed and not isinstance(form, str):
                    warmed.add(key)
                    from phc.study.ode_form import integrate

                    integrate(form, method, t_run, value, value / 100)
                report.rows.append(_run_scipy_point(form, method, value, mesh, t_run, repeats, outputs, closed,
                                                    reference, report.reference_message, grid, at_ref))
                bar.advance()
                continue
            if key not in warmed and not isinstance(compiled, Exception):
                # one untimed run first: the process's one-time costs (imports, the first call of
                # the generated functions) are no setting's work. A fixed-step solver warms up at
                # its finest step: where that run is long enough for `auto` to build a compiled
                # step loop, every row then runs on it (phc.codegen.backends.for_run), instead of
                # the coarse rows on the Python loop and the fine ones 10–40× faster per step
                warmed.add(key)
                warm = min(steps) if solver in FIXED_STEP else value
                _simulate_once(compiled, solver, warm, t_run)
            row = _run_point(compiled, solver, value, mesh, t_run, repeats, outputs, closed, reference,
                             report.reference_message, grid, at_ref)
            report.rows.append(row)
            bar.advance()
            if target_error and solver in FIXED_STEP and value == steps[-1]:
                # the listed steps are done: finer ones until the target is reached (the steps
                # come from the accuracy asked for, not from a count)
                floor = 2 * max([g for g in report.reference_gap.values() if math.isfinite(g)], default=0.0)
                while True:
                    mine = [r for r in report.rows if r.solver == solver and r.mesh == mesh]
                    finer = next_finer_step(mine, max(float(target_error), floor), min(steps), repeats)
                    if finer is None:
                        break
                    bar.total += 1
                    bar.show(_point_label(mesh, solver, finer))
                    report.rows.append(_run_point(compiled, solver, finer, mesh, t_run, repeats, outputs, closed,
                                                  reference, report.reference_message, grid, at_ref))
                    bar.advance()
    except KeyboardInterrupt:
        report.interrupted = True
    finally:
        bar.close()

    report.elapsed_s = time.perf_counter() - started
    for i in pareto_front(report.rows):
        report.rows[i].pareto = True
    report.flags = work_flags(report.rows)
    _write_files(report, out_dir, plot)
    return report


# ---------------------------------------------------------------------------------------
# finer steps from the accuracy asked for

EXTEND_MAX_HALVINGS = 6
"""A fixed-step sweep extended towards ``target_error`` goes at most this many halvings
below the finest listed step (64× its steps)…"""
EXTEND_MAX_JUMP = 3
"""…at most this many halvings at once (the rate measured on the last two steps may be
pre-asymptotic)…"""
EXTEND_MIN_RATE = 0.5
"""…and stops when the error fell slower than h^this over the last refinement (round-off,
the reference's own error or a Newton tolerance reached: a finer step buys nothing)…"""
EXTEND_MAX_CPU_S = 2.0
"""…or when the next run would take more than this CPU time (predicted from the finest run,
proportional to the steps, times the repeats)."""


def next_finer_step(rows, target: float, finest_listed: float, repeats: int = 1) -> Optional[float]:
    """The next step of a fixed-step solver's sweep towards the relative error `target`, or
    ``None`` when the sweep is done.

    `rows` are that solver's rows on one mesh so far. The finest successful row with a measured
    error above `target` is refined by halvings: as many (1 … :data:`EXTEND_MAX_JUMP`) as the
    rate measured between the two finest rows, ``err ∝ h^p``, says reach `target` (one when
    there is a single row). ``None`` when the finest row reached `target`, a step finer than
    `finest_listed` failed, the error fell slower than ``h^``:data:`EXTEND_MIN_RATE`, or the
    next step would pass the budget (:data:`EXTEND_MAX_HALVINGS`, :data:`EXTEND_MAX_CPU_S`).
    """
    if any(not r.success for r in rows if r.step and r.step < finest_listed * (1 - 1e-9)):
        return None  # an added step failed: finer ones will not do better
    done = sorted((r for r in rows if r.success and r.step and math.isfinite(r.error_relative)),
                  key=lambda r: r.step)
    if not done or done[0].error_relative <= target:
        return None
    finest, halvings = done[0], 1
    if len(done) > 1:
        coarser = done[1]
        if not coarser.error_relative > finest.error_relative > 0:
            return None
        rate = math.log(coarser.error_relative / finest.error_relative) / math.log(coarser.step / finest.step)
        if rate < EXTEND_MIN_RATE:
            return None
        needed = (finest.error_relative / target) ** (1 / rate)
        halvings = min(max(math.ceil(math.log2(needed)), 1), EXTEND_MAX_JUMP)
    # within the budget: no finer than finest_listed / 2^EXTEND_MAX_HALVINGS, no longer a run
    # than EXTEND_MAX_CPU_S (fewer halvings at once first, then none)
    room = math.floor(math.log2(finest.step / finest_listed) + EXTEND_MAX_HALVINGS + 1e-9)
    while halvings > 0 and (halvings > room or finest.cpu_time_s * 2 ** halvings * max(repeats, 1) > EXTEND_MAX_CPU_S):
        halvings -= 1
    return finest.step / 2 ** halvings if halvings else None


# ---------------------------------------------------------------------------------------
# readings of the rows


@dataclass
class WorkFlag:
    """A looser setting that cost more than a tighter one of the same solver and mesh."""

    solver: str
    mesh: str
    looser: str
    tighter: str
    what: str
    """`steps` or `CPU`."""
    looser_value: float
    tighter_value: float

    def text(self) -> str:
        unit = " s" if self.what == "CPU" else ""
        fmt = ".3g" if self.what == "CPU" else ".0f"
        return (f"{self.solver}{'' if self.mesh == 'default' else ' ' + self.mesh}: {self.looser} took "
                f"{format(self.looser_value, fmt)}{unit} {self.what}, {self.tighter} "
                f"{format(self.tighter_value, fmt)}{unit} ({self.looser_value / self.tighter_value:.2f}×)")

    def as_dict(self) -> dict:
        return dict(solver=self.solver, mesh=self.mesh, looser=self.looser, tighter=self.tighter, what=self.what,
                    looser_value=self.looser_value, tighter_value=self.tighter_value)


def _looseness(row: BenchRow) -> float:
    """Larger is looser: the step of a fixed-step row, rtol (then atol) of an IDA row."""
    return row.step if row.fixed_step else row.rtol


def work_flags(rows) -> list[WorkFlag]:
    """The looser settings that cost more than a tighter one of the same solver and mesh: more
    steps than :data:`STEPS_NOISE` times the tighter one's, or more CPU time than
    :data:`CPU_NOISE` times it and :data:`CPU_FLOOR_S` beyond. Each looser row is compared with
    every tighter one (a trap need not be next to its neighbour); failed rows are left out (a
    failure is reported as one)."""
    groups: dict[tuple[str, str], list[BenchRow]] = {}
    for r in rows:
        if r.success:
            groups.setdefault((r.solver, r.mesh_label), []).append(r)
    flags = []
    for (solver, mesh), group in groups.items():
        group = sorted(group, key=_looseness, reverse=True)  # loosest first
        for i, loose in enumerate(group):
            for tight in group[i + 1:]:
                if _looseness(tight) >= _looseness(loose):
                    continue  # the same setting twice
                if loose.steps > STEPS_NOISE * tight.steps:
                    flags.append(WorkFlag(solver, mesh, loose.setting, tight.setting, "steps", loose.steps,
                                          tight.steps))
                if (loose.cpu_time_s > CPU_NOISE * tight.cpu_time_s
                        and loose.cpu_time_s - tight.cpu_time_s > CPU_FLOOR_S):
                    flags.append(WorkFlag(solver, mesh, loose.setting, tight.setting, "CPU", loose.cpu_time_s,
                                          tight.cpu_time_s))
    return flags


def pareto_front(rows) -> list[int]:
    """Indices of the successful rows with a finite error that no other such row beats in both
    CPU time and error (≤ in both, < in one)."""
    ok = [(i, r.cpu_time_s, r.error_relative) for i, r in enumerate(rows)
          if r.success and np.isfinite(r.error_relative) and np.isfinite(r.cpu_time_s)]
    front = []
    for i, cpu, err in ok:
        beaten = any(c <= cpu and e <= err and (c < cpu or e < err) for j, c, e in ok if j != i)
        if not beaten:
            front.append(i)
    return front


def _relative_gap(a: np.ndarray, b: np.ndarray) -> float:
    """max |a − b| relative to the range of `a` (its largest |a| when flat)."""
    span = float(np.max(a) - np.min(a))
    scale = span if span > 0 else float(np.max(np.abs(a)))
    err = float(np.max(np.abs(a - b)))
    return err / scale if scale > 0 else (0.0 if err == 0 else math.inf)


def settings_label(s: dict) -> str:
    """`ida rtol 1.0e-10, atol 1.0e-12` or `midpoint4 step 6.2e-06` of a reference run."""
    if not s:
        return ""
    if s.get("step") is not None:
        return f"{s['solver']} step {s['step']:.2e}"
    return f"{s['solver']} rtol {s['rtol']:.1e}, atol {s['atol']:.1e}"


def parse_meshes(items) -> dict[str, list[int]]:
    """Mesh options of the command line, ``["rod=4,8,16", "beam=2,4"]`` → ``{"rod": [4, 8, 16],
    "beam": [2, 4]}`` (a component may be given more than once; its counts are merged)."""
    meshes: dict[str, list[int]] = {}
    for item in items or ():
        comp, sep, counts = str(item).partition("=")
        try:
            values = [int(c) for c in counts.split(",") if c.strip()]
        except ValueError:
            values = []
        if not sep or not comp.strip() or not values or min(values) < 1:
            raise SimulationSetupError(f"mesh option `{item}`: write COMPONENT=N1,N2,... (positive element counts)")
        meshes.setdefault(comp.strip(), [])
        meshes[comp.strip()] += [v for v in values if v not in meshes[comp.strip()]]
    return meshes


def _default_steps(opts: dict, span: float, n_out: int) -> list[float]:
    step = opts.get("step")
    if step:
        return [4 * float(step), 2 * float(step), float(step)]
    dt = span / max(n_out - 1, 1)
    return [dt / d for d in STEP_DIVISORS]


def _mesh_product(meshes: dict[str, list[int]]) -> list[dict[str, int]]:
    if not meshes:
        return [{}]
    comps = list(meshes)
    return [dict(zip(comps, combo)) for combo in itertools.product(*(sorted(set(meshes[c])) for c in comps))]


def _is_reference_output(name: str, names) -> bool:
    return name.endswith("_reference") and name.removesuffix("_reference") in names


def _simulate_once(compiled, solver, value, t_out, **extra):
    """One run; any exception (bad option, inconsistent start) becomes a failed result."""
    kwargs = dict(solver=solver, t_eval=t_out, **extra)
    if solver in FIXED_STEP:
        kwargs["step"] = value
    else:
        kwargs.update(rtol=value, atol=value / 100)
    try:
        return phc.simulate(compiled, **kwargs), ""
    except Exception as err:  # noqa: BLE001 — a failed point is a row, not an exception
        return None, f"{type(err).__name__}: {err}"


def _without_reference_values(scene_path: Path, reference):
    """The scene without the `reference_values` that `reference` (``--reference``) replaces
    (their file, maybe missing, is not read); None: compile the file (and report its mistakes)."""
    from phc.frontend.scene import is_scene_file, load_scene

    scene = load_scene(scene_path)[0] if reference is not None and is_scene_file(scene_path) else None
    if scene is None or scene.spec.reference_values is None:
        return None
    scene.spec = scene.spec.model_copy(update={"reference_values": None})
    return scene


def _published(reference, base, all_outputs, t0: float, t1: float):
    """The reference values: the `reference` file (command line) or the scene's."""
    if reference is None:
        return base.scene.reference_values if base.scene is not None else None
    try:
        published = refs.from_file(reference)
        refs.check(published, all_outputs, t0, t1)
    except refs.ReferenceValuesError as err:
        if err.span is None:
            raise SimulationSetupError(f"--reference: {err.message}") from None
        raise ModelError(DiagnosticList([refs.diagnostic(err)])) from None
    return published


def _merge_times(t_out: np.ndarray, extra: np.ndarray) -> np.ndarray:
    """The output grid with the times of `extra` added (a time within 1e-9 of the span of a
    grid point is that point: no sliver of an output interval)."""
    tol = 1e-9 * max(float(t_out[-1] - t_out[0]), abs(float(t_out[-1])))
    extra = np.clip(np.asarray(extra, dtype=float), t_out[0], t_out[-1])
    add = [t for t in extra if np.min(np.abs(t_out - t)) > tol]
    return np.unique(np.concatenate([t_out, add])) if add else t_out


def _nearest(t_run: np.ndarray, times) -> np.ndarray:
    """Indices of the points of `t_run` nearest to `times`."""
    times = np.asarray(times, dtype=float)
    i = np.clip(np.searchsorted(t_run, times), 1, max(len(t_run) - 1, 1))
    left = np.abs(times - t_run[i - 1]) <= np.abs(t_run[np.minimum(i, len(t_run) - 1)] - times)
    return np.where(left, i - 1, i)


def _run_point(compiled, solver, value, mesh, t_out, repeats, outputs, closed, reference, ref_message,
               grid=None, at_ref=None) -> BenchRow:
    row = BenchRow(solver, dict(mesh))
    if solver in FIXED_STEP:
        row.step = value
    else:
        row.rtol, row.atol = value, value / 100
    if isinstance(compiled, Exception):
        row.message = f"compilation failed: {_short(str(compiled), 300)}"
        return row
    times, result = [], None
    for _ in range(repeats):
        res, problem = _simulate_once(compiled, solver, value, t_out)
        if res is None:
            row.message = problem
            return row
        result = result or res
        times.append(res.cpu_time_s)
        if not res.success:
            break
    row.success, row.message = bool(result.success), result.message
    if solver in FIXED_STEP and getattr(result, "step", None):
        # the step taken: no longer than asked nor an output interval (d / ceil(d / h))
        row.step = float(result.step)
    row.cpu_time_s, row.cpu_time_median_s, row.repeats = min(times), statistics.median(times), len(times)
    row.steps, row.n_residual_evals, row.n_jacobian_evals = result.steps, result.n_residual_evals, result.n_jacobian_evals
    row.energy_balance_relative = float(result.energy_balance_relative)
    row.constraint_drift = float(result.constraint_drift)
    at_ref = at_ref or {}
    complete = result.success and len(result.t) == len(t_out) and np.allclose(result.t, t_out, rtol=0, atol=1e-12 * (
        1 + abs(t_out[-1])))
    _measure(row, result.outputs if complete else None, outputs, closed, reference, grid, at_ref)
    if not result.success:
        row.message = result.message
    elif ref_message and any(name not in closed and name not in at_ref for name in outputs):
        row.message = "no reference: " + ref_message
    return row


def _measure(row: BenchRow, values, outputs, closed, reference, grid=None, at_ref=None) -> None:
    """The row's errors: `values` (the run's outputs by name on the run's times, None when
    the run is incomplete) against the published values, closed forms or reference run."""
    grid = slice(None) if grid is None else grid
    at_ref = at_ref or {}
    for name in outputs:
        if values is None:
            row.errors[name] = row.relative_errors[name] = math.nan
            continue
        if name in at_ref:  # published values at their times: relative to their magnitude
            idx, ref = at_ref[name]
            err = float(np.max(np.abs(values[name][idx] - ref)))
            scale = float(np.max(np.abs(ref)))
            row.errors[name] = err
            row.relative_errors[name] = err / scale if scale > 0 else math.nan
            continue
        if name in closed:
            ref = values[reference_name(name)][grid]
        else:
            ref = reference.get(name)
        if ref is None:
            row.errors[name] = row.relative_errors[name] = math.nan
            continue
        err = float(np.max(np.abs(values[name][grid] - ref)))
        span = float(np.max(ref) - np.min(ref))
        scale = span if span > 0 else float(np.max(np.abs(ref)))
        row.errors[name] = err
        row.relative_errors[name] = err / scale if scale > 0 else math.nan


def scipy_solver(method: str) -> str:
    """The solver name of scipy's `method` in a sweep (``scipy_Radau``)."""
    return f"{SCIPY_PREFIX}{method}"


def _scipy_method(solver: str) -> Optional[str]:
    return solver[len(SCIPY_PREFIX):] if solver.startswith(SCIPY_PREFIX) else None


def _scipy_form(compiled):
    """The ODE form of a compiled model (:class:`phc.study.ode_form.OdeForm`), or why there is none."""
    from phc.study.ode_form import NotAnODE, OdeForm

    if isinstance(compiled, Exception):
        return f"compilation failed: {_short(str(compiled), 300)}"
    try:
        return OdeForm(compiled)
    except NotAnODE as err:
        return str(err)
    except Exception as err:  # noqa: BLE001 — no form is a row, not an exception
        return f"no ODE form: {type(err).__name__}: {err}"


def _run_scipy_point(form, method, rtol, mesh, t_out, repeats, outputs, closed, reference, ref_message,
                     grid=None, at_ref=None) -> BenchRow:
    """A row of scipy's `method` on the ODE form of the model (:mod:`phc.study.ode_form`), measured
    as a phc row: the minimum process time over the repeats (of the integration and of the
    algebraic variables at the output times, as phc's time holds its polish; the ODE form's
    start is phc's consistent initial state, computed once), the errors against the
    same references; `steps` are scipy's steps, the residual and Jacobian evaluations those
    of f and ∂f/∂x."""
    from phc.study.ode_form import integrate

    row = BenchRow(scipy_solver(method), dict(mesh), rtol=rtol, atol=rtol / 100)
    if isinstance(form, str):
        row.message = form
        return row
    times, result = [], None
    for _ in range(repeats):
        res = integrate(form, method, t_out, rtol, rtol / 100)
        result = result or res
        times.append(res["cpu_time_s"])
        if not res["success"]:
            break
    row.success, row.message = bool(result["success"]), result["message"]
    row.cpu_time_s, row.cpu_time_median_s, row.repeats = min(times), statistics.median(times), len(times)
    row.steps, row.n_residual_evals, row.n_jacobian_evals = result["steps"], result["nfev"], result["njev"]
    complete = row.success and len(result["t"]) == len(t_out)
    values = form.outputs(result["t"], result["y"], result["yp"], result["p"]) if complete else None
    _measure(row, values, outputs, closed, reference, grid, at_ref)
    if row.success and ref_message and any(name not in closed and name not in (at_ref or {}) for name in outputs):
        row.message = "no reference: " + ref_message
    return row


# ---------------------------------------------------------------------------------------
# the reference run and its cache


def _cache_dir(reference_cache) -> Optional[Path]:
    if reference_cache is False:
        return None
    if reference_cache not in (None, True):
        path = Path(reference_cache)
    else:
        from phc.codegen.load import cache_dir
        path = cache_dir() / "bench"
    try:
        path.mkdir(parents=True, exist_ok=True)
    except OSError:
        return None
    return path


def reference_key(scene_path: Path, model_path: Path, settings: dict, t_out: np.ndarray, outputs) -> str:
    """SHA-256 of the scene file, the model file, the phc version and the reference
    settings (solver, tolerances, mesh, output grid, outputs)."""
    h = hashlib.sha256()
    for path in (scene_path, model_path):
        h.update(Path(path).read_bytes())
        h.update(b"\0")
    meta = dict(settings, t=[float(t_out[0]), float(t_out[-1]), len(t_out)], outputs=sorted(outputs),
                version=phc.__version__)
    h.update(json.dumps(meta, sort_keys=True, default=str).encode())
    return h.hexdigest()[:32]


def _reference_run(scene_path, model_path, settings, t_out, outputs, reference_cache, compile_fn):
    """(outputs by name, cache hit, cache file, failure message)."""
    folder = _cache_dir(reference_cache)
    path = None
    if folder is not None:
        path = folder / f"ref_{reference_key(scene_path, model_path, settings, t_out, outputs)}.npz"
        if path.is_file():
            try:
                with np.load(path) as data:
                    if np.array_equal(data["t"], t_out):
                        meta = json.loads(str(data["meta"]))
                        settings["cpu_time_s"] = float(meta.get("cpu_time_s", math.nan))
                        return {name: np.array(data[f"out_{name}"]) for name in outputs}, True, path, ""
            except (OSError, KeyError, ValueError):
                pass  # a damaged entry is recomputed
    compiled = compile_fn()
    if isinstance(compiled, Exception):
        return {}, False, path, f"the reference mesh does not compile: {_short(str(compiled), 300)}"
    extra = dict(max_steps=settings["max_steps"])
    if settings["solver"] not in FIXED_STEP:
        extra["max_order"] = settings["max_order"]
    value = settings["step"] if settings["solver"] in FIXED_STEP else settings["rtol"]
    res, problem = _simulate_once(compiled, settings["solver"], value, t_out, **extra)
    if res is None:
        return {}, False, path, problem
    if not res.success or len(res.t) != len(t_out):
        return {}, False, path, res.message
    settings["cpu_time_s"] = float(res.cpu_time_s)
    ref = {name: np.asarray(res.outputs[name], dtype=float) for name in outputs}
    if path is not None:
        try:
            with atomic_write(path) as fh:
                np.savez(fh, t=t_out, **{f"out_{k}": v for k, v in ref.items()},
                         meta=json.dumps(dict(settings, scene=str(scene_path)), default=str))
        except OSError:
            pass
    return ref, False, path, ""


# ---------------------------------------------------------------------------------------
# output files


def _write_files(report: BenchReport, out_dir: Path, plot: bool) -> None:
    rows = [r.as_dict(report.outputs) for r in report.rows]
    columns = list(BenchRow("", {}).as_dict(report.outputs))
    csv_path = out_dir / "bench.csv"
    with atomic_write(csv_path, "w", newline="") as fh:  # every file: temporary file + rename
        writer = csv.DictWriter(fh, fieldnames=columns)
        writer.writeheader()
        for row in rows:
            writer.writerow({k: _csv_value(v) for k, v in row.items()})
    report.paths["csv"] = csv_path
    md_path = out_dir / "bench.md"
    write_text(md_path, _markdown(report))
    report.paths["md"] = md_path
    if not plot:
        report.plot_skipped = "not requested"
        return
    try:
        from matplotlib.backends.backend_agg import FigureCanvasAgg
        from matplotlib.figure import Figure
    except ImportError:
        report.plot_skipped = f"matplotlib is not installed ({INSTALL_HINT})"
        return
    png = out_dir / "bench.png"
    _plot(report, png, Figure, FigureCanvasAgg)
    report.paths["png"] = png


def _markdown(report: BenchReport) -> str:
    lines = [f"# Work-precision: {report.name}", ""]
    refs_ = []
    for out, kind in report.reference.items():
        if kind == "reference run" and report.reference_settings:
            s = report.reference_settings
            kind = f"reference run ({settings_label(s)}, mesh {mesh_label(s['mesh'])})"
        refs_.append(f"`{out}`: {kind}")
    published = [kind.startswith("published reference") for kind in report.reference.values()]
    what = []
    if not all(published):
        what.append("max over the output grid of |output − reference| (relative: divided by the reference's range)")
    if any(published):
        what.append("against a published reference, max over its reference times of |output − reference value| "
                    "(relative: divided by the largest |reference value|)")
    lines.append("Error: " + "; ".join(what) + "; the row's error is the largest over the outputs. Reference — "
                 + "; ".join(refs_) + "." + (f" Source: {report.reference_source}." if report.reference_source
                                             else ""))
    if report.reference_message:
        lines.append(f"\n**The reference run failed**: {report.reference_message}")
    if report.reference_check_message:
        lines.append(f"\nCross-check: the second reference run ({settings_label(report.reference_check)}) failed, "
                     f"the reference is not cross-checked: {_short(report.reference_check_message, 300)}")
    elif report.reference_check:
        gaps = ", ".join(f"`{o}` {_fmt(g)}" for o, g in report.reference_gap.items())
        lines.append(f"\nCross-check: a second reference run ({settings_label(report.reference_check)}) differs from "
                     f"it by {gaps} (relative to the range): a relative error below that is not resolved.")
    if report.interrupted:
        lines.append(f"\n**Interrupted**: {len(report.rows)} of {report.planned} runs finished.")
    lines += ["", ("| solver | mesh | rtol / step | ok | CPU [s] | steps | error | rel. error | front | "
                   "energy balance (rel.) | constraint drift | message |"),
              "|---|---|---|---|---:|---:|---:|---:|:---:|---:|---:|---|"]
    for r in report.rows:
        lines.append(f"| {r.solver} | {r.mesh_label} | {r.setting} | {'yes' if r.success else 'no'} | "
                     f"{_fmt(r.cpu_time_s, '.3g')} | {r.steps} | {_fmt(r.error)} | {_fmt(r.error_relative)} | "
                     f"{'◆' if r.pareto else ''} | "
                     f"{_fmt(r.energy_balance_relative)} | {_fmt(r.constraint_drift)} | "
                     f"{_short(r.message).replace('|', '/')} |")
    if len(report.outputs) > 1:  # the error of each output (relative), beside the largest
        lines += ["", "Relative error per output:", "",
                  "| solver | mesh | rtol / step | " + " | ".join(f"`{o}`" for o in report.outputs) + " |",
                  "|---|---|---|" + "---:|" * len(report.outputs)]
        for r in report.rows:
            lines.append(f"| {r.solver} | {r.mesh_label} | {r.setting} | "
                         + " | ".join(_fmt(r.relative_errors.get(o, math.nan)) for o in report.outputs) + " |")
    lines += ["", "Front ◆: no other run is both faster and more accurate (relative error). Work check — a "
              f"looser setting must not take more steps (beyond {STEPS_NOISE:g}×) or more CPU time (beyond "
              f"{CPU_NOISE:g}× and {CPU_FLOOR_S:g} s) than a tighter one of the same solver: "
              + ("passed." if not report.flags else f"**{len(report.flags)} flagged**:"), ""]
    lines += [f"- {flag.text()}" for flag in report.flags]
    return "\n".join(lines).rstrip("\n") + "\n"


def _plot(report: BenchReport, path: Path, Figure, Canvas) -> None:
    fig = Figure(figsize=(7, 5))
    Canvas(fig)
    ax = fig.add_subplot(1, 1, 1)
    groups: dict[tuple[str, str], list[BenchRow]] = {}
    for r in report.rows:
        groups.setdefault((r.solver, r.mesh_label), []).append(r)
    drawn = 0
    for (solver, mesh), rows in groups.items():
        # joined from the loosest setting to the tightest (not by CPU time: timing noise
        # must show as a kink, not reorder the line)
        ok = [r for r in rows if r.success and r.cpu_time_s > 0 and np.isfinite(r.error) and r.error > 0]
        pts = [(r.cpu_time_s, r.error, r) for r in sorted(ok, key=lambda r: -(r.step if r.fixed_step else r.rtol))]
        if not pts:
            continue
        label = solver if mesh == "default" else f"{solver}, {mesh}"
        ax.loglog([p[0] for p in pts], [p[1] for p in pts], "o-", label=label)
        for cpu, err, r in pts:
            ax.annotate(f"{r.step:.2g}" if r.fixed_step else f"{r.rtol:.0e}", (cpu, err), fontsize=7,
                        textcoords="offset points", xytext=(4, 4))
        drawn += 1
    ax.set_xlabel("CPU time [s]")
    ax.set_ylabel("max error of the outputs (absolute)")
    ax.set_title(f"{report.name}: work-precision" + (" (interrupted)" if report.interrupted else ""))
    ax.grid(True, which="both", alpha=0.3)
    if drawn:
        ax.legend(fontsize=8)
    else:
        ax.text(0.5, 0.5, "no successful run with a finite, nonzero error", ha="center", va="center",
                transform=ax.transAxes)
    fig.tight_layout()
    with atomic_write(path) as fh:
        fig.savefig(fh, format="png", dpi=120)


# ---------------------------------------------------------------------------------------
# progress and formatting


class _SweepBar:
    """A bar over the sweep's points: redrawn on a terminal, one line per point in a log."""

    def __init__(self, total: int, enabled: bool = True, stream=None) -> None:
        self.total, self.done, self.enabled = total, 0, enabled and total > 0
        self.stream = stream or sys.stderr
        self.tty = getattr(self.stream, "isatty", lambda: False)()
        self.start = time.monotonic()
        self.label = ""

    def show(self, label: str) -> None:
        self.label = label
        if self.enabled and self.tty:
            self._draw()

    def advance(self) -> None:
        self.done += 1
        if self.enabled:
            self._draw(log=not self.tty)

    def _draw(self, log: bool = False) -> None:
        width = 30
        frac = self.done / self.total
        elapsed = time.monotonic() - self.start
        eta = f"eta {elapsed / frac - elapsed:.0f} s" if self.done else ""
        text = f"bench [{'#' * int(frac * width):<{width}}] {self.done}/{self.total}  {self.label}  " \
               f"elapsed {elapsed:.1f} s {eta}"
        if self.tty:
            self.stream.write("\r" + text[:160].ljust(120))
        elif log:
            self.stream.write(text + "\n")
        self.stream.flush()

    def close(self) -> None:
        if self.enabled and self.tty:
            self.stream.write("\n")
            self.stream.flush()


def mesh_label(mesh: dict) -> str:
    return ",".join(f"{c}={n}" for c, n in sorted(mesh.items())) or "default"


def _point_label(mesh, solver, value) -> str:
    setting = f"step {value:.3g}" if solver in FIXED_STEP else f"rtol {value:.0e}"
    return f"{solver} {setting}" + ("" if not mesh else f" {mesh_label(mesh)}")


def _max_or_nan(values) -> float:
    values = list(values)
    if not values or any(not np.isfinite(v) for v in values):
        return math.nan
    return float(max(values))


def _blank(value):
    return "" if value is None else value


def _csv_value(value):
    if isinstance(value, float):
        return "" if math.isnan(value) else repr(value)
    return value


def _fmt(value, spec: str = ".2e") -> str:
    if value is None or (isinstance(value, float) and not np.isfinite(value)):
        return "—"
    return format(value, spec)


def _short(text: str, n: int = 120) -> str:
    text = " ".join(str(text).split())
    return text if len(text) <= n else text[: n - 1] + "…"


def _jsonable(row: dict) -> dict:
    return {k: (None if isinstance(v, float) and math.isnan(v) else v) for k, v in row.items()}


__all__ = ["run_bench", "BenchReport", "BenchRow", "WorkFlag", "parse_meshes", "reference_key", "mesh_label",
           "work_flags", "pareto_front", "settings_label", "scipy_solver", "SCIPY_PREFIX"]
