"""The moving beam with effect `axial` on (issue 17): longitudinal displacement u(ξ) with
axial stiffness EA beside the paper's bending field, the tangential momentum a field
p_a(ξ) coupled to the chord frame's rotation (docs/crank-test-problem.md).

Fast checks against closed forms: the pinned–free bar's axial frequencies
ω_k = (2k − 1)·π/(2L)·√(EA/ρA), the energy balance of the flexible slider–crank with axial
deformation at round-off with the midpoint rule, the stretch seen at the slider, and the
located errors for `axial` without `EA` or with `modes`.
"""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest

import phc

REPO = Path(__file__).resolve().parents[1]
MODELS = REPO / "models"

L, RHOA = 0.3, 0.50368

BAR = """
format_version: 1
name: pinned_free_bar
parameters: {{L: {L}, rhoA: {rhoA}, EI: 68.27, EA: {EA}}}
components:
  rod:
    type: moving_beam
    length: L
    rhoA: rhoA
    EI: EI
    EA: EA
    elements: {n}
    effects: {{axial: on}}
  pin: {{type: zero_flow, domain: mechanical.translational, dimension: 2}}
  free: {{type: zero_effort, domain: mechanical.translational, dimension: 2}}
  m0: {{type: zero_effort, domain: mechanical.rotational}}
  mf: {{type: zero_effort, domain: mechanical.rotational}}
connections:
  - [rod.p0, pin.port]
  - [rod.pf, free.port]
  - [rod.m0, m0.port]
  - [rod.mf, mf.port]
simulation:
  t_end: 0.01
  initial:
    rod.q0[0]: 0.0
    rod.q0[1]: 0.0
    rod.qf[0]: L
    rod.qf[1]: 0.0
"""


def _axial_crank(tmp_path, elements: int = 4, extra: str = "    effects: {axial: on}\n") -> Path:
    text = (MODELS / "flexible_slider_crank.yaml").read_text()
    old = "    elements: 8\n"
    assert old in text
    text = text.replace(old, f"    elements: {elements}\n    EA: 1.28e7\n{extra}", 1)
    path = tmp_path / "axial_crank.yaml"
    path.write_text(text)
    return path


def test_the_pinned_free_bar_has_the_axial_frequencies_of_the_closed_form(tmp_path):
    # EA chosen so that the two lowest axial modes lie below the first bending mode of the
    # pinned–free beam ((3.9266/L)²√(EI/ρA) ≈ 1995 rad/s): ω_1 = 500 rad/s, ω_2 = 1500 rad/s.
    c = 500.0 * 2 * L / math.pi
    ea = RHOA * c**2
    path = tmp_path / "bar.yaml"
    path.write_text(BAR.format(L=L, rhoA=RHOA, EA=ea, n=8))
    lin = phc.linearize_model(path, certify=False)
    omegas = sorted(abs(m.eigenvalue.imag) for m in lin.modes if abs(m.eigenvalue.imag) > 1.0)
    exact = [(2 * k - 1) * math.pi / (2 * L) * math.sqrt(ea / RHOA) for k in (1, 2)]
    bending = (3.926602 / L) ** 2 * math.sqrt(68.27 / RHOA)  # pinned–free beam: tan βL = tanh βL
    # P1 velocities / P0 strains: frequency error O((kh)²), 8 elements
    err = [omegas[0] / exact[0] - 1, omegas[1] / exact[1] - 1]
    assert 0 < err[0] < 3e-3 and 0 < err[1] < 2e-2, (omegas[:3], exact)
    assert 7.0 < err[1] / err[0] < 10.0, err  # second order: the third half-wave has 3× the kh
    # the bending modes are untouched: the third frequency is the first bending mode
    assert abs(omegas[2] / bending - 1) < 1e-3, (omegas[2], bending)


def test_the_energy_balance_with_axial_deformation_holds_to_round_off_with_the_midpoint_rule(tmp_path):
    path = _axial_crank(tmp_path)
    model = phc.compile_model(path, backend="numpy")
    r = phc.simulate(model, t_end=0.003, solver="midpoint", step=1e-5)
    assert r.success, r.message
    assert r.energy_balance_relative < 1e-12, r.energy_balance_relative
    # the rod really stretches, and the slider sees it: its distance from the crank pin is
    # L plus the integrated strain (the chord invariant), not L
    chord = np.hypot(r["rod.qf[0]"] - r["rod.q0[0]"], r["rod.qf[1]"] - r["rod.q0[1]"])
    eps = np.array([r[f"rod.eps[{k}]"] for k in range(4)]).T
    assert np.max(np.abs(chord - (L + eps.sum(axis=1) * L / 4))) < 1e-12
    assert np.max(np.abs(chord - L)) > 1e-7  # the rod's inertia stretches it by micrometres


def test_axial_without_EA_or_with_modes_is_a_located_error(tmp_path):
    path = _axial_crank(tmp_path, extra="    effects: {axial: on}\n")
    text = path.read_text().replace("    EA: 1.28e7\n", "", 1)
    path.write_text(text)
    dae, diags = phc.build_dae(path)
    errors = [d for d in diags if d.code == "PHC-E145"]
    assert dae is None and errors and "needs the axial stiffness `EA`" in errors[0].message
    assert errors[0].span is not None and errors[0].span.line > 1
    path = _axial_crank(tmp_path, extra="    effects: {axial: on, modes: 2}\n")
    dae, diags = phc.build_dae(path)
    assert dae is None and any(d.code == "PHC-E145" and "`modes`" in d.message for d in diags)


def test_the_axial_modulation_is_in_the_rows_as_the_description_says_it(tmp_path, monkeypatch):
    """The rows are derived from the complete description: the rows check (which compares
    them independently) finds them equal; and a modulation that is no longer skew — its
    half ṗ_a ∋ ω ρ C e_b flipped in the description, ṗ_b ∋ −ω ρ Cᵀ e_a kept — is in the
    compiled rows too, where the certificate of the compiled equations finds the power
    it creates."""
    from phc.checks.compiled import certify_compiled
    from phc.checks.rows import check_rows
    from phc.library import moving

    path = _axial_crank(tmp_path)
    dae = phc.build_dae(path)[0]
    cert = check_rows(dae)
    assert "rod" in cert.compared and not cert.diagnostics
    assert next(r for r in dae.topology.rows if r.component == "rod").derived
    assert certify_compiled(phc.compile_model(path, certify=False), n_random=2).certified
    honest = moving._modulate

    def half_flipped(load, trace, C, rho, omega):
        honest(lambda local, i, expr: load(local, i, -expr if local == "pa" else expr), trace, C, rho, omega)

    monkeypatch.setattr(moving, "_modulate", half_flipped)
    compiled = phc.compile_model(path, certify=False)
    assert next(r for r in compiled.dae.topology.rows if r.component == "rod").derived
    assert not check_rows(compiled.dae).diagnostics  # the rows still say what the description says
    assert not certify_compiled(compiled, n_random=2).certified
