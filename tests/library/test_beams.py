"""Tests of `phc.library.beams`: the string, Timoshenko and Euler–Bernoulli beam (seed
Example ex:expde) discretized by the partitioned mixed finite element method that keeps
the boundary ports.

What is checked, and against what (all reference values are derived here, in comments,
never taken from an earlier run):

* eigenfrequencies converge to the closed forms at the theoretical order (O(h²) for the
  string and the Timoshenko beam with P1/P0 elements, O(h⁴) for the Euler–Bernoulli beam
  with Hermite cubics / discontinuous linears), measured over three meshes;
* the interconnection is lossless at matrix level (free–free spectra on the imaginary axis)
  and the semi-discrete power balance dH/dt = −P_ports − P_diss holds to round-off at
  random states for any mesh, and along simulations;
* damping dissipates, ξ-dependent coefficients converge, errors are located diagnostics,
  the boundary ports exist and connect to lumped components;
* the shipped models `models/vibrating_string.yaml`, `models/euler_bernoulli_beam.yaml`
  and `models/timoshenko_beam.yaml` reproduce their closed forms.
"""

from __future__ import annotations

import math
from functools import lru_cache
from pathlib import Path

import numpy as np
import pytest
import scipy.linalg as sla
import yaml

import phc
from phc.errors import ModelError, SimulationSetupError
from phc.simulation import parameter_vector

REPO = Path(__file__).resolve().parents[2]
MODELS = REPO / "models"
TRANS, ROT = "mechanical.translational", "mechanical.rotational"

# The seed's slider–crank rod: steel (E = 200 GPa, ρ_s = 7870 kg/m³, ν = 0.3), 8 mm square
# section, so EI = E a⁴/12 ≈ 68.27 N m², ρA = ρ_s a² = 0.50368 kg/m; for the Timoshenko
# beam I_ρ = ρ_s a⁴/12 and K = (5/6) G a² with G = E/(2(1 + ν)).
EI, RHO_A, LENGTH = 68.27, 0.50368, 0.3
_A, _E, _RHO_S, _NU = 0.008, 2.0e11, 7870.0, 0.3
I_RHO = _RHO_S * _A**4 / 12
K_SHEAR = 5.0 / 6.0 * _E / (2 * (1 + _NU)) * _A**2
# A guitar-like string: wave speed c = sqrt(T/ρ) = 80 m/s.
STRING_RHO, STRING_T, STRING_L = 0.01, 64.0, 0.64


# -- building models -----------------------------------------------------------------


def write_model(directory: Path, name: str, body: dict, ends: dict, parameters: dict | None = None,
                extra: dict | None = None, simulation: dict | None = None) -> Path:
    """A model with one distributed component `body` whose ports are terminated or driven.

    `ends` maps a port of `body` to a termination type (`zero_flow`, `zero_effort`), to a
    number or expression string (an `effort_source` with that value), or to a full
    component dict.
    """
    components = {"body": body}
    connections = []
    for port, end in ends.items():
        domain = ROT if port.endswith("_rot") else TRANS
        if isinstance(end, dict):
            component = end
        elif end in ("zero_flow", "zero_effort"):
            component = {"type": end, "domain": domain}
        else:
            component = {"type": "effort_source", "domain": domain, "value": end}
        components[f"end_{port}"] = component
        connections.append([f"body.{port}", f"end_{port}.port"])
    components.update(extra or {})
    data = {"format_version": 1, "name": name, "parameters": parameters or {}, "components": components,
            "connections": connections}
    if simulation:
        data["simulation"] = simulation
    path = directory / f"{name}.yaml"
    path.write_text(yaml.safe_dump(data, sort_keys=False, allow_unicode=True))
    return path


def string_body(n, **extra):
    return {"type": "string", "length": STRING_L, "elements": n, "rho": "rho", "T": "T", **extra}


STRING_PARAMS = {"rho": STRING_RHO, "T": STRING_T}


def eb_body(n, length=LENGTH, **extra):
    return {"type": "euler_bernoulli_beam", "length": length, "elements": n, "rhoA": "rhoA", "EI": "EI", **extra}


EB_PARAMS = {"rhoA": RHO_A, "EI": EI}


def timoshenko_body(n, **extra):
    return {"type": "timoshenko_beam", "length": LENGTH, "elements": n, "rho": "rho", "I_rho": "I_rho",
            "EI": "EI", "K": "K", **extra}


TIMOSHENKO_PARAMS = {"rho": RHO_A, "I_rho": I_RHO, "EI": EI, "K": K_SHEAR}

