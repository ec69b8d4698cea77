"""The certificate of the compiled equations (:mod:`phc.checks.compiled`) and of each
component's rows against its description (:mod:`phc.checks.rows`).

It must be about what is simulated: a wrong row injected into a lowerer (a test double
flips the sign of one term of the first row the lowerer emits) makes `phc check` fail,
for every component type; a non-passive damping force is a located error at compile
time; and every shipped model is certified.

An energy balance alone cannot see a wrong row that keeps the system port-Hamiltonian —
the sign of a source's value (another input), or the kinematic row θ̇ = −ω of an angle
that does not enter H. The rows check sees those: the rows no longer say what the
component's description says (BALANCE_BLIND lists them; they are asserted to be found
by the rows check, and to pass the energy balance).
"""

from __future__ import annotations

import math
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
import scipy.sparse as sps
import sympy as sp

import phc
from phc.checks.compiled import certify_compiled
from phc.ir.dae import LinearTerm
from phc.errors import ModelError
from phc.library import LOWERERS
from model_texts import BESIDE_RIGID, CRANK, DIAGONAL, LINEAR, MODULATION, PDE1D  # shared with tests/test_registry.py

REPO = Path(__file__).resolve().parents[2]
MODELS = REPO / "models"
VALID = REPO / "tests" / "models" / "valid"

def _write(tmp_path, name, text):
    path = tmp_path / name
    path.write_text(text)
    if name == "linear.yaml":
        D = np.array([[1.0, 0.0], [-1.0, 1.0]])
        J = np.block([[np.zeros((2, 2)), D], [-D.T, np.zeros((2, 2))]])
        R = np.diag([0.0, 0.0, 0.0, 0.3])
        np.savez(tmp_path / "chain.npz", J=J, R=R, Q=np.eye(4))
    return path


BALANCE_BLIND = {
    "effort_source": "the sign of the imposed effort is another input, not a loss of energy",
    "flow_source": "the sign of the imposed flow is another input, not a loss of energy",
    "crank_wheel kinematics": "θ does not enter H, so θ̇ = −ω conserves energy",
}
"""Wrong rows the power-balance certificate cannot detect (see the module docstring)."""

from phc.checks.certify import certify  # noqa: E402
from phc.checks.rows import check_rows  # noqa: E402
from time_limits import SUBPROCESS_TIMEOUT

# One model per component type (the smallest that uses it).
CASES = {
    "phs": VALID / "lc_oscillator_phs.yaml",
    "rigid": MODELS / "pendulum.yaml",
    "mass": MODELS / "mass_spring_damper.yaml",
    "spring": MODELS / "mass_spring_damper.yaml",
    "damper": MODELS / "mass_spring_damper.yaml",
    "junction": MODELS / "mass_spring_damper.yaml",
    "inductor": MODELS / "rlc_circuit.yaml",
    "capacitor": MODELS / "rlc_circuit.yaml",
    "resistor": MODELS / "rlc_circuit.yaml",
    "orthogonal_transform": VALID / "rotated_springs_split.yaml",
    "string": MODELS / "vibrating_string.yaml",
    "timoshenko_beam": MODELS / "timoshenko_beam.yaml",
    "euler_bernoulli_beam": MODELS / "euler_bernoulli_beam.yaml",
    "moving_beam": MODELS / "moving_beam.yaml",
    "crank_wheel": "crank.yaml",
    "effort_source": MODELS / "rlc_circuit.yaml",
    "transformer": REPO / "tests" / "library" / "models" / "dc_motor.yaml",
    "gyrator": REPO / "tests" / "library" / "models" / "dc_motor.yaml",
    "flow_source": MODELS / "rigid_slider_crank.yaml",
    "modulation": "modulation.yaml",
    "pde1d": "pde1d.yaml",
    "linear_phs": "linear.yaml",
}
INLINE = {"modulation.yaml": MODULATION, "pde1d.yaml": PDE1D, "linear.yaml": LINEAR, "crank.yaml": CRANK}
# Terminations have no row of their own to get wrong: a zero effort or flow is a
# definition of a port variable, which the flipped-definition double below covers.
TERMINATIONS = {"zero_effort": MODELS / "euler_bernoulli_beam.yaml", "zero_flow": MODELS / "timoshenko_beam.yaml"}


def _flip_first_term(expr):
    terms = sp.Add.make_args(sp.expand(expr))
    if len(terms) < 2:
        return None
    return sp.Add(-terms[0], *terms[1:])


