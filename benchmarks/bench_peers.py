"""Peers (issue 7, item 3): phc against what a user would use without it, measured side by side.

(a) Flexible slider–crank (``models/flexible_slider_crank.yaml``: 8 Hermite elements,
    0.1 s, crank speed 150 rad/s, drive and slider ports free) against a hand-written
    numpy/scipy implementation of the same equations and discretization
    (``peers/flexible_handwritten.py``: an ODE with the joint multipliers eliminated at every
    right-hand-side call, integrated by ``scipy.integrate.solve_ivp``), in its plain form
    (finite-difference Jacobian) and with an exact analytic Jacobian.
(b) Rigid slider–crank, free under gravity (Exudyn's classic planar example data; phc model
    ``peers/rigid_slider_crank.yaml``) against Exudyn (``peers/rigid_exudyn.py``, its
    default generalized-α solver).

Protocol. The reference of (a) is the hand-written model with LSODA at rtol 1e-9 and the
analytic Jacobian (it agrees with rtol 1e-11 to 2e-12); the hand-written model is first
verified against phc (Richardson extrapolation of two midpoint runs). The reference of (b)
is a minimal-coordinate Lagrange model (``peers/rigid_lagrange.py``, DOP853 at rtol 1e-13).
Error = max over the output grid (201 resp. 101 points) of |slider x − reference|. Every
configuration is calibrated by a sweep from loose to tight settings (rtol in half decades;
fixed steps that divide the output interval) and the loosest setting whose error meets the
target (1e-6 resp. 2e-6) is then timed: wall clock of the whole solve (phc: ``phc.simulate``
with consistent initialization and post-processing; solve_ivp: the call; Exudyn:
``SolveDynamic`` on the assembled system), ``repeat`` runs, min / median / max. Compile
time of phc (and Exudyn's model assembly) is reported separately. "÷ fastest phc" is a
configuration's time over that of the fastest phc solver at the same criterion (medians;
range min/max … max/min): above 1, phc is faster by that factor. BLAS runs on one thread.

Every code backend is measured (``--backends numpy,numba,c``, those installed: phc rows are
labelled with theirs), and the issue's targets (issue 16 item 5) are checked at the end in the same run:
the fastest and the fastest energy-exact phc solver against Radau, IDA and the discrete
gradient against Exudyn, the CPU time of a midpoint step of the flexible slider–crank (a
whole ``phc.simulate`` of its 10 000 steps, set-up included, divided by the steps; on numba
the best of at least :data:`STEP_RUNS` runs of 0.2 s, against the shared machine's slow phases), and
the wall time of ``phc simulate models/pendulum.yaml`` from the shell; (b) also times IDA's
first run in a fresh process against Exudyn's (:func:`first_runs`). ``--clock cpu`` times
the runs by CPU time instead of the wall clock (steadier on a shared machine).

Run: ``python benchmarks/bench_peers.py [--repeat 5] [--part a|b|ab] [--clock cpu]`` (prints the
Markdown and writes it to ``benchmarks/peers/peers.md``, a part alone to
``benchmarks/peers/peers_part_<part>.md``, or ``--out``). ``--part s`` measures
only the midpoint step of the flexible slider–crank (the per-step target: CPU µs a step, best
of ``--repeat`` runs, with the residual evaluations and factorizations a step), for every
backend and, on numba, also with the Python step loop; ``--baseline REV`` adds the compiled
loop of phc at git revision REV, run alternately with this one.
"""

from __future__ import annotations

import argparse
import datetime
import functools
import os
import platform
import sys
import tempfile
import time
from pathlib import Path

# One thread for BLAS/OpenMP: the dense solves here are tiny (41×41 at most), and a threaded
# BLAS on a loaded 2-core machine slowed every solver by up to 10× and made timings erratic.
for _var in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(_var, "1")

import numpy as np  # noqa: E402

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
import phc  # noqa: E402

sys.path.insert(0, str(Path(__file__).resolve().parent))
from _timing import best_of  # noqa: E402
from peers import rigid_lagrange  # noqa: E402
from peers.flexible_handwritten import FlexibleSliderCrank  # noqa: E402

FLEX_MODEL = ROOT / "models" / "flexible_slider_crank.yaml"
RIGID_MODEL = Path(__file__).resolve().parent / "peers" / "rigid_slider_crank.yaml"
HALF_DECADES = [1e-3, 3e-4, 1e-4, 3e-5, 1e-5, 3e-6, 1e-6, 3e-7, 1e-7, 3e-8, 1e-8]


SOLVERS = None
"""phc solvers measured (``--solvers``; all by default)."""


def phc_solvers():
    from phc.simulation import BACKENDS
    fixed = getattr(__import__("phc.simulation", fromlist=["FIXED_STEP"]), "FIXED_STEP", ("midpoint",))
    return [s for s in BACKENDS if (s == "ida" or s in fixed) and (SOLVERS is None or s in SOLVERS)]


CLOCK = time.perf_counter
"""What the timed runs measure: wall clock, or this process's CPU time (``--clock cpu``:
steadier on a shared machine, where the wall clock includes waiting for a core)."""

