"""`phc sweep`: parameter studies — grids, Latin-hypercube and random samples — on a local
process pool or a Dask cluster.

Input: a model or scene file and the swept values (``NAME=SPEC``, :mod:`phc.spec.sweep`,
and a scene's ``sweep:`` section). Output: one row per run in a CSV file (and Parquet
with pyarrow), optionally the time series of every run in a second CSV file.

How a sweep runs
----------------
* **One compilation per sweep.** The model is compiled once in this process; parameters
  are run-time arguments of the generated module. Compile-time parameters (a mesh length,
  a coefficient varying along a distributed component) and ``accuracy.mesh.COMPONENT``
  group the points by compilation: each group is compiled once
  (:func:`phc.scene.scene_variant`, nothing written).
* **Workers get the compiled model by value**: a :class:`~phc.pipeline.CompiledModel`
  pickles as its generated source plus metadata and is rebuilt on the worker from the
  text in memory (:func:`phc.codegen.load.load_generated`); workers never read a model
  file. A pickle is code to whoever loads it, so it travels only from this process to the
  workers it starts or the Dask cluster the user names (see docs/security.md).
* **Executors**: a local process pool (default; one BLAS thread per worker) or Dask
  distributed (``pip install "port-hamiltonian-compiler[cluster]"``): a ``LocalCluster`` or a running scheduler.
  The same function runs every point in both.
* **Robustness**: a point that fails (the solver stops, the start is inconsistent, a
  parameter makes the model impossible to evaluate) is a row with ``success`` false and
  its message. Rows are appended to the CSV file as they arrive, each by one ``write`` of
  one complete line to a file opened for appending, then flushed to disk; ``resume``
  skips the points already there (a torn last line is dropped). A worker lost mid-run is
  run again elsewhere (a local pool is restarted; Dask reschedules it) and the row's
  ``attempts`` says so. When the sweep completes the CSV file is rewritten in point order.
"""

from __future__ import annotations

import csv
import hashlib
import io
import itertools
import json
import math
import multiprocessing
import os
import signal
import socket
import sys
import time
import uuid
import warnings
from concurrent.futures import ProcessPoolExecutor, as_completed
from concurrent.futures.process import BrokenProcessPool
from contextlib import contextmanager
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Iterator, Optional, Sequence, Union

import numpy as np

from phc.diagnostics import Diagnostic, DiagnosticList
from phc.errors import ModelError, SimulationSetupError, SweepSetupError
from phc.io import atomic_write
from phc.spec.sweep import Axis, SpecError, parse_spec

ACCURACY_OPTIONS = {"accuracy.rtol": "rtol", "accuracy.atol": "atol", "accuracy.step": "step"}
MESH_PREFIX = "accuracy.mesh."
MAX_POINTS = 1_000_000
MAX_ATTEMPTS = 3
"""Runs of one point on a local pool whose worker process died before it is recorded as failed
(Dask: the scheduler's ``distributed.scheduler.allowed-failures``)."""
STATS = ("final", "min", "max", "rms")
RUN_COLUMNS = ("success", "message", "t_final", "steps", "n_residual_evals", "n_jacobian_evals",
               "energy_balance_error", "energy_balance_relative", "constraint_drift", "velocity_drift")
MACHINE_COLUMNS = ("cpu_time_s", "wall_time_s", "attempts", "worker")
"""Columns that differ between two runs of the same point (timing, where it ran)."""
INSTALL_CLUSTER = 'pip install "port-hamiltonian-compiler[cluster]"'
INSTALL_PARQUET = 'pip install "port-hamiltonian-compiler[parquet]"'
INSTALL_PLOT = 'pip install "port-hamiltonian-compiler[plot]"'


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


def _raise(problems, locate) -> None:
    if locate is not None and all(name and locate(name) is not None for name, _, _ in problems):
        diags = DiagnosticList(Diagnostic("PHC-E606", message, span=locate(name), hint=hint or None,
                                          path=f"sweep.parameters.{name}") for name, message, hint in problems)
        raise ModelError(diags.sorted())
    name, message, hint = problems[0]
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


# ---------------------------------------------------------------------------------------
# one run (executed on the workers)


