"""IDA on stiff, undamped distributed models (issue 38 item 2).

An Euler–Bernoulli beam of 1 000 elements took ~10⁴ IDA steps per microsecond. Measured (the
numbers are in docs/how-to/solvers.md): the iteration matrix is reused as SUNDIALS intends —
Newton converges in about one iteration a step and a new matrix comes only with a change of
IDA's ``cj = α/h`` beyond the band ``[0.6, 5/3]`` of the last one — and the cost is the step
size itself: at BDF orders 3–5, which are not stable along part of the imaginary axis, IDA
holds its step where ``ω_max·h`` is about 0.6 (BDF5 is stable there below 0.71), whatever
the tolerances. What phc owes the user is to say so, also for models too large for a dense
eigenvalue computation, and to count the work of a run that stopped.

References: the Jacobian's consistency with the residual is checked through IDA's own
behaviour on a linear model (no refactorization that only a Newton failure explains); the
sparse mode search against the dense QZ of the same linearization (an independent method).
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

import phc
import phc.simulation as sim
from phc.options import RunOptions
from phc.simulation import ida as ida_module
from phc.simulation import monitor
from phc.simulation import parameter_vector
from phc.simulation.ida import integrate_ida
from phc.simulation.initial import consistent_initial_conditions

MODELS = Path(__file__).resolve().parents[2] / "models"

BAND = 0.6
"""IDA forms a new iteration matrix when ``cj/cj_old`` leaves ``[0.6, 1/0.6]`` (SUNDIALS'
``(1 − XRATE)/(1 + XRATE)`` with XRATE = 0.25, the Newton contraction its design assumes), or
after a failed Newton iteration, or at the start."""


def _beam(tmp_path, elements: int):
    text = (MODELS / "euler_bernoulli_beam.yaml").read_text().replace("elements: 6", f"elements: {elements}")
    path = tmp_path / f"beam{elements}.yaml"
    path.write_text(text)
    return phc.compile_model(path, certify=False)


def _recorded(monkeypatch):
    """Wrap the callbacks IDA gets: each residual evaluation ('r', t), each Jacobian ('j', t, cj)."""
    log = []
    original = ida_module._callbacks

    def recording(mod, p, n, sparse):
        resfn, jacfn, state = original(mod, p, n, sparse)

        def res(t, y, yp, out):
            log.append(("r", t))
            resfn(t, y, yp, out)

        def jac(t, y, yp, out, cj, JJ):
            log.append(("j", t, cj))
            jacfn(t, y, yp, out, cj, JJ)

        return res, jac, state

    monkeypatch.setattr(ida_module, "_callbacks", recording)
    return log


@pytest.mark.parametrize("elements", [6, 16])  # 55 unknowns (dense LU) and 135 (sparse LU)
def test_the_iteration_matrix_is_renewed_only_when_cj_leaves_idas_band(tmp_path, monkeypatch, elements):
    """On the (linear) undamped beam with its tight tolerances (rtol 1e-8: IDA's local
    5e-11), Newton converges with the matrix of an earlier step as IDA's design expects: a
    matrix whose cj lies within IDA's band of the last one is formed only when a Newton
    iteration failed, and with an exact Jacobian of a linear model that happens at most in
    round-off-dominated corners — not once every few steps (the run of issue 38 formed a
    matrix every 2.5 residual evaluations). Most steps need one residual evaluation."""
    compiled = _beam(tmp_path, elements)
    log = _recorded(monkeypatch)
    result = phc.simulate(compiled, solver="ida", t_end=2e-3, max_steps=4000, max_order=5)
    steps = result.steps
    assert steps > 500, result.message
    cjs = [e[2] for e in log if e[0] == "j"]
    residuals = sum(1 for e in log if e[0] == "r")
    assert result.n_jacobian_evals == len(cjs) and result.n_residual_evals == residuals
    in_band = sum(1 for a, b in zip(cjs, cjs[1:]) if BAND < b / a < 1 / BAND)
    # a Newton failure forcing a new matrix in one step of a hundred would already be a
    # malfunction (a Jacobian inconsistent with the residual, or tolerances below round-off)
    assert in_band <= steps // 100, (in_band, steps)
    assert len(cjs) <= steps // 10, (len(cjs), steps)
    assert residuals < 1.5 * steps


def test_a_run_stopped_at_max_steps_reports_its_work():
    """The counts come from the callbacks: a run that IDA leaves inside a call (the step hook's
    max_steps) reported the counts of the last call that returned (0 with one output
    interval). The first 123 steps are those of the full run, so their work is part of it."""
    compiled = phc.compile_model(MODELS / "mass_spring_damper.yaml", certify=False)
    mod = compiled.module
    p = parameter_vector(mod)
    index = {n: j for j, n in enumerate(mod.VARIABLES)}
    values = {index[iv.name]: iv.value for iv in compiled.dae.initial}
    values[index["energy.supplied"]] = 0.0
    init = consistent_initial_conditions(mod, p, 0.0, values, set(values))
    t_out = np.array([0.0, 3.0])  # one IDA call: nothing returns before the stop
    full = integrate_ida(mod, p, t_out, init.y0, init.yp0, RunOptions(rtol=1e-9, atol=1e-11, max_steps=100_000))
    run = integrate_ida(mod, p, t_out, init.y0, init.yp0, RunOptions(rtol=1e-9, atol=1e-11, max_steps=123))
    assert full["success"] and not run["success"] and run["steps"] == 123
    assert 123 <= run["nfev"] < full["nfev"] and 1 <= run["njev"] <= full["njev"]
    assert run["max_steps_reached"] and 0 < run["t_reached"] < 3.0
    assert not full["max_steps_reached"] and full["t_reached"] == 3.0


def _start_of(compiled):
    """The model and its consistent start (as phc.simulate finds it)."""
    mod = compiled.module
    result = phc.simulate(compiled, solver="ida", t_end=1e-6, n_out=2)
    return mod, parameter_vector(mod), 0.0, np.array(result.y[0]), np.array(result.yp[0])


def test_the_sparse_mode_search_finds_the_modes_of_the_dense_qz():
    """undamped_modes_near (ARPACK, shift-invert at iω) against undamped_modes (dense QZ) on
    the 6-element beam: each mode it returns is one of the QZ's, to ARPACK's tolerance
    (a Ritz value ν = 1/(λ − iω) to NEAR_TOL relative gives λ to NEAR_TOL·|λ − iω|), and the
    QZ's mode nearest iω is among them."""
    compiled = phc.compile_model(MODELS / "euler_bernoulli_beam.yaml", certify=False)
    mod, p, t, y, yp = _start_of(compiled)
    dense = monitor.undamped_modes(mod, p, t, y, yp)
    assert dense is not None and len(dense) > 8
    for target in (1.05 * dense[0], 0.97 * dense[3], 1.02 * dense[len(dense) // 2]):
        near = monitor.undamped_modes_near(mod, p, t, y, yp, target)
        assert near is not None and len(near) > 0
        for w in near:
            assert np.abs(dense - w).min() <= 2 * monitor.NEAR_TOL * abs(w - target) + 1e-9 * w, (w, target)
        nearest = dense[np.argmin(np.abs(dense - target))]
        assert np.abs(near - nearest).min() <= 2 * monitor.NEAR_TOL * abs(nearest - target) + 1e-9 * nearest


def test_a_large_model_that_uses_up_max_steps_is_told_of_its_undamped_modes(monkeypatch):
    """A run that stops at max_steps with steps that leave lightly damped modes unresolved at
    a BDF order above 2 is told to use max_order 2, also where the model is too large for the
    dense QZ (here forced by MODES_MAX = 0: the sparse search near 1/h). It used to be told
    that no undamped mode was left unresolved, without any mode computed. The frequency it
    names is one of the linearization's (dense QZ), with ω·h above UNRESOLVED. max_order 4:
    BDF4 amplifies an undamped mode at every ωh (at order 5 and this ωh, ~0.15, BDF5 is stable
    and the advice is another one: the test below)."""
    compiled = phc.compile_model(MODELS / "euler_bernoulli_beam.yaml", certify=False)
    mod, p, t, y, yp = _start_of(compiled)
    dense = monitor.undamped_modes(mod, p, t, y, yp)
    monkeypatch.setattr(monitor, "MODES_MAX", 0)
    assert monitor.undamped_modes(mod, p, t, y, yp) is None
    run = phc.simulate(compiled, solver="ida", rtol=1e-6, t_end=2e-3, max_order=4, max_steps=400)
    assert not run.success and "(max_steps)" in run.message, run.message
    assert f"IDA took {run.steps} steps" in run.message
    h = float(run.message.split("(mean step ")[1].split(")")[0])
    assert dense[0] * h > monitor.UNRESOLVED  # the case the hint is for (else the test says nothing)
    assert "undamped oscillations up to ω ≈" in run.message and "`max_order: 2`" in run.message
    w = float(run.message.split("up to ω ≈ ")[1].split(" rad/s")[0])
    assert np.abs(dense - w).min() <= 0.01 * w and w * h > monitor.UNRESOLVED
    # at max_order 2 (A-stable) the modes are not the limit: no advice to change the order
    run2 = phc.simulate(compiled, solver="ida", rtol=1e-6, t_end=2e-3, max_order=2, max_steps=400)
    assert "(max_steps)" in run2.message and f"IDA took {run2.steps} steps" in run2.message
    assert "`max_order: 2`" not in run2.message


def test_the_hint_claims_nothing_about_modes_it_could_not_compute(monkeypatch):
    """Where neither search answers, the hint names the error test without claiming that no
    undamped mode is unresolved."""
    compiled = phc.compile_model(MODELS / "euler_bernoulli_beam.yaml", certify=False)
    monkeypatch.setattr(monitor, "MODES_MAX", 0)
    monkeypatch.setattr(monitor, "undamped_modes_near", lambda *args, **kwargs: None)
    run = phc.simulate(compiled, solver="ida", rtol=1e-6, t_end=2e-3, max_order=5, max_steps=200)
    assert "(max_steps)" in run.message
    assert "could not be computed" in run.message and "no undamped mode" not in run.message
    assert sim.MANY_STEPS > 200  # the hint came from the stop, not from the step count


OSCILLATOR = """\
format_version: 1
name: oscillator
parameters: {m: 1.0, k: 4.0}
components:
  mass: {type: mass, m: m}
  spring: {type: spring, k: k}
connections:
  - [mass.port, spring.port]
simulation:
  t_end: 10.0
  initial: {spring.x: 0.5}
"""


def test_steps_that_bdf5_keeps_stable_are_not_told_to_use_max_order_2(tmp_path):
    """The hint said "`max_order: 2` … steps over them" wherever ω·h > UNRESOLVED at order 5,
    also below HELD, where BDF5 is stable for the mode and IDA can still double its step: the
    steps are the error test's, and BDF2 (second order) needs more of them. A 16-element
    cantilever with a tip mass (978 824 steps at order 5 over 0.05 s) was told so, and at
    max_order 2 took 10⁶ steps for its first 0.0047 s. Here an undamped oscillator
    (ω = sqrt(k/m) = 2 rad/s, the closed form) run by IDA at orders 5 and 2 with the same
    tolerances: order 2 takes more steps, and the hint for order 5's mean step (ωh between
    UNRESOLVED and HELD, asserted) names the mode and does not advise max_order 2; at
    max_order 4 (BDF4 amplifies undamped modes at every ωh) it still does."""
    from phc.simulation.order import HELD

    path = tmp_path / "oscillator.yaml"
    path.write_text(OSCILLATOR)
    compiled = phc.compile_model(path, certify=False)
    rtol, atol = 1e-4, 1e-6
    five = phc.simulate(compiled, solver="ida", rtol=rtol, atol=atol, max_order=5)
    two = phc.simulate(compiled, solver="ida", rtol=rtol, atol=atol, max_order=2)
    assert five.success and two.success
    assert two.steps > five.steps, (two.steps, five.steps)  # the advice max_order 2 would cost steps here
    mod, p = compiled.module, parameter_vector(compiled.module)
    y, yp = np.asarray(five.y), np.asarray(five.yp)
    omega = 2.0  # sqrt(k/m)
    h = 10.0 / five.steps
    assert monitor.UNRESOLVED < omega * h <= HELD, omega * h  # the window the fix is about
    hint = monitor.many_steps_hint(mod, p, five.t[[0, -1]], y[[0, -1]], yp[[0, -1]], steps=five.steps,
                                   span=10.0, max_order=5, rtol=rtol, atol=atol)
    assert "`max_order: 2` would make them shorter" in hint and "steps over them" not in hint, hint
    w = float(hint.split("up to ω ≈ ")[1].split(" rad/s")[0])
    assert abs(w - omega) <= 0.01 * omega  # printed to 2 digits
    four = monitor.many_steps_hint(mod, p, five.t[[0, -1]], y[[0, -1]], yp[[0, -1]], steps=five.steps,
                                   span=10.0, max_order=4, rtol=rtol, atol=atol)
    assert "`max_order: 2` or a fixed-step solver" in four, four
