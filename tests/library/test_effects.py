"""Tests of the effects of the library beams: `modes: k` (`phc.library.modal`, the
structure-preserving modal truncation) and the Timoshenko beam's `shear` and
`rotary_inertia` (`phc.library.beams`).

What is checked, and against what:

* issue 6 evidence (c): with k = 2, 4, 8 modes the lowest eigenfrequencies of the
  truncated component equal the full discretization's to round-off when all traces are
  held (clamped–clamped beam, fixed string: the fixed-interface modes are kept exactly),
  and converge to them monotonically with k for pinned and cantilevered ends;
* a driven cantilever's tip-velocity response converges to the full model's as k grows;
* the reduced system is pH: the lossless part of dF/de is skew, the energy matrix SPD,
  and the discrete energy balance of a driven lossless truncated beam holds to round-off
  (implicit midpoint is exact for quadratic H);
* the moving beam keeps its ports, its deflection output `w(ξ)` and its rigid start;
* what is left out is reported.
"""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest

import phc
from test_beams import (CLAMPED_FREE, EB_PARAMS, FIXED_STRING, PINNED, STRING_PARAMS, TIMOSHENKO_PARAMS,
                        eb_body, eigenfrequencies, jacobian_blocks, string_body, timoshenko_body, write_model)

MODELS = Path(__file__).resolve().parents[2] / "models"
CLAMPED = {"a": "zero_flow", "a_rot": "zero_flow", "b": "zero_flow", "b_rot": "zero_flow"}


def _compile(tmp_path, tag, body, ends, params, **kw):
    return phc.compile_model(write_model(tmp_path, tag, body, ends, params, **kw))


@pytest.fixture(scope="module")
def workdir(tmp_path_factory):
    return tmp_path_factory.mktemp("effects")


@pytest.mark.parametrize("body, params, ends", [
    (eb_body, EB_PARAMS, CLAMPED),
    (string_body, STRING_PARAMS, FIXED_STRING),
], ids=["euler_bernoulli_clamped", "string_fixed"])
def test_modes_exact_for_held_traces(workdir, body, params, ends):
    """All traces held: the reduced model's k lowest frequencies are the full ones."""
    full = _compile(workdir, "full", body(16), ends, params)
    reference = eigenfrequencies(full.module, 8)
    for k in (2, 4, 8):
        reduced = _compile(workdir, f"modes{k}", body(16, effects={"modes": k}), ends, params)
        omega = eigenfrequencies(reduced.module, k)
        assert np.abs(omega / reference[:k] - 1).max() < 1e-9
        assert reduced.module.N < full.module.N


@pytest.mark.parametrize("body, params, ends", [
    (eb_body, EB_PARAMS, PINNED),
    (eb_body, EB_PARAMS, CLAMPED_FREE),
    (timoshenko_body, TIMOSHENKO_PARAMS, PINNED),
], ids=["euler_bernoulli_pinned", "euler_bernoulli_cantilever", "timoshenko_pinned"])
def test_modes_converge_to_full_discretization(workdir, body, params, ends):
    """Free traces: Rayleigh–Ritz on [static modes | k fixed-interface modes] — frequencies
    are upper bounds that decrease to the full discretization's as k grows."""
    full = _compile(workdir, "full", body(16), ends, params)
    reference = eigenfrequencies(full.module, 2)
    errors = []
    for k in (2, 4, 8):
        reduced = _compile(workdir, f"modes{k}", body(16, effects={"modes": k}), ends, params)
        rel = eigenfrequencies(reduced.module, 2) / reference - 1
        assert rel.min() > -1e-10  # Rayleigh–Ritz: from above
        errors.append(rel.max())
    assert errors[0] > errors[1] > errors[2]
    assert errors[0] < 2e-3 and errors[2] < 1e-4


def test_reduced_structure_is_port_hamiltonian(workdir):
    """Rows K ż + J z + B e_∂: dF/dż symmetric positive definite (the energy metric), the
    z-block of dF/dz skew (lossless), as in the full discretization."""
    mod = _compile(workdir, "structure", eb_body(12, effects={"modes": 4}), PINNED, EB_PARAMS).module
    A, E = jacobian_blocks(mod)
    z = [j for j, name in enumerate(mod.VARIABLES) if ".z" in name]
    rows = [i for i, label in enumerate(mod.EQUATIONS) if ".modal_" in label]
    Ez, Az = E[np.ix_(rows, z)], A[np.ix_(rows, z)]
    assert np.abs(Ez - Ez.T).max() < 1e-12 * np.abs(Ez).max()
    assert np.linalg.eigvalsh(Ez).min() > 0
    assert np.abs(Az + Az.T).max() < 1e-12 * np.abs(Az).max()


def _driven_cantilever(workdir, tag, effects, damping=None):
    extra = {"effects": effects} if effects else {}
    if damping is not None:
        extra["damping"] = damping
    ends = {**CLAMPED_FREE, "b": "0.5*sin(2000*t)"}
    return _compile(workdir, tag, eb_body(12, **extra), ends, EB_PARAMS,
                    simulation={"t_end": 0.01, "n_out": 101, "solver": "midpoint", "step": 1e-5,
                                "outputs": {"v_tip": "body.b.f"}})