class WrongRow:
    """A test double around a lowerer: the first row of one kind that it emits gets one
    term's sign flipped — an equation, a definition of a port variable, or an entry of a
    sparse block (`mode`)."""

    MODES = ("linear", "equation", "define")

    def __init__(self, lowerer, mode, skip=()):
        self.lowerer = lowerer
        self.mode = mode
        self.skip = skip  # row labels left alone (BEYOND_THE_BALANCE)
        self.done = None

    def __call__(self, b, *args, **kwargs):
        original = (b.add_equation, b.define, b.add_linear_rows)
        double = self

        def add_equation(expr, *a, **k):
            label = a[2] if len(a) > 2 else ""
            skipped = any(s in label for s in double.skip)
            flipped = None if double.done or double.mode != "equation" or skipped else _flip_first_term(expr)
            if flipped is not None:
                double.done = f"equation {a[2] if len(a) > 2 else ''}: {expr} -> {flipped}"
                expr = flipped
            return original[0](expr, *a, **k)

        def define(sym, value, *a, **k):
            if not double.done and double.mode == "define" and value != 0:
                double.done = f"definition of {sym}"
                value = -value
            return original[1](sym, value, *a, **k)

        def add_linear_rows(component, label, n_rows, terms, *a, **k):
            couplings = [i for i, t in enumerate(terms) if not t.derivative and t.matrix.nnz]
            if not double.done and double.mode == "linear" and couplings:
                i = couplings[0]  # the structure operator (not a mass matrix)
                t = terms[i]
                m = sps.csr_matrix(t.matrix, copy=True)
                row = m.shape[0] // 2  # an interior node: an end may be clamped
                big = int(m.indptr[row] + np.argmax(np.abs(m.data[m.indptr[row]:m.indptr[row + 1]])))
                m.data[big] = -m.data[big]
                terms = [*terms[:i], LinearTerm(**{**t.__dict__, "matrix": m}), *terms[i + 1:]]
                double.done = f"linear block {label}, entry {big} of term {i}"
            return original[2](component, label, n_rows, terms, *a, **k)

        b.add_equation, b.define, b.add_linear_rows = add_equation, define, add_linear_rows
        try:
            return self.lowerer(b, *args, **kwargs)
        finally:
            b.add_equation, b.define, b.add_linear_rows = original


class _Check:
    """What `phc check` concludes: the certificate of the assembled model (Dirac
    structures, couplings, each component's rows against its description) and the
    certificate of the compiled equations (power balance, passivity)."""

    def __init__(self, compiled):
        self.structure = certify(compiled.dae, n_random=2)
        self.compiled = certify_compiled(compiled, n_random=2)
        self.rows = self.structure.rows

    @property
    def certified(self) -> bool:
        return self.structure.certified and self.compiled.certified and not self.compiled.skipped

    def summary(self) -> str:
        return "; ".join(d.render() for d in self.structure.diagnostics) + " | " + self.compiled.summary()


def _certificate(path, monkeypatch, kind, modes=WrongRow.MODES, skip=()):
    """The first mode whose double finds a row of `kind` to flip, and `phc check`'s verdict."""
    lowerer = LOWERERS[kind]
    for mode in modes:
        double = WrongRow(lowerer, mode, skip)
        monkeypatch.setitem(LOWERERS, kind, double)
        try:
            compiled = phc.compile_model(path, certify=False)
        except ModelError:
            return double, None  # the wrong row already breaks the model's structure
        if double.done:
            return double, _Check(compiled)
    return double, None


@pytest.mark.parametrize("kind", sorted(CASES))
def test_a_wrong_row_in_any_lowerer_fails_phc_check(kind, tmp_path, monkeypatch):
    path = CASES[kind]
    if isinstance(path, str):
        path = _write(tmp_path, path, INLINE[path])
    honest = _Check(phc.compile_model(path, certify=False))
    assert honest.certified, honest.summary()
    double, cert = _certificate(path, monkeypatch, kind)
    assert double.done, f"the double found no row of `{kind}` to flip"
    assert cert is None or not cert.certified, f"{double.done}: {cert.summary()}"


