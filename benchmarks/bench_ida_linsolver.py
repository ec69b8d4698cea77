"""Dense or sparse linear solver inside IDA: where is the crossover? (issue 16 item 3)

phc's IDA backend (``phc/simulation/ida.py``) factorizes the iteration matrix
``F_y + c_j F_ẏ`` with SUNDIALS' dense LU up to ``DENSE_LIMIT`` unknowns and with
SuperLU_MT (one thread) above. This script runs the flexible slider–crank
(``models/flexible_slider_crank.yaml``) with 1 to 32 rod elements — the same equations at
growing size — through ``phc.simulate(solver="ida")`` with each linear solver (SUNDIALS'
own dense LU ``dense``, LAPACK's ``lapackdense``, and ``sparse``), same tolerances, and
reports the CPU time of the whole run (best of ``--repeat``), the steps and the time per
step. The singularity monitor is off (``--monitor`` keeps it): its looks cost the same with
every linear solver. The round-off of the different factorizations changes the step sequence a little
(a few % more or fewer steps), so the solvers are compared by CPU time per step. The
crossover is the smallest size from which the sparse solver is faster per step at every
measured size; ``DENSE_LIMIT`` is set just below it.

Run: ``python benchmarks/bench_ida_linsolver.py [--elements 1 2 4 ...] [--repeat 3]``
(writes ``benchmarks/results/ida_linsolver.md`` and ``.json``, or ``--out``).
"""

from __future__ import annotations

import argparse
import datetime
import json
import os
import platform
import re
import sys
import tempfile
import time
from pathlib import Path

for _var in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(_var, "1")

import numpy as np  # noqa: E402

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
import phc  # noqa: E402
from phc.simulation import ida, monitor  # noqa: E402

SOLVERS = ("dense", "lapackdense", "sparse")


def model_with(elements: int, folder: Path) -> Path:
    text = (ROOT / "models" / "flexible_slider_crank.yaml").read_text()
    text, count = re.subn(r"(\n\s+elements:\s*)8\b", rf"\g<1>{elements}", text)
    assert count == 1, "the model's element count was not found"
    path = folder / f"flexible_slider_crank_{elements}.yaml"
    path.write_text(text)
    return path