BACKENDS = ["numpy"]
"""Code backends the phc rows run on (``--backends``; numba only where it is installed)."""


def compile_times(path, backend="numpy"):
    """(cold, warm) wall seconds of phc.compile_model: cold with an empty cache directory
    (and, for the compiled backend, an empty state directory: a new signing key)."""
    old = {var: os.environ.get(var) for var in ("PHC_CACHE_DIR", "PHC_STATE_DIR")}
    with tempfile.TemporaryDirectory() as tmp, tempfile.TemporaryDirectory() as state:
        os.environ["PHC_CACHE_DIR"], os.environ["PHC_STATE_DIR"] = tmp, state
        from phc.codegen import numba_cache
        numba_cache._LOADED.clear()  # compile, do not reuse what this process compiled
        t = time.perf_counter()
        phc.compile_model(path, backend=backend)
        cold = time.perf_counter() - t
    for var, value in old.items():
        if value is None:
            os.environ.pop(var, None)
        else:
            os.environ[var] = value
    phc.compile_model(path, backend=backend)
    t = time.perf_counter()
    compiled = phc.compile_model(path, backend=backend)
    return compiled, cold, time.perf_counter() - t


def phc_label(solver, backend):
    """A phc configuration's row label (the backend named when both are measured)."""
    return f"phc {solver}" + (f" [{backend}]" if len(BACKENDS) > 1 else "")


METRICS = ("max", "end")
"""Error metrics: max over the output grid, and at the final time only (the issue's figure)."""


def calibrate(label, settings, run, errors, tol, rows):
    """Run settings from loose to tight until every metric meets tol; {metric: first setting} (None if never)."""
    chosen = {m: None for m in METRICS}
    for s in settings:
        t = time.perf_counter()
        try:
            out = run(s)
            ok = True
        except Exception as exc:  # a failed peer run is a row, not a crash
            out, ok = exc, False
        dt = time.perf_counter() - t
        errs = {m: (f(out) if ok else float("nan")) for m, f in errors.items()}
        rows.append((label, s, errs, dt, ok))
        for m in METRICS:
            if chosen[m] is None and ok and errs[m] <= tol:
                chosen[m] = s
        if all(v is not None for v in chosen.values()):
            break
    return chosen


def time_chosen(configs, chosen, repeat, runner=None):
    """{(label, setting): (min, median, max)} for every chosen setting (each timed once)."""
    timings = {}
    for label, by_metric in chosen.items():
        for s in by_metric.values():
            if s is None or (label, s) in timings:
                continue
            fn = runner(label, s) if runner else None
            if fn is None:
                fn = functools.partial(configs[label][2], s)
            timings[(label, s)] = best_of(fn, repeat=repeat, number=1, clock=CLOCK)
    return timings


def errors_of(xr):
    return {"max": lambda x: float(np.abs(np.asarray(x) - xr).max()),
            "end": lambda x: float(abs(np.asarray(x)[-1] - xr[-1]))}


def fmt_setting(s):
    return f"{s:.3g}" if isinstance(s, float) else str(s)


def ratio_cells(peer, ours):
    """median ratio and range (peer / phc): min/max … max/min."""
    return f"{peer[1] / ours[1]:.2f}", f"{peer[0] / ours[2]:.2f}–{peer[2] / ours[0]:.2f}"


