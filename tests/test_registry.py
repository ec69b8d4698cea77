"""Tests for the component registry (:mod:`phc.library.registry`, built-ins in :mod:`phc.library.builtin`).

Every registered type has a schema entry, unit information (or a reason it has none), a
cost model, and a minimal model that compiles and certifies; the per-type tables other
modules import are the registry's; an entry that forgets a field or gets one wrong is
refused when it is registered. A new lumped type — a hardening (cubic) spring — is added
from this file with one registration and simulated against the Duffing oscillator's
period computed independently by quadrature.
"""

from __future__ import annotations

import dataclasses
import json
import math
import re
from pathlib import Path
from typing import Literal, Optional

import numpy as np
import pytest
import scipy.integrate
import scipy.sparse as sps
import sympy as sp

import phc
from phc.library import registry
from phc.ir.dae import T
from phc.errors import ModelError
from phc.library import LOWERERS
from phc.library.dirac import DiracBuilder, emit
from phc.library.registry import (ASSEMBLED, NO_FIELDS, NO_STATE_READS, ComponentType, ElementUnit, RegistryError, Units)
from phc.spec.export import build_schema, schema_text
from phc.spec.base import Expr, SpecModel
from phc.spec.components import Domain
from model_texts import CRANK, LINEAR, MODULATION, PDE1D, STRING_MODES  # shared with tests/checks/
from time_limits import SUBPROCESS_TIMEOUT

REPO = Path(__file__).resolve().parents[1]
MODELS = REPO / "models"
VALID = REPO / "tests" / "models" / "valid"
SCHEMA_FILE = REPO / "schemas" / "model.schema.json"

EXAMPLES = {
    "phs": VALID / "lc_oscillator_phs.yaml",
    "linear_phs": LINEAR,
    "rigid": MODELS / "pendulum.yaml",
    "mass": MODELS / "mass_spring_damper.yaml",
    "spring": MODELS / "mass_spring_damper.yaml",
    "damper": MODELS / "mass_spring_damper.yaml",
    "junction": MODELS / "mass_spring_damper.yaml",
    "inductor": MODELS / "rlc_circuit.yaml",
    "capacitor": MODELS / "rlc_circuit.yaml",
    "resistor": MODELS / "rlc_circuit.yaml",
    "effort_source": MODELS / "rlc_circuit.yaml",
    "flow_source": MODELS / "rigid_slider_crank.yaml",
    "zero_effort": MODELS / "euler_bernoulli_beam.yaml",
    "zero_flow": MODELS / "timoshenko_beam.yaml",
    "orthogonal_transform": VALID / "rotated_springs_split.yaml",
    "transformer": REPO / "tests" / "library" / "models" / "dc_motor.yaml",
    "gyrator": REPO / "tests" / "library" / "models" / "dc_motor.yaml",
    "modulation": MODULATION,
    "string": MODELS / "vibrating_string.yaml",
    "timoshenko_beam": MODELS / "timoshenko_beam.yaml",
    "euler_bernoulli_beam": MODELS / "euler_bernoulli_beam.yaml",
    "pde1d": PDE1D,
    "moving_beam": MODELS / "moving_beam.yaml",
    "crank_wheel": CRANK,
    "pi": MODELS / "dc_motor_pi.yaml",
    "contact": MODELS / "bouncing_ball.yaml",
    "state_space": """
format_version: 1
parameters: {m: 1.0, k: 4.0, tau: 0.1}
components:
  body: {type: mass, m: m}
  spring: {type: spring, k: k}
  lag: {type: state_space, input: ["-2*spring.x"], A: [[-1/tau]], B: [[1/tau]], C: [[1]]}
  push: {type: effort_source, value: "lag.y"}
  node: {type: junction, kind: common_flow, ports: [m, s, f]}
connections:
  - [node.m, body.port]
  - [node.s, spring.port]
  - [node.f, push.port]
simulation: {t_end: 1.0, initial: {spring.x: 0.1}}
""",
}
"""A small model that uses each type (a file, or the text of one)."""


def _model_path(kind: str, tmp_path: Path) -> Path:
    example = EXAMPLES[kind]
    if isinstance(example, Path):
        return example
    path = tmp_path / f"{kind}.yaml"
    path.write_text(example)
    if kind == "linear_phs":
        D = np.array([[1.0, 0.0], [-1.0, 1.0]])
        J = np.block([[np.zeros((2, 2)), D], [-D.T, np.zeros((2, 2))]])
        np.savez(tmp_path / "chain.npz", J=J, R=np.diag([0.0, 0.0, 0.0, 0.3]), Q=np.eye(4))
    return path


