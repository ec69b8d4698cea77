"""The built-in component types: one :class:`~phc.library.registry.ComponentType` entry each.

Imported by :mod:`phc.library.registry` on first use. Each entry is everything phc knows of its
type beside the spec model (:mod:`phc.spec.components`) and the lowerer
(:mod:`phc.library`); the per-type tables of the other modules are derived from these
entries. The units of the lumped elements' fields are products of their port domain's
effort ``e``, flow ``f`` and the second ``s``; the distributed components' fields are in
fixed SI units.

The lowerers of the distributed components (and of ``linear_phs``) are imported when first
called (:class:`_Deferred`): their modules load scipy's sparse matrices, which a model of
lumped components never needs (`phc validate` of one imports no scipy,
tests/test_validate_large.py).
"""

from __future__ import annotations

import importlib
from functools import partial

from phc.study import viz
from phc.library import lumped
from phc.library.contact import lower_contact
from phc.library.phs import lower_phs
from phc.library.rigid import lower_rigid
from phc.library.signal import lower_pi, lower_state_space
from phc.library.registry import (ASSEMBLED, NO_FIELDS, NO_STATE_READS, ComponentType, Drawing, ElementUnit, InitialFields,
                          PerElement, ROWS, StateReads, Units)
from phc.spec import components as c

TRANSLATIONAL, ELECTRICAL, GENERIC = "mechanical.translational", "electrical", "generic"
DERIVED, HAND_WRITTEN = ROWS
_MATRICES = "its matrices and expressions are in the model's own units"
_SIGNAL = "a signal block: its gains and signals have whatever units the controller's designer chose"


class _Deferred:
    """``module.name`` (a lowerer, or another function of a component), imported on its first call."""

    __slots__ = ("module", "name", "_function")

    def __init__(self, module: str, name: str) -> None:
        self.module, self.name, self._function = module, name, None

    def __call__(self, *args, **kwargs):
        if self._function is None:
            self._function = getattr(importlib.import_module(self.module), self.name)
        return self._function(*args, **kwargs)

    def __repr__(self) -> str:
        return f"{self.module}.{self.name}"


lower_euler_bernoulli = _Deferred("phc.library.beams", "lower_euler_bernoulli")
lower_string = _Deferred("phc.library.beams", "lower_string")
lower_timoshenko = _Deferred("phc.library.beams", "lower_timoshenko")
lower_linear_phs = _Deferred("phc.library.linear", "lower_linear_phs")
lower_crank_wheel = _Deferred("phc.library.moving", "lower_crank_wheel")
lower_moving_beam = _Deferred("phc.library.moving", "lower_moving_beam")
lower_pde1d = _Deferred("phc.library.pde1d", "lower_pde1d")
pde1d_rows = _Deferred("phc.library.pde1d", "pde1d_rows")


def _lumped(name, spec, lower, domain, units, sign_role=None, state_reads=NO_STATE_READS, drawing=None):
    """An entry without a mesh or initial fields; its rows are derived from its description."""
    return ComponentType(name=name, spec=spec, lower=lower, default_domain=domain, units=units, cost=ASSEMBLED,
                         spatial_order=None, initial_fields=NO_FIELDS, sign_role=sign_role,
                         state_reads=state_reads, drawing=drawing, rows=DERIVED)


def _element(name, spec, lower, domain, field, num, den, meaning, storage=None, states=None):
    return _lumped(name, spec, lower, domain, Units.of_port(ElementUnit(field, num, den, meaning), storage=storage,
                                                            states=states),
                   sign_role="load")


