"""Messages an engineer reads (issue 36 item 6): an unknown name (PHC-E101) is offered the
close names the model defines — all of them, never phc's own `t` or `pi` — and told where a
new parameter goes; an initial value or nominal scale for a state that does not exist
(PHC-E210) is offered states of the kind it asks for (a position for `body.x`, never the
momentum `body.p`), or told that the component has none; every message writes a place in
the file in one style, `connections[7][1]`, with only the keys the user wrote."""

from __future__ import annotations

import re
import textwrap

import pytest

from phc.cli import main

LINE = re.compile(r"^(?P<file>[^:]+):(?P<line>\d+):(?P<col>\d+): (?P<path>[^ ]+): (?P<rest>.*) \[(?P<code>PHC-[EW]\d{3})\]$")


def _errors(tmp_path, capsys, text: str, code: str) -> list[re.Match]:
    path = tmp_path / "model.yaml"
    path.write_text(textwrap.dedent(text), encoding="utf-8")
    assert main(["validate", str(path)]) == 1
    lines = capsys.readouterr().err.strip().splitlines()
    found = [LINE.match(line) for line in lines if f"[{code}]" in line]
    assert found and all(found), lines
    return found


# -- PHC-E101: a name the model does not define ----------------------------------------

STIFF = """\
    format_version: 1
    parameters: {{stiff_front: 40.0, stiff_rear: 60.0, m: 1.0}}
    components:
      mass: {{type: mass, m: m}}
      spring: {{type: spring, k: {k}}}
    connections:
      - [mass.port, spring.port]
    """


def test_an_unknown_name_is_offered_every_close_name_and_told_where_parameters_go(tmp_path, capsys):
    (m,) = _errors(tmp_path, capsys, STIFF.format(k="stiff_fron"), "PHC-E101")
    assert m["path"] == "components.spring.k"
    assert "hint: did you mean `stiff_front` or `stiff_rear`? Or add it under `parameters:`" in m["rest"]


def test_an_unknown_name_is_never_offered_phcs_own_names(tmp_path, capsys):
    for k in ("tt", "pii", "kappa"):
        (m,) = _errors(tmp_path, capsys, STIFF.format(k=k), "PHC-E101")
        hint = m["rest"].split("hint: ", 1)[1]
        assert not re.search(r"`(t|pi|H|sin|exp)`", hint), hint
        assert "add it under `parameters:`" in hint
    assert "defined here: `m`, `stiff_front`, `stiff_rear`" in hint  # nothing close to `kappa`


# -- PHC-E210: a state that does not exist ---------------------------------------------

QUARTER_CAR = """\
    format_version: 1
    parameters: {{m_body: 300.0, m_wheel: 40.0, k_s: 2.0e4, k_t: 2.0e5, c_s: 1500.0}}
    components:
      body: {{type: mass, m: m_body}}
      wheel: {{type: mass, m: m_wheel}}
      susp: {{type: spring, k: k_s, terminals: [top, bottom], domain: mechanical.translational}}
      damper: {{type: damper, d: c_s, terminals: [top, bottom], domain: mechanical.translational}}
      tire: {{type: spring, k: k_t}}
      top: {{type: junction, kind: common_flow, domain: mechanical.translational, ports: [body, s, d]}}
      axle: {{type: junction, kind: common_flow, domain: mechanical.translational, ports: [wheel, s, d, tire]}}
    connections:
      - [top.body, body.port]
      - [top.s, susp.top]
      - [top.d, damper.top]
      - [susp.bottom, axle.s]
      - [damper.bottom, axle.d]
      - [axle.wheel, wheel.port]
      - [axle.tire, tire.port]
    simulation:
      t_end: 1.0
      {section}: {{{name}: 0.01}}
    """


@pytest.mark.parametrize("section", ["initial", "nominal"])
def test_a_position_of_a_mass_is_offered_positions_not_its_momentum(tmp_path, capsys, section):
    (m,) = _errors(tmp_path, capsys, QUARTER_CAR.format(section=section, name="body.x"), "PHC-E210")
    assert m["path"] == f"simulation.{section}.body.x"
    assert "`body` (a mass) has no position state, only its momentum `body.p`" in m["rest"]
    assert "hint: `position: true` on `body` adds its position `body.x`; or: position states in this model: " \
        "`susp.x`, `tire.x`" in m["rest"]
    assert "did you mean `body.p`" not in m["rest"]