def run_point(compiled, task: dict) -> dict:
    """Run one point: ``{"index", "row", "series"}``. Never raises for a failing point:
    any error becomes ``success`` false with its message."""
    from phc.errors import InconsistentInitialError
    from phc.simulation import SimulationInterrupted, simulate

    outputs = list(compiled.module.OUTPUTS)
    row: dict[str, Any] = {"success": False, "message": "", "t_final": math.nan, "steps": 0, "n_residual_evals": 0,
                           "n_jacobian_evals": 0, **{c: math.nan for c in RUN_COLUMNS[6:]}}
    for name in outputs:
        row.update({f"{name}.{s}": math.nan for s in STATS})
    series = None
    wall = time.perf_counter()
    cpu = math.nan
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        try:
            result = simulate(compiled, params=task["params"], **task["options"], **task["run"])
        except SimulationInterrupted:
            raise
        except InconsistentInitialError as err:
            row["message"] = "inconsistent initial values: " + "; ".join(err.problems)
            result = None
        except Exception as err:  # noqa: BLE001 — a failing point is a row, not an exception
            row["message"] = f"{'' if isinstance(err, SimulationSetupError) else type(err).__name__ + ': '}{err}"
            result = None
    if result is not None:
        cpu = float(result.cpu_time_s)
        row.update(success=bool(result.success), message=result.message,
                   t_final=float(result.t[-1]) if len(result.t) else math.nan, steps=int(result.steps),
                   n_residual_evals=int(result.n_residual_evals), n_jacobian_evals=int(result.n_jacobian_evals),
                   energy_balance_error=float(result.energy_balance_error),
                   energy_balance_relative=float(result.energy_balance_relative),
                   constraint_drift=float(result.constraint_drift), velocity_drift=float(result.velocity_drift))
        for name in outputs:
            v = np.asarray(result.outputs[name], dtype=float)
            if len(v):
                row.update({f"{name}.final": float(v[-1]), f"{name}.min": float(v.min()),
                            f"{name}.max": float(v.max()), f"{name}.rms": float(np.sqrt(np.mean(v * v)))})
        if task.get("series"):
            series = (np.asarray(result.t, dtype=float), {n: np.asarray(result.outputs[n], dtype=float)
                                                          for n in outputs})
    notes = sorted({str(w.message) for w in caught})
    if notes:
        row["message"] = row["message"] + "".join(f" (warning: {n})" for n in notes)
    row["message"] = " ".join(str(row["message"]).split())  # one line per row
    row.update(cpu_time_s=cpu, wall_time_s=time.perf_counter() - wall, attempts=int(task.get("attempt", 1)),
               worker=task.get("worker") or f"{socket.gethostname()}:{os.getpid()}")
    return {"index": task["index"], "row": row, "series": series}


_MODELS: dict = {}
_INIT_ERROR: list = []


def _init_pool_worker(blob: bytes) -> None:
    """Initializer of a local pool process: Ctrl-C is the parent's business (it stops the
    pool), one BLAS thread, and the compiled models unpickled once (phc's own pickle, made
    by the parent process for its workers; never read from a file)."""
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    try:
        from threadpoolctl import threadpool_limits

        threadpool_limits(1)
    except Exception:  # noqa: BLE001 — optional; the environment set by the parent holds
        pass
    try:
        import pickle

        _MODELS.update(pickle.loads(blob))
    except Exception as err:  # noqa: BLE001 — reported on every row instead of a broken pool
        _INIT_ERROR.append(f"{type(err).__name__}: {err}")


def _pool_task(task: dict) -> dict:
    if _INIT_ERROR:
        return _failed(task, f"the worker could not load the compiled model: {_INIT_ERROR[0]}")
    return run_point(_MODELS[task["group"]], task)


def _unpickle_model(blob: bytes):
    """The compiled model on a Dask worker (phc's own pickle, sent by the sweep's client)."""
    import pickle

    return pickle.loads(blob)


def _dask_task(compiled, task: dict, topic: str) -> dict:
    """A point on a Dask worker; its start is logged as an event, so that a run repeated
    after a lost worker is seen by the client."""
    try:
        from distributed import get_worker

        worker = get_worker()
        task = dict(task, worker=worker.address)
        worker.log_event(topic, {"point": task["index"], "worker": worker.address})
    except Exception:  # noqa: BLE001 — outside a worker (tests): no event
        pass
    return run_point(compiled, task)


def _failed(task: dict, message: str, outputs: Sequence[str] = ()) -> dict:
    row: dict[str, Any] = {"success": False, "message": " ".join(message.split()), "t_final": math.nan, "steps": 0,
                           "n_residual_evals": 0, "n_jacobian_evals": 0, **{c: math.nan for c in RUN_COLUMNS[6:]},
                           "cpu_time_s": math.nan, "wall_time_s": math.nan, "attempts": int(task.get("attempt", 1)),
                           "worker": ""}
    for name in outputs:
        row.update({f"{name}.{s}": math.nan for s in STATS})
    return {"index": task["index"], "row": row, "series": None}


# ---------------------------------------------------------------------------------------
# executors


@contextmanager
def _one_blas_thread():
    """Worker processes started inside get one BLAS/OpenMP thread each (set before their
    numpy is imported); this process's own setting is restored after."""
    names = ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS")
    saved = {k: os.environ.get(k) for k in names}
    os.environ.update({k: "1" for k in names})
    try:
        yield
    finally:
        for k, v in saved.items():
            if v is None:
                os.environ.pop(k, None)
            else:
                os.environ[k] = v


def default_workers() -> int:
    try:
        return max(1, len(os.sched_getaffinity(0)))
    except AttributeError:
        return max(1, os.cpu_count() or 1)


def start_method() -> str:
    """How the local pool starts its processes: `fork` on Linux when this process runs no
    other thread (the workers start at once, with phc already imported; they still rebuild
    the compiled model from its pickle), else `forkserver` (POSIX) or `spawn`. The
    environment variable ``PHC_SWEEP_START_METHOD`` overrides it."""
    import threading

    methods = multiprocessing.get_all_start_methods()
    chosen = os.environ.get("PHC_SWEEP_START_METHOD", "")
    if chosen in methods:
        return chosen
    if sys.platform.startswith("linux") and "fork" in methods and threading.active_count() == 1:
        return "fork"
    return "forkserver" if "forkserver" in methods else "spawn"