PINNED = {"a": "zero_flow", "b": "zero_flow", "a_rot": "zero_effort", "b_rot": "zero_effort"}
CLAMPED_FREE = {"a": "zero_flow", "a_rot": "zero_flow", "b": "zero_effort", "b_rot": "zero_effort"}
FREE = {"a": "zero_effort", "b": "zero_effort", "a_rot": "zero_effort", "b_rot": "zero_effort"}
FIXED_STRING = {"a": "zero_flow", "b": "zero_flow"}
FREE_STRING = {"a": "zero_effort", "b": "zero_effort"}


# -- linear algebra on a compiled module ------------------------------------------------


def jacobian_blocks(mod, p=None, t=0.0):
    """Dense (dF/dy, dF/dyp) of the compiled module (the DAE is linear in y, yp here)."""
    p = mod.full_parameters() if p is None else p
    y = np.zeros(mod.N)

    def dense(cj):
        data = np.zeros(len(mod.JAC_ROWS))
        mod.jacobian(t, y, y, p, cj, data)
        out = np.zeros((len(mod.EQUATIONS), mod.N))
        np.add.at(out, (np.asarray(mod.JAC_ROWS), np.asarray(mod.JAC_COLS)), data)
        return out

    A = dense(0.0)
    return A, dense(1.0) - A


def finite_eigenvalues(mod, p=None) -> np.ndarray:
    """Finite generalized eigenvalues λ of A v + λ E v = 0 (i.e. eig(−A, E)), without the
    energy-accumulator variable and its balance row (they add a trivial zero)."""
    A, E = jacobian_blocks(mod, p)
    keep_cols = np.array([role != "energy" for role in mod.ROLES])
    keep_rows = np.array([eq != "energy.balance" for eq in mod.EQUATIONS])
    A, E = A[np.ix_(keep_rows, keep_cols)], E[np.ix_(keep_rows, keep_cols)]
    alpha, beta = sla.eig(-A, E, right=False, homogeneous_eigvals=True)
    finite = np.abs(beta) > 1e-11 * np.abs(alpha)
    return alpha[finite] / beta[finite]


def eigenfrequencies(mod, k=3, p=None) -> np.ndarray:
    lam = finite_eigenvalues(mod, p)
    omega = np.sort(lam.imag[lam.imag > 1e-6 * np.abs(lam).max()])
    return omega[:k]


@lru_cache(maxsize=None)
def _compiled(path: str) -> phc.CompiledModel:
    return phc.compile_model(path)


def compiled(path: Path) -> phc.CompiledModel:
    return _compiled(str(path))


def observed_orders(errors: np.ndarray) -> np.ndarray:
    """log2 of the error ratios of successive meshes (each halving h); errors[mesh, mode]."""
    return np.log2(errors[:-1] / errors[1:])


# -- convergence of eigenfrequencies --------------------------------------------------
#
# String, fixed–fixed: w = sin(kπξ/L) e^{iωt} in ρ w_tt = T w_ξξ gives ω_k = kπ sqrt(T/ρ)/L.
#
# Euler–Bernoulli, pinned–pinned (w = 0 and moment EI w_ξξ = 0 at both ends):
# w = sin(kπξ/L) e^{iωt} in ρA w_tt + EI w_ξξξξ = 0 gives ω_k = (kπ/L)² sqrt(EI/ρA).
#
# Euler–Bernoulli, clamped–free: w = A(cosh βξ − cos βξ) + B(sinh βξ − sin βξ) meets
# w = w_ξ = 0 at ξ = 0; zero moment and shear at ξ = L give 1 + cos βL cosh βL = 0 with
# roots βL = 1.8751040687, 4.6940911329, 7.8547574382, and ω = β² sqrt(EI/ρA).
#
# Timoshenko, simply supported (w = 0, moment EI φ_ξ = 0 at both ends): w = W sin kξ,
# φ = Φ cos kξ, k = nπ/L, in ρ w_tt = (K(w_ξ − φ))_ξ and I_ρ φ_tt = (EI φ_ξ)_ξ + K(w_ξ − φ):
#   (K k² − ρω²) W − K k Φ = 0,   −K k W + (EI k² + K − I_ρ ω²) Φ = 0,
# whose determinant is ρ I_ρ ω⁴ − (ρ(EI k² + K) + I_ρ K k²) ω² + K EI k⁴ = 0; the lower
# root ω² is the bending branch (the upper one, ~ K/I_ρ, is the shear branch).