@pytest.mark.parametrize("key", sorted(BALANCE_BLIND))
def test_rows_check_finds_what_the_energy_balance_cannot(key, tmp_path, monkeypatch):
    """The sign of a source's value and θ̇ = −ω keep the energy balance: only the rows
    check against the description finds them, as a located PHC-E452."""
    kind, _, label = key.partition(" ")
    path = CASES[kind]
    if isinstance(path, str):
        path = _write(tmp_path, path, INLINE[path])
    modes = ("equation",) if label else ("define",)
    skip = () if not label else [s for s in ("balance", "momentum", "dynamics") if s not in label]
    double, cert = _certificate(path, monkeypatch, kind, modes, skip)
    assert double.done and cert is not None
    assert cert.compiled.certified, "the energy balance is expected to miss this one"
    codes = [d.code for d in cert.rows.diagnostics]
    assert codes == ["PHC-E452"], cert.summary()
    diag = cert.rows.diagnostics[0]
    assert f"({kind})" in diag.message and "do not say what its description says" in diag.message
    assert diag.span is not None and Path(diag.span.file).name == Path(path).name and diag.span.line > 1


@pytest.mark.parametrize("kind", sorted(TERMINATIONS))
def test_a_wrong_termination_fails_the_certificate(kind, monkeypatch):
    """A termination that imposes e = c or f = c with c ≠ 0 instead of 0 feeds energy."""
    original = LOWERERS[kind]

    def leaky(b, *args, **kwargs):
        define = b.define

        def shifted(sym, value, *a, **k):
            return define(sym, value + sp.sin(sp.Symbol("t", real=True)) + 1, *a, **k)

        b.define = shifted
        try:
            return original(b, *args, **kwargs)
        finally:
            b.define = define

    monkeypatch.setitem(LOWERERS, kind, leaky)
    try:
        compiled = phc.compile_model(TERMINATIONS[kind], certify=False)
    except ModelError:
        return
    cert = certify_compiled(compiled, n_random=2)
    assert not cert.certified or cert.skipped, cert.summary()


NON_PASSIVE = """\
format_version: 1
name: cubic_damper
parameters: {m: 1.0, k: 4.0, c: 0.5, c3: 0.2}
components:
  body:
    type: rigid
    q: [x]
    v: [vx]
    M: [[m]]
    V: k*x**2/2
    damping: [DAMPING]
simulation:
  t_end: 1.0
  initial: {body.x: 0.1, body.p_vx: 0.0}
"""


@pytest.mark.parametrize("damping, passive", [("c*vx", True), ("c*vx + c3*vx**3", True),
                                              ("c*vx - c3*vx**3", False), ("-c*vx", False),
                                              ("c*vx*sin(x)", False)])
def test_a_non_passive_damping_force_is_a_located_error_at_compile(tmp_path, damping, passive):
    path = tmp_path / "m.yaml"
    path.write_text(NON_PASSIVE.replace("DAMPING", f'"{damping}"'))
    run = subprocess.run([sys.executable, "-m", "phc", "compile", str(path), "-o", str(tmp_path)],
                         capture_output=True, text=True, timeout=SUBPROCESS_TIMEOUT)
    if passive:
        assert run.returncode == 0, run.stderr
        assert "  certified (" in run.stdout
    else:
        assert run.returncode == 1
        line = run.stderr.strip().splitlines()[0]
        assert line.startswith(f"{path}:11:14: the dissipation of `body` is not passive"), line
        assert "body.p_vx = " in line and "[PHC-E451]" in line
        assert "Traceback" not in run.stderr
        # --no-certify compiles it anyway (and the run then gains energy: that is the point)
        run = subprocess.run([sys.executable, "-m", "phc", "compile", "--no-certify", str(path), "-o",
                              str(tmp_path)], capture_output=True, text=True, timeout=SUBPROCESS_TIMEOUT)
        assert run.returncode == 0 and "not certified (--no-certify)" in run.stdout


def test_a_non_psd_linear_phs_dissipation_is_refused(tmp_path):
    path = _write(tmp_path, "linear.yaml", LINEAR)
    D = np.array([[1.0, 0.0], [-1.0, 1.0]])
    J = np.block([[np.zeros((2, 2)), D], [-D.T, np.zeros((2, 2))]])
    np.savez(tmp_path / "chain.npz", J=J, R=np.diag([0.0, 0.0, 0.0, -0.3]), Q=np.eye(4))
    with pytest.raises(ModelError) as err:
        phc.compile_model(path)
    text = str(err.value)
    assert "not passive" in text or "positive semidefinite" in text, text


