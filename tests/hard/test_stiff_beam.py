"""Stress: a stiff Euler–Bernoulli cantilever, 256 Hermite elements (`phc.simulation.midpoint`).

The semi-discrete beam's highest frequency is ~5e8 rad/s, while the response of
interest (a tip force ramped over 3 ms) lives in the first mode, ω₁ ≈ 455 rad/s. An
explicit method needs h·ω_max ≤ 2 (leapfrog) — steps of ~4 ns. The implicit midpoint
rule is A-stable and energy-exact for this quadratic H, so the step is chosen for the
first mode only (h = 1e-4 s, h·ω_max ≈ 5e4): the run stays bounded, closes its energy
balance to round-off and converges at the rate of the resolved dynamics.
"""

import math
from pathlib import Path

import numpy as np
import pytest
import scipy.sparse as sps
import scipy.sparse.linalg as spla

import phc

BEAM = Path(__file__).resolve().parent / "models" / "stiff_beam.yaml"
EI, RHOA, L, F, T_RAMP = 68.27, 0.50368, 0.3, 1.0, 0.003


@pytest.fixture(scope="module")
def compiled():
    return phc.compile_model(BEAM)


def highest_frequency(mod, shift=1e9, iterations=300):
    """|λ| of the eigenvalue of the pencil (−F_y, F_ẏ) nearest i·shift, by inverse iteration
    with the shift (sparse solves only: no dense BLAS)."""
    n = mod.N
    buf = np.zeros(len(mod.JAC_ROWS))
    p, z = mod.full_parameters(), np.zeros(n)
    mod.jacobian(0.0, z, z, p, 0.0, buf)
    A = sps.csc_matrix((buf.copy(), (mod.JAC_ROWS, mod.JAC_COLS)), shape=(n, n))
    mod.jacobian(0.0, z, z, p, 1.0, buf)
    E = sps.csc_matrix((buf.copy(), (mod.JAC_ROWS, mod.JAC_COLS)), shape=(n, n)) - A
    sigma = 1j * shift
    lu = spla.splu((-A - sigma * E).tocsc())
    x = np.random.default_rng(0).standard_normal(n).astype(complex)
    for _ in range(iterations):
        y = lu.solve(E @ x)
        nu = np.vdot(x, y) / np.vdot(x, x)  # eigenvalue of (−A − σE)⁻¹E: ν = 1/(λ − σ)
        x = y / np.linalg.norm(y)
    return float(abs(sigma + 1.0 / nu))


def tip_deflection(r):
    v = r["tip_velocity"]
    return np.concatenate([[0.0], np.cumsum(0.5 * (v[1:] + v[:-1]) * np.diff(r.t))])


def test_step_is_set_by_accuracy_not_stability(compiled):
    omega_max = highest_frequency(compiled.module)
    assert omega_max > 1e6
    h = 1e-4
    assert h * omega_max > 1e3 * 2  # a thousand times the explicit (leapfrog) stability limit
    t_end = 0.017
    coarse = phc.simulate(compiled, solver="midpoint", step=h, t_end=t_end, n_out=171)
    fine = phc.simulate(compiled, solver="midpoint", step=h / 2, t_end=t_end, n_out=171)
    assert coarse.success and fine.success
    # bounded and energy-exact despite h·ω_max ≈ 5e4
    assert coarse.energy_balance_relative < 1e-12
    w_static = F * L**3 / (3 * EI)
    w = tip_deflection(coarse)
    assert np.abs(w).max() < 3 * w_static
    # the first mode is resolved: mean deflection over one period after the ramp is static
    T1 = 2 * math.pi / ((1.8751040687 / L) ** 2 * math.sqrt(EI / RHOA))
    window = (coarse.t >= T_RAMP) & (coarse.t <= T_RAMP + T1)
    mean = np.trapezoid(w[window], coarse.t[window]) / (coarse.t[window][-1] - coarse.t[window][0])
    assert mean == pytest.approx(w_static, rel=0.02)
    # halving the step changes the tip motion at second order in h·ω₁ (≈ 0.05), not more
    assert np.abs(w - tip_deflection(fine)).max() < 0.02 * w_static
