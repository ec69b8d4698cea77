"""What IDA costs around the model's own functions, driven through scikit-sundae's public interface.

    python benchmarks/record.py ida_callbacks -- python benchmarks/bench_ida_callbacks.py [--repeat N]

writes ``benchmarks/results/ida_callbacks.md``. Each shipped model below is integrated by
IDA over its own time span and tolerances (``phc.simulate(compiled, solver="ida")``); the
table gives the best CPU time of `--repeat` runs, IDA's counts, and — measured in the same
process — the CPU time of the generated residual and Jacobian alone, called as often as the
run called them (at the run's final state, into preallocated arrays). The rest, per step,
is what one IDA step costs beside the model: SUNDIALS' own work (BDF, the LU of the
iteration matrix, its error test), scikit-sundae's wrappers (NumPy arrays made of IDA's
vectors at each residual, Jacobian and root-function call, a result object per output
time) and phc's step hook (``phc.simulation.ida._StepHook``: the step count, the
singularity monitor's looks, the domain-edge check).

Since phc reaches IDA only through what scikit-sundae documents, this is the figure a C
back end calling SUNDIALS directly would reduce; ``benchmarks/results/ida_callbacks.md`` at
commit 80caebb (``git show 80caebb:benchmarks/results/ida_callbacks.md``) has the run times
of the earlier direct ``ctypes`` path for comparison.
"""

from __future__ import annotations

import argparse
import os
import sys
import time
import warnings
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

import phc  # noqa: E402
from phc.simulation import parameter_vector  # noqa: E402

MODELS = [("pendulum.yaml", "numpy"), ("double_pendulum.yaml", "numpy"), ("euler_bernoulli_beam.yaml", "numpy"),
          ("timoshenko_beam.yaml", "numba"), ("controlled_beam.yaml", "numba"),
          ("flexible_slider_crank.yaml", "numba")]


def _functions_cpu(compiled, result) -> float:
    """CPU seconds of the raw generated residual and Jacobian, called as often as `result`'s run did."""
    mod = compiled.module
    raw = getattr(mod, "module", mod)
    p = parameter_vector(mod)
    y, yp = np.array(result.y[-1]), np.array(result.yp[-1]) if getattr(result, "yp", None) is not None \
        else np.zeros(mod.N)
    res = np.empty(len(mod.EQUATIONS))
    jac = np.empty(len(mod.JAC_ROWS))
    t = float(result.t[-1])
    residual, jacobian = raw.residual, raw.jacobian
    start = time.process_time()
    for _ in range(int(result.n_residual_evals)):
        residual(t, y, yp, p, res)
    for _ in range(int(result.n_jacobian_evals)):
        jacobian(t, y, yp, p, 1.0, jac)
    return time.process_time() - start


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--repeat", type=int, default=3)
    ap.add_argument("--models", nargs="*", default=None, help="file names in models/ (default: the list in the script)")
    args = ap.parse_args(argv)
    os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")
    warnings.simplefilter("ignore")
    chosen = [(m, b) for m, b in MODELS if args.models is None or m in args.models]
    print("# IDA through scikit-sundae: the cost of a step beside the model's functions\n")
    print(f"Command: `python benchmarks/bench_ida_callbacks.py --repeat {args.repeat}`; CPU seconds of "
          "`phc.simulate(compiled, solver=\"ida\")` over each model's own time span and tolerances (best of "
          f"{args.repeat}); the generated functions alone, called as often as the run called them; the rest per "
          "step.\n")
    print("| model (backend) | unknowns | steps | residual evaluations | Jacobian evaluations | run [s] | "
          "functions [s] | rest per step [µs] |")
    print("|---|---:|---:|---:|---:|---:|---:|---:|")
    for name, backend in chosen:
        compiled = phc.compile_model(ROOT / "models" / name, backend=backend)
        best, result = None, None
        for _ in range(args.repeat):
            start = time.process_time()
            r = phc.simulate(compiled, solver="ida")
            cpu = time.process_time() - start
            if not r.success:
                print(f"{name}: the IDA run failed: {r.message}", file=sys.stderr)
                return 1
            if best is None or cpu < best:
                best, result = cpu, r
        functions = min(_functions_cpu(compiled, result) for _ in range(args.repeat))
        rest = (best - functions) / max(result.steps, 1) * 1e6
        print(f"| {name.removesuffix('.yaml')} ({backend}) | {compiled.module.N} | {result.steps} | "
              f"{result.n_residual_evals} | {result.n_jacobian_evals} | {best:.3f} | {functions:.3f} | {rest:.1f} |")
    return 0


if __name__ == "__main__":
    sys.exit(main())
