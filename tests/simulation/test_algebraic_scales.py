"""Circuits without or with one fast state, driven by a sine: the energy supplied and the
algebraic variables get scales that IDA's error test can meet (phc/simulation/scaling.py,
the energy throughput; phc/simulation/ida.py, ``determined_scales``).

Before: the resistive divider (no states) stopped after 10⁶ IDA steps at t = 1.3e-4 — the
energy supplied is identically 0 there (the source feeds the resistors, nothing is stored),
and its scale came out as 2e-18 J of round-off; the RL circuit took 556 000 steps for 0.1 s
(the inductor voltage V − Rφ/L, 0.04 V as the difference of 10 V terms, was tested at
1e-10 of its own size while ∂e/∂φ = −R/L = −25 000 ties it to the state's error).
Closed forms: i = V0 sin(ωt)/R and, for L di/dt + R i = V0 sin ωt with i(0) = 0,
i = V0/(R² + ω²L²) (R sin ωt − ωL cos ωt + ωL e^{−Rt/L}).
"""

from __future__ import annotations

import numpy as np
import pytest

import phc

V0, W, R1, RL = 10.0, 100.0, 5.0, 20.0

CIRCUIT = """\
format_version: 1
name: divider
parameters: {{V0: {V0}, w: {W}, R1: {R1}, RL: {RL}}}
components:
  src: {{type: effort_source, domain: electrical, value: V0*sin(w*t)}}
  r1: {{type: resistor, R: R1}}
  load: {{type: resistor, R: RL}}
  loop: {{type: junction, kind: common_flow, domain: electrical, ports: [s, d, r{extra_port}]}}
{coil}connections:
  - [src.port, loop.s]
  - [loop.d, r1.port]
  - [loop.r, load.port]
{coil_connection}simulation: {{t_end: 0.1, n_out: 101, outputs: {{i: load.port.f}}}}
"""


def _model(tmp_path, L=None):
    text = CIRCUIT.format(V0=V0, W=W, R1=R1, RL=RL, extra_port="" if L is None else ", l",
                          coil="" if L is None else f"  coil: {{type: inductor, L: {L}}}\n",
                          coil_connection="" if L is None else "  - [loop.l, coil.port]\n")
    path = tmp_path / "circuit.yaml"
    path.write_text(text, encoding="utf-8")
    return phc.compile_model(path, certify=False)


def test_a_circuit_without_states_runs_at_the_cost_of_its_source(tmp_path):
    r = phc.simulate(_model(tmp_path))
    assert r.success, r.message
    R = R1 + RL
    i = V0 * np.sin(W * r.t) / R
    sign = np.sign(np.dot(r["i"], i))  # the current as read through the series junction (docs/signs.md)
    assert np.abs(r["i"] - sign * i).max() < 1e-9 * np.abs(i).max()
    assert r.steps < 5_000  # was 10⁶ and a failure at t = 1.3e-4
    assert abs(r.energy_balance_error) < 1e-9  # nothing stored, nothing supplied in total


@pytest.mark.parametrize("L", [1e-3, 1.0])
def test_a_stiff_rl_circuit_driven_by_a_sine_takes_a_few_hundred_steps(tmp_path, L):
    r = phc.simulate(_model(tmp_path, L))
    assert r.success, r.message
    R, t = R1 + RL, r.t
    i = V0 / (R**2 + W**2 * L**2) * (R * np.sin(W * t) - W * L * np.cos(W * t) + W * L * np.exp(-R * t / L))
    sign = np.sign(np.dot(r["i"], i))  # the current as read through the series junction (docs/signs.md)
    assert np.abs(r["i"] - sign * i).max() < 1e-7 * np.abs(i).max()
    assert r.steps < 5_000  # L = 1e-3 H (τ = 40 µs) took 556 000 steps