def test_driven_response_converges_and_energy_balance_is_exact(workdir):
    full = phc.simulate(_driven_cantilever(workdir, "drive_full", None))
    assert full.success
    errors = []
    for k in (1, 2, 4):
        result = phc.simulate(_driven_cantilever(workdir, f"drive{k}", {"modes": k}))
        assert result.success
        # lossless, driven: H(t) − H(0) = ∫ port power, to round-off with implicit midpoint
        assert result.energy_balance_relative < 1e-10
        errors.append(np.abs(result["v_tip"] - full["v_tip"]).max())
    scale = np.abs(full["v_tip"]).max()
    assert errors[0] > errors[1] > errors[2]
    assert errors[2] < 0.05 * scale


def test_modes_left_out_is_reported(workdir):
    compiled = _compile(workdir, "report", eb_body(16, effects={"modes": 3}), PINNED, EB_PARAMS)
    entries = [(what, why) for comp, what, why in compiled.dae.left_out if comp == "body"]
    # 2(n+1) = 34 velocity DOFs, 4 trace DOFs: 30 fixed-interface modes, 3 kept
    assert ("27 modes above mode 3", "effect `modes` = 3") in entries


def _scene(workdir, name, effects, t_end=0.0012):
    path = workdir / f"{name}.yaml"
    path.write_text(
        f"format_version: 1\nmodel: {(MODELS / 'flexible_slider_crank.yaml').as_posix()}\nname: {name}\n"
        f"effects:\n  rod: {effects}\nt_end: {t_end}\nn_out: 25\naccuracy: {{step: 2.0e-5}}\nsolver: midpoint\n")
    return path


def test_moving_beam_modes_keep_deflection_output_and_energy(workdir):
    """The flexible slider–crank with a 2- and a 4-mode rod: the deflection w(L/2) and the
    slider converge to the full model's, the rigid start holds and energy is kept."""
    full = phc.simulate(phc.compile_model(_scene(workdir, "full", "{moving_frame: on}")))
    assert full.success
    w_full = full["midspan_deflection"]
    errors = []
    for k in (2, 4):
        compiled = phc.compile_model(_scene(workdir, f"modes{k}", f"{{modes: {k}}}"))
        reduced = phc.simulate(compiled)
        assert reduced.success
        assert compiled.module.N < 40
        assert reduced.energy_balance_relative < 1e-9
        assert reduced["midspan_deflection"][0] == pytest.approx(0.0, abs=1e-14)  # straight start
        errors.append((np.abs(reduced["midspan_deflection"] - w_full).max(),
                       np.abs(reduced["slider_x"] - full["slider_x"]).max()))
    assert errors[1][0] < errors[0][0] < 0.02 * np.abs(w_full).max()
    assert errors[1][1] < errors[0][1] < 1e-6


# -- Timoshenko beam: `shear` and `rotary_inertia` -------------------------------------


def _timoshenko_pinned(workdir, n, **effects):
    return _compile(workdir, f"timo{n}", timoshenko_body(n, effects=effects), PINNED, TIMOSHENKO_PARAMS)


def test_timoshenko_without_shear_and_rotary_inertia_is_euler_bernoulli(workdir):
    """Seed Example ex:expde (c): both effects off give the Euler–Bernoulli beam. Simply
    supported: ω_n = (nπ/L)² √(EI/ρA) (eq. euler-bernoulli-reference). The constrained
    P1/P0 discretization converges at O(h²), so the errors drop 4× per refinement and the
    Richardson extrapolation hits the closed form."""
    from test_beams import EI, LENGTH, RHO_A

    closed = np.array([(n * math.pi / LENGTH) ** 2 * math.sqrt(EI / RHO_A) for n in (1, 2)])
    errors = []
    for n in (8, 16, 32):
        compiled = _timoshenko_pinned(workdir, n, shear=False, rotary_inertia=False)
        errors.append(eigenfrequencies(compiled.module, 2) / closed - 1)
        assert not any(".gamma[" in v or ".M[" in v for v in compiled.module.VARIABLES)  # no such states
    errors = np.array(errors)
    ratios = errors[:-1] / errors[1:]
    assert np.all(np.abs(ratios - 4.0) < 0.25)  # 4.01–4.19: asymptotic from n = 8
    assert np.abs((4 * errors[2] - errors[1]) / 3).max() < 1e-4


def test_timoshenko_effects_off_stiffen(workdir):
    """Infinite shear stiffness or no rotary inertia raises every frequency of the same mesh
    (Rayleigh quotient: more stiffness, less kinetic energy); what is left out is reported."""
    reference = eigenfrequencies(_timoshenko_pinned(workdir, 16).module, 3)
    for effects in ({"shear": False}, {"rotary_inertia": False}):
        compiled = _timoshenko_pinned(workdir, 16, **effects)
        assert np.all(eigenfrequencies(compiled.module, 3) > reference)
        (effect,) = effects
        assert any(why == f"effect `{effect}` is off" for _, _, why in compiled.dae.left_out)


def test_timoshenko_euler_bernoulli_limit_keeps_energy_balance(workdir):
    """The constrained (index-2) system simulates with the midpoint rule and its discrete
    energy balance, driven through the tip, holds to round-off."""
    ends = {"a": "zero_flow", "a_rot": "zero_flow", "b": "0.5*sin(2000*t)", "b_rot": "zero_effort"}
    compiled = _compile(workdir, "timo_drive", timoshenko_body(8, effects={"shear": False, "rotary_inertia": False}),
                        ends, TIMOSHENKO_PARAMS,
                        simulation={"t_end": 0.005, "n_out": 51, "solver": "midpoint", "step": 1e-5})
    result = phc.simulate(compiled)
    assert result.success
    assert result.energy_balance_relative < 1e-10
