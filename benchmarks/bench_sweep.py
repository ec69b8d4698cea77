"""Parameter studies on several processes (issue 18, item 7): what `phc sweep` buys.

64 runs of the flexible slider–crank (`models/flexible_slider_crank.yaml`: crank at
150 rad/s, moving-frame Euler–Bernoulli rod with 8 elements, implicit midpoint at
h = 1e-5 s over 0.1 s) over the rod's bending stiffness EI from 0.1× to 10× its
68.27 N m² (`log:6.827:682.7:64`), run

* in this process, one ``phc.simulate`` after the other (the serial baseline);
* by :func:`phc.sweep.run_sweep` on the local process pool and on a Dask
  ``LocalCluster``, with 1 and 2 worker processes.

Per configuration: the wall time of the runs (from the first submission to the last row:
worker start-up, transfer of the compiled model and scheduling included), the speed-up
over the serial baseline, and the **overhead per run** = (workers × wall time − Σ the
runs' own wall times) / runs: worker time not spent simulating. All configurations must
give the same rows (the timing columns aside); the script checks it.

One compilation per sweep: the compile time of the model — in a fresh process, what every
``phc simulate`` pays, and the start-up of the ``phc`` command — times the runs is what
compiling once saves over compiling per run.

Writes ``benchmarks/sweep/sweep.md`` (the tables; read into benchmarks/README.md) and
``benchmarks/sweep/deflection.png`` (the sweep's result: the largest midspan deflection of
the rod against EI, drawn by ``phc sweep --plot``).

Run: ``python benchmarks/bench_sweep.py [--runs 64] [--t-end 0.1] [--workers 1 2]``.
"""

from __future__ import annotations

import argparse
import math
import os
import platform
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

import phc  # noqa: E402
from phc.sweep import MACHINE_COLUMNS, plot_sweep, read_results, run_sweep  # noqa: E402

MODEL = ROOT / "models" / "flexible_slider_crank.yaml"
OUT = ROOT / "benchmarks" / "sweep"
EI = 68.27


def serial(compiled, values, t_end):
    """Wall time and per-run wall times of the runs one after the other in this process."""
    times = []
    start = time.perf_counter()
    for v in values:
        t = time.perf_counter()
        phc.simulate(compiled, t_end=t_end, params={"EI": v})
        times.append(time.perf_counter() - t)
    return time.perf_counter() - start, times


