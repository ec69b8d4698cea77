"""Tests of :mod:`phc.checks.certify` (the Dirac and coupling certificates of the seed's
section 2) and of ``phc check`` on the shipped models.

* every shipped model is certified: each component is a Dirac structure with
  ``dim D = dim Z`` and each connection's coupling map Γ (Prop. "Interconnection through a
  finite-dimensional coupling space") has rank ``2 · port dimension``;
* the dimensions of the rigid components follow from the seed's eq. (rigidDirac2):
  ``dim Z = n_q + 2 n_v + Σ port dimensions`` (storage pairs of q and p, resistive pairs of
  v, ports);
* a property test writes random ``phs`` components in J/R/B form, builds their Dirac
  structure independently from J and B, and checks phc's certificate against it;
* a non-skew J is rejected (PHC-E402).
"""

from __future__ import annotations

import json
import math
import tempfile
from pathlib import Path

import numpy as np
import pytest
import scipy.linalg as sla
import sympy as sp
import yaml
from hypothesis import event, given, settings
from hypothesis import strategies as st

import phc
from phc.library import registry
from phc.checks.certify import certify
from phc.cli import main
from phc.pipeline import elaborate_file as elaborate

REPO = Path(__file__).resolve().parents[2]
MODELS = REPO / "models"
SLIDER_CRANK = MODELS / "rigid_slider_crank.yaml"

KNOWN_BROKEN: dict[str, str] = {}
"""Shipped models phc cannot certify today (strict xfail; remove the entry once fixed)."""


def _model_params() -> list:
    out = []
    for path in sorted(MODELS.glob("*.yaml")):
        reason = KNOWN_BROKEN.get(path.stem)
        marks = [pytest.mark.xfail(strict=True, reason=reason)] if reason else []
        out.append(pytest.param(path, id=path.stem, marks=marks))
    return out


MODEL_FILES = sorted(MODELS.glob("*.yaml"))
MODEL_PARAMS = _model_params()


def _certificate(path):
    dae, diags = phc.build_dae(path)
    assert dae is not None, "\n".join(d.render() for d in diags)
    return dae, certify(dae)


def _port_dims(dae) -> dict[str, int]:
    return {p.name: p.dimension for p in dae.topology.ports}


# -- the shipped models ------------------------------------------------------------


def test_there_are_shipped_models():
    assert len(MODEL_FILES) >= 4


@pytest.mark.parametrize("path", MODEL_PARAMS)
def test_shipped_model_is_certified(path):
    dae, cert = _certificate(path)
    assert cert.certified, cert.render_text()
    assert not cert.diagnostics.has_errors
    # every Dirac structure, then the signal blocks (controllers with state: no structure)
    signal = [name for name, kind, _ in dae.topology.components if registry.get(kind).signal]
    assert [c.name for c in cert.components] == [rel.component for rel in dae.topology.dirac] + signal
    for comp in cert.components:
        if comp.name in signal:
            assert comp.dirac is None and "outside the port-Hamiltonian certificate" in comp.note
            continue
        if comp.kind == "port_projection":
            assert comp.dirac is None
            continue
        assert comp.dirac is True, comp
        assert comp.dim_d == comp.dim_z, comp
        assert comp.isotropy <= 1e-9
    dims = _port_dims(dae)
    labels = sorted(label for _, _, label, _ in dae.topology.connections)
    assert sorted(c.label for c in cert.connections) == labels   # every connection once
    for conn in cert.connections:
        assert dims[conn.port_a] == dims[conn.port_b]
        assert conn.surjective, conn
        assert conn.achieved == conn.needed == 2 * dims[conn.port_a]
        assert conn.failing_samples == []
    assert cert.n_samples == 3


# dim Z by hand. Library one-ports: one storage or resistive pair plus one pair per port
# component; a junction: one pair per port; a source: its port only (certified as the
# termination it imposes, f = 0 or e = 0). Rigid (eq. rigidDirac2): n_q + 2 n_v + Σ ports.
EXPECTED_DIM_Z = {
    "rigid_slider_crank": {"drive": 1, "crank": 1 + 2 * 1 + 1 + 2, "rod": 3 + 2 * 3 + 2 + 2,
                           "slider": 1 + 2 * 1 + 2},
    "pendulum": {"pendulum": 2 + 2 * 2},
    "mass_spring_damper": {"mass": 2, "spring": 2, "damper": 2, "node": 3},
    "rlc_circuit": {"source": 1, "inductor": 2, "capacitor": 2, "resistor": 2, "loop": 4},
}


