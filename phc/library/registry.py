"""The component registry: one entry per component ``type``, everything phc knows of it.

A :class:`ComponentType` bundles what the passes need of one type of component entry:

=================  ======================================================================
field              used by
=================  ======================================================================
spec               the input layer: the pydantic model of the entry (``type: <name>``)
lower              elaboration (:data:`phc.library.LOWERERS`)
default_domain     the ports' domain when the entry gives none
units              unit checks of its fields and of its states (:mod:`phc.frontend.units`)
cost               the memory estimate before discretization (:mod:`phc.frontend.budget`)
spatial_order      the spatial error estimate (:data:`phc.study.accuracy.SPATIAL_ORDER`)
initial_fields     mesh-independent initial data (:data:`phc.ir.initial_fields.FIELDS`)
sign_role          the sign hints of ``phc check`` (:mod:`phc.checks.signs`)
state_reads        which fields may name other components' states (:mod:`phc.ir.interconnect`)
drawing            how ``phc animate`` draws it (:mod:`phc.study.viz`), or None
signal             a signal block (a controller with state, :mod:`phc.library.signal`): no
                   ports, no energy, outside the certificate of ``phc check``
implicit_effects   effects a user-defined entry of the type has without declaring them
                   (:mod:`phc.frontend.effects`; ``rigid`` has ``gravity`` and ``damping``)
rows               where its rows come from (:data:`ROWS`): ``"derived"`` from its
                   description, or ``"hand-written"`` by its lowerer and then compared
                   with the description by every compilation (:mod:`phc.checks.rows`);
                   a function of the spec when the form decides
=================  ======================================================================

Every field but `implicit_effects` (empty unless given) and `signal` (False unless given) is a required keyword: an entry that forgets one is a ``TypeError`` when it
is made, and :func:`register` checks the values (a spec whose ``type`` is not the
entry's name, an unknown sign role, unit information that is neither given nor declared
absent with a reason) before the type exists for any pass. The per-type tables other
modules import (``LOWERERS``, ``DEFAULT_DOMAIN``, ``SPATIAL_ORDER``, ``FIELDS``,
``MODULATED``) are :class:`FieldView` objects over this registry, read when used, so a
type registered later (a test's own type, :func:`registered`) is seen by every pass.

Adding a type: write its spec model and its lowerer, and register one entry
(:mod:`phc.library.builtin` holds the built-in ones). The built-in specs are also the
union :data:`phc.spec.components.ComponentSpec` as written (the input layer defines
``ModelSpec`` before any lowerer can be imported); loading the built-ins checks that the
union and the entries name the same specs (:func:`check_builtin_union`), an error
otherwise. Registering a type whose spec is not in the union extends it
(:class:`~phc.spec.ModelSpec` is rebuilt); :func:`unregister` restores it.

The built-in entries are loaded on first use: importing this module imports neither
sympy nor pydantic (the cached front end reads :mod:`phc.frontend.budget` without them).
"""

from __future__ import annotations

import threading
from collections.abc import Callable, Iterator, Mapping, MutableMapping
from contextlib import contextmanager
from dataclasses import dataclass, field, replace
from typing import Any, Optional

from phc.errors import RegistryError

__all__ = ["ASSEMBLED", "COMPONENT_TYPES", "ROWS", "ComponentType", "Drawing", "ElementUnit", "FieldView",
           "InitialFields", "NO_FIELDS", "NO_STATE_READS", "PerElement", "RegistryError", "SIGN_ROLES", "StateReads",
           "Units", "find", "get", "names", "register", "registered", "unregister"]

ROWS = ("derived", "hand-written")
"""Where a type's rows come from: ``derived`` — :func:`phc.library.dirac.emit` derives every
row from the component's description, so the compiled rows and the certified structure are
one thing (sparse rows too, :func:`phc.library.dirac.emit_sparse`); ``hand-written`` — the
lowerer writes (some of) its rows itself (a ``pde1d`` whose damping couples two
variables, a type registered with its own rows), and :func:`phc.compile_model`
compares them with the
description (:func:`phc.checks.rows.check_hand_written`). The elaborate pass also records
what each lowerer actually did (:attr:`phc.ir.dae.ComponentRows.derived`); a component whose
lowerer wrote a row itself is compared whatever its entry declares."""