CLAMPED_FREE_BETA_L = np.array([1.8751040687, 4.6940911329, 7.8547574382])


def string_exact():
    k = np.arange(1, 4)
    return k * math.pi * math.sqrt(STRING_T / STRING_RHO) / STRING_L


def eb_pinned_exact():
    k = np.arange(1, 4)
    return (k * math.pi / LENGTH) ** 2 * math.sqrt(EI / RHO_A)


def eb_clamped_free_exact():
    return (CLAMPED_FREE_BETA_L / LENGTH) ** 2 * math.sqrt(EI / RHO_A)


def timoshenko_simply_supported_exact(rho=RHO_A, i_rho=I_RHO, ei=EI, K=K_SHEAR, length=LENGTH):
    k = np.arange(1, 4) * math.pi / length
    a = rho * i_rho
    b = rho * (ei * k**2 + K) + i_rho * K * k**2
    c = K * ei * k**4
    lower = 2 * c / (b + np.sqrt(b * b - 4 * a * c))  # (b − sqrt(b² − 4ac))/(2a) without cancellation
    return np.sqrt(lower)


CONVERGENCE_CASES = {
    "string-fixed-fixed": (string_body, STRING_PARAMS, FIXED_STRING, string_exact, 2),
    "euler-bernoulli-pinned-pinned": (eb_body, EB_PARAMS, PINNED, eb_pinned_exact, 4),
    "euler-bernoulli-clamped-free": (eb_body, EB_PARAMS, CLAMPED_FREE, eb_clamped_free_exact, 4),
    "timoshenko-simply-supported": (timoshenko_body, TIMOSHENKO_PARAMS, PINNED,
                                    timoshenko_simply_supported_exact, 2),
}
MESHES = (8, 16, 32)


@pytest.mark.parametrize("case", CONVERGENCE_CASES)
def test_eigenfrequencies_converge_at_the_theoretical_order(case, tmp_path):
    body, params, ends, exact, order = CONVERGENCE_CASES[case]
    omega = exact()
    errors = []
    for n in MESHES:
        mod = compiled(write_model(tmp_path, f"conv{n}", body(n), ends, params)).module
        errors.append(np.abs(eigenfrequencies(mod) - omega) / omega)
    errors = np.array(errors)
    orders = observed_orders(errors)
    assert errors[-1].max() < errors[0].max()
    assert np.all(np.abs(orders - order) <= 0.3), (orders, errors)


def test_timoshenko_closed_form_is_the_bending_branch_and_approaches_euler_bernoulli():
    # Sanity of the closed form itself: for a slender rod (K, 1/I_ρ → ∞) the lower root
    # tends to the Euler–Bernoulli frequency; shear and rotary inertia lower it.
    timo, eb = timoshenko_simply_supported_exact(), eb_pinned_exact()
    assert np.all(timo < eb)
    assert np.all(np.abs(timo - eb) / eb < 0.02)
    stiff = timoshenko_simply_supported_exact(i_rho=1e-12, K=1e14)
    np.testing.assert_allclose(stiff, eb, rtol=1e-6)


# -- lossless structure --------------------------------------------------------------

FREE_CASES = {
    "string": (string_body, STRING_PARAMS, FREE_STRING),
    "euler-bernoulli": (eb_body, EB_PARAMS, FREE),
    "timoshenko": (timoshenko_body, TIMOSHENKO_PARAMS, FREE),
}


@pytest.mark.parametrize("n", [3, 16])
@pytest.mark.parametrize("case", FREE_CASES)
def test_free_free_spectrum_is_purely_imaginary(case, n, tmp_path):
    body, params, ends = FREE_CASES[case]
    mod = compiled(write_model(tmp_path, "free", body(n), ends, params)).module
    lam = finite_eigenvalues(mod)
    # Every state is free: the pencil has one finite eigenvalue per state.
    assert len(lam) == sum(role == "state" for role in mod.ROLES)
    assert np.abs(lam.real).max() <= 1e-9 * np.abs(lam).max()
    # The rigid motions (translation, and rotation for beams) are the zero eigenvalues;
    # everything else oscillates.
    rigid = 1 if case == "string" else 2
    assert np.sum(np.abs(lam) <= 1e-9 * np.abs(lam).max()) == rigid


# -- discrete power balance ---------------------------------------------------------


