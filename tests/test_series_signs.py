"""Series chains keep the sign a user draws (docs/signs.md, "Series chains keep the sign you
draw"; issue 36 item 3).

The rule (:mod:`phc.ir.wires`): in the electrical, hydraulic and thermal domains a connection
that joins a terminal of a two-terminal element to a port that reads power-in (another
terminal, the one port of a storage or resistive element, port `a` of a transformer or
gyrator) is a wire, ``e_x = e_y``, ``f_x = −f_y``. So along a chain written
``source → x.a``, ``x.b → y.a``, … every element's flow is positive from its `a` to its `b`
(the chain current as drawn) and ``v_a − v_b`` is the drop in that direction; writing an
element the other way round (`b` toward the source) negates exactly its own current.

Each model here is checked against an independent solution written in the test, with the
sign as drawn: the loudspeaker drawn in series (source, coil resistance, coil inductance, the
motor's gyrator to a mass–spring–damper) against scipy's solution of its ODE, a series RLC
against its closed form. Before the rule, ``r.b → coil.a`` negated the coil's current (and
``r.b → cap.port`` the capacitor's charge), so the comparisons with the drawn signs fail.
"""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest
from scipy.integrate import solve_ivp

import phc
from phc.checks.signs import sign_hints
from phc.pipeline import build_dae

MODELS = Path(__file__).resolve().parents[1] / "models"
V, F, R, L, BL, M, K, C = 2.83, 200.0, 6.0, 5.0e-4, 5.0, 0.01, 2000.0, 2.7  # models/loudspeaker.yaml

SPEAKER = """\
format_version: 1
name: speaker_in_series
parameters: {{V: 2.83, f: 200.0, R: 6.0, L: 5.0e-4, Bl: 5.0, m: 0.01, k: 2000.0, c: 2.7}}
components:
  source: {{type: effort_source, domain: electrical, value: "V*sin(2*pi*f*t)"}}
  coil_r: {{type: resistor, R: R, terminals: [a, b]}}
  coil_l: {{type: inductor, L: L, terminals: [a, b]}}
  motor: {{type: gyrator, ratio: Bl, domain_a: electrical, domain_b: mechanical.translational}}
  cone: {{type: mass, m: m}}
  suspension: {{type: spring, k: k}}
  losses: {{type: damper, d: c}}
  moving: {{type: junction, kind: common_flow, domain: mechanical.translational, ports: [g, m, k, d]}}
connections:
{chain}  - [motor.b, moving.g]
  - [moving.m, cone.port]
  - [moving.k, suspension.port]
  - [moving.d, losses.port]
simulation:
  t_end: 0.02
  n_out: 201
  rtol: 1.0e-10
  atol: 1.0e-12
  outputs:
    current: coil_l.phi / L
    current_r: coil_r.a.f
    drop_r: coil_r.b.e - coil_r.a.e
    velocity: cone.p / m
    excursion: suspension.x
"""


def chain(*pairs) -> str:
    return "".join(f"  - [{a}, {b}]\n" for a, b in pairs)


AS_DRAWN = chain(("source.port", "coil_r.a"), ("coil_r.b", "coil_l.a"), ("coil_l.b", "motor.a"))
# every element written the other way round: its `b` toward the source
TURNED = chain(("source.port", "coil_r.b"), ("coil_r.a", "coil_l.b"), ("coil_l.a", "motor.a"))
# the same chain as AS_DRAWN, each pair and the pairs' order written backwards
BACKWARDS = chain(("motor.a", "coil_l.b"), ("coil_l.a", "coil_r.b"), ("coil_r.a", "source.port"))


def speaker_reference(t):
    """The loudspeaker's equations with the signs as drawn (the voltage drives the coil
    current i from the source through R and L into the motor's port `a`, whose force Bl·i
    pushes the cone forward): L i' = V sin(2π f t) − R i − Bl v, m v' = Bl i − k x − c v,
    x' = v, from rest. Radau with the constant Jacobian: the coil's mode (−R/L) is stiff."""
    A = np.array([[-R / L, -BL / L, 0.0], [BL / M, -C / M, -K / M], [0.0, 1.0, 0.0]])

    def rhs(s, y):
        return A @ y + np.array([V * math.sin(2 * math.pi * F * s) / L, 0.0, 0.0])

    ref = solve_ivp(rhs, (0.0, t[-1]), [0.0, 0.0, 0.0], t_eval=t, method="Radau", jac=lambda s, y: A,
                    rtol=1e-12, atol=1e-14)
    assert ref.success
    return ref.y


def run(tmp_path, name, text):
    path = tmp_path / f"{name}.yaml"
    path.write_text(text, encoding="utf-8")
    dae, _ = build_dae(path)
    return phc.simulate(phc.compile_model(path)), dae


def close(actual, expected):
    """Both solutions are accurate to about 1e-9 of their amplitude (IDA at rtol 1e-10,
    Radau at 1e-12); 1e-6 of the amplitude leaves that margin many times over and is far
    below a sign error, which is twice the amplitude."""
    scale = np.abs(expected).max()
    assert scale > 0
    np.testing.assert_allclose(actual, expected, rtol=0, atol=1e-6 * scale)