def cold_compile() -> tuple[float, float]:
    """(compile time in a fresh process, wall time of `phc compile` in a fresh process)."""
    code = ("import time; t = time.perf_counter(); import phc; "
            f"c = phc.compile_model({str(MODEL)!r}); print(time.perf_counter() - t)")
    compile_s = float(subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                                     check=True).stdout.split()[-1])
    with tempfile.TemporaryDirectory() as tmp:
        t = time.perf_counter()
        # a compilation, not a hit in the record of an earlier `phc compile` of the same model
        subprocess.run([sys.executable, "-m", "phc", "compile", str(MODEL), "-o", tmp], capture_output=True,
                       check=True, env=dict(os.environ, PHC_FRONT_END_CACHE="0"))
        cli_s = time.perf_counter() - t
    return compile_s, cli_s


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--runs", type=int, default=64)
    parser.add_argument("--t-end", type=float, default=0.1)
    parser.add_argument("--workers", type=int, nargs="+", default=[1, 2])
    parser.add_argument("--executors", nargs="+", default=["local", "dask"])
    args = parser.parse_args()
    OUT.mkdir(parents=True, exist_ok=True)
    load_start = os.getloadavg()[0] if hasattr(os, "getloadavg") else math.nan
    spec = f"log:{EI / 10:g}:{EI * 10:g}:{args.runs}"
    compiled = phc.compile_model(MODEL)
    warm_compile = phc.compile_model(MODEL).compile_time  # the second in this process
    from phc.spec.sweep import parse_spec

    values = parse_spec("EI", spec).values
    print(f"serial: {args.runs} runs in this process ...", file=sys.stderr)
    serial_s, serial_runs = serial(compiled, values, args.t_end)
    cold_s, cli_s = cold_compile()

    rows, reference, figure = [], None, None
    with tempfile.TemporaryDirectory() as tmp:
        for executor in args.executors:
            for workers in args.workers:
                print(f"{executor}, {workers} worker(s) ...", file=sys.stderr)
                out = Path(tmp) / f"{executor}_{workers}.csv"
                report = run_sweep(MODEL, out, params=[("EI", spec)], t_end=args.t_end, executor=executor,
                                   workers=workers, progress=False, compiled=compiled)
                results = read_results(out)
                strip = [{k: v for k, v in r.items() if k not in MACHINE_COLUMNS} for r in results]
                if reference is None:
                    reference, figure = strip, report
                identical = strip == reference
                if not identical:
                    diff = sorted({k for a, b in zip(strip, reference) for k in a if a[k] != b.get(k)
                                   and not (isinstance(a[k], float) and math.isnan(a[k]) and math.isnan(b[k]))})
                    identical = not diff
                    if diff:
                        print(f"  rows differ in {', '.join(diff)}", file=sys.stderr)
                        for a, b in zip(strip, reference):
                            if any(a[k] != b[k] for k in diff):
                                print(f"  e.g. {[(k, a[k], b[k]) for k in diff]}", file=sys.stderr)
                                break
                busy = sum(r["wall_time_s"] for r in results)
                wall = report.run_elapsed_s
                rows.append(dict(executor=executor, workers=workers, wall=wall, speedup=serial_s / wall,
                                 overhead=(workers * wall - busy) / len(results),
                                 run=statistics.median(r["wall_time_s"] for r in results),
                                 failed=len(report.failed), identical=identical))
    plot_sweep(figure, OUT / "deflection.png", "midspan_deflection.max")

    n = args.runs
    load_end = os.getloadavg()[0] if hasattr(os, "getloadavg") else math.nan
    lines = [
        f"Command: `python benchmarks/bench_sweep.py --runs {n} --t-end {args.t_end:g}` "
        f"({os.cpu_count()}-core {platform.machine()} machine, Python {platform.python_version()}, "
        f"backend {compiled.backend}; load average {load_start:.1f} at the start, {load_end:.1f} at the end)",
        "",
        f"{n} runs of the flexible slider–crank over EI = `{spec}` (0.1× to 10× of {EI} N m²), "
        f"t_end = {args.t_end:g} s, implicit midpoint at h = 1e-5 s.",
        "",
        "| executor | workers | wall [s] | speed-up vs serial | overhead per run [s] | median run [s] | "
        "failed | rows identical |",
        "|---|---:|---:|---:|---:|---:|---:|---|",
        f"| serial, in process | 1 | {serial_s:.1f} | 1.00 | — | {statistics.median(serial_runs):.2f} | 0 | — |",
    ]
    for r in rows:
        lines.append(f"| {'local pool' if r['executor'] == 'local' else 'Dask LocalCluster'} | {r['workers']} | "
                     f"{r['wall']:.1f} | {r['speedup']:.2f} | {r['overhead']:.3f} | {r['run']:.2f} | {r['failed']} | "
                     f"{'yes' if r['identical'] else 'NO'} |")
    lines += [
        "",
        "| compile time | per compilation [s] | × runs [s] |",
        "|---|---:|---:|",
        f"| `phc.compile_model` in a fresh process (what every `phc simulate` pays) | {cold_s:.2f} | {n * cold_s:.0f} |",
        f"| `phc compile` command, start-up included | {cli_s:.2f} | {n * cli_s:.0f} |",
        f"| `phc.compile_model` warm (this process, caches filled) | {warm_compile:.2f} | {n * warm_compile:.0f} |",
        "",
        f"One compilation per sweep saves (runs − 1) × the cold compile time: {(n - 1) * cold_s:.0f} s of "
        f"{n} runs, {(n - 1) * cold_s / serial_s:.0%} of the serial run time; with one `phc simulate` command "
        f"per run, {(n - 1) * cli_s:.0f} s.",
        "",
        "![largest midspan deflection against EI](deflection.png)",
    ]
    text = "\n".join(lines) + "\n"
    (OUT / "sweep.md").write_text(text)
    print(text)


if __name__ == "__main__":
    main()
