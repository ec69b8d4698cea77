"""Back ends (numba, C) and the exported FMU against the reference NumPy module: compile, call, step, run times.

For every model (default: the shipped ``models/*.yaml``):

* **compile**: ``phc.compile_model(path, certify=False, backend=...)`` in a fresh Python
  process, first with an empty cache directory and an empty state directory (*cold*:
  numba imported, every function compiled and written to the signed cache), then again in a
  second fresh process (*warm*: loaded from the cache). The backend's own stage
  (``timings["backend"]``) is reported in wall and CPU seconds, and the whole compilation.
  For the C back end also the command a user runs, ``phc compile MODEL --backend c``
  (certified, written to a temporary directory) in a fresh process, cold (empty cache: the
  model's library and phc's call bridge compiled) and warm (the unchanged model's signed
  compile record: the texts written again, the library loaded): the CPU seconds of the process and
  of the C compiler it starts (``RUSAGE_CHILDREN``). *Cold* means phc's caches are empty;
  Python's bytecode of phc is written first (``compileall``), as ``pip install`` does.
* **per call**: one residual and one Jacobian evaluation of each backend at a consistent
  state, in microseconds (best of 7 repetitions of a timed loop: a loaded machine only ever
  adds time), called from Python as the integrators call them.

* **per step** (the pendulum and the flexible slider–crank, ``--step-models``): a fixed number
  of implicit midpoint steps of one fixed step size, CPU time (``time.process_time``) per step,
  best of ``--step-repeat``: ``phc.simulate`` on the NumPy, numba and C back ends (output at
  the two ends only; the run's ``integrate`` phase of ``SimResult.timings`` over the number of
  steps: the steps and the step loop's set-up, not the consistent start, the nominal scales,
  the output polish or the outputs), and the FMU that ``phc export --fmu`` writes for the same model and
  step, run by FMPy's ``FMU2Slave``: one ``doStep`` per step (one midpoint step each) in a
  Python loop, only that loop timed (the FMU's step plus one ctypes call; not
  ``fmpy.simulate_fmu``, whose own Python bookkeeping per communication point would dominate).
  The export is timed once (wall, and CPU of this process and the C compiler). Without FMPy,
  or when the model cannot be exported, the FMU's row says why.

Then whole runs of ``phc simulate`` from the shell (a fresh process each: start-up,
compilation, initialization, integration, post-processing) for the flexible and the rigid
slider–crank and the pendulum, on each backend, with a cold cache and warm (best of
``--repeat``). Wall time and the CPU time of the process are both given: on a shared
machine the wall time includes waiting for a core.

Writes ``backends.md`` (the tables) and ``backends.json`` (every figure) into ``--out-dir``
(default ``benchmarks/backends``) and prints the Markdown.

Run: ``python benchmarks/bench_backends.py [--repeat 3] [--models a.yaml b.yaml] [--skip-runs]
[--step-models a.yaml ...] [--step-repeat 5]``
"""

from __future__ import annotations

import argparse
import datetime
import json
import os
import platform
import resource
import subprocess
import sys
import tempfile
import time
import timeit
from pathlib import Path

for _var in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(_var, "1")

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

import numpy as np  # noqa: E402

import phc  # noqa: E402
from phc.codegen import numba_backend  # noqa: E402

RUNS = [ROOT / "models" / "flexible_slider_crank.yaml", ROOT / "models" / "rigid_slider_crank.yaml",
        ROOT / "models" / "pendulum.yaml"]

STEP_RUNS = {"pendulum": (0.01, 2000), "flexible_slider_crank": (1e-5, 1000)}
"""Per-step rows: model stem -> (midpoint step [s], number of steps). The slider–crank's step is
its file's `simulation.step`; the pendulum's file has none (its FMU's test steps 0.01 s)."""

