"""Component specs: user-defined (`phs`, `rigid`), nested models and the library.

Each class is one ``type:`` of a component entry in a model file. The union
:data:`ComponentSpec` is discriminated on ``type``. The physics of each type
lives in :mod:`phc.library`; this module only describes what a user may write.
"""

from __future__ import annotations

from typing import Annotated, Literal, Optional, Union

from pydantic import Field, field_validator, model_validator

from phc.spec.base import Expr, Identifier, Matrix, SpecModel, Switch, Vector

Domain = Literal[
    "mechanical.translational",
    "mechanical.rotational",
    "electrical",
    "hydraulic",
    "thermal",
    "generic",
]
"""Physical domain of a power port. Connected ports must share it."""


def _unique(names: list[str]) -> list[str]:
    seen = set()
    for name in names:
        if name in seen:
            raise ValueError(f"port `{name}` is listed twice; give each port its own name")
        seen.add(name)
    return names


class _Component(SpecModel):
    description: Optional[str] = None
    """Free text shown in reports."""


class _Effects(SpecModel):
    """Optional physics of a component, each on (`true`) or off (`false`). A scene
    (`models/scenes/*.yaml`, key `effects`) overrides them per run; an effect that is off
    does not appear in the generated code."""


class DistributedEffects(_Effects):
    """Effects of the library PDE components (`string`, `euler_bernoulli_beam`)."""

    damping: Switch = True
    """Distributed viscous damping (the component's `damping` coefficient; nothing without one)."""
    modes: Optional[int] = Field(None, ge=1)
    """Keep only the k lowest modes of the discretized PDE (structure-preserving modal
    truncation: the reduced system is again pH with the same boundary ports). Default: all."""


class TimoshenkoEffects(DistributedEffects):
    """Effects of the `timoshenko_beam`; with `shear` and `rotary_inertia` both off it behaves
    as an Euler–Bernoulli beam."""

    shear: Switch = True
    """Shear deformation (off: the shear strain is constrained to zero, infinite shear stiffness)."""
    rotary_inertia: Switch = True
    """Rotary inertia of the cross-sections (off: their angular momentum is neglected)."""


class MovingBeamEffects(_Effects):
    """Effects of the `moving_beam` (paper, Section 5.1)."""

    flexibility: Switch = True
    """Elastic deformation (off: a rigid link with the same mass and rigid-body inertia —
    the flexible slider–crank becomes the rigid one)."""
    moving_frame: Switch = True
    """The modulation terms K_r, K_f of the moving frame (paper,
    Proposition 11): ω∫p_b in the tangential momentum and −ρωp_t/m in the
    transverse momentum. Off drops both (they exchange power with each other only)."""
    damping: Switch = True
    """Kelvin–Voigt damping of the elastic motion (the `damping` coefficient)."""
    modes: Optional[int] = Field(None, ge=1)
    """Keep only the k lowest modes of the elastic part (see `DistributedEffects.modes`)."""
    axial: Switch = False
    """Axial deformation (beyond the paper; off by default, the paper's inextensible rod):
    longitudinal displacement u(ξ) with axial stiffness `EA`, the chord length becomes
    L + u(L) and the tangential momentum a field p_a(ξ) coupled to the frame's rotation
    (ṗ_a ∋ ω p_b, ṗ_b ∋ −ω p_a). Needs `EA`; not with `modes`."""
    stiffening: Switch = False
    """Centrifugal stiffening (beyond the paper; off by default, the paper's model): the
    axial force of the spin about the end ξ = 0, N = ρω²(L² − ξ²)/2, in the transverse
    momentum, ṗ_b ∋ ∂(N ∂w/∂ξ) + ρω²w (geometric stiffness and centrifugal softening, the
    consistent first-order theory of a rotating beam), with the reaction on the chord's
    rotation that makes the pair power-neutral. Not with `axial` or `modes`."""


UserEffects = dict[Identifier, Switch]
"""Effects of user-defined components: name → default. Each name can be used as a 0/1
factor in the component's expressions, and names terms of a Hamiltonian or potential
written as a mapping."""


class PortSpec(SpecModel):
    """A power port: a flow vector f and an effort vector e of equal dimension.

    Generator sign convention (paper, Remark 2 "Sign convention"): ``f·e`` is the power the
    component delivers through the port; mechanical efforts are reaction forces
    (``e = -F_acting``).
    """

    domain: Domain = "generic"
    """Physical domain; connected ports must have the same domain, except that a `generic`
    port connects to a port of any domain."""
    dimension: int = Field(1, ge=1, le=64)
    """Number of flow (and effort) components."""
    frame: Optional[str] = None
    """Name of the coordinate frame of vector ports; connected ports must agree when both give one."""
    description: Optional[str] = None
    """Free text shown in reports."""