def test_rigid_slider_crank_dimensions_follow_rigidDirac2():
    _, cert = _certificate(SLIDER_CRANK)
    dims = {c.name: (c.dim_z, c.dim_d) for c in cert.components if c.kind == "rigid"}
    assert dims == {"crank": (6, 6), "rod": (13, 13), "slider": (5, 5)}


@pytest.mark.parametrize("name", sorted(EXPECTED_DIM_Z))
def test_component_dimensions(name):
    _, cert = _certificate(MODELS / f"{name}.yaml")
    assert {c.name: c.dim_z for c in cert.components} == EXPECTED_DIM_Z[name]
    assert all(c.dim_d == c.dim_z for c in cert.components)


@pytest.mark.parametrize("path", MODEL_PARAMS)
def test_rigid_dim_z_formula_from_the_yaml(path):
    """dim Z = n_q + 2 n_v + Σ port dimensions for every rigid component, read from the file."""
    spec = yaml.safe_load(path.read_text())
    _, cert = _certificate(path)
    by_name = {c.name: c for c in cert.components}
    for name, comp in spec["components"].items():
        if comp["type"] != "rigid":
            continue
        n_q = len(comp["q"])
        n_v = len(comp.get("v") or comp["q"])
        ports = sum(p.get("dimension", 1) for p in (comp.get("ports") or {}).values())
        assert by_name[name].dim_z == by_name[name].dim_d == n_q + 2 * n_v + ports


def test_matrix_component_is_certified_through_its_ports(tmp_path):
    """A `linear_phs` records only its port projection: dirac None, coupling still tested."""
    path = tmp_path / "model.yaml"
    path.write_text(
        "format_version: 1\n"
        "components:\n"
        "  osc:\n"
        "    type: linear_phs\n"
        "    states: 2\n"
        "    J: [[0, 1], [-1, 0]]\n"
        "    Q: [[4, 0], [0, 1]]\n"
        "    ports:\n"
        "      tip: {B: [[0], [1]]}\n"
        "  free: {type: zero_effort}\n"
        "connections:\n"
        "  - [osc.tip, free.port]\n")
    _, cert = _certificate(path)
    osc = next(c for c in cert.components if c.name == "osc")
    assert osc.kind == "port_projection" and osc.dirac is None and osc.dim_d is None
    assert cert.certified
    assert [(c.achieved, c.needed) for c in cert.connections] == [(2, 2)]


# -- phc check on the command line ---------------------------------------------------


def test_phc_check_json_for_rigid_slider_crank(capsys):
    code = main(["check", str(SLIDER_CRANK), "--format", "json"])
    captured = capsys.readouterr()
    assert code == 0, captured.err
    report = json.loads(captured.out)
    assert report["certified"] is True
    assert report["model"] == "rigid_slider_crank"
    assert isinstance(report["loops"], list)
    assert report["loops"] == []   # a chain: drive – crank – rod – slider
    assert len(report["connections"]) == 3
    assert all(c["surjective"] is True for c in report["connections"])
    assert all(c["rank_achieved"] == c["rank_needed"] for c in report["connections"])
    assert {c["name"]: c["dirac"] for c in report["components"]} == {
        "drive": True, "crank": True, "rod": True, "slider": True}
    assert not any(d["severity"] == "error" for d in report["diagnostics"])


@pytest.mark.parametrize("path", MODEL_PARAMS)
def test_phc_check_text_says_certified(path, capsys):
    assert main(["check", str(path)]) == 0
    out = capsys.readouterr().out
    assert out.splitlines()[0].startswith(f"{yaml.safe_load(path.read_text())['name']}: certified (")
    assert "NOT" not in out and "FAILED" not in out


# -- property test: random J/R/B components -------------------------------------------

QUARTERS = st.integers(-8, 8).map(lambda k: k / 4)   # exact in binary floating point
SMALL = st.integers(-2, 2).map(lambda k: k / 2)      # zeros and parallel columns are common


@st.composite
def jrb_components(draw, skew=True):
    n = draw(st.integers(1, 3))
    upper = [[draw(QUARTERS) for _ in range(n)] for _ in range(n)]
    if skew:
        J = [[(upper[i][j] if i < j else -upper[j][i] if i > j else 0.0) for j in range(n)] for i in range(n)]
    else:
        J = upper
    Q = [draw(st.sampled_from([0.5, 1.0, 2.0])) for _ in range(n)]
    ports = []
    for k in range(draw(st.integers(1, 3))):
        dim = draw(st.integers(1, 2))
        B = [[draw(SMALL) for _ in range(dim)] for _ in range(n)]
        ports.append((f"p{k}", dim, B, draw(st.sampled_from(["effort_in", "flow_in"]))))
    return n, J, Q, ports


