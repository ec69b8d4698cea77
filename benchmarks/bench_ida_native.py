"""What phc's native IDA driver costs per step beside SUNDIALS' own work, against scikit-sundae.

    python benchmarks/bench_ida_native.py [--repeat N] [--models pendulum.yaml ...]

Each model runs on the C back end at its own time span and tolerances
(``phc.simulate(compiled, solver="ida")``); the table gives the best CPU time of the
integration phase (``result.timings["integrate"]``: IDA's set-up, its steps, phc's work between
them) of `--repeat` runs in five configurations:

* **C loop only**: the native driver in one call (one chunk of all the steps), the singularity
  monitor off, the maximum order fixed at 5 — SUNDIALS' own work and the model's C functions, and
  phc's set-up of the run; the reference the others are measured against;
* **native in chunks, monitor off, max_order 5**: the driver returning to Python every
  ``ida_native.CHUNK`` steps, nothing done there: the cost of the chunks themselves;
* **native, monitor off** / **native**: the native driver as a run uses it (the monitor's
  routine looks in C, chunks ending at a look Python's monitor makes and where phc's choice of
  the order looks, which may start IDA again at order 2), without and with the monitor's looks;
* **native, every look in Python**: the same with ``ida_native.C_LOOKS = False``: each of the
  monitor's looks ends a chunk and is made in Python (the driver before its routine look in C);
* **scikit-sundae, monitor off** / **scikit-sundae**: ``PHC_NATIVE_IDA=0``, IDA through
  scikit-sundae's Python callbacks (:mod:`phc.simulation.ida`).

"above C [µs/step]" is (configuration − C loop only) / steps: what a step costs beyond SUNDIALS'
work and the model's functions (which every configuration calls equally often: the step counts
are checked equal). Needs SUNDIALS' headers (``apt install libsundials-dev``) and a C compiler.
"""

from __future__ import annotations

import argparse
import os
import sys
import warnings
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

import phc  # noqa: E402
from phc.codegen import c_ida  # noqa: E402
from phc.simulation import ida_native, monitor as monitor_module  # noqa: E402

MODELS = ["pendulum.yaml", "double_pendulum.yaml"]


def _run(compiled, *, native: bool, monitor: bool, one_chunk: bool = False, c_looks: bool = True, **options):
    os.environ["PHC_NATIVE_IDA"] = "1" if native else "0"
    size, chunk, looks = monitor_module.MAX_SIZE, ida_native.CHUNK, ida_native.C_LOOKS
    ida_native.C_LOOKS = c_looks
    try:
        if not monitor:
            monitor_module.MAX_SIZE = -1  # SingularityMonitor.enabled is N <= MAX_SIZE
        if one_chunk:
            ida_native.CHUNK = 10 ** 9
        r = phc.simulate(compiled, solver="ida", **options)
    finally:
        monitor_module.MAX_SIZE, ida_native.CHUNK, ida_native.C_LOOKS = size, chunk, looks
    if not r.success:
        raise SystemExit(f"the run failed: {r.message}")
    return r


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--repeat", type=int, default=3)
    ap.add_argument("--models", nargs="*", default=MODELS,
                    help="file names in models/, or paths relative to the repository")
    ap.add_argument("--rtol", type=float, default=None, help="instead of each model's own (atol = rtol/100)")
    args = ap.parse_args(argv)
    warnings.simplefilter("ignore")
    if c_ida.library() is None:
        print(f"the native IDA driver cannot be built here: {c_ida.why_not()}", file=sys.stderr)
        return 1
    major, minor = c_ida.library().sundials_version
    print(f"# IDA's cost per step beside SUNDIALS' own work: native driver (SUNDIALS {major}.{minor}) vs "
          "scikit-sundae\n")
    print(f"Command: `python benchmarks/bench_ida_native.py {' '.join(argv if argv is not None else sys.argv[1:])}`; CPU seconds of the integration "
          f"phase, best of {args.repeat}, C back end.\n")
    print("| model | configuration | steps | residual evaluations | integrate [s] | per step [µs] | "
          "above C [µs/step] |")
    print("|---|---|---:|---:|---:|---:|---:|")
    configs = [("C loop only", dict(native=True, monitor=False, one_chunk=True, max_order=5)),
               ("native in chunks, monitor off, max_order 5", dict(native=True, monitor=False, max_order=5)),
               ("native, monitor off", dict(native=True, monitor=False)),
               ("native", dict(native=True, monitor=True)),
               ("native, every look in Python", dict(native=True, monitor=True, c_looks=False)),
               ("scikit-sundae, monitor off", dict(native=False, monitor=False)),
               ("scikit-sundae", dict(native=False, monitor=True))]
    for name in args.models:
        compiled = phc.compile_model(ROOT / name if "/" in name else ROOT / "models" / name, backend="c")
        tolerances = {} if args.rtol is None else dict(rtol=args.rtol, atol=args.rtol * 1e-2)
        base = None
        for label, kw in configs:
            best, steps, nfev = None, None, None
            for _ in range(args.repeat):
                r = _run(compiled, **kw, **tolerances)
                cpu = r.timings["integrate"]
                if best is None or cpu < best:
                    best, steps, nfev = cpu, r.steps, r.n_residual_evals
            if base is None:
                base, base_steps = best, steps
            elif steps != base_steps:
                print(f"({label}: {steps} steps, the C loop only {base_steps}: not comparable per step)",
                      file=sys.stderr)
            above = (best - base) / steps * 1e6
            print(f"| {Path(name).stem} | {label} | {steps} | {nfev} | {best:.3f} | "
                  f"{best / steps * 1e6:.1f} | {above:.1f} |")
    return 0


if __name__ == "__main__":
    sys.exit(main())
