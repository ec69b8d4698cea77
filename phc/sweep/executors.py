"""Running the points of a sweep: one point (:func:`run_point`, the same function on
every executor), a local process pool (:class:`LocalExecutor`) and Dask distributed
(:class:`DaskExecutor`).

Workers get the compiled model by value (phc's own pickle, made by this process for the
workers it starts or the Dask cluster the user names) and never read the model's files; a
point that fails is a row with ``success`` false and its message; a point whose worker died
while running it is run again elsewhere, and only its own runs count against it.
"""

from __future__ import annotations

import math
import multiprocessing
import os
import signal
import socket
import sys
import time
import uuid
import warnings
from contextlib import contextmanager
from pathlib import Path
from typing import Any, Iterable, Iterator, Optional, Sequence

import numpy as np

from phc.errors import SimulationSetupError, SweepSetupError
from phc.sweep.results import RUN_COLUMNS, STATS

MAX_ATTEMPTS = 3
"""Runs of one point whose worker process died each time before it is recorded as failed (on
a local pool; on Dask, a point the scheduler gives up on after ``allowed-failures`` lost
workers is submitted again while it started on fewer than this many)."""
INSTALL_CLUSTER = 'pip install "port-hamiltonian-compiler[cluster]"'
SUBMIT_AHEAD = 256
"""Points submitted to Dask and not yet returned, at most: the design is taken as the
cluster runs it, never submitted whole."""


# ---------------------------------------------------------------------------------------
# one run (executed on the workers)


@contextmanager
def _checked(compiled, task: dict):
    """The verdict of the client's parameter check (`task["checked"]`, the key of values the
    model file accepts) known to this copy of the model while the point runs: the copy was
    made (pickled for the pool or the cluster) before the point was checked. Forgotten
    after, so a worker's cache does not grow with the sweep."""
    key = task.get("checked")
    if key is not None:  # hashable whatever carried it (a serializer may make lists of tuples)
        key = tuple((str(name), float(value)) for name, value in key)
    cache = compiled.cache.parameter_checks
    added = key is not None and key not in cache
    if added:
        cache[key] = []
    try:
        yield
    finally:
        if added:
            cache.pop(key, None)


def run_point(compiled, task: dict) -> dict:
    """Run one point: ``{"index", "row", "series"}``. Never raises for a failing point:
    any error becomes ``success`` false with its message."""
    with _checked(compiled, task):
        return _run_point(compiled, task)


def _run_point(compiled, task: dict) -> dict:
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


def _init_pool_worker(blob: bytes, parent: int = 0) -> None:
    """Start of a local pool process: Ctrl-C is the parent's business (it stops the
    pool), the process ends with its parent (Linux), one BLAS thread, and the compiled models
    unpickled once (phc's own pickle, made by the parent process for its workers; never read
    from a file)."""
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    signal.signal(signal.SIGTERM, signal.SIG_DFL)  # not a handler of the parent's (fork)
    if hasattr(signal, "pthread_sigmask"):  # held by the parent while it started us (_signals_held)
        signal.pthread_sigmask(signal.SIG_UNBLOCK, _HELD)
    _end_with_parent(parent)
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


_HELD = {signal.SIGINT, signal.SIGTERM}


@contextmanager
def _signals_held(method: str):
    """Hold SIGINT and SIGTERM in this thread while a worker starts. A forked worker inherits
    the parent's handlers (the sweep command's SIGTERM handler raises KeyboardInterrupt) and
    would run them, with a traceback, if the sweep were stopped before the worker set its own
    (:func:`_init_pool_worker`, which releases them); a spawned one inherits the held mask
    the same way. A signal that comes meanwhile reaches the parent when the block ends. A fork
    server is left alone: it would keep the mask for every worker it starts later."""
    if method == "forkserver" or not hasattr(signal, "pthread_sigmask"):
        yield
        return
    previous = signal.pthread_sigmask(signal.SIG_BLOCK, _HELD)
    try:
        yield
    finally:
        signal.pthread_sigmask(signal.SIG_SETMASK, previous)


