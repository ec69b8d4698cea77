"""Scale of compilation and residual evaluation for discretized beams (phc.library.beams).

An Euler–Bernoulli cantilever (the seed's slider–crank rod: EI = 68.27 N m²,
ρA = 0.50368 kg/m, L = 0.3 m) clamped at ξ = 0 and loaded by a tip force, with n
Hermite elements (4n + 4 unknowns besides the port efforts). For each n we measure

* compile time of ``phc.compile_model`` (read, elaborate, assemble, check, lower, print,
  load), wall clock, best of 3;
* one residual plus one Jacobian evaluation of the generated module, as a ratio to one
  scipy sparse matrix–vector product with the model's matrices [dF/dy, dF/dẏ] acting on
  [y; ẏ] (the least work any residual evaluation does), and to one product with dF/dy
  alone; both assembled from the module's own Jacobian data and measured in the same run.

Targets: 1000 elements compile in < 2 s; residual + Jacobian ≤ 2 matvecs.

Run: ``python benchmarks/bench_beam_scale.py`` (prints a Markdown table).
"""

from __future__ import annotations

import os
import sys
import tempfile
import time
from pathlib import Path

import numpy as np
import scipy.sparse as sps

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
import phc  # noqa: E402

sys.path.insert(0, str(Path(__file__).resolve().parent))
from _timing import best_of  # noqa: E402

MODEL = """format_version: 1
name: cantilever{n}
parameters:
  EI: {{value: 68.27, unit: N*m^2}}
  rhoA: {{value: 0.50368, unit: kg/m}}
  F: {{value: 1.0, unit: N}}
components:
  beam: {{type: euler_bernoulli_beam, length: 0.3, elements: {n}, rhoA: rhoA, EI: EI}}
  clamp: {{type: zero_flow, domain: mechanical.translational}}
  clamp_rot: {{type: zero_flow, domain: mechanical.rotational}}
  load: {{type: effort_source, domain: mechanical.translational, value: "F*sin(100*t)"}}
  free_rot: {{type: zero_effort, domain: mechanical.rotational}}
connections:
  - [beam.a, clamp.port]
  - [beam.a_rot, clamp_rot.port]
  - [beam.b, load.port]
  - [beam.b_rot, free_rot.port]
"""


def measure(directory: Path, n: int):
    path = directory / f"cantilever{n}.yaml"
    path.write_text(MODEL.format(n=n))
    compile_times = []
    for _ in range(3):
        t = time.perf_counter()
        compiled = phc.compile_model(path)
        compile_times.append(time.perf_counter() - t)
    mod = compiled.module
    p = mod.full_parameters()
    N = mod.N
    rng = np.random.default_rng(0)
    y, yp, out = rng.standard_normal(N), rng.standard_normal(N), np.zeros(N)
    jac = np.zeros(len(mod.JAC_ROWS))
    mod.jacobian(0.3, y, yp, p, 0.0, jac)
    dFdy_data = jac.copy()
    dFdy = sps.csr_matrix((dFdy_data, (mod.JAC_ROWS, mod.JAC_COLS)), shape=(N, N))
    dFdy.eliminate_zeros()  # the pattern also holds the dF/dyp entries, zero at cj = 0
    mod.jacobian(0.3, y, yp, p, 1.0, jac)
    dFdyp = sps.csr_matrix((jac - dFdy_data, (mod.JAC_ROWS, mod.JAC_COLS)), shape=(N, N))
    dFdyp.eliminate_zeros()
    stacked = sps.hstack([dFdy, dFdyp]).tocsr()  # [dF/dy, dF/dyp]: all matrices of the model
    x, xx = rng.standard_normal(N), rng.standard_normal(2 * N)
    matvec = best_of(lambda: dFdy @ x)
    matvec2 = best_of(lambda: stacked @ xx)
    res_jac = best_of(lambda: (mod.residual(0.3, y, yp, p, out), mod.jacobian(0.3, y, yp, p, 1.0, jac)))
    return (n, N, dFdy.nnz, stacked.nnz, min(compile_times), res_jac[0] * 1e6, matvec[0] * 1e6,
            matvec2[0] * 1e6, res_jac[0] / matvec[0], res_jac[0] / matvec2[0], res_jac[1] / matvec2[1])


def main(sizes=(125, 250, 500, 1000)) -> None:
    with tempfile.TemporaryDirectory() as tmp:
        os.environ["PHC_CACHE_DIR"] = str(Path(tmp) / "cache")  # keep ~/.cache/phc clean
        rows = [measure(Path(tmp), n) for n in sizes]
    print("| elements | unknowns | dF/dy nnz | [dF/dy, dF/dẏ] nnz | compile [s] | residual+Jacobian [µs] "
          "| dF/dy matvec [µs] | stacked matvec [µs] | ratio vs dF/dy | ratio vs stacked (min) "
          "| ratio vs stacked (median) |")
    print("|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|")
    for r in rows:
        print(f"| {r[0]} | {r[1]} | {r[2]} | {r[3]} | {r[4]:.2f} | {r[5]:.1f} | {r[6]:.1f} | {r[7]:.1f} "
              f"| {r[8]:.2f} | {r[9]:.2f} | {r[10]:.2f} |")
    n, compile_s, ratio, ratio_y = rows[-1][0], rows[-1][4], rows[-1][9], rows[-1][8]
    print()
    print(f"{n} elements: compile {compile_s:.2f} s (target < 2 s: {'met' if compile_s < 2 else 'NOT met'}); "
          f"residual+Jacobian = {ratio:.2f} products with the model's matrices [dF/dy, dF/dyp] "
          f"(target <= 2: {'met' if ratio <= 2 else 'NOT met'}); {ratio_y:.2f} products with dF/dy alone")


if __name__ == "__main__":
    main()