# ----------------------------------------------------------------------------------------------------
def part_a(repeat, methods):
    tol = 1e-6
    print("## (a) Flexible slider–crank, 8 elements, 0.1 s: phc vs hand-written solve_ivp\n")
    model = FlexibleSliderCrank()
    te = np.linspace(0.0, 0.1, 201)
    t = time.perf_counter()
    ref = model.solve(te, "LSODA", 1e-9, atol=1e-11, analytic_jacobian=True)
    t_ref = time.perf_counter() - t
    xr, wr = model.slider_x(ref.y), model.midspan_deflection(ref.y)
    by_backend = {b: compile_times(FLEX_MODEL, b) for b in BACKENDS}
    compiled = by_backend["numpy"][0] if "numpy" in by_backend else next(iter(by_backend.values()))[0]
    # Verification: the hand-written model solves phc's equations.
    ver = {}
    for h in (2e-5, 1e-5):
        r = phc.simulate(compiled, solver="midpoint", step=h, n_out=201)
        ver[h] = (r["slider_x"], r["midspan_deflection"])
    rich_x = (4 * ver[1e-5][0] - ver[2e-5][0]) / 3
    rich_w = (4 * ver[1e-5][1] - ver[2e-5][1]) / 3
    t = time.perf_counter()
    # rtol 2e-6, atol 2e-8: IDA runs at 1/200 of both (docs/tolerances.md), the local 1e-8 and
    # 1e-10 of this line's earlier versions
    r = phc.simulate(compiled, solver="ida", rtol=2e-6, atol=2e-8, n_out=201, max_steps=5_000_000)
    t_ida = time.perf_counter() - t
    ida_x, ida_w = r["slider_x"], r["midspan_deflection"]
    print(f"Reference: hand-written model, LSODA rtol 1e-9 with the analytic Jacobian ({t_ref:.1f} s); "
          f"x_slider(0.1 s) = {xr[-1]:.10f} m, midspan deflection w(L/2, 0.1 s) = {wr[-1]:.6e} m.\n")
    print("Verification against phc (max over the 201 output times):\n")
    print("| phc run | max \\|Δ slider x\\| [m] | max \\|Δ w(L/2)\\| [m] (max \\|w\\| = "
          f"{np.abs(wr).max():.2e}) |")
    print("|---|---:|---:|")
    print(f"| midpoint h = 1e-5 | {np.abs(ver[1e-5][0] - xr).max():.2e} | {np.abs(ver[1e-5][1] - wr).max():.2e} |")
    print(f"| Richardson of midpoint h = 2e-5, 1e-5 | {np.abs(rich_x - xr).max():.2e} | "
          f"{np.abs(rich_w - wr).max():.2e} |")
    print(f"| ida rtol 2e-6, atol 2e-8 ({t_ida:.0f} s) | {np.abs(ida_x - xr).max():.2e} | "
          f"{np.abs(ida_w - wr).max():.2e} |\n")
    for b, (_, cold, warm) in by_backend.items():
        print(f"phc compile, {b} backend (not in the times below): {cold:.2f} s with an empty cache, "
              f"{warm:.2f} s cached.\n")

    rows, chosen = [], {}

    def ivp(method, jac):
        return lambda rtol: model.slider_x(model.solve(te, method, rtol, analytic_jacobian=jac).y)

    def phc_ida(compiled):
        return lambda rtol: phc.simulate(compiled, solver="ida", rtol=rtol, atol=rtol * 1e-2, n_out=201)["slider_x"]

    def phc_fixed(compiled, solver):
        return lambda k: phc.simulate(compiled, solver=solver, step=5e-4 / k, n_out=201)["slider_x"]

    configs = {}
    for method in methods:
        configs[f"solve_ivp {method}, FD Jacobian"] = ("rtol", HALF_DECADES, ivp(method, False))
        configs[f"solve_ivp {method}, analytic Jacobian"] = ("rtol", HALF_DECADES, ivp(method, True))
    for backend, (compiled_b, _, _) in by_backend.items():
        for solver in phc_solvers():
            if solver == "ida":
                configs[phc_label("ida", backend)] = ("rtol", HALF_DECADES, phc_ida(compiled_b))
            else:
                # step = 5e-4/k divides the output interval; the order-4 composition needs fewer
                ks = ([1, 2, 3, 4, 5, 6, 8, 10, 12, 16, 20] if solver == "midpoint4"
                      else [5, 10, 20, 25, 30, 35, 40, 45, 50, 60, 80, 100])
                configs[phc_label(solver, backend)] = ("steps per 5e-4 s", ks, phc_fixed(compiled_b, solver))
    for label, (_, settings, run) in configs.items():
        chosen[label] = calibrate(label, settings, run, errors_of(xr), tol, rows)
    print(f"Calibration (one run per setting, loosest first, until both errors are ≤ {tol:g}):\n")
    print("| configuration | setting | max error over t [m] | error at 0.1 s [m] | time [s] |")
    print("|---|---:|---:|---:|---:|")
    for label, st, e, dt, ok in rows:
        kind = configs[label][0]
        print(f"| {label} | {kind} {fmt_setting(st)}{'' if ok else ' (failed)'} | {e['max']:.2e} | "
              f"{e['end']:.2e} | {dt:.2f} |")
    timings = time_chosen(configs, chosen, repeat)
    for metric in METRICS:
        report(metric, configs, chosen, timings, repeat, tol, rows)
    return configs, chosen, timings, {b: c for b, (c, _, _) in by_backend.items()}


def report(metric, configs, chosen, timings, repeat, tol, rows, extra=None):
    """One table; "÷ phc" = this configuration's time over the fastest phc solver's (medians; range
    min/max … max/min), so a peer row above 1 means phc is faster by that factor."""
    what = "max over the output grid" if metric == "max" else "at the final time"
    errs = {(label, st): e[metric] for label, st, e, dt, ok in rows if ok}
    sel = {label: by[metric] for label, by in chosen.items()}
    ours = [label for label in configs if label.startswith("phc") and sel[label] is not None]
    best = min(ours, key=lambda c: timings[(c, sel[c])][1]) if ours else None
    clock = "CPU time" if CLOCK is time.process_time else "wall clock"
    print(f"\nTime to solution at slider error ≤ {tol:g}, {what} ({repeat} runs each, {clock}; "
          f"fastest phc solver: {best}):\n")
    print("| configuration | setting | error [m] |" + (" energy drift |" if extra else "")
          + " min [s] | median [s] | max [s] | ÷ fastest phc (median) | range |")
    print("|---|---:|---:|" + ("---:|" if extra else "") + "---:|---:|---:|---:|---:|")
    for label in configs:
        st = sel[label]
        if st is None:
            print(f"| {label} | not reached in the sweep |" + " |" * (5 + bool(extra)))
            continue
        mn, md, mx = timings[(label, st)]
        line = f"| {label} | {configs[label][0]} {fmt_setting(st)} | {errs[(label, st)]:.2e} |"
        if extra:
            line += f" {extra[(label, st)]:.1e} |"
        line += f" {mn:.3f} | {md:.3f} | {mx:.3f} |"
        if best is not None:
            a, b = ratio_cells(timings[(label, st)], timings[(best, sel[best])])
            line += f" {a} | {b} |"
        print(line)