_COMPILE = r"""
import json, sys, time
t, c = time.perf_counter(), time.process_time()
import phc
compiled = phc.compile_model(sys.argv[1], certify=False, backend=sys.argv[2])
report = getattr(compiled.module, "COMPILE_REPORT", None) or getattr(compiled.module, "C_REPORT", None)
print(json.dumps({"wall": time.perf_counter() - t, "cpu": time.process_time() - c,
                  "backend_wall": compiled.timings.get("backend", 0.0),
                  "backend_cpu": report.cpu_seconds if report else 0.0,
                  "cached": report.cached if report else "", "backend": compiled.backend}))
"""


def _env(cache: str, state: str) -> dict:
    env = dict(os.environ, PHC_CACHE_DIR=cache, PHC_STATE_DIR=state)
    # as installed for a user: Python's bytecode cache on (pip writes it at install time; see
    # main, which writes it for phc's sources first); a machine with PYTHONDONTWRITEBYTECODE
    # set would otherwise compile phc's 30 000 lines in every fresh process (about 1.2 s)
    env.pop("PYTHONDONTWRITEBYTECODE", None)
    env["PYTHONPATH"] = os.pathsep.join(p for p in (str(ROOT), env.get("PYTHONPATH", "")) if p)
    return env


def compile_in_fresh_process(path: Path, backend: str, env: dict) -> dict:
    done = subprocess.run([sys.executable, "-c", _COMPILE, str(path), backend], capture_output=True, text=True,
                          env=env, timeout=1800, check=True)
    return json.loads(done.stdout.strip().splitlines()[-1])


def cli_compile(path: Path, backend: str, env: dict) -> dict:
    """``phc compile PATH --backend BACKEND`` (certified, as a user runs it) in a fresh process:
    wall seconds and the CPU seconds of the process and everything it started (the C compiler)."""
    cpu, wall = _child_cpu(), time.perf_counter()
    with tempfile.TemporaryDirectory() as out:
        subprocess.run([sys.executable, "-m", "phc", "compile", str(path), "--backend", backend, "-o", out],
                       capture_output=True, text=True, env=env, timeout=1800, check=True)
    return {"wall": time.perf_counter() - wall, "cpu": _child_cpu() - cpu}


def compile_times(path: Path) -> dict:
    from phc.codegen import cc

    out = {}
    for backend in ("numpy", "numba") + (("c",) if cc.available()[0] else ()):
        with tempfile.TemporaryDirectory() as cache, tempfile.TemporaryDirectory() as state:
            env = _env(cache, state)
            out[backend] = {"cold": compile_in_fresh_process(path, backend, env),
                            "warm": compile_in_fresh_process(path, backend, env)}
    if "c" in out:  # the command a user runs, start-up and certificate included
        with tempfile.TemporaryDirectory() as cache, tempfile.TemporaryDirectory() as state:
            env = _env(cache, state)
            out["c"]["cli_cold"], out["c"]["cli_warm"] = cli_compile(path, "c", env), cli_compile(path, "c", env)
    return out


def per_call(path: Path) -> dict:
    """Residual and Jacobian µs of each backend at the model's consistent start."""
    compiled = phc.compile_model(path, certify=False, backend="numba")
    fast = compiled.module
    ref = fast.REFERENCE
    run = phc.simulate(compiled, t_end=float(compiled.dae.options["t_start"]) + 1e-9, n_out=2,
                       solver="midpoint", step=1e-9, backend="numpy")
    y, yp = np.array(run.y[0]), np.array(run.yp[0])
    y.setflags(write=False)  # as IDA hands them over
    yp.setflags(write=False)
    p = np.asarray(ref.full_parameters(), dtype=float)
    out, jac = np.zeros(ref.N), np.zeros(len(ref.JAC_ROWS))
    times = {}
    modules = [("numpy", ref), ("numba", fast)]
    from phc.codegen import backends, c_backend, c_bridge, cc

    if cc.available()[0]:  # the C module's functions, through the call bridge and through plain ctypes
        c_module = backends.for_compiled(compiled, "c")
        if c_bridge.bridge() is not None:
            modules.append(("c", c_module))
        os.environ["PHC_C_BRIDGE"] = "0"
        try:
            modules.append(("c_ctypes", c_backend.load_source(c_module.C_SOURCE, ref)[0]))
        finally:
            del os.environ["PHC_C_BRIDGE"]
    for name, mod in modules:
        res = timeit.Timer(lambda m=mod: m.residual(0.0, y, yp, p, out))
        jc = timeit.Timer(lambda m=mod: m.jacobian(0.0, y, yp, p, 10.0, jac))
        number = max(1, int(0.05 / max(res.timeit(number=5) / 5, 1e-7)))
        times[name] = {"residual_us": min(res.repeat(7, number)) / number * 1e6,
                       "jacobian_us": min(jc.repeat(7, number)) / number * 1e6}
    return {"N": int(ref.N), "jacobian_nnz": int(len(ref.JAC_ROWS)), **times,
            "emitted": list(fast.COMPILE_REPORT.emitted)}