def test_a_velocity_of_a_mass_is_told_to_give_its_momentum(tmp_path, capsys):
    (m,) = _errors(tmp_path, capsys, QUARTER_CAR.format(section="initial", name="wheel.v"), "PHC-E210")
    assert "`wheel` (a mass) has no velocity state" in m["rest"]
    assert "hint: give its momentum `wheel.p` (mass × velocity) instead" in m["rest"]


def test_an_output_of_a_position_is_not_offered_a_momentum(tmp_path, capsys):
    text = QUARTER_CAR.format(section="outputs", name="body_x").replace("body_x: 0.01", "body_x: body.x")
    (m,) = _errors(tmp_path, capsys, text, "PHC-E101")
    assert "unknown name `body.x`" in m["rest"] and "`body.p`" not in m["rest"]


def test_a_misspelt_state_is_offered_the_state_of_its_kind(tmp_path, capsys):
    (m,) = _errors(tmp_path, capsys, QUARTER_CAR.format(section="initial", name="tyre.x"), "PHC-E210")
    assert "hint: did you mean `tire.x`?" in m["rest"]


# -- one path style -----------------------------------------------------------------------

WIRED = """\
    format_version: 1
    components:
      mass: {{type: mass, m: 1.0}}
      spring: {{type: spring, k: 4.0}}
      osc:
        type: phs
        states: [q, p]
        hamiltonian: q**2/2 + p**2/2
        J: [[0, 1], [-1, oops]]
    connections:
      - [mass.port, spring.port]
      {connection}
    """


def test_paths_index_lists_in_brackets_and_name_only_keys_the_user_wrote(tmp_path, capsys):
    text = WIRED.format(connection="- [spring.port, mass.prot]")
    found = {m["code"]: m for m in _errors(tmp_path, capsys, text, "PHC-E201")}
    assert found["PHC-E201"]["path"] == "connections[1][1]"  # before: connections.1.between.1
    (m,) = _errors(tmp_path, capsys, text, "PHC-E101")
    assert m["path"] == "components.osc.J[1][1]"  # before: components.osc.J.1.1
    (m,) = _errors(tmp_path, capsys, WIRED.format(connection="- {between: [spring.port, mass.prot]}"), "PHC-E201")
    assert m["path"] == "connections[1].between[1]"  # the key written: named


def test_schema_errors_use_the_same_path_style(tmp_path, capsys):
    (m,) = _errors(tmp_path, capsys, WIRED.format(connection="- [spring.port, mass.port, osc.x]"), "PHC-E016")
    assert m["path"] == "connections[1]"


# -- PHC-W230 where the user is ---------------------------------------------------------

RC_FED = """\
    format_version: 1
    parameters: {V: 12.0, R: 2.0, C: 0.25}
    components:
      src: {type: flow_source, domain: electrical, value: V/R}
      n: {type: junction, kind: common_effort, domain: electrical, ports: [s, c, r]}
      r: {type: resistor, R: R}
      cap: {type: capacitor, C: C}
    connections:
      - [n.c, cap.port]
      - [src.port, n.s]
      - [n.r, r.port]
    simulation:
      t_end: 1.0
      outputs: {q: cap.q}
    """


@pytest.mark.parametrize("command", [["validate"], ["simulate", "--quiet"]])
def test_the_sign_hint_is_printed_by_validate_and_simulate(tmp_path, capsys, command):
    """Before, only `phc check` warned that a current source feeding the node of R ∥ C reads
    the node power-out like the node's own ports, which negates the charge (docs/signs.md)."""
    path = tmp_path / "rc.yaml"
    path.write_text(textwrap.dedent(RC_FED), encoding="utf-8")
    assert main([*command, str(path)]) == 0
    hints = [line for line in capsys.readouterr().err.splitlines() if "[PHC-W230]" in line]
    assert len(hints) == 1 and hints[0].startswith(f"{path}:10:") and ": warning: connections[1]: " in hints[0]
    assert "`src.port` and `n.s` both read the voltage power-out" in hints[0]