# ----------------------------------------------------------------------------------------------------
def part_b(repeat):
    tol = 2e-6
    print("\n## (b) Rigid slider–crank under gravity, 1 s: phc vs Exudyn\n")
    t_grid = np.linspace(0.0, 1.0, 101)
    _, xr, Er = rigid_lagrange.solve(t_grid)
    E0 = Er[0]
    print(f"Reference: minimal-coordinate Lagrange model, DOP853 rtol 1e-13: x_slider(1 s) = {xr[-1]:.9f} m "
          f"(issue: 0.700371930), H(0) = {E0:.6f} J, its energy drift {np.abs(Er - E0).max() / E0:.1e}.\n")
    try:
        import exudyn
        from peers import rigid_exudyn
        exu_version = exudyn.__version__
    except ImportError as exc:  # pragma: no cover - depends on the machine
        rigid_exudyn, exu_version = None, None
        print(f"Exudyn is not importable here ({exc}); install the `bench` extra. Only phc is measured.\n")
    by_backend = {b: compile_times(RIGID_MODEL, b) for b in BACKENDS}
    for b, (_, cold, warm) in by_backend.items():
        print(f"phc compile, {b} backend (not in the times below): {cold:.2f} s with an empty cache, "
              f"{warm:.2f} s cached.")
    rows, chosen, configs, drift = [], {}, {}, {}

    if rigid_exudyn is not None:
        t = time.perf_counter()
        rigid_exudyn.build(1000)
        print(f"Exudyn {exu_version}: model build and assembly {time.perf_counter() - t:.4f} s (not in the times).")

        def exu_run(steps):
            t, xs, E = rigid_exudyn.energy_history(steps)
            pick = np.rint(t_grid * steps).astype(int)  # sensor rows: t = 0, h, 2h, ...
            drift[("Exudyn generalized-α", steps)] = float(np.abs(E[pick] - E0).max() / E0)
            return xs[pick]

        configs["Exudyn generalized-α"] = ("steps", [200, 300, 400, 500, 600, 700, 800, 900, 1000, 1100, 1200, 1300,
                                                      1400, 1500, 1700, 2000, 2500, 3000, 4000, 5000], exu_run)

    def phc_ida(compiled, name):
        def run(rtol):
            r = phc.simulate(compiled, solver="ida", n_out=101, rtol=rtol, atol=rtol * 1e-2)
            drift[(name, rtol)] = float(np.abs(r.H - r.H[0]).max() / E0)
            return r["slider_x"]
        return run

    def phc_fixed(compiled, solver, name):
        def run(k):
            r = phc.simulate(compiled, solver=solver, n_out=101, step=0.01 / k)
            drift[(name, k)] = float(np.abs(r.H - r.H[0]).max() / E0)
            return r["slider_x"]
        return run

    for backend, (compiled_b, _, _) in by_backend.items():
        for solver in phc_solvers():
            name = phc_label(solver, backend)
            if solver == "ida":
                configs[name] = ("rtol", HALF_DECADES, phc_ida(compiled_b, name))
            else:
                configs[name] = ("steps per 0.01 s", [1, 2, 3, 4, 5, 6, 8, 10, 12, 15, 20],
                                 phc_fixed(compiled_b, solver, name))
    for label, (_, settings, run) in configs.items():
        chosen[label] = calibrate(label, settings, run, errors_of(xr), tol, rows)
    print(f"\nCalibration (one run per setting, loosest first, until both errors are ≤ {tol:g}; energy drift = "
          "max |H(t) − H(0)| / H(0) on the output grid):\n")
    print("| configuration | setting | max error over t [m] | error at 1 s [m] | energy drift | time [s] |")
    print("|---|---:|---:|---:|---:|---:|")
    for label, st, e, dt, ok in rows:
        kind = configs[label][0]
        print(f"| {label} | {kind} {fmt_setting(st)}{'' if ok else ' (failed)'} | {e['max']:.2e} | "
              f"{e['end']:.2e} | {drift.get((label, st), float('nan')):.1e} | {dt:.2f} |")

    def runner(label, st):
        if not label.startswith("Exudyn"):
            return None
        exu, _sc, mbs, settings, _nodes, _ = rigid_exudyn.build(st)
        return lambda: exu.SolveDynamic(mbs, settings)

    timings = time_chosen(configs, chosen, repeat, runner)
    for metric in METRICS:
        report(metric, configs, chosen, timings, repeat, tol, rows, extra=drift)
    first = first_runs(chosen, xr[-1], tol, rigid_exudyn is not None)
    return configs, chosen, timings, drift, first


FIRST_RUNS = 5
"""Fresh processes per configuration in the first-run comparison (the median is reported)."""

