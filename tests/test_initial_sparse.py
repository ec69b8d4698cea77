"""Consistent initialization through sparse least-norm solves (phc/simulation/minnorm.py):
the dense and sparse paths give the same start, and a large beam never calls dense
least squares."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
import scipy.linalg as sla

import phc
import phc.simulation.initial as initial
import phc.simulation.minnorm as minnorm
from phc.simulation import initial_values, parameter_vector

MODELS = Path(__file__).resolve().parent.parent / "models"


def _start(compiled):
    mod = compiled.module
    p = parameter_vector(mod, None)
    values, fixed = initial_values(compiled, p)
    return initial.consistent_initial_conditions(mod, p, float(compiled.options.get("t_start", 0.0)), values, fixed)


@pytest.mark.parametrize("name", ["pendulum", "double_pendulum", "rigid_slider_crank", "vibrating_string",
                                  "flexible_slider_crank"])
def test_dense_and_sparse_paths_agree(name, monkeypatch):
    compiled = phc.compile_model(str(MODELS / f"{name}.yaml"), certify=False, backend="numpy")
    dense = _start(compiled)
    # every solve through the sparse paths: LU of the regular part, else LSMR
    monkeypatch.setattr(minnorm, "DENSE_SOLVE_LIMIT", 0)
    monkeypatch.setattr(initial, "DENSE_LIMIT", 0)
    sparse = _start(compiled)
    # Both converge to the initialization's tolerance (1e-11 of the largest value) on the
    # same least-norm solution: they differ by the rounding of the solves, amplified by
    # the Newton iteration's tolerance, not by a different choice of the guessed states.
    for a, b in ((dense.y0, sparse.y0), (dense.yp0, sparse.yp0)):
        scale = max(1.0, float(np.abs(a).max()))
        assert np.max(np.abs(a - b)) <= 1e-8 * scale


def test_large_beam_initialization_calls_no_dense_lstsq(monkeypatch, tmp_path):
    src = (MODELS / "euler_bernoulli_beam.yaml").read_text()
    assert "elements: 6" in src
    path = tmp_path / "beam.yaml"
    path.write_text(src.replace("elements: 6", "elements: 100"))
    compiled = phc.compile_model(str(path), certify=False, backend="numpy")
    calls = []
    lstsq = sla.lstsq

    def counting(*args, **kwargs):
        calls.append(np.shape(args[0]))
        return lstsq(*args, **kwargs)

    monkeypatch.setattr(sla, "lstsq", counting)
    init = _start(compiled)
    assert not calls, f"dense least squares on {calls}"
    assert init.residual <= 1e-10
