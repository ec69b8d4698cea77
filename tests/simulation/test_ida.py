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


# ---------------------------------------------------------------------------------------
# IDA calls the residual through phc's ctypes callback (_IdaCounters.install_residual)

def _tiny_solver(calls):
    """A scikit-SUNDAE IDA solver of y' = −y (two components), started, and its counters."""
    from sksundae.ida import IDA

    def resfn(t, y, yp, r):
        calls.append("wrapper")
        r[:] = yp + y

    def jacfn(t, y, yp, r, cj, J):  # (IDA's difference quotients would call the residual too)
        J[:] = (cj + 1.0) * np.eye(2)

    solver = IDA(resfn, rtol=1e-8, atol=1e-10, linsolver="dense", jacfn=jacfn)
    start = solver.init_step(0.0, np.ones(2), -np.ones(2))
    counters = _IdaCounters.attach(solver, 2, int(start.nfev))
    assert counters is not None and counters.can_advance
    return solver, counters


def _residual_fields(counters):
    import ctypes

    word = ctypes.c_void_p.from_address
    return [word(counters.mem.value + off).value for off in counters._residual[2]]


def test_ida_calls_the_residual_through_phcs_callback_and_gets_its_own_back():
    calls = []
    solver, counters = _tiny_solver(calls)

    def direct(t, y, yp, r):
        calls.append("direct")
        r[:] = yp + y

    assert counters.install_residual(direct, 2)
    replaced = counters._residual[1]
    fields = _residual_fields(counters)
    assert len(fields) == 2 and replaced not in fields  # ida_res and the nonlinear solver's nls_res
    status, t = counters.advance(1.0)
    assert status >= 0 and t == 1.0
    assert set(calls) == {"direct"} and len(calls) == counters.residual_evaluations()
    assert counters.direct_residual
    assert np.allclose(counters.y, np.exp(-1.0), rtol=1e-6)
    offsets = counters._residual[2]
    counters.restore_residual()
    import ctypes

    assert [ctypes.c_void_p.from_address(counters.mem.value + off).value for off in offsets] == [replaced] * 2
    calls.clear()
    solver.step(1.5, method="normal")  # scikit-SUNDAE's own wrapper again
    assert calls and set(calls) == {"wrapper"}


def test_a_callback_ida_does_not_call_is_taken_back_after_the_first_chunk():
    """If the field taken for the nonlinear solver's copy were not the one IDA calls, the
    first chunk's residual evaluations would bypass the callback: it is then removed."""
    import ctypes

    calls = []
    _solver, counters = _tiny_solver(calls)
    def direct(t, y, yp, r):
        calls.append("direct")
        r[:] = yp + y

    assert counters.install_residual(direct, 2)
    callback, replaced, offsets, _seen = counters._residual
    ctypes.c_void_p.from_address(counters.mem.value + offsets[1]).value = replaced  # as if the wrong field
    status, _t = counters.advance(0.5)
    assert status >= 0 and not counters.direct_residual
    assert "direct" not in calls and np.allclose(counters.y, np.exp(-0.5), rtol=1e-6)


def test_the_callback_is_not_installed_where_the_layout_is_not_recognised(monkeypatch):
    calls = []
    _solver, counters = _tiny_solver(calls)
    monkeypatch.setattr(_IdaCounters, "_SCAN", _IdaCounters._USER + 8)  # the nonlinear solver's copy not found
    assert not counters.install_residual(lambda *args: None, 2)
    assert not counters.direct_residual
    counters._aux = 1  # a user-data word that is not scikit-SUNDAE's AuxData object
    monkeypatch.undo()
    assert not counters.install_residual(lambda *args: None, 2)
    status, _t = counters.advance(0.5)
    assert status >= 0 and set(calls) == {"wrapper"}