_FIRST_PHC = r"""
import json, resource, sys, time, warnings
warnings.simplefilter("ignore")
import phc
children = resource.getrusage(resource.RUSAGE_CHILDREN)
t = time.process_time()
c = phc.compile_model(sys.argv[1], backend=sys.argv[2])
load = time.process_time() - t
t = time.process_time()
r = phc.simulate(c, solver="ida", n_out=101, rtol=float(sys.argv[3]), atol=float(sys.argv[3]) * 1e-2)
run = time.process_time() - t
after = resource.getrusage(resource.RUSAGE_CHILDREN)
child = (after.ru_utime + after.ru_stime) - (children.ru_utime + children.ru_stime)
print(json.dumps([load, run + child, float(r["slider_x"][-1])]))
"""

_FIRST_EXUDYN = r"""
import json, sys, time
sys.path.insert(0, sys.argv[1])
from peers import rigid_exudyn
t = time.process_time()
exu, _sc, mbs, settings, nodes, _ = rigid_exudyn.build(int(sys.argv[2]))
load = time.process_time() - t
t = time.process_time()
exu.SolveDynamic(mbs, settings)
run = time.process_time() - t
print(json.dumps([load, run, float(mbs.GetNodeOutput(nodes["slider"], exu.OutputVariableType.Position)[0])]))
"""


def first_runs(chosen, x_end, tol, exudyn):
    """(b') The first run in a fresh process: phc IDA on each compiled backend at its setting
    chosen for the error at 1 s, against Exudyn at its; {label: (median load s, median run s,
    error)} over :data:`FIRST_RUNS` processes. phc's run is ``phc.simulate`` right after a cached
    ``phc.compile_model`` (loading the compiled model, not in the run), so it includes what a
    process does once (loading the solver library, the first run's scales); Exudyn's is
    ``SolveDynamic`` after building and assembling its model (not in the run). CPU time of the
    process and of any child it waits for. The processes may write Python's bytecode files
    (``PYTHONDONTWRITEBYTECODE`` unset for them, as in an installed package), and one untimed
    process of each configuration runs first, so a run does not include compiling phc's or
    Exudyn's Python source."""
    import json
    import subprocess

    jobs = []
    for backend in BACKENDS:
        label = phc_label("ida", backend)
        if backend != "numpy" and label in chosen and chosen[label]["end"] is not None:
            rtol = chosen[label]["end"]
            phc.compile_model(RIGID_MODEL, backend=backend)  # cached for the fresh processes
            jobs.append((label, f"rtol {fmt_setting(rtol)}",
                         [sys.executable, "-c", _FIRST_PHC, str(RIGID_MODEL), backend, repr(rtol)]))
    exu = "Exudyn generalized-α"
    if exudyn and exu in chosen and chosen[exu]["end"] is not None:
        steps = chosen[exu]["end"]
        jobs.append((exu, f"steps {steps}",
                     [sys.executable, "-c", _FIRST_EXUDYN, str(Path(__file__).resolve().parent), str(steps)]))
    if not jobs:
        return {}
    print(f"\nFirst run in a fresh process (median of {FIRST_RUNS} processes, CPU time of the process and its "
          "children; the model's loading or building not in the run):\n")
    print("| configuration | setting | load [s] | first run [s] | error at 1 s [m] |")
    print("|---|---:|---:|---:|---:|")
    env = {k: v for k, v in os.environ.items() if k != "PYTHONDONTWRITEBYTECODE"}
    out = {}
    for label, setting, cmd in jobs:
        runs = [json.loads(subprocess.run(cmd, capture_output=True, text=True, check=True, env=env)
                           .stdout.splitlines()[-1]) for _ in range(FIRST_RUNS + 1)][1:]
        load, run = (float(np.median([r[i] for r in runs])) for i in (0, 1))
        error = max(abs(r[2] - x_end) for r in runs)
        out[label] = (load, run, error)
        print(f"| {label} | {setting} | {load:.3f} | {run:.3f} | {error:.2e}{'' if error <= tol else ' (above)'} |")
    return out


# ----------------------------------------------------------------------------------------------------
ENERGY_EXACT = ("midpoint", "midpoint4", "discrete_gradient")
"""Fixed-step solvers whose discrete energy balance is exact (for quadratic H; the discrete
gradient for any H)."""


def _fastest(configs, chosen, timings, metric, pick):
    """(label, (min, median, max)) of the fastest configuration `pick(label)` accepts."""
    found = [(label_, timings[(label_, chosen[label_][metric])]) for label_ in configs
             if pick(label_) and chosen[label_][metric] is not None]
    return min(found, key=lambda item: item[1][1]) if found else (None, None)


def _solver_of(label_):
    return label_.split()[1] if label_.startswith("phc ") else ""


STEP_RUNS = 10
"""Runs of the compiled midpoint step measurement in the targets (best of them): each is a
whole ``phc.simulate`` of 10 000 steps, set-up included."""


