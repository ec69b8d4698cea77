"""Tests of `phc.simulation.midpoint4` (triple-jump composition of the midpoint rule, order 4)."""

from pathlib import Path

import numpy as np
import pytest

import phc
from phc.simulation.midpoint4 import GAMMA1, GAMMA2
from rigid_cases import bead_on_turned_rod

MODELS = Path(__file__).resolve().parents[2] / "models"


def test_triple_jump_coefficients():
    assert abs(2 * GAMMA1 + GAMMA2 - 1.0) < 1e-15  # consistent
    assert abs(2 * GAMMA1**3 + GAMMA2**3) < 1e-14  # third-order error term cancels
    assert GAMMA2 < 0


def test_fourth_order_convergence_to_the_closed_form():
    """Damped oscillator: the backward middle substep does not spoil order or stability."""
    compiled = phc.compile_model(MODELS / "mass_spring_damper.yaml")
    w = np.sqrt(3.96)
    errors = []
    for step in (0.05, 0.025, 0.0125):
        r = phc.simulate(compiled, solver="midpoint4", step=step, t_end=10.0, n_out=11)
        assert r.success
        exact = 0.5 * np.exp(-0.2 * r.t) * (np.cos(w * r.t) + 0.2 / w * np.sin(w * r.t))
        errors.append(np.abs(r["x"] - exact).max())
    orders = np.log2(np.array(errors[:-1]) / np.array(errors[1:]))
    assert np.all(np.abs(orders - 4.0) < 0.3)  # 3.97, 3.99 measured
    assert errors[-1] < 1e-7


def test_damped_oscillator_decays_at_large_steps():
    compiled = phc.compile_model(MODELS / "mass_spring_damper.yaml")
    for step in (1.0, 5.0):
        r = phc.simulate(compiled, solver="midpoint4", step=step, t_end=100.0, n_out=11)
        assert r.success
        assert np.all(np.diff(r.H) <= 1e-15) and r.H[-1] < r.H[0]
        assert r.energy_balance_relative < 1e-13


def test_energy_balance_exact_for_a_lossless_model_at_large_steps():
    """Quadratic H: every substep is energy exact, so the composite step is."""
    compiled = phc.compile_model(MODELS / "mass_spring_damper.yaml")
    for step in (0.3, 2.0):
        r = phc.simulate(compiled, solver="midpoint4", step=step, t_end=200.0, n_out=11, params={"c": 0.0})
        assert r.success
        assert r.energy_balance_relative < 1e-13
        assert abs(r.H[-1] - r.H[0]) < 1e-13 * r.H[0]
    string = phc.compile_model(MODELS / "vibrating_string.yaml")
    r = phc.simulate(string, solver="midpoint4", step=1e-4, n_out=11)
    assert r.success and r.energy_balance_relative < 1e-12


def test_pendulum_constraints_do_not_drift():
    """Position constraints at every substep end: no drift over many periods, fourth order in
    the positions."""
    compiled = phc.compile_model(MODELS / "pendulum.yaml")
    r = phc.simulate(compiled, solver="midpoint4", step=0.05, t_end=200.0, n_out=201)
    assert r.success
    assert r.constraint_drift < 1e-10
    assert np.abs(r["rod_length_error"]).max() < 1e-10
    assert r.energy_balance_relative < 1e-10  # H and the constraint are quadratic
    fine = phc.simulate(compiled, solver="midpoint4", step=0.0025, t_end=2.0, n_out=11)
    errors = [np.abs(phc.simulate(compiled, solver="midpoint4", step=h, t_end=2.0, n_out=11)["pendulum.x"]
                     - fine["pendulum.x"]).max() for h in (0.02, 0.01)]
    assert 3.6 < np.log2(errors[0] / errors[1]) < 4.4


def test_one_newton_matrix_per_substep_size():
    """The two substep sizes keep their own factorizations: far fewer than substeps."""
    compiled = phc.compile_model(MODELS / "flexible_slider_crank.yaml")
    r = phc.simulate(compiled, solver="midpoint4", step=1e-4, t_end=0.02, n_out=3)
    assert r.success
    assert r.n_jacobian_evals < 0.25 * 3 * r.steps  # 88 factorizations for 600 substeps measured
    assert r.energy_balance_relative < 1e-12 and r.constraint_drift < 1e-12


