"""Tests of `phc.simulation.discrete_gradient` (energy-exact step for non-quadratic H)."""

from pathlib import Path

import numpy as np
import pytest

import phc
from rigid_cases import bead_on_turned_rod

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


def test_double_pendulum_in_angles_balances_the_energy_of_its_states(tmp_path):
    """A double pendulum in its two angles (M(q), no constraints): H = ½pᵀv + V is written in the
    velocities v of the rows M(q) v = p, which the stage imposes at the point y(s), not at the step
    end. Before, the balance used the extrapolated end velocities, which are not M(q₁)⁻¹p₁: it was
    kept exactly for a function that is not the energy of the states, and at h = 1e-3 a step came
    where no s balanced that function (the run stopped). Now the velocities are made consistent at
    the step ends: the run finishes and every step's balance holds to round-off (the secant
    iteration's tolerance, 2e-15 of the energy scale a step — the sum of |terms| of H, a few
    times max |H| — accepted up to 1e3 times that at the round-off floor of H)."""
    path = tmp_path / "dpend.yaml"
    path.write_text(DOUBLE_PENDULUM_ANGLES)
    compiled = phc.compile_model(path, certify=False)
    t = np.linspace(0.0, 1.0, 1001)  # one step per output: every step is checked
    r = phc.simulate(compiled, solver="discrete_gradient", t_eval=t, backend="numpy")
    assert r.success, r.message
    assert _per_step_balance(r).max() < 1e-11


CART_POLE = """\
format_version: 1
name: cartpole
parameters: {mc: 2.0, mp: 0.5, l: 0.8, g: 9.81}
components:
  cart:
    type: rigid
    q: [s, th]
    v: [ds, dth]
    M: [[mc + mp, mp*l*cos(th)], [mp*l*cos(th), mp*l**2]]
    V: -mp*g*l*cos(th)
simulation:
  t_end: 2.0
  n_out: 201
  initial: {cart.s: 0.0, cart.th: 2.5, cart.p_ds: 0.3, cart.p_dth: 0.0}
  outputs: {px: cart.p_ds, energy: H}
"""


@pytest.fixture(scope="module")
def cart_pole(tmp_path_factory):
    path = tmp_path_factory.mktemp("cart_pole") / "cartpole.yaml"
    path.write_text(CART_POLE)
    return path


def _ida_reference(compiled, t_end):
    ref = phc.simulate(compiled, solver="ida", t_end=t_end, n_out=2, rtol=1e-11, atol=1e-12)
    assert ref.success
    return ref


@pytest.mark.parametrize("backend", ["numpy", None])  # None: the default back end (C where a compiler is found)
def test_cart_pole_energy_and_horizontal_momentum_are_exact(cart_pole, backend):
    """A cart–pole as one rigid body, q = [s, th], M(q) = [[mc+mp, mp l cos th], [mp l cos th, mp l²]],
    V = −mp g l cos th (a user's model). It stopped at t ≈ 0.74 at every step size with "no point
    along the step balances the energy", and before that its energy drifted by 2.6e-3 at h = 0.01
    (the balance was kept for H evaluated at the extrapolated velocities, not at M(q₁)⁻¹p₁; the
    outputs, whose velocities are recomputed from the states, showed the drift).

    Each step's balance H(x₁) − H(x₀) = 0 (no ports, no damping) holds to the secant iteration's
    tolerance, 2e-15 of the energy scale (the sum of |terms| of H, ≈ 11 J against max |H| ≈ 3.2 J:
    7e-15 of max |H|), accepted up to 1e3 times that (7e-12) at the round-off floor of H: 1e-11
    of max |H| a step, and over the 200 steps (1.4e-12 at the tolerance with one sign, plus a step
    at the floor), is round-off. p_ds is conserved by the row ṗ_ds = 0, which Newton solves to
    its tolerance 1e-14 (relative to 1 + |y| ≤ 10) a step: at most 2e-11 over 200 steps."""
    compiled = phc.compile_model(cart_pole, certify=False, **({"backend": backend} if backend else {}))
    r = phc.simulate(compiled, solver="discrete_gradient", step=0.01)
    assert r.success, r.message
    assert len(r.t) == 201 and r.t[-1] == 2.0  # one step per output: every step is checked
    assert _per_step_balance(r).max() < 1e-11
    assert r.energy_balance_relative < 1e-11
    assert np.abs(r["px"] - 0.3).max() < 2e-11
    # the energy of the states: H from q, p alone (v = M(q)⁻¹p), not from the velocities the run carries
    th, pds, pdth = r["cart.th"], r["cart.p_ds"], r["cart.p_dth"]
    mc, mp, length, g = 2.0, 0.5, 0.8, 9.81
    det = (mc + mp) * mp * length**2 - (mp * length * np.cos(th)) ** 2
    kinetic = (mp * length**2 * pds**2 - 2 * mp * length * np.cos(th) * pds * pdth + (mc + mp) * pdth**2) / (2 * det)
    H = kinetic - mp * g * length * np.cos(th)
    assert np.abs(H - H[0]).max() < 1e-11 * np.abs(H).max()  # as the balance above