def per_step_us(compiled, repeat, compiled_loop=True, counts=None, mixed=True):
    """CPU µs per step of the midpoint rule on the flexible slider–crank at its model step
    (`compiled_loop` False: ``PHC_COMPILED_LOOP=0``, the Python step loop calling the same functions;
    `mixed` False: ``PHC_MIXED_PRECISION=0``, the compiled loop's corrections in double precision);
    `counts` (a dict, optional) gets the residual evaluations and factorizations a step."""
    best = None
    runs = []
    old = os.environ.get("PHC_COMPILED_LOOP")
    old_mixed = os.environ.get("PHC_MIXED_PRECISION")
    os.environ["PHC_COMPILED_LOOP"] = "1" if compiled_loop else "0"
    os.environ["PHC_MIXED_PRECISION"] = "1" if mixed else "0"
    try:
        for _ in range(repeat):
            t = time.process_time()
            r = phc.simulate(compiled, solver="midpoint")
            cpu = time.process_time() - t
            best = min(best or cpu, cpu)
            runs.append(cpu)
    finally:
        for name, value in (("PHC_COMPILED_LOOP", old), ("PHC_MIXED_PRECISION", old_mixed)):
            if value is None:
                os.environ.pop(name, None)
            else:
                os.environ[name] = value
    if counts is not None:
        counts.update(fev=r.n_residual_evals / max(r.steps, 1), fact=r.n_jacobian_evals / max(r.steps, 1),
                      median=float(np.median(runs)) / max(r.steps, 1) * 1e6, runs=len(runs))
    return best / max(r.steps, 1) * 1e6, r.steps


def part_step(repeat, baseline=None):
    """(s) The midpoint step of the flexible slider–crank alone (the per-step target); with
    `baseline` (a git revision), the same measurement of that revision's phc in a separate
    process, the two alternating run by run (a shared machine's load hits both alike)."""
    print("## (s) Midpoint step of the flexible slider–crank (models/flexible_slider_crank.yaml, 83 unknowns, "
          f"h = 1e-5 s, 10 000 steps): CPU time a step, best of {repeat} runs\n")
    rows = []
    for backend in BACKENDS:
        compiled = phc.compile_model(FLEX_MODEL, backend=backend)
        for loop in ([True, False] if backend == "numba" else [False]):
            which = "compiled step loop" if loop else "Python step loop" + (" (PHC_COMPILED_LOOP=0)" if backend == "numba"
                                                                             else "")
            os.environ["PHC_COMPILED_LOOP"] = "1" if loop else "0"
            phc.simulate(compiled, solver="midpoint", t_end=1e-3)  # load the compiled loop before timing
            os.environ.pop("PHC_COMPILED_LOOP")
            rows.append((f"{backend}, {which}", functools.partial(per_step_us, compiled, 1, compiled_loop=loop)))
            if backend == "numba" and loop:  # what the single-precision copy of the inverse gains
                rows.append((f"{backend}, {which}, double precision (PHC_MIXED_PRECISION=0)",
                             functools.partial(per_step_us, compiled, 1, compiled_loop=loop, mixed=False)))
            if baseline and backend == "numba" and loop:
                rows.append((f"{backend}, {which}, phc at {baseline}", functools.partial(_baseline_step, baseline)))
    best, every = {}, {}
    with tempfile.TemporaryDirectory() as tmp:
        if baseline:
            import subprocess

            archive = subprocess.run(["git", "-C", str(ROOT), "archive", baseline, "phc"], capture_output=True,
                                     check=True).stdout
            subprocess.run(["tar", "-x", "-C", tmp], input=archive, check=True)
        for _ in range(repeat):
            for label_, run in rows:
                counts = {}
                us = run(tmp, counts) if label_.endswith(f"phc at {baseline}") else run(counts=counts)[0]
                every.setdefault(label_, []).append(us)
                if label_ not in best or us < best[label_][0]:
                    best[label_] = (us, counts)
    print("| backend, step loop | µs CPU a step (best) | median, max of the runs | residual evaluations a step | "
          "factorizations a step | goal (best) |")
    print("|---|---:|---:|---:|---:|---|")
    for label_, _ in rows:
        us, counts = best[label_]
        print(f"| {label_} | {us:.1f} | {np.median(every[label_]):.1f}, {max(every[label_]):.1f} | {counts['fev']:.2f} | "
              f"{counts['fact']:.4f} | ≤ 20 µs: {'met' if us <= 20 else 'not met'} |")
    return best


def _baseline_step(revision, folder, counts):
    """One measurement of per_step_us with the phc of `revision` (extracted to `folder`), in a fresh process."""
    import json
    import subprocess

    code = ("import json, sys, time; sys.path.insert(0, sys.argv[1]); import phc; "
            "c = phc.compile_model(sys.argv[2], backend='numba'); phc.simulate(c, solver='midpoint', t_end=1e-3); "
            "t = time.process_time(); r = phc.simulate(c, solver='midpoint'); cpu = time.process_time() - t; "
            "print(json.dumps([phc.__file__, cpu / r.steps * 1e6, r.n_residual_evals / r.steps, "
            "r.n_jacobian_evals / r.steps]))")
    env = dict(os.environ, PHC_COMPILED_LOOP="1")
    out = subprocess.run([sys.executable, "-c", code, folder, str(FLEX_MODEL)], capture_output=True, text=True,
                         env=env, check=True)
    where, us, fev, fact = json.loads(out.stdout.strip().splitlines()[-1])
    assert where.startswith(folder), where  # the baseline's phc, not this one
    counts.update(fev=fev, fact=fact)
    return us