class PhsPortSpec(PortSpec):
    """A port of a `phs` component in input-state-output form.

    ``causality: effort_in``: ``ẋ = (J−R)∇H − B e``, ``f = Bᵀ∇H``.
    ``causality: flow_in``: ``ẋ = (J−R)∇H + B f``, ``e = −Bᵀ∇H``.
    Both give ``dH/dt = −∇HᵀR∇H − f·e`` (paper, Remark 3 "Energy balance").
    """

    B: Optional[Matrix] = None
    """Input matrix (n_states × dimension). Only in J/R/B form."""
    causality: Literal["effort_in", "flow_in"] = "effort_in"
    """Which port variable is the input in J/R/B form."""


class ResistiveSpec(SpecModel):
    """A resistive port (f_R, e_R) with a constitutive law; passive when f_R·e_R ≥ 0, or a
    controlled source (`kind: source`) whose power is supplied to the model."""

    dimension: int = Field(1, ge=1, le=64)
    """Number of components of `f_<name>` and `e_<name>`."""
    law: list[str]
    """`dimension` equations relating `f_<name>` and `e_<name>`, e.g. `e_R = r*f_R`."""
    kind: Literal["dissipative", "source"] = "dissipative"
    """`dissipative`: the law dissipates, f·e ≥ 0 (checked). `source`: a controlled source
    that may supply power (a transistor's collector): its power f·e is counted as power
    through an external port (supplied energy), not as dissipation, and `phc check` lists it."""


class PhsSpec(_Component):
    """A user-defined port-Hamiltonian component.

    Either in input-state-output form (give `J`, optionally `R` and each port's `B`) or in
    kernel form (give `relations`: linear relations among the flows `f_*` and efforts `e_*`
    of states, ports and resistive ports, with optional latent `multipliers`, as in the
    paper's eq. (4) with its ∃μ). States' flows are `f_x = dx/dt`, their efforts
    `e_x = ∂H/∂x`.
    """

    type: Literal["phs"]
    parameters: dict[Identifier, Expr] = {}
    """Local parameters (may refer to model parameters)."""
    states: list[Identifier]
    """Energy variables x."""
    hamiltonian: Union[Expr, dict[Identifier, Expr]] = 0
    """H(x): the stored energy; or a mapping of named terms (summed), where a term named
    after an effect is dropped when that effect is off."""
    J: Optional[Matrix] = None
    """Skew-symmetric interconnection matrix J(x) (n_states × n_states)."""
    R: Optional[Matrix] = None
    """Symmetric positive semidefinite dissipation matrix R(x)."""
    ports: dict[Identifier, PhsPortSpec] = {}
    """Power ports by name."""
    multipliers: list[Identifier] = []
    """Latent variables of the kernel form."""
    relations: Optional[list[str]] = None
    """Dirac relations (kernel form), one equation each."""
    resistive: dict[Identifier, ResistiveSpec] = {}
    """Resistive ports (kernel form)."""
    effects: UserEffects = {}
    """Named effects and their defaults (built in: `damping`, which switches `R`)."""

    @model_validator(mode="after")
    def _one_form(self):
        if self.J is not None and self.relations is not None:
            raise ValueError("give either `J` (input-state-output form) or `relations` (kernel form), not both")
        if self.J is None and self.relations is None:
            raise ValueError("a `phs` component needs `J` (input-state-output form) or `relations` (kernel form)")
        return self


MatrixRef = Union[Matrix, str]
"""A matrix given inline (rows of numbers) or as the name of an array in the `matrices` file."""


class LinearPhsPortSpec(PortSpec):
    """A port of a `linear_phs` component (input-state-output form, see `PhsPortSpec`)."""

    B: MatrixRef
    """Input matrix (n_states × dimension), inline or the name of an array in `matrices`."""
    causality: Literal["effort_in", "flow_in"] = "effort_in"
    """Which port variable is the input."""