def hessian_of_quadratic(fn, n):
    """Q with fn(x) = ½ xᵀ Q x, by polarization (exact up to round-off for a quadratic fn)."""
    eye = np.eye(n)
    diag = np.array([fn(eye[i]) for i in range(n)])
    Q = np.empty((n, n))
    for i in range(n):
        for j in range(i, n):
            Q[i, j] = Q[j, i] = fn(eye[i] + eye[j]) - diag[i] - diag[j] if i != j else 2 * diag[i]
    return Q


def power_defects(mod, rng, samples=4):
    """At random states x, random t, with all algebraic variables and ẋ solved from the DAE,
    return (dH/dt + P_ports + P_diss) / scale for each sample.

    dH/dt = (Qx)·ẋ with Q the exact Hessian of the compiled `hamiltonian`; scale is
    Σ|(Qx)_i ẋ_i| + |P_ports| + |P_diss|, the size of the terms that must cancel.
    """
    p = mod.full_parameters()
    n = mod.N
    diff = np.asarray(mod.DIFFERENTIAL, dtype=bool)
    states = np.array([role == "state" for role in mod.ROLES])
    energy = mod.VARIABLES.index("energy.supplied")
    balance_row = mod.EQUATIONS.index("energy.balance")
    rows = np.array([i != balance_row for i in range(len(mod.EQUATIONS))])
    unknown = np.ones(n, dtype=bool)
    unknown[energy] = False
    Q = hessian_of_quadratic(lambda x: mod.hamiltonian(0.0, _embed(n, states, x), p), int(states.sum()))
    defects = []
    for _ in range(samples):
        t = float(rng.uniform(0.0, 1.0))
        y = np.zeros(n)
        y[states] = rng.standard_normal(int(states.sum()))
        # The rows other than the energy balance are linear in (ẏ_differential, y_algebraic).
        F0 = np.zeros(len(mod.EQUATIONS))
        mod.residual(t, y, np.zeros(n), p, F0)
        A, E = jacobian_blocks(mod, p, t)
        M = np.where(diff[None, :], E, A)[np.ix_(rows, unknown)]
        z = np.linalg.solve(M, -F0[rows])
        yp = np.zeros(n)
        full = np.zeros(n)
        full[unknown] = z
        yp[diff] = full[diff]
        y[~diff] = full[~diff]
        # The energy accumulator's rate from its own row.
        res = np.zeros(len(mod.EQUATIONS))
        mod.residual(t, y, yp, p, res)
        assert np.abs(res[rows]).max() <= 1e-8 * (1 + np.abs(F0).max() + np.abs(A @ y).max())
        yp[energy] = -res[balance_row]
        P_ports, P_diss = mod.powers(t, y, yp, p)
        grad = Q @ y[states]
        dH = grad @ yp[states]
        scale = np.abs(grad * yp[states]).sum() + abs(P_ports) + abs(P_diss)
        defects.append(abs(dH + P_ports + P_diss) / scale)
        # The accumulator integrates exactly the port and dissipated power.
        assert yp[energy] == pytest.approx(P_ports + P_diss, rel=1e-12, abs=1e-14 * scale)
    return np.array(defects)


def _embed(n, mask, x):
    y = np.zeros(n)
    y[mask] = x
    return y


DRIVEN = {
    "string": (string_body, STRING_PARAMS, {"a": "sin(7*t) + 0.3", "b": "-2*cos(3*t)"}),
    "euler-bernoulli": (eb_body, EB_PARAMS, {"a": "sin(7*t)", "b": "0.5", "a_rot": "t**2 - 0.2",
                                              "b_rot": "cos(5*t)"}),
    "timoshenko": (timoshenko_body, TIMOSHENKO_PARAMS, {"a": "sin(7*t)", "b": "0.5", "a_rot": "t - 0.2",
                                                        "b_rot": "cos(5*t)"}),
}


@pytest.mark.parametrize("damping", [None, "0.5*(1 + xi)"])
@pytest.mark.parametrize("n", [1, 3, 8])
@pytest.mark.parametrize("case", DRIVEN)
def test_semi_discrete_power_balance_holds_to_round_off_at_random_states(case, n, damping, tmp_path):
    body, params, ends = DRIVEN[case]
    extra = {} if damping is None else {"damping": damping}
    mod = compiled(write_model(tmp_path, "driven", body(n, **extra), ends, params)).module
    defects = power_defects(mod, np.random.default_rng(n))
    assert defects.max() <= 1e-12, defects


