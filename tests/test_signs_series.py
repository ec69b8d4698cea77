"""The sign hint PHC-W230 through series loops (common-flow junctions), transformers and
gyrators (docs/signs.md, "Series chains and the sign of a node").

A source V, a resistor R and a capacitor C in a series loop (a common-flow junction)
charge the capacitor as ``q = C·V·(1 − e^{−t/RC})`` with the current
``i = V/R·e^{−t/RC}`` through the resistor. A two-port node (a common-effort junction
with ports x, y: ``e_x = e_y``, ``f_x = −f_y``) between the loop and one of its branches
turns that branch's voltage and current, so the capacitor charges to ``−C·V`` (node before
the capacitor), the resistor's current reads negated (node before the resistor), or the
source drives the other way round (node before the source). Each variant is simulated and
compared with the closed form written here, with the sign it must have; PHC-W230 must
warn exactly at the variants with a turned sign, at the connection given.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

import phc

REPO = Path(__file__).resolve().parents[1]
V, R, C, N, G, R_L = 12.0, 2.0, 0.25, 2.0, 2.0, 6.0

HEAD = """\
format_version: 1
name: {name}
parameters: {{V: 12.0, R: 2.0, C: 0.25, N: 2.0, G: 2.0, R_L: 6.0}}
components:
  src: {{type: effort_source, domain: electrical, value: V}}
  r: {{type: resistor, R: R}}
  cap: {{type: capacitor, C: C}}
{components}connections:
{wiring}simulation:
  t_end: 1.0
  rtol: 1.0e-10
  atol: 1.0e-12
  initial: {{cap.q: 0.0}}
  outputs: {{q: cap.q, i_r: r.port.f}}
