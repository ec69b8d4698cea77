"""Tests of :mod:`phc.simulation.monitor` (the singularity monitor of a run) through
:func:`phc.simulate` on the rigid slider–crank.

With the rod as long as the crank (L = r = 0.15) the rod can fold onto the crank: at crank
angles θ = π/2 + kπ the rod stands perpendicular to the guide, the joint constraints become
dependent and the interconnection loses surjectivity (seed, Prop. "Interconnection through
a finite-dimensional coupling space"). The run must stop there with a message naming the
dependent equations and keep the results computed so far. The default geometry (L = 2r)
never reaches such a configuration and runs to the end.
"""

from __future__ import annotations

import math
import re
from pathlib import Path

import numpy as np
import pytest

import phc

REPO = Path(__file__).resolve().parents[2]
SLIDER_CRANK = REPO / "models" / "rigid_slider_crank.yaml"
R, OMEGA = 0.15, 150.0   # crank radius and imposed crank speed of the shipped model


@pytest.fixture(scope="module")
def compiled():
    return phc.compile_model(SLIDER_CRANK)


@pytest.fixture(scope="module")
def folded(compiled):
    return phc.simulate(compiled, params={"L": 0.15})


def test_singular_configuration_stops_the_run(compiled, folded):
    t_end = compiled.dae.options["t_end"]
    assert folded.success is False
    assert "singular configuration" in folded.message
    assert folded.t[-1] < t_end
    assert len(folded.t) > 1
    assert np.all(np.diff(folded.t) > 0)
    assert folded.summary()["success"] is False


def test_message_names_dependent_equations(compiled, folded):
    names = re.findall(r"`([^`]+)`", folded.message.split("become dependent")[0])
    assert names, folded.message
    equations = set(compiled.module.EQUATIONS)
    assert set(names) <= equations, (names, sorted(equations))


def test_run_stops_where_the_rod_is_perpendicular_to_the_guide(folded):
    """The stop time in the message is a singular crank angle θ = π/2 + kπ (θ = ω t)."""
    match = re.search(r"stopped at t = ([0-9.eE+-]+)", folded.message)
    assert match, folded.message
    t_stop = float(match.group(1))
    assert folded.t[-1] <= t_stop
    assert abs(math.cos(OMEGA * t_stop)) < 0.05
    theta = folded["crank.theta"]
    assert theta[-1] == pytest.approx(OMEGA * folded.t[-1], rel=1e-6)


def test_results_before_the_stop_are_kept_and_valid(folded):
    """With L = r the slider sits on one of the branches s = 2r cos θ or s = 0."""
    theta, s = folded["crank.theta"], folded["slider.s"]
    assert np.all(np.isfinite(folded.y))
    off_branch = np.minimum(np.abs(s - 2 * R * np.cos(theta)), np.abs(s))
    assert off_branch.max() < 1e-6
    assert folded.constraint_drift < 1e-6


def test_default_slider_crank_runs_to_the_end(compiled):
    result = phc.simulate(compiled)
    t_end = compiled.dae.options["t_end"]
    assert result.success is True, result.message
    assert "singular" not in result.message
    assert result.t[-1] == pytest.approx(t_end)
    # the closed form of the shipped model's outputs: x = r cos θ + sqrt(L² − r² sin² θ)
    assert np.abs(result["slider_x"] - result["slider_x_exact"]).max() < 1e-6