SIGN_ROLES = ("load", "source", "series", "junction")
"""Roles in the sign hints of :mod:`phc.checks.signs`: a one-port element that takes power
in (``load``), a source that delivers it (``source``), a two-port passing it through
(``series``), or a junction whose ``kind`` decides (common effort: a node; common flow: a
series group). None: the type takes no part in the hints."""

DOMAINS = ("mechanical.translational", "mechanical.rotational", "electrical", "hydraulic", "thermal", "generic")


# -- the parts of an entry -----------------------------------------------------------------

@dataclass(frozen=True)
class ElementUnit:
    """A field whose dimension follows from the port's domain: ``numerator / denominator``,
    products of ``e`` (the domain's effort), ``f`` (its flow), ``s`` (second) and ``1``
    (a spring's ``k`` is ``e / f*s``: N/m in ``mechanical.translational``)."""

    field: str
    numerator: str
    denominator: str
    meaning: str


@dataclass(frozen=True)
class Units:
    """What a type's fields and states are in. Exactly one of `si` (fields in fixed SI
    units), `element` (fields in units of the port's domain), `ratio` (a two-port's
    ``ratio`` between the units of its ports ``a`` and ``b``) or `none` (the reason there is
    no unit information) is given; make it with :meth:`fixed`, :meth:`of_port`,
    :meth:`two_port` or :meth:`absent`."""

    si: Mapping[str, tuple[str, str]] = field(default_factory=dict)
    """field -> (SI unit, what it is)."""
    element: tuple[ElementUnit, ...] = ()
    storage: Optional[str] = None
    """With `element`, for a lumped storage element: its state is effort·time (``"e"``: a
    momentum, a flux linkage) or flow·time (``"f"``: a displacement, a charge)."""
    states: Mapping[str, str] = field(default_factory=dict)
    """With `storage`: states (by name, without the index) of the other kind, e.g. a mass's
    position ``x`` (``"f"``) beside its momentum."""

    def storage_of(self, state: str) -> Optional[str]:
        """``"e"`` or ``"f"`` for the state `state` (``x`` or ``x[1]``), None without `storage`."""
        return self.states.get(state.split("[", 1)[0], self.storage) if self.storage else None
    ratio: Optional[tuple[str, str]] = None
    """(quantity of port b, quantity of port a), each ``"e"`` or ``"f"``: a transformer's
    ratio is ``("f", "f")``, a gyrator's ``("e", "f")``."""
    none: str = ""
    """Why the type has no unit information (its fields are matrices or expressions in the
    model's own units)."""

    @classmethod
    def fixed(cls, si: Mapping[str, tuple[str, str]]) -> "Units":
        return cls(si=dict(si))

    @classmethod
    def of_port(cls, *element: ElementUnit, storage: Optional[str] = None,
                states: Optional[Mapping[str, str]] = None) -> "Units":
        return cls(element=tuple(element), storage=storage, states=dict(states or {}))

    @classmethod
    def two_port(cls, b: str, a: str) -> "Units":
        return cls(ratio=(b, a))

    @classmethod
    def absent(cls, reason: str) -> "Units":
        return cls(none=reason)

    def problems(self) -> list[str]:
        given = [bool(self.si), bool(self.element), self.ratio is not None, bool(self.none)]
        out = []
        if sum(given) != 1:
            out.append("give exactly one of `si`, `element`, `ratio`, or `none` with a reason "
                       "(Units.fixed / of_port / two_port / absent)")
        if self.storage not in (None, "e", "f") or (self.storage and not self.element):
            out.append("`storage` is 'e' or 'f', and only with `element`")
        if self.states and (not self.storage or any(k not in ("e", "f") for k in self.states.values())):
            out.append("`states` maps state names to 'e' or 'f', and only with `storage`")
        for eu in self.element:
            for text in (eu.numerator, eu.denominator):
                if any(part not in ("e", "f", "s", "1") for part in text.split("*")):
                    out.append(f"`{eu.field}`: `{text}` is not a product of e, f, s, 1")
        if self.ratio is not None and any(q not in ("e", "f") for q in self.ratio):
            out.append("`ratio` is a pair of 'e'/'f'")
        return out


@dataclass(frozen=True)
class PerElement:
    """Memory cost of a discretized component: `unknowns` and Jacobian `nonzeros` per element
    of phc's discretization (counted on ``elements + 1`` nodes for the unknowns)."""

    unknowns: int
    nonzeros: int

    def __call__(self, spec) -> tuple[int, int]:
        n = int(spec.elements)
        return self.unknowns * (n + 1), self.nonzeros * n


