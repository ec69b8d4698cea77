"""Error estimates (`--estimate-error`) bracket the true error on closed forms; `--profile`."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

import phc
from phc.study.accuracy import estimate_errors
from phc.cli import main

MODELS = Path(__file__).resolve().parents[1] / "models"


def msd_exact(t):
    w = np.sqrt(3.96)  # m = 1, k = 4, c = 0.4: ω_d = √(k/m − (c/2m)²)
    return 0.5 * np.exp(-0.2 * t) * (np.cos(w * t) + 0.2 / w * np.sin(w * t))


@pytest.mark.parametrize("kwargs", [dict(solver="midpoint", step=0.01), dict(rtol=1e-6, atol=1e-8),
                                    dict(rtol=1e-9, atol=1e-11)])
def test_temporal_estimate_brackets_the_true_error(kwargs):
    compiled = phc.compile_model(MODELS / "mass_spring_damper.yaml")
    result = phc.simulate(compiled, **kwargs)
    true = np.abs(result.outputs["x"] - msd_exact(result.t)).max()
    (temporal,) = estimate_errors(compiled, result, kwargs)
    assert temporal.kind == "temporal" and temporal.ok
    assert true / 3 < temporal.per_output["x"] < 3 * true


def test_spatial_estimate_brackets_the_true_error_of_a_string(tmp_path):
    """d'Alembert: a force pulse F(t) on the end of a string fixed at the other end gives the
    end velocity (F(t) − 2F(t − τ) + 2F(t − 2τ) − …)/Z, Z = √(Tρ), τ = 2L/c, in the
    direction of the force."""
    scene = tmp_path / "s.yaml"
    scene.write_text(f"model: {MODELS / 'vibrating_string.yaml'}\nt_end: 0.03\nn_out: 301\n"
                     "accuracy: {mesh: {string: 32}}\noutputs: {v: string.b.f}\n")
    compiled = phc.compile_model(scene)
    result = phc.simulate(compiled)
    rho, T, L, F0, tp = 0.01, 64.0, 0.64, 1.0, 0.004
    Z, tau = np.sqrt(T * rho), 2 * L / np.sqrt(T / rho)

    def F(s):
        return np.where((s > 0) & (s < tp), F0 * np.sin(np.pi * s / tp) ** 2, 0.0)

    exact = (F(result.t) - 2 * F(result.t - tau) + 2 * F(result.t - 2 * tau)) / Z
    # The sign of v = string.b.f (generator convention: f·e is the power a port delivers;
    # a connection makes f_b = f_src, e_b = −e_src): the source imposes e_src = F, so the
    # string's end has e_b = −F and receives the power −f_b·e_b = f_b·F. Until the first
    # reflection the end is that of a semi-infinite string, a linear relation e_b = c·f_b
    # that can only receive power (−f_b·e_b = −c·f_b² ≥ 0): c = −Z, so f_b = F/Z, the same
    # sign as `exact` (and as the end velocity in tests/library/test_beams.py).
    v = result.outputs["v"]
    true = np.abs(v - exact).max()
    temporal, spatial = estimate_errors(compiled, result, {})
    assert spatial.kind == "spatial" and "32 → 64" in spatial.method
    assert true / 2 < spatial.per_output["v"] < 2 * true
    assert temporal.per_output["v"] < 1e-3 * true  # the mesh, not the time step, limits this run


def test_cli_estimate_error_and_profile(capsys):
    args = ["simulate", str(MODELS / "mass_spring_damper.yaml"), "--quiet", "--estimate-error", "--profile"]
    assert main(args) == 0
    out = capsys.readouterr().out
    assert "error    temporal ≈" in out and "profile  (CPU seconds)" in out and "residual evaluations" in out
    assert main(args + ["--format", "json"]) == 0
    data = json.loads(capsys.readouterr().out)
    assert data["error_estimates"][0]["kind"] == "temporal"
    prof = data["profile"]
    assert prof["residual evaluations"]["seconds"] > 0
    assert "calls" in prof["Jacobian evaluations"]["note"]
    assert all(v["seconds"] >= 0 for v in prof.values())


# IDA at rtol = atol = 1e-4: atol is relative to the nominal scales and IDA runs at 1/200
# of both (docs/tolerances.md), so 1e-5 is now accurate to 4e-9, below the 1e-8 the integration
# error must stay above for the model error not to matter
@pytest.mark.parametrize("kwargs", [dict(solver="midpoint", step=0.01), dict(rtol=1e-4, atol=1e-4)])
def test_temporal_estimate_brackets_the_small_angle_pendulum(tmp_path, kwargs):
    """Small-angle limit: θ = θ0 cos(√(g/L) t); for θ0 = 1e-3 the model error (O(θ0²)
    frequency shift, ~1e-9 in x here) is far below the integration error measured."""
    theta0 = 1e-3
    scene = tmp_path / "small.yaml"
    scene.write_text(f"model: {MODELS / 'pendulum.yaml'}\nt_end: 5.0\nn_out: 501\n"
                     f"initial: {{pendulum.x: {float(np.sin(theta0))!r}, pendulum.y: {{value: {float(-np.cos(theta0))!r}, "
                     "guess: true}}\noutputs: {x: pendulum.x}\n")
    compiled = phc.compile_model(scene)
    result = phc.simulate(compiled, **kwargs)
    exact = np.sin(theta0 * np.cos(np.sqrt(9.81) * result.t))
    true = np.abs(result.outputs["x"] - exact).max()
    assert true > 1e-8  # the integration error dominates the O(θ0³) model error
    (temporal,) = estimate_errors(compiled, result, kwargs)
    assert true / 3 < temporal.per_output["x"] < 3 * true


def test_relative_output_errors_against_a_reference():
    from types import SimpleNamespace

    from phc.study.accuracy import relative_output_errors

    ref = SimpleNamespace(outputs={"x": np.array([0.0, 2.0, -4.0]), "tiny": np.array([1e-17, -2e-17, 0.0]),
                                   "field": np.zeros((3, 2))})
    run = SimpleNamespace(outputs={"x": np.array([0.0, 2.1]),  # stopped early: compared where both are
                                   "tiny": np.array([1e-16, 0.0, 0.0]), "field": np.ones((3, 2))})
    errors = relative_output_errors(run, ref)
    # x over the two times both reached (scale 2); `tiny` is round-off, `field` not scalar
    assert set(errors) == {"x"} and abs(errors["x"] - 0.1 / 2.0) < 1e-15