def _yaml(n, J, Q, ports) -> str:
    states = [f"x{i}" for i in range(n)]
    lines = ["format_version: 1", "name: random_phs", "components:", "  sys:", "    type: phs",
             f"    states: [{', '.join(states)}]",
             "    hamiltonian: " + " + ".join(f"{q}*{x}**2/2" for q, x in zip(Q, states)),
             f"    J: {json.dumps(J)}", "    ports:"]
    for name, dim, B, causality in ports:
        lines.append(f"      {name}: {{dimension: {dim}, causality: {causality}, B: {json.dumps(B)}}}")
    for name, dim, _, _ in ports:
        lines.append(f"  end_{name}: {{type: zero_effort, dimension: {dim}}}")
    lines.append("connections:")
    for name, _, _, _ in ports:
        lines.append(f"  - [sys.{name}, end_{name}.port]")
    return "\n".join(lines) + "\n"


def _relation_matrix(n, J, ports) -> np.ndarray:
    """Kernel form K [f_x; f_p; e_x; e_p] = 0 of the J/R/B Dirac structure, written from
    the documented equations (R is not part of it):
    effort_in:  f_x = J e_x − B e_p,  f_p = Bᵀ e_x;   flow_in:  f_x = J e_x + B f_p,  e_p = −Bᵀ e_x."""
    m = sum(dim for _, dim, _, _ in ports)
    K = np.zeros((n + m, 2 * (n + m)))
    fx, fp, ex, ep = 0, n, n + m, 2 * n + m
    K[:n, fx:fx + n] = np.eye(n)
    K[:n, ex:ex + n] = -np.asarray(J, dtype=float)
    row, col = n, 0
    for _, dim, B, causality in ports:
        B = np.asarray(B, dtype=float)
        for k in range(dim):
            if causality == "effort_in":
                K[:n, ep + col + k] += B[:, k]
                K[row, fp + col + k] = 1.0
                K[row, ex:ex + n] = -B[:, k]
            else:
                K[:n, fp + col + k] -= B[:, k]
                K[row, ep + col + k] = 1.0
                K[row, ex:ex + n] = B[:, k]
            row += 1
        col += dim
    return K


def _phc_structure(rel, n, ports) -> np.ndarray:
    """phc's recorded relations, reordered to [f_x; f_p; e_x; e_p], as a kernel basis."""
    variables = list(rel.flows) + list(rel.efforts) + list(rel.multipliers)
    K = np.array(sp.Matrix(list(rel.relations)).jacobian(variables).evalf(), dtype=float)
    N = sla.null_space(K)[: 2 * len(rel.flows)]
    order = list(range(n)) + [i for name, _, _, _ in ports for i in rel.ports[name][0]]
    nz = len(rel.flows)
    return N[order + [nz + i for i in order]]


def _flow_in_columns(n, ports) -> list[list[float]]:
    """The input matrices of the flow_in ports side by side (n rows)."""
    return [[B[i][k] for _, dim, B, c in ports if c == "flow_in" for k in range(dim)] for i in range(n)]


def _flow_in_rank_ok(n, ports) -> bool:
    """Exact rank (rationals): the stacked flow_in input matrix has full column rank."""
    stacked = sp.Matrix([[sp.Rational(x) for x in row] for row in _flow_in_columns(n, ports)])
    return stacked.rank() == stacked.shape[1]


