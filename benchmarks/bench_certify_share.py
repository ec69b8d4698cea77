"""Share of compile time spent on the certificate of the compiled equations.

Every ``phc compile``/``phc simulate`` certifies the compiled equations
(:mod:`phc.checks.compiled`: the power balance at the initial consistent state and one
perturbed consistent state, passivity of every dissipative term). For each shipped model
and scene this measures the compile time without the certificate (read → elaborate →
assemble → lower → print → load) and the certificate's time, including its import of
:mod:`phc.simulation` (a compilation alone does not import it). "Cold" is a fresh process,
what one ``phc compile`` pays: the median of `--cold` processes after one that fills the
caches an installed phc has (Python's bytecode of phc, kept under a temporary
PYTHONPYCACHEPREFIX, and the generated-module cache). "Warm" is the best of `--repeat`
repeats in one process (sympy's caches filled too). The generated functions run as the
NumPy module (``PHC_BACKEND=numpy``, `--backend`): compiling them with numba adds seconds
of JIT compilation to the compile time and makes the share look smaller than it is.

Part of the certificate is what ``phc simulate`` needs anyway: the import of
:mod:`phc.simulation` and the consistent state at t₀ (:func:`phc.simulation.start_state`),
which the compiled model keeps so that the run starts from it without solving again. The
table gives that part and the share of the rest (what the certificate adds to a compile
and simulate). It writes ``benchmarks/certify/share.md`` (read into benchmarks/README.md),
ending with a summary line.

Run: ``python benchmarks/bench_certify_share.py [--repeat 3] [--cold 3]``.
"""

from __future__ import annotations

import argparse
import json
import os
import shutil
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

import phc  # noqa: E402
from phc.pipeline import FAST_BALANCE_LIMIT, FAST_SAMPLES  # noqa: E402

spent = [0.0]
"""Seconds in phc.simulation.start_state since the last reset (see `certify`)."""


def certify(compiled) -> tuple[float, float]:
    """(certificate seconds, of which shared with `phc simulate`: the import of
    phc.simulation and the start state), as compile_model runs the certificate."""
    t = time.perf_counter()
    import phc.simulation  # what the certificate imports first (as simulate does)

    imported = time.perf_counter() - t
    if hasattr(phc.simulation, "start_state") and not hasattr(phc.simulation.start_state, "timed"):
        # The certificate imports start_state from phc.simulation when it runs: timed here.
        start_state = phc.simulation.start_state

        def timed(*args, **kwargs):
            t = time.perf_counter()
            try:
                return start_state(*args, **kwargs)
            finally:
                spent[0] += time.perf_counter() - t

        timed.timed = True
        phc.simulation.start_state = timed
    from phc.checks.compiled import certify_compiled

    spent[0] = 0.0
    t = time.perf_counter()
    cert = certify_compiled(compiled, n_random=FAST_SAMPLES, max_unknowns=FAST_BALANCE_LIMIT)
    total = time.perf_counter() - t
    assert cert.certified and not cert.skipped, cert.summary()
    return imported + total, imported + spent[0]


def measure(path: Path, repeat: int) -> tuple[float, float, int]:
    phc.compile_model(path, certify=False)  # warm the module cache
    compile_times, certify_times = [], []
    for _ in range(repeat):
        t = time.perf_counter()
        compiled = phc.compile_model(path, certify=False)
        compile_times.append(time.perf_counter() - t)
        certify_times.append(certify(compiled)[0])
    return min(compile_times), min(certify_times), compiled.n_states


COLD = """
import json, sys, time
sys.path.insert(0, {bench!r})
import bench_certify_share as b
t = time.perf_counter(); c = b.phc.compile_model({path!r}, certify=False); tc = time.perf_counter() - t
print(json.dumps([tc, *b.certify(c)]))
"""


def measure_cold(path: Path, runs: int, env: dict) -> tuple[float, float, float]:
    """Medians over `runs` fresh processes (after one that fills the caches): compile,
    certificate, its part shared with simulate."""
    rows = []
    for _ in range(runs + 1):
        run = subprocess.run([sys.executable, "-c", COLD.format(bench=str(ROOT / "benchmarks"), path=str(path))],
                             capture_output=True, text=True, check=True, env=env)
        rows.append(json.loads(run.stdout.strip().splitlines()[-1]))
    return tuple(statistics.median(r[k] for r in rows[1:]) for k in range(3))


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--repeat", type=int, default=3)
    parser.add_argument("--cold", type=int, default=3, help="fresh processes per model (median)")
    parser.add_argument("--backend", default="numpy", help="PHC_BACKEND for the runs (default numpy)")
    parser.add_argument("--out", default=str(ROOT / "benchmarks" / "certify" / "share.md"))
    args = parser.parse_args()
    os.environ["PHC_BACKEND"] = args.backend
    rows = ["| model | states | cold compile [s] | cold certificate [s] | cold share | shared with simulate [s] "
            "| cold share without it | warm compile [s] | warm certificate [s] | warm share |",
            "|---|---:|---:|---:|---:|---:|---:|---:|---:|---:|"]
    shares, rest = [], []
    pycache = tempfile.mkdtemp(prefix="phc-bench-pycache-")
    env = {k: v for k, v in os.environ.items() if k != "PYTHONDONTWRITEBYTECODE"}
    env["PYTHONPYCACHEPREFIX"] = pycache
    paths = sorted((ROOT / "models").glob("*.yaml")) + sorted((ROOT / "models" / "scenes").glob("*.yaml"))
    for path in paths:
        cc, ck, cs = measure_cold(path, args.cold, env)
        tc, tk, n = measure(path, args.repeat)
        name = path.relative_to(ROOT / "models").with_suffix("").as_posix()
        shares.append((100 * ck / cc, name))
        rest.append((100 * (ck - cs) / cc, name))
        rows.append(f"| {name} | {n} | {cc:.3f} | {ck:.3f} | {shares[-1][0]:.1f} % | {cs:.3f} | {rest[-1][0]:.1f} % "
                    f"| {tc:.3f} | {tk:.3f} | {100 * tk / tc:.0f} % |")
        print(rows[-1], flush=True)
    shutil.rmtree(pycache, ignore_errors=True)
    (lo, lo_name), (hi, hi_name) = min(shares), max(shares)
    summary = (f"Summary: cold, the certificate takes {lo:.1f}–{hi:.1f} % of the compile time ({lo_name} to "
               f"{hi_name}); without the part `phc simulate` needs anyway (the import of phc.simulation and "
               f"the consistent start state, which the run reuses), {min(rest)[0]:.1f}–{max(rest)[0]:.1f} %. "
               f"{sum(s < 10 for s, _ in shares)} of {len(shares)} models are under 10 % in total, "
               f"{sum(s < 10 for s, _ in rest)} of {len(rest)} without that part.")
    out = Path(args.out)
    out.parent.mkdir(parents=True, exist_ok=True)
    out.write_text(f"Command: `python benchmarks/bench_certify_share.py --repeat {args.repeat} --cold {args.cold} "
                   f"--backend {args.backend}`\n\n"
                   + "\n".join(rows) + "\n\n" + summary + "\n")
    print(summary)
    print(f"wrote {out}")


if __name__ == "__main__":
    main()