def test_the_direct_callback_integrates_exactly_as_scikit_sundaes_wrapper(monkeypatch):
    """Same residual on the same vectors: the same steps and the same numbers, bit for bit
    (the shipped pendulum, an index-2 system with its constraint)."""
    compiled = phc.compile_model(MODELS / "pendulum.yaml", certify=False, backend="numpy")
    installed = []
    install = _IdaCounters.install_residual

    def spy(self, resfn, n):
        installed.append(install(self, resfn, n))
        return installed[-1]

    monkeypatch.setattr(_IdaCounters, "install_residual", spy)
    direct = phc.simulate(compiled, t_end=2.0, n_out=41, rtol=1e-8, atol=1e-8)
    assert direct.success and installed == [True]
    monkeypatch.setattr(_IdaCounters, "install_residual", lambda self, resfn, n: False)
    wrapped = phc.simulate(compiled, t_end=2.0, n_out=41, rtol=1e-8, atol=1e-8)
    assert wrapped.success
    assert np.array_equal(direct.y, wrapped.y)
    assert (direct.steps, direct.n_residual_evals, direct.n_jacobian_evals) == \
        (wrapped.steps, wrapped.n_residual_evals, wrapped.n_jacobian_evals)


def test_a_sigint_while_ida_steps_is_taken_between_chunks_without_a_traceback(oscillator, monkeypatch, capfd):
    """SIGINT delivered while IDA is inside phc's residual callback: noted by the run's own
    handler, raised between chunks as an interrupt (outputs kept, checked against the
    closed form), nothing printed by ctypes, and Python's default handler back afterwards."""
    import signal

    # The run installs its handler only where SIGINT has Python's default handler and is
    # delivered: set that up, as a user's process has it (libraries that earlier tests ran —
    # thread and process pools — may leave SIGINT blocked or handled otherwise in this process).
    blocked = signal.pthread_sigmask(signal.SIG_UNBLOCK, {signal.SIGINT})
    previous = signal.signal(signal.SIGINT, signal.default_int_handler)
    try:
        _interrupt_during_ida(oscillator, monkeypatch, capfd)
    finally:
        signal.signal(signal.SIGINT, previous)
        signal.pthread_sigmask(signal.SIG_SETMASK, blocked)


def _interrupt_during_ida(oscillator, monkeypatch, capfd):
    import signal

    calls = {"n": 0}
    residual = oscillator.module.residual

    def signalling(*args):
        calls["n"] += 1
        if calls["n"] == 400:
            signal.raise_signal(signal.SIGINT)  # the handler runs here, inside the callback
        return residual(*args)

    monkeypatch.setattr(oscillator.module, "residual", signalling)
    with pytest.raises(SimulationInterrupted) as info:
        phc.simulate(oscillator, solver="ida")
    result = info.value.result
    assert result.interrupted and result.message.startswith("interrupted at t = ")
    assert calls["n"] > 400  # the callback finished its evaluation and IDA its chunk
    assert 0 < result.t[-1] < 10 and np.abs(result["x"] - _closed_form(result.t)).max() < 1e-6
    assert "Exception ignored" not in capfd.readouterr().err
    assert signal.getsignal(signal.SIGINT) is signal.default_int_handler


def test_a_trial_point_the_model_cannot_be_evaluated_at_is_retried_with_a_shorter_step():
    """A model error at IDA's trial point is a recoverable failure (the callback returns 1):
    IDA retries shorter and the run goes on. Here y' = −y refuses, once, to be evaluated
    beyond t = 0.3 — as a long trial step overshooting into a region the solution never
    reaches would; the run still meets the closed form. (A solution that runs into the edge
    of the domain: tests/test_cli_faults.py.)"""
    from phc.simulation.guard import ModelEvaluationError

    calls = []
    _solver, counters = _tiny_solver(calls)
    refused = []

    def once(t, y, yp, r):
        if t > 0.3 and not refused:
            refused.append(t)
            raise ModelEvaluationError(f"cannot be evaluated at t = {t}", function="residual", t=t)
        r[:] = yp + y

    assert counters.install_residual(once, 2)
    status, t = counters.advance(1.0)
    assert refused and status >= 0 and t == 1.0
    assert counters.failures[0] == 1 and np.allclose(counters.y, np.exp(-1.0), rtol=1e-6)