def _schema_mapping(schema: dict) -> dict:
    return schema["properties"]["components"]["additionalProperties"]["discriminator"]["mapping"]


# -- every registered type ---------------------------------------------------------------

@pytest.mark.parametrize("kind", registry.names())
def test_every_type_has_its_parts_and_a_minimal_model_compiles_and_certifies(kind, tmp_path):
    entry = registry.get(kind)
    assert entry.problems() == []

    # a schema entry: the published schema (kept up to date by tests/test_schema.py) and
    # the live one both map `type: <kind>` to the entry's spec
    for schema in (json.loads(SCHEMA_FILE.read_text()), build_schema()):
        assert _schema_mapping(schema)[kind] == f"#/$defs/{entry.spec.__name__}"

    # unit information, or the reason there is none
    units = entry.units
    assert isinstance(units, Units) and units.problems() == []
    if units.none:
        assert not (units.si or units.element or units.ratio)
    else:
        assert units.si or units.element or units.ratio

    # a cost model; the minimal model compiles and certifies
    assert kind in EXAMPLES, f"add a minimal model using `{kind}` to EXAMPLES"
    compiled = phc.compile_model(_model_path(kind, tmp_path))
    assert compiled.certificate is not None and not compiled.certificate.diagnostics.has_errors
    of_kind = [name for name, ctype, _ in compiled.dae.topology.components if ctype == kind]
    assert of_kind, f"the example of `{kind}` has no component of that type"
    specs = compiled.dae.topology.specs
    if "elements" in entry.spec.model_fields:
        # the estimate is of phc's own discretization: within 10 % of the unknowns compiled
        # (the per-element counts are rounded to whole unknowns; the ends add a few)
        name = of_kind[0]
        unknowns, nonzeros = entry.cost(specs[name])
        actual = sum(1 for v in compiled.dae.variables if v.component == name)
        assert nonzeros > 0 and abs(unknowns - actual) <= 0.1 * actual + 8, (unknowns, actual)
    else:
        assert entry.cost is ASSEMBLED and entry.cost(specs.get(of_kind[0])) is None


def test_the_built_in_types_are_the_spec_union(monkeypatch):
    """Every spec of phc.spec.components' union has an entry, and every entry is in it."""
    registry.check_builtin_union()
    union = set(_schema_mapping(build_schema())) - {"model"}
    assert union == set(registry.names())
    monkeypatch.delitem(registry.COMPONENT_TYPES, "spring")
    with pytest.raises(RegistryError, match="no registry entry for SpringSpec"):
        registry.check_builtin_union()


def test_the_per_type_tables_are_the_registrys():
    from phc.study.accuracy import SPATIAL_ORDER
    from phc.ir.initial_fields import FIELDS
    from phc.ir.interconnect import MODULATED
    from phc.library.lumped import DEFAULT_DOMAIN

    assert list(LOWERERS) == registry.names()
    assert LOWERERS["spring"] is registry.get("spring").lower
    assert DEFAULT_DOMAIN["capacitor"] == "electrical" and "string" not in DEFAULT_DOMAIN
    assert dict(SPATIAL_ORDER) == {"string": 2, "timoshenko_beam": 2, "euler_bernoulli_beam": 4, "pde1d": 2,
                                   "moving_beam": 4}
    assert set(FIELDS) == {"string", "timoshenko_beam", "euler_bernoulli_beam", "moving_beam"}
    assert set(MODULATED) == {"modulation", "transformer", "gyrator"}


def test_the_effects_message_names_the_registrys_types_with_effects():
    """A scene that switches an effect of a type without effects is told which types have
    them: read from the registry (a type registered later is named too), not a list."""
    from phc.frontend.effects import apply_overrides

    spring = registry.get("spring").spec.model_validate({"type": "spring", "k": 1.0})
    _, message = apply_overrides(spring, {"damping": False})
    with_effects = [n for n in registry.names() if "effects" in registry.get(n).spec.model_fields]
    assert {"rigid", "phs", "string", "moving_beam"} <= set(with_effects)
    assert all(f"{name}" in message for name in with_effects)
    assert "no optional effects" in message and "spring" not in message.split("exist for", 1)[1]