def test_the_loudspeaker_drawn_in_series_has_the_current_as_drawn(tmp_path):
    result, dae = run(tmp_path, "as_drawn", SPEAKER.format(chain=AS_DRAWN))
    i, v, x = speaker_reference(result.t)
    close(result.outputs["current"], i)          # the inductor's φ/L: from its a to its b
    close(result.outputs["current_r"], i)        # the resistor's terminal a: the current into it
    close(result.outputs["drop_r"], R * i)       # v_a − v_b = −(e_a − e_b) = R i, in the drawn direction
    close(result.outputs["velocity"], v)         # a positive current pushes the cone forward
    close(result.outputs["excursion"], x)
    assert dae.topology.wires == {"connections[1]", "connections[2]"}  # not the source's bond
    assert sign_hints(dae.topology) == []


def test_the_loudspeaker_in_series_agrees_with_the_shipped_loop_model(tmp_path):
    """models/loudspeaker.yaml draws the same circuit as a series loop (a common-flow
    junction): the chain of two-terminal elements gives the same current and motion."""
    shipped = phc.simulate(phc.compile_model(MODELS / "loudspeaker.yaml"), t_end=0.02, n_out=201)
    result, _ = run(tmp_path, "as_drawn", SPEAKER.format(chain=AS_DRAWN))
    for name in ("current", "velocity", "excursion"):
        close(result.outputs[name], shipped.outputs[name])


def test_an_element_written_the_other_way_round_reads_its_own_current_negated(tmp_path):
    """The rule's prediction: with every element's `b` toward the source, each element's
    current (positive from its `a` to its `b`) and voltage drop read negated, and nothing
    else changes — the motor's port `a` still takes the current the source drives."""
    result, dae = run(tmp_path, "turned", SPEAKER.format(chain=TURNED))
    i, v, x = speaker_reference(result.t)
    close(result.outputs["current"], -i)
    close(result.outputs["current_r"], -i)
    close(result.outputs["drop_r"], -R * i)
    close(result.outputs["velocity"], v)
    close(result.outputs["excursion"], x)
    assert sign_hints(dae.topology) == []


def test_the_order_a_connection_is_written_in_does_not_matter(tmp_path):
    """A wire, like a bond, is symmetric in its two ends: the chain written from the motor
    back to the source, each pair backwards, is the same circuit."""
    result, dae = run(tmp_path, "backwards", SPEAKER.format(chain=BACKWARDS))
    i, v, _ = speaker_reference(result.t)
    close(result.outputs["current"], i)
    close(result.outputs["velocity"], v)
    assert dae.topology.wires == {"connections[0]", "connections[1]"}


RLC = """\
format_version: 1
name: rlc_chain
parameters: {{V: 10.0, R: 2.0, L: 0.5, C: 0.1}}
components:
  src: {{type: effort_source, domain: electrical, value: V}}
  r: {{type: resistor, R: R, terminals: [a, b]}}
  l: {{type: inductor, L: L, terminals: [a, b]}}
{cap}connections:
{chain}simulation:
  t_end: 3.0
  n_out: 151
  rtol: 1.0e-10
  atol: 1.0e-12
  outputs: {{i: l.phi / L, i_r: r.a.f, q: cap.q}}
"""
ONE_PORT_CAP = "  cap: {type: capacitor, C: C}\n"
TWO_TERMINAL_CAP = ("  cap: {type: capacitor, C: C, terminals: [a, b]}\n"
                    "  ground: {type: zero_effort, domain: electrical}\n")


def rlc_closed_form(t, Vs=10.0, Rs=2.0, Ls=0.5, Cs=0.1):
    """L q'' + R q' + q/C = V from rest, underdamped (α = R/2L = 2, ω_d = 4 here):
    q = C V (1 − e^{−αt}(cos ω_d t + α/ω_d sin ω_d t)), i = q' = V/(L ω_d) e^{−αt} sin ω_d t."""
    a = Rs / (2 * Ls)
    wd = math.sqrt(1 / (Ls * Cs) - a * a)
    q = Cs * Vs * (1 - np.exp(-a * t) * (np.cos(wd * t) + a / wd * np.sin(wd * t)))
    i = Vs / (Ls * wd) * np.exp(-a * t) * np.sin(wd * t)
    return q, i