class LocalExecutor:
    """A pool of `workers` processes on this machine (forkserver where available, else
    spawn: no state of this process leaks into them but the compiled models)."""

    name = "local"

    def __init__(self, workers: Optional[int] = None) -> None:
        self.workers = workers or default_workers()
        self.startup_s = math.nan

    def describe(self) -> str:
        return f"local process pool, {self.workers} worker{'s' if self.workers != 1 else ''}"

    def _pool(self, models: dict) -> ProcessPoolExecutor:
        ctx = multiprocessing.get_context(start_method())
        if ctx.get_start_method() == "forkserver":
            ctx.set_forkserver_preload(["phc.sweep", "phc.pipeline", "phc.simulation"])
        import pickle

        return ProcessPoolExecutor(max_workers=self.workers, mp_context=ctx, initializer=_init_pool_worker,
                                   initargs=(pickle.dumps(models, protocol=pickle.HIGHEST_PROTOCOL),))

    def run(self, models: dict, tasks: list[dict], outputs: Sequence[str]) -> Iterator[dict]:
        attempts = {t["index"]: 1 for t in tasks}
        pending = list(tasks)
        started = time.perf_counter()
        with _one_blas_thread():
            while pending:
                pool = self._pool(models)
                futures = {}
                finished = False
                try:
                    futures = {pool.submit(_pool_task, dict(t, attempt=attempts[t["index"]])): t for t in pending}
                    broken = []
                    for fut in as_completed(futures):
                        task = futures[fut]
                        if math.isnan(self.startup_s):
                            self.startup_s = time.perf_counter() - started
                        try:
                            out = fut.result()
                        except BrokenProcessPool:
                            broken.append(task)
                            continue
                        except Exception as err:  # noqa: BLE001 — e.g. a result that cannot be sent back
                            out = _failed(dict(task, attempt=attempts[task["index"]]),
                                          f"the worker failed: {type(err).__name__}: {err}", outputs)
                        yield out
                    finished = True
                finally:
                    if finished:
                        pool.shutdown(wait=True)
                    else:  # Ctrl-C or the consumer stopped: stop the workers now
                        _stop_pool(pool)
                pending = []
                for task in broken:
                    attempts[task["index"]] += 1
                    if attempts[task["index"]] > MAX_ATTEMPTS:
                        yield _failed(dict(task, attempt=MAX_ATTEMPTS),
                                      f"the worker process died {MAX_ATTEMPTS} times while this point was running or "
                                      "queued (out of memory? a crash in a native library?)", outputs)
                    else:
                        pending.append(task)


def _stop_pool(pool: ProcessPoolExecutor) -> None:
    procs = list((getattr(pool, "_processes", None) or {}).values())
    pool.shutdown(wait=False, cancel_futures=True)
    for p in procs:
        try:
            p.terminate()
        except Exception:  # noqa: BLE001
            pass
    for p in procs:
        p.join(timeout=5)


class DaskExecutor:
    """Dask distributed: a running scheduler (`address`: ``tcp://host:8786``, or a scheduler
    file written by ``dask scheduler --scheduler-file``), else a ``LocalCluster`` of
    `workers` processes with one thread each. `client` uses an existing Client."""

    name = "dask"

    def __init__(self, address: Optional[str] = None, workers: Optional[int] = None, client=None) -> None:
        try:
            import distributed  # noqa: F401
        except ImportError:
            raise SweepSetupError(f"the dask executor needs dask.distributed: {INSTALL_CLUSTER}") from None
        self.address, self.workers, self.client = address, workers, client
        self.startup_s = math.nan
        self._where = ""

    def describe(self) -> str:
        return f"dask, {self._where}" if self._where else "dask"

    @contextmanager
    def _client(self):
        from distributed import Client, LocalCluster

        if self.client is not None:
            self._where = f"client of {self.client.scheduler.address}"
            yield self.client
            return
        if self.address:
            path = Path(self.address)
            kwargs = {"scheduler_file": str(path)} if path.suffix == ".json" and path.is_file() else \
                {"address": self.address}
            client = Client(**kwargs, timeout=30)
            self._where = f"scheduler {client.scheduler.address}, {len(client.scheduler_info()['workers'])} workers"
            try:
                yield client
            finally:
                client.close()
            return
        import logging

        n = self.workers or default_workers()
        cluster = LocalCluster(n_workers=n, threads_per_worker=1, processes=True, dashboard_address=None,
                               silence_logs=logging.ERROR)
        client = Client(cluster)
        self._where = f"LocalCluster, {n} worker{'s' if n != 1 else ''}"
        try:
            yield client
        finally:
            client.close()
            cluster.close()

    def run(self, models: dict, tasks: list[dict], outputs: Sequence[str]) -> Iterator[dict]:
        from distributed import as_completed as dask_completed

        started = time.perf_counter()
        with self._client() as client:
            topic = f"phc-sweep-{uuid.uuid4().hex[:12]}"
            starts: dict[int, set] = {}

            def seen(event) -> None:
                _, msg = event
                starts.setdefault(int(msg["point"]), set()).add(str(msg["worker"]))

            client.subscribe_topic(topic, seen)
            futures, loaded = {}, {}
            try:
                # The compiled models as tasks that unpickle them (not scattered data): a worker
                # lost with its copy is recomputed from the task, not lost with it.
                import pickle

                loaded = {key: client.submit(_unpickle_model, pickle.dumps(model, protocol=pickle.HIGHEST_PROTOCOL),
                                             pure=False, key=f"{topic}-model-{i}")
                          for i, (key, model) in enumerate(models.items())}
                futures = {client.submit(_dask_task, loaded[t["group"]], t, topic, pure=False,
                                         key=f"{topic}-{t['index']}"): t for t in tasks}
                for fut in dask_completed(list(futures)):
                    task = futures[fut]
                    if math.isnan(self.startup_s):
                        self.startup_s = time.perf_counter() - started
                    try:
                        out = fut.result()
                    except Exception as err:  # noqa: BLE001 — KilledWorker, a worker without phc, ...
                        runs = max(len(starts.get(task["index"], ())), 1)
                        out = _failed(dict(task, attempt=runs), _dask_failure(err), outputs)
                    else:
                        workers = set(starts.get(task["index"], ())) | {out["row"]["worker"]}
                        out["row"]["attempts"] = len(workers)
                        if len(workers) > 1:
                            lost = ", ".join(sorted(workers - {out["row"]["worker"]}))
                            out["row"]["message"] += f" (run again after its worker was lost: {lost})"
                    fut.release()
                    yield out
            finally:
                for fut in [*futures, *loaded.values()]:
                    if not fut.done():
                        fut.cancel()
                    fut.release()
                try:
                    client.unsubscribe_topic(topic)
                except Exception:  # noqa: BLE001
                    pass