def pde1d_cost(spec) -> tuple[int, int]:
    """Unknowns and Jacobian nonzeros of a ``pde1d`` of order N with n variables on E
    elements: 2N·n per node; per element 4 (N = 1) or 7 (N = 2) times that times n/2."""
    n, per = int(spec.elements), 2 * int(spec.order) * len(spec.variables)
    return per * (n + 1), per * (4 if spec.order == 1 else 7) * max(1, len(spec.variables) // 2) * n


_LENGTH, _DAMPING = ("m", "a length"), ("N*s/m^2", "a damping per length")
_VALUE = (("a", "a", 0), ("b", "b", 0))

BUILTINS = (
    ComponentType(name="phs", spec=c.PhsSpec, lower=lower_phs, default_domain=None,
                  units=Units.absent(_MATRICES), cost=ASSEMBLED, spatial_order=None, initial_fields=NO_FIELDS,
                  sign_role=None, state_reads=NO_STATE_READS, drawing=None, rows=DERIVED,
                  implicit_effects={"damping": True}),
    ComponentType(name="linear_phs", spec=c.LinearPhsSpec, lower=lower_linear_phs, default_domain=None,
                  units=Units.absent(_MATRICES), cost=ASSEMBLED, spatial_order=None, initial_fields=NO_FIELDS,
                  sign_role=None, state_reads=NO_STATE_READS, drawing=None, rows=DERIVED),
    ComponentType(name="rigid", spec=c.RigidSpec, lower=lower_rigid, default_domain=None,
                  units=Units.absent(_MATRICES), cost=ASSEMBLED, spatial_order=None, initial_fields=NO_FIELDS,
                  sign_role=None, state_reads=NO_STATE_READS, drawing=Drawing(viz.draw_rigid), rows=DERIVED,
                  implicit_effects={"gravity": True, "damping": True}),
    _element("mass", c.MassSpec, partial(lumped.lower_inertia, coeff_field="m", state="p"), TRANSLATIONAL,
             "m", "e*s", "f", "effort·time/flow (a mass, or a moment of inertia)", storage="e", states={"x": "f"}),
    _element("inductor", c.InductorSpec, partial(lumped.lower_inertia, coeff_field="L", state="phi"), ELECTRICAL,
             "L", "e*s", "f", "effort·time/flow (an inductance)", storage="e"),
    _element("spring", c.SpringSpec, partial(lumped.lower_compliance, coeff_field="k", state="x", inverse=False),
             TRANSLATIONAL, "k", "e", "f*s", "effort/displacement (a stiffness)", storage="f"),
    _element("capacitor", c.CapacitorSpec, partial(lumped.lower_compliance, coeff_field="C", state="q", inverse=True),
             ELECTRICAL, "C", "f*s", "e", "displacement/effort (a capacitance)", storage="f"),
    _element("damper", c.DamperSpec, partial(lumped.lower_resistance, coeff_field="d"), TRANSLATIONAL,
             "d", "e", "f", "effort/flow (a damping coefficient)"),
    _element("resistor", c.ResistorSpec, partial(lumped.lower_resistance, coeff_field="R"), ELECTRICAL,
             "R", "e", "f", "effort/flow (a resistance)"),
    _lumped("effort_source", c.EffortSourceSpec, partial(lumped.lower_source, which="effort"), GENERIC,
            Units.of_port(ElementUnit("value", "e", "1", "the effort of its domain")), sign_role="source",
            state_reads=StateReads(("value",))),
    _lumped("flow_source", c.FlowSourceSpec, partial(lumped.lower_source, which="flow"), GENERIC,
            Units.of_port(ElementUnit("value", "f", "1", "the flow of its domain"),
                          ElementUnit("position", "f*s", "1", "a displacement")),
            sign_role="source", state_reads=StateReads(("value",))),
    _lumped("zero_effort", c.ZeroEffortSpec, partial(lumped.lower_termination, which="effort"), GENERIC,
            Units.absent("a termination has no field with a dimension")),
    _lumped("zero_flow", c.ZeroFlowSpec, partial(lumped.lower_termination, which="flow"), GENERIC,
            Units.absent("a termination; the units of its optional `position` are not checked"),
            drawing=Drawing(viz.draw_support, stage="attachment")),
    _lumped("orthogonal_transform", c.OrthogonalTransformSpec, lumped.lower_transform, GENERIC,
            Units.absent("an orthogonal matrix is dimensionless"),
            drawing=Drawing(viz.draw_guide, stage="attachment")),
    _lumped("transformer", c.TransformerSpec, lumped.lower_transformer, GENERIC, Units.two_port("f", "f"),
            sign_role="series", state_reads=StateReads(("ratio",), modulated=True)),
    _lumped("gyrator", c.GyratorSpec, lumped.lower_gyrator, GENERIC, Units.two_port("e", "f"),
            sign_role="series", state_reads=StateReads(("ratio",), modulated=True)),
    _lumped("junction", c.JunctionSpec, lumped.lower_junction, GENERIC,
            Units.absent("a junction has no field with a dimension"), sign_role="junction"),
    _lumped("modulation", c.ModulationSpec, lumped.lower_modulation, GENERIC,
            Units.of_port(ElementUnit("K", "e", "f", "effort/flow")), state_reads=StateReads(("K",), modulated=True)),
    ComponentType(
        name="string", spec=c.StringSpec, lower=lower_string, default_domain=None,
        units=Units.fixed({"rho": ("kg/m", "a mass per length"), "T": ("N", "a force (the tension)"),
                           "length": _LENGTH, "damping": _DAMPING}),
        cost=PerElement(4, 16), spatial_order=2,  # P1/P0 elements
        initial_fields=InitialFields({
            "w": "transverse deflection w(ξ); sets the strain ε = ∂w/∂ξ",
            "velocity": "transverse velocity v(ξ); sets the momentum density p = ρv",
            "p": "momentum density p(ξ)",
            "eps": "strain ε(ξ) = ∂w/∂ξ",
        }, pin_traces={"velocity": _VALUE, "p": _VALUE}),
        sign_role=None, state_reads=NO_STATE_READS, drawing=None, rows=DERIVED),
    ComponentType(
        name="timoshenko_beam", spec=c.TimoshenkoBeamSpec, lower=lower_timoshenko, default_domain=None,
        units=Units.fixed({"rho": ("kg/m", "a mass per length"), "I_rho": ("kg*m", "a rotary inertia per length"),
                           "EI": ("N*m^2", "a bending stiffness"), "K": ("N", "a shear stiffness (κGA)"),
                           "length": _LENGTH, "damping": _DAMPING}),
        cost=PerElement(8, 36), spatial_order=2,  # P1/P0 elements
        initial_fields=InitialFields({
            "w": "transverse deflection w(ξ); with `phi` sets γ = ∂w/∂ξ − φ and θ = ∂φ/∂ξ (without `phi`: "
                 "φ = ∂w/∂ξ, no shear)",
            "phi": "rotation φ(ξ) of the cross-sections (with `w`)",
            "velocity": "transverse velocity ∂w/∂t; sets p = ρ v",
            "angular_velocity": "angular velocity ∂φ/∂t of the cross-sections; sets M = I_ρ ∂φ/∂t",
            "p": "transverse momentum density", "M": "angular momentum density",
            "gamma": "shear strain γ = ∂w/∂ξ − φ", "theta": "bending strain θ = ∂φ/∂ξ",
        }, pin_traces={"velocity": _VALUE, "p": _VALUE, "angular_velocity": (("a_rot", "a", 0), ("b_rot", "b", 0)),
                       "M": (("a_rot", "a", 0), ("b_rot", "b", 0))}),
        sign_role=None, state_reads=NO_STATE_READS, drawing=None, rows=DERIVED),
    ComponentType(
        name="euler_bernoulli_beam", spec=c.EulerBernoulliBeamSpec, lower=lower_euler_bernoulli, default_domain=None,
        units=Units.fixed({"rhoA": ("kg/m", "a mass per length"), "EI": ("N*m^2", "a bending stiffness"),
                           "length": _LENGTH, "damping": _DAMPING}),
        cost=PerElement(8, 54), spatial_order=4,  # Hermite/DP1 elements
        initial_fields=InitialFields({
            "w": "transverse deflection w(ξ); sets the curvature κ = ∂²w/∂ξ²",
            "velocity": "transverse velocity v(ξ); sets the momentum density p = ρA v",
            "p": "momentum density p(ξ)",
            "kappa": "curvature κ(ξ)",
        }, pin_traces={"velocity": _VALUE + (("a_rot", "a", 1), ("b_rot", "b", 1)), "p": _VALUE}),
        sign_role=None, state_reads=NO_STATE_READS, drawing=None, rows=DERIVED),
    ComponentType(
        name="pde1d", spec=c.Pde1dSpec, lower=lower_pde1d, default_domain=None, units=Units.absent(_MATRICES),
        cost=pde1d_cost, spatial_order=2, initial_fields=InitialFields(from_variables=True),
        sign_role=None, state_reads=NO_STATE_READS, drawing=None, rows=pde1d_rows),
    ComponentType(
        name="moving_beam", spec=c.MovingBeamSpec, lower=lower_moving_beam, default_domain=None,
        units=Units.fixed({"length": _LENGTH, "rhoA": ("kg/m", "a mass per length"),
                           "EI": ("N*m^2", "a bending stiffness"), "damping": ("N*m^2*s", "a Kelvin–Voigt damping")}),
        cost=PerElement(8, 62), spatial_order=4,  # Hermite/DP1 elements
        initial_fields=InitialFields({
            "w": "elastic deflection w(ξ) from the chord, w(0) = w(L) = 0; sets κ = ∂²w/∂ξ²",
            "velocity": "elastic transverse velocity ∂w/∂t relative to the chord's rigid motion, zero at both ends",
            "kappa": "curvature κ(ξ)",
            "p": "transverse momentum density p_b(ξ) in the chord frame, rigid motion included (its end values "
                 "set the ends' normal velocities)",
            "u": "axial displacement u(ξ) (effect `axial`); sets the axial strain ε = ∂u/∂ξ",
            "axial_velocity": "axial velocity ∂u/∂t relative to the end ξ = 0 (effect `axial`), zero at ξ = 0",
            "eps": "axial strain ε(ξ) (effect `axial`)",
        }),
        sign_role=None, state_reads=NO_STATE_READS, drawing=Drawing(viz.draw_moving_beam), rows=DERIVED),
    ComponentType(
        name="crank_wheel", spec=c.CrankWheelSpec, lower=lower_crank_wheel, default_domain=None,
        units=Units.fixed({"radius": _LENGTH, "inertia": ("kg*m^2", "a moment of inertia"),
                           "center": ("m", "a position")}),
        cost=ASSEMBLED, spatial_order=None, initial_fields=NO_FIELDS, sign_role=None,
        state_reads=NO_STATE_READS, drawing=Drawing(viz.draw_crank_wheel), rows=DERIVED),
    ComponentType(
        name="state_space", spec=c.StateSpaceSpec, lower=lower_state_space, default_domain=None,
        units=Units.absent(_SIGNAL), cost=ASSEMBLED, spatial_order=None, initial_fields=NO_FIELDS,
        sign_role=None, state_reads=StateReads(("input",)), drawing=None, rows=HAND_WRITTEN, signal=True),
    ComponentType(
        name="pi", spec=c.PiSpec, lower=lower_pi, default_domain=None,
        units=Units.absent(_SIGNAL), cost=ASSEMBLED, spatial_order=None, initial_fields=NO_FIELDS,
        sign_role=None, state_reads=StateReads(("input",)), drawing=None, rows=HAND_WRITTEN, signal=True),
    ComponentType(
        name="contact", spec=c.ContactSpec, lower=lower_contact, default_domain=None,
        units=Units.absent("a contact's gap is in the units of the positions it is written in"),
        cost=ASSEMBLED, spatial_order=None, initial_fields=NO_FIELDS, sign_role=None,
        state_reads=StateReads(("gap",)), drawing=None, rows=DERIVED),
)
"""The built-in entries, registered by :func:`phc.library.registry._load_builtins` on first use."""
