"""`SimResult.timings`: the run's CPU time by phase (what a benchmark of a solver's step cost
reads instead of differencing whole calls, whose one-off costs follow the time span)."""

from __future__ import annotations

import json
import math
from pathlib import Path

import pytest

import phc

MODELS = Path(__file__).resolve().parents[2] / "models"
RUN = ("start", "scales", "integrate", "polish")  # the phases `cpu_time_s` covers


@pytest.fixture(scope="module")
def pendulum():
    return phc.compile_model(MODELS / "pendulum.yaml")


@pytest.mark.parametrize("solver", ["ida", "midpoint"])
def test_phases_add_up_to_the_run(pendulum, solver):
    res = phc.simulate(pendulum, t_end=0.5, n_out=11, solver=solver)
    assert res.success, res.message
    assert tuple(res.timings) == (*RUN, "finish")
    assert all(v >= 0.0 and math.isfinite(v) for v in res.timings.values())
    # telescoping differences of the same clock readings: equal up to the rounding of a few
    # additions of numbers below the process's CPU time (~1e3 s at most, eps ~ 2e-13 s)
    assert sum(res.timings[k] for k in RUN) == pytest.approx(res.cpu_time_s, abs=1e-9)


def test_timings_are_in_the_json_summary(pendulum):
    res = phc.simulate(pendulum, t_end=0.1, n_out=3, solver="midpoint")
    summary = json.loads(json.dumps(res.summary()))
    assert set(summary["timings"]) == {*RUN, "finish"}
    assert summary["timings"]["integrate"] == res.timings["integrate"]
