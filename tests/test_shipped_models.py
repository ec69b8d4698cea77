"""End-to-end tests of the shipped models in ``models/`` through :func:`phc.compile_model`
and :func:`phc.simulate` (:mod:`phc.pipeline`, :mod:`phc.simulation`).

Every model is checked against a closed-form solution or a physical invariant derived
here, independently of the model file (never against numbers printed by an earlier run).
"""

from __future__ import annotations

import math
from functools import lru_cache
from pathlib import Path

import numpy as np
import pytest
from scipy.integrate import quad

import phc
from phc.errors import InconsistentInitialError

REPO = Path(__file__).resolve().parents[1]
MODELS = REPO / "models"


@lru_cache(maxsize=None)
def compiled(name: str) -> phc.CompiledModel:
    return phc.compile_model(MODELS / f"{name}.yaml")


@lru_cache(maxsize=None)
def default_run(name: str) -> phc.SimResult:
    result = phc.simulate(compiled(name))
    assert result.success, result.message
    return result


# -- mass–spring–damper ------------------------------------------------------------
# m x'' + c x' + k x = 0 with x the spring elongation. On the common-flow junction the
# spring's elongation rate equals the mass velocity (all port flows equal), so
# x' = v = p/m and m v' = -k x - c v.


def damped_oscillator(t, m, k, c, x0, v0=0.0):
    """(x, v) of m x'' + c x' + k x = 0 in the underdamped case."""
    w0 = math.sqrt(k / m)
    zeta = c / (2.0 * math.sqrt(k * m))
    assert zeta < 1.0
    wd = w0 * math.sqrt(1.0 - zeta**2)
    a = zeta * w0
    b = (v0 + a * x0) / wd
    decay = np.exp(-a * t)
    x = decay * (x0 * np.cos(wd * t) + b * np.sin(wd * t))
    v = decay * ((b * wd - a * x0) * np.cos(wd * t) - (x0 * wd + a * b) * np.sin(wd * t))
    return x, v


def test_mass_spring_damper_matches_the_underdamped_closed_form():
    result = default_run("mass_spring_damper")
    x, v = damped_oscillator(result.t, m=1.0, k=4.0, c=0.4, x0=0.5)
    assert result.t[-1] == 10.0
    assert np.abs(result["x"] - x).max() <= 1e-6
    assert np.abs(result["spring.x"] - x).max() <= 1e-6
    assert np.abs(result["v"] - v).max() <= 1e-6
    assert np.abs(result["mass.p"] - 1.0 * v).max() <= 1e-6


def test_mass_spring_damper_dissipates_exactly_c_v_squared():
    m, k, c, x0 = 1.0, 4.0, 0.4, 0.5
    result = default_run("mass_spring_damper")
    x, v = damped_oscillator(result.t, m, k, c, x0)
    # H = p²/2m + k x²/2 along the exact solution, and H(t) - H(0) = -∫ c v² dt.
    assert np.abs(result.H - (0.5 * m * v**2 + 0.5 * k * x**2)).max() <= 1e-6
    lost = np.cumsum([0.0] + [quad(lambda s: c * damped_oscillator(s, m, k, c, x0)[1] ** 2, a, b,
                                   epsabs=1e-14, epsrel=1e-12)[0]
                              for a, b in zip(result.t[:-1], result.t[1:])])
    assert np.abs((result.H - result.H[0]) - (-lost)).max() <= 1e-6
    assert np.abs(result.dissipation - c * v**2).max() <= 1e-6
    assert np.abs(result.port_power).max() == 0.0  # closed system: no external ports
    assert result.energy_balance_relative <= 1e-7


def test_parameter_study_reuses_one_compilation():
    model = phc.compile_model(MODELS / "mass_spring_damper.yaml")
    for k in (4.0, 9.0):
        result = phc.simulate(model, params={"k": k})
        assert result.success, result.message
        x, _ = damped_oscillator(result.t, m=1.0, k=k, c=0.4, x0=0.5)
        assert np.abs(result["x"] - x).max() <= 1e-6
        assert result.energy_balance_relative <= 1e-7


# -- RLC circuit -------------------------------------------------------------------