class LinearPhsSpec(_Component):
    """A linear port-Hamiltonian system given by (possibly large, sparse) matrices::

        E ẋ = (J − R) Q x − Σ_{effort_in} B e + Σ_{flow_in} B f,   H = ½ xᵀQx,

    with J skew, R ⪰ 0, Q ≻ 0 symmetric. The matrices stay sparse through compilation
    (no per-entry symbolic work), so models exported from FE codes with thousands of
    states compile quickly. Each matrix can be scaled by a parameter expression in
    `scale`, keeping parameters run-time arguments.
    """

    type: Literal["linear_phs"]
    parameters: dict[Identifier, Expr] = {}
    """Local parameters (may refer to model parameters)."""
    states: Union[int, list[Identifier]]
    """Number of states (named `x[0]`, `x[1]`, ...) or their names."""
    matrices: Optional[str] = None
    """An `.npz` file (relative to the model file) holding named arrays: dense 2-D arrays,
    or sparse ones stored as `NAME.data`, `NAME.indices`, `NAME.indptr`, `NAME.shape` (CSR)."""
    J: MatrixRef
    """Skew-symmetric interconnection matrix (n_states × n_states), inline or the name of an
    array in `matrices`."""
    R: Optional[MatrixRef] = None
    """Symmetric positive semidefinite dissipation matrix (default zero)."""
    Q: Optional[MatrixRef] = None
    """Energy matrix (default identity)."""
    E: Optional[MatrixRef] = None
    """Descriptor matrix on ẋ (default identity)."""
    scale: dict[Literal["J", "R", "Q", "E"], Expr] = {}
    """Scalar factors (expressions in parameters) multiplying the matrices."""
    ports: dict[Identifier, LinearPhsPortSpec] = {}
    """Power ports by name."""


class RigidPortSpec(PortSpec):
    """A port of a rigid multibody component: its flow is ``Bᵀ(q) v`` (paper, eq. (3))."""

    B: Matrix
    """Port map B(q, t) (n_velocities × dimension)."""
    position: Optional[Vector] = None
    """Position r(q) of the port (dimension entries, not depending on `t`) with ``d/dt r(q) = Bᵀv``. When two
    connected ports both give positions, phc keeps ``r₁ = r₂`` at position level (GGL
    stabilization) so the joint does not drift."""


class RigidSpec(_Component):
    """Rigid multibody data of the paper's Section 3 (eq. (3)).

    State (q, p) with p = M(q) v; H = ½ pᵀv + V(q). Position constraints c(q) = 0 are
    integrated in the stabilized index-2 (Gear–Gupta–Leimkuhler) form. Each field may depend
    on the variables named in its description, on parameters and on `t`; anything else is a
    located error (docs/constraints.md).
    """

    type: Literal["rigid"]
    parameters: dict[Identifier, Expr] = {}
    """Local parameters (may refer to model parameters)."""
    q: list[Identifier] = Field(min_length=1)
    """Configuration variables."""
    v: Optional[list[Identifier]] = None
    """Generalized velocities (default: `v_<q>` for each q; requires Z square)."""
    M: Matrix = Field(min_length=1)
    """Mass matrix, constant or configuration dependent M(q, t); symmetric positive definite."""
    Z: Optional[Matrix] = None
    """Kinematics q̇ = Z(q, t) v (n_q × n_v). Default identity."""
    V: Union[Expr, dict[Identifier, Expr]] = 0
    """Potential energy V(q, t) (its ∂V/∂t is booked in the energy balance); or a mapping of named terms (summed), e.g.
    `{gravity: m*g*y, spring: k*x**2/2}`, where a term named after an effect is dropped when
    that effect is off."""
    constraints: list[Expr] = []
    """Position constraints c(q, t) = 0; with `t` a prescribed motion (rheonomic): velocity
    form c_q Z v + c_t = 0, and the constraint's work is booked in the energy balance."""
    velocity_constraints: Matrix = []
    """Rows of A(q, t) in the velocity constraints A(q, t) v = 0 (homogeneous: ideal, no work)."""
    damping: Optional[Vector] = None
    """Damping force F_d(q, v, t) with vᵀF_d ≥ 0."""
    G: Optional[Matrix] = None
    """Skew gyroscopic matrix G(q, p, t)."""
    ports: dict[Identifier, RigidPortSpec] = {}
    """Power ports by name; each port's flow is `Bᵀ(q) v`."""
    effects: UserEffects = {}
    """Named effects and their defaults (built in: `gravity`, which switches the `V` term named
    `gravity`, and `damping`, which switches `damping`)."""


class ModelComponentSpec(_Component):
    """Another model file used as a component; its exposed `ports` become this component's ports."""

    type: Literal["model"]
    file: str
    """Path of the model file, relative to this file."""
    parameters: dict[Identifier, Expr] = {}
    """Overrides of the nested model's parameters (expressions in this model's parameters)."""