def test_implicit_effects_come_from_the_registry():
    """`damping` of a `phs` and `gravity` of a `rigid` exist without being declared: the
    registry entry says so (no table beside it in phc.frontend.effects)."""
    from phc.frontend.effects import effect_names

    assert registry.get("rigid").implicit_effects == {"gravity": True, "damping": True}
    assert registry.get("phs").implicit_effects == {"damping": True}
    assert registry.get("spring").implicit_effects == {}
    phs = registry.get("phs").spec.model_validate(
        {"type": "phs", "states": ["x"], "hamiltonian": "x**2/2", "J": [[0]], "effects": {"wind": False}})
    assert effect_names(phs) == {"damping": True, "wind": False}


def test_a_forgotten_or_wrong_field_is_refused_at_registration():
    spring = registry.get("spring")
    values = {f.name: getattr(spring, f.name) for f in dataclasses.fields(ComponentType)}
    optional = {f.name for f in dataclasses.fields(ComponentType) if f.default_factory is not dataclasses.MISSING
                or f.default is not dataclasses.MISSING}
    assert optional == {"implicit_effects", "signal"}  # none without effects of its own; physical unless said
    for missing in set(values) - optional:
        with pytest.raises(TypeError, match=missing):
            ComponentType(**{k: v for k, v in values.items() if k != missing})
    wrong = {
        "name": ("soft_spring", "must have the field `type: Literal['soft_spring']`"),
        "units": (Units(), "give exactly one of"),
        "sign_role": ("sink", "`sign_role` 'sink' is not one of"),
        "default_domain": ("magnetic", "`default_domain` 'magnetic'"),
        "cost": (None, "`cost` is not callable"),
        "spatial_order": (0, "`spatial_order` is a positive integer"),
        "rows": ("by hand", "`rows` 'by hand' is one of derived, hand-written"),
        "signal": ("yes", "`signal` is a bool"),
    }
    for field, (value, message) in wrong.items():
        with pytest.raises(RegistryError, match=re.escape(message)):
            registry.register(dataclasses.replace(spring, **{field: value}))
    with pytest.raises(RegistryError, match="needs a spec with an `effects` field"):
        registry.register(dataclasses.replace(spring, name="spring", implicit_effects={"damping": True}))
    rigid = registry.get("rigid")
    with pytest.raises(RegistryError, match="the default of `gravity` is a bool"):
        registry.register(dataclasses.replace(rigid, implicit_effects={"gravity": "on"}))
    with pytest.raises(RegistryError, match="name the field in `state_reads`"):
        registry.register(dataclasses.replace(spring, name="spring", signal=True))
    with pytest.raises(RegistryError, match="registered already"):
        registry.register(spring)
    beam = registry.get("string")
    with pytest.raises(RegistryError, match="estimates the mesh"):
        registry.register(dataclasses.replace(beam, cost=ASSEMBLED))
    assert registry.get("spring") is spring and registry.get("string") is beam


# -- a new type from this file: the cubic spring --------------------------------------------

class CubicSpringSpec(SpecModel):
    """Hardening spring: H = k x²/2 + k3 x⁴/4, ẋ = f, e = −(k x + k3 x³)."""

    type: Literal["cubic_spring"]
    k: Expr
    """Linear stiffness, positive."""
    k3: Expr
    """Cubic stiffness, non-negative."""
    domain: Optional[Domain] = None


def lower_cubic_spring(b, ctx, name, spec, path):
    scope = {"t": T, **ctx.params}
    k = b.expr(ctx, spec.k, (*path, "k"), scope)
    k3 = b.expr(ctx, spec.k3, (*path, "k3"), scope)
    span = ctx.smap.locate(path)
    port = b.add_port(name, "port", spec.domain or registry.get("cubic_spring").default_domain, 1, span=span)
    x, dx = b.add_state(name, "x", span)
    d = DiracBuilder(name, spec.type, span)
    d.port(port)
    fx, ex = d.storage_pair("x", x, dx, k * x + k3 * x**3)
    d.rel(fx - port.f[0], solve=port.f[0])
    d.rel(port.e[0] + ex, kind="storage", label="force[0]")
    d.energy(k * x**2 / 2 + k3 * x**4 / 4)
    emit(b, d.register(b))