def _fmpy():
    """The FMPy modules the FMU rows use, or the reason they cannot run."""
    try:
        import fmpy
        from fmpy.fmi2 import FMU2Slave
    except Exception as err:  # ImportError, or a broken installation
        return None, f"FMPy is not importable ({type(err).__name__}: {err}); the FMU was not measured"
    return (fmpy, FMU2Slave), f"FMPy {fmpy.__version__}"


def _fmu_steps(path: str, h: float, steps: int, repeat: int, fmpy_modules) -> list:
    """CPU seconds of `steps` calls of ``doStep(t, h)`` on a fresh instance, `repeat` times."""
    fmpy, slave = fmpy_modules
    md = fmpy.read_model_description(path)
    t0 = float(md.defaultExperiment.startTime or 0.0) if md.defaultExperiment else 0.0
    with tempfile.TemporaryDirectory() as unzipped:
        fmpy.extract(path, unzipdir=unzipped)
        times = []
        for _ in range(repeat):
            fmu = slave(guid=md.guid, unzipDirectory=unzipped, modelIdentifier=md.coSimulation.modelIdentifier,
                        instanceName="bench")
            fmu.instantiate()
            try:
                fmu.setupExperiment(startTime=t0)
                fmu.enterInitializationMode()
                fmu.exitInitializationMode()
                do_step = fmu.doStep
                c = time.process_time()
                for k in range(steps):
                    do_step(currentCommunicationPoint=t0 + k * h, communicationStepSize=h)
                times.append(time.process_time() - c)
                fmu.terminate()
            finally:
                fmu.freeInstance()
    return times


def per_step(path: Path, h: float, steps: int, repeat: int) -> dict:
    """µs of CPU per implicit midpoint step: phc.simulate on each back end, and the exported FMU."""
    compiled = phc.compile_model(path, certify=False, backend="numpy")
    t0 = float(compiled.dae.options["t_start"])
    out = {"solver": "midpoint", "step": h, "steps": steps, "repeat": repeat, "rows": {}}
    for backend in ("numpy", "numba", "c"):
        try:
            def run(n, b=backend):
                return phc.simulate(compiled, solver="midpoint", step=h, t_end=t0 + n * h, n_out=2, backend=b)

            for n in (1, steps):  # builds or loads the back end, checks the step count: not timed
                first = run(n)
                if not first.success or first.steps != n:
                    raise RuntimeError(f"the run took {first.steps} steps, not {n} (success={first.success})")
            best = {}
            for n in (1, steps):  # the integrate phase of the run's own clock (SimResult.timings)
                runs = [run(n) for _ in range(repeat)]
                best[n] = min(r.timings["integrate"] for r in runs)
                whole = min(r.cpu_time_s for r in runs)
            out["rows"][backend] = {"us_per_step": best[steps] / steps * 1e6, "one_step_integrate_s": best[1],
                                    "run_cpu_s": whole,
                                    "measured": f"phc.simulate: SimResult.timings['integrate'] of {steps} steps / {steps}"}
        except Exception as err:  # an unavailable back end is a row that says so
            out["rows"][backend] = {"us_per_step": None, "note": f"{type(err).__name__}: {err}"}
    modules, note = _fmpy()
    if modules is None:
        out["rows"]["fmu"] = {"us_per_step": None, "note": note}
        return out
    from phc.export import export_fmu

    with tempfile.TemporaryDirectory() as folder:
        target = str(Path(folder) / f"{path.stem}.fmu")
        cpu, child, wall = time.process_time(), _child_cpu(), time.perf_counter()
        try:
            export_fmu(path, target, step=h, certify=False)
        except Exception as err:
            out["rows"]["fmu"] = {"us_per_step": None, "note": f"not exported: {err}"}
            return out
        export = {"wall": time.perf_counter() - wall, "cpu": time.process_time() - cpu + _child_cpu() - child}
        try:
            times = _fmu_steps(target, h, steps, repeat, modules)
        except Exception as err:  # an FMI error status (FMPy raises on it)
            out["rows"]["fmu"] = {"us_per_step": None, "export": export, "note": f"doStep failed: {err}"}
            return out
    out["rows"]["fmu"] = {"us_per_step": min(times) / steps * 1e6, "export": export, "fmpy": note,
                          "measured": "FMU2Slave.doStep loop (one midpoint step per call; ctypes call included)"}
    return out