class _OnePort(_Component):
    domain: Optional[Domain] = None
    """Domain of the port. Default: `mechanical.translational` for a mass, spring or damper,
    `electrical` for an inductor, capacitor or resistor, `generic` for the sources and
    terminations (a `generic` port connects to a port of any domain)."""
    dimension: int = Field(1, ge=1, le=64)
    """Number of flow (and effort) components of each port: a vector element (a planar
    mass has dimension 2, with `m` the same in every direction)."""
    ports: list[Identifier] = Field(["port"], min_length=1)
    """Port names. Several ports share the same flow (like a 1-junction): a mass with
    several attachment points."""

    @field_validator("ports")
    @classmethod
    def _unique_ports(cls, value):
        return _unique(value)


class _Element(_OnePort):
    terminals: Optional[list[Identifier]] = None
    """Two port names `[a, b]`: the element sits *between* two neighbours instead of at
    the end of one port. It acts on the relative across variable of its terminals — in
    the mechanical domains the relative velocity ``f_a − f_b`` with ``e_b = −e_a`` (a
    spring between two masses), in the electrical, hydraulic and thermal domains the
    relative effort ``e_a − e_b`` with ``f_b = −f_a`` (a resistor between two nodes).
    In those domains a series chain keeps the sign as drawn: a terminal joined to another
    terminal, to a capacitor, inductor or resistor, or to port `a` of a transformer or
    gyrator is a wire (``e_x = e_y``, ``f_x = −f_y``), so each element's flow is positive
    from its `a` to its `b` (docs/signs.md). Not together with `ports`."""

    @field_validator("terminals")
    @classmethod
    def _two_terminals(cls, value):
        if value is not None and len(value) != 2:
            raise ValueError(f"`terminals` names exactly two ports, e.g. [a, b]; got {len(value)}")
        return value if value is None else _unique(value)

    @model_validator(mode="after")
    def _terminals_or_ports(self):
        if self.terminals is not None and "ports" in self.model_fields_set:
            raise ValueError("give either `terminals` (an element between two ports) or `ports` (ports "
                             "sharing one flow), not both")
        return self


class MassSpec(_OnePort):
    """Mass (or inertia): H = |p|²/2m, port flow p/m, ṗ = −Σ e."""

    type: Literal["mass"]
    m: Expr
    """Mass (or moment of inertia in the rotational domain), positive."""
    position: bool = False
    """Also integrate its position `x` (an angle in the rotational domain): ẋ = p/m, the
    canonical partner of the momentum, with no energy of its own, so that where the mass
    is can be an output or an initial value (`body.x`)."""


class InductorSpec(_Element):
    """Inductor: H = φ²/2L, port flow (current) φ/L, φ̇ = −Σ e."""

    type: Literal["inductor"]
    L: Expr
    """Inductance, positive."""


class SpringSpec(_Element):
    """Linear spring: H = k|x|²/2, ẋ = f, e = −kx (one port: its elongation rate)."""

    type: Literal["spring"]
    k: Expr
    """Stiffness, positive."""


class CapacitorSpec(_Element):
    """Capacitor: H = q²/2C, q̇ = f (current), e = −q/C."""

    type: Literal["capacitor"]
    C: Expr
    """Capacitance, positive."""


class DamperSpec(_Element):
    """Linear damper: e = −d f, dissipating d|f|² ≥ 0."""

    type: Literal["damper"]
    d: Expr
    """Damping coefficient, non-negative."""


class ResistorSpec(_Element):
    """Linear resistor: e = −R f (voltage drop), dissipating R f² ≥ 0."""

    type: Literal["resistor"]
    R: Expr
    """Resistance, non-negative."""


class EffortSourceSpec(_OnePort):
    """Imposes the effort it applies to its neighbour: e = value(t)."""

    type: Literal["effort_source"]
    value: Union[Expr, Vector]
    """Expression(s) in `t`, parameters and — for feedback (a controller) — other
    components' states and port variables by full name (`spring.x`, `coil.port.f`). The
    plant stays certified; a controller may inject energy, which the energy balance counts
    as supplied power."""


class FlowSourceSpec(_OnePort):
    """Imposes the flow: f = value(t)."""

    type: Literal["flow_source"]
    value: Union[Expr, Vector]
    """Expression(s) in `t`, parameters and — for feedback — other components' states and
    port variables by full name, as for `effort_source`."""
    position: Optional[Vector] = None
    """Optional position (integral of the flow) in `t`; lets phc keep the driven
    coordinate at position level."""


class ZeroEffortSpec(_OnePort):
    """Termination e = 0 with free flow (the paper's D_free of Section 4.2 and D_pin of Section 5.2)."""

    type: Literal["zero_effort"]


class ZeroFlowSpec(_OnePort):
    """Termination f = 0 with free effort (the paper's D_guide of Section 5.2, a fixed support)."""

    type: Literal["zero_flow"]
    position: Optional[Vector] = None
    """Optional fixed position of the support; with a rigid port position it gives a
    position-level constraint."""


