"""A mass's position (`position: true`, issue 36 item 1): ẋ = p/m beside the momentum.

In the damped oscillator (mass, spring and damper sharing one velocity) the mass's position
started at the spring's elongation stays equal to it: both integrate the same velocity.
The position carries no energy (H is unchanged), the structure stays a Dirac structure
(the certificate passes), the position is an initial value and an output like any state,
and it has the unit of a length (an angle for a rotational mass).
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

import phc

MODELS = Path(__file__).resolve().parents[2] / "models"


def _model(tmp_path, domain_line: str = "") -> Path:
    text = (MODELS / "mass_spring_damper.yaml").read_text()
    assert "  mass: {type: mass, m: m}\n" in text and "    spring.x: 0.5" in text
    text = text.replace("  mass: {type: mass, m: m}\n", "  mass: {type: mass, m: m, position: true}\n")
    text = text.replace("    spring.x: 0.5", "    mass.x: 0.5\n    spring.x: 0.5")
    text = text.replace("    energy: H\n", "    energy: H\n    where: mass.x\n")
    path = tmp_path / "msd_position.yaml"
    path.write_text(text)
    return path


@pytest.mark.parametrize("solver", ["ida", "midpoint"])
def test_the_position_follows_the_velocity(tmp_path, solver):
    compiled = phc.compile_model(_model(tmp_path))  # certified: still a Dirac structure
    plain = phc.simulate(MODELS / "mass_spring_damper.yaml", t_end=5.0, n_out=51, solver=solver)
    result = phc.simulate(compiled, t_end=5.0, n_out=51, solver=solver)
    assert result.success, result.message
    # one velocity, integrated twice from the same start: equal to the integrator's error
    # (IDA at rtol 1e-10 of values ~0.5; midpoint's two integrals are the same sum)
    assert np.max(np.abs(result.outputs["where"] - result.outputs["x"])) < 1e-8
    # the position has no energy: the motion and H are the model's without it
    assert np.max(np.abs(result.outputs["x"] - plain.outputs["x"])) < 1e-8
    assert np.max(np.abs(result.outputs["energy"] - plain.outputs["energy"])) < 1e-8


def test_the_position_has_a_length_unit(tmp_path):
    pytest.importorskip("pint")
    compiled = phc.compile_model(_model(tmp_path), certify=False)
    assert compiled.description.units["where"] == "m"
    assert compiled.description.units["mass.p"] in ("kg*m/s", "kg·m/s", "N*s", "N·s")