@settings(max_examples=100, deadline=None)
@given(jrb_components())
def test_random_jrb_component_is_dirac_and_agrees_with_brute_force(component):
    n, J, Q, ports = component
    m = sum(dim for _, dim, _, _ in ports)
    # The structure built here from J and B.
    K = _relation_matrix(n, J, ports)
    N = sla.null_space(K)
    assert N.shape[1] == n + m                       # dim D = dim Z
    f, e = N[: n + m], N[n + m:]
    rng = np.random.default_rng(len(ports) * 10 + n)
    for _ in range(5):
        a, b = N @ rng.normal(size=n + m), N @ rng.normal(size=n + m)
        pairing = a[: n + m] @ b[n + m:] + b[: n + m] @ a[n + m:]
        assert abs(pairing) <= 1e-10 * np.linalg.norm(a) * np.linalg.norm(b)
    assert np.abs(f.T @ e + e.T @ f).max() <= 1e-10

    with tempfile.TemporaryDirectory() as tmp:
        path = Path(tmp) / "model.yaml"
        path.write_text(_yaml(n, J, Q, ports))
        dae, diags = elaborate(path)
        assert dae is not None and not diags.has_errors, "\n".join(d.render() for d in diags)
        cert = certify(dae)
        rank_ok = _flow_in_rank_ok(n, ports)
        event("flow_in inputs independent" if rank_ok else "flow_in inputs dependent")
        if rank_ok:
            built, build_diags = phc.build_dae(path)
            assert built is not None, "\n".join(d.render() for d in build_diags)
    sys_cert = next(c for c in cert.components if c.name == "sys")
    assert sys_cert.dirac is True
    assert sys_cert.dim_d == sys_cert.dim_z == n + m
    assert sys_cert.isotropy <= 1e-9
    # phc's recorded structure is the same subspace as the one built here.
    rel = next(r for r in dae.topology.dirac if r.component == "sys")
    P = _phc_structure(rel, n, ports)
    assert P.shape[1] == n + m
    assert np.linalg.matrix_rank(np.hstack([N, P]), tol=1e-9) == n + m
    # Coupling to e = 0 terminations is onto Z_c × Z_c unless the flow_in input maps are
    # dependent: then B_flow_inᵀ ∇H = 0 over-determines the state, and Γ loses exactly the
    # missing rank (summed over the connections, in any interconnection order).
    deficit = sum(c.needed - c.achieved for c in cert.connections)
    flow_in_cols = sum(dim for _, dim, _, c in ports if c == "flow_in")
    if rank_ok:
        assert cert.certified, cert.render_text()
        assert deficit == 0
    else:
        assert not cert.certified
        assert "PHC-E421" in {d.code for d in cert.diagnostics}
        stacked = sp.Matrix([[sp.Rational(x) for x in row] for row in _flow_in_columns(n, ports)])
        assert deficit == flow_in_cols - stacked.rank()


@settings(max_examples=30, deadline=None)
@given(jrb_components(skew=False))
def test_non_skew_J_is_rejected(component):
    n, J, Q, ports = component
    JJ = np.asarray(J)
    if not np.any(JJ + JJ.T):
        J = [[J[i][j] + (1.0 if i == j == 0 else 0.0) for j in range(n)] for i in range(n)]
    with tempfile.TemporaryDirectory() as tmp:
        path = Path(tmp) / "model.yaml"
        text = _yaml(n, J, Q, ports)
        path.write_text(text)
        dae, diags = phc.build_dae(path)
    assert dae is None
    e402 = [d for d in diags if d.code == "PHC-E402"]
    assert len(e402) == 1
    assert e402[0].span.line == text.splitlines().index(f"    J: {json.dumps(J)}") + 1
    worst = np.abs(np.asarray(J) + np.asarray(J).T).max()
    assert worst > 0
    assert f"max |J + Jᵀ| = {worst:.3g}" in e402[0].message


# -- singular configurations and known bugs (strict xfail: they fail once phc is fixed) ---


def test_isotropy_error_is_the_maximum_over_unit_elements(tmp_path):
    path = tmp_path / "model.yaml"
    path.write_text(
        "format_version: 1\n"
        "components:\n"
        "  osc:\n"
        "    type: phs\n"
        "    states: [x]\n"
        "    hamiltonian: x**2/2\n"
        "    ports:\n"
        "      port: {}\n"
        "    relations:\n"
        "      - f_x = f_port\n"
        "      - e_port = -2*e_x\n"
        "  sink: {type: zero_effort}\n"
        "connections:\n"
        "  - [osc.port, sink.port]\n")
    dae, _ = elaborate(path)
    cert = certify(dae)
    osc = next(c for c in cert.components if c.name == "osc")
    assert osc.dirac is False and osc.dim_d == osc.dim_z == 2
    # D = span{(f_x, f_port) = (1, 1)/√2, (e_x, e_port) = (1, −2)/√5}: the pairing of the two
    # basis vectors is (1·1 + 1·(−2))/√10, and that is the maximum over unit elements.
    assert osc.isotropy == pytest.approx(1 / math.sqrt(10), rel=1e-9)


