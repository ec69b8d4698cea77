"""Tests of :mod:`phc.checks.loops`: does a kinematic loop constrain the motion?

Every expected count is derived by hand in the test's comment from the component
equations (docs/reference/components.md): a connection sets the two flows equal and the
efforts opposite; a mass's ports all move with its velocity v = p/m (its storage effort);
a two-terminal spring or damper in the mechanical domain acts on f_a − f_b and passes its
force (e_b = −e_a); a transformer has f_b = N f_a, e_a = −Nᵀ e_b. The count is the number
of independent relations among the storage efforts (functions of the states) that closing
the loop adds, wherever the loop is opened (the minimum over its connections).
"""

from __future__ import annotations

import json

import pytest
import sympy as sp

import phc
from phc.checks import loops
from phc.checks.certify import _Component, certify
from phc.checks.graph import component_graph
from phc.cli import main

from model_texts import BESIDE_RIGID, DIAGONAL  # shared with test_compiled_certificate.py

PARALLEL = """\
format_version: 1
name: parallel
components:
  m1: {type: mass, m: 1.0, ports: [a, b]}
  m2: {type: mass, m: 2.0, ports: [a, b]}
  k: {type: spring, k: 3.0, terminals: [a, b]}
  d: {type: damper, d: 0.5, terminals: [a, b]}
connections:
  - [m1.a, k.a]
  - [k.b, m2.a]
  - [m1.b, d.a]
  - [d.b, m2.b]
"""

LEVER_ON_JUNCTIONS = """\
format_version: 1
name: lever_on_junctions
components:
  mA: {type: mass, m: 1.0}
  mB: {type: mass, m: 2.0}
  A: {type: junction, kind: common_flow, ports: [m, lever, toB]}
  B: {type: junction, kind: common_flow, ports: [m, lever, toA]}
  lever: {type: transformer, ratio: 2.0}
connections:
  - [A.m, mA.port]
  - [B.m, mB.port]
  - [A.lever, lever.a]
  - [lever.b, B.lever]
  - [A.toB, B.toA]
"""


def _verdicts(tmp_path, text):
    path = tmp_path / "model.yaml"
    path.write_text(text)
    dae, diags = phc.build_dae(path)
    assert dae is not None, "\n".join(d.render() for d in diags)
    cert = certify(dae)
    assert len(cert.loop_verdicts) == len(cert.loops)
    for verdict, loop in zip(cert.loop_verdicts, cert.loops):
        assert verdict.components == loop
    return cert.loop_verdicts


def test_parallel_spring_and_damper_do_not_constrain(tmp_path):
    # Storage efforts: v1, v2 (masses), F (spring). Closed: k and d both stretch with
    # v2 − v1 (ẋ = v2 − v1: a rate, dynamics) and pass their forces to the masses, whose
    # momenta take them (ṗ = −Σ e: rates). No relation among v1, v2, F alone: 0 closed,
    # 0 opened anywhere → 0.
    [verdict] = _verdicts(tmp_path, PARALLEL)
    assert sorted(verdict.components) == ["d", "k", "m1", "m2"]
    assert len(verdict.connections) == 4
    assert verdict.constraints == 0
    assert verdict.describe() == "closed through compliant elements (no constraint)"


def test_spring_beside_rigid_masses_does_not_constrain(tmp_path):
    # m1.b — m2.a joins the masses rigidly: v1 = v2, one relation among the efforts, with
    # or without the spring. Closed: v1 = v2 (and ẋ = v2 − v1 = 0, a rate, not counted):
    # 1. Opened at a spring connection: v1 = v2 still: 1, so closing adds 1 − 1 = 0.
    # (Opened at the rigid joint it would add 1: the minimum over the openings is 0.)
    [verdict] = _verdicts(tmp_path, BESIDE_RIGID)
    assert verdict.constraints == 0


def test_two_transformers_close_a_kinematic_chain(tmp_path):
    # m1 moves in the plane (v = (vx, vy)), m2 on a line (w). lx: w = vx, ly: w = vy.
    # Closed: w = vx and w = vy, 2 independent relations among (vx, vy, w). Opened at any
    # of the 4 connections only one transformer ties w to m1: 1. Closing adds 2 − 1 = 1
    # (m1 can only move along the diagonal vx = vy).
    [verdict] = _verdicts(tmp_path, DIAGONAL)
    assert verdict.constraints == 1
    assert verdict.describe() == "closes a kinematic chain: 1 algebraic relation"