def _child_cpu() -> float:
    usage = resource.getrusage(resource.RUSAGE_CHILDREN)
    return usage.ru_utime + usage.ru_stime


def simulate_run(path: Path, backend: str, env: dict) -> dict:
    cpu = _child_cpu()
    t = time.perf_counter()
    done = subprocess.run([sys.executable, "-m", "phc", "simulate", str(path), "--quiet", "--no-certify",
                           "--backend", backend, "--format", "json"], capture_output=True, text=True, env=env,
                          timeout=3600)
    wall = time.perf_counter() - t
    if done.returncode != 0:
        raise RuntimeError(f"phc simulate {path.name} --backend {backend} failed: {done.stderr[-2000:]}")
    summary = json.loads(done.stdout)
    return {"wall": wall, "cpu": _child_cpu() - cpu, "steps": summary.get("steps"),
            "solver": summary.get("solver"), "run_cpu": summary.get("cpu_time_s")}


def whole_runs(paths, repeat: int) -> dict:
    from phc.codegen import cc

    out = {}
    for path in paths:
        out[path.stem] = {}
        for backend in ("numpy", "numba") + (("c",) if cc.available()[0] else ()):
            with tempfile.TemporaryDirectory() as cache, tempfile.TemporaryDirectory() as state:
                env = _env(cache, state)
                cold = simulate_run(path, backend, env)
                warm = [simulate_run(path, backend, env) for _ in range(repeat)]
            best = min(warm, key=lambda r: r["wall"])
            out[path.stem][backend] = {"cold": cold, "warm": best, "warm_cpu_min": min(r["cpu"] for r in warm),
                                       "warm_walls": [r["wall"] for r in warm]}
    return out


