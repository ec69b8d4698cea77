"""IDA driven one internal step at a time through scikit-sundae's public interface
(:mod:`phc.simulation.ida`): the same solution as scikit-sundae's own ``solve`` (IDA's
normal mode, its loop in C), the step count honoured exactly, and what a run stopped
mid-way keeps. Both must meet the closed form of the damped oscillator."""

from __future__ import annotations

import math
import warnings
from pathlib import Path

import numpy as np
import pytest

import phc
from phc.simulation import SimulationInterrupted, parameter_vector
from phc.simulation import ida as ida_module
from phc.options import RunOptions
from phc.simulation.ida import integrate_ida, solver_options
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


def _solve_reference(mod, p, t_out, y0, yp0, rtol, atol):
    """scikit-sundae's ``solve`` over the output times (IDA in its normal mode, from one
    output time to the next in C), with the options `integrate_ida` sets: local
    tolerances, index-1 algebraic variables tested, their rates at the start."""
    from sksundae.ida import IDA

    from phc.simulation.ida import LOCAL_TOLERANCE, algebraic_rates, determined_algebraic

    determined = determined_algebraic(mod, p, t_out[0], y0, yp0)
    yp0 = algebraic_rates(mod, p, t_out[0], y0, yp0, determined)
    options, _ = solver_options(mod, p, rtol=rtol * LOCAL_TOLERANCE, atol=atol * LOCAL_TOLERANCE,
                                determined=determined)
    with warnings.catch_warnings():  # scikit-sundae's note that our Jacobian replaces its approximation
        warnings.simplefilter("ignore", UserWarning)
        solver = IDA(options.pop("resfn"), max_num_steps=100_000, **options)
    out = solver.solve(t_out, y0, yp0)
    assert out.success, out.message
    return out.y


@pytest.mark.parametrize("sparse", [False, True])
def test_the_step_loop_equals_idas_own_loop_and_the_closed_form(oscillator, sparse, monkeypatch):
    if sparse:  # the sparse linear solver on this small system: the same steps, the same numbers
        monkeypatch.setattr(ida_module, "DENSE_LIMIT", 0)
    mod, p, init = _start(oscillator)
    t_out = np.linspace(0.0, 3.0, 61)
    rtol, atol = 1e-9, 1e-11
    run = integrate_ida(mod, p, t_out, init.y0, init.yp0, RunOptions(rtol=rtol, atol=atol, max_steps=100_000))
    ref = _solve_reference(mod, p, t_out, init.y0, init.yp0, rtol, atol)
    assert run["success"], run["message"]
    assert run["y"].shape == ref.shape
    # the same steps up to the last one, which the run's stop time clips (IDA's normal mode
    # steps past the end and interpolates): the same numbers to round-off before it, and
    # within IDA's local tolerance (rtol · LOCAL_TOLERANCE = 5e-12) at the end
    scale = np.abs(ref).max()
    assert np.abs(run["y"][:-1] - ref[:-1]).max() <= 1e-13 * scale
    assert np.abs(run["y"][-1] - ref[-1]).max() <= rtol * ida_module.LOCAL_TOLERANCE * scale
    x = run["y"][:, list(mod.VARIABLES).index("spring.x")]
    assert np.abs(x - _closed_form(t_out)).max() < 1e-7
    assert run["nfev"] > run["steps"] > 0 and run["njev"] > 0


def _onestep_count(mod, p, t_out, y0, yp0, rtol, atol):
    """IDA's steps counted independently: scikit-sundae's one-step mode toward the end, with
    the options `integrate_ida` sets, one call per internal step."""
    from sksundae.ida import IDA

    from phc.simulation.ida import LOCAL_TOLERANCE, algebraic_rates, determined_algebraic

    determined = determined_algebraic(mod, p, t_out[0], y0, yp0)
    yp0 = algebraic_rates(mod, p, t_out[0], y0, yp0, determined)
    options, _ = solver_options(mod, p, rtol=rtol * LOCAL_TOLERANCE, atol=atol * LOCAL_TOLERANCE,
                                determined=determined)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", UserWarning)
        solver = IDA(options.pop("resfn"), **options)
    solver.init_step(t_out[0], y0, yp0)
    steps, t = 0, t_out[0]
    while t < t_out[-1]:
        res = solver.step(t_out[-1], method="onestep", tstop=t_out[-1])
        assert res.success, res.message
        steps, t = steps + 1, res.t
    return steps


@pytest.mark.parametrize("n_out", [2, 7, 61, 601])
def test_the_step_count_is_idas_whatever_the_output_times(oscillator, n_out):
    """The step hook counts each step once: not the root finding's evaluations, not the
    output times inside a step (where IDA evaluates the hook at the output time and again at
    the step's end in the next call)."""
    mod, p, init = _start(oscillator)
    t_out = np.linspace(0.0, 3.0, n_out)
    run = integrate_ida(mod, p, t_out, init.y0, init.yp0, RunOptions(rtol=1e-9, atol=1e-11, max_steps=100_000))
    assert run["success"], run["message"]
    assert run["steps"] == _onestep_count(mod, p, t_out, init.y0, init.yp0, 1e-9, 1e-11)


