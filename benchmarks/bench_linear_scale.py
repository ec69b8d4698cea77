"""Scale of compilation and residual evaluation for large sparse linear components.

A fixed–free chain of n masses and springs (2n states) written as a `linear_phs`
component with its matrices in an .npz file. For each n we measure

* compile time (read, elaborate, assemble, check, lower, print, load),
* the cost of one residual plus one Jacobian evaluation, as a ratio to one sparse
  matrix–vector product with the same matrix (J − R)Q measured in the same run.

Run: ``python benchmarks/bench_linear_scale.py`` (prints a Markdown table).
"""

from __future__ import annotations

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


def write_chain(directory: Path, n: int) -> tuple[Path, sps.csr_matrix]:
    D = sps.diags([np.ones(n), -np.ones(n - 1)], [0, -1], shape=(n, n))
    Z = sps.csr_matrix((n, n))
    J = sps.bmat([[Z, D], [-D.T, Z]]).tocsr()
    arrays = {"J.data": J.data, "J.indices": J.indices, "J.indptr": J.indptr, "J.shape": np.array(J.shape)}
    np.savez(directory / f"chain{n}.npz", **arrays)
    B = ", ".join(["[0]"] * (2 * n - 1) + ["[1]"])
    path = directory / f"chain{n}.yaml"
    path.write_text(f"""format_version: 1
parameters: {{k: 4.0}}
components:
  chain:
    type: linear_phs
    states: {2 * n}
    matrices: chain{n}.npz
    J: J
    scale: {{Q: k}}
    ports:
      tip: {{B: [{B}], domain: mechanical.translational}}
  free: {{type: zero_effort, domain: mechanical.translational}}
connections:
  - [chain.tip, free.port]
""")
    return path, (4.0 * J).tocsr()


def main(sizes=(125, 250, 500, 1000, 2000)) -> None:
    rows = []
    with tempfile.TemporaryDirectory() as tmp:
        for n in sizes:
            path, A = write_chain(Path(tmp), n)
            t = time.perf_counter()
            compiled = phc.compile_model(path)
            compile_s = time.perf_counter() - t
            mod = compiled.module
            p = mod.full_parameters()
            N = mod.N
            y, yp, out = np.random.rand(N), np.random.rand(N), np.zeros(N)
            jac = np.zeros(len(mod.JAC_ROWS))
            x = np.random.rand(A.shape[0])
            matvec = best_of(lambda: A @ x)
            res_jac = best_of(lambda: (mod.residual(0.0, y, yp, p, out), mod.jacobian(0.0, y, yp, p, 1.0, jac)))
            rows.append((2 * n, compile_s, res_jac[0] * 1e6, matvec[0] * 1e6, res_jac[0] / matvec[0],
                         res_jac[1] / matvec[1]))
    print("| states | compile [s] | residual+Jacobian [µs] | sparse matvec [µs] | ratio (min) | ratio (median) |")
    print("|---:|---:|---:|---:|---:|---:|")
    for r in rows:
        print(f"| {r[0]} | {r[1]:.2f} | {r[2]:.1f} | {r[3]:.1f} | {r[4]:.1f} | {r[5]:.1f} |")


if __name__ == "__main__":
    main()
