"""phc's native IDA driver (:mod:`phc.simulation.ida_native`, ``phc/codegen/c_runtime/ida_driver.c``):
IDA calling the C back end's residual and Jacobian directly, its steps in a C loop.

Both paths are SUNDIALS' IDA with the same settings (:func:`phc.simulation.ida.run_settings`: the
tolerances, the id vector, the maximum order; SUNDIALS' own dense LU): the native path against the
machine's SUNDIALS, the other through scikit-sundae's copy. Each run's outputs are within phc's
promise of the solution (rtol relative to an output's scale), so the two are within twice that of
each other whatever the SUNDIALS versions round differently; and each meets the pendulum's closed
form. Skipped, with the reason, where SUNDIALS' headers and libraries are not installed (Debian:
``apt install libsundials-dev``) or no C compiler is found.
"""

from __future__ import annotations

import math
import warnings
from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pytest
from scipy.special import ellipj, ellipk

import phc
from phc.codegen import c_backend, c_ida
from phc.simulation import ida_native

MODELS = Path(__file__).resolve().parents[2] / "models"

_SUNDIALS, _WHY = c_ida.find_sundials()
needs_sundials = pytest.mark.skipif(_SUNDIALS is None or not c_backend.available()[0],
                                    reason=f"the native IDA driver cannot be built here: {_WHY or 'no C compiler'}")

RTOL = 1e-8
T_END = 5.0  # two periods of the 90° release
PROMISE = 3.0
"""phc promises outputs within rtol relative to their scale (docs/tolerances.md); its local fraction was set
with a ±30 % spread between runs that differ only in rounding (phc.simulation.ida.LOCAL_TOLERANCE): a
factor 3 covers it twice over."""


def _angle_exact(t, L=1.0, g=9.81, theta0=math.pi / 2):
    """The pendulum released at rest from θ0: θ(t) = 2 arcsin(k sn(K(k) − ω t; k)), k = sin(θ0/2),
    ω = √(g/L) (sn(K) = 1 gives θ(0) = θ0)."""
    k = math.sin(theta0 / 2)
    sn = ellipj(ellipk(k * k) - math.sqrt(g / L) * np.asarray(t), k * k)[0]
    return 2 * np.arcsin(k * sn)


@pytest.fixture(scope="module")
def pendulum():
    if _SUNDIALS is None or not c_backend.available()[0]:
        pytest.skip(f"the native IDA driver cannot be built here: {_WHY or 'no C compiler'}")
    return phc.compile_model(MODELS / "pendulum.yaml", certify=False, backend="c")


def _run(compiled, native: bool, monkeypatch, **options):
    """A run through the native driver (checked: it ran and handed nothing back) or through scikit-sundae."""
    calls = []
    original = ida_native._native

    def spy(*args, **kwargs):
        out = original(*args, **kwargs)
        calls.append(out)
        return out

    monkeypatch.setattr(ida_native, "_native", spy)
    monkeypatch.setenv("PHC_NATIVE_IDA", "1" if native else "0")
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        r = phc.simulate(compiled, solver="ida", **options)
    if native:
        assert len(calls) == 1 and calls[0][0] is not None, calls[0][1] if calls else "the native path was not tried"
    else:
        assert not calls
    return r


@needs_sundials
def test_native_and_scikit_sundae_agree_and_meet_the_closed_form(pendulum, monkeypatch):
    options = dict(t_end=T_END, n_out=251, rtol=RTOL, atol=RTOL * 1e-2)
    native = _run(pendulum, True, monkeypatch, **options)
    other = _run(pendulum, False, monkeypatch, **options)
    assert native.success and other.success
    np.testing.assert_array_equal(native.t, other.t)
    scale = math.pi / 2  # the angle's scale
    exact = _angle_exact(native.t)
    for r in (native, other):
        assert np.abs(r["angle"] - exact).max() <= PROMISE * RTOL * scale
    # two runs each within the promise of the solution are within twice it of each other
    assert np.abs(native["angle"] - other["angle"]).max() <= 2 * PROMISE * RTOL * scale
    assert np.abs(native.y - other.y).max() <= 2 * PROMISE * RTOL * np.abs(other.y).max()
    # the energy m g y + |p|²/2m is conserved by the pendulum: IDA keeps it to its tolerance (scale m g L)
    mgL = 9.81
    assert np.abs(native.H - native.H[0]).max() <= PROMISE * RTOL * mgL
    # the rod keeps its length (the GGL constraint is one of IDA's equations)
    assert np.abs(native["rod_length_error"]).max() <= PROMISE * RTOL


@needs_sundials
def test_max_steps_is_honoured_exactly(pendulum, monkeypatch):
    """A chunk of the C loop ends at max_steps: the run stops at that step, as the scikit-sundae path does."""
    native = _run(pendulum, True, monkeypatch, t_end=T_END, n_out=251, rtol=RTOL, atol=RTOL * 1e-2, max_steps=123)
    other = _run(pendulum, False, monkeypatch, t_end=T_END, n_out=251, rtol=RTOL, atol=RTOL * 1e-2, max_steps=123)
    assert not native.success and "max_steps" in native.message
    assert native.steps == other.steps == 123
    np.testing.assert_allclose(native.t[-1], other.t[-1])
    assert len(native.t) == len(other.t)


def test_usable_says_why_not():
    """Not on the C back end: nothing to say; too large for the dense solver: the reason."""
    assert ida_native.usable(SimpleNamespace(BACKEND="numpy", N=3)) == (False, "")
    if _SUNDIALS is None or not c_backend.available()[0]:
        ok, why = ida_native.usable(SimpleNamespace(BACKEND="c", C_LIBRARY=object(), N=3))
        assert not ok and why
        return
    ok, why = ida_native.usable(SimpleNamespace(BACKEND="c", C_LIBRARY=object(), N=500))
    assert not ok and "dense" in why
    ok, why = ida_native.usable(SimpleNamespace(BACKEND="c", C_LIBRARY=object(), N=3), SimpleNamespace(n=1))
    assert not ok and "switching" in why


