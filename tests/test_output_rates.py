"""``der(x)`` in outputs: the rate of a state, read from the solution's ẏ (issue 36 item 1).

The damped oscillator m ẍ = −k x − c ẋ: its acceleration output ``der(mass.p)/m`` must equal
−(k x + c v)/m computed from the position and velocity outputs of the same run, and
``der(spring.x)`` the velocity; ``der`` outside outputs, of a non-state or of an expression
is a located error.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

import phc
from phc.errors import ModelError

MODELS = Path(__file__).resolve().parents[1] / "models"
M, K, C = 1.0, 4.0, 0.4  # models/mass_spring_damper.yaml


def _model(tmp_path, outputs: str, extra: str = "") -> Path:
    text = (MODELS / "mass_spring_damper.yaml").read_text()
    assert "    energy: H\n" in text and "  k: {value: 4.0" in text
    text = text.replace("    energy: H\n", "    energy: H\n" + outputs)
    if extra:
        text = text.replace("  spring: {type: spring, k: k}\n", "  spring: {type: spring, k: k}\n" + extra)
    path = tmp_path / "msd.yaml"
    path.write_text(text)
    return path


def test_rates_of_states_are_outputs(tmp_path):
    path = _model(tmp_path, "    a: der(mass.p) / m\n    rate: der(spring.x)\n")
    result = phc.simulate(path, t_end=5.0, n_out=51, solver="ida", rtol=1e-10, atol=1e-12)
    assert result.success, result.message
    x, v, a = result.outputs["x"], result.outputs["v"], result.outputs["a"]
    # ẏ at the output times satisfies the residual to IDA's local error (rtol 1e-10 on values
    # of order 1): the equation of motion, from x and v of the same run, to 1e-7 of k·x
    assert np.max(np.abs(a + (K * x + C * v) / M)) < 1e-7 * K * 0.5
    assert np.max(np.abs(result.outputs["rate"] - v)) < 1e-7 * 0.5 * np.sqrt(K / M)


def test_rates_carry_units(tmp_path):
    pytest.importorskip("pint")
    path = _model(tmp_path, "    a: der(mass.p) / m\n")
    compiled = phc.compile_model(path, certify=False)
    assert compiled.description.units["a"] in ("m/s²", "m/s^2", "m/s**2", "m / s ** 2")


@pytest.mark.parametrize("outputs, extra, message", [
    ("    bad: der(v)\n", "", "is not a known name"),
    ("    bad: der(mass.p * 2)\n", "", "takes the name of a state"),
    ("    bad: der(m)\n", "", "`m` is not a state"),
    ("", "  push: {type: effort_source, domain: mechanical.translational, value: \"der(spring.x)\"}\n",
     "can be used in outputs only"),
])
def test_misused_rates_are_located_errors(tmp_path, outputs, extra, message):
    path = _model(tmp_path, outputs, extra)
    with pytest.raises(ModelError) as err:
        phc.compile_model(path, certify=False)
    found = [d for d in err.value.diagnostics if message in d.message]
    assert found, [d.message for d in err.value.diagnostics]
    assert found[0].span is not None and found[0].span.file.endswith("msd.yaml") and found[0].span.line > 1
