"""One-dimensional finite elements for structure-preserving discretization.

Meshes are uniform on ``[0, L]``. Spaces:

* ``P0``  — piecewise constants (one DOF per element),
* ``P1``  — continuous piecewise linears (nodal values),
* ``DP1`` — discontinuous piecewise linears (two DOFs per element),
* ``H3``  — C¹ Hermite cubics (value and slope at each node).

:func:`assemble` builds sparse matrices ``A_ij = ∫ c(ξ) ∂^r φ_i ∂^s ψ_j dξ`` by
vectorized element loops (cost linear in the number of elements), with 5-point
Gauss–Legendre quadrature (exact for the products of cubics used here when the
coefficient is piecewise constant).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Callable, Optional

import numpy as np
import scipy.sparse as sps

_GAUSS_S, _GAUSS_W = np.polynomial.legendre.leggauss(5)
_GAUSS_S = 0.5 * (_GAUSS_S + 1.0)  # on [0, 1]
_GAUSS_W = 0.5 * _GAUSS_W


@dataclass(frozen=True)
class Mesh:
    length: float
    elements: int

    @property
    def h(self) -> float:
        return self.length / self.elements

    @property
    def nodes(self) -> np.ndarray:
        return np.linspace(0.0, self.length, self.elements + 1)

    def quadrature_points(self) -> np.ndarray:
        """ξ at the Gauss points, shape (elements, n_gauss)."""
        left = self.nodes[:-1]
        return left[:, None] + self.h * _GAUSS_S[None, :]


class Space:
    """A finite element space: local basis values and the local-to-global DOF map."""

    name: str

    def __init__(self, mesh: Mesh):
        self.mesh = mesh

    @property
    def size(self) -> int:
        raise NotImplementedError

    def dofs(self) -> np.ndarray:
        """(elements, n_local) global DOF indices."""
        raise NotImplementedError

    def values(self, derivative: int) -> np.ndarray:
        """(n_local, n_gauss) values of the local basis (or ξ-derivatives) at Gauss points."""
        raise NotImplementedError

    def evaluate_at(self, coefficients: np.ndarray, xi: float, derivative: int = 0) -> float:
        """The discrete function (or derivative) with these coefficients at ξ."""
        e = min(int(xi / self.mesh.h), self.mesh.elements - 1)
        s = (xi - e * self.mesh.h) / self.mesh.h
        local = self._local(np.array([s]), derivative)[:, 0]
        return float(coefficients[self.dofs()[e]] @ local)

    def _local(self, s, derivative):
        raise NotImplementedError


class P0(Space):
    name = "P0"

    @property
    def size(self):
        return self.mesh.elements

    def dofs(self):
        return np.arange(self.mesh.elements)[:, None]

    def _local(self, s, derivative):
        return np.ones((1, len(s))) if derivative == 0 else np.zeros((1, len(s)))

    def values(self, derivative):
        return self._local(_GAUSS_S, derivative)


class P1(Space):
    name = "P1"

    @property
    def size(self):
        return self.mesh.elements + 1

    def dofs(self):
        e = np.arange(self.mesh.elements)
        return np.stack([e, e + 1], axis=1)

    def _local(self, s, derivative):
        h = self.mesh.h
        if derivative == 0:
            return np.stack([1 - s, s])
        if derivative == 1:
            return np.stack([-np.ones_like(s), np.ones_like(s)]) / h
        return np.zeros((2, len(s)))

    def values(self, derivative):
        return self._local(_GAUSS_S, derivative)


class DP1(P1):
    name = "DP1"

    @property
    def size(self):
        return 2 * self.mesh.elements

    def dofs(self):
        e = np.arange(self.mesh.elements)
        return np.stack([2 * e, 2 * e + 1], axis=1)


class H3(Space):
    """Hermite cubics; DOF 2i is the value and 2i+1 the slope at node i."""

    name = "H3"

    @property
    def size(self):
        return 2 * (self.mesh.elements + 1)

    def dofs(self):
        e = np.arange(self.mesh.elements)
        return np.stack([2 * e, 2 * e + 1, 2 * e + 2, 2 * e + 3], axis=1)

    def _local(self, s, derivative):
        h = self.mesh.h
        if derivative == 0:
            return np.stack([1 - 3 * s**2 + 2 * s**3, h * (s - 2 * s**2 + s**3), 3 * s**2 - 2 * s**3,
                             h * (-s**2 + s**3)])
        if derivative == 1:
            return np.stack([(-6 * s + 6 * s**2) / h, 1 - 4 * s + 3 * s**2, (6 * s - 6 * s**2) / h,
                             -2 * s + 3 * s**2])
        if derivative == 2:
            return np.stack([(-6 + 12 * s) / h**2, (-4 + 6 * s) / h, (6 - 12 * s) / h**2, (-2 + 6 * s) / h])
        raise ValueError("H3 has second derivatives at most here")

    def values(self, derivative):
        return self._local(_GAUSS_S, derivative)


SPACES = {"P0": P0, "P1": P1, "DP1": DP1, "H3": H3}


def assemble(rows: Space, r: int, cols: Space, c: int,
             coefficient: Optional[Callable[[np.ndarray], np.ndarray]] = None) -> sps.csr_matrix:
    """``A[i, j] = ∫ coefficient(ξ) · ∂^r φ_i(ξ) · ∂^c ψ_j(ξ) dξ`` for φ in `rows`, ψ in `cols`."""
    mesh = rows.mesh
    vi = rows.values(r)  # (nl_r, g)
    vj = cols.values(c)  # (nl_c, g)
    weights = mesh.h * _GAUSS_W  # (g,)
    if coefficient is None:
        cw = np.broadcast_to(weights, (mesh.elements, len(weights)))
    else:
        cw = np.asarray(coefficient(mesh.quadrature_points()), dtype=float) * weights[None, :]
        cw = np.broadcast_to(cw, (mesh.elements, len(weights)))
    local = np.einsum("ag,eg,bg->eab", vi, cw, vj)  # (elements, nl_r, nl_c)
    di, dj = rows.dofs(), cols.dofs()
    ii = np.broadcast_to(di[:, :, None], local.shape).ravel()
    jj = np.broadcast_to(dj[:, None, :], local.shape).ravel()
    matrix = sps.coo_matrix((local.ravel(), (ii, jj)), shape=(rows.size, cols.size)).tocsr()
    # Integrals that vanish exactly come out as quadrature round-off: drop them.
    if matrix.nnz:
        matrix.data[np.abs(matrix.data) <= 1e-13 * np.abs(matrix.data).max()] = 0.0
    matrix.eliminate_zeros()
    return matrix