def test_switched_off_by_the_environment(monkeypatch):
    """PHC_NATIVE_IDA=0: the driver is not used, silently."""
    monkeypatch.setenv("PHC_NATIVE_IDA", "0")
    monkeypatch.setattr(c_ida, "_LIBRARY", None)
    assert c_ida.library() is None and c_ida.why_not() == ""
    assert ida_native.usable(SimpleNamespace(BACKEND="c", C_LIBRARY=object(), N=3)) == (False, "")


class _Handed(Exception):
    """The native driver handed the run to scikit-sundae (the test stops there)."""


def _looks(compiled, monkeypatch, c_looks: bool, **options):
    """A native run with the monitor's routine looks in C or all in Python: (every look the monitor kept:
    (t, h, ratio); the looks Python's monitor made itself; the stops the step hook raised: (t, message);
    the run, or None where the native path handed it over)."""
    from phc.simulation import ida as ida_module
    from phc.simulation.monitor import SingularityMonitor

    kept, checks, stops = [], [], []
    record, check, look = SingularityMonitor._record, SingularityMonitor.check, ida_module._StepHook._look

    def spy_record(self, t, y, yp, h, ratio):
        kept.append((t, h, ratio))
        return record(self, t, y, yp, h, ratio)

    def spy_check(self, *args, **kwargs):
        checks.append(args[0])
        return check(self, *args, **kwargs)

    def spy_look(self, t, y, yp, h):
        try:
            return look(self, t, y, yp, h)
        except ida_module._Stop as stop:
            stops.append((t, stop.message))
            raise

    def handed(*args, **kwargs):
        raise _Handed

    run = None
    with monkeypatch.context() as patch, warnings.catch_warnings():
        patch.setattr(SingularityMonitor, "_record", spy_record)
        patch.setattr(SingularityMonitor, "check", spy_check)
        patch.setattr(ida_module._StepHook, "_look", spy_look)
        patch.setattr(ida_native, "integrate_ida", handed)
        patch.setattr(ida_native, "C_LOOKS", c_looks)
        patch.setenv("PHC_NATIVE_IDA", "1")
        warnings.simplefilter("ignore")
        try:
            run = phc.simulate(compiled, solver="ida", **options)
        except _Handed:
            pass
    return kept, checks, stops, run


@needs_sundials
def test_routine_looks_in_c_stop_the_folding_slider_crank_as_pythons(monkeypatch):
    """The rigid slider–crank with its rod as long as the crank folds at θ = π/2 (the rod perpendicular to
    the guide: tests/simulation/test_monitor.py). With the routine looks in C, the monitor looks at the same
    steps as when Python makes every look (the cadence, the minimum test and the crawl check are the same
    functions, translated), keeps ratios within 1e-6 of Python's (two condition estimates of the same
    equilibrated matrix from two LUs of it: they differ by the LU's rounding times the matrix's condition,
    below 1/(RCOND_MARGIN·threshold) = 1e8 where the C look passes, so ~1e-8), and hands the same step to
    Python, which stops the run with the same message; and the C looks did take over some looks."""
    compiled = phc.compile_model(MODELS / "rigid_slider_crank.yaml", certify=False, backend="c")
    options = dict(params={"L": 0.15}, t_end=0.011)
    kept_c, checks_c, stops_c, run_c = _looks(compiled, monkeypatch, True, **options)
    kept_py, checks_py, stops_py, run_py = _looks(compiled, monkeypatch, False, **options)
    assert run_c is None and run_py is None  # the monitor stopped both: handed to scikit-sundae's path
    assert stops_c and stops_c == stops_py
    assert "singular configuration" in stops_c[-1][1]
    assert [k[:2] for k in kept_c] == [k[:2] for k in kept_py]
    np.testing.assert_allclose([k[2] for k in kept_c], [k[2] for k in kept_py], rtol=1e-6)
    assert len(checks_py) == len(kept_py) and len(checks_c) < len(kept_c)


@needs_sundials
def test_routine_looks_in_c_leave_the_run_unchanged_and_python_idle(pendulum, monkeypatch):
    """Far from any singular configuration (the pendulum) Python's monitor makes almost none of the looks,
    the run's outputs are bit for bit those of a run whose looks are all Python's (a look does not change
    IDA's steps), and the monitor keeps as many looks within 10 % and its worst ratio within 10 % (its ratios
    are condition estimates, 1/(n κ̂₁) with κ̂₁ a lower bound of κ₁, from two LUs of the same matrix: where
    the estimator's choice of its next vector is a tie, their rounding may choose differently, and the two
    estimates, both within a small factor of κ₁, then differ by more than rounding — and the cadence they
    set with them)."""
    options = dict(t_end=T_END, n_out=251, rtol=RTOL, atol=RTOL * 1e-2)
    kept_c, checks_c, _, run_c = _looks(pendulum, monkeypatch, True, **options)
    kept_py, checks_py, _, run_py = _looks(pendulum, monkeypatch, False, **options)
    assert run_c.success and run_py.success
    np.testing.assert_array_equal(run_c.y, run_py.y)
    assert run_c.steps == run_py.steps
    assert len(checks_py) == len(kept_py) > 50
    assert len(checks_c) < 0.25 * len(kept_c)
    assert abs(len(kept_c) - len(kept_py)) <= 0.1 * len(kept_py)
    worst_c, worst_py = min(k[2] for k in kept_c), min(k[2] for k in kept_py)
    assert worst_c == pytest.approx(worst_py, rel=0.1)