def _dask_failure(err: BaseException) -> str:
    kind = type(err).__name__
    if kind == "KilledWorker":
        return ("its worker was lost every time it ran this point (KilledWorker: out of memory? a crash in a "
                f"native library?): {err}")
    if isinstance(err, (ImportError, ModuleNotFoundError)):
        return f"the worker cannot import phc ({err}); install phc on every worker"
    return f"the worker failed: {kind}: {err}"


# ---------------------------------------------------------------------------------------
# result files


def _cell(value) -> str:
    if isinstance(value, bool):
        return "true" if value else "false"
    if isinstance(value, float):
        return repr(value)
    if value is None:
        return ""
    return str(value)


def _csv_line(cells: Sequence[str]) -> bytes:
    buf = io.StringIO()
    csv.writer(buf, lineterminator="\n").writerow(cells)
    return buf.getvalue().encode()


def _parse(value: str, kind: str):
    if kind == "bool":
        return value.strip().lower() == "true"
    if kind == "int":
        return int(value) if value else 0
    if kind == "str":
        return value
    return float(value) if value else math.nan


class AppendLog:
    """A CSV file written one complete line per ``write`` to a file opened for appending,
    flushed to disk after each: a killed process leaves whole rows (at most a torn last
    line, dropped by :meth:`load`)."""

    def __init__(self, path: Path, columns: Sequence[str]) -> None:
        self.path, self.columns = Path(path), list(columns)

    def create(self) -> None:
        with atomic_write(self.path) as fh:
            fh.write(_csv_line(self.columns))

    def append(self, rows: Sequence[Sequence]) -> None:
        data = b"".join(_csv_line([_cell(v) for v in row]) for row in rows)
        fd = os.open(self.path, os.O_WRONLY | os.O_APPEND)
        try:
            view = memoryview(data)
            while view:
                view = view[os.write(fd, view):]
            os.fsync(fd)
        finally:
            os.close(fd)

    def read(self) -> tuple[list[str], list[list[str]]]:
        """(header, complete rows); a torn last line (no newline) is left out."""
        data = self.path.read_bytes()
        if not data.endswith(b"\n"):
            data = data[: data.rfind(b"\n") + 1]
        lines = list(csv.reader(io.StringIO(data.decode("utf-8", errors="replace"))))
        if not lines:
            return [], []
        header = lines[0]
        return header, [line for line in lines[1:] if len(line) == len(header)]

    def rewrite(self, rows: Sequence[Sequence]) -> None:
        with atomic_write(self.path) as fh:
            fh.write(_csv_line(self.columns))
            for row in rows:
                fh.write(_csv_line([_cell(v) for v in row]))


def _kinds(columns: Sequence[str]) -> dict[str, str]:
    kinds = {c: "float" for c in columns}
    kinds.update(point="int", steps="int", n_residual_evals="int", n_jacobian_evals="int", attempts="int",
                 success="bool", message="str", worker="str")
    return kinds


# ---------------------------------------------------------------------------------------
# the sweep


