"""Tests of `phc.simulation.discrete_gradient` (energy-exact step for non-quadratic H)."""

from pathlib import Path

import numpy as np
import pytest

import phc

REPO = Path(__file__).resolve().parents[2]
HARD = REPO / "tests" / "hard" / "models"


@pytest.fixture(scope="module")
def pendulum():
    return phc.compile_model(HARD / "pendulum_minimal.yaml")


@pytest.fixture(scope="module")
def duffing():
    return phc.compile_model(HARD / "duffing.yaml")


def _per_step_balance(result):
    """|H(y_{n+1}) − H(y_n) + E_{n+1} − E_n| of every step, relative to the energy scale."""
    b = result.H + result.energy_supplied
    return np.abs(np.diff(b)) / np.abs(result.H).max()


@pytest.mark.parametrize("h", [0.01, 0.2, 0.7])
@pytest.mark.parametrize("model", ["pendulum", "duffing"])
def test_discrete_energy_balance_holds_at_every_step_for_any_step_size(model, h, request):
    compiled = request.getfixturevalue(model)
    t = np.arange(0, 61) * h  # one step per output: every step is checked
    dg = phc.simulate(compiled, solver="discrete_gradient", t_eval=t)
    assert dg.success, dg.message
    assert _per_step_balance(dg).max() < 1e-14
    # the same steps by the midpoint rule violate the balance (H is not quadratic) …
    mp = phc.simulate(compiled, solver="midpoint", t_eval=t)
    assert mp.success
    assert _per_step_balance(mp).max() > 1e3 * _per_step_balance(dg).max()


def test_large_step_pendulum_stays_on_its_energy_level_over_long_times(pendulum):
    """Step h = 0.5 s (a sixth of the period at q0 = 2.5 rad): no drift over 1000 steps."""
    r = phc.simulate(pendulum, solver="discrete_gradient", step=0.5, t_end=500.0, n_out=1001)
    assert r.success
    assert r.energy_balance_relative < 1e-12
    assert np.abs(r["pend.q"]).max() < np.pi  # still librating, never over the top


def test_dissipation_is_accounted_exactly(duffing):
    r = phc.simulate(duffing, solver="discrete_gradient", step=0.3, params={"c": 0.5}, t_end=30.0, n_out=101)
    assert r.success
    assert r.H[-1] < 1e-2 * r.H[0]  # the damper removed the energy …
    assert r.energy_balance_relative < 1e-13  # … and the accumulator booked every joule


def test_second_order_convergence(pendulum):
    """Symmetric method (the evaluation point is the root nearest 1/2): order 2."""
    ref = phc.simulate(pendulum, solver="ida", t_end=2.0, n_out=5, rtol=1e-12, atol=1e-12)
    errors = []
    for h in (0.02, 0.01, 0.005):
        r = phc.simulate(pendulum, solver="discrete_gradient", step=h, t_end=2.0, n_out=5)
        errors.append(np.abs(r["pend.q"] - ref["pend.q"]).max())
    orders = np.log2(np.array(errors[:-1]) / np.array(errors[1:]))
    assert np.all(np.abs(orders - 2.0) < 0.1), orders


def test_quadratic_hamiltonian_gives_the_midpoint_rule():
    compiled = phc.compile_model(REPO / "models" / "mass_spring_damper.yaml")
    a = phc.simulate(compiled, solver="discrete_gradient", step=0.1, n_out=21)
    b = phc.simulate(compiled, solver="midpoint", step=0.1, n_out=21)
    assert a.success and b.success
    np.testing.assert_allclose(a.y, b.y, rtol=0, atol=1e-13)


def test_constrained_pendulum_energy_and_constraint_exact_with_large_steps():
    """Cartesian pendulum (GGL index 2): positions constrained at the step ends."""
    compiled = phc.compile_model(REPO / "models" / "pendulum.yaml")
    r = phc.simulate(compiled, solver="discrete_gradient", step=0.1, t_end=50.0, n_out=101)
    assert r.success, r.message
    assert r.energy_balance_relative < 1e-12
    assert r.constraint_drift < 1e-12


def test_constrained_pendulum_with_a_non_quadratic_potential(tmp_path):
    """Index-2 GGL constraints and a non-quadratic H together: the evaluation point y(s*)
    carries the constraint gradients and the efforts at once, so the balance stays exact."""
    text = (REPO / "models" / "pendulum.yaml").read_text()
    assert "    V: m*g*y\n" in text
    path = tmp_path / "pendulum_nl.yaml"
    path.write_text(text.replace("    V: m*g*y\n", "    V: m*g*y + 5*y**4 + 3*cos(x)\n"))
    compiled = phc.compile_model(path)
    dg = phc.simulate(compiled, solver="discrete_gradient", step=0.1, t_end=50.0, n_out=101)
    mp = phc.simulate(compiled, solver="midpoint", step=0.1, t_end=50.0, n_out=101)
    assert dg.success and mp.success
    assert dg.energy_balance_relative < 1e-12
    assert dg.constraint_drift < 1e-12
    assert mp.energy_balance_relative > 1e3 * dg.energy_balance_relative


DOUBLE_PENDULUM_ANGLES = """\
format_version: 1
name: dpend_angles
parameters: {m1: 1.2, L1: 0.8, m2: 0.7, L2: 0.6, g: 9.81, J1: "m1*L1**2/3", J2: "m2*L2**2/12"}
components:
  dp:
    type: rigid
    q: [a, b]
    v: [da, db]
    M: [["J1 + m2*L1**2", "m2*L1*L2/2*cos(a - b)"], ["m2*L1*L2/2*cos(a - b)", "J2 + m2*L2**2/4"]]
    V: -m1*g*L1/2*cos(a) - m2*g*(L1*cos(a) + L2/2*cos(b))
simulation:
  t_end: 1.0
  n_out: 101
  initial: {dp.a: 1.2, dp.b: -0.4, dp.p_da: 0, dp.p_db: 0}
"""


def test_without_constraints_a_step_with_no_balancing_point_fails_with_what_to_do(tmp_path):
    """A double pendulum in its two angles (M(q), no constraints) at h = 1e-3 reaches a step
    where no point of the step balances the energy. Without constraints no projection's
    work explains that, so it is not taken as a midpoint step (which made the run 10x less
    accurate than the midpoint rule's and blamed a GGL projection the model does not have):
    the run stops and says what to do."""
    path = tmp_path / "dpend.yaml"
    path.write_text(DOUBLE_PENDULUM_ANGLES)
    compiled = phc.compile_model(path, certify=False)
    r = phc.simulate(compiled, solver="discrete_gradient", step=1e-3, backend="numpy")
    assert not r.success
    assert "no point along the step balances the energy" in r.message and "GGL" not in r.message
    assert "`ida`" in r.message and "shorter `step`" in r.message
    assert r.energy_balance_relative < 1e-12  # up to there the balance is exact
