"""The shared dense equilibration (phc.simulation.equilibrate): the scaled matrix has the
row and column sizes the method promises, power-of-two scales scale exactly, a zero row or
column is left alone, and a badly scaled matrix becomes well conditioned."""

import numpy as np
import pytest

from phc.simulation.equilibrate import equilibrate

EPS = np.finfo(float).eps


def _badly_scaled(rng, m, n):
    """A random m×n matrix with rows and columns scaled by factors from 1e-8 to 1e8."""
    B = rng.normal(size=(m, n))
    return B, (10.0 ** rng.uniform(-8, 8, size=(m, 1))) * B * (10.0 ** rng.uniform(-8, 8, size=(1, n)))


@pytest.mark.parametrize("rounds", [1, 2, 4])
@pytest.mark.parametrize("shape", [(5, 5), (3, 7), (8, 4)])
def test_plain_scaling_gives_largest_entry_one(rounds, shape):
    rng = np.random.default_rng(rounds * 100 + shape[0])
    _, M = _badly_scaled(rng, *shape)
    S, r, c = equilibrate(M, rounds=rounds)
    # the last step divides each column by its largest entry: 1 up to the round-off of
    # the products r_i·a_ij·c_j (a few ulps)
    assert np.allclose(np.abs(S).max(axis=0), 1.0, rtol=8 * EPS, atol=0)
    assert np.abs(S).max() <= 1.0 + 8 * EPS  # rows were at most 1 before their columns shrank them
    # the scales are what was applied (same round-off)
    assert np.allclose(S, r[:, None] * M * c[None, :], rtol=16 * rounds * EPS, atol=0)


@pytest.mark.parametrize("rounds", [1, 4])
def test_power_of_two_scaling_is_exact(rounds):
    rng = np.random.default_rng(7 + rounds)
    _, M = _badly_scaled(rng, 6, 6)
    S, r, c = equilibrate(M, rounds=rounds, power_of_two=True)
    for s in (r, c):
        mantissa, _ = np.frexp(s)
        assert np.all(mantissa == 0.5)  # every scale is a power of two
    # scaling by powers of two is exact: the scaled matrix is the product to the last bit
    assert np.array_equal(S, (r[:, None] * M) * c[None, :])
    # each column's largest entry was divided by its nearest power of two last
    col = np.abs(S).max(axis=0)
    assert np.all(col >= 2 ** -0.5) and np.all(col <= 2 ** 0.5)


@pytest.mark.parametrize("power_of_two", [False, True])
def test_zero_row_and_column_keep_scale_one(power_of_two):
    rng = np.random.default_rng(3)
    _, M = _badly_scaled(rng, 5, 4)
    M[2, :] = 0.0
    M[:, 1] = 0.0
    S, r, c = equilibrate(M, rounds=2, power_of_two=power_of_two)
    assert r[2] == 1.0 and c[1] == 1.0
    assert not S[2, :].any() and not S[:, 1].any()
    others = np.abs(np.delete(S, 1, axis=1)).max(axis=0)
    top = 2 ** 0.5 if power_of_two else 1.0 + 8 * EPS  # as in the tests above
    assert np.all(others >= 2 ** -0.5) and np.all(others <= top)


@pytest.mark.parametrize("power_of_two", [False, True])
def test_badly_scaled_matrix_becomes_well_conditioned(power_of_two):
    rng = np.random.default_rng(11)
    n = 6
    B, M = _badly_scaled(rng, n, n)
    before, well = np.linalg.cond(M), np.linalg.cond(B)
    assert before > 1e6 * well  # the scaling is what makes M ill-conditioned
    S, _, _ = equilibrate(M, rounds=4, power_of_two=power_of_two)
    # van der Sluis: scaling one side to equal max-norm rows (columns) is within a factor
    # of order n of the best diagonal scaling of that side, so both sides: n²·cond(B);
    # powers of two lose at most another factor 2 on each side
    assert np.linalg.cond(S) <= 4 * n ** 2 * well


def test_empty_matrix():
    S, r, c = equilibrate(np.zeros((0, 3)))
    assert S.shape == (0, 3) and r.shape == (0,) and np.array_equal(c, np.ones(3))