class OrthogonalTransformSpec(_Component):
    """Power-preserving port transform (the paper's Q_s, Section 5.2, eq. (29)).

    Port `a` (dimension n) and port `b`: ``f_b = Q f_a``, ``e_b = −Q e_a`` so that
    ``f_a·e_a + f_b·e_b = 0``. Connected to a port (f, e) of a neighbour, `b` carries
    (Q f, Q e). With `split`, `b` is replaced by ports with the given dimensions.
    """

    type: Literal["orthogonal_transform"]
    Q: Matrix
    """Orthogonal n × n matrix (constant or modulated by parameters/time)."""
    domain: Optional[Domain] = None
    """Domain of both ports."""
    split: Optional[dict[Identifier, int]] = None
    """Output ports and their dimensions, in order (e.g. `{s: 1, n: 1}`)."""


class TransformerSpec(_Component):
    """Ideal transformer between port `a` (dimension n) and port `b` (dimension m): a gear,
    lever, pulley, a piston's area, a transformer's turns ratio.

    ``f_b = N f_a`` and ``e_a = −Nᵀ e_b`` with the ratio N (a number, or an m × n
    matrix), so ``f_a·e_a + f_b·e_b = 0`` for every N: power-conserving, a Dirac
    structure for any ratio. N may depend on `t`, parameters and the states of other
    components written by their full names (a modulated transformer: a crank's
    ``r·sin(wheel.theta)``)."""

    type: Literal["transformer"]
    ratio: Union[Expr, Matrix]
    """The ratio N from port `a` to port `b`: flow at `b` = N × flow at `a` (`f_b = N f_a`), effort
    at `a` = −Nᵀ × effort at `b` (`e_a = −Nᵀ e_b`). A gear with `a` on the motor and `b` on the
    load has N = ω_load/ω_motor (1/n for a reduction n : 1). Signs: docs/signs.md."""
    domain_a: Optional[Domain] = None
    """Domain of port `a` (default `generic`)."""
    domain_b: Optional[Domain] = None
    """Domain of port `b` (default: that of `a`)."""


class GyratorSpec(_Component):
    """Ideal gyrator between port `a` (dimension n) and port `b` (dimension m): a DC
    motor's electromechanical coupling (torque = Km·current, back-EMF = Km·speed), a
    gyroscope, a Hall element.

    ``e_b = G f_a`` and ``e_a = −Gᵀ f_b`` with the ratio G (a number, or an m × n
    matrix), so ``f_a·e_a + f_b·e_b = 0`` for every G. G may depend on `t`, parameters
    and other components' states, as for `transformer`."""

    type: Literal["gyrator"]
    ratio: Union[Expr, Matrix]
    """The ratio G from port `a` to port `b`: effort at `b` = G × flow at `a` (`e_b = G f_a`),
    effort at `a` = −Gᵀ × flow at `b` (`e_a = −Gᵀ f_b`). A DC motor with `a` electrical and `b`
    the shaft has G = Km: torque Km·i, back-EMF Km·ω. Signs: docs/signs.md."""
    domain_a: Optional[Domain] = None
    """Domain of port `a` (default `generic`; `electrical` for a motor's coil)."""
    domain_b: Optional[Domain] = None
    """Domain of port `b` (default: that of `a`; `mechanical.rotational` for a motor's shaft)."""


class ModulationSpec(_Component):
    """Finite-dimensional modulation of port variables (paper, Section 4.2).

    Between port `a` (towards a fixed Dirac structure) and port `b` (outside):
    ``f_b = f_a``, ``e_b = −e_a + K(x) f_a`` with K skew, i.e. the paper's
    ``U_x : (f_m, e_m) ↦ (f_m, e_m + K(x) f_m)``. Power preserving for every x:
    ``f_a·e_a + f_b·e_b = f_aᵀK(x)f_a = 0``. K may depend on `t`, parameters and the
    states of other components, written by their full names (e.g. `wheel.theta`).
    """

    type: Literal["modulation"]
    K: Matrix
    """Skew-symmetric n × n matrix K(x)."""
    domain: Optional[Domain] = None
    """Domain of both ports."""