def _end_with_parent(parent: int) -> None:
    """Linux: SIGTERM to this worker when the process that started it ends, however it ends
    (``prctl(PR_SET_PDEATHSIG)``; a fork server's workers end with the fork server, which
    ends with the sweep); a parent already gone (`parent`, 0 for a fork server) ends it now.
    Elsewhere the parent's own clean-up (:meth:`LocalExecutor.run`) stops it."""
    if not sys.platform.startswith("linux"):
        return
    parent = parent or os.getppid()
    try:
        import ctypes

        ctypes.CDLL(None, use_errno=True).prctl(1, int(signal.SIGTERM), 0, 0, 0)  # 1 = PR_SET_PDEATHSIG
    except (OSError, AttributeError):
        return
    if os.getppid() != parent:  # the parent ended before prctl: nobody will read our rows
        os._exit(0)


def _pool_task(task: dict) -> dict:
    if _INIT_ERROR:
        return _failed(task, f"the worker could not load the compiled model: {_INIT_ERROR[0]}")
    return run_point(_MODELS[task["group"]], task)


def _pool_worker(conn, blob: bytes, parent: int) -> None:
    """A process of the local pool: the compiled models unpickled once, then one point at a
    time from `conn` and its row sent back, until None (or the pipe closes)."""
    _init_pool_worker(blob, parent)
    while True:
        try:
            task = conn.recv()
        except (EOFError, OSError):
            return
        if task is None:
            return
        model = _MODELS.get(task["group"])
        outputs = list(model.module.OUTPUTS) if model is not None else []
        try:
            out = _pool_task(task)
        except Exception as err:  # noqa: BLE001 — the point's failure, not the process's
            out = _failed(task, f"the worker failed: {type(err).__name__}: {err}", outputs)
        try:
            conn.send(out)
        except (EOFError, OSError):
            return
        except Exception as err:  # noqa: BLE001 — a row that cannot be pickled back
            conn.send(_failed(task, f"the worker failed: {type(err).__name__}: {err}", outputs))


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
    """A pool of `workers` processes on this machine, each running one point at a time.

    Every point's run is known to its worker process: when a process dies (killed by the
    out-of-memory killer, a crash in a native library) only the point it was running is
    charged an attempt and queued again, and only that process is replaced; the others
    keep running. Ctrl-C, the end of the sweep or an error stops every worker."""

    name = "local"

    def __init__(self, workers: Optional[int] = None) -> None:
        self.workers = workers or default_workers()
        self.startup_s = math.nan

    def describe(self) -> str:
        return f"local process pool, {self.workers} worker{'s' if self.workers != 1 else ''}"

    def run(self, models: dict, tasks: Iterable[dict], outputs: Sequence[str]) -> Iterator[dict]:
        """The rows of `tasks`, as they finish. `tasks` is taken one point at a time: a worker
        is started for each of the first points (at most `workers`), then one more point is
        taken while they run (its check, in this process, overlaps their runs) and given to
        the first worker that returns a row; so at most `workers` + 1 points are out."""
        import pickle
        from collections import deque
        from multiprocessing.connection import wait

        ctx = multiprocessing.get_context(start_method())
        if ctx.get_start_method() == "forkserver":
            ctx.set_forkserver_preload(["phc.sweep", "phc.pipeline", "phc.simulation"])
        blob = pickle.dumps(models, protocol=pickle.HIGHEST_PROTOCOL)
        attempts: dict[int, int] = {}  # points being run -> their run (1 unless a worker died running it)
        deaths: dict[int, list[str]] = {}
        pending: deque = deque()  # points to run again after their worker died
        source = iter(tasks)
        staged: list[dict] = []  # the next point, taken (and checked) while the workers run

        def take() -> Optional[dict]:
            if pending:
                return pending.popleft()
            task = staged.pop() if staged else next(source, None)
            if task is not None:
                attempts.setdefault(task["index"], 1)
            return task

        workers: list[_Worker] = []
        started = time.perf_counter()
        try:
            while len(workers) < self.workers:
                task = take()
                if task is None:
                    break
                with _one_blas_thread():
                    workers.append(_Worker(ctx, blob))
                workers[-1].give(task, attempts)
            while True:
                for i, w in enumerate(workers):
                    if w.task is None:
                        task = take()
                        if task is None:
                            break
                        if not w.process.is_alive():  # it died between points: replaced, nobody charged
                            w.death()
                            with _one_blas_thread():
                                w = workers[i] = _Worker(ctx, blob)
                        w.give(task, attempts)
                busy = [w for w in workers if w.task is not None]
                if not busy:
                    break
                if not staged and not pending:
                    task = next(source, None)
                    if task is not None:
                        staged.append(task)
                ready = set(wait([w.conn for w in busy] + [w.process.sentinel for w in busy]))
                for w in busy:
                    if w.conn not in ready and w.process.sentinel not in ready:
                        continue
                    out = w.receive()
                    if out is not None:
                        if math.isnan(self.startup_s):
                            self.startup_s = time.perf_counter() - started
                        if not w.process.is_alive():  # it died after sending: replaced, nobody charged
                            w.death()
                            with _one_blas_thread():
                                workers[workers.index(w)] = _Worker(ctx, blob)
                        index = out["index"]
                        attempts.pop(index, None)
                        if deaths.get(index):
                            out["row"]["message"] += (" (run again after its worker process died: "
                                                      f"{', '.join(deaths.pop(index))})")
                        yield out
                        continue
                    # the process died running w.task: that point alone is charged the attempt
                    task, why = w.task, w.death()
                    index = task["index"]
                    deaths.setdefault(index, []).append(why)
                    attempts[index] += 1
                    with _one_blas_thread():
                        workers[workers.index(w)] = _Worker(ctx, blob)
                    if attempts[index] > MAX_ATTEMPTS:
                        attempts.pop(index)
                        yield _failed(dict(task, attempt=MAX_ATTEMPTS),
                                      f"its worker process died each of the {MAX_ATTEMPTS} times it ran this point "
                                      f"({'; '.join(deaths.pop(index))}; out of memory? a crash in a native library?)",
                                      outputs)
                    else:
                        pending.appendleft(task)
        finally:  # done, Ctrl-C, or the consumer stopped: no worker outlives the sweep
            _stop_workers(workers)