def _singular_slider_crank(tmp_path, L: str) -> Path:
    """The shipped slider–crank started at θ = π/2 with rod length `L` (crank radius 0.15).
    With L = r the rod stands vertical on the guide: a singular configuration."""
    text = SLIDER_CRANK.read_text()
    r, l_val = 0.15, float(L)
    s = math.sqrt(l_val**2 - r**2)
    phi = math.atan2(-r, s)
    initial = ("  initial:\n"
               f"    crank.theta: {math.pi / 2!r}\n"
               f"    rod.x: {s / 2!r}\n"
               f"    rod.y: {r / 2!r}\n"
               f"    rod.phi: {phi!r}\n"
               f"    slider.s: {s!r}\n")
    start = text.index("  initial:\n")
    end = text.index("  outputs:\n")
    text = text[:start] + initial + text[end:]
    text = text.replace("L: {value: 0.30,", f"L: {{value: {L},")
    path = tmp_path / f"slider_crank_{L}.yaml"
    path.write_text(text)
    return path


def test_slider_crank_at_theta_pi_over_2_with_long_rod_is_certified(tmp_path):
    """Control for the xfail below: with L = 2r the same crank angle is regular."""
    _, cert = _certificate(_singular_slider_crank(tmp_path, "0.30"))
    assert cert.certified, cert.render_text()


def test_slider_crank_singular_configuration_is_not_certified(tmp_path):
    """The crank speed is imposed (flow source, certified as its termination f = 0) and the
    rod stands vertical on the guide (L = r, θ = π/2): the joint at the slider loses rank at
    the initial state — the singularity the simulation monitor stops at."""
    dae, cert = _certificate(_singular_slider_crank(tmp_path, "0.15"))
    assert not cert.certified
    failing = [c for c in cert.connections if not c.surjective]
    assert len(failing) == 1
    assert failing[0].achieved == failing[0].needed - 1
    assert len(failing[0].failing_samples) == 1          # the initial state only
    assert failing[0].failing_samples[0]["rod.phi"] == pytest.approx(-math.pi / 2)
    e421 = [d for d in cert.diagnostics if d.code == "PHC-E421"]
    assert len(e421) == 1 and "at 1 of 3 sampled states" in e421[0].message


def test_symbolic_failure_condition_is_not_claimed_where_gamma_has_full_rank(tmp_path):
    path = tmp_path / "model.yaml"
    path.write_text(
        "format_version: 1\n"
        "components:\n"
        "  bob:\n"
        "    type: rigid\n"
        "    q: [x, y]\n"
        "    M: [[1, 0], [0, 1]]\n"
        "    ports:\n"
        "      rope:\n"
        "        B: [[x], [y]]\n"
        "  anchor: {type: zero_flow}\n"
        "connections:\n"
        "  - [bob.rope, anchor.port]\n"
        "simulation:\n"
        "  initial: {bob.x: 0.0, bob.y: 1.0}\n")
    _, cert = _certificate(path)
    (conn,) = cert.connections
    assert conn.surjective and conn.failing_samples == []   # full rank at x = 0, y = 1 ...
    assert cert.certified
    # ... so a failure set, if reported, must involve y as well (it is x = y = 0).
    assert conn.condition is None or "bob.y" in conn.condition


@pytest.mark.parametrize("theta, certified", [(0.7, True), (1.5707963267948966, False)])
def test_flexible_slider_crank_with_the_rod_orthogonal_to_the_guide(tmp_path, theta, certified):
    """Seed section 5.2: Γ is onto where a_s·t ≠ 0 — a sufficient condition. With the rod
    orthogonal to the guide (a_s·t = 0) the wheel's pin velocity still restores the rank
    unless it is parallel to the rod normal as well (θ = π/2 here): phc finds exactly that."""
    text = (MODELS / "flexible_slider_crank.yaml").read_text()
    text = text.replace("    wheel.theta: 0.0", f"    wheel.theta: {theta}")
    text = text.replace("    rod.q0[0]: r\n", "    rod.q0[0]: 0.0\n").replace("    rod.q0[1]: 0.0", "    rod.q0[1]: 0.3")
    text = text.replace("    rod.qf[0]: r + L", "    rod.qf[0]: 0.0")
    path = tmp_path / "fsc.yaml"
    path.write_text(text)
    cert = certify(phc.build_dae(path)[0])
    assert cert.certified is certified
    if not certified:
        [bad] = [c for c in cert.connections if not c.surjective]
        assert (bad.port_a, bad.port_b) == ("wheel.pin", "rod.p0")
        assert bad.failing_samples[0]["wheel.theta"] == pytest.approx(theta)