def loop_compile_times():
    """(cold, warm) CPU seconds of building the compiled step loop in a fresh process: cold with an
    empty cache and state directory, warm with the cache the cold run filled."""
    import subprocess

    code = ("import time, phc.simulation.compiled_steps as c; t = time.process_time(); "
            "ok = bool(c._build()); print(time.process_time() - t if ok else 'nan')")
    times = []
    with tempfile.TemporaryDirectory() as tmp, tempfile.TemporaryDirectory() as state:
        env = dict(os.environ, PHC_CACHE_DIR=tmp, PHC_STATE_DIR=state, PYTHONPATH=str(ROOT))
        for _ in range(2):
            out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, env=env)
            times.append(float((out.stdout.strip().splitlines() or ["nan"])[-1]))
    return tuple(times)


def shell_wall(model, backend, repeat):
    """Best wall (and its CPU) of `phc simulate MODEL` from the shell, cache warm."""
    import resource
    import subprocess

    cmd = [sys.executable, "-m", "phc", "simulate", str(model), "--quiet", "--backend", backend]
    subprocess.run(cmd, capture_output=True, check=True)  # warm the caches
    best = None
    for _ in range(repeat):
        usage = resource.getrusage(resource.RUSAGE_CHILDREN)
        cpu0 = usage.ru_utime + usage.ru_stime
        t = time.perf_counter()
        subprocess.run(cmd, capture_output=True, check=True)
        wall = time.perf_counter() - t
        usage = resource.getrusage(resource.RUSAGE_CHILDREN)
        cpu = usage.ru_utime + usage.ru_stime - cpu0
        if best is None or wall < best[0]:
            best = (wall, cpu)
    return best


def targets(a, b, repeat):
    """The issue's targets, each measured in this run: a table of (target, measured, goal, met)."""
    rows = []

    def add(what, value, goal, met, note=""):
        rows.append((what, value, goal, "met" if met else "not met", note))

    if a is not None:
        configs, chosen, timings, compiled = a
        radau = "solve_ivp Radau, analytic Jacobian"
        if radau in chosen and chosen[radau]["max"] is not None:
            peer = timings[(radau, chosen[radau]["max"])]
            best, t = _fastest(configs, chosen, timings, "max", lambda c: c.startswith("phc "))
            if best:
                ratio = peer[1] / t[1]
                add("(a) fastest phc solver vs Radau (analytic Jacobian), slider error ≤ 1e-6 max over t",
                    f"{ratio:.2f}× ({best}: {t[1]:.3f} s; Radau {peer[1]:.3f} s)", "≥ 5× (moonshot 10×)", ratio >= 5)
            exact, t = _fastest(configs, chosen, timings, "max", lambda c: _solver_of(c) in ENERGY_EXACT)
            if exact:
                ratio = peer[1] / t[1]
                add("(a) energy-exact solver vs Radau (analytic Jacobian), same criterion",
                    f"{ratio:.2f}× ({exact}: {t[1]:.3f} s)", "≥ 2×", ratio >= 2)
        for backend, comp in compiled.items():
            counts = {}
            # a compiled run is 0.2 s: best of STEP_RUNS (at least) against the machine's slow phases;
            # the Python loop's 3 s runs, best of at most 3
            runs = max(repeat, STEP_RUNS) if backend in ("numba", "c") else max(1, min(repeat, 3))
            us, steps = per_step_us(comp, runs, counts=counts)
            loop = " (compiled step loop)" if backend in ("numba", "c") else ""
            add(f"(a) midpoint step on the flexible slider–crank, {backend} backend{loop} (model step, {steps} steps)",
                f"{us:.1f} µs CPU, best of {counts['runs']} runs (median {counts['median']:.1f}; "
                f"{counts['fev']:.2f} residual evaluations, {counts['fact']:.3f} factorizations a step)",
                "≤ 20 µs", us <= 20)
            if backend == "numba":  # the same run with the Python step loop: what the compiled loop gains
                before, _ = per_step_us(comp, max(1, min(repeat, 3)), compiled_loop=False)
                add("(a) … the same, numba backend with the Python step loop (PHC_COMPILED_LOOP=0), for comparison",
                    f"{before:.1f} µs CPU ({before / us:.1f}× the compiled loop)", "—", False)
    if b is not None:
        configs, chosen, timings, _drift, first = b
        exu = "Exudyn generalized-α"
        if exu in chosen and chosen[exu]["end"] is not None:
            peer = timings[(exu, chosen[exu]["end"])]
            # ≤ 1× is issue 16's goal; issue 33 (item 3) asks ≤ 0.5× of IDA
            for solver, goal in (("ida", 0.5), ("discrete_gradient", 2.0)):
                best, t = _fastest(configs, chosen, timings, "end", lambda c, s=solver: _solver_of(c) == s)
                if best:
                    ratio = t[1] / peer[1]
                    add(f"(b) phc {solver} vs Exudyn, slider error ≤ 2e-6 at 1 s",
                        f"{ratio:.2f}× Exudyn's time ({best}: {t[1]:.3f} s; Exudyn {peer[1]:.3f} s)",
                        f"≤ {goal:g}×", ratio <= goal)
            for label_, (_, run, error) in first.items():
                if label_ != exu and exu in first and error <= 2e-6:
                    ratio = run / first[exu][1]
                    add(f"(b) {label_} vs Exudyn, slider error ≤ 2e-6 at 1 s, the first run in a fresh process",
                        f"{ratio:.2f}× Exudyn's time ({run:.3f} s; Exudyn {first[exu][1]:.3f} s)", "≤ 0.5×",
                        ratio <= 0.5)
    pendulum = ROOT / "models" / "pendulum.yaml"
    for backend in BACKENDS:
        wall, cpu = shell_wall(pendulum, "auto" if backend == "numpy" else backend, max(1, min(repeat, 5)))
        add(f"`phc simulate models/pendulum.yaml` from the shell, cached, --backend "
            f"{'auto' if backend == 'numpy' else backend}", f"{wall:.2f} s wall ({cpu:.2f} s CPU)", "≤ 0.8 s",
            wall <= 0.8)
    print("\n## Targets (issue 16 item 5; issue 33 item 3 for IDA against Exudyn), measured in this run\n")
    print("| target | measured | goal | |")
    print("|---|---|---|---|")
    for what, value, goal, met, _ in rows:
        print(f"| {what} | {value} | {goal} | {met if goal != '—' else ''} |")
    if "numba" in BACKENDS and a is not None:
        cold, warm = loop_compile_times()
        print(f"\nThe compiled step loop of the fixed-step solvers (phc/simulation/compiled_steps.py; once per "
              f"machine and phc version, not in the times above): {cold:.1f} s CPU to compile in a fresh process "
              f"with an empty cache, {warm:.2f} s CPU to load it from the cache.")
    return rows


