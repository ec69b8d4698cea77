"""Same results with and without the certificate's shortcuts (benchmarks/README.md).

For every shipped model and scene: compile and simulate as phc does (the certificate's
start state reused by `simulate`, hopeless stages of consistent initialization skipped),
and again with both shortcuts off (`_Problem.hopeless` always False, the kept start state
dropped so that `simulate` solves it again). Prints whether the trajectories (t, y, ẏ, H)
are bit-for-bit equal and the certificate's balance error both ways.

Run: ``python benchmarks/certify/check_identical.py`` (a few minutes: the slider–cranks
simulate for seconds). The model's solver is used; where IDA (scikit-sundae) is not
installed, the implicit midpoint rule.
"""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[2]
sys.path.insert(0, str(ROOT))

import phc  # noqa: E402
import phc.simulation.initial as initial  # noqa: E402
from phc.checks.compiled import certify_compiled  # noqa: E402
from phc.errors import SimulationSetupError  # noqa: E402
from phc.pipeline import FAST_BALANCE_LIMIT, FAST_SAMPLES  # noqa: E402


def run(compiled, solver):
    try:
        return phc.simulate(compiled, solver=solver), solver
    except SimulationSetupError as err:
        if "scikit-sundae" not in str(err):
            raise
        return phc.simulate(compiled, solver="midpoint"), "midpoint"


def main() -> int:
    hopeless = initial._Problem.hopeless
    paths = sorted((ROOT / "models").glob("*.yaml")) + sorted((ROOT / "models" / "scenes").glob("*.yaml"))
    same_all = True
    for path in paths:
        name = path.relative_to(ROOT / "models").as_posix()
        initial._Problem.hopeless = lambda self, bound: False  # every stage runs, as before
        try:
            plain = phc.compile_model(path, certify=False)
            cert0 = certify_compiled(plain, n_random=FAST_SAMPLES, max_unknowns=FAST_BALANCE_LIMIT)
            plain.cache.start_state = None  # simulate solves the start again (phc.codegen.compiled.RunCache)
            r0, solver = run(plain, None)
        finally:
            initial._Problem.hopeless = hopeless
        compiled = phc.compile_model(path)
        r1, _ = run(compiled, solver)
        same = all(np.array_equal(getattr(r0, k), getattr(r1, k)) for k in ("t", "y", "yp", "H"))
        same_all &= same
        print(f"{name:36s} {solver or 'default':9s} identical: {same}; balance error "
              f"{cert0.balance_error:.3e} / {compiled.certificate.balance_error:.3e}", flush=True)
    print("all identical" if same_all else "DIFFERENCES")
    return 0 if same_all else 1


if __name__ == "__main__":
    sys.exit(main())