class _Worker:
    """One process of :class:`LocalExecutor` and its pipe; `task` is the point it runs."""

    def __init__(self, ctx, blob: bytes) -> None:
        self.conn, child = ctx.Pipe(duplex=True)
        parent = os.getpid() if ctx.get_start_method() != "forkserver" else 0  # a fork server starts it
        self.process = ctx.Process(target=_pool_worker, args=(child, blob, parent), daemon=True,
                                   name="phc-sweep-worker")
        with _signals_held(ctx.get_start_method()):
            self.process.start()
        child.close()  # the worker holds the other end alone: its death is an end of file here
        self.task: Optional[dict] = None

    def give(self, task: dict, attempts: dict) -> None:
        self.task = task
        try:
            self.conn.send(dict(task, attempt=attempts[task["index"]]))
        except OSError:  # the process is gone: its sentinel says so next
            pass

    def receive(self) -> Optional[dict]:
        """The row of the point it ran, or None when the process died before sending it."""
        try:
            if self.conn.poll():
                out = self.conn.recv()
                self.task = None
                return out
        except (EOFError, OSError):  # the process died (mid-send, at worst)
            pass
        return None

    def death(self) -> str:
        """How the process ended ("killed by SIGKILL", "exit code 3")."""
        self.process.join(timeout=5)
        if self.process.is_alive():
            self.process.kill()
            self.process.join(timeout=5)
        code = self.process.exitcode
        self.conn.close()
        if code is not None and code < 0:
            try:
                return f"killed by {signal.Signals(-code).name}"
            except ValueError:
                return f"killed by signal {-code}"
        return f"exit code {code}"