@pytest.mark.parametrize("path", sorted(MODELS.glob("*.yaml")), ids=lambda p: p.stem)
def test_shipped_models_are_certified(path):
    compiled = phc.compile_model(path)
    cert = compiled.certificate
    assert cert.certified and not cert.skipped, cert.summary()
    assert cert.samples >= 2
    assert cert.balance_error < 1e-6


def test_above_the_size_limit_the_fast_certificate_checks_passivity_only(tmp_path):
    """The fast certificate of a compilation does not sample consistent states of a large
    model (that costs several simulation starts); it says so and still refuses a
    non-passive damping force."""
    compiled = phc.compile_model(MODELS / "mass_spring_damper.yaml", certify=False)
    cert = certify_compiled(compiled, n_random=1, max_unknowns=2)
    assert cert.certified and cert.samples == 0 and cert.terms_checked == 1
    assert cert.summary().startswith("passivity certified, balance not sampled (power balance not sampled")
    path = tmp_path / "m.yaml"
    path.write_text(NON_PASSIVE.replace("DAMPING", '"-c*vx"'))
    bad = certify_compiled(phc.compile_model(path, certify=False), max_unknowns=1)
    assert not bad.certified and "PHC-E451" in bad.diagnostics[0].render()


def test_the_balance_is_checked_where_power_flows():
    """Closed form: for the mass–spring–damper at any state, dH/dt = −c v² = −P_diss; the
    certificate's samples are states where that is not trivially zero."""
    compiled = phc.compile_model(MODELS / "mass_spring_damper.yaml", certify=False)
    cert = certify_compiled(compiled, n_random=3, seed=1)
    assert cert.samples == 4 and cert.terms_checked == 1
    assert cert.balance_error < 1e-8
    assert math.isfinite(cert.seconds)


PUSHED_AT_REST = """
format_version: 1
parameters: {m: 2.0, Fc: 3.0}
components:
  push: {type: effort_source, domain: mechanical.translational, value: 1.5}
  block:
    type: phs
    states: [p]
    hamiltonian: p**2/(2*m)
    ports:
      a: {domain: mechanical.translational}
    resistive:
      fr: {law: [e_fr = Fc*sign(f_fr)]}
    relations:
      - f_p = -e_a - e_fr
      - f_fr = e_p
      - f_a = e_p
connections:
  - [push.port, block.a]
simulation:
  t_end: 1.0
  initial: {block.p: 0.0}
"""


@pytest.mark.parametrize("noise", [0.0, 1e-15, -3e-15])
def test_round_off_at_rest_is_not_an_energy_error(tmp_path, noise, monkeypatch):
    """A block held by friction: at rest, the consistent start has velocities of round-off
    size (their sign and last bits depend on the CPU's BLAS kernels), and the two powers
    v·F_push and v·F_friction do not cancel to the last bit. That is a residual of ~1e-15
    with powers of ~1e-15: the certificate judges it against the power that passes through
    the model at its other samples, not against the sample's own vanishing powers (a
    correct model was refused with "relative error 2.2e-06" on an AMD processor)."""
    from phc.checks import compiled as certificate

    path = tmp_path / "m.yaml"
    path.write_text(PUSHED_AT_REST)
    compiled = phc.compile_model(path, certify=False)
    velocity = list(compiled.module.VARIABLES).index("block.a.f")
    consistent = certificate._consistent_samples

    def with_round_off(*args, **kwargs):
        samples, notes = consistent(*args, **kwargs)
        t, y, yp = samples[0]
        y = y.copy()
        y[velocity] += noise  # what another CPU's consistent initialization gave
        return [(t, y, yp)] + samples[1:], notes

    monkeypatch.setattr(certificate, "_consistent_samples", with_round_off)
    cert = certify_compiled(compiled, n_random=3, seed=1)
    assert cert.samples >= 2 and not cert.diagnostics.has_errors, [d.message for d in cert.diagnostics]


def test_a_wrong_power_at_a_sample_in_motion_is_still_refused(tmp_path):
    """The floor of round-off at rest does not hide a wrong row where power flows: the same
    block with the friction force entering the momentum balance with the wrong sign."""
    path = tmp_path / "m.yaml"
    path.write_text(PUSHED_AT_REST.replace("f_p = -e_a - e_fr", "f_p = -e_a + e_fr"))
    compiled = phc.compile_model(path, certify=False)
    cert = certify_compiled(compiled, n_random=3, seed=1)
    assert [d.code for d in cert.diagnostics.errors] == ["PHC-E450"]