def markdown(data: dict) -> str:
    lines = [f"# Backends — {data['date']}, {data['machine']}\n",
             f"numba {data['numba']}; command: `{data['command']}`\n",
             "## Compile (fresh process each; cold: empty cache; warm: the same cache again)\n",
             "| model | unknowns | Jacobian nnz | numpy compile [s] | numba backend stage cold: wall / CPU [s] | "
             "numba backend stage warm: wall / CPU [s] | numba whole compile cold / warm [s] | "
             "C backend stage cold: wall / CPU [s] | C whole compile cold / warm [s] | "
             "`phc compile --backend c` CPU cold / warm [s] |",
             "|---|---:|---:|---:|---:|---:|---:|---:|---:|---:|"]
    for name, row in data["models"].items():
        c = row["compile"]
        nb_cold, nb_warm = c["numba"]["cold"], c["numba"]["warm"]
        cc_cold, cc_warm = (c["c"]["cold"], c["c"]["warm"]) if "c" in c else (None, None)
        cli = (f"{c['c']['cli_cold']['cpu']:.2f} / {c['c']['cli_warm']['cpu']:.2f}"
               if cc_cold and "cli_cold" in c["c"] else "")
        c_cells = (f"{cc_cold['backend_wall']:.2f} / {cc_cold['backend_cpu']:.2f} | "
                   f"{cc_cold['wall']:.2f} / {cc_warm['wall']:.2f} | {cli} |") if cc_cold else " | | |"
        lines.append(f"| {name} | {row['calls']['N']} | {row['calls']['jacobian_nnz']} | "
                     f"{c['numpy']['warm']['wall']:.2f} | "
                     f"{nb_cold['backend_wall']:.2f} / {nb_cold['backend_cpu']:.2f} | "
                     f"{nb_warm['backend_wall']:.2f} / {nb_warm['backend_cpu']:.2f} | "
                     f"{nb_cold['wall']:.2f} / {nb_warm['wall']:.2f} | " + c_cells)
    lines += ["", "## Per call, from Python (µs, best of 7)\n",
              "With read-only y and ẏ, as IDA hands them over. Ratio: numpy's µs over numba's. C: the C module's "
              "functions through phc's call bridge (the buffer protocol in C; `auto`'s choice); C ctypes: the "
              "same functions through plain ctypes (`PHC_C_BRIDGE=0`, or where Python's C headers are "
              "missing). Empty where no C compiler was found.\n",
              "| model | residual numpy | residual numba | residual C | residual C ctypes | ratio | "
              "Jacobian numpy | Jacobian numba | Jacobian C | Jacobian C ctypes | ratio |",
              "|---|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|"]
    for name, row in data["models"].items():
        a, b = row["calls"]["numpy"], row["calls"]["numba"]
        cells = {}
        for key in ("c", "c_ctypes"):
            c = row["calls"].get(key)
            cells[key] = (f"{c['residual_us']:.2f}", f"{c['jacobian_us']:.2f}") if c else ("", "")
        lines.append(f"| {name} | {a['residual_us']:.2f} | {b['residual_us']:.2f} | {cells['c'][0]} | "
                     f"{cells['c_ctypes'][0]} | {a['residual_us'] / b['residual_us']:.1f} | {a['jacobian_us']:.2f} | "
                     f"{b['jacobian_us']:.2f} | {cells['c'][1]} | {cells['c_ctypes'][1]} | "
                     f"{a['jacobian_us'] / b['jacobian_us']:.1f} |")
    if data.get("steps"):
        repeat = next(iter(data["steps"].values()))["repeat"]
        lines += ["", f"## Per step: implicit midpoint, fixed step (CPU µs per step, best of {repeat})\n",
                  "phc.simulate rows: output at the two ends only; the run's `integrate` phase "
                  "(`SimResult.timings`: the steps and the step loop's set-up, not the consistent start, "
                  "the nominal scales, the output polish or the outputs) over the number of steps. FMU row: the FMU that "
                  "`phc export --fmu` wrote for the same step, run by FMPy's `FMU2Slave.doStep` in a Python "
                  "loop, one midpoint step per call (the FMU's step plus one ctypes call; not "
                  "`fmpy.simulate_fmu`). Ratio: numpy's µs per step over the row's, both measured in this run. "
                  f"{data.get('fmpy', '')}.\n",
                  "| model | step [s], steps | runs on | µs per step | ratio to numpy | export: wall / CPU [s] |",
                  "|---|---|---|---:|---:|---:|"]
        labels = {"numpy": "phc.simulate, numpy", "numba": "phc.simulate, numba", "c": "phc.simulate, C",
                  "fmu": "FMU under FMPy (doStep loop)"}
        for name, st in data["steps"].items():
            base = st["rows"].get("numpy", {}).get("us_per_step")
            for runner, r in st["rows"].items():
                head = f"| {name} | {st['step']:g}, {st['steps']} | {labels[runner]} |"
                if r.get("us_per_step") is None:
                    note = " ".join(str(r["note"]).split())[:300].replace("|", "/")
                    lines.append(f"{head} not measured | — | {note} |")
                    continue
                ratio = f"{base / r['us_per_step']:.1f}" if base else "—"
                ex = r.get("export")
                export = f"{ex['wall']:.2f} / {ex['cpu']:.2f}" if ex else ""
                lines.append(f"{head} {r['us_per_step']:.2f} | {ratio} | {export} |")
    if data.get("runs"):
        lines += ["", "## Whole runs: `phc simulate MODEL --no-certify --backend B` (fresh process each)\n",
                  "| model | solver, steps | backend | cold: wall / CPU [s] | warm: wall / CPU [s] | "
                  "integration CPU (warm) [s] |",
                  "|---|---|---|---:|---:|---:|"]
        for name, by_backend in data["runs"].items():
            for backend, r in by_backend.items():
                lines.append(f"| {name} | {r['warm']['solver']}, {r['warm']['steps']} | {backend} | "
                             f"{r['cold']['wall']:.2f} / {r['cold']['cpu']:.2f} | "
                             f"{r['warm']['wall']:.2f} / {r['warm_cpu_min']:.2f} | {r['warm']['run_cpu']:.2f} |")
    return "\n".join(lines) + "\n"