@dataclass(frozen=True)
class _Assembled:
    """The cost model of a component without a mesh: nothing to estimate before lowering;
    its variables are counted exactly after assembly (:func:`phc.frontend.budget.check_assembled`)."""

    def __call__(self, spec) -> None:
        return None


ASSEMBLED = _Assembled()


@dataclass(frozen=True)
class InitialFields:
    """Mesh-independent initial fields of a distributed type (:mod:`phc.ir.initial_fields`)."""

    names: Mapping[str, str] = field(default_factory=dict)
    """field -> what it sets."""
    pin_traces: Mapping[str, tuple] = field(default_factory=dict)
    """field -> the end traces a pin (`zero_flow` on the port) sets to zero:
    (port, end, derivative) for each."""
    from_variables: bool = False
    """The fields are the spec's `variables` (``pde1d``)."""


NO_FIELDS = InitialFields()
"""A type without initial fields (its states are given one by one)."""


@dataclass(frozen=True)
class StateReads:
    """Fields of a spec whose expressions may name other components' states (``wheel.theta``)."""

    fields: tuple[str, ...] = ()
    modulated: bool = False
    """The fields are a matrix of the type's Dirac structure (a modulated structure): always
    lowered after the other components, whose states it may read."""


NO_STATE_READS = StateReads()


@dataclass(frozen=True)
class Drawing:
    """How ``phc animate`` draws a type (:mod:`phc.study.viz`): `draw(ctx, full, spec, prefix)`
    returns the parts. ``body`` drawings run first and place the planar points of their
    ports; ``attachment`` drawings (a guide, a support) are drawn at the points placed."""

    draw: Callable
    stage: str = "body"


@dataclass(frozen=True, kw_only=True)
class ComponentType:
    """One component type: see the module docstring for what each field is used by."""

    name: str
    spec: type
    lower: Callable
    default_domain: Optional[str]
    """Domain of the ports when the entry gives none; None: the lowerer decides."""
    units: Units
    cost: Callable[[Any], Optional[tuple[int, int]]]
    """spec -> (unknowns, Jacobian nonzeros) before discretization, or None (:data:`ASSEMBLED`)."""
    spatial_order: Optional[int]
    """Convergence order in the element size of the discretization; None without a mesh."""
    initial_fields: InitialFields
    sign_role: Optional[str]
    state_reads: StateReads
    drawing: Optional[Drawing]
    rows: Any
    """One of :data:`ROWS`, or ``spec -> one of ROWS`` when the form of the entry decides."""
    implicit_effects: Mapping[str, bool] = field(default_factory=dict)
    """Effects (name -> default) that an entry of a type with a free-form ``effects`` field
    has without declaring them, e.g. ``damping`` of a ``phs``: its lowerer reads them with
    :func:`phc.frontend.effects.is_on`, and a scene may switch them."""

    signal: bool = False
    """A signal block: no ports and no energy; ``phc check`` lists it as outside the
    port-Hamiltonian certificate and the rows check does not compare its rows."""

    def rows_of(self, spec) -> str:
        """Where the rows of a component with this `spec` come from (one of :data:`ROWS`)."""
        return self.rows(spec) if callable(self.rows) else self.rows

    def problems(self) -> list[str]:
        """What is wrong with the entry (empty when it can be registered)."""
        out = []
        type_field = getattr(self.spec, "model_fields", {}).get("type")
        if type_field is None or getattr(type_field.annotation, "__args__", None) != (self.name,):
            out.append(f"its spec `{getattr(self.spec, '__name__', self.spec)}` must have the field "
                       f"`type: Literal[{self.name!r}]`")
        if not callable(self.lower):
            out.append("`lower` is not callable")
        if self.default_domain is not None and self.default_domain not in DOMAINS:
            out.append(f"`default_domain` {self.default_domain!r} is not one of {', '.join(DOMAINS)}")
        if not isinstance(self.units, Units):
            out.append("`units` is not a Units")
        else:
            out.extend(f"units: {p}" for p in self.units.problems())
            spec_fields = getattr(self.spec, "model_fields", {})
            named = list(self.units.si) + [eu.field for eu in self.units.element]
            out.extend(f"units name the field `{f}`, which the spec does not have" for f in named
                       if f not in spec_fields)
        if not callable(self.cost):
            out.append("`cost` is not callable (ASSEMBLED for a component without a mesh)")
        elif self.cost is ASSEMBLED and "elements" in getattr(self.spec, "model_fields", {}):
            out.append("a spec with `elements` is discretized: its `cost` estimates the mesh (PerElement)")
        if self.spatial_order is not None and not (isinstance(self.spatial_order, int) and self.spatial_order > 0):
            out.append("`spatial_order` is a positive integer or None")
        if not isinstance(self.initial_fields, InitialFields):
            out.append("`initial_fields` is an InitialFields (NO_FIELDS for none)")
        if self.sign_role is not None and self.sign_role not in SIGN_ROLES:
            out.append(f"`sign_role` {self.sign_role!r} is not one of {', '.join(SIGN_ROLES)} or None")
        if not isinstance(self.state_reads, StateReads):
            out.append("`state_reads` is a StateReads (NO_STATE_READS for none)")
        else:
            spec_fields = getattr(self.spec, "model_fields", {})
            out.extend(f"`state_reads` names the field `{f}`, which the spec does not have"
                       for f in self.state_reads.fields if f not in spec_fields)
        if self.drawing is not None and not (isinstance(self.drawing, Drawing) and callable(self.drawing.draw)
                                             and self.drawing.stage in ("body", "attachment")):
            out.append("`drawing` is a Drawing(draw, stage='body'|'attachment') or None")
        if self.implicit_effects:
            effects_field = getattr(self.spec, "model_fields", {}).get("effects")
            if effects_field is None:
                out.append("`implicit_effects` needs a spec with an `effects` field")
            out.extend(f"`implicit_effects`: the default of `{k}` is a bool" for k, v in self.implicit_effects.items()
                       if not isinstance(v, bool))
        if not isinstance(self.signal, bool):
            out.append("`signal` is a bool")
        elif self.signal and isinstance(self.state_reads, StateReads) and not self.state_reads.fields:
            out.append("a signal block reads its input: name the field in `state_reads`")
        if not (callable(self.rows) or self.rows in ROWS):
            out.append(f"`rows` {self.rows!r} is one of {', '.join(ROWS)} (or a function of the spec to one)")
        return out


