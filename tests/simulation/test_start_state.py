"""The consistent state at t₀: solved once per compiled model, and a stage that cannot
succeed is not run.

`compile_model` certifies the compiled equations at the consistent start state; `simulate`
with the same parameters and initial values starts from that state instead of solving
again (phc.simulation.start_state). Consistent initialization first holds every state
(stage 1) and only then lets the guessed ones move (stage 2); `_Problem.hopeless` skips
stage 1 when rows that are affine in its unknowns cannot be met. Both must leave every
result as it was: the tests compare against the unskipped, uncached computation.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

import phc
import phc.simulation as simulation
import phc.simulation.initial as initial
from phc.simulation import initial_values, parameter_vector

MODELS = Path(__file__).resolve().parents[2] / "models"


def _solve_both_ways(path, monkeypatch):
    """(result with the skip, result without it, number of stage solves with the skip)."""
    compiled = phc.compile_model(path, certify=False)
    mod = compiled.module
    p = parameter_vector(mod)
    values, fixed = initial_values(compiled, p)
    calls = []
    solve = initial._solve
    monkeypatch.setattr(initial, "_solve", lambda *a, **k: calls.append(1) or solve(*a, **k))
    skipped = initial.consistent_initial_conditions(mod, p, 0.0, values, fixed)
    n_skipped = len(calls)
    monkeypatch.setattr(initial._Problem, "hopeless", lambda self, bound: False)
    full = initial.consistent_initial_conditions(mod, p, 0.0, values, fixed)
    return skipped, full, n_skipped, len(calls) - n_skipped


def test_a_hopeless_first_stage_is_skipped_with_the_same_result(monkeypatch, tmp_path):
    """The moving beam given its end momenta only (per dof; the shipped model gives the
    whole momentum field): the guessed interior momenta do not fit the motion of its ends:
    holding them, its mass rows M e = p cannot hold, so stage 1 fails after all its iterations."""
    text = (MODELS / "moving_beam.yaml").read_text()
    field = "    beam.p: rhoA*v0*(1 - 2*xi/L)"
    assert field in text
    path = tmp_path / "moving_beam.yaml"
    path.write_text(text.replace(field, "    beam.p[0]: rhoA*v0\n    beam.p[16]: -rhoA*v0\n    #"))
    skipped, full, n_skipped, n_full = _solve_both_ways(path, monkeypatch)
    assert (n_skipped, n_full) == (1, 2)
    assert np.array_equal(skipped.y0, full.y0) and np.array_equal(skipped.yp0, full.yp0)
    assert skipped.chosen == full.chosen


def test_a_first_stage_that_can_succeed_runs(monkeypatch):
    """The pendulum's given state is consistent: stage 1 succeeds and is not skipped."""
    skipped, full, n_skipped, n_full = _solve_both_ways(MODELS / "pendulum.yaml", monkeypatch)
    assert (n_skipped, n_full) == (1, 1)
    assert np.array_equal(skipped.y0, full.y0)


@pytest.mark.parametrize("model", ["pendulum", "rlc_circuit"])
def test_simulate_starts_from_the_certificate_state(model, monkeypatch):
    certified = phc.compile_model(MODELS / f"{model}.yaml")
    assert certified.certificate.certified and certified.cache.start_state is not None
    plain = phc.compile_model(MODELS / f"{model}.yaml", certify=False)
    expected = phc.simulate(plain, t_end=0.05, solver="midpoint", n_out=11)

    def no_second_solve(*args, **kwargs):
        raise AssertionError("the start state was solved again")

    monkeypatch.setattr(simulation, "consistent_initial_conditions", no_second_solve)
    result = phc.simulate(certified, t_end=0.05, solver="midpoint", n_out=11)
    assert result.success
    assert np.array_equal(result.y, expected.y) and np.array_equal(result.yp, expected.yp)
    # other parameters: another start state, solved (here: refused by the stub)
    name = certified.module.PARAMETERS[certified.module.BASE_PARAMETERS[0]]
    value = float(certified.module.PARAMETER_DEFAULTS[certified.module.BASE_PARAMETERS[0]])
    with pytest.raises(AssertionError, match="solved again"):
        phc.simulate(certified, t_end=0.05, solver="midpoint", n_out=11, params={name: 1.5 * value})
