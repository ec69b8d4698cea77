"""Tests of the `modulation` component in `phc.library.lumped` (seed section 4.2)."""

import numpy as np
import pytest

import phc
from phc.checks.certify import certify

MODEL = """
format_version: 1
parameters: {{m: 1.0, k: 4.0, b: 0.7}}
components:
  mass: {{type: mass, m: m, dimension: 2}}
  spring: {{type: spring, k: k, dimension: 2}}
  mod:
    type: modulation
    K: {K}
  node: {{type: junction, kind: common_flow, dimension: 2, ports: [m, s]}}
connections:
  - [mass.port, mod.a]
  - [mod.b, node.m]
  - [node.s, spring.port]
simulation:
  t_end: 5
  rtol: 1.0e-10
  atol: 1.0e-12
  initial:
    spring.x[0]: 0.1
    spring.x[1]: 0.0
"""


@pytest.mark.parametrize("K", [
    '[[0, b], ["-b", 0]]',                                              # constant (a gyrator-like field)
    '[[0, "b*(1 + spring.x[0])"], ["-b*(1 + spring.x[0])", 0]]',        # modulated by another component's state
])
def test_modulation_preserves_power_and_is_certified(tmp_path, K):
    path = tmp_path / "m.yaml"
    path.write_text(MODEL.format(K=K))
    result = phc.simulate(phc.compile_model(path))
    assert result.success
    assert result.energy_balance_relative < 1e-7          # lossless: H is conserved
    assert np.abs(result["spring.x[1]"]).max() > 1e-3     # and the skew coupling does act
    cert = certify(phc.build_dae(path)[0])
    mod = next(c for c in cert.components if c.name == "mod")
    assert (mod.dim_z, mod.dim_d, mod.dirac) == (4, 4, True)


def test_non_skew_modulation_is_rejected(tmp_path):
    path = tmp_path / "m.yaml"
    path.write_text(MODEL.format(K='[[0, b], [b, 0]]'))
    dae, diags = phc.build_dae(path)
    assert dae is None
    assert [d.code for d in diags.errors] == ["PHC-E402"]
    assert diags.errors[0].path == "components.mod.K"
