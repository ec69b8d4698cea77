"""The per-step functions of the NumPy module read their arguments as Python floats.

`residual` and `jacobian` unpack y, ẏ and p with one ``tolist()`` (Python float arithmetic
costs about a third of NumPy scalars'). Python floats raise where IEEE arithmetic gives inf
or nan, so such a call is evaluated again on NumPy scalars: every value is what NumPy
gives, and a term a condition switches off may divide by zero, as before.
"""

from __future__ import annotations

import math

import numpy as np
import pytest

import phc
from model_texts import GUARDED_DIVISION  # shared with tests/test_guarded_terms.py

MODEL = GUARDED_DIVISION


@pytest.fixture(scope="module")
def compiled(tmp_path_factory):
    path = tmp_path_factory.mktemp("float_arguments") / "guarded_division.yaml"
    path.write_text(MODEL)
    return phc.compile_model(path, certify=False, backend="numpy")


def test_residual_and_jacobian_read_python_floats(compiled):
    source = compiled.source
    assert "_y = _read(y)" in source and "_floats = np.ndarray.tolist" in source
    mod = compiled.module
    assert mod.residual.__doc__ and mod._residual.__doc__


def test_a_division_by_zero_a_condition_discards_is_not_evaluated(compiled):
    """The terms with 1/c sit in branches c = 0 switches off: each branch is its own block
    (phc.codegen.printer), so neither reading meets 1/c, and both give the same values."""
    mod = compiled.module
    p = mod.full_parameters()
    n = mod.N
    rng = np.random.default_rng(3)
    y, yp = rng.normal(size=n), rng.normal(size=n)
    fast, ieee, called = np.zeros(n), np.zeros(n), np.zeros(n)
    with np.errstate(divide="raise", invalid="raise"):
        mod._residual(0.0, y, yp, p, fast, mod._floats)  # Python floats: 1/0 would raise
        mod._residual(0.0, y, yp, p, ieee, list)  # NumPy scalars under errstate: 1/0 would raise
        mod.residual(0.0, y, yp, p, called)
    assert np.all(np.isfinite(fast)) and np.array_equal(fast, ieee) and np.array_equal(fast, called)


def test_python_float_errors_fall_back_to_numpy_scalars():
    """Where Python floats raise and NumPy gives inf (a square of 1e200 in the pendulum's
    constraint row), the call is evaluated again on NumPy scalars: the values are NumPy's,
    for the checks (phc.simulation.guard) to judge."""
    from pathlib import Path

    compiled = phc.compile_model(Path(__file__).resolve().parents[2] / "models" / "pendulum.yaml",
                                 certify=False, backend="numpy")
    mod = compiled.module
    p = mod.full_parameters()
    y, yp = np.zeros(mod.N), np.zeros(mod.N)
    y[list(mod.VARIABLES).index("pendulum.x")] = 1e200
    with pytest.raises(OverflowError):
        mod._residual(0.0, y, yp, p, np.zeros(mod.N), mod._floats)
    called, ieee = np.zeros(mod.N), np.zeros(mod.N)
    with np.errstate(over="ignore", invalid="ignore"):
        mod.residual(0.0, y, yp, p, called)
        mod._residual(0.0, y, yp, p, ieee, list)
    assert np.isinf(called).any()
    assert np.array_equal(called, ieee, equal_nan=True)


def test_the_model_runs_as_the_plain_spring(compiled):
    """With c = 0 the terms are off: x(t) = 0.1 cos(ω t), ω = sqrt(k/m) = 2."""
    with np.errstate(divide="ignore", invalid="ignore"):
        run = phc.simulate(compiled)
    assert run.success, run.message
    x = np.asarray(run.outputs["x"])
    assert np.abs(x - 0.1 * np.cos(2.0 * np.asarray(run.t))).max() < 1e-6


def test_floats_and_numpy_scalars_agree_on_a_shipped_model():
    from pathlib import Path

    compiled = phc.compile_model(Path(__file__).resolve().parents[2] / "models" / "double_pendulum.yaml",
                                 certify=False, backend="numpy")
    mod = compiled.module
    p = mod.full_parameters()
    rng = np.random.default_rng(7)
    for _ in range(5):
        y, yp = rng.normal(size=mod.N), rng.normal(size=mod.N)
        a, b = np.zeros(mod.N), np.zeros(mod.N)
        mod._residual(0.3, y, yp, p, a, mod._floats)
        mod._residual(0.3, y, yp, p, b, list)
        scale = max(1.0, np.abs(b).max())
        assert np.abs(a - b).max() <= 4 * math.ulp(scale)
        ja, jb = np.zeros(len(mod.JAC_ROWS)), np.zeros(len(mod.JAC_ROWS))
        mod._jacobian(0.3, y, yp, p, 2.0, ja, mod._floats)
        mod._jacobian(0.3, y, yp, p, 2.0, jb, list)
        assert np.abs(ja - jb).max() <= 4 * math.ulp(max(1.0, np.abs(jb).max()))
