"""The positive corpus: every ``tests/models/valid/*.yaml`` must validate, compile and simulate.

The models exercise language features the shipped ``models/`` do not: a ``phs`` in J/R/B
form with ``effort_in`` and ``flow_in`` ports, a ``phs`` in kernel form with a multiplier
and a resistive port, a nested ``type: model`` with parameter overrides and an exposed
port (its inner file lives in ``valid/parts/`` and is valid on its own), ``dimension: 2``
one-ports, an ``orthogonal_transform`` with ``split``, a ``common_effort`` junction, a time
function with ``ifelse``, a rigid body with ``velocity_constraints`` and an exposed port
driven by ``simulation.inputs``.

Every model simulates over its own (short) ``simulation.t_end`` with ``success`` and a
relative energy-balance error below 1e-6; each model's header comment gives the closed
form or invariant that its own test below checks.
"""

from __future__ import annotations

from functools import lru_cache
from pathlib import Path

import numpy as np
import pytest

import phc
from phc.cli import main

VALID = Path(__file__).parent / "valid"
MODELS = sorted(VALID.glob("*.yaml")) + sorted((VALID / "parts").glob("*.yaml"))
IDS = [str(p.relative_to(VALID)) for p in MODELS]


@lru_cache(maxsize=None)
def _run(name: str):
    """Compile and simulate ``valid/<name>`` once per test session."""
    compiled = phc.compile_model(VALID / name)
    return compiled, phc.simulate(compiled)


def test_corpus_is_there():
    assert len(MODELS) >= 8


@pytest.mark.parametrize("path", MODELS, ids=IDS)
def test_validates_cleanly(path, capsys):
    code = main(["validate", str(path)])
    captured = capsys.readouterr()
    assert code == 0, captured.err
    assert captured.err == ""   # not even a warning
    assert captured.out.startswith(f"{path}: ok (")


@pytest.mark.parametrize("path", MODELS, ids=IDS)
def test_compiles_and_simulates(path):
    compiled, result = _run(str(path.relative_to(VALID)))
    assert result.success, result.message
    assert result.t[-1] == pytest.approx(compiled.dae.options["t_end"])
    assert np.all(np.isfinite(result.y))
    assert result.energy_balance_relative < 1e-6


def _damped(t, x0, alpha, omega_d):
    """Free damped oscillation from rest: x0 e^{-αt}(cos ω_d t + α/ω_d sin ω_d t)."""
    return x0 * np.exp(-alpha * t) * (np.cos(omega_d * t) + alpha / omega_d * np.sin(omega_d * t))


def test_lc_oscillator_phs_step_response():
    _, r = _run("lc_oscillator_phs.yaml")
    L, C, R, V0 = 0.5, 0.02, 1.0, 3.0
    alpha = R / (2 * L)
    omega_d = np.sqrt(1 / (L * C) - alpha**2)
    q = C * V0 - _damped(r.t, C * V0, alpha, omega_d)
    assert np.abs(r["lc.q"] - q).max() < 1e-7 * C * V0
    # the current is dq/dt (the flow_in port is held at zero flow)
    i = C * V0 * np.exp(-alpha * r.t) * (omega_d + alpha**2 / omega_d) * np.sin(omega_d * r.t)
    assert np.abs(r["current"] - i).max() < 1e-7 * np.abs(i).max()
    # the frequency: zero crossings of q − C V0 are π/ω_d apart
    d = r["lc.q"] - C * V0
    crossings = r.t[:-1][np.sign(d[:-1]) != np.sign(d[1:])]
    assert np.diff(crossings) == pytest.approx(np.pi / omega_d, abs=2 * (r.t[1] - r.t[0]))
    # the resistor dissipates: less energy is stored than the source delivered
    assert r.energy_supplied[-1] < 0 < r.H[-1] < -r.energy_supplied[-1]


def test_kernel_phs_multiplier_matches_one_mass():
    _, r = _run("kernel_phs_multiplier.yaml")
    m1, m2, k, c = 1.0, 3.0, 16.0, 0.8
    M = m1 + m2
    alpha = c / (2 * M)
    x = _damped(r.t, 0.2, alpha, np.sqrt(k / M - alpha**2))
    assert np.abs(r["pair.x"] - x).max() < 1e-7
    # the multiplier keeps both velocities equal
    assert np.abs(r["pair.p1"] / m1 - r["pair.p2"] / m2).max() < 1e-8
    # the damper only takes energy out
    assert np.all(np.diff(r.H) <= 1e-12)