class _Tee:
    """stdout also written to a file (the Markdown the README quotes)."""

    def __init__(self, path):
        self.file, self.stdout = open(path, "w"), sys.stdout

    def write(self, text):
        self.stdout.write(text)
        self.file.write(text)

    def flush(self):
        self.stdout.flush()
        self.file.flush()


def main(argv=None):
    global BACKENDS, CLOCK, SOLVERS
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--repeat", type=int, default=5)
    ap.add_argument("--part", default="ab")
    ap.add_argument("--methods", default="Radau,LSODA", help="solve_ivp methods of (a), e.g. Radau,LSODA,BDF")
    ap.add_argument("--backends", default="numpy,numba,c",
                    help="code backends of the phc rows (numba where it is installed, c where a C compiler is)")
    ap.add_argument("--solvers", default=None,
                    help="only these phc solvers, e.g. ida (the peers run as always); default: all")
    ap.add_argument("--baseline", default=None,
                    help="with --part s: also measure the midpoint step with phc at this git revision, alternating")
    ap.add_argument("--clock", choices=("wall", "cpu"), default="wall",
                    help="time the runs by the wall clock or by this process's CPU time")
    ap.add_argument("--out", type=Path, default=None,
                    help="also write the Markdown here (default: peers/peers.md for the whole run, "
                         "peers/peers_part_<part>.md for a part, so that a part does not overwrite the whole)")
    args = ap.parse_args(argv)
    if args.out is None:
        folder = Path(__file__).resolve().parent / "peers"
        args.out = folder / ("peers.md" if set(args.part) == {"a", "b"} else f"peers_part_{args.part}.md")
    from phc.codegen.numba_backend import available

    CLOCK = time.process_time if args.clock == "cpu" else time.perf_counter
    from phc.codegen.c_backend import available as c_available

    BACKENDS = [b for b in args.backends.split(",") if b == "numpy" or (b == "numba" and available()[0])
                or (b == "c" and c_available()[0])]
    SOLVERS = set(args.solvers.split(",")) if args.solvers else None
    args.out.parent.mkdir(parents=True, exist_ok=True)
    sys.stdout = _Tee(args.out)
    start = time.perf_counter()
    load = os.getloadavg()[0] if hasattr(os, "getloadavg") else float("nan")
    print(f"# Peers — {datetime.datetime.now():%Y-%m-%d %H:%M}, {platform.machine()} {os.cpu_count()} cores "
          f"(load average {load:.1f} at the start), Python {platform.python_version()}, numpy {np.__version__}; "
          f"backends {', '.join(BACKENDS)}; times are {'CPU' if args.clock == 'cpu' else 'wall-clock'} seconds"
          f"{' (the midpoint step: CPU time always)' if 's' in args.part or 'a' in args.part else ''}\n")
    print(f"Command: `python benchmarks/bench_peers.py {' '.join(argv if argv is not None else sys.argv[1:])}`\n")
    a = part_a(args.repeat, args.methods.split(",")) if "a" in args.part else None
    b = part_b(args.repeat) if "b" in args.part else None
    if "s" in args.part:
        part_step(args.repeat, args.baseline)
    if a is not None or b is not None:
        targets(a, b, args.repeat)
    load = os.getloadavg()[0] if hasattr(os, "getloadavg") else float("nan")
    print(f"\nWhole script: {time.perf_counter() - start:.0f} s; load average at the end {load:.1f}.")


if __name__ == "__main__":
    main()
