"""IDA's residual and Jacobian as compiled C callbacks (phc/simulation/ida_native.py).

On the numba backend a long IDA run changes from phc's Python callback to numba cfuncs
around the compiled functions: the same numbers (the same functions on the same vectors),
no Python in IDA's step loop, the same located errors."""

from __future__ import annotations

import math
import sys
from pathlib import Path

import numpy as np
import pytest

numba = pytest.importorskip("numba")

import phc  # noqa: E402
from phc.simulation import ida as ida_module  # noqa: E402
from phc.simulation import ida_native  # noqa: E402
from phc.simulation.ida import _IdaCounters  # noqa: E402

MODELS = Path(__file__).resolve().parents[2] / "models"


class _Decay:
    """A stand-in for a compiled model module: y₀' = −y₀, y₁' = −2 y₁ (F = ẏ + diag(1, 2) y)
    as numba functions with the generated functions' signatures."""

    N = 2
    JAC_ROWS = np.array([0, 1])
    JAC_COLS = np.array([0, 1])
    BACKEND = "numba"

    def __init__(self):
        @numba.njit
        def residual(t, y, yp, p, out):
            out[0] = yp[0] + p[0] * y[0]
            out[1] = yp[1] + p[1] * y[1]

        @numba.njit
        def jacobian(t, y, yp, p, cj, out):
            out[0] = cj + p[0]
            out[1] = cj + p[1]

        self.residual, self.jacobian = residual, jacobian


def _solver(calls):
    from sksundae.ida import IDA

    def resfn(t, y, yp, r):
        calls.append(t)
        r[:] = yp + np.array([1.0, 2.0]) * y

    def jacfn(t, y, yp, r, cj, J):
        J[:] = np.diag([cj + 1.0, cj + 2.0])

    solver = IDA(resfn, rtol=1e-9, atol=1e-12, linsolver="dense", jacfn=jacfn)
    start = solver.init_step(0.0, np.ones(2), np.array([-1.0, -2.0]))
    counters = _IdaCounters.attach(solver, 2, int(start.nfev))
    assert counters is not None and counters.can_advance
    return solver, counters


def test_ida_steps_with_the_compiled_callbacks_alone_and_gets_its_own_back():
    calls = []
    solver, counters = _solver(calls)
    at = ida_native.data_offset(counters.lib, counters._base, counters._vectors[0].value, 2)
    assert at in (8, 16)
    native = ida_native.Native(_Decay(), np.array([1.0, 2.0]), _Decay.JAC_ROWS, _Decay.JAC_COLS, at)
    assert counters.install_native(native, None, np.array([1.0, 2.0]))
    status, t = counters.advance(1.0)
    assert status >= 0 and t == 1.0
    assert not calls  # no Python residual call: IDA evaluated the cfuncs
    assert counters.residual_evaluations() > 10 and counters.jacobian_evaluations() > 0
    assert np.allclose(counters.y, [math.exp(-1.0), math.exp(-2.0)], rtol=1e-7)
    assert native.cj > 0
    counters.restore_native()
    res = solver.step(1.5, method="normal")  # scikit-SUNDAE's wrapper again (Jacobian by difference quotients)
    assert calls and res.success and np.allclose(res.y, [math.exp(-1.5), math.exp(-3.0)], rtol=1e-6)


def test_a_value_that_is_not_finite_is_recoverable_and_recorded_with_its_point():
    """The compiled residual refuses (nan) beyond t = 0.3 once the context's flag says so; IDA
    retries shorter, the record holds the failing time and state, and a failure that persists
    is raised when IDA gives up."""

    class Refusing(_Decay):
        def __init__(self):
            @numba.njit
            def residual(t, y, yp, p, out):
                out[0] = yp[0] + p[0] * y[0]
                out[1] = yp[1] + p[1] * y[1]
                if t > p[2]:
                    out[1] = math.nan

            self.residual, self.jacobian = residual, _Decay().jacobian

    calls = []
    _solver_, counters = _solver(calls)
    at = ida_native.data_offset(counters.lib, counters._base, counters._vectors[0].value, 2)
    p = np.array([1.0, 2.0, 10.0])
    native = ida_native.Native(Refusing(), p, _Decay.JAC_ROWS, _Decay.JAC_COLS, at)
    assert counters.install_native(native, None, p)
    status, _t = counters.advance(0.5)
    assert status >= 0 and native.count == 0
    native.context[ida_native._HEADER + 2] = 0.8  # p[2]: refuse beyond t = 0.8 from now on
    reached = 0.5
    for _ in range(5):  # IDA's steps creep up to t = 0.8 (the run's driver stops that: the test below)
        status, reached = counters.advance(2.0)
    assert native.count >= 1 and 0.5 < reached <= 0.8 < native.time < 2.0
    assert not calls  # all in the compiled callbacks
    err = native.error(None, p)
    assert isinstance(err, ida_module.ModelEvaluationError) and "residual is not finite at t = 0.8" in str(err)
    recorded_y = native.context[ida_native._HEADER + 3:ida_native._HEADER + 5]
    assert np.all(np.isfinite(recorded_y)) and 0 < recorded_y[0] < math.exp(-0.7)


def _numba_model(path):
    return phc.compile_model(path, backend="numba", certify=False)


def test_a_long_run_changes_to_the_compiled_callbacks_with_the_same_numbers(monkeypatch):
    compiled = _numba_model(MODELS / "double_pendulum.yaml")
    installed = []
    install = _IdaCounters.install_native

    def spy(self, *args):
        installed.append(install(self, *args))
        return installed[-1]

    monkeypatch.setattr(_IdaCounters, "install_native", spy)
    monkeypatch.setattr(ida_module, "SWITCH_EVALUATIONS", 500)
    monkeypatch.setenv("PHC_IDA_NATIVE", "0")
    python = phc.simulate(compiled, t_end=2.0, n_out=41, rtol=1e-8, atol=1e-8)
    assert python.success and not installed
    monkeypatch.setenv("PHC_IDA_NATIVE", "1")
    native = phc.simulate(compiled, t_end=2.0, n_out=41, rtol=1e-8, atol=1e-8)
    assert native.success and installed == [True]
    assert np.array_equal(native.y, python.y)
    assert (native.steps, native.n_residual_evals, native.n_jacobian_evals) == \
        (python.steps, python.n_residual_evals, python.n_jacobian_evals)


def test_the_compiled_callbacks_give_the_located_error_where_the_model_leaves_its_domain(tmp_path, monkeypatch):
    """The state model of tests/test_cli_faults.py (energy e^q, q' = 1000: e^q overflows at
    q = 709.78) on the numba backend, in compiled callbacks from the 200th evaluation on."""
    sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
    from test_cli_faults import STATE_MODEL

    path = tmp_path / "m.yaml"
    path.write_text(STATE_MODEL.replace("HAMILTONIAN", "exp(a*q)").replace("RATE", "1000"))
    monkeypatch.setattr(ida_module, "SWITCH_EVALUATIONS", 200)
    installed = []
    install = _IdaCounters.install_native
    monkeypatch.setattr(_IdaCounters, "install_native",
                        lambda self, *args: installed.append(install(self, *args)) or installed[-1])
    result = phc.simulate(_numba_model(path), solver="ida")
    assert installed == [True]
    assert not result.success
    assert "cannot be evaluated at t = " in result.message and "overflow" in result.message
    t_star = math.log(sys.float_info.max) / 1000
    assert t_star - 0.03 <= result.t[-1] <= t_star
    assert np.abs(result["s.q"] - 1000 * result.t).max() < 1e-6 * 1000