def test_error_estimate_uses_order_4():
    from phc.study.accuracy import temporal_estimate

    compiled = phc.compile_model(MODELS / "mass_spring_damper.yaml")
    kwargs = dict(solver="midpoint4", step=0.05, t_end=5.0, n_out=11)
    r = phc.simulate(compiled, **kwargs)
    est = temporal_estimate(compiled, r, kwargs)
    assert "order 4" in est.method
    w = np.sqrt(3.96)
    exact = 0.5 * np.exp(-0.2 * r.t) * (np.cos(w * r.t) + 0.2 / w * np.sin(w * r.t))
    true = np.abs(r["x"] - exact).max()
    assert true / 3 < est.per_output["x"] < 3 * true


def test_a_step_in_the_unstable_band_of_a_damped_mode_is_refused(tmp_path):
    """c = 100: an overdamped mode λ ≈ −100. At h = 0.0115 (h·|λ| ≈ 1.15, inside the
    composition's unstable disk) the run stops before starting with a message naming the mode;
    at h = 0.01 it runs and matches IDA."""
    src = (Path(__file__).resolve().parents[2] / "models" / "mass_spring_damper.yaml").read_text()
    model = tmp_path / "stiff_damper.yaml"
    model.write_text(src.replace("c: {value: 0.4", "c: {value: 100.0"))
    compiled = phc.compile_model(model)
    bad = phc.simulate(compiled, solver="midpoint4", step=0.0115, t_end=2.0, n_out=3)
    assert not bad.success
    assert "unstable band" in bad.message and "-99.9" in bad.message and "change `step`" in bad.message
    good = phc.simulate(compiled, solver="midpoint4", step=0.01, t_end=2.0, n_out=3)
    ref = phc.simulate(compiled, t_end=2.0, n_out=3, rtol=1e-12, atol=1e-14)
    assert good.success
    assert np.abs(good.y[-1] - ref.y[-1]).max() < 1e-6


BEAD_ON_TURNED_ROD = bead_on_turned_rod(n_out=16)


def test_positions_of_order_four_and_constrained_momenta_of_order_two(tmp_path):
    """A bead sliding freely on a rod turned at the prescribed rate Ω (M(q), the rheonomic
    constraint θ = Ωt; closed form r = r₀ cosh Ωt, p_θ = (J + m r²)Ω). The velocity constraint
    holds at the midpoint substeps' step points, not at the step ends, so the momentum along it
    is second order at the ends while the positions are fourth order (docs/how-to/solvers.md,
    "No constraint drift"). Observed orders from halving h twice: each error ratio is 2^order
    up to the next term of the expansion (asserted ≥ 2^order·0.8: 12.8 and 3.2)."""
    path = tmp_path / "bead.yaml"
    path.write_text(BEAD_ON_TURNED_ROD)
    compiled = phc.compile_model(path, certify=False)
    m, J, Om, r0 = 0.5, 0.02, 2.0, 0.1
    errors = []
    for h in (0.01, 0.005, 0.0025):
        run = phc.simulate(compiled, solver="midpoint4", step=h)
        assert run.success, run.message
        names = list(run.variables)
        y = np.asarray(run.y)
        r, p_th = y[:, names.index("rod.r")], y[:, names.index("rod.p_om")]
        exact = r0 * np.cosh(Om * np.asarray(run.t))
        errors.append((np.abs(r - exact).max(), np.abs(p_th - (J + m * exact**2) * Om).max()))
    errors = np.array(errors)
    ratios = errors[:-1] / errors[1:]
    assert (ratios[:, 0] > 0.8 * 16).all(), ratios
    assert (ratios[:, 1] > 0.8 * 4).all(), ratios


# ---------------------------------------------------------------------------------------------------
# the passivity guard's round-off floor, on the three step loops (the Python loop, numba's, steps.c's)

def _loop_model(tmp_path, text, backend):
    """`text` compiled for `backend` (numpy: the Python loop; numba, c: their compiled loops), or a skip."""
    if backend == "numba":
        from phc.codegen.numba_backend import available
    elif backend == "c":
        from phc.codegen.c_backend import available
    else:
        available = None
    if available is not None:
        ok, why = available()
        if not ok:
            pytest.skip(f"the {backend} step loop is not available: {why}")
    path = tmp_path / f"model_{backend}.yaml"
    path.write_text(text)
    model = phc.compile_model(path, certify=False, backend=backend)
    assert model.backend == backend
    return model


