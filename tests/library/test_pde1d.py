"""Tests of `phc.library.pde1d` (generic 1-D pH PDEs, seed eq. BH1gen and BNDtriplet)."""

import numpy as np
import pytest
import scipy.linalg as sla

import phc
from phc.library.pde1d import green_identity_error

STRING = """
format_version: 1
parameters: {{rho: 2.0, T: 8.0}}
components:
  s:
    type: pde1d
    order: 1
    variables: [p, eps]
    P: {P}
    H: {H}
    W_f: {W_f}
    W_e: {W_e}
    ports: [left, right]
    port_domains: [mechanical.translational, mechanical.translational]
    length: 1.0
    elements: 16
  l: {{type: zero_flow, domain: mechanical.translational}}
  r: {{type: zero_flow, domain: mechanical.translational}}
connections:
  - [s.left, l.port]
  - [s.right, r.port]
"""
GOOD = dict(P="[[[0, 0], [0, 0]], [[0, 1], [1, 0]]]", H='[["1/rho", 0], [0, T]]',
            W_f="[[0, 0, 1, 0], [1, 0, 0, 0]]", W_e="[[0, 0, 0, 1], [0, -1, 0, 0]]")


def spectrum(path):
    """Finite generalized eigenvalues of the linear DAE E ẏ + A y = 0, sorted by frequency."""
    mod = phc.compile_model(path).module
    p, y, buf = mod.full_parameters(), np.zeros(mod.N), np.zeros(len(mod.JAC_ROWS))
    mats = []
    for cj in (0.0, 1.0):
        mod.jacobian(0.0, y, y, p, cj, buf)
        M = np.zeros((mod.N, mod.N))
        M[mod.JAC_ROWS, mod.JAC_COLS] = buf
        mats.append(M)
    lam = sla.eig(-mats[0], mats[1] - mats[0], right=False)
    lam = lam[np.isfinite(lam)]
    return lam[np.argsort(lam.imag)]


def frequencies(path):
    lam = spectrum(path)
    return np.sort(lam.imag[lam.imag > 1e-6])


def write(tmp_path, **changes):
    path = tmp_path / "m.yaml"
    path.write_text(STRING.format(**{**GOOD, **changes}))
    return path


def test_seed_string_as_pde1d_has_the_string_frequencies(tmp_path):
    """The seed's Example ex:expde (a) written as a generic pde1d: ω_k = kπ sqrt(T/ρ)/L to O(h²)."""
    w = frequencies(write(tmp_path))
    exact = np.arange(1, 4) * np.pi * 2.0
    assert np.all(np.abs(w[:3] - exact) / exact < 0.02)
    lib = tmp_path / "lib.yaml"
    lib.write_text("""
format_version: 1
components:
  s: {type: string, length: 1.0, rho: 2.0, T: 8.0, elements: 16}
  l: {type: zero_flow, domain: mechanical.translational}
  r: {type: zero_flow, domain: mechanical.translational}
connections:
  - [s.a, l.port]
  - [s.b, r.port]
""")
    assert np.allclose(w[:5], frequencies(lib)[:5], rtol=1e-12)


@pytest.mark.parametrize("changes, code, where", [
    (dict(W_e="[[0, 0, 0, 1], [0, 1, 0, 0]]"), "PHC-E155", "W_e"),           # wrong sign: Green identity fails
    (dict(P="[[[0, 1], [0, 0]], [[0, 1], [1, 0]]]"), "PHC-E151", "P[0]"),     # P_0 not skew
    (dict(P="[[[0, 0], [0, 0]], [[0, 1], [2, 0]]]"), "PHC-E151", "P[1]"),     # P_1 not symmetric
    (dict(W_f="[[0, 0, 1, 0], [0, 0, 1, 0]]"), "PHC-E154", "W_f"),           # W singular
    (dict(H='[["-1/rho", 0], [0, T]]'), "PHC-E152", "H"),                    # H not positive definite
])
def test_structural_conditions_are_located_errors(tmp_path, changes, code, where):
    dae, diags = phc.build_dae(write(tmp_path, **changes))
    assert dae is None
    assert [d.code for d in diags.errors] == [code]
    assert diags.errors[0].path.endswith(where)
    assert diags.errors[0].span.line > 1


def test_green_identity_of_the_seed_timoshenko_boundary_choice():
    """Example ex:expde (b): the physical W_f, W_e satisfy eq. BNDtriplet."""
    P0 = np.array([[0, 0, 0, -1], [0, 0, 0, 0], [0, 0, 0, 0], [1, 0, 0, 0]], dtype=float)
    P1 = np.array([[0, 1, 0, 0], [1, 0, 0, 0], [0, 0, 0, 1], [0, 0, 1, 0]], dtype=float)
    # γ = (e(b), e(a)), e = (e_γ, e_p, e_θ, e_M)
    Wf = np.zeros((4, 8))
    We = np.zeros((4, 8))
    Wf[0, 4 + 1] = Wf[1, 1] = Wf[2, 4 + 3] = Wf[3, 3] = 1.0       # v(a), v(b), ω(a), ω(b)
    We[0, 4 + 0], We[1, 0], We[2, 4 + 2], We[3, 2] = 1.0, -1.0, 1.0, -1.0  # Kγ(a), −Kγ(b), EIθ(a), −EIθ(b)
    assert green_identity_error([P0, P1], Wf, We, 1.3) < 1e-12
    We[1, 0] = 1.0
    assert green_identity_error([P0, P1], Wf, We, 1.3) > 1e-3


def test_dissipation_D_matches_the_damped_library_string(tmp_path):
    """The D term of eq. BH1gen: D = diag(c, 0) is viscous damping on the momentum, the
    library string's `damping: c`; both give the same (now damped) spectrum."""

    text = STRING.format(**GOOD).replace("    H: [", "    D: [[0.5, 0], [0, 0]]\n    H: [", 1)
    generic = tmp_path / "generic.yaml"
    generic.write_text(text)
    lib = tmp_path / "lib.yaml"
    lib.write_text("""
format_version: 1
components:
  s: {type: string, length: 1.0, rho: 2.0, T: 8.0, elements: 16, damping: 0.5}
  l: {type: zero_flow, domain: mechanical.translational}
  r: {type: zero_flow, domain: mechanical.translational}
connections:
  - [s.a, l.port]
  - [s.b, r.port]
""")
    a, b = spectrum(generic), spectrum(lib)
    assert np.all(a.real[np.abs(a.imag) > 1.0] < -1e-3)  # the oscillating modes are damped
    assert np.allclose(a, b, rtol=1e-9, atol=1e-9)       # identical discretization
    result = phc.simulate(phc.compile_model(generic), t_end=0.5, rtol=1e-9, atol=1e-11,
                          initial={"s.p[8]": 0.5})
    assert result.success and result.energy_balance_relative < 1e-6 and result.H[-1] < result.H[0]
