"""The solver contract (:mod:`phc.simulation.backend`), run on every backend.

Each backend takes the same arguments and returns a typed BackendRun; each reaches the
closed-form solution of a damped oscillator; a failed run returns what it computed; an
option the chosen backend does not use is reported, never dropped in silence."""

from __future__ import annotations

import math
import warnings
from pathlib import Path

import numpy as np
import pytest

import phc
from phc.options import RunOptions
from phc.simulation import BACKENDS, FIXED_STEP, parameter_vector
from phc.simulation.backend import Backend, BackendRun, IgnoredOptionWarning
from phc.simulation.initial import consistent_initial_conditions

MODELS = Path(__file__).resolve().parents[2] / "models"


@pytest.fixture(scope="module", params=["numpy", "numba", "c"])
def oscillator(request):
    """The oscillator on each code backend (the generated NumPy module, and compiled: numba,
    and C through the system C compiler)."""
    if request.param == "numba":
        from phc.codegen.numba_backend import available

        ok, why = available()
        if not ok:
            pytest.skip(f"compiled backend not tested: {why}")
    if request.param == "c":
        from phc.codegen.c_backend import available

        ok, why = available()
        if not ok:
            pytest.skip(f"C backend not tested: {why}")
    compiled = phc.compile_model(MODELS / "mass_spring_damper.yaml", certify=False, backend=request.param)
    assert compiled.backend == request.param
    return compiled


def _start(compiled):
    mod = compiled.module
    p = parameter_vector(mod)
    index = {n: j for j, n in enumerate(mod.VARIABLES)}
    values = {index[iv.name]: iv.value for iv in compiled.dae.initial}
    values[index["energy.supplied"]] = 0.0
    init = consistent_initial_conditions(mod, p, 0.0, values, set(values))
    return mod, p, init


def _options(name, **over):
    """The backend's keywords: the run options (one RunOptions object) and no progress."""
    options = RunOptions(solver=name, rtol=1e-9, atol=1e-11, max_steps=100_000,
                         step=1e-3 if BACKENDS[name].fixed_step else None).replace(**over)
    return dict(options=options, progress=None, names=None)


def _closed_form(t, m=1.0, k=4.0, c=0.4, x0=0.5):
    w0 = math.sqrt(k / m)
    zeta = c / (2 * math.sqrt(k * m))
    wd = w0 * math.sqrt(1 - zeta**2)
    return np.exp(-zeta * w0 * t) * (x0 * np.cos(wd * t) + zeta * w0 * x0 / wd * np.sin(wd * t))


@pytest.mark.parametrize("name", sorted(BACKENDS))
def test_every_backend_returns_a_typed_run_that_reaches_the_closed_form(name, oscillator):
    backend = BACKENDS[name]
    assert isinstance(backend, Backend) and backend.name == name
    mod, p, init = _start(oscillator)
    t_out = np.linspace(0.0, 2.0, 21)
    run = backend(mod, p, t_out, init.y0, init.yp0, **_options(name))
    assert isinstance(run, BackendRun)
    assert run.success and isinstance(run.message, str) and run.steps > 0 and run.cpu >= 0
    assert np.array_equal(run.t, t_out) and run.y.shape == run.yp.shape == (21, mod.N)
    x = run.y[:, list(mod.VARIABLES).index("spring.x")]
    tol = 1e-5 if name in ("midpoint", "discrete_gradient") else 1e-7  # order 2 at h = 1e-3; order 4 / IDA
    assert np.abs(x - _closed_form(t_out)).max() < tol
    assert run["t"] is run.t and set(run) >= {"t", "y", "yp", "steps", "success", "message"}


@pytest.mark.parametrize("name", sorted(BACKENDS))
def test_every_backend_returns_what_it_computed_when_it_stops(name, oscillator):
    mod, p, init = _start(oscillator)
    t_out = np.linspace(0.0, 2.0, 21)
    run = BACKENDS[name](mod, p, t_out, init.y0, init.yp0, **_options(name, max_steps=50))
    assert not run.success and "max_steps" in run.message
    assert 1 <= len(run.t) < len(t_out) and np.array_equal(run.t, t_out[:len(run.t)])
    assert np.isfinite(run.y).all() and run.y.shape == (len(run.t), mod.N)


@pytest.mark.parametrize("name", sorted(BACKENDS))
def test_an_option_the_backend_does_not_use_is_reported(name, oscillator):
    unused = {"rtol": 1e-6} if name in FIXED_STEP else {"step": 1e-3}
    with pytest.warns(IgnoredOptionWarning, match=f"solver `{name}` ignores `{next(iter(unused))}`"):
        phc.simulate(oscillator, solver=name, t_end=0.1, n_out=3, **unused)
    used = {"step": 1e-3} if name in FIXED_STEP else {"rtol": 1e-6}
    with warnings.catch_warnings():
        warnings.simplefilter("error", IgnoredOptionWarning)
        assert phc.simulate(oscillator, solver=name, t_end=0.1, n_out=3, **used).success
