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