@dataclass
class SweepReport:
    """What :func:`run_sweep` did."""

    name: str
    file: str
    design: Design
    columns: list[str]
    units: dict[str, str]
    rows: dict[int, dict] = field(default_factory=dict)
    """Point index -> row (typed values), the earlier rows of a resumed sweep included."""
    resumed: int = 0
    """Rows found in the results file and skipped."""
    executor: str = ""
    workers_startup_s: float = math.nan
    compilations: list[dict] = field(default_factory=list)
    """Per compilation group: label, points, compile_time_s, error."""
    n_compilations: int = 1
    """Compilations made (the base model's, and one per group compiled with other values)."""
    paths: dict[str, Path] = field(default_factory=dict)
    parquet_skipped: str = ""
    interrupted: bool = False
    elapsed_s: float = 0.0
    run_elapsed_s: float = 0.0
    """Wall time from the first submission to the last row (workers' start included)."""

    @property
    def planned(self) -> int:
        return len(self.design.points)

    @property
    def failed(self) -> list[dict]:
        return [r for _, r in sorted(self.rows.items()) if not r["success"]]

    @property
    def complete(self) -> bool:
        return len(self.rows) == self.planned

    @property
    def success(self) -> bool:
        return self.complete and not self.failed and not self.interrupted

    def ordered(self) -> list[dict]:
        return [self.rows[i] for i in sorted(self.rows)]

    def render_text(self) -> str:
        d = self.design
        what = ", ".join(f"{a.name} ({a.describe()})" for a in d.axes) or "no parameter (one run)"
        sampled = f"; {d.samples} {d.sampling} samples, seed {d.seed}" if d.samples else ""
        status = ("INTERRUPTED — finished rows kept, rerun with --resume" if self.interrupted else
                  "complete" if self.complete else "incomplete")
        lines = [f"{self.name}: sweep of {self.planned} runs over {what}{sampled} — {status}"]
        compile_s = sum({c["label"]: c["compile_time_s"] for c in self.compilations
                         if not math.isnan(c["compile_time_s"])}.values())
        n = self.n_compilations
        lines.append(f"  compiled  {n} compilation{'s' if n != 1 else ''} for {self.planned} runs ({compile_s:.2f} s)"
                     + "".join(f"; {c['label']}: FAILED" for c in self.compilations if c["error"]))
        ran = len(self.rows) - self.resumed
        cpu = [r["cpu_time_s"] for r in self.rows.values() if not math.isnan(r["cpu_time_s"])]
        lines.append(f"  ran       {ran} run{'s' if ran != 1 else ''} on {self.executor} in {self.run_elapsed_s:.1f} s"
                     + (f" ({self.resumed} earlier rows kept)" if self.resumed else "")
                     + (f"; median {np.median(cpu):.3g} s CPU per run" if cpu else ""))
        ok = sum(1 for r in self.rows.values() if r["success"])
        lines.append(f"  results   {ok} succeeded, {len(self.rows) - ok} failed"
                     + (f", {self.planned - len(self.rows)} not run" if not self.complete else ""))
        for r in self.failed[:10]:
            values = ", ".join(f"{a.name} = {r[a.name]:.6g}" for a in d.axes)
            lines.append(f"  FAILED    point {r['point']} ({values}): {_short(r['message'])}")
        if len(self.failed) > 10:
            lines.append(f"  FAILED    ... and {len(self.failed) - 10} more (success = false in the results)")
        for key in ("csv", "parquet", "series", "meta", "plot"):
            if key in self.paths:
                lines.append(f"  wrote     {self.paths[key]}")
        if self.parquet_skipped:
            lines.append(f"  parquet   skipped: {self.parquet_skipped}")
        return "\n".join(lines)

    def summary(self) -> dict:
        return {"model": self.name, "file": self.file, "planned": self.planned, "rows": len(self.rows),
                "resumed": self.resumed, "succeeded": sum(1 for r in self.rows.values() if r["success"]),
                "failed": len(self.failed), "interrupted": self.interrupted, "executor": self.executor,
                "elapsed_s": self.elapsed_s, "run_elapsed_s": self.run_elapsed_s,
                "compilations": [{k: (None if isinstance(v, float) and math.isnan(v) else v) for k, v in c.items()}
                                 for c in self.compilations], "n_compilations": self.n_compilations,
                "axes": [{"name": a.name, "spec": a.text} for a in self.design.axes],
                "samples": self.design.samples, "seed": self.design.seed, "sampling": self.design.sampling,
                "paths": {k: str(v) for k, v in self.paths.items()}, "parquet_skipped": self.parquet_skipped}


def results_paths(out: Union[str, os.PathLike]) -> dict[str, Path]:
    """The CSV file, the Parquet copy and the sidecar description of a results path
    (``x.csv`` or ``x.parquet`` → ``x.csv``, ``x.parquet``, ``x.sweep.json``)."""
    out = Path(out)
    stem = out.with_suffix("")
    return {"csv": stem.with_suffix(".csv"), "parquet": stem.with_suffix(".parquet"),
            "meta": stem.with_name(stem.name + ".sweep.json")}


def parquet_available() -> bool:
    try:
        import pyarrow  # noqa: F401
        import pyarrow.parquet  # noqa: F401
    except ImportError:
        return False
    return True


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