def test_driven_string_simulation_closes_the_energy_balance(tmp_path):
    path = write_model(tmp_path, "driven_string", string_body(7), DRIVEN["string"][2], STRING_PARAMS,
                       simulation={"t_end": 0.03, "rtol": 1e-10, "atol": 1e-12})
    result = phc.simulate(compiled(path))
    assert result.success, result.message
    assert np.ptp(result.H) > 1e-3 * np.abs(result.H).max() > 0
    assert np.abs(result.port_power).max() > 0
    assert result.energy_balance_relative <= 1e-8


def test_driven_euler_bernoulli_simulation_closes_the_energy_balance(tmp_path):
    # Smooth inputs that start at zero: a step at t = 0 would ring the stiffest modes.
    ends = {"a": "100*sin(2000*t)", "b": "50*sin(3000*t)**2", "a_rot": "2*sin(1000*t)", "b_rot": "1 - cos(4000*t)"}
    path = write_model(tmp_path, "driven_eb", eb_body(3), ends, EB_PARAMS,
                       simulation={"t_end": 0.004, "rtol": 1e-10, "atol": 1e-12})
    result = phc.simulate(compiled(path))
    assert result.success, result.message
    assert np.ptp(result.H) > 0
    assert result.energy_balance_relative <= 1e-8


# -- damping -------------------------------------------------------------------------
#
# With a uniform damping d on the momentum equation, ṗ = (T ε)_ξ − d p/ρ: the damping is
# proportional to the mass, so every mode q̈ + (d/ρ) q̇ + ω² q = 0 loses energy at the
# same mean rate, E(t) = E(0) e^{−(d/ρ) t} (1 + O(ζ)), ζ = d/(2ρω) the modal damping
# ratio (the O(ζ) part oscillates at 2ω). And dH/dt = −d ∫ e_p² ≤ 0 at every instant.


