"""Tests of `phc.discretize.fem1d`: the 1-D meshes, finite element spaces (P0, P1, DP1,
Hermite H3) and the quadrature-based assembly used by the string and beam components.

Reference values are closed-form integrals of polynomials computed here with exact
antiderivatives (numpy.polynomial), never numbers from an earlier run.
"""

from __future__ import annotations

import numpy as np
import pytest
from numpy.polynomial import Polynomial

from phc.discretize.fem1d import DP1, H3, P0, P1, SPACES, Mesh, assemble

MESHES = [Mesh(0.3, 1), Mesh(0.3, 4), Mesh(2.0, 7), Mesh(1.0, 32)]
MESH_IDS = [f"L{m.length}-n{m.elements}" for m in MESHES]


def dense(space_r, r, space_c, c, coefficient=None):
    return assemble(space_r, r, space_c, c, coefficient).toarray()


def hermite_dofs(mesh, f: Polynomial) -> np.ndarray:
    """H3 coefficients of the interpolant of f: (f(x_i), f'(x_i)) interleaved."""
    x = mesh.nodes
    out = np.empty(2 * len(x))
    out[0::2], out[1::2] = f(x), f.deriv()(x)
    return out


def dp1_dofs(mesh, f: Polynomial) -> np.ndarray:
    """DP1 coefficients of the (element-wise) interpolant: f at the two ends of each element."""
    x = mesh.nodes
    out = np.empty(2 * mesh.elements)
    out[0::2], out[1::2] = f(x[:-1]), f(x[1:])
    return out


# -- mesh ------------------------------------------------------------------------------


@pytest.mark.parametrize("mesh", MESHES, ids=MESH_IDS)
def test_mesh_nodes_and_quadrature_points(mesh):
    assert mesh.h == pytest.approx(mesh.length / mesh.elements, rel=1e-15)
    assert mesh.nodes[0] == 0.0 and mesh.nodes[-1] == pytest.approx(mesh.length, rel=1e-15)
    q = mesh.quadrature_points()
    assert q.shape[0] == mesh.elements
    # Each row lies strictly inside its element.
    assert np.all(q > mesh.nodes[:-1, None]) and np.all(q < mesh.nodes[1:, None])


@pytest.mark.parametrize("name, size", [("P0", lambda n: n), ("P1", lambda n: n + 1),
                                        ("DP1", lambda n: 2 * n), ("H3", lambda n: 2 * (n + 1))])
def test_space_sizes_and_dof_maps(name, size):
    mesh = Mesh(1.0, 5)
    space = SPACES[name](mesh)
    assert space.size == size(5)
    dofs = space.dofs()
    assert dofs.shape[0] == 5
    assert set(dofs.ravel()) == set(range(space.size))  # every DOF belongs to some element


# -- mass matrices ---------------------------------------------------------------------
#
# The basis functions of P0, P1 and DP1 sum to 1, so Σ_ij M_ij = ∫ 1·1 = L. For H3 the
# value functions sum to 1; the slope functions integrate to ±h²/12 on each element and
# cancel between neighbours except at the two ends, where they are +h²/12 (node 0) and
# −h²/12 (node n) and cancel each other: Σ_{i value} Σ_j M_ij = L as well.


@pytest.mark.parametrize("mesh", MESHES, ids=MESH_IDS)
@pytest.mark.parametrize("space", [P0, P1, DP1])
def test_mass_matrix_integrates_constants(space, mesh):
    M = dense(space(mesh), 0, space(mesh), 0)
    assert M.sum() == pytest.approx(mesh.length, rel=1e-13)
    np.testing.assert_allclose(M, M.T, atol=1e-15 * mesh.length)
    assert np.linalg.eigvalsh(M).min() > 0


@pytest.mark.parametrize("mesh", MESHES, ids=MESH_IDS)
def test_hermite_mass_matrix_value_rows_integrate_constants(mesh):
    M = dense(H3(mesh), 0, H3(mesh), 0)
    value = slice(0, None, 2)
    assert M[value][:, value].sum() == pytest.approx(mesh.length, rel=1e-13)
    assert M[value].sum() == pytest.approx(mesh.length, rel=1e-13)
    np.testing.assert_allclose(M, M.T, atol=1e-15 * mesh.length)
    assert np.linalg.eigvalsh(M).min() > 0