def run_sweep(path: Union[str, os.PathLike], out: Union[str, os.PathLike], *,
              params: Sequence[tuple[str, str]] = (), samples: Optional[int] = None, seed: Optional[int] = None,
              sampling: Optional[str] = None, executor: Union[str, Any] = "local", scheduler: Optional[str] = None,
              workers: Optional[int] = None, series: Union[None, str, os.PathLike] = None, resume: bool = False,
              overwrite: bool = False, t_end: Optional[float] = None, n_out: Optional[int] = None,
              solver: Optional[str] = None, certify: bool = True, progress: bool = True, stream=None,
              compiled=None) -> SweepReport:
    """Run a parameter study of a model or scene file; see the module docstring.

    Parameters
    ----------
    path
        Model or scene file (a scene's ``sweep:`` section gives the swept values).
    out
        Results file, ``.csv`` (also ``.parquet`` when pyarrow is installed) or
        ``.parquet`` (needs pyarrow; the CSV file is written too, as the append log).
    params
        ``(NAME, SPEC)`` pairs (:func:`phc.spec.sweep.parse_spec`), over the scene's.
    samples, seed, sampling
        Number of samples of the distributions, the sampler's seed (default 0) and
        ``"lhs"`` (default) or ``"random"``; over the scene's.
    executor
        ``"local"`` (a process pool of `workers`), ``"dask"`` (the scheduler at
        `scheduler`, else a LocalCluster of `workers`), or an executor object.
    series
        A CSV file for the time series of every run (long format: point, t, outputs).
    resume, overwrite
        Continue the results in `out` (skip its points), or replace them. Without either,
        an existing results file is an error.
    t_end, n_out, solver
        Run options of every point (default: the model's or scene's).
    compiled
        The compiled model of `path` when the caller has it (it is compiled otherwise).

    Raises
    ------
    ModelError
        The model does not compile, or a located problem in the scene's sweep section.
    SweepSetupError
        A wrong name, SPEC or option; results that do not belong to this sweep.
    """
    from phc.codegen.load import source_hash
    from phc.pipeline import compile_model

    started = time.perf_counter()
    stream = stream or sys.stderr
    paths = results_paths(out)
    want_parquet = Path(out).suffix.lower() == ".parquet"
    if want_parquet and not parquet_available():
        raise SweepSetupError(f"writing Parquet needs pyarrow: {INSTALL_PARQUET} (or give a .csv file)")
    if compiled is None:
        compiled = compile_model(path, certify=certify)
    axes, spec, locate = sweep_axes(compiled, params)
    if samples is None and spec is not None and any(a.sampled for a in axes):
        samples = spec.samples  # the scene's, when a distribution is left to sample
    design = make_design(compiled, axes, samples,
                         seed if seed is not None else (spec.seed if spec else 0),
                         sampling or (spec.sampling if spec else "lhs"), locate)
    run = {k: v for k, v in (("t_end", t_end), ("n_out", n_out), ("solver", solver)) if v is not None}
    outputs = list(compiled.module.OUTPUTS)
    names = [a.name for a in design.axes]
    columns = ["point", *names, *RUN_COLUMNS, *(f"{o}.{s}" for o in outputs for s in STATS), *MACHINE_COLUMNS]
    units = _units(compiled, design, outputs)
    report = SweepReport(compiled.name, str(path), design, columns, units)
    series_path = Path(series) if series else None

    # -- compile each group once ----------------------------------------------------------
    models, failed_groups = {}, {}
    for group in design.groups:
        t = time.perf_counter()
        entry = {"label": group_label(group), "points": sum(p.group == group for p in design.points),
                 "compile_time_s": compiled.compile_time if not group else math.nan, "error": ""}
        try:
            models[group] = compile_group(compiled, path, group, certify)
            if models[group] is not compiled:
                entry["compile_time_s"] = time.perf_counter() - t
                report.n_compilations += 1
            else:
                entry["compile_time_s"] = compiled.compile_time
        except ModelError as err:
            report.n_compilations += 1
            first = next((d.render() for d in err.diagnostics if d.severity == "error"), str(err))
            failed_groups[group] = entry["error"] = f"compilation failed: {first}"
        report.compilations.append(entry)
    fingerprint = _fingerprint(design, run, series_path, outputs)
    hashes = {group_label(g): source_hash(m.source) for g, m in models.items()}

    # -- the results files: new, or resumed --------------------------------------------------
    log = AppendLog(paths["csv"], columns)
    series_log = AppendLog(series_path, ["point", "t", *outputs]) if series_path else None
    meta = {"phc_version": _version(), "file": str(path), "fingerprint": fingerprint, "models": hashes,
            "points": len(design.points), "axes": [{"name": a.name, "spec": a.text} for a in design.axes],
            "samples": design.samples, "seed": design.seed, "sampling": design.sampling, "run": run,
            "series": str(series_path) if series_path else None,
            "columns": {c: {"unit": units[c]} if c in units else {} for c in columns}}
    existing = paths["csv"].exists()
    if existing and not (resume or overwrite):
        raise SweepSetupError(f"`{paths['csv']}` exists; pass --resume to continue it (finished points are "
                              "skipped) or --overwrite to start over")
    if existing and resume:
        report.rows = _resume(log, paths["meta"], meta, series_log)
        report.resumed = len(report.rows)
    else:
        log.create()
        if series_log is not None:
            series_log.create()
    with atomic_write(paths["meta"], "w") as fh:
        json.dump(meta, fh, indent=1)
    report.paths.update(csv=paths["csv"], meta=paths["meta"])
    if series_log is not None:
        report.paths["series"] = series_path

    # -- run ----------------------------------------------------------------------------
    todo = [p for p in design.points if p.index not in report.rows]
    bar = None
    if progress:
        from phc.progress import CountProgress

        bar = CountProgress(len(design.points), label=compiled.name, done=len(report.rows), stream=stream)

    def record(out_: dict) -> None:
        point = design.points[out_["index"]]
        row = {"point": point.index, **point.values, **out_["row"]}
        if series_log is not None and out_["series"] is not None:
            t, outs = out_["series"]
            series_log.append([[point.index, float(ti), *(float(outs[o][k]) for o in outputs)]
                               for k, ti in enumerate(t)])
        log.append([[row.get(c, "") for c in columns]])  # the row last: a row means its series is complete
        report.rows[point.index] = row
        if bar is not None:
            bar.advance(failed=not row["success"])

    tasks = []
    for p in todo:
        task = {"index": p.index, "group": p.group, "params": p.params, "options": p.options, "run": run,
                "series": series_log is not None}
        if p.group in failed_groups:
            record(_failed(task, failed_groups[p.group], outputs))
        else:
            tasks.append(task)
    runner = _executor(executor, scheduler, workers)
    t_run = time.perf_counter()
    try:
        if tasks:
            if bar is not None:
                bar.draw(force=True)
            results = runner.run({g: models[g] for g in {t["group"] for t in tasks}}, tasks, outputs)
            try:
                for result in results:
                    record(result)
            finally:
                results.close()  # stops the workers when interrupted
    except KeyboardInterrupt:
        report.interrupted = True
    finally:
        if bar is not None:
            bar.close()
    report.run_elapsed_s = time.perf_counter() - t_run
    report.workers_startup_s = runner.startup_s
    report.executor = runner.describe()
    if report.complete:
        log.rewrite([[r.get(c, "") for c in columns] for r in report.ordered()])
    if parquet_available():
        write_parquet(report, paths["parquet"])
        report.paths["parquet"] = paths["parquet"]
    else:
        report.parquet_skipped = f"pyarrow is not installed ({INSTALL_PARQUET})"
    report.elapsed_s = time.perf_counter() - started
    return report