def test_damping_dissipates_at_the_mass_proportional_rate(tmp_path):
    rho, tension, d, n = 0.5, STRING_T, 0.5, 16
    c = math.sqrt(tension / rho)
    zeta1 = d / (2 * rho * math.pi * c / STRING_L)
    path = write_model(tmp_path, "damped", string_body(n, damping=d), FIXED_STRING, {"rho": rho, "T": tension},
                       simulation={"t_end": 0.5, "n_out": 501, "rtol": 1e-10, "atol": 1e-12})
    # Pluck: a triangle with its peak at the middle (strain +δ on the left half, −δ right).
    initial = {f"body.eps[{i}]": (0.01 if i < n // 2 else -0.01) for i in range(n)}
    result = phc.simulate(compiled(path), initial=initial)
    assert result.success, result.message
    H = result.H
    assert H[0] == pytest.approx(0.5 * tension * 0.01**2 * STRING_L, rel=1e-12)
    assert np.all(np.diff(H) <= 1e-9 * H[0])                       # never increases
    assert result.dissipation.min() >= -1e-12 * result.dissipation.max()
    assert H[-1] < 0.7 * H[0]
    envelope = H * np.exp(d / rho * result.t) / H[0]
    assert np.abs(envelope - 1).max() <= 2 * zeta1                 # ζ₁ ≈ 0.009
    assert result.energy_balance_relative <= 1e-7


# -- coefficients that vary along the beam --------------------------------------------


@pytest.mark.parametrize("coefficients", [{"rhoA": "0.5*(1 + 0.5*xi)", "EI": "1"},
                                          {"rhoA": "0.5", "EI": "1 + xi**2"}],
                         ids=["rhoA(xi)", "EI(xi)"])
def test_xi_dependent_coefficients_converge_at_fourth_order(coefficients, tmp_path):
    def frequencies(n):
        body = {**eb_body(n, length=1.0), **coefficients}
        return eigenfrequencies(compiled(write_model(tmp_path, f"xi{n}", body, PINNED)).module)

    reference = frequencies(64)
    errors = np.array([np.abs(frequencies(n) - reference) / reference for n in (4, 8, 16)])
    assert np.all(observed_orders(errors) >= 3.7), observed_orders(errors)
    # The coefficient really varies: the spectrum is not the one of its value at ξ = 0.
    frozen = {**eb_body(16, length=1.0), "rhoA": "0.5", "EI": "1"}
    at_zero = eigenfrequencies(compiled(write_model(tmp_path, "frozen", frozen, PINNED)).module)
    assert np.all(np.abs(at_zero - reference) / reference > 0.05)


# -- errors ----------------------------------------------------------------------------


def model_errors(tmp_path, body):
    path = write_model(tmp_path, "broken", body, PINNED, EB_PARAMS)
    with pytest.raises(ModelError) as info:
        phc.compile_model(path)
    text = path.read_text().splitlines()
    return [d for d in info.value.diagnostics if d.severity == "error"], text


def line_of(text, key):
    """1-based line of `key:` inside the `body` component of a model written by write_model."""
    start = text.index("  body:")
    for i, line in enumerate(text[start:], start):
        if line.strip().startswith(f"{key}:"):
            return i + 1
    raise AssertionError(key)


@pytest.mark.parametrize("key, value, code", [
    ("elements", 0, "PHC-E01"),             # schema: at least one element
    ("EI", "-EI", "PHC-E141"),              # energy density not positive definite
    ("rhoA", "rhoA*(1 - 4*xi)", "PHC-E141"),  # negative on part of [0, L]
    ("length", -1, "PHC-E142"),
    ("EI", "EI*(1 + t)", "PHC-E140"),       # coefficients may not depend on time
    ("damping", "0.1*t", "PHC-E140"),
])
def test_invalid_distributed_components_give_one_located_diagnostic(key, value, code, tmp_path):
    errors, text = model_errors(tmp_path, eb_body(8, **{key: value}))
    assert len(errors) == 1, [d.render() for d in errors]
    [diag] = errors
    assert diag.code.startswith(code)
    assert diag.path == f"components.body.{key}"
    assert diag.span is not None and diag.span.line == line_of(text, key)


def test_unknown_name_in_length_gives_only_the_unknown_name_error(tmp_path):
    errors, _ = model_errors(tmp_path, eb_body(8, length="L2"))
    assert [d.code for d in errors] == ["PHC-E101"]


def test_coefficient_negative_near_an_end_is_rejected(tmp_path):
    errors, _ = model_errors(tmp_path, eb_body(8, EI="EI*(xi - 0.001)"))
    assert [d.code for d in errors] == ["PHC-E141"]


def test_negative_damping_is_rejected(tmp_path):
    errors, _ = model_errors(tmp_path, eb_body(8, damping=-0.5))
    assert [d.path for d in errors] == ["components.body.damping"]


@pytest.mark.parametrize("name, body, factor, ratio", [
    ("L", eb_body(8, length="L"), 2.0, 0.25),
    ("rhoA", eb_body(8, rhoA="rhoA*(1 + 0.5*xi/L)"), 4.0, 0.5),
], ids=["length", "xi-coefficient"])
def test_overriding_a_compile_time_parameter_is_refused_and_a_recompile_honours_it(name, body, factor, ratio,
                                                                                    tmp_path):
    # The mesh length and ξ-dependent coefficients are fixed in the compiled module: a
    # run-time override is refused naming the parameter. Recompiled with the new value,
    # ω ∝ L⁻² for uniform coefficients (doubling L quarters ω) and scaling ρA(ξ) by 4
    # halves every ω on the same mesh.
    base = {"L": LENGTH, "rhoA": RHO_A}[name]
    mod = compiled(write_model(tmp_path, "override", body, PINNED, {**EB_PARAMS, "L": LENGTH})).module
    assert name in mod.COMPILE_TIME_PARAMETERS
    with pytest.raises(SimulationSetupError, match=f"parameter `{name}` was used at compile time"):
        parameter_vector(mod, {name: factor * base})
    changed = {**EB_PARAMS, "L": LENGTH, name: factor * base}
    again = compiled(write_model(tmp_path, "override2", body, PINNED, changed)).module
    np.testing.assert_allclose(eigenfrequencies(again), ratio * eigenfrequencies(mod), rtol=1e-9)


# -- ports -----------------------------------------------------------------------------


@pytest.mark.parametrize("body, ports", [
    (string_body(4), {"a": TRANS, "b": TRANS}),
    (eb_body(4), {"a": TRANS, "b": TRANS, "a_rot": ROT, "b_rot": ROT}),
    (timoshenko_body(4), {"a": TRANS, "b": TRANS, "a_rot": ROT, "b_rot": ROT}),
], ids=["string", "euler-bernoulli", "timoshenko"])
def test_each_component_exposes_its_boundary_ports(body, ports, tmp_path):
    # Alone and unconnected, every boundary port is reported as not connected.
    params = {**STRING_PARAMS, **EB_PARAMS, **TIMOSHENKO_PARAMS}
    path = write_model(tmp_path, "alone", body, {}, params)
    with pytest.raises(ModelError) as info:
        phc.compile_model(path)
    unconnected = sorted(d.path.split(".")[-1] for d in info.value.diagnostics if d.code == "PHC-E208")
    assert unconnected == sorted(ports)
    # Each port has its domain: terminating it in the other domain is an error.
    wrong = {port: {"type": "zero_effort", "domain": ROT if domain == TRANS else TRANS}
             for port, domain in ports.items()}
    with pytest.raises(ModelError):
        phc.compile_model(write_model(tmp_path, "wrong_domain", body, wrong, params))
    right = {port: "zero_effort" for port in ports}
    assert phc.compile_model(write_model(tmp_path, "right_domain", body, right, params)).n_states > 0


# A string fixed at ξ = 0 carrying a point mass m at ξ = L: w = sin(βξ) e^{iωt}, ω = cβ,
# and Newton for the mass, m w_tt(L) = −T w_ξ(L), give −mω² sin βL = −Tβ cos βL, i.e.
# βL tan βL = ρL/m. With m = ρL the first root is βL = 0.8603335890.


def test_string_with_a_tip_mass_matches_the_frequency_equation_and_simulates(tmp_path):
    beta_l = 0.8603335890193797
    assert beta_l * math.tan(beta_l) == pytest.approx(1.0, abs=1e-12)
    exact = beta_l / STRING_L * math.sqrt(STRING_T / STRING_RHO)
    tip = {"type": "mass", "m": "rho*Ls"}
    errors, paths = [], []
    for n in (8, 16, 32):
        paths.append(write_model(tmp_path, f"tip_mass{n}", string_body(n), {"a": "zero_flow", "b": tip},
                                 {**STRING_PARAMS, "Ls": STRING_L}))
        errors.append(abs(eigenfrequencies(compiled(paths[-1]).module, k=1)[0] - exact) / exact)
    assert errors[-1] < 1e-3
    assert np.all(np.abs(observed_orders(np.array(errors)) - 2) <= 0.3)
    # And it simulates: the mass is released with a velocity and swings the string.
    result = phc.simulate(compiled(paths[0]), t_end=0.02, initial={"end_b.p": 1e-3}, rtol=1e-10, atol=1e-12)
    assert result.success, result.message
    assert result.H[0] > 0 and np.ptp(result["end_b.p"]) > 1e-4
    assert result.energy_balance_relative <= 1e-7


# -- shipped models ------------------------------------------------------------------


@lru_cache(maxsize=None)
def shipped_run(name: str) -> phc.SimResult:
    result = phc.simulate(compiled(MODELS / f"{name}.yaml"))
    assert result.success, result.message
    return result


def integral(t, v):
    """Cumulative trapezoid ∫₀ᵗ v dt on the output grid."""
    return np.concatenate([[0.0], np.cumsum(0.5 * (v[1:] + v[:-1]) * np.diff(t))])


def window_mean(t, v, start, stop):
    m = (t >= start - 1e-12) & (t <= stop + 1e-12)
    return np.trapezoid(v[m], t[m]) / (t[m][-1] - t[m][0])


@pytest.mark.parametrize("name", ["vibrating_string", "euler_bernoulli_beam", "timoshenko_beam"])
def test_shipped_beam_model_simulates_with_a_closed_energy_balance(name):
    result = shipped_run(name)
    assert result.t[-1] > 0
    assert np.abs(result.port_power).max() > 0
    assert result.H.max() > 0
    assert result.energy_balance_relative <= 1e-7


def test_vibrating_string_pulse_matches_dalembert():
    # Parameters of models/vibrating_string.yaml; see its header for the closed forms.
    rho, T, L, F0, tp = 0.01, 64.0, 0.64, 1.0, 0.004
    c, Z = math.sqrt(T / rho), math.sqrt(T * rho)
    assert tp < 2 * L / c
    r = shipped_run("vibrating_string")
    t = r.t
    during = t <= tp
    # End velocity of a semi-infinite string: v = F/Z (the pulse spans 8 of 16 elements).
    assert np.abs(r["end_velocity"][during] - r["force"][during] / Z).max() <= 0.05 * F0 / Z
    # The injected energy ∫F²/Z dt = 3F0²tp/(8Z) is kept afterwards (lossless string).
    injected = 3 * F0**2 * tp / (8 * Z)
    assert r.H[-1] == pytest.approx(injected, rel=0.02)
    assert np.ptp(r.H[t >= tp]) <= 1e-6 * injected
    # The end moves by the impulse over the impedance, ∫F dt / Z = F0 tp/(2Z).
    moved = integral(t, r["end_velocity"])[np.searchsorted(t, tp)]
    assert moved == pytest.approx(F0 * tp / (2 * Z), rel=1e-3)
    # The support feels nothing before the front arrives at t = L/c (up to dispersion of
    # the discrete wave), then twice the incident force when it reflects.
    support = np.abs(r["support_force"])
    assert support[t < 0.5 * L / c].max() <= 1e-3 * F0
    assert support.max() == pytest.approx(2 * F0, rel=0.03)


def test_cantilever_oscillates_about_the_static_tip_deflection():
    # Parameters of models/euler_bernoulli_beam.yaml. Static cantilever with a tip force F:
    # the bending moment is EI w'' = F (L − ξ) and w(0) = w'(0) = 0, hence
    # w = F ξ²(3L − ξ)/(6EI), w(L) = F L³/(3EI), w'(L) = F L²/(2EI). After the ramp the
    # undamped response is the static one plus free modal oscillations; averaged over one
    # period T₁ = 2π/ω₁ of the dominant first mode (ω₁ = (1.8751040687/L)² sqrt(EI/ρA)) it
    # is the static one up to the small higher-mode remainders.
    EI_, rhoA, L, F, t_ramp = 68.27, 0.50368, 0.3, 1.0, 0.003
    w_static, slope_static = F * L**3 / (3 * EI_), F * L**2 / (2 * EI_)
    T1 = 2 * math.pi / ((1.8751040687 / L) ** 2 * math.sqrt(EI_ / rhoA))
    r = shipped_run("euler_bernoulli_beam")
    assert r.t[-1] >= t_ramp + T1 - 1e-4
    w = integral(r.t, r["tip_velocity"])
    slope = integral(r.t, r["tip_rotation_rate"])
    stop = min(t_ramp + T1, r.t[-1])
    assert window_mean(r.t, w, t_ramp, stop) == pytest.approx(w_static, rel=0.01)
    assert window_mean(r.t, slope, t_ramp, stop) == pytest.approx(slope_static, rel=0.01)
    # It does oscillate about it (a quick ramp nearly doubles the peak deflection) ...
    assert w.max() > 1.5 * w_static
    assert w[r.t > t_ramp].min() < 0.5 * w_static
    # ... and on average the clamp holds the beam with −F and −F L.
    assert window_mean(r.t, r["clamp_force"], t_ramp, stop) == pytest.approx(-F, rel=0.01)
    assert window_mean(r.t, r["clamp_moment"], t_ramp, stop) == pytest.approx(-F * L, rel=0.01)


def test_timoshenko_beam_follows_the_quasi_static_end_rotation_with_shear():
    # Parameters of models/timoshenko_beam.yaml. Static simply supported Timoshenko beam
    # with an end moment M at ξ = 0: the bending moment is M(1 − ξ/L), the shear force
    # K γ = M/L; integrating EI φ' and w' = φ + γ with w(0) = w(L) = 0 gives
    # |φ(0)| = M (L/(3EI) + 1/(KL)) and |φ(L)| = M (L/(6EI) − 1/(KL)), with opposite signs.
    E, G, rho_s, a, L = 2.0e11, 7.6923e10, 7870.0, 0.05, 0.3
    ei, K = E * a**4 / 12, 5 / 6 * G * a**2
    c_a, c_b, c_eb = L / (3 * ei) + 1 / (K * L), L / (6 * ei) - 1 / (K * L), L / (3 * ei)
    # The pulse is slow: ω₁ tp ≫ 2π, so the dynamic correction is ~ (2π/(ω₁ tp))² ≈ 0.7 %.
    omega1 = timoshenko_simply_supported_exact(rho_s * a**2, rho_s * a**4 / 12, ei, K, L)[0]
    assert (2 * math.pi / (omega1 * 0.01)) ** 2 < 0.01
    r = shipped_run("timoshenko_beam")
    M = r["moment"]
    peak = int(np.argmax(M))
    phi_a = integral(r.t, r["rotation_rate_a"])
    phi_b = integral(r.t, r["rotation_rate_b"])
    assert phi_a[peak] == pytest.approx(c_a * M[peak], rel=0.01)
    assert phi_b[peak] == pytest.approx(-c_b * M[peak], rel=0.03)
    # The shear term is 2 % of the end rotation: Euler–Bernoulli would be measurably off.
    assert abs(phi_a[peak] - c_a * M[peak]) < 0.5 * abs(c_a - c_eb) * M[peak]