class JunctionSpec(_Component):
    """A power-conserving junction of n ports.

    `common_flow` (1-junction): all flows equal, efforts sum to zero (series electrical
    connection, forces on one body). `common_effort` (0-junction): all efforts equal,
    flows sum to zero.
    """

    type: Literal["junction"]
    kind: Literal["common_flow", "common_effort"]
    """`common_flow` (1-junction) or `common_effort` (0-junction)."""
    ports: list[Identifier] = Field(min_length=2)
    """Names of the junction's ports (at least two)."""

    @field_validator("ports")
    @classmethod
    def _unique_ports(cls, value):
        return _unique(value)
    domain: Optional[Domain] = None
    """Domain of the ports."""
    dimension: int = Field(1, ge=1, le=64)
    """Number of flow (and effort) components of each port."""


class _Distributed(_Component):
    """A 1-D pH PDE component (paper, Section 4.1, eq. (7)), discretized by a structure-preserving
    mixed finite element method that keeps the boundary ports."""

    length: Expr
    """Length L of the domain [0, L] (evaluated at the default parameters: it fixes the mesh)."""
    elements: int = Field(16, ge=1, le=200_000)
    """Number of finite elements."""
    damping: Optional[Expr] = None
    """Viscous damping per unit length on the transverse momentum (the D term of the paper's eq. (7));
    may depend on `xi`."""
    effects: DistributedEffects = DistributedEffects()
    """Optional physics, each on by default (a scene overrides them)."""


class StringSpec(_Distributed):
    """Vibrating string (paper, Example 1 (a)): state (p, ε), H = ½∫(p²/ρ + Tε²).

    Ports `a`, `b`: transverse velocity and reaction force at ξ = 0 and ξ = L.
    """

    type: Literal["string"]
    rho: Expr
    """Mass per unit length ρ(ξ) (may depend on `xi`)."""
    T: Expr
    """Tension T(ξ)."""


class TimoshenkoBeamSpec(_Distributed):
    """Timoshenko beam (paper, Example 1 (b)): state (γ, p, θ, M).

    Ports `a`, `b` (transverse velocity / shear force) and `a_rot`, `b_rot` (angular
    velocity / moment) at the two ends.
    """

    type: Literal["timoshenko_beam"]
    rho: Expr
    """Mass per unit length."""
    I_rho: Expr
    """Rotary inertia per unit length."""
    EI: Expr
    """Bending stiffness."""
    K: Expr
    """Shear stiffness (κ G A)."""
    effects: TimoshenkoEffects = TimoshenkoEffects()
    """Optional physics, each on by default (a scene overrides them)."""


class EulerBernoulliBeamSpec(_Distributed):
    """Euler–Bernoulli beam (paper, Example 1 (c)): state (κ, p), N = 2.

    Ports `a`, `b` (transverse velocity / shear force) and `a_rot`, `b_rot` (angular
    velocity / moment) at the two ends.
    """

    type: Literal["euler_bernoulli_beam"]
    rhoA: Expr
    """Mass per unit length ρA(ξ)."""
    EI: Expr
    """Bending stiffness EI(ξ)."""


class MovingBeamSpec(_Component):
    """Planar Euler–Bernoulli beam in a chord frame (paper, Section 5.1,
    eqs. (19)–(24)).

    State: endpoint positions q0, qf, tangential momentum p_t, curvature κ(ξ) and transverse
    momentum density p_b(ξ); Hamiltonian eq. (21). Ports: `p0`, `pf` (planar
    translational, positions q0 and qf) and `m0`, `mf` (rotational: angular velocity /
    reaction moment). The chord length |qf − q0| = L is kept as a position invariant.
    """

    type: Literal["moving_beam"]
    length: Expr
    """Length L of the beam (its chord length stays L)."""
    rhoA: Expr
    """Mass per unit length ρ (constant)."""
    EI: Expr
    """Bending stiffness (constant)."""
    EA: Optional[Expr] = None
    """Axial stiffness (constant); used with effect `axial` on."""
    elements: int = Field(8, ge=1, le=100_000)
    """Number of finite elements."""
    initial_shape: Literal["straight", "free"] = "straight"
    """`straight`: at t₀ the rod is undeformed and moves rigidly (no elastic velocity), except
    for what initial fields give (`<name>.w` or `.kappa`: the deflection; `<name>.velocity`:
    the elastic velocity; docs/how-to/initial-fields.md); `free`: phc chooses the initial
    elastic velocity. A scene's `initial_shape` overrides it."""
    deflection_at: list[float] = [0.5]
    """Fractions ξ/L where the transverse deflection w(ξ) is available as output
    `<name>.w[i]` (reconstructed from κ with w(0) = w(L) = 0, paper, Remark 7 "Reconstruction
    of the relative displacement")."""
    damping: Optional[Expr] = None
    """Kelvin–Voigt damping c (N·m²·s): the bending moment gains c·κ̇, which damps the
    elastic motion and not the rigid one."""
    effects: MovingBeamEffects = MovingBeamEffects()
    """Optional physics, each on by default (a scene overrides them)."""


