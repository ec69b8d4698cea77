"""The N four-bar mechanism (IFToMM library of computational benchmarks, problem A02) at
N = 1, 10 and 40 loops: compile, certify and run 20 s through every singular configuration.

    python benchmarks/record.py four_bar -- python benchmarks/bench_four_bar.py

Each size runs in a fresh process (its peak memory is that process's): the model is written
by ``models/n_four_bar.py`` with ``t_end = 20``, compiled as ``phc compile`` does (with the
certificate, default back end), then run with the midpoint rule and the discrete gradient at
h = 1e-3. The errors are against the exact one-degree-of-freedom motion (all cranks turn
together; θ'' = −g·M/I·cos θ with I = (N+1)/3 + N and M = (N+1)/2 + N for unit bars, solved
by SciPy at 1e-12: `exact_theta` of tests/hard/test_n_four_bar.py); the benchmark's tolerance is 1e-3 m on
the tip B0 of crank 0, at most the crank angle's error in rad.
"""

from __future__ import annotations

import argparse
import json
import resource
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "tests" / "hard"))
sys.path.insert(0, str(ROOT / "tests"))
from test_n_four_bar import _generator, exact_theta  # noqa: E402  (the exact motion the tests check against)

T_END = 20.0
STEP = 1e-3
SOLVERS = ("midpoint", "discrete_gradient")


def measure(loops: int) -> dict:
    """Run in the child process: compile and both runs, with CPU times and the peak memory."""
    import yaml

    sys.path.insert(0, str(ROOT))
    import phc

    with tempfile.TemporaryDirectory() as tmp:
        path = Path(tmp) / f"n_four_bar_{loops}.yaml"
        path.write_text(yaml.safe_dump(_generator().n_four_bar(loops, t_end=T_END), sort_keys=False))
        c0 = time.process_time()
        compiled = phc.compile_model(path)
        out = {"loops": loops, "unknowns": compiled.module.N, "compile": time.process_time() - c0,
               "certified": bool(compiled.certificate is None or compiled.certificate.certified)}
        for solver in SOLVERS:
            c0 = time.process_time()
            r = phc.simulate(compiled, solver=solver, step=STEP, t_end=T_END, n_out=int(T_END * 100) + 1)
            cpu = time.process_time() - c0
            theta = np.asarray(r["crank0.theta"])
            spread = max(float(np.abs(np.asarray(r[f"crank{k}.theta"]) - theta).max()) for k in range(1, loops + 1))
            passes = int(np.count_nonzero(np.diff(np.floor(theta / np.pi))))
            out[solver] = {"success": bool(r.success), "t": float(r.t[-1]), "cpu": cpu, "steps": int(r.steps),
                           "passes": passes, "spread": spread, "balance": float(r.energy_balance_relative),
                           "t_out": np.asarray(r.t).tolist(), "theta": theta.tolist(),
                           "message": "" if r.success else r.message.splitlines()[0][:160]}
    out["peak_mib"] = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024
    return out


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--loops", type=int, nargs="+", default=[1, 10, 40])
    parser.add_argument("--measure", type=int, help=argparse.SUPPRESS)
    args = parser.parse_args()
    if args.measure is not None:
        print(json.dumps(measure(args.measure)))
        return 0
    rows = []
    for loops in args.loops:
        run = subprocess.run([sys.executable, __file__, "--measure", str(loops)], capture_output=True, text=True,
                             cwd=ROOT)
        if run.returncode != 0:
            print(run.stderr, file=sys.stderr)
            return run.returncode
        rows.append(json.loads(run.stdout.strip().splitlines()[-1]))
    print(f"Midpoint rule and discrete gradient at h = {STEP:g} to t = {T_END:g} s (default back end); "
          "compile = `phc.compile_model` with the certificate, CPU seconds; peak memory of the whole process.\n")
    print("| N | unknowns | compile [s CPU] | certified | peak [MiB] | solver | reached [s] | passes "
          "| run [s CPU] | µs/step | crank 0 vs exact [rad] | cranks apart [rad] | energy balance (rel.) |")
    print("|---:|---:|---:|---|---:|---|---:|---:|---:|---:|---:|---:|---:|")
    for row in rows:
        for solver in SOLVERS:
            s = row[solver]
            t = np.asarray(s["t_out"])
            err = float(np.abs(np.asarray(s["theta"]) - exact_theta(row["loops"], t)).max())
            per_step = 1e6 * s["cpu"] / max(s["steps"], 1)
            print(f"| {row['loops']} | {row['unknowns']} | {row['compile']:.2f} | {'yes' if row['certified'] else 'no'} "
                  f"| {row['peak_mib']:.0f} | {solver} | {s['t']:.3f} | {s['passes']} | {s['cpu']:.2f} "
                  f"| {per_step:.0f} | {err:.1e} | {s['spread']:.1e} | {s['balance']:.1e} |")
    failed = [(row["loops"], solver, row[solver]["message"]) for row in rows for solver in SOLVERS
              if not row[solver]["success"]]
    for loops, solver, message in failed:
        print(f"\nN = {loops}, {solver}: {message}")
    if not failed:
        print(f"\nEvery run reached t = {T_END:g} s. The benchmark's tolerance is 1e-3 rad on crank 0 "
              f"(B0 within 1e-3 m); passes counts the horizontal configurations crossed.")
    return 0


if __name__ == "__main__":
    sys.exit(main())
