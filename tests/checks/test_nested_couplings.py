"""Couplings inside nested models get their own certificate.

A connection written in a nested file is labelled with the instance's name
(``inner.connections[0]``), so it does not collide with the top-level file's
``connections[0]``; ``phc check`` certifies every connection once, and a coupling map Γ
that is not onto (Proposition 3 "Interconnection through a finite-dimensional coupling
space" of T. Berger, R. Hochdahl, T. Reis, R. Seifried, "Port-Hamiltonian modelling of
coupled rigid/flexible multibody systems") inside a nested file is reported at that file's
line.
"""

from __future__ import annotations

import json
import math
import re

import pytest

import phc
from phc.checks.certify import certify
from phc.checks.graph import traversal_order
from phc.cli import main

# The wheel of tests/checks/invalid/gamma_rank_deficient_on_subset in a file of its own:
# its port flow is cos(th)*w and a flow source imposes it, so Γ has rank 1 of 2 where
# cos(th) = 0 (the initial state set by the outer file). A second port (B = 1) is exposed
# and damped at the top level, where Γ is onto.
INNER = """\
format_version: 1
components:
  wheel:
    type: rigid
    q: [th]
    M: [[1]]
    ports:
      drive:
        B: [["cos(th)"]]
      brake:
        B: [[1]]
  motor: {type: flow_source, value: 1.0}
connections:
  - [motor.port, wheel.drive]
ports:
  shaft: {port: wheel.brake}
"""

OUTER = """\
format_version: 1
name: outer
components:
  inner: {type: model, file: inner.yaml}
  damper: {type: damper, d: 0.5}
connections:
  - [inner.shaft, damper.port]
simulation:
  initial: {inner.wheel.th: 1.5707963267948966}
"""


@pytest.fixture
def nested(tmp_path, monkeypatch):
    (tmp_path / "inner.yaml").write_text(INNER, encoding="utf-8")
    (tmp_path / "outer.yaml").write_text(OUTER, encoding="utf-8")
    monkeypatch.chdir(tmp_path)
    return tmp_path / "outer.yaml"


def test_every_connection_has_its_own_label_and_certificate(nested):
    dae, diags = phc.build_dae(nested)
    assert dae is not None, "\n".join(d.render() for d in diags)
    labels = [label for _, _, label, _ in dae.topology.connections]
    assert sorted(labels) == ["connections[0]", "inner.connections[0]"]
    assert sorted(label for _, _, label in traversal_order(dae.topology)) == sorted(labels)
    cert = certify(dae)
    by_label = {c.label: c for c in cert.connections}
    assert sorted(by_label) == sorted(labels)
    inner, top = by_label["inner.connections[0]"], by_label["connections[0]"]
    assert (inner.port_a, inner.port_b) == ("inner.motor.port", "inner.wheel.drive")
    assert (top.port_a, top.port_b) == ("inner.wheel.brake", "damper.port")
    assert top.surjective
    # Γ loses rank at the initial state th = π/2 only: 1 of 2 there
    assert not inner.surjective and inner.achieved == 1 and inner.needed == 2
    assert len(inner.failing_samples) == 1
    assert math.isclose(inner.failing_samples[0]["inner.wheel.th"], math.pi / 2)
    assert inner.span is not None and inner.span.file.endswith("inner.yaml") and inner.span.line == 14
    assert top.span is not None and top.span.file.endswith("outer.yaml") and top.span.line == 7


def test_phc_check_reports_the_nested_coupling_in_the_nested_file(nested, capsys):
    assert main(["check", "outer.yaml"]) == 1
    out = capsys.readouterr()
    text = out.out + out.err
    assert "Traceback" not in text
    located = [line for line in text.splitlines() if "[PHC-E421]" in line]
    assert len(located) == 1, text
    line = located[0]
    assert re.match(r"^(.*/)?inner\.yaml:14:5: inner\.connections\[0\]: connection `inner\.motor\.port` — "
                    r"`inner\.wheel\.drive` is not surjective: rank of the coupling map Γ is 1, needs 2 "
                    r"\(at 1 of \d+ sampled states, e\.g\. ", line), line
    assert "inner.wheel.th = 1.57" in line
    assert "it fails where cos(inner.wheel.th) = 0" in line
    # the table lists both connections, the nested one under its full label
    assert re.search(r"^  inner\.connections\[0\] +inner\.motor\.port — inner\.wheel\.drive: rank 1/2 NOT surjective",
                     out.out, re.M), out.out
    assert re.search(r"^  connections\[0\] +inner\.wheel\.brake — damper\.port: rank 2/2 surjective", out.out, re.M)


def test_phc_check_json_lists_both_connections(nested, capsys):
    assert main(["check", "outer.yaml", "--format", "json"]) == 1
    report = json.loads(capsys.readouterr().out)
    conns = {c["label"]: c for c in report["connections"]}
    assert sorted(conns) == ["connections[0]", "inner.connections[0]"]
    assert conns["connections[0]"]["surjective"] and not conns["inner.connections[0]"]["surjective"]


def test_run_monitor_names_the_nested_connection_of_a_coupling_row(nested):
    # a coupling row is labelled `<connection label>.f[k]`: the monitor that stops a run near
    # a singular configuration names the connection it belongs to, in its own file
    from phc.simulation.monitor import describe_equations

    compiled = phc.compile_model(nested, certify=False)  # the monitor reads its description
    rows = [eq.label for eq in compiled.description.equations
            if ".connections[" in eq.label or eq.label.startswith("connections[")]
    # the flow source's row stays (it is not a substitution): it belongs to the nested file
    assert any(label.startswith("inner.connections[0].") for label in rows), rows
    names = describe_equations(compiled)
    for label in rows:
        where = "inner.yaml:14" if label.startswith("inner.") else "outer.yaml:7"
        ports = ("`inner.motor.port — inner.wheel.drive`" if label.startswith("inner.")
                 else "`inner.wheel.brake — damper.port`")
        assert names[label].startswith(f"connection {ports} ("), names[label]
        assert where in names[label]


def test_traversal_keeps_connections_whose_labels_repeat():
    # labels are unique in an elaborated model; the traversal still tells connections
    # apart by their place, never by their label
    from phc.ir.dae import PortInfo, Topology

    ports = tuple(PortInfo(f"{c}.p", c, "generic", 1, None) for c in "abcd")
    top = Topology(components=tuple((c, "test", None) for c in "abcd"), ports=ports,
                   connections=(("a.p", "b.p", "connections[0]", None), ("c.p", "d.p", "connections[0]", None)),
                   exposed=())
    order = traversal_order(top)
    assert sorted((a, b) for a, b, _ in order) == [("a.p", "b.p"), ("c.p", "d.p")]


def test_views_accept_a_component_graph_built_once(nested):
    from phc.checks.graph import component_graph, independent_parts, kinematic_loops

    top = phc.build_dae(nested)[0].topology
    graph = component_graph(top)
    assert component_graph(graph) is graph
    assert traversal_order(graph) == traversal_order(top)
    assert kinematic_loops(graph) == kinematic_loops(top) == []
    assert independent_parts(graph) == independent_parts(top) == [["damper", "inner.motor", "inner.wheel"]]
    with pytest.raises(ValueError):
        component_graph(graph, reads=True)  # made without the reads edges
