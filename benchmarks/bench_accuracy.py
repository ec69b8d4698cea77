"""What `rtol` gives on the shipped models: IDA at ``rtol = atol = TOL`` against IDA at a tight
tolerance, the largest relative error of each model's outputs over its whole run.

    python benchmarks/record.py accuracy -- python benchmarks/bench_accuracy.py [--tol 1e-6] [--ref 2e-9]

The relative error of an output is ``max_t |y − y_ref| / max_t |y_ref|``; outputs that are zero
up to round-off in the reference (|y_ref| < 1e-10 throughout: a constraint residual, a
midspan deflection that stays at 1e-17) are left out, since a relative error of them means
nothing. Each model is simulated with its own output grid and end time. The reference is
IDA at ``--ref`` (the same algebraic-output recomputation, docs/tolerances.md); where it
does not reach the end in ``--max-steps`` steps the comparison covers what it reached, and
the table says so. ``models/crank_testset.yaml`` is left out by default (its reference takes
minutes; ``--all`` includes it).

The column "IDA as is" repeats each run the way phc ran IDA before issue 14: IDA's local
tolerances equal to `rtol` and `atol`, every algebraic variable out of its tests, and the
algebraic outputs as IDA's interpolation gives them.
"""

from __future__ import annotations

import argparse
import sys
import time
import warnings
from contextlib import redirect_stdout
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

import phc  # noqa: E402
from phc.study.accuracy import relative_output_errors  # noqa: E402



NOT_MEASURED: dict[str, str] = {}
"""Shipped models this benchmark (IDA against IDA) leaves out, each with the reason printed in its row."""


def _worst(run, ref) -> tuple[str, float]:
    errors = relative_output_errors(run, ref)
    return max(errors.items(), key=lambda kv: kv[1], default=("—", 0.0))


def _as_is(compiled, **kw):
    """The run as phc made it before (module docstring)."""
    import phc.simulation as simulation
    import phc.simulation.ida as ida
    import phc.simulation.polish as polish

    saved = (ida.LOCAL_TOLERANCE, ida.determined_algebraic, polish.polish_outputs)
    ida.LOCAL_TOLERANCE = 1.0
    ida.determined_algebraic = lambda mod, *a: np.zeros(mod.N, dtype=bool)
    polish.polish_outputs = lambda mod, p, out, scales, **k: out
    try:
        return simulation.simulate(compiled, **kw)
    finally:
        ida.LOCAL_TOLERANCE, ida.determined_algebraic, polish.polish_outputs = saved


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--tol", type=float, default=1e-6, help="rtol = atol of the runs (default 1e-6)")
    # 2e-9: IDA's local tolerances 1e-11, where the references ran when IDA took a tenth
    ap.add_argument("--ref", type=float, default=2e-9, help="rtol = atol of the references (default 2e-9)")
    ap.add_argument("--max-steps", type=int, default=2_000_000)
    ap.add_argument("--all", action="store_true", help="include models/crank_testset.yaml")
    args = ap.parse_args(argv)
    warnings.simplefilter("ignore")
    print(f"IDA at rtol = atol = {args.tol:g} against IDA at {args.ref:g}; largest relative output error "
          "over the run (max over t of |y − y_ref| / max over t of |y_ref|).\n")
    print("| model | worst output | relative error | steps | time [s] | IDA as is: worst output | relative error | steps "
          "| time [s] | reference reached |")
    print("|---|---|---:|---:|---:|---|---:|---:|---:|---|")
    for path in sorted((ROOT / "models").glob("*.yaml")):
        if path.stem == "crank_testset" and not args.all:
            continue
        if path.stem in NOT_MEASURED:
            print(f"| {path.stem} | {NOT_MEASURED[path.stem]} | | | | | | | | |", flush=True)
            continue
        compiled = phc.compile_model(path, certify=False)
        # scikit-sundae prints SUNDIALS' failure lines ("[IDAHandleFailure, Error: -4] ...") with
        # print(): to stderr, so that the table on stdout (the results file) holds only the table
        with redirect_stdout(sys.stderr):
            t0 = time.perf_counter()
            run = phc.simulate(compiled, solver="ida", rtol=args.tol, atol=args.tol, max_steps=args.max_steps)
            elapsed = time.perf_counter() - t0
            t0 = time.perf_counter()
            old = _as_is(compiled, solver="ida", rtol=args.tol, atol=args.tol, max_steps=args.max_steps)
            elapsed_old = time.perf_counter() - t0
            ref = phc.simulate(compiled, solver="ida", rtol=args.ref, atol=args.ref, max_steps=args.max_steps)
        name, err = _worst(run, ref)
        name_old, err_old = _worst(old, ref)
        reached = "end" if ref.success else f"t = {ref.t[-1]:.4g} of {run.t[-1]:.4g}"
        status = "" if run.success else " (run failed: " + run.message[:60] + ")"
        print(f"| {path.stem} | {name}{status} | {err:.1e} | {run.steps} | {elapsed:.2f} | {name_old} | {err_old:.1e} "
              f"| {old.steps} | {elapsed_old:.2f} | {reached} |", flush=True)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