def test_masses_on_the_junctions_of_a_loop_count(tmp_path):
    # The loop A – lever – B holds no storage; the masses hang on its junctions (all flows
    # of a common-flow junction equal: vA on A, vB on B). Closed: A.toB — B.toA gives
    # vA = vB, the lever vB = 2 vA: 2 relations. Opened anywhere: 1. Adds 1 (it locks).
    [verdict] = _verdicts(tmp_path, LEVER_ON_JUNCTIONS)
    assert sorted(verdict.components) == ["A", "B", "lever"]
    assert verdict.constraints == 1


def test_a_loop_above_the_limit_is_named_with_why(tmp_path, monkeypatch):
    monkeypatch.setattr(loops, "MAX_LOOP", 3)  # the 4-component loop of PARALLEL is above it
    [verdict] = _verdicts(tmp_path, PARALLEL)
    assert verdict.constraints is None
    assert "more than 3" in verdict.reason
    assert verdict.describe().startswith("not classified (4 components, more than 3")


def test_phc_check_says_what_each_loop_does(tmp_path, capsys):
    path = tmp_path / "parallel.yaml"
    path.write_text(PARALLEL)
    assert main(["check", str(path)]) == 0
    out = capsys.readouterr().out.splitlines()
    i = out.index("kinematic loops: 1")
    names, verdict = out[i + 1].strip().split(": ", 1)
    assert sorted(names.split(" – ")) == ["d", "k", "m1", "m2"]
    assert verdict == "closed through compliant elements (no constraint)"


def test_phc_check_json_has_loop_constraints(tmp_path, capsys):
    path = tmp_path / "diagonal.yaml"
    path.write_text(DIAGONAL)
    main(["check", "--format", "json", str(path)])  # the verdict does not depend on the exit code
    report = json.loads(capsys.readouterr().out)
    [entry] = report["loop_constraints"]
    assert entry["components"] == report["loops"][0]
    assert entry["constraints"] == 1          # derived in test_two_transformers_close_a_kinematic_chain
    assert entry["reason"] is None
    assert sorted(entry["connections"]) == [f"connections[{i}]" for i in range(4)]


@pytest.mark.parametrize("order", [(0, 1, 2), (1, 2, 0), (2, 0, 1), (2, 1, 0)])
def test_the_verdict_does_not_depend_on_where_the_loop_is_written_closed(tmp_path, order):
    # BESIDE_RIGID with its connections in another order (the rigid joint last in some):
    # the count is the same 0 (derived above) whichever connection the cycle basis ends on.
    head, rest = BESIDE_RIGID.split("connections:\n")
    lines = rest.splitlines()
    text = head + "connections:\n" + "\n".join(lines[i] for i in order) + "\n"
    [verdict] = _verdicts(tmp_path, text)
    assert verdict.constraints == 0


def test_opening_only_at_the_rigid_joint_would_count_one(tmp_path):
    # Why the minimum over the openings: by hand, with the rigid joint open the masses are
    # free (no relation among v1, v2, F), closed v1 = v2: 1 added there; 0 at the spring.
    path = tmp_path / "model.yaml"
    path.write_text(BESIDE_RIGID)
    dae, _ = phc.build_dae(path)
    cert = certify(dae)
    [verdict] = cert.loop_verdicts
    comps = {rel.component: _Component(rel, dae.topology.parameter_defaults) for rel in dae.topology.dirac}
    graph = component_graph(dae.topology)
    counts = list(loops._added_per_opening(graph, comps, verdict.components, verdict.connections, {}))
    by_label = dict(zip([label for _, _, label in verdict.connections], counts))
    assert by_label["connections[0]"] == 1     # m1.b — m2.a, the rigid joint
    assert by_label["connections[1]"] == 0 and by_label["connections[2]"] == 0