CUBIC_SPRING = ComponentType(
    name="cubic_spring", spec=CubicSpringSpec, lower=lower_cubic_spring, default_domain="mechanical.translational",
    units=Units.of_port(ElementUnit("k", "e", "f*s", "a stiffness"),
                        ElementUnit("k3", "e", "f*s*f*s*f*s", "a cubic stiffness"), storage="f"), cost=ASSEMBLED,
    spatial_order=None, initial_fields=NO_FIELDS, sign_role="load", state_reads=NO_STATE_READS, drawing=None,
    rows="derived")

DUFFING = """
format_version: 1
parameters: {m: 1.0, k: 4.0, k3: 10.0, A: 0.8}
components:
  mass: {type: mass, m: m}
  spring: {type: cubic_spring, k: k, k3: k3}
connections:
  - [mass.port, spring.port]
simulation:
  t_end: 6.0
  initial: {spring.x: A, mass.p: 0.0}
"""


def duffing_period(m: float, k: float, k3: float, amplitude: float) -> float:
    """Period of m ẍ = −k x − k3 x³ released at rest from x = A: with x = A sin θ the
    energy integral 4∫₀ᴬ dx / v(x) becomes 4∫₀^{π/2} √m dθ / √(k + k3 A² (1 + sin²θ)/2),
    a smooth integrand."""
    integrand = lambda th: math.sqrt(m) / math.sqrt(k + k3 * amplitude**2 * (1 + math.sin(th) ** 2) / 2)  # noqa: E731
    value, error = scipy.integrate.quad(integrand, 0.0, math.pi / 2, epsabs=1e-14, epsrel=1e-13)
    assert error < 1e-12
    return 4 * value


def _upward_crossings(t: np.ndarray, x: np.ndarray) -> np.ndarray:
    """Times where x crosses 0 upwards, by linear interpolation between output points."""
    i = np.nonzero((x[:-1] < 0) & (x[1:] >= 0))[0]
    return t[i] - x[i] * (t[i + 1] - t[i]) / (x[i + 1] - x[i])


def test_a_cubic_spring_registered_here_simulates_the_duffing_oscillator(tmp_path):
    path = tmp_path / "duffing.yaml"
    path.write_text(DUFFING)
    m, k, k3, amplitude = 1.0, 4.0, 10.0, 0.8
    period = duffing_period(m, k, k3, amplitude)
    h0 = k * amplitude**2 / 2 + k3 * amplitude**4 / 4
    errors = {}
    published = schema_text()
    with registry.registered(CUBIC_SPRING):
        assert "cubic_spring" in _schema_mapping(build_schema())
        compiled = phc.compile_model(path)
        assert compiled.certificate is not None and not compiled.certificate.diagnostics.has_errors
        for h in (1e-3, 5e-4):
            result = phc.simulate(compiled, solver="discrete_gradient", step=h, n_out=round(6.0 / h) + 1)
            assert result.success
            t, x = np.asarray(result.t), np.asarray(result["spring.x"])
            # the energy: the discrete gradient keeps H exactly, up to the Newton tolerance
            assert abs(result.H[0] - h0) < 1e-12 * h0
            assert np.max(np.abs(result.H - h0)) < 1e-9 * h0
            # the period, from successive upward zero crossings (x'' = 0 there, so linear
            # interpolation between output points is third-order accurate: ~1e-9 s)
            crossings = _upward_crossings(t, x)
            assert len(crossings) >= 2
            errors[h] = np.max(np.abs(np.diff(crossings) - period))
    # The discrete gradient method is second order: its relative period error on a linear
    # oscillator of frequency ω is (ω h)²/12; here the local frequency √((k + 3 k3 x²)/m)
    # is at most ω_max ≈ 4.8 (at x = A), so (ω_max h)²/12 bounds it (4.1e-6 s at h = 1e-3;
    # measured 2.7e-6). Halving h divides the error by 4.
    omega_max = math.sqrt((k + 3 * k3 * amplitude**2) / m)
    assert errors[1e-3] < (omega_max * 1e-3) ** 2 / 12 * period
    assert 3.0 < errors[1e-3] / errors[5e-4] < 5.0
    # ... and the period is not the linear spring's 2π√(m/k) it would be without k3
    assert abs(period - 2 * math.pi * math.sqrt(m / k)) > 0.1

    # the registration is undone: the type is gone from the registry and from the schema
    assert "cubic_spring" not in registry.names() and "cubic_spring" not in LOWERERS
    assert schema_text() == published
    with pytest.raises(phc.errors.ModelError):
        phc.compile_model(path)


