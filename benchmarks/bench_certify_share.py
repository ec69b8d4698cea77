"""Share of compile time spent on the certificate of the compiled equations.

Every ``phc compile``/``phc simulate`` certifies the compiled equations
(:mod:`phc.checks.compiled`: the power balance at the initial consistent state and one
perturbed consistent state, passivity of every dissipative term). For each shipped model
this measures the compile time without the certificate (read → elaborate → assemble →
lower → print → load) and the certificate's time: "cold" is a fresh process (what one
``phc compile`` pays), "warm" the best of `--repeat` repeats in one process (sympy's caches
and the module cache filled). It writes a Markdown table to ``benchmarks/certify/share.md``
(read into benchmarks/README.md).

Run: ``python benchmarks/bench_certify_share.py [--repeat 3]``.
"""

from __future__ import annotations

import argparse
import json
import subprocess
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

import phc  # noqa: E402
from phc.checks.compiled import certify_compiled  # noqa: E402
from phc.pipeline import FAST_SAMPLES  # noqa: E402


def measure(path: Path, repeat: int) -> tuple[float, float, int]:
    phc.compile_model(path, certify=False)  # warm the module cache
    compile_times, certify_times = [], []
    for _ in range(repeat):
        t = time.perf_counter()
        compiled = phc.compile_model(path, certify=False)
        compile_times.append(time.perf_counter() - t)
        t = time.perf_counter()
        cert = certify_compiled(compiled, n_random=FAST_SAMPLES)
        certify_times.append(time.perf_counter() - t)
        assert cert.certified, cert.summary()
    return min(compile_times), min(certify_times), compiled.n_states


COLD = """
import json, sys, time
sys.path.insert(0, {root!r})
import phc
from phc.checks.compiled import certify_compiled
from phc.pipeline import FAST_SAMPLES
t = time.perf_counter(); c = phc.compile_model({path!r}, certify=False); tc = time.perf_counter() - t
t = time.perf_counter(); certify_compiled(c, n_random=FAST_SAMPLES); tk = time.perf_counter() - t
print(json.dumps([tc, tk]))
"""


def measure_cold(path: Path) -> tuple[float, float]:
    run = subprocess.run([sys.executable, "-c", COLD.format(root=str(ROOT), path=str(path))],
                         capture_output=True, text=True, check=True)
    tc, tk = json.loads(run.stdout.strip().splitlines()[-1])
    return tc, tk


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--repeat", type=int, default=3)
    parser.add_argument("--out", default=str(ROOT / "benchmarks" / "certify" / "share.md"))
    args = parser.parse_args()
    rows = ["| model | states | cold compile [s] | cold certificate [s] | cold share | warm compile [s] "
            "| warm certificate [s] | warm share |",
            "|---|---:|---:|---:|---:|---:|---:|---:|"]
    for path in sorted((ROOT / "models").glob("*.yaml")):
        cc, ck = measure_cold(path)
        tc, tk, n = measure(path, args.repeat)
        rows.append(f"| {path.stem} | {n} | {cc:.3f} | {ck:.3f} | {100 * ck / cc:.0f} % | {tc:.3f} | {tk:.3f} "
                    f"| {100 * tk / tc:.0f} % |")
        print(rows[-1], flush=True)
    out = Path(args.out)
    out.parent.mkdir(parents=True, exist_ok=True)
    out.write_text(f"Command: `python benchmarks/bench_certify_share.py --repeat {args.repeat}`\n\n"
                   + "\n".join(rows) + "\n")
    print(f"wrote {out}")


if __name__ == "__main__":
    main()