def _exact_added(dae, members, connections, attached) -> list[int]:
    """An independent count, exact (sympy, rational coefficients), in kernel form: the
    components' relations ``F f + E e + G λ = 0`` stacked with the connection rows
    ``f_a − f_b``, ``e_a + e_b``; the relations among the storage efforts alone are
    ``rank M − rank M_other`` (the combinations of rows that vanish on every other column).
    `attached`: (component, connection) hanging on the loop."""
    rels = {r.component: r for r in dae.topology.dirac}
    names = list(members) + [c for c, _ in attached]
    cols, port_syms, effort_syms = [], {}, []
    for name in names:
        r = rels[name]
        cols += list(r.flows) + list(r.efforts) + list(r.multipliers)
        for p, (fi, ei) in r.ports.items():
            port_syms[f"{name}.{p}"] = ([r.flows[i] for i in fi], [r.efforts[i] for i in ei])
        effort_syms += [s.effort for s in r.storage]
    defaults = {k: sp.Rational(repr(float(v))) for k, v in dae.topology.parameter_defaults.items()}

    def rows(conns):
        out = [rel for name in names for rel in rels[name].relations]
        for a, b in conns:
            (fa, ea), (fb, eb) = port_syms[a], port_syms[b]
            out += [x - y for x, y in zip(fa, fb)] + [x + y for x, y in zip(ea, eb)]
        return out

    def count(conns):
        M = sp.Matrix(rows(conns)).jacobian(cols).xreplace(defaults).applyfunc(sp.nsimplify)
        other = [j for j, c in enumerate(cols) if c not in effort_syms]
        return M.rank() - M.extract(list(range(M.rows)), other).rank()

    base = [conn for _, conn in attached]
    loop = [(a, b) for a, b, _ in connections]
    closed = count(base + loop)
    return [closed - count(base + loop[:k] + loop[k + 1:]) for k in range(len(loop))]


@pytest.mark.parametrize("text", [PARALLEL, BESIDE_RIGID, DIAGONAL, LEVER_ON_JUNCTIONS],
                         ids=["parallel", "beside_rigid", "diagonal", "lever_on_junctions"])
def test_counts_per_opening_match_an_exact_kernel_form_count(tmp_path, text):
    path = tmp_path / "model.yaml"
    path.write_text(text)
    dae, _ = phc.build_dae(path)
    comps = {rel.component: _Component(rel, dae.topology.parameter_defaults) for rel in dae.topology.dirac}
    graph = component_graph(dae.topology)
    [(members, connections)] = loops.loops_with_connections(graph)
    attached = []
    for m in members:
        for _, other, data in sorted(graph.edges(m, data=True), key=lambda e: e[2]["index"]):
            if other not in members and other not in [c for c, _ in attached]:
                attached.append((other, data["ports"]))
    counts = list(loops._added_per_opening(graph, comps, members, connections, {}))
    assert counts == _exact_added(dae, members, connections, attached)


def _ladder(n: int) -> str:
    """n cells: masses joined by a spring and a damper in parallel, n loops alike but for the
    two ends."""
    lines = ["format_version: 1", "name: ladder", "components:",
             "  m0: {type: mass, m: 1.0, ports: [r1, r2]}"]
    for i in range(1, n):
        lines.append(f"  m{i}: {{type: mass, m: 1.0, ports: [l1, l2, r1, r2]}}")
    lines.append(f"  m{n}: {{type: mass, m: 1.0, ports: [l1, l2]}}")
    for i in range(n):
        lines += [f"  k{i}: {{type: spring, k: 3.0, terminals: [a, b]}}",
                  f"  d{i}: {{type: damper, d: 0.5, terminals: [a, b]}}"]
    lines.append("connections:")
    for i in range(n):
        lines += [f"  - [m{i}.r1, k{i}.a]", f"  - [k{i}.b, m{i + 1}.l1]",
                  f"  - [m{i}.r2, d{i}.a]", f"  - [d{i}.b, m{i + 1}.l2]"]
    return "\n".join(lines) + "\n"


def test_loops_alike_up_to_names_are_classified_once(tmp_path, monkeypatch):
    """Each cell of the ladder is a spring and a damper in parallel between two masses: 0
    relations (as in PARALLEL). The interior cells' loops, with what hangs on them, are the
    same up to names, so they are classified once; the verdicts are those of classifying
    each loop on its own."""
    n = 9
    shared = _verdicts(tmp_path, _ladder(n))
    assert len(shared) == n and all(v.constraints == 0 for v in shared)
    calls = []
    real = loops._added_per_opening
    monkeypatch.setattr(loops, "_added_per_opening", lambda *a, **k: calls.append(a[2]) or real(*a, **k))
    again = _verdicts(tmp_path, _ladder(n))
    # the first and the last two cells differ (an end mass with two ports, on the loop or
    # hanging on it); the other cells share one classification
    assert 1 <= len(calls) <= 5 < n, calls
    monkeypatch.setattr(loops, "_shape_key", lambda *a, **k: None)  # every loop on its own
    calls.clear()
    alone = _verdicts(tmp_path, _ladder(n))
    assert len(calls) == n
    assert [(v.components, v.constraints) for v in again] == [(v.components, v.constraints) for v in alone]
