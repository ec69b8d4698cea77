"""Tests of :mod:`phc.checks.graph` (the interconnection graph: loops, independent parts,
the breadth-first order of the coupling certificate, DOT output) and of ``phc graph``."""

from __future__ import annotations

import builtins
import re
import sys
from pathlib import Path

import pytest

import phc
from phc.library import registry
from phc.checks.certify import certify
from phc.checks.graph import (build_interconnection_graph, component_graph, connected_to, independent_parts,
                              kinematic_loops, to_dot, traversal_order)
from phc.cli import main
from phc.ir.interconnect import reads_of
from phc.ir.dae import PortInfo, Topology

REPO = Path(__file__).resolve().parents[2]
MODELS = REPO / "models"
MODEL_FILES = sorted(MODELS.glob("*.yaml"))
MSD = MODELS / "mass_spring_damper.yaml"

RING = """\
format_version: 1
name: ring
# Three masses on common-flow junctions A, B, C; springs between them on common-effort
# junctions AB, BC, CA: the junctions form one ring A – AB – B – BC – C – CA – A.
components:
  mA: {type: mass, m: 1.0}
  mB: {type: mass, m: 2.0}
  mC: {type: mass, m: 3.0}
  kAB: {type: spring, k: 1.0}
  kBC: {type: spring, k: 2.0}
  kCA: {type: spring, k: 3.0}
  A: {type: junction, kind: common_flow, ports: [m, toB, toC]}
  B: {type: junction, kind: common_flow, ports: [m, toC, toA]}
  C: {type: junction, kind: common_flow, ports: [m, toA, toB]}
  AB: {type: junction, kind: common_effort, ports: [a, b, k]}
  BC: {type: junction, kind: common_effort, ports: [b, c, k]}
  CA: {type: junction, kind: common_effort, ports: [c, a, k]}
connections:
  - [A.m, mA.port]
  - [B.m, mB.port]
  - [C.m, mC.port]
  - [A.toB, AB.a]
  - [AB.b, B.toA]
  - [AB.k, kAB.port]
  - [B.toC, BC.b]
  - [BC.c, C.toB]
  - [BC.k, kBC.port]
  - [C.toA, CA.c]
  - [CA.a, A.toC]
  - [CA.k, kCA.port]
"""


def _topology(path):
    dae, diags = phc.build_dae(path)
    assert dae is not None, "\n".join(d.render() for d in diags)
    return dae.topology


@pytest.fixture
def ring(tmp_path):
    path = tmp_path / "ring.yaml"
    path.write_text(RING)
    return path


def _synthetic(components: dict[str, list[str]], connections: list[tuple[str, str]]) -> Topology:
    """A topology by hand: component -> port names; connections by full port names."""
    ports = tuple(PortInfo(f"{c}.{p}", c, "generic", 1, None) for c, names in components.items() for p in names)
    return Topology(components=tuple((c, "test", None) for c in components), ports=ports,
                    connections=tuple((a, b, f"connections[{i}]", None) for i, (a, b) in enumerate(connections)),
                    exposed=())


# -- the graph ------------------------------------------------------------------------


def test_mass_spring_damper_graph_counts():
    graph = build_interconnection_graph(_topology(MSD))
    kinds = [data["kind"] for _, _, data in graph.edges(data=True)]
    nodes = [n[0] for n in graph.nodes]
    assert nodes.count("component") == 4            # mass, spring, damper, node
    assert nodes.count("port") == 6                 # one each + the junction's three
    assert nodes.count("external") == 0
    assert graph.number_of_nodes() == 10
    assert kinds.count("has") == 6
    assert kinds.count("connection") == 3
    assert graph.number_of_edges() == 9
    assert graph.degree(("component", "node")) == 3
    assert graph.degree(("port", "node.to_mass")) == 2   # owned by node, connected to mass.port
    assert graph.nodes[("component", "spring")]["type"] == "spring"
    labels = sorted(d["label"] for _, _, d in graph.edges(data=True) if d["kind"] == "connection")
    assert labels == ["connections[0]", "connections[1]", "connections[2]"]


def test_graph_counts_match_topology_for_every_shipped_model():
    for path in MODEL_FILES:
        top = _topology(path)
        graph = build_interconnection_graph(top)
        kinds = [d["kind"] for _, _, d in graph.edges(data=True)]
        assert kinds.count("has") == len(top.ports), path
        assert kinds.count("connection") == len(top.connections), path
        assert kinds.count("exposed") == len(top.exposed), path
        assert graph.number_of_nodes() == len(top.components) + len(top.ports) + len(top.exposed), path