def test_rlc_charge_matches_the_step_response():
    L, C, R, V0 = 0.5, 0.02, 2.0, 12.0
    result = default_run("rlc_circuit")
    t = result.t
    alpha = R / (2 * L)
    wd = math.sqrt(1 / (L * C) - alpha**2)
    q = C * V0 * (1 - np.exp(-alpha * t) * (np.cos(wd * t) + alpha / wd * np.sin(wd * t)))
    i = C * V0 * np.exp(-alpha * t) * (alpha**2 + wd**2) / wd * np.sin(wd * t)  # q'
    assert t[-1] == 2.0
    assert np.abs(result["charge"] - q).max() <= 1e-6
    assert np.abs(result["capacitor.q"] - q).max() <= 1e-6
    assert np.abs(result["current"] - i).max() <= 1e-6 * max(1.0, np.abs(i).max())
    assert result.energy_balance_relative <= 1e-7


# -- pendulum ----------------------------------------------------------------------


def test_pendulum_conserves_energy_and_stays_on_the_circle():
    L = 1.0
    result = default_run("pendulum")
    assert result.t[-1] == 20.0
    assert result.energy_balance_relative <= 1e-8
    assert result.constraint_drift / L**2 <= 1e-8
    assert result.invariant_labels == ("pendulum.constraints[0]",)
    radius = np.hypot(result["pendulum.x"], result["pendulum.y"])
    assert np.abs(radius - L).max() <= 1e-8


def upward_zero_crossings(t, x):
    i = np.flatnonzero((x[:-1] < 0) & (x[1:] >= 0))
    return t[i] - x[i] * (t[i + 1] - t[i]) / (x[i + 1] - x[i])


def test_pendulum_small_angle_period():
    L, g, theta0 = 1.0, 9.81, 0.1
    # The bob hangs at y = -L (V = m g y); release at rest at angle theta0 from the vertical.
    result = phc.simulate(compiled("pendulum"), t_end=12.0, n_out=6001,
                          initial={"pendulum.x": L * math.sin(theta0), "pendulum.y": -L * math.cos(theta0)})
    assert result.success, result.message
    crossings = upward_zero_crossings(result.t, result["pendulum.x"])
    assert len(crossings) >= 4
    period = float(np.mean(np.diff(crossings)))
    expected = 2 * math.pi * math.sqrt(L / g) * (1 + theta0**2 / 16)
    assert abs(period - expected) / expected <= 1e-4


def test_inconsistent_fixed_initial_values_are_reported():
    with pytest.raises(InconsistentInitialError, match=r"pendulum\.constraints\[0\]"):
        phc.simulate(compiled("pendulum"), t_end=0.1, initial={"pendulum.x": 1.1, "pendulum.y": 0.0})


@pytest.mark.parametrize("guess, chosen", [(0.3, 0.8), (-0.3, -0.8)])
def test_guessed_initial_value_is_chosen_on_the_constraint(guess, chosen):
    result = phc.simulate(compiled("pendulum"), t_end=0.1,
                          initial={"pendulum.y": (guess, True), "pendulum.x": 0.6})
    assert result.success, result.message
    assert result.initial_choices.keys() == {"pendulum.y"}
    assert result.initial_choices["pendulum.y"] == pytest.approx(chosen, abs=1e-10)
    assert result["pendulum.x"][0] == 0.6
    assert result["pendulum.y"][0] == pytest.approx(chosen, abs=1e-10)


# -- rigid slider–crank ------------------------------------------------------------


def test_slider_crank_follows_the_kinematic_closed_form():
    r, L, omega = 0.15, 0.30, 150.0
    result = default_run("rigid_slider_crank")
    t = result.t
    theta = result["crank.theta"]
    assert t[-1] == 0.1
    assert np.abs(theta - omega * t).max() <= 1e-9
    slider = r * np.cos(theta) + np.sqrt(L**2 - r**2 * np.sin(theta) ** 2)
    assert np.abs(result["slider.s"] - slider).max() <= 1e-8


def test_slider_crank_energy_balance_closes_with_the_drive_work():
    result = default_run("rigid_slider_crank")
    # The drive does work: the stored energy changes substantially ...
    assert np.ptp(result.H) > 1.0
    assert np.abs(result.port_power).max() > 0.0
    # ... and is accounted for by the supplied energy.
    assert result.energy_balance_relative <= 1e-7


# -- solver statistics -------------------------------------------------------------


def test_step_count_does_not_depend_on_the_number_of_outputs():
    model = compiled("pendulum")
    few = phc.simulate(model, t_end=0.5, n_out=2)
    many = phc.simulate(model, t_end=0.5, n_out=2001)
    # Output values are interpolated by IDA; the integration itself is the same.
    assert many.n_residual_evals == few.n_residual_evals
    assert many.steps == few.steps
    assert many.steps <= many.n_residual_evals  # each step costs at least one residual evaluation
