"""A solution that grows without bound (issue 34): the run stops with a message that names the
state, the time and the cause (a finite-time blow-up, an exponential growth) and keeps the
results so far — IDA (its steps collapse until the model overflows or `max_steps` is used up)
and the fixed-step solvers (Newton fails once a step multiplies the state).

Closed forms: ẋ = x² from x₀ has x(t) = x₀/(1 − x₀t), infinite at t* = 1/x₀; ẋ = x has
x₀eᵗ. The models supply energy through a "dissipative" law of the wrong sign, so they are
compiled without the certificate (they would not certify: PHC-E451)."""

from __future__ import annotations

import re

import numpy as np
import pytest

import phc
from phc.simulation.monitor import unbounded_growth

MODEL = """\
format_version: 1
name: runaway
parameters:
  x0: 2.0
components:
  b:
    type: phs
    states: [x]
    hamiltonian: x**2/2
    resistive:
      src: {{law: [e_src = {law}]}}
    relations:
      - f_x = -e_src
      - f_src = e_x
simulation:
  t_end: {t_end}
  n_out: 201
  initial: {{b.x: x0}}
  outputs: {{x: b.x}}
"""
"""ẋ = −e_src with f_src = x: the law e_src = −x·f_src gives ẋ = x², e_src = −f_src gives ẋ = x."""

X0 = 2.0
T_STAR = 1.0 / X0


def _compile(tmp_path, law, t_end):
    path = tmp_path / "runaway.yaml"
    path.write_text(MODEL.format(law=law, t_end=t_end))
    return phc.compile_model(path, certify=False)


def _stop_time(message):
    """The time the diagnosis names: `… grows without bound: it reached … at t = T, …`."""
    return float(re.search(r"grows without bound: it reached \S+ at t = ([0-9.e+-]+),", message).group(1))


@pytest.fixture(scope="module")
def square(tmp_path_factory):
    return _compile(tmp_path_factory.mktemp("square"), "-x*f_src", 1.0)


def _kept_against_closed_form(result, rel):
    x = result.outputs["x"]
    exact = X0 / (1.0 - X0 * result.t)
    assert len(result.t) > 50 and result.t[-1] < T_STAR
    assert np.max(np.abs(x - exact) / exact) < rel


def test_ida_names_the_blow_up_of_x_squared(square):
    result = phc.simulate(square)
    assert not result.success
    message = result.message
    assert "`b.x` grows without bound" in message and "finite-time blow-up" in message
    assert "raise `max_steps`" not in message
    # IDA follows x to some 1e56 before its steps collapse, so t* − t_stop = 1/x there is far
    # below the error of the blow-up time itself, which is the accumulated error of 1/x: IDA's
    # global error at rtol 1e-8 over a run of ~130 e-foldings of x stays below 100·rtol·t*
    t_stop = _stop_time(message)
    assert abs(t_stop - T_STAR) < 100 * 1e-8 * T_STAR
    # the outputs before it are kept, on the closed form to IDA's global error (as above)
    _kept_against_closed_form(result, 100 * 1e-8)


def test_ida_at_max_steps_names_the_blow_up_not_max_steps(square):
    result = phc.simulate(square, max_steps=3000)
    message = result.message
    assert not result.success and message.startswith("stopped after 3000 steps")
    assert "`b.x` grows without bound" in message and "finite-time blow-up" in message
    assert "raise `max_steps`" not in message
    assert 0.0 < T_STAR - _stop_time(message) < 1e-3 * T_STAR  # steps this short are only taken near t*


@pytest.mark.parametrize("solver", ["midpoint", "discrete_gradient"])
def test_fixed_step_newton_failure_names_the_blow_up(square, solver):
    h = 1e-3
    result = phc.simulate(square, solver=solver, step=h)
    message = result.message
    assert not result.success
    assert "`b.x` grows without bound" in message and "finite-time blow-up" in message
    assert "reduce `step`" not in message
    # The midpoint rule (the discrete gradient of x²/2 is the same step) has a real step from x
    # only while 1 − 2hx ≥ 0, i.e. x ≤ 1/(2h); its 1/x falls by h·m²/(x₀x₁) ≥ h a step (m the
    # mean of the step's ends, AM–GM), so its x is never below the exact one and the step that
    # fails starts after t* − 1/x reaches 2h, from a state the step before (from x < 1/(2h))
    # reached: within 4 steps before t*, never after it.
    t_stop = _stop_time(message)
    assert T_STAR - 4 * h <= t_stop < T_STAR
    # kept outputs: the midpoint rule's excess decrease of 1/x is h·(hx)²/4 a step, summed
    # h²/4·∫dt/(t* − t)² ≤ h²/4·x(t) up to t: a relative error of x below (hx)²/4, at most
    # (h·x_last)²/4 with x_last = 1/(t* − t_last) the last output kept; twice that for margin
    x_last = 1.0 / (T_STAR - result.t[-1])
    _kept_against_closed_form(result, 2 * (h * x_last) ** 2 / 4)