def test_max_steps_is_honoured_exactly_and_the_outputs_before_are_kept(oscillator):
    mod, p, init = _start(oscillator)
    t_out = np.linspace(0.0, 3.0, 61)
    full = integrate_ida(mod, p, t_out, init.y0, init.yp0, RunOptions(rtol=1e-9, atol=1e-11, max_steps=100_000))
    run = integrate_ida(mod, p, t_out, init.y0, init.yp0, RunOptions(rtol=1e-9, atol=1e-11, max_steps=123))
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
def test_progress_is_reported_every_few_steps_in_time_order(oscillator, monitored, monkeypatch):
    if not monitored:  # as for a system too large for the singularity monitor
        from phc.simulation import monitor

        monkeypatch.setattr(monitor, "MAX_SIZE", 0)
    seen = []
    result = phc.simulate(oscillator, solver="ida", t_end=2.0, n_out=5, progress=seen.append)
    assert result.success and result.steps > 2 * ida_module.PROGRESS_STEPS
    # with 5 output times, progress is still reported every PROGRESS_STEPS steps (and once at the end)
    assert result.steps // ida_module.PROGRESS_STEPS <= len(seen) <= result.steps // ida_module.PROGRESS_STEPS + 1
    assert seen == sorted(seen) and seen[-1] == pytest.approx(2.0)


def test_a_successful_run_with_very_many_steps_says_what_may_cost_them(monkeypatch):
    """A free beam spun up took 840 000 IDA steps with `success` and no word; beyond
    MANY_STEPS the message says what cost them: here (a damped oscillator) not stiff
    undamped modes, which it names only where the steps leave some unresolved
    (tests/simulation/test_tolerance_budget.py), but the error test at the tolerances."""
    import phc
    import phc.simulation as sim

    compiled = phc.compile_model(MODELS / "mass_spring_damper.yaml", certify=False)
    quiet = phc.simulate(compiled)
    assert quiet.success and quiet.message == "integration finished"
    monkeypatch.setattr(sim, "MANY_STEPS", quiet.steps - 1)
    loud = phc.simulate(compiled)
    assert loud.success and f"IDA needed {quiet.steps} steps" in loud.message
    assert "no undamped mode is left unresolved" in loud.message and "rtol = " in loud.message
    assert "--solver midpoint" not in loud.message


def test_a_sigint_while_ida_steps_is_taken_between_chunks_without_a_traceback(oscillator, monkeypatch, capfd):
    """SIGINT delivered while IDA is inside phc's residual callback: the KeyboardInterrupt
    leaves the callback through scikit-sundae, IDA stops, and the run ends as interrupted
    (outputs kept, checked against the closed form), nothing printed as ignored, and
    Python's default handler untouched."""
    import signal

    # SIGINT with Python's default handler, delivered, as a user's process has it (libraries
    # that earlier tests ran — thread and process pools — may leave it blocked or handled
    # otherwise in this process).
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
    assert calls["n"] >= 400
    assert 0 < result.t[-1] < 10 and np.abs(result["x"] - _closed_form(result.t)).max() < 1e-6
    assert "Exception ignored" not in capfd.readouterr().err
    assert signal.getsignal(signal.SIGINT) is signal.default_int_handler


def test_a_trial_point_the_model_cannot_be_evaluated_at_is_retried_with_a_shorter_step(oscillator, monkeypatch):
    """A model error at IDA's trial point is a recoverable failure (the callback gives IDA a
    residual of NaN, its Newton iteration fails, it retries shorter) and the run goes on.
    Here the oscillator refuses, once, to be evaluated beyond t = 0.3 — as a long trial
    step overshooting into a region the solution never reaches would; the run still meets
    the closed form. (A solution that runs into the edge of the domain:
    tests/test_cli_faults.py and test_a_failure_mid_run_keeps_the_outputs_before_it.)"""
    from phc.simulation.guard import ModelEvaluationError

    refused = []
    residual = oscillator.module.residual

    def once(t, *args):
        if t > 0.3 and not refused:
            refused.append(t)
            raise ModelEvaluationError(f"cannot be evaluated at t = {t}", function="residual", t=t)
        return residual(t, *args)

    monkeypatch.setattr(oscillator.module, "residual", once)
    result = phc.simulate(oscillator, solver="ida", t_end=2.0, n_out=41)
    assert refused and result.success, result.message
    assert np.abs(result["x"] - _closed_form(result.t)).max() < 1e-6