def main(argv=None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--models", nargs="*", type=Path, default=sorted((ROOT / "models").glob("*.yaml")))
    ap.add_argument("--repeat", type=int, default=3, help="warm whole runs per backend (the best is kept)")
    ap.add_argument("--skip-runs", action="store_true", help="compile and per-call figures only")
    ap.add_argument("--step-models", nargs="*", type=Path,
                    default=[ROOT / "models" / f"{stem}.yaml" for stem in STEP_RUNS],
                    help=f"per-step rows (models among: {', '.join(STEP_RUNS)}; none: skip them)")
    ap.add_argument("--step-repeat", type=int, default=5, help="timed repetitions of each per-step row (best kept)")
    ap.add_argument("--out-dir", type=Path, default=ROOT / "benchmarks" / "backends")
    args = ap.parse_args(argv)
    unknown = [path.name for path in args.step_models if path.stem not in STEP_RUNS]
    if unknown:
        ap.error(f"--step-models: no per-step setting for {', '.join(unknown)} (models among: {', '.join(STEP_RUNS)})")
    ok, version = numba_backend.available()
    if not ok:
        sys.exit(f"bench_backends: {version}")
    import compileall

    compileall.compile_dir(str(ROOT / "phc"), quiet=1)  # what `pip install` does (see _env)
    load = os.getloadavg()[0] if hasattr(os, "getloadavg") else float("nan")
    data = {"date": datetime.datetime.now().strftime("%Y-%m-%d %H:%M"),
            "machine": f"{platform.machine()}, {os.cpu_count()} cores, load average {load:.1f} at the start",
            "numba": version, "command": "python benchmarks/bench_backends.py " + " ".join(argv or sys.argv[1:]),
            "fmpy": _fmpy()[1], "models": {}, "steps": {}, "runs": {}}
    with tempfile.TemporaryDirectory() as cache, tempfile.TemporaryDirectory() as state:
        os.environ.update(PHC_CACHE_DIR=cache, PHC_STATE_DIR=state)
        for path in args.models:
            print(f"{path.name} ...", file=sys.stderr, flush=True)
            data["models"][path.stem] = {"compile": compile_times(path), "calls": per_call(path)}
        for path in args.step_models:
            print(f"{path.name}: per step ...", file=sys.stderr, flush=True)
            data["steps"][path.stem] = per_step(path, *STEP_RUNS[path.stem], max(1, args.step_repeat))
    if not args.skip_runs:
        data["runs"] = whole_runs(RUNS, args.repeat)
    data["load_at_end"] = os.getloadavg()[0] if hasattr(os, "getloadavg") else float("nan")
    text = markdown(data) + f"\nLoad average at the end: {data['load_at_end']:.1f}.\n"
    args.out_dir.mkdir(parents=True, exist_ok=True)
    (args.out_dir / "backends.md").write_text(text)
    (args.out_dir / "backends.json").write_text(json.dumps(data, indent=1))
    print(text)


if __name__ == "__main__":
    main()
