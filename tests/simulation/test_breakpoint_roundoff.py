"""A breakpoint within round-off of the end or of an output time (0.1 + 0.2 vs 0.3).

A force switched on at t_s = 0.3 drives a mass–spring at rest: x(t) = F/k·(1 − cos ω(t − t_s))
after the switch. The run's end (or an output time) is written as a sum that rounds to
0.30000000000000004: the integrators must not be asked for a piece of length 5e-17 (IDA
refuses such an interval), and every requested output time must be in the result.
Both drivers are covered: an input table's breakpoint (a scene's piecewise input) and a
switching condition (`ifelse` in a source's value).
"""

from __future__ import annotations

import math

import numpy as np
import pytest

import phc

M, K, F, T_SWITCH = 2.0, 8.0, 0.5, 0.3
OMEGA = math.sqrt(K / M)


def _model(tmp_path, force: str, exposed: bool) -> str:
    source = "" if exposed else f"""  push: {{type: effort_source, domain: mechanical.translational, value: "{force}"}}
"""
    extra = "" if exposed else "  - [node.to_push, push.port]\n"
    ports = "ports:\n  drive: {port: node.to_push}\n" if exposed else ""
    text = f"""parameters:
  m: {{value: {M}}}
  k: {{value: {K}}}
components:
  mass: {{type: mass, m: m}}
  spring: {{type: spring, k: k}}
{source}  node:
    type: junction
    kind: common_flow
    domain: mechanical.translational
    ports: [to_mass, to_spring, to_push]
connections:
  - [node.to_mass, mass.port]
  - [node.to_spring, spring.port]
{extra}{ports}simulation:
  t_end: 1.0
  rtol: 1.0e-10
  atol: 1.0e-12
  initial: {{spring.x: 0.0, mass.p: 0.0}}
  outputs:
    x: spring.x
"""
    path = tmp_path / "pushed.yaml"
    path.write_text(text)
    return str(path)


def _scene(tmp_path, model: str, t_end: float, n_out: int, solver: str) -> str:
    path = tmp_path / "scene.yaml"
    path.write_text(f"""model: {model}
t_end: {t_end!r}
n_out: {n_out}
solver: {solver}
accuracy: {{step: 1.0e-4, rtol: 1.0e-10, atol: 1.0e-12}}
inputs:
  drive:
    effort:
      - {{until: {T_SWITCH}, value: 0.0}}
      - {{value: {-F}}}   # an input effort on an exposed port acts on the model with the port's sign
outputs:
  x: spring.x
""")
    return str(path)


def _exact(t):
    t = np.asarray(t)
    return np.where(t > T_SWITCH, F / K * (1 - np.cos(OMEGA * (t - T_SWITCH))), 0.0)


# 0.1 + 0.2 = 0.30000000000000004; linspace(0, 0.9000000000000001, 4)[1] likewise lands
# within round-off of the breakpoint
CASES = [(0.1 + 0.2, 7), (0.1 + 0.2, 2), (0.9000000000000001, 4)]


@pytest.mark.parametrize("solver", ["ida", "midpoint"])
@pytest.mark.parametrize("t_end, n_out", CASES)
def test_an_input_breakpoint_within_roundoff(tmp_path, solver, t_end, n_out):
    model = _model(tmp_path, "", exposed=True)
    result = phc.simulate(_scene(tmp_path, model, t_end, n_out, solver))
    assert result.success, result.message
    t_out = np.linspace(0.0, t_end, n_out)
    assert np.array_equal(result.t, t_out)
    # IDA at rtol 1e-10 and midpoint at h = 1e-4 (error ~ (ωh)²/24 relative): 1e-7 of F/k
    assert np.max(np.abs(result.outputs["x"] - _exact(t_out))) < 1e-7 * F / K


@pytest.mark.parametrize("solver", ["ida", "midpoint"])
@pytest.mark.parametrize("t_end, n_out", CASES)
def test_a_switching_time_within_roundoff(tmp_path, solver, t_end, n_out):
    model = _model(tmp_path, f"ifelse(t < {T_SWITCH}, 0, {F})", exposed=False)  # a source delivers e·f
    step = {"step": 1e-4} if solver == "midpoint" else {}
    result = phc.simulate(model, t_end=t_end, n_out=n_out, solver=solver, **step)
    assert result.success, result.message
    t_out = np.linspace(0.0, t_end, n_out)
    assert np.array_equal(result.t, t_out)
    assert np.max(np.abs(result.outputs["x"] - _exact(t_out))) < 1e-7 * F / K
