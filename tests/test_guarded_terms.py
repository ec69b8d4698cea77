"""Terms a condition switches off: never evaluated where it discards them, never a warning.

* ``ifelse(c > 0, k*x**4/(4*c), 0)`` and ``exp(-1/e)`` with c = e = 0: ``phc simulate``,
  ``phc check`` and ``phc linearize`` print no NumPy RuntimeWarning (the compile-time
  certificate evaluates the generated functions as a run does, NumPy's floating-point
  warnings off);
* ``ifelse(abs(x) > 1e-9, sin(x)/x, 1)`` guards the removable singularity of sin(x)/x: a run
  starting at x = 0 (where the event driver takes the side the motion goes to) runs, and
  follows the ODE written out below;
* ``ifelse(x > 0, ... sqrt(x) ...)`` at x < 0: a ``sqrt(x)`` shared by two branches is not
  hoisted out of them (common subexpressions stay inside their branch);
* a non-finite value the condition as written selects is still a located error.
"""

from __future__ import annotations

import math
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from scipy.integrate import solve_ivp

import phc
from model_texts import GUARDED_DIVISION  # shared with tests/codegen/test_float_arguments.py
from phc.simulation import ModelEvaluationError
from time_limits import SUBPROCESS_TIMEOUT

REPO = Path(__file__).resolve().parents[1]

CPAR = GUARDED_DIVISION

# exp(-1/e) with e = 0 is exp(-inf) = 0 as NumPy computes it (Python's 1/0 raises: the generated
# functions evaluate such a call again on NumPy scalars): the quartic term is off
EXP = CPAR.replace("name: guarded_division", "name: exp_switch").replace(
    'c: {value: 0.0, unit: m^2, description: "softening length squared; 0 turns the term off"}',
    'e: {value: 0.0, unit: "1"}').replace(
    '"k*x**2/2 + ifelse(c > 0, k*x**4/(4*c), 0) + ifelse(c > 0, k*x**2/c, 0)"', '"k*x**2/2 + k*x**4/4*exp(-1/e)"')

SINC = """\
format_version: 1
name: sinc_spring
parameters:
  m: {value: 1.0, unit: kg}
  k: {value: 4.0, unit: N/m}
components:
  body:
    type: rigid
    q: [x]
    v: [vx]
    M: [[m]]
    V: "k*x**2/2*ifelse(COND, sin(x)/x, 1) + k*x**2/2*ifelse(COND, sin(x)/x, 1)**2"
simulation:
  t_end: T_END
  n_out: 31
  rtol: 1.0e-8
  atol: 1.0e-10
  initial:
    body.x: 0.0
    body.p_vx: P0
  outputs:
    x: body.x
"""

SQRT = """\
format_version: 1
name: sqrt_guard
parameters:
  m: {value: 1.0, unit: kg}
  k: {value: 4.0, unit: N/m}
components:
  body:
    type: rigid
    q: [x]
    v: [vx]
    M: [[m]]
    V: "k*x**2/2 + ifelse(x > 0, k*sin(sqrt(x))*x**2, 0) + ifelse(x > 0, k*cos(sqrt(x))*x**3, 0)"
simulation:
  t_end: 0.5
  n_out: 11
  rtol: 1.0e-8
  atol: 1.0e-10
  initial:
    body.x: -0.1
    body.p_vx: 0.0
  outputs:
    x: body.x
"""

K, M = 4.0, 1.0


def _sinc(tmp_path, cond="abs(x) > 1e-9", t_end=1.0, p0=1.0) -> Path:
    path = tmp_path / "sinc.yaml"
    path.write_text(SINC.replace("COND", cond).replace("T_END", repr(t_end)).replace("P0", repr(p0)))
    return path


@pytest.mark.parametrize("model", [CPAR, EXP], ids=["ifelse", "exp"])
@pytest.mark.parametrize("command", [["simulate"], ["check"], ["linearize"]])
def test_a_term_switched_off_by_a_parameter_prints_no_warning(tmp_path, command, model):
    assert "e: {value: 0.0" in EXP and "exp(-1/e)" in EXP
    path = tmp_path / "model.yaml"
    path.write_text(model)
    run = subprocess.run([sys.executable, "-m", "phc", *command, str(path)], cwd=REPO, capture_output=True,
                         text=True, timeout=SUBPROCESS_TIMEOUT)
    assert run.returncode == 0, run.stderr
    assert "Warning" not in run.stderr and "Traceback" not in run.stderr, run.stderr
    assert "divide by zero" not in run.stdout + run.stderr