def test_midpoint4_names_the_supplying_dissipation(square):
    """midpoint4's passivity guard rejects every step of a model whose "dissipation" supplies
    power, at any step size: the message says that the resistive ports supply power, what makes
    a model so, and which solvers follow it — not the advice for a damped mode in the
    composition's unstable band (change the step by 10 %), which cannot help here. The power it
    names is that of the law at the rejected step's mean state, e·f = −x·f² with f = x: −x³,
    within the step's change of x₀ = 2 (the three substeps span at most 2γ₁h ≈ 2.7h, which
    moves x by 2.7·h·x₀² ≈ 1 % at h = 1e-3: −x³ by 3 %; 5 % allowed)."""
    for h in (1e-3, 1e-4):
        result = phc.simulate(square, solver="midpoint4", step=h)
        message = result.message
        assert not result.success
        assert "resistive ports supply power" in message and "PHC-E451" in message
        assert "`midpoint`, `discrete_gradient` or `ida`" in message
        assert "h·|λ|" not in message and "change `step`" not in message
        power = float(re.search(r"the dissipated power is (\S+) ", message).group(1))
        assert power == pytest.approx(-X0 ** 3, rel=0.05)


def test_exponential_growth_is_named_as_such(tmp_path):
    # ẋ = x from 2 overflows the energy x²/2 near t = ln(1e154/2) ≈ 354: IDA follows it there
    compiled = _compile(tmp_path, "-f_src", 400.0)
    result = phc.simulate(compiled)
    message = result.message
    assert not result.success
    assert "`b.x` grows without bound" in message and "exponential" in message
    assert "finite-time" not in message
    # the e-folding time it names is that of eᵗ, 1 s, to the digits printed
    assert re.search(r"grows by a factor e every 1\.0e\+00 s", message)
    # it stops at the last step before the power x·x overflows (x = √1.8e308 = 1.34e154): on the exact
    # solution at t = ln(1.34e154/2); the run's x carries the relative error ε it has at its last output
    # (ẋ = x carries a relative error unchanged), which moves that time by −ln(1 + ε); the last step
    # before it is shorter than 1 s (a step of eᵗ at rtol 1e-8 is a fraction of an e-folding)
    x = result.outputs["x"]
    eps = x[-1] / (X0 * np.exp(result.t[-1])) - 1.0
    t_over = np.log(np.sqrt(np.finfo(float).max) / X0) - np.log1p(eps)
    assert result.t[-1] > 300 and t_over - 1.0 < _stop_time(message) <= t_over * (1 + 1e-9)  # (10 digits printed)


def test_a_bounded_state_is_not_diagnosed_as_growth(square):
    mod = square.module
    n = mod.N
    i = list(mod.VARIABLES).index("b.x")
    y0, yp0 = np.zeros(n), np.zeros(n)
    y0[i], yp0[i] = 2.0, 4.0
    scales = np.ones(n)
    y, yp = y0.copy(), yp0.copy()
    y[i], yp[i] = 15.0, 1e4  # fast, but only 7.5 times its scale: not a blow-up yet
    assert unbounded_growth(mod, 0.4, y, yp, start=(0.0, y0, yp0), scales=scales) is None
    y[i], yp[i] = 1e3, 1e-3  # large, but growing slowly: a drift, not a failure's cause
    assert unbounded_growth(mod, 0.4, y, yp, start=(0.0, y0, yp0), scales=scales) is None
    y[i], yp[i] = 1e3, 1e6  # large and fast
    assert "`b.x` grows without bound" in unbounded_growth(mod, 0.4, y, yp, start=(0.0, y0, yp0), scales=scales)