"""


def node(name: str, ports: str = "[x, y]") -> str:
    return f"  {name}: {{type: junction, kind: common_effort, domain: electrical, ports: {ports}}}\n"


def loop(name: str = "loop", ports: str = "[s, r, c]") -> str:
    return f"  {name}: {{type: junction, kind: common_flow, domain: electrical, ports: {ports}}}\n"


def model(name: str, components: str, *wiring: tuple[str, str]) -> str:
    return HEAD.format(name=name, components=components,
                       wiring="".join(f"  - [{a}, {b}]\n" for a, b in wiring))


def rc(t, v_eff=V):
    """Charge and resistor current of the series RC loop charged from v_eff."""
    return C * v_eff * (1 - np.exp(-t / (R * C))), v_eff / R * np.exp(-t / (R * C))


def rc_parallel_load(t):
    """The loop drives the node of C ∥ R_L through R: a Thevenin source of
    V·R_L/(R + R_L) behind R·R_L/(R + R_L)."""
    v_th, r_th = V * R_L / (R + R_L), R * R_L / (R + R_L)
    q = C * v_th * (1 - np.exp(-t / (r_th * C)))
    v = q / C
    return q, (V - v) / R


TRANSFORMER = "  tr: {type: transformer, ratio: N, domain_a: electrical}\n"
GYRATOR = "  g: {type: gyrator, ratio: G, domain_a: electrical, domain_b: electrical}\n"


def gyrated(t):
    """A gyrator of ratio G makes the source a current source V/G into R and C in series."""
    return V / G * t, np.full_like(t, V / G)


# name, model text, closed form, sign of q, sign of the resistor's current, the warning
# (label, the two ends as the message names them) or None
VARIANTS = [
    ("direct", model("direct", loop(), ("src.port", "loop.s"), ("loop.r", "r.port"), ("loop.c", "cap.port")),
     rc, 1, 1, None),
    ("node_before_cap", model("node_cap", loop() + node("n"), ("src.port", "loop.s"), ("loop.r", "r.port"),
                              ("loop.c", "n.x"), ("n.y", "cap.port")),
     rc, -1, 1, ("connections[2]", "`loop.c` and `n.x` both read the voltage power-out")),
    ("node_before_resistor", model("node_res", loop() + node("n"), ("src.port", "loop.s"), ("loop.r", "n.x"),
                                   ("n.y", "r.port"), ("loop.c", "cap.port")),
     rc, 1, -1, ("connections[1]", "`loop.r` and `n.x` both read the voltage power-out")),
    ("node_before_source", model("node_src", loop() + node("n"), ("src.port", "n.x"), ("n.y", "loop.s"),
                                 ("loop.r", "r.port"), ("loop.c", "cap.port")),
     rc, -1, -1, ("connections[1]", "`n.y` and `loop.s` both read the voltage power-in")),
    ("two_nodes_before_cap", model("two_nodes", loop() + node("n") + node("m"), ("src.port", "loop.s"),
                                   ("loop.r", "r.port"), ("loop.c", "n.x"), ("n.y", "m.x"), ("m.y", "cap.port")),
     rc, 1, 1, None),
    ("a_node_before_every_branch", model("all_nodes", loop() + node("a") + node("b") + node("d"),
                                         ("src.port", "a.x"), ("a.y", "loop.s"), ("loop.r", "b.x"),
                                         ("b.y", "r.port"), ("loop.c", "d.x"), ("d.y", "cap.port")),
     rc, 1, 1, None),
    ("parallel_load_node", model("parallel", loop(ports="[s, r, o]") + node("n", "[x, c, l]")
                                 + "  load: {type: resistor, R: R_L}\n",
                                 ("src.port", "loop.s"), ("loop.r", "r.port"), ("loop.o", "n.x"),
                                 ("n.c", "cap.port"), ("n.l", "load.port")),
     rc_parallel_load, -1, 1, ("connections[2]", "`loop.o` and `n.x` both read the voltage power-out")),
    ("parallel_load_node_fixed", model("parallel_fixed", loop(ports="[s, r, o]") + node("m") + node("n", "[x, c, l]")
                                       + "  load: {type: resistor, R: R_L}\n",
                                       ("src.port", "loop.s"), ("loop.r", "r.port"), ("loop.o", "m.x"),
                                       ("m.y", "n.x"), ("n.c", "cap.port"), ("n.l", "load.port")),
     rc_parallel_load, 1, 1, None),
    ("two_loops_joined", model("two_loops", loop("j1", "[s, r, p]") + loop("j2", "[q, c]"),
                               ("src.port", "j1.s"), ("j1.r", "r.port"), ("j1.p", "j2.q"), ("j2.c", "cap.port")),
     rc, 1, 1, None),
    ("node_between_two_loops", model("two_loops_node", loop("j1", "[s, r, p]") + loop("j2", "[q, c]") + node("n"),
                                     ("src.port", "j1.s"), ("j1.r", "r.port"), ("j1.p", "n.x"), ("n.y", "j2.q"),
                                     ("j2.c", "cap.port")),
     rc, -1, 1, ("connections[2]", "`j1.p` and `n.x` both read the voltage power-out")),
    ("transformer", model("transformer", TRANSFORMER + loop(ports="[u, r, c]"),
                          ("src.port", "tr.a"), ("tr.b", "loop.u"), ("loop.r", "r.port"), ("loop.c", "cap.port")),
     lambda t: rc(t, V / N), 1, 1, None),
    ("node_after_transformer", model("transformer_node", TRANSFORMER + loop(ports="[u, r, c]") + node("n"),
                                     ("src.port", "tr.a"), ("tr.b", "n.x"), ("n.y", "loop.u"),
                                     ("loop.r", "r.port"), ("loop.c", "cap.port")),
     lambda t: rc(t, V / N), -1, -1, ("connections[1]", "`tr.b` and `n.x` both read the voltage power-out")),
    ("gyrator", model("gyrator", GYRATOR + loop(ports="[u, r, c]"),
                      ("src.port", "g.a"), ("g.b", "loop.u"), ("loop.r", "r.port"), ("loop.c", "cap.port")),
     gyrated, 1, 1, None),
    ("node_after_gyrator", model("gyrator_node", GYRATOR + loop(ports="[u, r, c]") + node("n"),
                                 ("src.port", "g.a"), ("g.b", "n.x"), ("n.y", "loop.u"),
                                 ("loop.r", "r.port"), ("loop.c", "cap.port")),
     gyrated, -1, -1, ("connections[1]", "`g.b` and `n.x` both read the voltage power-out")),
]


@pytest.mark.parametrize("name, text, closed_form, q_sign, i_sign, warning", VARIANTS,
                         ids=[v[0] for v in VARIANTS])
def test_charge_against_the_closed_form_and_the_warning(tmp_path, name, text, closed_form, q_sign, i_sign, warning):
    path = tmp_path / f"{name}.yaml"
    path.write_text(text, encoding="utf-8")
    result = phc.simulate(phc.compile_model(path), n_out=21)
    q, i = closed_form(result.t)
    np.testing.assert_allclose(result.outputs["q"], q_sign * q, rtol=1e-6, atol=1e-8)
    np.testing.assert_allclose(result.outputs["i_r"], i_sign * i, rtol=1e-6, atol=1e-8)

    report = phc.certify_model(path, samples=0)
    assert report.certified  # a hint, not an error
    hints = [d for d in report.diagnostics if d.code == "PHC-W230"]
    if warning is None:
        assert hints == [], [h.message for h in hints]
    else:
        label, ends = warning
        (hint,) = hints
        assert hint.severity == "warning" and hint.path == label
        assert ends in hint.message
        assert "common_effort" in hint.hint and "docs/signs.md" in hint.hint


def test_the_hint_at_a_loop_names_both_fixes(tmp_path):
    """Both fixes the hint names are variants above whose charge is +C·V: leaving out the
    two-port node (`direct`) and putting a second node in (`two_nodes_before_cap`)."""
    path = tmp_path / "node_cap.yaml"
    path.write_text(VARIANTS[1][1], encoding="utf-8")
    (hint,) = [d for d in phc.certify_model(path, samples=0).diagnostics if d.code == "PHC-W230"]
    assert "a port of the common-flow junction `loop` toward a load" in hint.message
    assert "put a node `{type: junction, kind: common_effort, domain: electrical, ports: [x, y]}` between them" \
        in hint.hint
    assert "leave out the two-port node `n`" in hint.hint


@pytest.mark.parametrize("relpath", ["models/rlc_circuit.yaml", "models/dc_motor_gear.yaml",
                                     "tests/models/valid/rl_pulse.yaml", "tests/library/models/dc_motor.yaml"])
def test_series_loops_joined_directly_stay_silent(relpath):
    """Elements and sources joined to a common-flow junction directly read the loop as
    drawn (their closed forms are tested elsewhere): no hint, also where a motor's
    gyrator to the shaft stops the reasoning."""
    from phc.checks.signs import sign_hints
    from phc.pipeline import build_dae

    dae, _ = build_dae(REPO / relpath)
    assert sign_hints(dae.topology) == []