def _stop_workers(workers: list) -> None:
    """Stop the pool's processes: a worker between points ends on None; the others (and any
    that do not end at once) are terminated, then killed."""
    for w in workers:
        if w.task is None and w.process.is_alive():
            try:
                w.conn.send(None)
            except OSError:
                pass
        else:
            w.process.terminate()
    deadline = time.monotonic() + 5
    for w in workers:
        w.process.join(timeout=max(0.0, deadline - time.monotonic()))
        if w.process.is_alive():
            w.process.kill()
            w.process.join(timeout=5)
        try:
            w.conn.close()
        except OSError:
            pass


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
        if address:
            _check_scheduler(address)
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
            try:
                client = Client(**kwargs, timeout=30)
            except (OSError, ValueError, TypeError, KeyError) as err:  # unreachable, refused, a bad file
                raise SweepSetupError(f"--scheduler `{self.address}`: cannot connect to the Dask scheduler "
                                      f"({type(err).__name__}: {err})") from None
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

    def run(self, models: dict, tasks: Iterable[dict], outputs: Sequence[str]) -> Iterator[dict]:
        """The rows of `tasks`, as they finish; at most :data:`SUBMIT_AHEAD` points are
        submitted and not yet returned (a point is taken from `tasks` as one returns)."""
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
                source = iter(tasks)
                done = dask_completed([])

                def submit_next() -> bool:
                    """One more point to the cluster (False when there is none)."""
                    t = next(source, None)
                    if t is None:
                        return False
                    fut = client.submit(_dask_task, loaded[t["group"]], t, topic, pure=False,
                                        key=f"{topic}-{t['index']}")
                    futures[fut] = t
                    done.add(fut)
                    return True

                while len(futures) < SUBMIT_AHEAD and submit_next():
                    pass
                again: dict[int, int] = {}
                for fut in done:
                    task = futures.pop(fut)
                    if math.isnan(self.startup_s):
                        self.startup_s = time.perf_counter() - started
                    try:
                        out = fut.result()
                    except Exception as err:  # noqa: BLE001 — KilledWorker, a worker without phc, ...
                        index = task["index"]
                        runs = len(starts.get(index, ()))
                        if type(err).__name__ == "KilledWorker" and runs < MAX_ATTEMPTS and \
                                again.get(index, 0) < MAX_ATTEMPTS:
                            # the scheduler also counts the workers that died while the point waited
                            # in their queues: not its own runs, so it is submitted again
                            again[index] = again.get(index, 0) + 1
                            fut.release()
                            new = client.submit(_dask_task, loaded[task["group"]], task, topic, pure=False,
                                                key=f"{topic}-{index}-again{again[index]}")
                            futures[new] = task
                            done.add(new)
                            continue
                        out = _failed(dict(task, attempt=max(runs, 1)), _dask_failure(err), outputs)
                    else:
                        workers = set(starts.get(task["index"], ())) | {out["row"]["worker"]}
                        out["row"]["attempts"] = len(workers)
                        if len(workers) > 1:
                            lost = ", ".join(sorted(workers - {out["row"]["worker"]}))
                            out["row"]["message"] += f" (run again after its worker was lost: {lost})"
                    fut.release()
                    starts.pop(task["index"], None)
                    again.pop(task["index"], None)
                    while len(futures) < SUBMIT_AHEAD and submit_next():  # the cluster kept busy meanwhile
                        pass
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


def _check_scheduler(address: str) -> None:
    """Refuse, before any work, a `--scheduler` that is neither a scheduler file (an existing
    ``.json`` file) nor a network address with a port (``tcp://HOST:PORT``, ``HOST:PORT``;
    also tls, ws, wss)."""
    path = Path(address)
    try:
        if path.suffix == ".json" and path.is_file():
            return
    except OSError:  # a name too long for a file: an address, checked below
        pass
    scheme = address.rpartition("://")[0]
    if scheme not in ("", "tcp", "tls", "ws", "wss"):
        return  # another transport of distributed: its own connection says what is wrong
    from distributed.comm.addressing import get_address_host_port

    try:
        host, port = get_address_host_port(address)
        ok = bool(host) and 0 < int(port) < 65536
    except (ValueError, TypeError):
        ok = False
    if not ok:
        raise SweepSetupError(f"--scheduler `{address}` is neither a scheduler address (tcp://HOST:PORT) nor a "
                              "scheduler file (the .json file of `dask scheduler --scheduler-file`)")


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


__all__ = ["DaskExecutor", "INSTALL_CLUSTER", "LocalExecutor", "MAX_ATTEMPTS", "SUBMIT_AHEAD",
           "default_workers", "run_point", "start_method"]