def test_the_first_use_from_several_threads_at_once_sees_every_built_in_type():
    """A Dask worker runs sweep points on threads: the first lookups of a fresh process come
    from several threads at once, and each must find the built-in types (one thread loading
    them while another read the half-filled registry gave KeyError: 'linear_phs')."""
    import subprocess
    import sys
    import textwrap

    code = textwrap.dedent("""
        import threading
        from phc.library import registry
        from phc.library import LOWERERS
        barrier = threading.Barrier(8)
        found = []
        def look():
            barrier.wait()
            found.append("linear_phs" in LOWERERS and registry.find("linear_phs") is not None)
        threads = [threading.Thread(target=look) for _ in range(8)]
        [t.start() for t in threads]
        [t.join() for t in threads]
        print(found.count(True), len(registry.names()))
    """)
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=SUBPROCESS_TIMEOUT)
    assert out.returncode == 0, out.stderr
    hits, count = map(int, out.stdout.split())
    assert hits == 8 and count >= 24


# -- where every type's rows come from ------------------------------------------------------


ROW_CASES = {
    **{kind: (kind, EXAMPLES[kind]) for kind in EXAMPLES if not registry.get(kind).signal},
    "phs (kernel form)": ("phs", MODELS / "quarter_car.yaml"),
    "string (modal truncation)": ("string", STRING_MODES),
}
"""Each registry entry's example, and the forms whose rows come from elsewhere: a kernel-form
``phs`` (J/R/B in EXAMPLES) and a modal truncation. Signal blocks have no description to
derive rows from or compare them with (:func:`test_a_signal_blocks_rows_are_outside_the_rows_check`)."""


def _flip_first_term(expr):
    terms = sp.Add.make_args(sp.expand(expr))
    return sp.Add(-terms[0], *terms[1:]) if len(terms) > 1 else None


class FlipOneRow:
    """A test double around a lowerer: in each call (each assembly of the model, the coarse
    one of :func:`phc.checks.rows.check_hand_written` included), the first row of one kind
    that the lowerer writes itself gets one sign flipped — a residual row's first term
    (`equation`), a definition of a port variable (`define`) or the largest entry of an
    interior row of a sparse block's structure operator (`linear`). Rows derived by
    :func:`phc.library.dirac.emit` are left alone."""

    MODES = ("linear", "equation", "define")

    def __init__(self, lowerer, mode, derived_too=False):
        self.lowerer, self.mode, self.flipped = lowerer, mode, []
        self.derived_too = derived_too  # flip a derived row too (a type declared hand-written)

    def __call__(self, b, *args, **kwargs):
        original = (b.add_equation, b.define, b.add_linear_rows)
        done = []

        def add_equation(expr, component, kind, label, span=None, *, derived=False):
            flipped = (None if done or (derived and not self.derived_too) or self.mode != "equation"
                       else _flip_first_term(expr))
            if flipped is not None:
                done.append(f"equation {label}")
                expr = flipped
            return original[0](expr, component, kind, label, span, derived=derived)

        def define(sym, value, *, derived=False):
            if not done and not derived and self.mode == "define" and value != 0:
                done.append(f"definition of {sym}")
                value = -value
            return original[1](sym, value, derived=derived)

        def add_linear_rows(component, label, n_rows, terms, span=None, *, derived=False):
            couplings = [i for i, t in enumerate(terms) if not t.derivative and t.matrix.nnz]
            if not done and not derived and self.mode == "linear" and couplings:
                t = terms[couplings[0]]
                m = sps.csr_matrix(t.matrix, copy=True)
                row = m.shape[0] // 2  # an interior node: an end may be clamped
                big = int(m.indptr[row] + np.argmax(np.abs(m.data[m.indptr[row]:m.indptr[row + 1]])))
                m.data[big] = -m.data[big]
                terms = [*terms[:couplings[0]], dataclasses.replace(t, matrix=m), *terms[couplings[0] + 1:]]
                done.append(f"block {label}, entry {big}")
            return original[2](component, label, n_rows, terms, span, derived=derived)

        b.add_equation, b.define, b.add_linear_rows = add_equation, define, add_linear_rows
        try:
            return self.lowerer(b, *args, **kwargs)
        finally:
            b.add_equation, b.define, b.add_linear_rows = original
            self.flipped += done