@pytest.fixture
def step_loops(monkeypatch):
    """Per call of compiled_steps.integrate: the loop that ran the piece ("c", "numba"), None for Python's."""
    from phc.simulation import compiled_steps

    seen = []
    original = compiled_steps.integrate

    def spy(*args, **kwargs):
        out = original(*args, **kwargs)
        seen.append(None if out is None else out["step_loop"])
        return out

    monkeypatch.setattr(compiled_steps, "integrate", spy)
    return seen


LOOPS = (("numpy", None), ("numba", "numba"), ("c", "c"))


@pytest.mark.parametrize("backend, loop", LOOPS, ids=[b for b, _ in LOOPS])
@pytest.mark.parametrize("c, t_end", [(0.4, 0.5), (4.0, 1.0)], ids=["stuck", "stick-slip"])
def test_a_driven_block_that_sticks_passes_the_passivity_guard(tmp_path, step_loops, backend, loop, c, t_end):
    """The block of test_events.py pushed by c·t against Coulomb friction F_c = 3 (m = 2): stuck
    (v = 0, no power dissipated) until t* = F_c/c, then m v̇ = c (t − t*), v = c (t − t*)²/(2m).
    While it sticks its energy scale is H ≈ 1e-73 and the dissipated power round-off (±4e-54):
    against a floor of 1e-13 times the state's energy scale alone, midpoint4's passivity guard
    rejected such steps: the numba loop stopped ("the resistive ports supply power") at t = 0.3125
    (c = 0.4), the numba and the C loop at t = 0.745 (c = 4). With the run's energy scale in the
    floor (scaling.run_energy) no step is rejected, on every loop.

    Closed form: ṗ = c t − F_c is linear in t, which the composition of order 4 integrates
    exactly; the slip is located to EVENT_TOL = 1e-12·max(1, t) in time (regula falsi on a
    switching function linear in t), which moves v by at most (c/m)(t − t*)·1e-12 ≤ 1e-12; the
    rest is round-off of a few hundred steps (1e-13 allowed, v ≤ 0.125)."""
    from test_events import PUSHED

    model = _loop_model(tmp_path, PUSHED.format(force="c*t").replace("c: 4.0", f"c: {c}"), backend)
    r = phc.simulate(model, solver="midpoint4", step=1e-3, t_end=t_end)
    assert r.success, r.message
    assert "needed a restart or a split" not in r.message, r.message  # no step rejected and retried
    assert step_loops and set(step_loops) == {loop}
    m, fc = 2.0, 3.0
    t_star = fc / c
    if t_star < t_end:
        assert [(e.kind, e.direction) for e in r.events] == [("stick", 0), ("slip", 1)]
        assert abs(r.events[1].t - t_star) <= 2e-12
    else:
        assert [(e.kind, e.direction) for e in r.events] == [("stick", 0)]
    stuck = r.t < t_star
    assert np.abs(r["v"][stuck]).max() < 1e-12  # sticking is exact
    exact = np.where(stuck, 0.0, c * (r.t - t_star) ** 2 / (2 * m))
    assert np.abs(r["v"] - exact).max() < 1e-12


ACTIVE = """\
format_version: 1
name: negative_damper
parameters:
  m: 1.0
  k: 4.0
  d: 0.5
components:
  osc:
    type: phs
    states: [p, x]
    hamiltonian: p**2/(2*m) + k*x**2/2
    resistive:
      dmp: {law: [e_dmp = -d*f_dmp]}
    relations:
      - f_x = e_p
      - f_p = -e_x - e_dmp
      - f_dmp = e_p
simulation:
  t_end: 1.0
  n_out: 11
  initial: {osc.x: 1.0, osc.p: 0.0}
"""
"""An oscillator with a damper of negative coefficient (ṗ = −k x + d v): an active model, its
"dissipated" power −d v² < 0."""


@pytest.mark.parametrize("backend, loop", LOOPS, ids=[b for b, _ in LOOPS])
def test_the_guard_still_rejects_a_negative_damper(tmp_path, step_loops, backend, loop):
    """The floor is round-off of the run's energy (1e-13 · H ≈ 2e-13), far below a negative
    damper's −d v² h per step (≈ 5e-4·v² at h = 1e-3, with v of order one once it moves): every loop
    rejects the step where the block moves and says that the resistive ports supply power."""
    model = _loop_model(tmp_path, ACTIVE, backend)
    r = phc.simulate(model, solver="midpoint4", step=1e-3)
    assert not r.success
    assert "resistive ports supply power" in r.message and "PHC-E451" in r.message
    assert step_loops and step_loops[0] == loop
