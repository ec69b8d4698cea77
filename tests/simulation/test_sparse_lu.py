"""phc.simulation.sparse_lu: the one sparse LU of the solvers — a panel of one column from
NARROW_PANEL_FROM unknowns on (SuperLU's dense work arrays are n × panel), scipy's default below."""

from __future__ import annotations

import numpy as np
import scipy.sparse as sps
import scipy.sparse.linalg as spla

from phc.simulation.sparse_lu import NARROW_PANEL_FROM, sparse_lu


def _tridiagonal(n: int):
    """tridiag(-1, 4, -1): diagonally dominant, ‖A‖∞ ‖A⁻¹‖∞ <= 6 / 2 = 3."""
    return sps.diags([np.full(n - 1, -1.0), np.full(n, 4.0), np.full(n - 1, -1.0)], [-1, 0, 1], format="csc")


def test_a_large_matrix_is_factored_with_a_one_column_panel_and_solves_to_round_off(monkeypatch):
    asked = []
    splu = spla.splu
    monkeypatch.setattr(spla, "splu", lambda J, *a, **k: asked.append((J.shape[0], k)) or splu(J, *a, **k))
    n = NARROW_PANEL_FROM + 7
    A = _tridiagonal(n)
    x = np.random.default_rng(0).standard_normal(n)
    got = sparse_lu(A).solve(A @ x)
    # condition number <= 3: the LU's backward error of a few ulps gives a forward error of a few
    # ulps of max|x| (about 4), bounded generously by 100 ulps
    assert np.max(np.abs(got - x)) <= 100 * np.finfo(float).eps * np.max(np.abs(x))
    small = _tridiagonal(50)
    assert np.allclose(sparse_lu(small).solve(small @ x[:50]), x[:50], rtol=0, atol=1e-13)
    assert asked == [(n, {"panel_size": 1}), (50, {})]