def _located_e452(err: ModelError, name: str, kind: str, path: Path):
    found = [d for d in err.diagnostics if d.code == "PHC-E452"]
    assert found, "; ".join(d.render() for d in err.diagnostics)
    diag = found[0]
    assert f"`{name}`" in diag.message and "do not say what its description says" in diag.message
    assert "fault in phc" in diag.hint and "not in the model" in diag.hint
    assert diag.span is not None and Path(diag.span.file).name == path.name and diag.span.line > 1
    return diag


@pytest.mark.parametrize("case", sorted(ROW_CASES))
def test_every_types_rows_are_derived_from_its_description_or_compared_with_it_when_compiling(
        case, tmp_path, monkeypatch):
    """Issue 31's "every component type's rows come from its description", as far as it holds
    today: each entry declares where its rows come from (`rows`), the elaborate pass records
    what its lowerer did and the two agree; rows derived from the description are the
    description, and for hand-written ones compile_model runs the rows check — a row
    flipped in the lowerer makes compile_model refuse the model with a located PHC-E452."""
    kind, example = ROW_CASES[case]
    entry = registry.get(kind)
    path = _model_path(kind, tmp_path) if example is EXAMPLES.get(kind) else example
    if isinstance(path, str):
        path = tmp_path / "model.yaml"
        path.write_text(example)
    compiled = phc.compile_model(path, backend="numpy")
    top = compiled.dae.topology
    names = [name for name, ctype, _ in top.components if ctype == kind]
    assert names
    rows = {r.component: r for r in top.rows}
    declared = {entry.rows_of(top.specs[name]) for name in names}
    assert len(declared) == 1, declared
    declared = declared.pop()
    assert declared in registry.ROWS
    assert all(rows[name].derived == (declared == "derived") for name in names), \
        f"`{kind}` declares its rows {declared}, its lowerer did otherwise"
    if declared == "derived":
        assert "certify_rows" in compiled.timings  # nothing of this type was compared: nothing to compare
        return
    assert "certify_rows" in compiled.timings
    for mode in FlipOneRow.MODES:
        double = FlipOneRow(entry.lower, mode)
        monkeypatch.setitem(LOWERERS, kind, double)
        try:
            phc.compile_model(path, certify=False, backend="numpy")
        except ModelError:
            continue  # this flip breaks the model's structure before any check: try another row
        if double.flipped:
            break
    else:
        pytest.fail(f"no row of `{kind}` could be flipped")
    with pytest.raises(ModelError) as err:
        phc.compile_model(path, backend="numpy")
    _located_e452(err.value, names[0], kind, path)


STILL_HAND_WRITTEN: dict[str, str] = {}
"""The cases (ROW_CASES) whose rows are not derived yet (issue 31 item 1), with why: none.
A ``pde1d`` whose `D` couples two variables writes its rows
(:func:`phc.library.pde1d.pde1d_rows`; tested below)."""


@pytest.mark.parametrize("case", sorted(ROW_CASES))
def test_every_types_rows_are_derived_from_its_description(case, tmp_path, request):
    """Issue 31 item 1's goal, per registry entry (and per form of an entry): its lowerer
    derives every row from its description (:func:`phc.library.dirac.emit`), its entry
    says so, compile_model has none of its rows to compare (:func:`hand_written`), and the
    rows check of ``phc check`` — which compares every component's rows with its
    description independently of how they were made — finds them equal. The types that
    still write their rows are expected failures (strict: one that becomes derived must
    leave STILL_HAND_WRITTEN)."""
    from phc.checks.rows import check_rows, hand_written

    kind, example = ROW_CASES[case]
    if case in STILL_HAND_WRITTEN:
        request.applymarker(pytest.mark.xfail(strict=True, reason=STILL_HAND_WRITTEN[case]))
    entry = registry.get(kind)
    path = _model_path(kind, tmp_path) if example is EXAMPLES.get(kind) else example
    if isinstance(path, str):
        path = tmp_path / "model.yaml"
        path.write_text(example)
    dae, diags = phc.build_dae(path)
    assert dae is not None, diags.render_text()
    top = dae.topology
    names = [name for name, ctype, _ in top.components if ctype == kind]
    assert names
    rows = {r.component: r for r in top.rows}
    cert = check_rows(dae, components=names)
    assert not cert.diagnostics, [d.message for d in cert.diagnostics]
    assert {entry.rows_of(top.specs[name]) for name in names} == {"derived"}
    assert all(rows[name].derived for name in names)
    assert not set(names) & set(hand_written(dae))