def run(compiled, linsolver: str, t_end: float, rtol: float, repeat: int, monitor_on: bool):
    """(best CPU seconds, steps, slider x at t_end) of IDA with `linsolver`."""
    saved = ida.DENSE_LIMIT, ida.DENSE_SOLVER, monitor.MAX_SIZE
    ida.DENSE_LIMIT = 0 if linsolver == "sparse" else 10**9
    ida.DENSE_SOLVER = linsolver if linsolver != "sparse" else saved[1]
    if not monitor_on:  # the monitor's dense SVD costs the same with either solver: left out
        monitor.MAX_SIZE = 0
    try:
        best, result = None, None
        for _ in range(repeat):
            t = time.process_time()
            result = phc.simulate(compiled, solver="ida", t_end=t_end, n_out=21, rtol=rtol, atol=rtol * 1e-2)
            cpu = time.process_time() - t
            best = cpu if best is None else min(best, cpu)
    finally:
        ida.DENSE_LIMIT, ida.DENSE_SOLVER, monitor.MAX_SIZE = saved
    if not result.success:
        raise RuntimeError(f"{linsolver}: {result.message}")
    return best, result.steps, float(result["slider_x"][-1])


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--elements", type=int, nargs="+", default=[1, 2, 4, 6, 8, 10, 12, 14, 16, 24, 32])
    ap.add_argument("--repeat", type=int, default=3)
    ap.add_argument("--t-end", type=float, default=0.05)
    ap.add_argument("--rtol", type=float, default=1e-5)
    ap.add_argument("--backend", default="auto")
    ap.add_argument("--monitor", action="store_true",
                    help="keep the singularity monitor on (its looks cost the same with every solver)")
    ap.add_argument("--out", type=Path, default=ROOT / "benchmarks" / "results" / "ida_linsolver.md")
    args = ap.parse_args(argv)
    rows = []
    with tempfile.TemporaryDirectory() as tmp:
        for e in args.elements:
            compiled = phc.compile_model(model_with(e, Path(tmp)), certify=False, backend=args.backend)
            n = compiled.module.N
            cells = {}
            for solver in SOLVERS:
                cells[solver] = run(compiled, solver, args.t_end, args.rtol, args.repeat, args.monitor)
            x = [c[2] for c in cells.values()]
            rows.append(dict(elements=e, n=n, nnz=len(compiled.module.JAC_ROWS), backend=compiled.backend,
                             **{f"{s}_cpu": cells[s][0] for s in SOLVERS},
                             **{f"{s}_steps": cells[s][1] for s in SOLVERS},
                             spread=float(max(x) - min(x))))
            print(rows[-1], flush=True)
    # per step: round-off of the different factorizations changes the step sequence a little
    per_step = {s: [r[f"{s}_cpu"] / r[f"{s}_steps"] for r in rows] for s in SOLVERS}
    dense_best = [min(a, b) for a, b in zip(per_step["dense"], per_step["lapackdense"])]
    sparse_faster = [sp < d for sp, d in zip(per_step["sparse"], dense_best)]
    crossover = None
    for i in range(len(rows)):
        if all(sparse_faster[i:]):
            crossover = rows[i]["n"]
            break
    largest_dense = max((r["n"] for r, f in zip(rows, sparse_faster) if not f), default=None)
    load = os.getloadavg()[0] if hasattr(os, "getloadavg") else float("nan")
    lines = [f"# IDA linear solver: dense or sparse — {datetime.datetime.now():%Y-%m-%d %H:%M}, "
             f"{platform.machine()} {os.cpu_count()} cores (load average {load:.1f}), Python "
             f"{platform.python_version()}, numpy {np.__version__}",
             "",
             f"Command: `python benchmarks/bench_ida_linsolver.py {' '.join(sys.argv[1:] if argv is None else argv)}`",
             "",
             f"Flexible slider–crank with 1–{max(args.elements)} rod elements, IDA to t = {args.t_end:g} s at rtol "
             f"{args.rtol:g} (atol = rtol/100), code backend `{rows[0]['backend']}`; CPU seconds of the whole "
             f"`phc.simulate`, best of {args.repeat}; BLAS on one thread; singularity monitor "
             f"{'on' if args.monitor else 'off (its dense SVD costs the same with every linear solver)'}.",
             "",
             "| elements | unknowns | Jacobian entries | dense [s] | lapackdense [s] | sparse [s] | steps (dense) | "
             "µs/step dense | µs/step lapackdense | µs/step sparse | sparse ÷ best dense (per step) |",
             "|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|"]
    for i, (r, d) in enumerate(zip(rows, dense_best)):
        lines.append(f"| {r['elements']} | {r['n']} | {r['nnz']} | {r['dense_cpu']:.3f} | {r['lapackdense_cpu']:.3f} | "
                     f"{r['sparse_cpu']:.3f} | {r['dense_steps']} | {per_step['dense'][i] * 1e6:.0f} | "
                     f"{per_step['lapackdense'][i] * 1e6:.0f} | {per_step['sparse'][i] * 1e6:.0f} | "
                     f"{per_step['sparse'][i] / d:.2f} |")
    lines += ["",
              f"Largest size where a dense solver was faster: {largest_dense} unknowns; sparse faster at every size "
              f"from: {crossover} unknowns. `phc/simulation/ida.py` has DENSE_LIMIT = {ida.DENSE_LIMIT} and "
              f"DENSE_SOLVER = `{ida.DENSE_SOLVER}`."]
    text = "\n".join(lines) + "\n"
    print(text)
    args.out.parent.mkdir(parents=True, exist_ok=True)
    args.out.write_text(text)
    args.out.with_suffix(".json").write_text(json.dumps(dict(rows=rows, crossover=crossover,
                                                             largest_dense_faster=largest_dense), indent=1))


if __name__ == "__main__":
    main()