def _executor(executor, scheduler, workers):
    if not isinstance(executor, str):
        return executor
    if executor == "local":
        if scheduler:
            raise SweepSetupError("--scheduler needs --executor dask")
        return LocalExecutor(workers)
    if executor == "dask":
        return DaskExecutor(scheduler, workers)
    raise SweepSetupError(f"unknown executor `{executor}`; choose local or dask")


def _version() -> str:
    from phc import __version__

    return __version__


def _fingerprint(design: Design, run: dict, series: Optional[Path], outputs) -> str:
    h = hashlib.sha256()
    h.update(json.dumps({"points": [[p.index, sorted(p.values.items())] for p in design.points], "run": run,
                         "series": series is not None, "outputs": outputs}, sort_keys=True).encode())
    return h.hexdigest()[:32]


def _resume(log: AppendLog, meta_path: Path, meta: dict, series_log: Optional[AppendLog]) -> dict[int, dict]:
    """The rows already in the results file, after checking they belong to this sweep."""
    try:
        old = json.loads(meta_path.read_text())
    except (OSError, ValueError):
        raise SweepSetupError(f"cannot resume `{log.path}`: its description `{meta_path}` is missing or damaged; "
                              "pass --overwrite to start over") from None
    if old.get("fingerprint") != meta["fingerprint"]:
        raise SweepSetupError(f"cannot resume `{log.path}`: it holds a different sweep (other parameters, values, "
                              "samples, run options or outputs); use another --out, or --overwrite")
    changed = [label for label, digest in meta["models"].items() if old.get("models", {}).get(label) not in
               (None, digest)]
    if changed:
        raise SweepSetupError(f"cannot resume `{log.path}`: the model changed since its rows were computed (the "
                              f"generated code of {', '.join(changed)} differs); use another --out, or --overwrite")
    header, lines = log.read()
    if header != log.columns:
        raise SweepSetupError(f"cannot resume `{log.path}`: its columns are not this sweep's; use --overwrite")
    kinds = _kinds(log.columns)
    rows = {}
    for line in lines:
        try:
            row = {c: _parse(v, kinds[c]) for c, v in zip(header, line)}
        except ValueError:
            continue
        if 0 <= row["point"] < meta["points"]:
            rows[row["point"]] = row
    log.rewrite([[r.get(c, "") for c in log.columns] for r in rows.values()])  # drops a torn line
    if series_log is not None:
        if series_log.path.exists():
            _, kept = series_log.read()
            series_log.rewrite([s for s in kept if s and s[0].isdigit() and int(s[0]) in rows])
        else:
            series_log.create()
    return rows


def _units(compiled, design: Design, outputs) -> dict[str, str]:
    units = {"t_final": "s", "cpu_time_s": "s", "wall_time_s": "s", "accuracy.step": "s", "accuracy.rtol": "1"}
    for par in compiled.dae.parameters:
        if par.unit:
            units[par.name] = par.unit
    for name in design.kinds:
        if name.startswith(MESH_PREFIX):
            units[name] = "elements"
    return {k: v for k, v in units.items() if k in {a.name for a in design.axes} or k in RUN_COLUMNS + MACHINE_COLUMNS}


def write_parquet(report: SweepReport, path: Path) -> None:
    """The rows as a Parquet table (atomically), units in the fields' metadata."""
    import pyarrow as pa
    import pyarrow.parquet as pq

    kinds = _kinds(report.columns)
    types = {"int": pa.int64(), "bool": pa.bool_(), "str": pa.string(), "float": pa.float64()}
    rows = report.ordered()
    fields, arrays = [], []
    for c in report.columns:
        meta = {"unit": report.units[c]} if c in report.units else None
        fields.append(pa.field(c, types[kinds[c]], metadata=meta))
        arrays.append(pa.array([r.get(c) for r in rows], type=types[kinds[c]]))
    table = pa.Table.from_arrays(arrays, schema=pa.schema(fields, metadata={
        "phc": json.dumps({"model": report.name, "file": report.file,
                           "axes": [{"name": a.name, "spec": a.text} for a in report.design.axes]})}))
    with atomic_write(path) as fh:
        pq.write_table(table, fh)


def read_results(path: Union[str, os.PathLike]) -> list[dict]:
    """The rows of a sweep's CSV file, typed (ints, bools, floats, strings)."""
    log = AppendLog(Path(path), [])
    header, lines = log.read()
    kinds = _kinds(header)
    return [{c: _parse(v, kinds[c]) for c, v in zip(header, line)} for line in lines]


# ---------------------------------------------------------------------------------------
# plot