def test_every_registry_entry_has_a_rows_case():
    signal = {kind for kind in registry.names() if registry.get(kind).signal}
    assert {kind for kind, _ in ROW_CASES.values()} == set(registry.names()) - signal
    assert signal == {"pi", "state_space"}


@pytest.mark.parametrize("kind", sorted(k for k in registry.names() if registry.get(k).signal))
def test_a_signal_blocks_rows_are_outside_the_rows_check(kind, tmp_path):
    """A signal block (a controller with state) has no ports and no description: it writes
    its rows itself, the rows check leaves it out, and ``phc check`` lists it as outside
    the certificate while every physical component is compared."""
    from phc.checks.rows import check_rows, hand_written

    dae, diags = phc.build_dae(_model_path(kind, tmp_path))
    assert dae is not None, diags.render_text()
    top = dae.topology
    names = [name for name, ctype, _ in top.components if ctype == kind]
    assert names and not {rel.component for rel in top.dirac} & set(names)
    assert not [p for p in top.ports if p.component in names]
    assert not set(names) & set(hand_written(dae))
    cert = check_rows(dae)
    assert not cert.diagnostics and not set(names) & set(cert.compared)
    assert set(STILL_HAND_WRITTEN) <= set(ROW_CASES)


def test_a_pde1d_whose_damping_couples_two_variables_writes_its_rows(tmp_path, monkeypatch):
    """An off-diagonal entry of `D` is a dissipation between two variables, not a resistive
    pair of one field: such a ``pde1d`` writes its rows, its entry says so, and
    compile_model compares them with its description."""
    from phc.checks.rows import hand_written

    text = PDE1D.replace("    H: [", "    D: [[0.5, 0.1], [0.1, 0.2]]\n    H: [", 1)
    assert text != PDE1D
    path = tmp_path / "model.yaml"
    path.write_text(text)
    compiled = phc.compile_model(path, backend="numpy")
    top = compiled.dae.topology
    name = next(n for n, ctype, _ in top.components if ctype == "pde1d")
    assert registry.get("pde1d").rows_of(top.specs[name]) == "hand-written"
    assert not next(r for r in top.rows if r.component == name).derived
    assert name in hand_written(compiled.dae)
    for mode in ("linear", "define"):  # a flipped row is refused when compiling, located at the component
        double = FlipOneRow(registry.get("pde1d").lower, mode)
        monkeypatch.setitem(LOWERERS, "pde1d", double)
        with pytest.raises(ModelError) as err:
            phc.compile_model(path, backend="numpy")
        assert double.flipped
        _located_e452(err.value, name, "pde1d", path)


def test_a_large_moving_beam_is_compared_on_a_coarse_mesh(tmp_path, monkeypatch):
    """Above COMPILE_MAX_UNKNOWNS the moving beam's rows (dense test) are compared on the same
    component with COARSE_ELEMENTS elements: a flipped row is still refused, and the
    message says where it was compared."""
    from phc.checks.rows import COARSE_ELEMENTS

    text = (MODELS / "moving_beam.yaml").read_text()
    assert "    elements: 8\n" in text
    path = tmp_path / "moving_beam.yaml"
    path.write_text(text.replace("    elements: 8\n", "    elements: 24\n"))
    honest = phc.compile_model(path, backend="numpy")
    assert not [d for d in honest.diagnostics if d.code == "PHC-W452"]
    # the moving beam derives its rows: as a type that writes them (declared so, one row
    # flipped as a faulty lowerer would), it is compared when compiling
    entry = registry.get("moving_beam")
    monkeypatch.setitem(registry.COMPONENT_TYPES, "moving_beam", dataclasses.replace(
        entry, rows="hand-written", lower=FlipOneRow(entry.lower, "equation", derived_too=True)))
    with pytest.raises(ModelError) as err:
        phc.compile_model(path, backend="numpy")
    diag = _located_e452(err.value, "beam", "moving_beam", path)
    assert f"with {COARSE_ELEMENTS} elements" in diag.message
