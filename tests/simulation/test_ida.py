"""IDA integrated in its normal mode (:mod:`phc.simulation.ida`): the same solution as
driving it one step at a time, IDA's own step count, and what a run stopped mid-way keeps.

The reference of the first test is the way phc drove IDA before (one internal step per
Python call, ``method="onestep"``, the output times filled by IDA's interpolation inside
the last step), written out here with scikit-sundae directly; both must meet the closed
form of the damped oscillator."""

from __future__ import annotations

import math
import warnings
from pathlib import Path

import numpy as np
import pytest

import phc
from phc.simulation import SimulationInterrupted, parameter_vector
from phc.simulation import ida as ida_module
from phc.simulation.ida import _IdaCounters, integrate_ida, solver_options
from phc.simulation.initial import consistent_initial_conditions

MODELS = Path(__file__).resolve().parents[2] / "models"


@pytest.fixture(scope="module")
def oscillator():
    return phc.compile_model(MODELS / "mass_spring_damper.yaml", certify=False)


def _start(compiled):
    mod = compiled.module
    p = parameter_vector(mod)
    index = {n: j for j, n in enumerate(mod.VARIABLES)}
    values = {index[iv.name]: iv.value for iv in compiled.dae.initial}
    values[index["energy.supplied"]] = 0.0
    init = consistent_initial_conditions(mod, p, 0.0, values, set(values))
    return mod, p, init


def _closed_form(t, m=1.0, k=4.0, c=0.4, x0=0.5):
    w0 = math.sqrt(k / m)
    zeta = c / (2 * math.sqrt(k * m))
    wd = w0 * math.sqrt(1 - zeta**2)
    return np.exp(-zeta * w0 * t) * (x0 * np.cos(wd * t) + zeta * w0 * x0 / wd * np.sin(wd * t))


def _onestep_reference(mod, p, t_out, y0, yp0, rtol, atol):
    """phc's former loop: one internal step per call, outputs interpolated inside it (with the
    options `integrate_ida` sets: local tolerances, index-1 algebraic variables tested, their
    rates at the start)."""
    from sksundae.ida import IDA

    from phc.simulation.ida import LOCAL_TOLERANCE, algebraic_rates, determined_algebraic

    determined = determined_algebraic(mod, p, t_out[0], y0, yp0)
    yp0 = algebraic_rates(mod, p, t_out[0], y0, yp0, determined)
    options, _ = solver_options(mod, p, rtol=rtol * LOCAL_TOLERANCE, atol=atol * LOCAL_TOLERANCE,
                                determined=determined)
    with warnings.catch_warnings():  # scikit-sundae's note that our Jacobian replaces its approximation
        warnings.simplefilter("ignore", UserWarning)
        solver = IDA(options.pop("resfn"), **options)
    solver.init_step(t_out[0], y0, yp0)
    ys = [np.asarray(y0, dtype=float)]
    k, t_end, steps, t_last = 1, t_out[-1], 0, t_out[0]
    while k < len(t_out):
        res = solver.step(t_end, method="onestep", tstop=t_end)
        assert res.success, res.message
        if res.t != t_last:  # a onestep call after an interpolation may return without stepping
            steps, t_last = steps + 1, res.t
        while k < len(t_out) and t_out[k] <= res.t + 1e-14 * max(1.0, abs(res.t)):
            ys.append(solver.step(t_out[k], method="normal").y)
            k += 1
    return np.array(ys), steps


@pytest.mark.parametrize("sparse", [False, True])
def test_normal_mode_equals_the_onestep_loop_and_the_closed_form(oscillator, sparse, monkeypatch):
    if sparse:  # the sparse linear solver on this small system: the same steps, the same numbers
        monkeypatch.setattr(ida_module, "DENSE_LIMIT", 0)
    mod, p, init = _start(oscillator)
    t_out = np.linspace(0.0, 3.0, 61)
    rtol, atol = 1e-9, 1e-11
    run = integrate_ida(mod, p, t_out, init.y0, init.yp0, rtol=rtol, atol=atol, max_steps=100_000)
    ref, ref_steps = _onestep_reference(mod, p, t_out, init.y0, init.yp0, rtol, atol)
    assert run["success"], run["message"]
    assert run["y"].shape == ref.shape
    assert np.abs(run["y"] - ref).max() <= 1e-12 * np.abs(ref).max()
    x = run["y"][:, list(mod.VARIABLES).index("spring.x")]
    assert np.abs(x - _closed_form(t_out)).max() < 1e-7
    # the step count is IDA's own (IDAGetNumSteps where the counters attach)
    assert run["steps"] == ref_steps
    assert run["nfev"] > run["steps"] > 0 and run["njev"] > 0


def test_ida_counters_attach_here(oscillator):
    """The fast path (IDA's counters through SUNDIALS' C API) is the one these tests run."""
    from sksundae.ida import IDA

    mod, p, init = _start(oscillator)
    options, _ = solver_options(mod, p, rtol=1e-8, atol=1e-10)
    solver = IDA(options.pop("resfn"), **options)
    start = solver.init_step(0.0, init.y0, init.yp0)
    counters = _IdaCounters.attach(solver, mod.N, int(start.nfev))
    assert counters is not None
    assert counters.steps() == 0
    solver.step(0.5, method="normal")
    assert counters.steps() > 0 and counters.last_step() > 0
    # attach refuses what is not an IDA solver of this size
    assert _IdaCounters.attach(solver, mod.N + 1, int(start.nfev)) is None
    assert _IdaCounters.attach(object(), mod.N, 0) is None