def test_nested_model_equals_its_flat_equivalent():
    _, nested = _run("nested_oscillator.yaml")
    _, flat = _run("nested_oscillator_flat.yaml")
    assert np.abs(nested["x"] - flat["x"]).max() < 1e-10
    assert np.abs(nested["osc.mass.p"] - flat["mass.p"]).max() < 1e-10
    assert np.abs(nested.H - flat.H).max() < 1e-10
    # and the overrides took effect: m = 2, k = 2*stiffness = 18, d = 0.6
    alpha = 0.6 / (2 * 2.0)
    x = _damped(nested.t, 0.3, alpha, np.sqrt(18.0 / 2.0 - alpha**2))
    assert np.abs(nested["x"] - x).max() < 1e-7


def test_nested_parameters_are_prefixed_and_overridden():
    compiled, _ = _run("nested_oscillator.yaml")
    params = {p.name: p for p in compiled.dae.parameters}
    assert params["osc.m"].default == 2.0
    assert params["osc.k"].default == 18.0


def test_planar_mass_runs_on_an_ellipse():
    _, r = _run("planar_mass_2d.yaml")
    omega = np.sqrt(8.0 / 0.5)
    assert np.abs(r["spring.x[0]"] - 0.4 * np.cos(omega * r.t)).max() < 1e-7
    assert np.abs(r["spring.x[1]"] - 1.2 / omega * np.sin(omega * r.t)).max() < 1e-7
    assert np.ptp(r.H) < 1e-6 * r.H[0]   # no damping: energy is conserved


def test_rotated_springs_decouple():
    _, r = _run("rotated_springs_split.yaml")
    assert np.abs(r["along.x"] - 0.1 * np.cos(2.0 * r.t)).max() < 1e-7     # ω_s = sqrt(4/1)
    assert np.abs(r["across.x"] + 0.05 * np.cos(5.0 * r.t)).max() < 1e-7   # ω_n = sqrt(25/1)
    # Q is orthogonal, so the transform neither stores nor dissipates energy
    assert np.ptp(r.H) < 1e-6 * r.H[0]


def test_parallel_rc_discharges_exponentially():
    _, r = _run("parallel_rc.yaml")
    tau = 100.0 * 1.0e-3
    assert np.abs(r["cap.q"] - 2.0e-3 * np.exp(-r.t / tau)).max() < 1e-9
    assert np.abs(r["voltage"] - 2.0 * np.exp(-r.t / tau)).max() < 1e-6


def test_rl_pulse_follows_ifelse():
    _, r = _run("rl_pulse.yaml")
    L, R, V0, T = 0.2, 2.0, 5.0, 0.25
    tau = L / R
    i_T = V0 / R * (1 - np.exp(-T / tau))
    i = np.where(r.t <= T, V0 / R * (1 - np.exp(-r.t / tau)), i_T * np.exp(-(r.t - T) / tau))
    assert np.abs(r["current"] - i).max() < 1e-6
    assert r["current"].argmax() == np.searchsorted(r.t, T)   # the peak is at the switch-off


def test_knife_edge_runs_on_a_circle():
    _, r = _run("knife_edge.yaml")
    u, omega = 1.5, 2.0
    assert np.abs(r["sled.theta"] - omega * r.t).max() < 1e-8
    assert np.abs(r["sled.x"] - u / omega * np.sin(omega * r.t)).max() < 1e-7
    assert np.abs(r["sled.y"] - u / omega * (1 - np.cos(omega * r.t))).max() < 1e-7
    assert r.velocity_drift < 1e-8
    assert np.ptp(r.H) < 1e-6 * r.H[0]   # the constraint force does no work


def test_input_drives_exposed_port():
    _, r = _run("driven_oscillator.yaml")
    m, k, F0 = 1.0, 9.0, 2.0
    x = F0 / k * (1 - np.cos(np.sqrt(k / m) * r.t))
    assert np.abs(r["x"] - x).max() < 1e-7
    # all stored energy came in through the port: H(t) = −E_supplied(t), E(0) = 0
    assert np.abs(r.H + r.energy_supplied).max() < 1e-8
    assert r.H.max() > 0.1


def test_exposed_port_is_external():
    compiled, _ = _run("driven_oscillator.yaml")
    assert compiled.dae.external_ports == ("push",)