# -- the registry --------------------------------------------------------------------------

COMPONENT_TYPES: dict[str, ComponentType] = {}
"""name -> entry. Read it through :func:`get` and :func:`names` (they load the built-ins)."""
_state = {"loaded": False, "loading": False}
_LOADING = threading.RLock()


def _load_builtins() -> None:
    """Register the built-in types (once): their specs are the union written in
    :mod:`phc.spec.components`, which :func:`check_builtin_union` compares with them."""
    if _state["loaded"]:
        return
    # another thread (a Dask worker's) waits until the built-ins are in; the loading thread
    # itself re-enters through register() and passes
    with _LOADING:
        if _state["loaded"] or _state["loading"]:
            return
        _state["loading"] = True
        try:
            from phc.library.builtin import BUILTINS

            for entry in BUILTINS:
                register(entry)
        finally:
            _state["loading"] = False
        check_builtin_union()
        _state["loaded"] = True


def register(entry: ComponentType) -> ComponentType:
    """Add `entry` to the registry (after the built-ins, which load first).

    Raises
    ------
    RegistryError
        When the entry has a problem (:meth:`ComponentType.problems`) or its name is taken.
    """
    _load_builtins()
    if not isinstance(entry, ComponentType):
        raise RegistryError(f"register takes a ComponentType, not {type(entry).__name__}")
    problems = entry.problems()
    if entry.name in COMPONENT_TYPES or entry.name == "model":  # `type: model` is a nested model file
        problems.append("a type of that name is registered already")
    if problems:
        raise RegistryError(f"component type `{entry.name}`: " + "; ".join(problems))
    COMPONENT_TYPES[entry.name] = entry
    if _state["loaded"]:
        _sync_spec_union()
    return entry


def unregister(name: str) -> ComponentType:
    """Remove the type `name` (one that :func:`register` added) and return its entry."""
    _load_builtins()
    entry = COMPONENT_TYPES.pop(name)
    _sync_spec_union()
    return entry


@contextmanager
def registered(entry: ComponentType) -> Iterator[ComponentType]:
    """Register `entry` for the duration of the block (a test's own type)."""
    _load_builtins()
    register(entry)
    try:
        yield entry
    finally:
        unregister(entry.name)


def get(name: str) -> ComponentType:
    """The entry of type `name` (KeyError when there is none)."""
    _load_builtins()
    return COMPONENT_TYPES[name]