def test_p1_mass_matrix_is_the_textbook_one():
    mesh = Mesh(1.0, 3)
    h = mesh.h
    expected = h / 6 * np.array([[2, 1, 0, 0], [1, 4, 1, 0], [0, 1, 4, 1], [0, 0, 1, 2]])
    np.testing.assert_allclose(dense(P1(mesh), 0, P1(mesh), 0), expected, rtol=1e-14, atol=1e-16)


# -- derivative matrices ---------------------------------------------------------------


@pytest.mark.parametrize("mesh", MESHES, ids=MESH_IDS)
def test_p1_derivative_against_p0_is_the_difference_matrix(mesh):
    # ∫_{element e} 1 · φ_i' = φ_i(x_{e+1}) − φ_i(x_e): −1 for node e, +1 for node e+1.
    D = dense(P0(mesh), 0, P1(mesh), 1)
    n = mesh.elements
    expected = np.zeros((n, n + 1))
    expected[np.arange(n), np.arange(n)] = -1.0
    expected[np.arange(n), np.arange(n) + 1] = 1.0
    np.testing.assert_allclose(D, expected, rtol=1e-13, atol=1e-13)
    # Constants are in its kernel: the derivative of a constant vanishes.
    np.testing.assert_allclose(D @ np.ones(n + 1), 0.0, atol=1e-13)


@pytest.mark.parametrize("mesh", MESHES, ids=MESH_IDS)
def test_hermite_second_derivative_against_dp1_is_exact_for_cubics(mesh):
    # For a cubic f (interpolated exactly by H3), row j of D u is ∫ ψ_j f'' with ψ_j the
    # DP1 basis: on element [x_e, x_e + h], ∫ (1 − s) f'' and ∫ s f'' (s = (ξ − x_e)/h).
    f = Polynomial([0.3, -1.0, 2.0, 0.7])
    D = dense(DP1(mesh), 0, H3(mesh), 2)
    got = D @ hermite_dofs(mesh, f)
    x, h = mesh.nodes, mesh.h
    expected = np.empty(2 * mesh.elements)
    for e in range(mesh.elements):
        left = Polynomial([x[e + 1] / h, -1 / h]) * f.deriv(2)   # (x_{e+1} − ξ)/h · f''
        right = Polynomial([-x[e] / h, 1 / h]) * f.deriv(2)      # (ξ − x_e)/h · f''
        expected[2 * e] = left.integ()(x[e + 1]) - left.integ()(x[e])
        expected[2 * e + 1] = right.integ()(x[e + 1]) - right.integ()(x[e])
    np.testing.assert_allclose(got, expected, rtol=1e-11, atol=1e-11 * np.abs(expected).max())


# -- interpolation and evaluation ------------------------------------------------------


@pytest.mark.parametrize("mesh", MESHES, ids=MESH_IDS)
def test_hermite_interpolation_of_a_cubic_is_exact(mesh):
    f = Polynomial([0.3, -1.0, 2.0, 0.7]) * (1.0 / mesh.length)
    u = hermite_dofs(mesh, f)
    space = H3(mesh)
    points = np.concatenate([np.random.default_rng(0).uniform(0, mesh.length, 20), mesh.nodes])
    for xi in points:
        for derivative, g in enumerate([f, f.deriv(), f.deriv(2)]):
            assert space.evaluate_at(u, xi, derivative) == pytest.approx(g(xi), rel=1e-10, abs=1e-10)


@pytest.mark.parametrize("mesh", MESHES, ids=MESH_IDS)
def test_p1_and_dp1_interpolation_of_linears_is_exact(mesh):
    f = Polynomial([0.5, -2.0])
    points = np.concatenate([np.random.default_rng(1).uniform(0, mesh.length, 10), mesh.nodes])
    for space, u in [(P1(mesh), f(mesh.nodes)), (DP1(mesh), dp1_dofs(mesh, f))]:
        for xi in points:
            assert space.evaluate_at(u, xi) == pytest.approx(f(xi), rel=1e-12, abs=1e-12)
            assert space.evaluate_at(u, xi, 1) == pytest.approx(-2.0, rel=1e-12)