@pytest.mark.parametrize("seed", [0, 1, 2, 3])
def test_uniform_motion_against_internal_forces_is_certified(tmp_path, seed):
    """Two rigidly joined masses with a spring beside them: a lossless interconnection,
    dH/dt = 0 exactly. At a random consistent state both masses move with one velocity v
    while the spring, stretched by x, pushes them apart and the joint holds them:
    ṗ₁ = e − kx = 0 with e = kx ≠ 0. The computed dH/dt is v times the round-off of that
    cancellation, ~ε·v·kx, with every power of the balance 0. It was refused as "relative
    error 4.8e-01"; the rates are now judged by the terms they sum."""
    path = tmp_path / "m.yaml"
    path.write_text(BESIDE_RIGID)
    compiled = phc.compile_model(path, certify=False)
    cert = certify_compiled(compiled, n_random=4, seed=seed)
    assert cert.samples >= 2 and cert.certified, [d.message for d in cert.diagnostics]


WRONG_JOINT_SIGN = """
format_version: 1
name: wrong_joint_sign
components:
  m1:
    type: phs
    states: [p]
    hamiltonian: p**2/2
    ports:
      a: {domain: mechanical.translational}
      b: {domain: mechanical.translational}
    relations:
      - f_p = -e_a + e_b
      - f_a = e_p
      - f_b = e_p
  m2: {type: mass, m: 2.0, ports: [a, b]}
  k: {type: spring, k: 3.0, terminals: [a, b]}
connections:
  - [m1.b, m2.a]
  - [m1.a, k.a]
  - [k.b, m2.b]
"""


def test_a_wrong_sign_against_internal_forces_is_still_refused(tmp_path):
    """The same mechanism with the joint's force entering the first mass with the wrong sign
    (f_p = −e_a + e_b where −e_a − e_b conserves power): the balance is off by 2·v·e_b, of
    the order of the very terms the rates are judged by, and is refused."""
    path = tmp_path / "m.yaml"
    path.write_text(WRONG_JOINT_SIGN)
    compiled = phc.compile_model(path, certify=False)
    cert = certify_compiled(compiled, n_random=4, seed=0)
    assert [d.code for d in cert.diagnostics.errors] == ["PHC-E450"]


def test_coasting_with_no_force_is_certified(tmp_path):
    """A planar mass tied to a line mass along both of its axes: the three velocities are
    equal and nothing acts on them, so every power is 0 and H is constant. The computed
    dH/dt at a consistent state is ~1e-81 (round-off of forces that are 0); a power that
    would change H by less than 1e-11 of its scale over the simulated span is round-off,
    not a finding (it was refused as "relative error 1.0e+00")."""
    path = tmp_path / "m.yaml"
    path.write_text(DIAGONAL)
    compiled = phc.compile_model(path, certify=False)
    cert = certify_compiled(compiled, n_random=4, seed=0)
    assert cert.samples >= 2 and cert.certified, [d.message for d in cert.diagnostics]


def test_samples_of_many_closed_loops_are_found_without_the_dense_rescue(tmp_path, monkeypatch):
    """The N four-bar with five loops: perturbing every angle and position by a tenth of the
    largest coordinate lands where Gauss–Newton cannot return to the constraint manifold; the
    certificate shrinks the perturbation (same direction) instead of running SciPy's dense
    least-squares rescue, which cost minutes per sample at N = 40. Both random samples are
    found, and the rescue is never called."""
    import importlib.util

    import yaml

    import phc.simulation.initial as initial

    spec = importlib.util.spec_from_file_location("n_four_bar", MODELS / "n_four_bar.py")
    generator = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(generator)
    path = tmp_path / "n_four_bar_5.yaml"
    path.write_text(yaml.safe_dump(generator.n_four_bar(5), sort_keys=False))
    compiled = phc.compile_model(path, certify=False, backend="numpy")
    ends = []
    solve = initial.gauss_newton

    def recording(*args, **kwargs):
        out = solve(*args, **kwargs)
        ends.append(out[1])
        return out

    def rescue(*args, **kwargs):
        raise AssertionError("the dense least-squares rescue ran for a certificate sample")

    monkeypatch.setattr(initial, "gauss_newton", recording)
    monkeypatch.setattr(initial, "least_squares", rescue)
    cert = certify_compiled(compiled, n_random=2, seed=0)
    assert cert.samples == 3 and cert.certified, [d.message for d in cert.diagnostics]
    assert max(ends) > 1.0  # a full perturbation did fail (else this tests nothing)