@pytest.mark.parametrize("model", [CPAR, EXP], ids=["ifelse", "exp"])
def test_the_certificate_evaluates_without_numpy_warnings(tmp_path, model):
    import warnings

    from phc.checks.compiled import certify_compiled

    path = tmp_path / "model.yaml"
    path.write_text(model)
    compiled = phc.compile_model(path, certify=False, backend="numpy")
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        cert = certify_compiled(compiled, n_random=2)
    assert cert.samples >= 1 and cert.certified
    assert not [w for w in caught if issubclass(w.category, RuntimeWarning)], [str(w.message) for w in caught]


def _sinc_ode(t, z):
    """m x'' = -V'(x) with V = k x sin(x)/2 + k sin(x)**2/2 (the guarded potential, unguarded)."""
    x, v = z
    dV = K / 2 * (math.sin(x) + x * math.cos(x)) + K * math.sin(x) * math.cos(x)
    return [v, -dV / M]


def test_a_guarded_removable_singularity_runs_from_zero(tmp_path):
    compiled = phc.compile_model(_sinc(tmp_path), certify=False, backend="numpy")
    run = phc.simulate(compiled)
    assert run.success, run.message
    t, x = np.asarray(run.t), np.asarray(run.outputs["x"])
    assert t[-1] == pytest.approx(1.0)
    ref = solve_ivp(_sinc_ode, (0.0, 1.0), [0.0, 1.0 / M], t_eval=t, rtol=1e-11, atol=1e-13, method="DOP853")
    assert np.abs(x - ref.y[0]).max() < 1e-6


def test_a_small_oscillation_through_the_guard_has_the_closed_form_frequency(tmp_path):
    """Near 0 the potential is k x²/2 + k x²/2 = k x² - k x⁴/4 + ...: x = A sin(ω t) with
    A = p0/(m ω), ω = sqrt(2k/m), through three passes of x = 0. The quartic term shifts ω by
    the fraction 3A²/16 = 2.3e-6 (a phase error below 2e-5 at t = 3). The start is on the
    condition's boundary (|x| - 1e-9 = -1e-9, +2e-9 a probe instant later), so the driver
    freezes the sin(x)/x side at x = 0."""
    p0 = 1e-2
    compiled = phc.compile_model(_sinc(tmp_path, t_end=3.0, p0=p0), certify=False, backend="numpy")
    run = phc.simulate(compiled)
    assert run.success, run.message
    t, x = np.asarray(run.t), np.asarray(run.outputs["x"])
    w = math.sqrt(2 * K / M)
    amplitude = p0 / (M * w)
    assert t[-1] == pytest.approx(3.0)
    assert np.abs(x - amplitude * np.sin(w * t)).max() < 1e-4 * amplitude


def test_a_root_shared_by_branches_is_not_evaluated_where_they_are_off(tmp_path):
    """x < 0 throughout: the ifelse terms are off, x = -0.1 cos(2 t) (ω = sqrt(k/m) = 2)."""
    path = tmp_path / "sqrt.yaml"
    path.write_text(SQRT)
    compiled = phc.compile_model(path, certify=False, backend="numpy")
    assert compiled.source.count("math.sqrt(") >= 2  # the shared root, in each branch that uses it
    run = phc.simulate(compiled)
    assert run.success, run.message
    t, x = np.asarray(run.t), np.asarray(run.outputs["x"])
    assert np.abs(x + 0.1 * np.cos(2.0 * t)).max() < 1e-6


def test_a_non_finite_value_the_condition_selects_is_still_reported(tmp_path):
    """`ifelse(x < 1, sin(x)/x, 1)` at x = 0: the condition holds, sin(0)/0 is the value."""
    compiled = phc.compile_model(_sinc(tmp_path, cond="x < 1"), certify=False, backend="numpy")
    with pytest.raises(ModelEvaluationError) as info:
        phc.simulate(compiled)
    message = str(info.value)
    assert "division by zero" in message and "body.x = 0" in message and "sinc.yaml:8" in message