class CrankWheelSpec(_Component):
    """Rigid crank wheel of the paper's Section 5.2 (eq. (28)).

    State (θ, p_θ), H = p_θ²/2I. Ports `drive` (rotational: angular velocity / reaction
    torque, position θ) and `pin` (planar: crank-pin velocity r a⊥(θ) θ̇, position
    q_O + r a(θ)).
    """

    type: Literal["crank_wheel"]
    radius: Expr
    """Crank radius r: distance from the center to the crank pin."""
    inertia: Expr
    """Moment of inertia I of the wheel about its center."""
    center: list[Expr] = [0, 0]
    """Position q_O of the center (planar)."""


class Pde1dSpec(_Component):
    """A generic 1-D port-Hamiltonian PDE (paper, Section 4.1, eq. (7)) with boundary ports (eq. (8))::

        ∂x/∂t = −D H x + Σ_k P_k ∂^k(H x),   f_∂ = W_f γ(Hx),   e_∂ = W_e γ(Hx),

    with ``P_k = (−1)^{k+1} P_kᵀ``, ``P_N`` invertible, ``H ≻ 0``, ``D + Dᵀ ⪰ 0``,
    ``[W_f; W_e]`` invertible and the Green identity (eq. (10)) — all checked.
    """

    type: Literal["pde1d"]
    parameters: dict[Identifier, Expr] = {}
    """Local parameters (may refer to model parameters)."""
    order: Literal[1, 2]
    """N, the order of the differential operator."""
    variables: list[Identifier] = Field(min_length=1)
    """Names of the d components of the state x."""
    P: list[Matrix]
    """P_0, …, P_N (numbers), each d × d."""
    H: Matrix
    """Energy density matrix H(ξ) (d × d, expressions in `xi` and parameters)."""
    D: Optional[Matrix] = None
    """Dissipation matrix D(ξ) (d × d) with D + Dᵀ ⪰ 0; its entries share one parameter
    factor (or are numbers)."""
    W_f: Matrix
    """Boundary flow map (Nd × 2Nd numbers) on γ(Hx) = (e(b), …, e^{(N−1)}(b), e(a), …)."""
    W_e: Matrix
    """Boundary effort map (Nd × 2Nd numbers)."""
    ports: list[Identifier]
    """Names of the Nd boundary ports: port i has flow f_∂[i] and effort e_∂[i]."""
    port_domains: Optional[list[Domain]] = None
    """Domain of each boundary port, in the order of `ports` (default `generic`)."""
    length: Expr
    """Length L of the domain [0, L] (evaluated at the default parameters: it fixes the mesh)."""
    elements: int = Field(16, ge=1, le=200_000)
    """Number of finite elements."""


class StateSpaceSpec(_Component):
    """A linear signal block (a controller with state): ż = A z + B u, y = C z + D u.

    Not a physical component: it has no ports and no energy. Its input `u` reads other
    components' states and port variables (by full name, as a feedback source's `value`)
    and other blocks' outputs; its output `y` is read as `<name>.y` (`<name>.y[k]` for several) by a
    source's `value`, another block's `input` or the model's outputs. Its states
    `<name>.z` (`<name>.z[i]` for several) are integrated like any other state and start
    at 0 unless `simulation.initial` gives them. An integrator is `A: [[0]], B: [[1]],
    C: [[1]]`; a first-order lag with time constant τ and gain K is `A: [[-1/tau]],
    B: [[K/tau]], C: [[1]]`. `phc check` reports it as outside the port-Hamiltonian
    certificate; the energy it makes a source inject is counted as supplied power."""

    type: Literal["state_space"]
    input: Union[Expr, Vector]
    """Input u: expression(s) in `t`, parameters, other components' states, their port
    variables and other blocks' outputs, by full name (`load.p`, `coil.port.f`, `ctrl.y`)."""
    A: Matrix
    """State matrix (n × n; numbers or expressions of parameters)."""
    B: Matrix
    """Input matrix (n × m, m the number of inputs)."""
    C: Matrix
    """Output matrix (p × n, p the number of outputs)."""
    D: Optional[Matrix] = None
    """Feedthrough matrix (p × m); zero when left out."""