def test_cart_pole_is_second_order(cart_pole):
    """Consistent end velocities change what the run carries, not the states' step: the method
    stays of order 2 (errors at t = 1 against IDA at rtol 1e-11, halving h from 0.01)."""
    compiled = phc.compile_model(cart_pole, certify=False, backend="numpy")
    ref = _ida_reference(compiled, 1.0)
    errors = []
    for h in (0.01, 0.005, 0.0025):
        r = phc.simulate(compiled, solver="discrete_gradient", step=h, t_end=1.0, n_out=2)
        assert r.success, r.message
        errors.append(abs(r["cart.th"][-1] - ref["cart.th"][-1]))
    orders = np.log2(np.array(errors[:-1]) / np.array(errors[1:]))
    assert np.all(np.abs(orders - 2.0) < 0.1), (errors, orders)


BEAD = bead_on_turned_rod(n_out=151)


@pytest.mark.parametrize("outputs", [False, True])
def test_outputs_that_read_velocities_keep_them_those_of_the_states(tmp_path, outputs):
    """A bead sliding freely on a rod turned at the prescribed rate Ω (M(q) = diag(m, J + m r²),
    the rheonomic constraint θ = Ωt; closed form r = r₀ cosh Ωt). The discrete gradient balances
    each step to round-off, but with an output reading an algebraic variable (`energy: H`) the
    output polish (simulation/polish.py) solved the velocities by least squares from the rows
    M(q) v = p together with the velocity constraint's hidden rows, which a fixed-step solver's
    step ends do not meet (drift 1.9e-4 here): v left M(q)⁻¹p, and H = ½pᵀv was not the energy
    of the states — the balance reported 1.2e-6 with the output, 3e-15 without. The velocities
    are checked against M(q)⁻¹p from the states, H against ½pᵀM⁻¹p, both to round-off; the
    balance to 1e-13 of the energy scale (151 steps, each balanced to 2e-15 of it)."""
    text = BEAD + ("  outputs: {energy: H, radius: rod.r}\n" if outputs else "")
    path = tmp_path / "bead.yaml"
    path.write_text(text)
    compiled = phc.compile_model(path, certify=False)
    run = phc.simulate(compiled, solver="discrete_gradient", step=0.01)
    assert run.success, run.message
    names = list(run.variables)
    col = {n: np.asarray(run.y)[:, names.index(n)] for n in ("rod.r", "rod.p_vr", "rod.p_om", "rod.vr", "rod.om")}
    m, J = 0.5, 0.02
    inertia = J + m * col["rod.r"] ** 2
    assert np.abs(col["rod.vr"] - col["rod.p_vr"] / m).max() < 1e-13
    assert np.abs(col["rod.om"] - col["rod.p_om"] / inertia).max() < 1e-13 * 2.0
    energy = 0.5 * col["rod.p_vr"] ** 2 / m + 0.5 * col["rod.p_om"] ** 2 / inertia
    assert np.abs(np.asarray(run.H) - energy).max() < 1e-13 * energy.max()
    assert run.energy_balance_relative < 1e-13, run.energy_balance_relative
    # the motion itself (second order, h = 0.01): r = r0 cosh(Ωt) within the midpoint-rule error
    r = 0.1 * np.cosh(2.0 * np.asarray(run.t))
    assert np.abs(col["rod.r"] - r).max() < 1e-3 * r.max()
