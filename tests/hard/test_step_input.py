"""Step and discontinuous inputs: a torque switched on at t = 0.05 (issue 8).

The input is a piecewise signal; its breakpoint stops the integrators at t = 0.05 exactly
and they restart from a consistent state (phc/simulation/__init__.py). Before the step the
mechanism rests at the dead centre; after it the crank accelerates.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

import phc

MODELS = Path(__file__).resolve().parents[2] / "models"


def scene(tmp_path: Path, flexible: bool, solver: str) -> Path:
    effects = "" if flexible else "effects: {rod: {flexibility: off}}\n"
    path = tmp_path / f"step_{solver}_{flexible}.yaml"
    path.write_text(f"""model: {MODELS / 'flexible_slider_crank.yaml'}
parameters: {{omega0: 0.0}}
{effects}t_end: 0.06
n_out: 61
solver: {solver}
accuracy: {{step: 2.0e-5, rtol: 1.0e-8, atol: 1.0e-10}}
inputs:
  drive:
    effort:
      - {{until: 0.05, value: 0.0}}
      - {{value: -0.5}}
outputs:
  theta: wheel.theta
  speed: wheel.p_theta / Iw
""")
    return path


@pytest.mark.parametrize("flexible, solver", [(False, "ida"), (False, "midpoint"), (True, "midpoint")])
def test_torque_step_is_located_and_integrated(tmp_path, flexible, solver):
    compiled = phc.compile_model(scene(tmp_path, flexible, solver))
    assert compiled.module.BREAKPOINTS == (0.05,)
    result = phc.simulate(compiled)
    assert result.success, result.message
    before = result.t <= 0.05 + 1e-12
    assert np.abs(result.outputs["theta"][before]).max() < 1e-12  # at rest until the step
    assert result.outputs["speed"][-1] > 1.0                      # and turning after it
    # the work done by the torque is what the mechanism stores: the balance closes
    assert result.energy_balance_relative < (1e-7 if solver == "ida" else 1e-12)
    # right after the step the crank accelerates as τ / I_eff with I_eff = Iw + what the rod adds
    # at the dead centre (θ = 0: the pin moves normal to the rod, the slider not at all)
    k = int(np.searchsorted(result.t, 0.051))
    dt = result.t[k] - 0.05
    accel = result.outputs["speed"][k] / dt
    assert 0.5 / (1e-3 + 0.15**2 * 0.50368 * 0.3) < accel * 1.05 and accel < 0.5 / 1e-3