def test_exposed_ports_are_external_nodes():
    top = _synthetic({"a": ["p", "q"], "b": ["p"]}, [("a.p", "b.p")])
    top = Topology(top.components, top.ports, top.connections, exposed=(("handle", "a.q"),))
    graph = build_interconnection_graph(top)
    assert graph.has_edge(("port", "a.q"), ("external", "handle"))
    assert graph.number_of_nodes() == 2 + 3 + 1


# -- kinematic loops -------------------------------------------------------------------


def test_ring_has_one_kinematic_loop(ring):
    loops = kinematic_loops(_topology(ring))
    assert len(loops) == 1
    assert sorted(loops[0]) == ["A", "AB", "B", "BC", "C", "CA"]


def test_ring_is_certified_with_its_loop(ring, capsys):
    """A loop is information, not an error: `phc check` certifies the ring and lists it."""
    assert main(["check", str(ring)]) == 0
    out = capsys.readouterr().out
    lines = out.splitlines()
    i = next(k for k, x in enumerate(lines) if x.startswith("kinematic loops:"))
    assert lines[i] != "kinematic loops: none"
    line = lines[i + 1].strip().split(": ", 1)[0]  # "A – AB – …: <whether it constrains>"
    assert sorted(line.split(" – ")) == ["A", "AB", "B", "BC", "C", "CA"]
    # the springs stretch with the velocity differences and the masses take the forces
    # (both rates): no relation among the velocities and spring forces alone
    assert lines[i + 1].endswith(": closed through compliant elements (no constraint)")


@pytest.mark.parametrize("path", MODEL_FILES, ids=[p.stem for p in MODEL_FILES])
def test_shipped_chains_have_no_loops(path):
    assert kinematic_loops(_topology(path)) == []


def test_parallel_connections_count_as_loops():
    top = _synthetic({"a": ["p", "q", "r"], "b": ["p", "q", "r"]},
                     [("a.p", "b.p"), ("a.q", "b.q"), ("a.r", "b.r")])
    loops = kinematic_loops(top)
    assert len(loops) == 2
    assert all(sorted(loop) == ["a", "b"] for loop in loops)


def test_triangle_of_components_is_one_loop():
    top = _synthetic({"A": ["b", "c"], "B": ["a", "c"], "C": ["a", "b"]},
                     [("A.b", "B.a"), ("B.c", "C.b"), ("C.a", "A.c")])
    loops = kinematic_loops(top)
    assert len(loops) == 1 and sorted(loops[0]) == ["A", "B", "C"]


# -- independent parts -----------------------------------------------------------------


def test_connected_models_are_one_part(ring):
    parts = independent_parts(_topology(ring))
    assert len(parts) == 1 and len(parts[0]) == 12
    for path in MODEL_FILES:
        top = _topology(path)
        # a signal block (a controller with state) and a contact have no port: each a part of
        # its own in the graph of connections, which `phc check` does not report (a block acts
        # through a source, a contact on the bodies its gap names)
        signal = [[name] for name, kind, _ in top.components if registry.get(kind).signal or kind == "contact"]
        physical = sorted(name for name, _, _ in top.components if [name] not in signal)
        # (sorted as documented: largest first, then by name; the woodpecker is one body and three contacts)
        assert independent_parts(top) == sorted([physical, *signal], key=lambda c: (-len(c), c)), path


def test_independent_parts_largest_first_then_by_name():
    top = _synthetic({"z": ["p"], "y": ["p"], "lone": [], "b": ["p"], "a": ["p", "q"], "c": ["p"]},
                     [("z.p", "y.p"), ("a.p", "b.p"), ("a.q", "c.p")])
    assert independent_parts(top) == [["a", "b", "c"], ["y", "z"], ["lone"]]


def test_two_sub_assemblies_are_two_parts(tmp_path):
    path = tmp_path / "two.yaml"
    path.write_text("format_version: 1\ncomponents:\n  m1: {type: mass, m: 1.0}\n  s1: {type: spring, k: 1.0}\n"
                    "  m2: {type: mass, m: 2.0}\n  s2: {type: spring, k: 3.0}\n"
                    "connections:\n  - [m1.port, s1.port]\n  - [m2.port, s2.port]\n")
    assert independent_parts(_topology(path)) == [["m1", "s1"], ["m2", "s2"]]


# -- breadth-first traversal -------------------------------------------------------------