def test_max_steps_is_honoured_exactly_and_the_outputs_before_are_kept(oscillator):
    mod, p, init = _start(oscillator)
    t_out = np.linspace(0.0, 3.0, 61)
    full = integrate_ida(mod, p, t_out, init.y0, init.yp0, rtol=1e-9, atol=1e-11, max_steps=100_000)
    run = integrate_ida(mod, p, t_out, init.y0, init.yp0, rtol=1e-9, atol=1e-11, max_steps=123)
    assert not run["success"] and "max_steps" in run["message"]
    assert run["steps"] == 123
    kept = len(run["t"])
    assert 1 < kept < len(t_out)
    reached = float(run["message"].split("at t = ")[1].split()[0])
    assert run["t"][-1] <= reached < t_out[kept]
    # what is kept is what the full run computed there
    assert np.array_equal(run["y"], full["y"][:kept])


STATE_MODEL = """\
format_version: 1
name: state_model
components:
  s:
    type: phs
    states: [q]
    hamiltonian: q**2/2 + asin(q)
    J: [[0]]
    R: [[0]]
    ports:
      u:
        domain: electrical
        causality: effort_in
        B: [[1]]
  src: {type: effort_source, domain: electrical, value: 1}
connections:
  - [s.u, src.port]
simulation:
  t_end: 2.0
  n_out: 201
  initial:
    s.q: 0.0
"""
# q' = 1, q(t) = t: the gradient q + 1/sqrt(1 − q²) is not defined from t = 1 on


def test_a_failure_mid_run_keeps_the_outputs_before_it(tmp_path):
    path = tmp_path / "state_model.yaml"
    path.write_text(STATE_MODEL)
    result = phc.simulate(phc.compile_model(path, certify=False), solver="ida")
    assert not result.success
    assert "cannot be evaluated at t = " in result.message and "are kept" in result.message
    assert 1 < len(result.t) < 201 and result.t[-1] <= 1.0
    assert result.t[-1] >= 0.97  # output interval 0.01: no more than a few outputs short of t = 1
    q = result["s.q"]
    assert np.all(np.isfinite(q)) and np.abs(q - result.t).max() < 1e-6


def test_ctrl_c_mid_run_keeps_the_outputs_so_far(oscillator, monkeypatch):
    calls = {"n": 0}
    residual = oscillator.module.residual

    def interrupting(*args):
        calls["n"] += 1
        if calls["n"] == 400:
            raise KeyboardInterrupt
        return residual(*args)

    monkeypatch.setattr(oscillator.module, "residual", interrupting)
    with pytest.raises(SimulationInterrupted) as info:
        phc.simulate(oscillator, solver="ida")
    result = info.value.result
    assert result.interrupted and not result.success and result.message.startswith("interrupted at t = ")
    assert 0 < result.t[-1] < 10 and len(result.t) == len(result.H) == len(result["x"]) > 1
    assert np.abs(result["x"] - _closed_form(result.t)).max() < 1e-6


@pytest.mark.parametrize("monitored", [True, False])
def test_progress_is_reported_per_chunk_in_time_order(oscillator, monitored, monkeypatch):
    if not monitored:  # as for a system too large for the singularity monitor
        from phc.simulation import monitor

        monkeypatch.setattr(monitor, "MAX_SIZE", 0)
    seen = []
    result = phc.simulate(oscillator, solver="ida", t_end=2.0, n_out=5, progress=seen.append)
    assert result.success and result.steps > 2 * ida_module.CHUNK_STEPS
    # with 5 output times, chunks of at most CHUNK_STEPS steps still report progress, and
    # without the monitor's looks IDA takes CHUNK_STEPS steps a call
    assert len(seen) >= result.steps // ida_module.CHUNK_STEPS
    if not monitored:
        assert len(seen) <= result.steps // ida_module.CHUNK_STEPS + 5
    assert seen == sorted(seen) and seen[-1] == pytest.approx(2.0)


def test_without_idas_counters_the_run_is_the_same(oscillator, monkeypatch):
    """Where scikit-sundae's layout is not the expected one the counters do not attach: IDA
    then stops after CHUNK_STEPS steps a call by its constructor's limit, and residual
    evaluations bound the step count (max_steps stops no later than asked)."""
    mod, p, init = _start(oscillator)
    t_out = np.linspace(0.0, 3.0, 61)
    fast = integrate_ida(mod, p, t_out, init.y0, init.yp0, rtol=1e-9, atol=1e-11, max_steps=100_000)
    monkeypatch.setattr(_IdaCounters, "attach", classmethod(lambda cls, *args: None))
    slow = integrate_ida(mod, p, t_out, init.y0, init.yp0, rtol=1e-9, atol=1e-11, max_steps=100_000)
    assert slow["success"], slow["message"]
    assert np.abs(slow["y"] - fast["y"]).max() <= 1e-12 * np.abs(fast["y"]).max()
    assert slow["steps"] >= fast["steps"]
    stopped = integrate_ida(mod, p, t_out, init.y0, init.yp0, rtol=1e-9, atol=1e-11, max_steps=200)
    assert not stopped["success"] and "max_steps" in stopped["message"] and 1 < len(stopped["t"]) < 61


def test_a_successful_run_with_very_many_steps_says_what_may_cost_them(monkeypatch):
    """A free beam spun up took 840 000 IDA steps with `success` and no word; beyond
    MANY_STEPS the message names the likely cause and the remedy."""
    import phc
    import phc.simulation as sim

    compiled = phc.compile_model(MODELS / "mass_spring_damper.yaml", certify=False)
    quiet = phc.simulate(compiled)
    assert quiet.success and quiet.message == "integration finished"
    monkeypatch.setattr(sim, "MANY_STEPS", quiet.steps - 1)
    loud = phc.simulate(compiled)
    assert loud.success and f"IDA needed {quiet.steps} steps" in loud.message
    assert "--solver midpoint" in loud.message
