"""The Newton matrix of the fixed-step methods (:class:`phc.simulation.midpoint.NewtonMatrix`)
is equilibrated before its LU, so that its solves do not depend on the rows' units.

The case that once failed: a state q with q' = u and an energy accumulator E with
E' = −u·∂H/∂q for H = exp(q). The matrix is lower triangular, ``[[1/h, 0], [b, 1/h]]`` with
``b ≈ exp(q)/h`` huge; the q-row's correction is ``−r_q·h`` whatever b is. Partial pivoting
on the unscaled matrix pivots column q on the E row, and the q correction is then a
difference of two numbers of the E row's size: with one BLAS kernel it came out exactly 0,
Newton saw no correction of q and accepted a step that was off by 15 (tests/test_cli_faults.py,
the midpoint run that did not stop at exp's overflow)."""

from __future__ import annotations

import types

import numpy as np
import pytest
import scipy.sparse as sps

from phc.simulation.midpoint import NewtonMatrix, equilibration


def _matrix(values, nominal=None):
    values = np.asarray(values, dtype=float)

    def jacobian(t, y, yp, p, cj, out):
        out[:] = values

    # CSC order: (0,0), (1,0), (1,1)
    mod = types.SimpleNamespace(N=2, JAC_ROWS=[0, 1, 1], JAC_COLS=[0, 0, 1], jacobian=jacobian)
    matrix = NewtonMatrix(mod, None, nominal=nominal)
    assert matrix.factor(0.0, 0.01, np.zeros(2), np.zeros(2), s=1.0)
    return matrix


@pytest.mark.parametrize("b", [10.0 ** k for k in range(0, 50, 3)])
def test_a_states_correction_does_not_depend_on_another_rows_units(b):
    """In the Newton test's units (q ~ 1, E ~ 1e52 as the nominal scales had it) the q
    correction is exact to round-off, whatever the size b of the coupling."""
    h = 0.01
    matrix = _matrix([1 / h, b, 1 / h], nominal=[1.0, 1.3e52])
    rhs = np.array([1477.0, -1.24e30])
    delta = matrix.solve(rhs)
    # exact: δq = rhs_q·h, δE = (rhs_E − b δq)·h: a few correctly rounded operations each
    assert delta[0] == pytest.approx(rhs[0] * h, rel=4 * np.finfo(float).eps)
    assert delta[1] == pytest.approx((rhs[1] - b * delta[0]) * h, rel=8 * np.finfo(float).eps)


def test_without_the_nominal_scale_the_same_solve_loses_the_state():
    """The failure the scales prevent (so the test above can fail): equilibrated on its own
    entries only, the matrix pivots column q on the E row and δq is lost to cancellation."""
    h, b = 0.01, 1e6
    delta = _matrix([1 / h, b, 1 / h]).solve(np.array([1477.0, -1.24e30]))
    assert abs(delta[0] - 14.77) > 1.0


def test_equilibration_by_powers_of_two_columns_first_then_rows():
    rng = np.random.default_rng(0)
    dense = rng.standard_normal((6, 6)) * 10.0 ** rng.integers(-30, 30, size=(6, 1))
    dense[rng.random((6, 6)) < 0.4] = 0.0
    np.fill_diagonal(dense, 1e-3)
    nominal = np.array([0.0, 3.0, 0.0, 1e40, 0.0, 0.0])  # 0: scale the column by its entries
    rows, cols = equilibration(sps.csr_matrix(dense), nominal)
    for scales in (rows, cols):
        assert np.all(np.frexp(scales)[0] == 0.5)  # powers of two: the scaling is exact
    assert cols[1] == 2.0 and 1e40 / 2 < cols[3] <= 1e40
    scaled = np.abs(np.diag(rows) @ dense @ np.diag(cols))
    assert np.all((scaled.max(axis=1) >= 1.0) & (scaled.max(axis=1) < 2.0))
    free = nominal == 0
    assert np.all(np.abs(dense @ np.diag(cols)).max(axis=0)[free] < 2.0)
    assert np.all(np.abs(dense @ np.diag(cols)).max(axis=0)[free] >= 1.0)