@pytest.mark.parametrize("cap, last, sign_i", [
    (ONE_PORT_CAP, chain(("src.port", "r.a"), ("r.b", "l.a"), ("l.b", "cap.port")), 1),
    (TWO_TERMINAL_CAP, chain(("src.port", "r.a"), ("r.b", "l.a"), ("l.b", "cap.a"), ("cap.b", "ground.port")), 1),
    (ONE_PORT_CAP, chain(("src.port", "r.b"), ("r.a", "l.b"), ("l.a", "cap.port")), -1),
], ids=["one_port_capacitor", "two_terminal_capacitor_to_ground", "elements_turned"])
def test_a_series_rlc_driven_by_a_source_has_the_current_of_the_closed_form(tmp_path, cap, last, sign_i):
    """The capacitor charges to +C·V as drawn (q/C = v_a − v_b for a two-terminal
    capacitor, the node voltage for a one-port one); the current is the closed form's with
    the sign the rule gives: + from each element's `a` to its `b` along the chain, − for
    the elements written the other way round."""
    result, dae = run(tmp_path, "rlc", RLC.format(cap=cap, chain=last))
    q, i = rlc_closed_form(result.t)
    close(result.outputs["q"], q)
    close(result.outputs["i"], sign_i * i)
    close(result.outputs["i_r"], sign_i * i)
    assert sign_hints(dae.topology) == []


TRANSFORMED = """\
format_version: 1
name: transformed
parameters: {{V: 12.0, R: 2.0, C: 0.25, N: {ratio}}}
components:
  src: {{type: effort_source, domain: electrical, value: V}}
  tr: {{type: transformer, ratio: N, domain_a: electrical}}
  r: {{type: resistor, R: R, terminals: [a, b]}}
  cap: {{type: capacitor, C: C}}
connections:
{chain}  - [r.b, cap.port]
simulation:
  t_end: 1.0
  n_out: 21
  rtol: 1.0e-10
  atol: 1.0e-12
  outputs: {{q: cap.q}}
"""


@pytest.mark.parametrize("ratio, wiring, sign", [
    (0.5, chain(("src.port", "tr.a"), ("tr.b", "r.a")), 1),
    (2.0, chain(("src.port", "tr.b"), ("tr.a", "r.a")), -1),
], ids=["a_toward_the_source", "b_toward_the_source"])
def test_a_transformer_takes_power_in_at_a(tmp_path, ratio, wiring, sign):
    """A transformer (f_b = N f_a: v_b = v_a/N) passes the source's V to the chain as 2·V
    either way round (N = 1/2 from `a`, N = 2 from `b`); the RC chain then charges to
    C·2V(1 − e^{−t/RC}). Drawn with `a` toward the source the sign is kept. Drawn with `b`
    toward the source, `r.a → tr.a` is still a wire (the rule does not look past the
    transformer), port `a` reads the voltage power-out there, and the wire turns the sign:
    the charge is negated and PHC-W230 says so at that connection, with the fix."""
    result, dae = run(tmp_path, "tr", TRANSFORMED.format(ratio=ratio, chain=wiring))
    tau = 2.0 * 0.25
    close(result.outputs["q"], sign * 0.25 * 2 * 12.0 * (1 - np.exp(-result.t / tau)))
    hints = sign_hints(dae.topology)
    if sign > 0:
        assert hints == []
    else:
        (hint,) = hints
        assert hint.path == "connections[1]" and hint.severity == "warning"
        assert "`tr.a` reads the voltage power-out" in hint.message and "the wire" in hint.message
        assert "turn `tr` round so that its port `a` faces the source" in hint.hint


CHAIN_TO_STORE = """\
format_version: 1
name: chain_{domain}
parameters: {{P: 3.0, R1: 1.0, R2: 3.0, C: 0.5}}
components:
  src: {{type: effort_source, domain: {domain}, value: P}}
  r1: {{type: resistor, R: R1, domain: {domain}, terminals: [a, b]}}
  r2: {{type: resistor, R: R2, domain: {domain}, terminals: [a, b]}}
  store: {{type: capacitor, C: C, domain: {domain}}}
connections:
  - [src.port, r1.a]
  - [r1.b, r2.a]
  - [r2.b, store.port]
simulation:
  t_end: 4.0
  n_out: 41
  rtol: 1.0e-10
  atol: 1.0e-12
  outputs: {{q: store.q, flow: r2.a.f}}
"""


@pytest.mark.parametrize("domain", ["hydraulic", "thermal"])
def test_the_rule_holds_in_every_effort_across_domain(tmp_path, domain):
    """A pressure (temperature) P behind R1 and R2 in series fills (heats) a store C:
    q = C P (1 − e^{−t/τ}), τ = (R1 + R2) C, with the flow P/(R1 + R2) e^{−t/τ} from each
    resistor's `a` to its `b`; the mechanical domains keep bonds (a chain of springs keeps
    its signs with them): models/quarter_car.yaml's two-terminal tyre has no wire."""
    result, dae = run(tmp_path, domain, CHAIN_TO_STORE.format(domain=domain))
    tau = (1.0 + 3.0) * 0.5
    close(result.outputs["q"], 0.5 * 3.0 * (1 - np.exp(-result.t / tau)))
    close(result.outputs["flow"], 3.0 / 4.0 * np.exp(-result.t / tau))
    assert dae.topology.wires == {"connections[1]", "connections[2]"}
    assert sign_hints(dae.topology) == []
    car, _ = build_dae(MODELS / "quarter_car.yaml")
    assert car.topology.wires == frozenset()