def plot_sweep(report: SweepReport, path: Union[str, os.PathLike], column: Optional[str] = None,
               against: Optional[Sequence[str]] = None) -> str:
    """Draw `column` (default: the first output's maximum) against one swept parameter
    (a line) or two (a heat map on a grid, else coloured points); failed points are
    marked. Returns the column drawn.

    Raises
    ------
    SweepSetupError
        Unknown column or parameters, or matplotlib missing.
    """
    try:
        from matplotlib.backends.backend_agg import FigureCanvasAgg
        from matplotlib.colors import LogNorm
        from matplotlib.figure import Figure
    except ImportError:
        raise SweepSetupError(f"--plot needs matplotlib: {INSTALL_PLOT}") from None
    design = report.design
    outputs = [c[: -len(".max")] for c in report.columns if c.endswith(".max")]
    column = column or (f"{outputs[0]}.max" if outputs else "energy_balance_relative")
    numeric = [c for c in report.columns if _kinds(report.columns)[c] in ("float", "int") and c != "point"]
    if column not in numeric:
        raise SweepSetupError(f"--plot-output `{column}` is not a column of the results; choose one of "
                              f"{', '.join(numeric)}")
    varying = [a.name for a in design.axes if len({p.values[a.name] for p in design.points}) > 1]
    against = list(against or varying[:2])
    if not against or len(against) > 2 or any(a not in [x.name for x in design.axes] for a in against):
        raise SweepSetupError(f"--plot-against takes one or two of the swept parameters "
                              f"({', '.join(varying) or 'none varies'})")
    log_axis = {a.name: a.log or (min(a.values, default=1) > 0 and max(a.values, default=1) / min(a.values, default=1)
                                  > 100) for a in design.axes}
    rows = report.ordered()
    ok = [r for r in rows if r["success"] and np.isfinite(r[column])]
    bad = [r for r in rows if not r["success"]]
    fig = Figure(figsize=(7, 5))
    FigureCanvasAgg(fig)
    ax = fig.add_subplot(1, 1, 1)
    x = against[0]
    if len(against) == 1:
        others = [n for n in varying if n != x]
        groups: dict[tuple, list] = {}
        for r in ok:
            groups.setdefault(tuple(r[n] for n in others), []).append(r)
        for key, members in groups.items():
            members.sort(key=lambda r: r[x])
            label = ", ".join(f"{n} = {v:.4g}" for n, v in zip(others, key)) or None
            ax.plot([r[x] for r in members], [r[column] for r in members], "o-" if len(groups) < 8 else ".",
                    label=label, markersize=4)
        if bad:
            ymin = min((r[column] for r in ok), default=0.0)
            ax.plot([r[x] for r in bad], [ymin] * len(bad), "rx", label="failed", markersize=8)
        ax.set_ylabel(column + (f" [{report.units[column]}]" if column in report.units else ""))
        values = [r[column] for r in ok]
        if values and min(values) > 0 and max(values) / min(values) > 100:
            ax.set_yscale("log")
        if (len(groups) > 1 and len(groups) < 8) or bad:
            ax.legend(fontsize=8)
    else:
        y = against[1]
        xs = sorted({r[x] for r in rows})
        ys = sorted({r[y] for r in rows})
        values = [r[column] for r in ok]
        positive = bool(values) and min(values) > 0 and max(values) / min(values) > 100
        norm = LogNorm() if positive else None
        if len(xs) * len(ys) == len(rows):  # a full grid: heat map
            grid = np.full((len(ys), len(xs)), np.nan)
            for r in ok:
                grid[ys.index(r[y]), xs.index(r[x])] = r[column]
            mesh = ax.pcolormesh(_edges(xs, log_axis[x]), _edges(ys, log_axis[y]), np.ma.masked_invalid(grid),
                                 shading="flat", norm=norm)
        else:
            mesh = ax.scatter([r[x] for r in ok], [r[y] for r in ok], c=values, norm=norm, s=30)
        if bad:
            ax.plot([r[x] for r in bad], [r[y] for r in bad], "rx", label="failed", markersize=8)
            ax.legend(fontsize=8)
        fig.colorbar(mesh, ax=ax, label=column)
        ax.set_ylabel(y + (f" [{report.units[y]}]" if y in report.units else ""))
        if log_axis[y]:
            ax.set_yscale("log")
    ax.set_xlabel(x + (f" [{report.units[x]}]" if x in report.units else ""))
    if log_axis[x]:
        ax.set_xscale("log")
    ax.set_title(f"{report.name}: {column}" + (" (interrupted)" if report.interrupted else ""))
    ax.grid(True, which="both", alpha=0.3)
    fig.tight_layout()
    with atomic_write(path) as fh:
        fig.savefig(fh, format=Path(path).suffix.lstrip(".").lower() or "png", dpi=120)
    return column


def _edges(values: Sequence[float], log: bool) -> np.ndarray:
    v = np.log(values) if log else np.asarray(values, dtype=float)
    if len(v) == 1:
        e = np.array([v[0] - 0.5, v[0] + 0.5]) if not log else np.array([v[0] - 0.1, v[0] + 0.1])
    else:
        mid = (v[1:] + v[:-1]) / 2
        e = np.concatenate([[2 * v[0] - mid[0]], mid, [2 * v[-1] - mid[-1]]])
    return np.exp(e) if log else e


def _short(text: str, n: int = 140) -> str:
    text = " ".join(str(text).split())
    return text if len(text) <= n else text[: n - 1] + "…"


__all__ = ["AppendLog", "DaskExecutor", "Design", "LocalExecutor", "Point", "SweepReport", "SweepSetupError",
           "make_design", "plot_sweep", "read_results", "recompile_for", "results_paths", "run_point", "run_sweep",
           "sample_unit"]