class PiSpec(_Component):
    """A PI (or, with `Kd`, PID) controller, a signal block: with the error e = `input`,
    ż = e and y = Kp e + Ki z (+ Kd times the filtered derivative of e).

    With `limits: [lo, hi]` the output is clamped to [lo, hi] and the integrator stops
    while the output is clamped and e would drive it further (anti-windup by conditional
    integration). The state is `<name>.z` (the integral of e; with `Kd` also
    `<name>.d`, the filter state), the output `<name>.y`. Not a physical component:
    `phc check` reports it as outside the port-Hamiltonian certificate."""

    type: Literal["pi"]
    input: Expr
    """The control error e, an expression in `t`, parameters, other components' states,
    their port variables and other blocks' outputs by full name (e.g. `w_ref - load.p/J_l`,
    `i_ref - coil.port.f`)."""
    Kp: Expr
    """Proportional gain."""
    Ki: Expr
    """Integral gain."""
    Kd: Optional[Expr] = None
    """Derivative gain (a PID); the derivative is filtered with time constant `Tf`."""
    Tf: Optional[Expr] = None
    """Time constant of the derivative filter (required with `Kd`, > 0): the derivative
    part is Kd·s/(Tf·s + 1) applied to e."""
    limits: Optional[list[Expr]] = Field(None, min_length=2, max_length=2)
    """Output limits [lo, hi]: the output is clamped and the integrator held while clamped
    (anti-windup)."""


class ContactSpec(_Component):
    """A unilateral contact with Newton's restitution law (an impact): the `gap` g ≥ 0, an
    expression in the positions of masses with `position: true` (lowered before it, e.g.
    `ball.x - floor_height`, or `b.x - a.x - clearance` between two masses). Where g falls
    through zero with closing velocity ġ⁻ < 0 the run stops, the masses' momenta jump along
    the contact normal ∂g/∂x so that ġ⁺ = −e·ġ⁻, and the run restarts; the kinetic energy
    lost, (1 − e²)·½ m_eff ġ⁻², is counted as dissipated (the energy balance stays exact).
    Where the bounces die out (see `rest_speed`) or a body starts at rest on it, the contact
    closes: it holds ġ = 0 with the contact force `<name>.force` ≥ 0 (a variable of the run)
    until that force falls to zero, where it opens again. Outputs `<name>.gap`,
    `<name>.gap_rate` (ġ), `<name>.restitution` and one `<name>.normal.<momentum>` per
    momentum the impulse acts on. With `friction` and `tangent`, Coulomb friction acts
    while the contact is closed (docs/events.md)."""

    type: Literal["contact"]
    gap: Expr
    """The gap g(x) ≥ 0 (open while positive), in the positions `<mass>.x` of masses with
    `position: true` declared before this entry, `t`-free, and parameters."""
    restitution: Expr
    """Newton's coefficient of restitution e in [0, 1] (parameters only): 1 elastic, 0
    plastic."""
    rest_speed: Optional[Expr] = None
    """The rebound speed |ġ⁺| (gap units per time, parameters only) below which a contact
    whose load presses the masses into it closes (persistent contact: the bounces of a ball
    accumulate at a finite time, and the ball then lies on the floor); the impact is then
    plastic. It also closes where 50 impacts fall within 1e-6 of the run. Default: 1e-6 of
    the largest closing speed this contact has seen in the run."""
    friction: Optional[Expr] = None
    """Coulomb's coefficient of friction μ ≥ 0 (parameters only) while the contact is closed:
    a tangential force `<name>.friction_force` λ_t along the `tangent` with |λ_t| ≤ μ λ,
    sticking (the slip rate held at 0, λ_t its multiplier) or sliding (λ_t = −μ λ
    sign(slip rate)); its power −λ_t·(slip rate) is counted as dissipated. Needs `tangent`.
    Impacts stay frictionless (docs/events.md)."""
    tangent: Optional[Expr] = None
    """The coordinate s(x) along the surface (positions and parameters, like `gap`) whose rate
    ṡ = Σ ∂s/∂x_j ẋ_j is the slip rate `<name>.slip_rate`, e.g. `block.x` for a floor
    `block.y`; ∂s/∂x should be orthogonal to the normal ∂g/∂x. Only with `friction`."""


ComponentSpec = Annotated[
    Union[
        PhsSpec, LinearPhsSpec, RigidSpec, ModelComponentSpec,
        MassSpec, InductorSpec, SpringSpec, CapacitorSpec, DamperSpec, ResistorSpec,
        EffortSourceSpec, FlowSourceSpec, ZeroEffortSpec, ZeroFlowSpec,
        OrthogonalTransformSpec, TransformerSpec, GyratorSpec, JunctionSpec, ModulationSpec,
        StringSpec, TimoshenkoBeamSpec, EulerBernoulliBeamSpec, Pde1dSpec, MovingBeamSpec, CrankWheelSpec,
        StateSpaceSpec, PiSpec, ContactSpec,
    ],
    Field(discriminator="type"),
]