def _check_traversal(top):
    order = traversal_order(top)
    labels = [label for _, _, label in order]
    assert sorted(labels) == sorted(label for _, _, label, _ in top.connections)   # each once
    assert len(set(labels)) == len(labels)
    owner = {p.name: p.component for p in top.ports}
    by_label = {label: (a, b) for a, b, label, _ in top.connections}
    seen, closing = set(), 0
    parts = {c: i for i, part in enumerate(independent_parts(top)) for c in part}
    for a, b, label in order:
        assert {a, b} == set(by_label[label])                  # the ports of that connection
        ca, cb = owner[a], owner[b]
        if ca in seen and cb in seen:
            closing += 1                                        # closes a loop
        else:
            # breadth-first: each tree edge grows the reached set from an endpoint already
            # reached, or starts a new part at its first component
            starts_part = ca not in seen and cb not in seen
            if starts_part:
                assert not any(parts[c] == parts[ca] for c in seen)
        seen |= {ca, cb}
    assert closing == len(kinematic_loops(top))
    return order


@pytest.mark.parametrize("path", MODEL_FILES, ids=[p.stem for p in MODEL_FILES])
def test_traversal_covers_every_connection_once(path):
    _check_traversal(_topology(path))


def test_traversal_of_the_ring_closes_one_loop(ring):
    _check_traversal(_topology(ring))


def test_traversal_with_parallel_connections_and_parts():
    top = _synthetic({"a": ["p", "q"], "b": ["p", "q"], "c": ["p"], "d": ["p"]},
                     [("a.p", "b.p"), ("c.p", "d.p"), ("b.q", "a.q")])
    order = _check_traversal(top)
    assert [label for _, _, label in order][:2] == ["connections[0]", "connections[2]"]   # part {a, b} first


# -- DOT and `phc graph` -----------------------------------------------------------------


def _assert_dot(dot: str, top, name: str):
    assert dot.startswith(f'graph "{name}" {{\n')
    assert dot.rstrip().endswith("}")
    assert dot.count("{") == dot.count("}")
    for a, b, label, _ in top.connections:
        assert f'"{a}" -- "{b}" [label="{label}"];' in dot
    for port in top.ports:
        assert re.search(rf'^\s+"{re.escape(port.name)}" \[label=', dot, re.M), port.name
    assert dot.count("subgraph cluster_") == len(top.components)


@pytest.mark.parametrize("path", MODEL_FILES, ids=[p.stem for p in MODEL_FILES])
def test_phc_graph_prints_dot(path, capsys):
    assert main(["graph", str(path)]) == 0
    captured = capsys.readouterr()
    dae, _ = phc.build_dae(path)
    _assert_dot(captured.out, dae.topology, dae.name)
    assert captured.out == to_dot(dae.topology, dae.name)


def test_phc_graph_writes_dot_file(tmp_path, capsys):
    target = tmp_path / "x.dot"
    assert main(["graph", str(MSD), "-o", str(target)]) == 0
    out = capsys.readouterr().out
    assert f"wrote {target}" in out
    text = target.read_text()
    _assert_dot(text, _topology(MSD), "mass_spring_damper")
    assert main(["graph", str(MSD), "-o", "-"]) == 0
    assert capsys.readouterr().out == text


def test_phc_graph_rejects_other_suffixes(tmp_path, capsys):
    assert main(["graph", str(MSD), "-o", str(tmp_path / "x.svg")]) == 2
    err = capsys.readouterr().err
    assert "must end in .dot or .png" in err and "Traceback" not in err
    assert not (tmp_path / "x.svg").exists()


def test_phc_graph_of_a_broken_model_exits_1(tmp_path, capsys):
    path = tmp_path / "broken.yaml"
    path.write_text("format_version: 1\ncomponents:\n  mass: {type: mass, m: 1.0}\n  cap: {type: capacitor, C: 0.1}\n"
                    "connections:\n  - [mass.port, cap.port]\n")
    assert main(["graph", str(path)]) == 1
    captured = capsys.readouterr()
    assert captured.out == ""
    assert "[PHC-E204]" in captured.err


def test_phc_graph_png_with_matplotlib(tmp_path, capsys):
    pytest.importorskip("matplotlib")
    target = tmp_path / "x.png"
    assert main(["graph", str(MSD), "-o", str(target)]) == 0
    assert f"wrote {target}" in capsys.readouterr().out
    assert target.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"


