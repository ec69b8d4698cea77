"""Tests of `phc.library.linear` (matrix-defined linear pH components)."""

import numpy as np
import scipy.sparse as sps
from scipy.integrate import solve_ivp

import phc


def _put(arrays, name, matrix):
    m = sps.csr_matrix(matrix)
    arrays[f"{name}.data"], arrays[f"{name}.indices"] = m.data, m.indices
    arrays[f"{name}.indptr"], arrays[f"{name}.shape"] = m.indptr, np.array(m.shape)


def chain_model(tmp_path, n, *, damping=0.0, t_end=3.0):
    """A fixed–free chain of n masses and n springs as E ẋ = (J − R) Q x."""
    D = sps.diags([np.ones(n), -np.ones(n - 1)], [0, -1], shape=(n, n))
    Z = sps.csr_matrix((n, n))
    J = sps.bmat([[Z, D], [-D.T, Z]])
    R = sps.bmat([[Z, Z], [Z, damping * sps.identity(n)]])
    arrays = {}
    _put(arrays, "J", J)
    _put(arrays, "R", R)
    Q = np.r_[np.ones(n), np.ones(n)]
    arrays["Q"] = np.diag(Q)
    np.savez(tmp_path / "chain.npz", **arrays)
    (tmp_path / "chain.yaml").write_text(f"""
format_version: 1
parameters:
  k: 4.0
components:
  chain:
    type: linear_phs
    states: {2 * n}
    matrices: chain.npz
    J: J
    R: R
    Q: Q
    scale: {{Q: k}}
    ports:
      tip: {{B: [{", ".join(["[0]"] * (2 * n - 1) + ["[1]"])}], domain: mechanical.translational}}
  free: {{type: zero_effort, domain: mechanical.translational}}
connections:
  - [chain.tip, free.port]
simulation:
  t_end: {t_end}
  rtol: 1.0e-10
  atol: 1.0e-12
  initial: {{"chain.x[0]": 0.1}}
""")
    return tmp_path / "chain.yaml", (J - R) @ sps.diags(4.0 * Q)


def test_linear_chain_matches_direct_ode_and_conserves_energy(tmp_path):
    path, A = chain_model(tmp_path, 20)
    compiled = phc.compile_model(path)
    result = phc.simulate(compiled)
    assert result.success
    x0 = np.zeros(40)
    x0[0] = 0.1
    ref = solve_ivp(lambda t, x: A @ x, (0, 3.0), x0, t_eval=result.t, rtol=1e-12, atol=1e-14, method="DOP853")
    states = np.column_stack([result[f"chain.x[{i}]"] for i in range(40)])
    assert np.abs(states - ref.y.T).max() < 1e-7
    assert result.energy_balance_relative < 1e-8


def test_linear_chain_damped_energy_balance(tmp_path):
    path, _ = chain_model(tmp_path, 10, damping=0.3)
    result = phc.simulate(phc.compile_model(path))
    assert result.success
    assert result.H[-1] < 0.9 * result.H[0]          # it does dissipate
    assert result.energy_balance_relative < 1e-7      # and the balance closes


def test_linear_blocks_stay_sparse_in_generated_code(tmp_path):
    path, _ = chain_model(tmp_path, 200)
    compiled = phc.compile_model(path)
    assert "_matvec_add(_AY, y, out)" in compiled.source
    # a matrix-vector product, not one line per state
    assert compiled.source.count("\n    out[") < 50
    assert compiled.jacobian_nnz < 4 * 400


def test_the_blas_fast_path_agrees_with_plain_numpy(tmp_path):
    """The generated module uses BLAS axpy when the output buffer is contiguous; its
    fallback (non-contiguous output buffers) must give the same numbers."""
    path, _ = chain_model(tmp_path, 30, damping=0.2)
    mod = phc.compile_model(path).module
    p = mod.full_parameters()
    rng = np.random.default_rng(3)
    y, yp = rng.standard_normal(mod.N), rng.standard_normal(mod.N)
    fast_res, fast_jac = np.zeros(mod.N), np.zeros(len(mod.JAC_ROWS))
    mod.residual(0.1, y, yp, p, fast_res)
    mod.jacobian(0.1, y, yp, p, 3.7, fast_jac)
    strided_res = np.zeros(2 * mod.N)[::2]
    strided_jac = np.zeros(2 * len(mod.JAC_ROWS))[::2]
    mod.residual(0.1, y, yp, p, strided_res)
    mod.jacobian(0.1, y, yp, p, 3.7, strided_jac)
    assert np.allclose(strided_res, fast_res, rtol=1e-13, atol=1e-13)
    assert np.allclose(strided_jac, fast_jac, rtol=1e-13, atol=1e-13)


def test_inline_matrices_need_numbers(tmp_path):
    (tmp_path / "m.yaml").write_text("""
format_version: 1
components:
  lc:
    type: linear_phs
    states: [q, phi]
    J: [[0, 1], [-1, 0]]
    Q: [["1/C", 0], [0, 2]]
    ports:
      p: {B: [[0], [1]]}
  free: {type: zero_effort}
connections:
  - [lc.p, free.port]
""")
    dae, diags = phc.build_dae(tmp_path / "m.yaml")
    assert dae is None
    assert [d.code for d in diags] == ["PHC-E132"]
    assert diags[0].span.line == 8


