"""What IDA's callbacks cost (issue 16 item 3): scikit-SUNDAE's wrapper, phc's Python callback, compiled callbacks.

    python benchmarks/record.py ida_callbacks -- python benchmarks/bench_ida_callbacks.py [--repeat N]

writes ``benchmarks/results/ida_callbacks.md``. Each shipped model below is integrated by
IDA over its own time span and tolerances (``phc.simulate(compiled, solver="ida")``), in
one process, the configurations alternating run by run (a shared machine's load hits
them alike); the table gives the best and the median CPU time of `--repeat` runs and the
ratio of the best to the wrapper's:

* **scikit-SUNDAE's wrapper**: IDA calls scikit-SUNDAE's Cython residual wrapper, which
  makes three NumPy arrays of IDA's vectors each call (phc's callback not installed);
* **phc's Python callback**: IDA calls phc's ``ctypes`` callback, which reads the vectors
  through NumPy views made once (``PHC_IDA_NATIVE=0``: it stays for the whole run);
* **compiled callbacks** (numba backend only): the run changes from the Python callback
  to numba C callbacks after ``phc.simulation.ida.SWITCH_EVALUATIONS`` residual evaluations
  (``phc/simulation/ida_native.py``); the first run of a process builds them (its time
  includes that; the best of the runs does not).

Every run of a model must give the same states as the wrapper's, bit for bit; the script
fails otherwise.
"""

from __future__ import annotations

import argparse
import os
import statistics
import sys
import time
import warnings
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

import phc  # noqa: E402
from phc.simulation import ida  # noqa: E402

MODELS = [("pendulum.yaml", "numpy"), ("double_pendulum.yaml", "numpy"), ("euler_bernoulli_beam.yaml", "numpy"),
          ("timoshenko_beam.yaml", "numba"), ("controlled_beam.yaml", "numba"),
          ("flexible_slider_crank.yaml", "numba")]


def _run(compiled, config: str):
    """(CPU seconds, result, whether the compiled callbacks were installed)."""
    install, install_native = ida._IdaCounters.install_residual, ida._IdaCounters.install_native
    os.environ["PHC_IDA_NATIVE"] = "1" if config == "compiled callbacks" else "0"
    if config == "scikit-SUNDAE's wrapper":
        ida._IdaCounters.install_residual = lambda self, resfn, n: False
    native = []
    ida._IdaCounters.install_native = lambda self, *a: native.append(install_native(self, *a)) or native[-1]
    try:
        t = time.process_time()
        r = phc.simulate(compiled, solver="ida")
        return time.process_time() - t, r, any(native)
    finally:
        ida._IdaCounters.install_residual, ida._IdaCounters.install_native = install, install_native
        os.environ.pop("PHC_IDA_NATIVE", None)


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--repeat", type=int, default=3)
    ap.add_argument("--models", nargs="*", default=None, help="file names in models/ (default: the list in the script)")
    args = ap.parse_args(argv)
    os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")
    warnings.simplefilter("ignore")
    chosen = [(m, b) for m, b in MODELS if args.models is None or m in args.models]
    print("# IDA's callbacks: scikit-SUNDAE's wrapper, phc's Python callback, compiled callbacks\n")
    print(f"Command: `python benchmarks/bench_ida_callbacks.py --repeat {args.repeat}`; CPU seconds of "
          "`phc.simulate(compiled, solver=\"ida\")` over each model's own time span and tolerances; best and median "
          f"of {args.repeat} runs, alternating.\n")
    print("| model (backend) | configuration | steps | residual evaluations | best [s] | median [s] | "
          "wrapper's best ÷ this best |")
    print("|---|---|---:|---:|---:|---:|---:|")
    for name, backend in chosen:
        compiled = phc.compile_model(ROOT / "models" / name, backend=backend)
        configs = ["scikit-SUNDAE's wrapper", "phc's Python callback"]
        if getattr(compiled.module, "BACKEND", "numpy") == "numba":
            configs.append("compiled callbacks")
        times = {c: [] for c in configs}
        runs = {}
        switched = False
        for _ in range(args.repeat):
            for config in configs:
                cpu, r, native = _run(compiled, config)
                times[config].append(cpu)
                runs[config] = r
                switched = switched or native
        reference = runs[configs[0]]
        for config in configs:
            r = runs[config]
            if not (r.steps == reference.steps and np.array_equal(r.y, reference.y)):
                print(f"{name}: {config} differs from scikit-SUNDAE's wrapper", file=sys.stderr)
                return 1
            best = min(times[config])
            label = config
            if config == "compiled callbacks" and not switched:
                label += f" (not reached: fewer than {ida.SWITCH_EVALUATIONS} evaluations)"
            elif config == "compiled callbacks":
                label += f" (from evaluation {ida.SWITCH_EVALUATIONS} on)"
            print(f"| {name.removesuffix('.yaml')} ({backend}) | {label} | {r.steps} | {r.n_residual_evals} | "
                  f"{best:.3f} | {statistics.median(times[config]):.3f} | {min(times[configs[0]]) / best:.2f}× |")
    print("\nEvery configuration gave the wrapper's states bit for bit (checked by the script).")
    return 0


if __name__ == "__main__":
    sys.exit(main())