def find(name: Optional[str]) -> Optional[ComponentType]:
    """The entry of type `name`, or None (a nested model, an unknown type)."""
    _load_builtins()
    return COMPONENT_TYPES.get(name)


def names() -> list[str]:
    """The registered type names, in registration order."""
    _load_builtins()
    return list(COMPONENT_TYPES)


def _members(annotation) -> tuple:
    """The specs of ``dict[Identifier, Annotated[Union[...], ...]]``."""
    import typing

    value = typing.get_args(annotation)[1]
    return typing.get_args(typing.get_args(value)[0])


def _spec_union_members() -> tuple:
    from phc.spec.model import ModelSpec

    return _members(ModelSpec.model_fields["components"].annotation)


def _sync_spec_union() -> None:
    """Make the union model files are validated with that of the registered specs (plus
    nested models, ``type: model``): rebuild :class:`~phc.spec.ModelSpec` when they differ."""
    from typing import Annotated, Union

    from pydantic import Field

    from phc.spec.base import Identifier
    from phc.spec.components import ModelComponentSpec
    from phc.spec.model import ModelSpec

    field = ModelSpec.model_fields["components"]
    original = _original.setdefault("components", field.annotation)
    current = _spec_union_members()
    wanted = tuple(c for c in current if c is ModelComponentSpec or any(e.spec is c for e in COMPONENT_TYPES.values()))
    wanted += tuple(e.spec for e in COMPONENT_TYPES.values() if e.spec not in wanted)
    if wanted == current:
        return
    if wanted == _members(original):  # back to the union as written: the very annotation
        field.annotation = original
    else:
        field.annotation = dict[Identifier, Annotated[Union[wanted], Field(discriminator="type")]]
    ModelSpec.model_rebuild(force=True)


_original: dict = {}
"""The annotation of ModelSpec.components before the registry first changed it."""


def check_builtin_union() -> None:
    """The built-in entries and the union of :mod:`phc.spec.components` name the same specs.

    Raises
    ------
    RegistryError
        Naming the specs with no entry, or the entries whose spec is not in the union.
    """
    from phc.spec.components import ModelComponentSpec

    members = {c for c in _spec_union_members() if c is not ModelComponentSpec}
    specs = {e.spec for e in COMPONENT_TYPES.values()}
    missing = sorted(c.__name__ for c in members - specs)
    extra = sorted(c.__name__ for c in specs - members)
    if missing or extra:
        raise RegistryError("phc.spec.components.ComponentSpec and the registry differ: "
                            + "; ".join([f"no registry entry for {', '.join(missing)}"] * bool(missing)
                                        + [f"not in the union: {', '.join(extra)}"] * bool(extra)))


# -- derived tables ------------------------------------------------------------------------

class FieldView(MutableMapping):
    """A per-type table derived from the registry: type name -> ``entry.<attribute>``, or
    ``derive(entry)`` (types where it is None are left out). Read when used, so it always
    shows the registry as it is. Setting an item replaces that field of an existing
    entry (a test double for one type's lowerer: ``monkeypatch.setitem(LOWERERS, …)``)."""

    def __init__(self, attribute: str, derive: Optional[Callable[[ComponentType], Any]] = None) -> None:
        self.attribute = attribute
        self.derive = derive

    def _value(self, entry: ComponentType):
        return self.derive(entry) if self.derive is not None else getattr(entry, self.attribute)

    def __getitem__(self, name: str):
        entry = find(name)
        value = None if entry is None else self._value(entry)
        if value is None:
            raise KeyError(name)
        return value

    def __contains__(self, name) -> bool:
        # without the KeyError of Mapping's: asked once per component (phc.frontend.elaborate)
        entry = find(name) if isinstance(name, str) else None
        return entry is not None and self._value(entry) is not None

    def __iter__(self) -> Iterator[str]:
        return (name for name in names() if self._value(COMPONENT_TYPES[name]) is not None)

    def __len__(self) -> int:
        return sum(1 for _ in self)

    def __setitem__(self, name: str, value) -> None:
        if self.derive is not None:
            raise TypeError(f"{self.attribute}: a derived table; change the registry entry")
        COMPONENT_TYPES[name] = replace(get(name), **{self.attribute: value})

    def __delitem__(self, name: str) -> None:
        raise TypeError("remove a type with phc.library.registry.unregister")

    def __repr__(self) -> str:
        return f"FieldView({self.attribute!r}: {dict(self)!r})"