def test_p0_evaluation_is_piecewise_constant():
    mesh = Mesh(1.0, 4)
    u = np.array([1.0, 2.0, 3.0, 4.0])
    assert [P0(mesh).evaluate_at(u, xi) for xi in (0.1, 0.3, 0.6, 0.9, 1.0)] == [1.0, 2.0, 3.0, 4.0, 4.0]


# -- quadrature with variable coefficients ---------------------------------------------


def test_p0_mass_with_a_polynomial_coefficient_is_the_exact_element_integral():
    # 5-point Gauss–Legendre integrates degree ≤ 9 exactly.
    mesh = Mesh(1.7, 6)
    c = Polynomial([1.0, 0.0, 0.0, -2.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.4])  # 1 − 2ξ³ + 0.4ξ⁹
    M = dense(P0(mesh), 0, P0(mesh), 0, c)
    C = c.integ()
    x = mesh.nodes
    np.testing.assert_allclose(M, np.diag(C(x[1:]) - C(x[:-1])), rtol=1e-12, atol=1e-14)


@pytest.mark.parametrize("mesh", MESHES, ids=MESH_IDS)
def test_hermite_weighted_mass_matches_the_closed_form_integral(mesh):
    # uᵀ M_c v = ∫ c f g for cubics f, g and a quadratic c (degree 8 ≤ 9: exact).
    c = Polynomial([1.0, 0.5, 0.25])
    f = Polynomial([0.3, -1.0, 2.0, 0.7])
    g = Polynomial([-0.2, 0.4, 0.0, 1.1])
    M = assemble(H3(mesh), 0, H3(mesh), 0, c)
    got = hermite_dofs(mesh, f) @ (M @ hermite_dofs(mesh, g))
    F = (c * f * g).integ()
    assert got == pytest.approx(F(mesh.length) - F(0.0), rel=1e-12)


def test_smooth_coefficient_quadrature_converges():
    # A non-polynomial coefficient is integrated with the Gauss rule's O(h¹⁰) error.
    def total(n):
        mesh = Mesh(1.0, n)
        return dense(P0(mesh), 0, P0(mesh), 0, np.exp).sum()

    exact = np.e - 1
    assert abs(total(2) - exact) <= 1e-10
    assert abs(total(8) - exact) <= 1e-14


# -- sparsity and cost ----------------------------------------------------------------

PAIRS = [("P1", 0, "P1", 0), ("P0", 0, "P0", 0), ("DP1", 0, "DP1", 0), ("H3", 0, "H3", 0),
         ("P0", 0, "P1", 1), ("DP1", 0, "H3", 2)]


@pytest.mark.parametrize("rows, r, cols, c", PAIRS, ids=[f"{a}{r}-{b}{c}" for a, r, b, c in PAIRS])
def test_assembled_matrices_are_sparse_with_nnz_linear_in_the_elements(rows, r, cols, c):
    # Each element adds a fixed local block, so nnz(n) = a n + b exactly: the second
    # differences over n = 100, 200, 400, 800 vanish, and nnz per element stays bounded.
    nnz = []
    for n in (100, 200, 400, 800):
        mesh = Mesh(1.0, n)
        A = assemble(SPACES[rows](mesh), r, SPACES[cols](mesh), c)
        assert A.shape == (SPACES[rows](mesh).size, SPACES[cols](mesh).size)
        nnz.append(A.nnz)
    nnz = np.array(nnz)
    slopes = np.diff(nnz) / np.diff([100, 200, 400, 800])
    assert np.all(slopes == slopes[0])
    assert slopes[0] <= 16


def test_p1_mass_matrix_nnz_is_tridiagonal():
    mesh = Mesh(1.0, 50)
    assert assemble(P1(mesh), 0, P1(mesh), 0).nnz == 3 * 51 - 2


def test_exactly_vanishing_integrals_are_not_stored():
    mesh = Mesh(0.3, 10)
    D = assemble(DP1(mesh), 0, H3(mesh), 2)
    assert np.abs(D.data).min() > 1e-12 * np.abs(D.data).max()
    # per element, ∫ N_a H_b'' ds over the 2 × 4 local pairs: two vanish exactly
    # (∫(1−s)(−2+6s) = ∫ s(−4+6s) = 0), so 6 entries per element are stored.
    assert D.nnz == 6 * mesh.elements
