"""Stress: the Cartesian pendulum over long horizons (`phc.simulation.midpoint`, drift control).

Stabilization in phc is the GGL formulation (seed, rigid multibody DAE: velocity
constraints plus position constraints with their own multipliers η) and, in the
structure-preserving solvers, the position constraints imposed at every step *end*
(the other rows at the midpoint). The drift |x² + y² − L²| then stays at the Newton
tolerance for any horizon. Without it — only the velocity constraint kept, the index-2
formulation without position constraints — the drift of a BDF code (IDA) grows with time.
"""

from pathlib import Path

import numpy as np
import pytest

import phc
from phc.options import RunOptions
from phc.simulation.ida import integrate_ida
from phc.simulation.midpoint import integrate_midpoint

PENDULUM = Path(__file__).resolve().parents[2] / "models" / "pendulum.yaml"


@pytest.fixture(scope="module")
def compiled():
    return phc.compile_model(PENDULUM)


class WithoutPositionConstraints:
    """The generated module with each position-constraint row g(q) = 0 replaced by η = 0:
    the unstabilized index-2 DAE (velocity constraint only). Dense Jacobian pattern."""

    def __init__(self, mod):
        self.mod = mod
        for name in ("N", "VARIABLES", "DIFFERENTIAL", "ROLES", "hamiltonian", "energy_scale", "powers"):
            setattr(self, name, getattr(mod, name))
        n = mod.N
        self.g_rows = [list(mod.EQUATIONS).index(label) for label in mod.INVARIANTS]
        self.eta = [j for j, v in enumerate(mod.VARIABLES) if v.startswith("ggl.eta")]
        self.EQUATIONS = tuple(f"{e}.dropped" if i in self.g_rows else e for i, e in enumerate(mod.EQUATIONS))
        self.INVARIANTS = ()
        self.JAC_COLS, self.JAC_ROWS = np.divmod(np.arange(n * n), n)  # CSC order of a dense matrix
        self._buf = np.zeros(len(mod.JAC_ROWS))

    def residual(self, t, y, yp, p, out):
        self.mod.residual(t, y, yp, p, out)
        out[self.g_rows] = y[self.eta]

    def jacobian(self, t, y, yp, p, cj, out):
        self.mod.jacobian(t, y, yp, p, cj, self._buf)
        D = np.zeros((self.N, self.N))
        D[self.mod.JAC_ROWS, self.mod.JAC_COLS] = self._buf
        D[self.g_rows, :] = 0.0
        D[self.g_rows, self.eta] = 1.0
        out[:] = D.ravel(order="F")


def _drift(mod, p, result_y):
    return np.array([np.abs(mod.invariants(0.0, y, p)).max() for y in result_y])


@pytest.mark.parametrize("t_end", [200.0, pytest.param(10_000.0, marks=pytest.mark.slow)])
def test_stabilized_midpoint_keeps_the_constraint_and_the_energy(compiled, t_end):
    r = phc.simulate(compiled, solver="midpoint", step=0.05, t_end=t_end, n_out=101)
    assert r.success, r.message
    print(f"\nmidpoint over {t_end:g} s: constraint drift {r.constraint_drift:.1e}, "
          f"energy {r.energy_balance_relative:.1e}")
    assert r.constraint_drift <= 1e-8
    assert r.energy_balance_relative <= 1e-10  # η does no work: g is quadratic


@pytest.mark.parametrize("t_end", [50.0, pytest.param(1000.0, marks=pytest.mark.slow)])
def test_drift_grows_without_stabilization(compiled, t_end):
    """IDA on the GGL formulation vs IDA on the index-2 formulation without position rows."""
    rtol = 1e-6
    ggl = phc.simulate(compiled, solver="ida", t_end=t_end, n_out=101, rtol=rtol, atol=1e-2 * rtol)
    assert ggl.success, ggl.message
    mod = compiled.module
    p = mod.full_parameters()
    out = integrate_ida(WithoutPositionConstraints(mod), p, ggl.t, ggl.y[0], ggl.yp[0],
                        RunOptions(rtol=rtol, atol=1e-2 * rtol, max_steps=10**8))
    assert out.success, out.message
    drift = _drift(mod, p, out.y)
    half = len(drift) // 2
    print(f"\nIDA over {t_end:g} s, rtol {rtol:g}: constraint drift with GGL {ggl.constraint_drift:.1e}, "
          f"without position constraints {drift.max():.1e}")
    assert ggl.constraint_drift <= 10 * rtol
    assert drift.max() > 100 * ggl.constraint_drift
    assert drift[half:].max() > 1.5 * drift[:half].max()  # and it keeps growing


def test_midpoint_alone_keeps_quadratic_constraints(compiled):
    """Why the structure-preserving rule needs no projection here: with the velocity
    constraint G(q_mid) q̇ = 0 imposed at the midpoint, g(q₁) − g(q₀) = G(q_mid)(q₁ − q₀) = 0
    exactly for quadratic g — even in the formulation without position rows."""
    mod = compiled.module
    p = mod.full_parameters()
    r = phc.simulate(compiled, solver="midpoint", step=0.05, t_end=50.0, n_out=51)
    out = integrate_midpoint(WithoutPositionConstraints(mod), p, r.t, r.y[0], r.yp[0],
                             RunOptions(solver="midpoint", max_steps=10**9, step=0.05))
    assert out.success, out.message
    assert _drift(mod, p, out.y).max() <= 1e-12