def test_phc_graph_png_without_matplotlib(tmp_path, capsys, monkeypatch):
    """Without the `plot` extra: exit 2, a message naming `port-hamiltonian-compiler[plot]`, no file."""
    real_import = builtins.__import__

    def no_matplotlib(name, *args, **kwargs):
        if name == "matplotlib" or name.startswith("matplotlib."):
            raise ImportError(f"No module named {name!r}")
        return real_import(name, *args, **kwargs)

    for mod in [m for m in sys.modules if m == "matplotlib" or m.startswith("matplotlib.")]:
        monkeypatch.delitem(sys.modules, mod)
    monkeypatch.setattr(builtins, "__import__", no_matplotlib)
    target = tmp_path / "x.png"
    assert main(["graph", str(MSD), "-o", str(target)]) == 2
    captured = capsys.readouterr()
    assert "pip install 'port-hamiltonian-compiler[plot]'" in captured.err
    assert "Traceback" not in captured.err and "internal error" not in captured.err
    assert not target.exists()


def test_component_graph_has_one_edge_per_connection(ring):
    top = _topology(ring)
    graph = component_graph(top)
    assert graph.number_of_edges() == len(top.connections)
    assert graph.number_of_nodes() == len(top.components)


# -- one graph for pruning and the certificate -------------------------------------------

MODULATED = (Path(__file__).parent / "modulated_two_parts.yaml").read_text()


def _edges(graph):
    return sorted((tuple(sorted((u, v))), d.get("label", d.get("kind"))) for u, v, d in graph.edges(data=True))


def test_pruning_and_the_certificate_see_the_same_graph(tmp_path):
    """The graph scene pruning builds from the model as written (the modulation's reads
    from the free symbols of its parsed `K`) is the one the certificate builds from the
    assembled topology (the reads from the states its Dirac structure depends on)."""
    path = tmp_path / "modulated.yaml"
    path.write_text(MODULATED)
    spec, _, diags = phc.load_model(path)
    assert spec is not None, diags
    top = _topology(path)
    written, assembled = component_graph(spec, reads=True), component_graph(top, reads=True)
    assert sorted(written.nodes) == sorted(assembled.nodes) == sorted(spec.components)
    assert _edges(written) == _edges(assembled)
    assert (("gyro", "spring"), "reads") in _edges(written)
    full_written, full_assembled = build_interconnection_graph(spec), build_interconnection_graph(top)
    assert set(full_written.nodes) == set(full_assembled.nodes)   # every port is connected
    assert _edges(full_written) == _edges(full_assembled)
    # The certificate's parts are connections only: two parts, as the written model has.
    assert independent_parts(spec) == independent_parts(top) == certify(phc.build_dae(path)[0]).parts
    assert len(independent_parts(top)) == 2
    # The read joins them for pruning: the wheel's angle keeps the mass–spring part.
    assert connected_to(spec, {"wheel"}) == connected_to(top, {"wheel"}) == set(spec.components)
    scene = tmp_path / "scene.yaml"
    scene.write_text("model: modulated.yaml\noutputs: {theta: wheel.theta}\n")
    dae, diags = phc.build_dae(scene)
    assert dae is not None, diags
    assert dae.left_out == ()


def test_a_modulation_that_reads_nothing_lets_pruning_leave_the_other_part_out(tmp_path):
    path = tmp_path / "modulated.yaml"
    text = MODULATED.replace('"c*(1 + spring.x)"', "c").replace('"-c*(1 + spring.x)"', "-c")
    assert "spring.x)" not in text
    path.write_text(text)
    spec, _, _ = phc.load_model(path)
    assert not [e for e in component_graph(spec, reads=True).edges(data=True) if e[2].get("kind") == "reads"]
    scene = tmp_path / "scene.yaml"
    scene.write_text("model: modulated.yaml\noutputs: {theta: wheel.theta}\n")
    dae, diags = phc.build_dae(scene)
    assert dae is not None, diags
    assert {comp for comp, _, _ in dae.left_out} == {"mass", "spring", "node", "wall"}


def test_a_modulation_whose_K_does_not_parse_reads_everything(tmp_path):
    """Pruning keeps what a broken `K` might read; the error itself is reported where the
    modulation is lowered."""
    path = tmp_path / "modulated.yaml"
    path.write_text(MODULATED.replace('"c*(1 + spring.x)"', '"c*(1 + spring.x"'))
    spec, _, _ = phc.load_model(path)
    assert sorted(reads_of(spec)) == sorted(("gyro", c) for c in spec.components if c != "gyro")
    dae, diags = phc.build_dae(path)
    assert dae is None
    assert ("PHC-E101", "components.gyro.K[0][1]") in [(d.code, d.path) for d in diags.errors]
