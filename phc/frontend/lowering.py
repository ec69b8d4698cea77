"""Lowering one component: a pure function of its spec and a read-only context.

:func:`lower` runs a component type's lowerer (the ``lower`` field of its registry entry,
:mod:`phc.library.registry`) and returns what it produced as a frozen :class:`ComponentLowering`:
the component's variables, rows (residual rows, definitions of port variables, sparse
linear blocks with rows counted from the component's first row), ports, description,
energy and dissipation terms, invariants, initial relations, outputs, compile-time
parameters and diagnostics. The elaborate pass (:mod:`phc.frontend.elaborate`) folds the lowerings
of all components, in order, into its :class:`~phc.frontend.elaborate.Elaboration`; nothing a
lowerer does reaches another component except through that fold.

A lowerer is called as ``lower_x(b, ctx, name, spec, path)``: `b` is a fresh
:class:`Recorder` of this component only (it writes its variables, rows, ports, ... there,
and parses expressions through it), `ctx` the :class:`~phc.frontend.reporter.FileContext` of the
file the component is written in (its source map and parameter symbols). What the
lowerer may read of the rest of the model — the parameters' default values, the
variables of the components lowered before it, the ports declared so far, the units of
parameters — is the read-only :class:`LoweringContext` ``b.context``.
"""

from __future__ import annotations

import dataclasses
import itertools
from collections.abc import Sequence as SequenceABC
from dataclasses import dataclass, field
from types import MappingProxyType
from typing import Any, Callable, Mapping, Optional, Sequence

import pydantic_core
import sympy as sp

from phc.ir.alike import unevaluated_pow
from phc.ir.dae import Equation, Invariant, LinearBlock, Parameter, Variable, real_symbol
from phc.diagnostics import Diagnostic
from phc.frontend.reporter import Port, Reporter
from phc.frontend.files import FileAccess
from phc.frontend.source_map import SourceSpan


class ReadOnlySequence(SequenceABC):
    """A read-only view of a list (no copy): what a lowerer sees of a list the elaborate
    pass extends between lowerings."""

    __slots__ = ("_items",)

    def __init__(self, items: Sequence) -> None:
        self._items = items

    def __getitem__(self, index):
        return self._items[index]

    def __len__(self) -> int:
        return len(self._items)

    def __iter__(self):
        return iter(self._items)


@dataclass(frozen=True)
class LoweringContext:
    """What a lowerer may read of the model beyond its own spec: read-only views of the
    elaborate pass's state at the time the component is lowered."""

    default_values: Mapping
    """Parameter symbol -> its default as a sympy Float (the parameters known so far)."""
    variables: Sequence[Variable]
    """The variables of the components lowered before this one (a modulation reads their states)."""
    ports: Mapping[str, Port]
    """The ports declared before this one, by full name."""
    unset_parameters: frozenset
    """Parameters whose value had an error (their default 0 means nothing)."""
    units: Mapping = field(default_factory=lambda: MappingProxyType({}))
    """Parameter symbol -> its unit (:mod:`phc.frontend.units`)."""
    unit_text: Mapping = field(default_factory=lambda: MappingProxyType({}))
    """Parameter symbol -> its unit as written."""
    override_note: str = ""
    """The scene's parameter overrides, named in refusals of their values."""
    files: Optional[FileAccess] = None
    """What referenced files (tables, matrices) are read through."""
    signals: Mapping = field(default_factory=lambda: MappingProxyType({}))
    """Output name (``ctrl.y``) -> its expression in states and `t`: the outputs of the
    signal blocks lowered before this one (:mod:`phc.library.signal`)."""


@dataclass(frozen=True, eq=False)
class ComponentLowering:
    """What lowering one component produced (:func:`lower`); every collection is a tuple.

    Row indices of `linear_blocks` count from the component's first row in `equations`;
    the elaborate pass shifts them when it appends the rows to the model's."""

    component: str
    variables: tuple[Variable, ...]
    equations: tuple[Equation, ...]
    linear_blocks: tuple[LinearBlock, ...]
    definitions: tuple[tuple[sp.Symbol, sp.Expr], ...]
    """Port variables given an explicit value, in the order defined (a later one replaces an earlier)."""
    hand_written: frozenset
    """Components with a row not derived from their description (:func:`phc.library.dirac.emit`)."""
    ports: tuple[Port, ...]
    parameters: tuple[Parameter, ...]
    """Parameters the component declares itself (a ``phs`` entry's local `parameters`)."""
    descriptions: tuple
    hamiltonian: tuple
    dissipation: tuple
    source_power: tuple
    supplied: tuple
    """Declared controlled sources (a ``phs`` resistive port with ``kind: source``), as
    (component, port, power the model delivers to it, source span); their power is in `source_power`."""
    quadratic_energy: tuple
    quadratic_dissipation: tuple
    invariants: tuple[Invariant, ...]
    velocity_invariants: tuple[Invariant, ...]
    resistive_laws: tuple
    rigid_constraints: tuple
    extra_outputs: tuple[tuple[str, sp.Expr], ...]
    signals: tuple[tuple[str, sp.Expr], ...]
    """Outputs of a signal block that later components may read (:attr:`LoweringContext.signals`)."""
    initial_relations: tuple
    position_maps: tuple
    compile_time_parameters: frozenset
    initial_fields: tuple
    """(component, :class:`phc.ir.initial_fields.FieldSet`) pairs."""
    unavailable: tuple[tuple[str, str], ...]
    """(name, why): outputs an effect that is off leaves out."""
    left_out: tuple[tuple[str, str, str], ...]
    failed: frozenset
    """Components the lowerer itself marked as failed (besides any with an error)."""
    diagnostics: tuple[Diagnostic, ...]
    field_dims: tuple
    """((source map id, field path), [(path, dimension)]) of the expressions parsed
    (:class:`~phc.frontend.reporter.Reporter`), read by the elaborate pass's check of the
    fields' units."""

    @property
    def errors(self) -> int:
        """How many errors lowering found."""
        return sum(1 for d in self.diagnostics if d.severity == "error")


class Recorder(Reporter):
    """Where one component's lowerer writes: its own variables, rows, ports and terms, and
    its own diagnostics (the expression helpers of :class:`~phc.frontend.reporter.Reporter` report
    here). :meth:`freeze` turns it into the :class:`ComponentLowering`. Nothing here is
    shared with another component; the model so far is read through :attr:`context`."""

    def __init__(self, component: str, context: LoweringContext) -> None:
        super().__init__(context.files)
        self.component = component
        self.context = context
        self.units = context.units
        self.unit_text = context.unit_text
        self.override_note = context.override_note
        self.unset_parameters = context.unset_parameters
        self.variables: list[Variable] = []
        self.equations: list[Equation] = []
        self.linear_blocks: list[LinearBlock] = []
        self.definitions: dict[sp.Symbol, sp.Expr] = {}
        self.hand_written: set[str] = set()
        self.ports: dict[str, Port] = {}
        self.parameters: dict[str, Parameter] = {}
        self.dirac: list = []
        self.hamiltonian: list[sp.Expr] = []
        self.dissipation: list = []  # (component, P_diss, source span)
        self.source_power: list[sp.Expr] = []
        self.supplied: list = []  # (component, port, P delivered to it, source span)
        self.quadratic_energy: list = []
        self.quadratic_dissipation: list = []
        self.invariants: list[Invariant] = []
        self.velocity_invariants: list[Invariant] = []
        self.resistive_laws: list = []
        self.rigid_constraints: list = []
        self.extra_outputs: dict[str, sp.Expr] = {}
        self.signals: dict[str, sp.Expr] = {}
        self.initial_relations: list = []
        self.position_maps: list = []
        self.compile_time_parameters: set = set()
        self.initial_fields: dict = {}  # component -> phc.ir.initial_fields.FieldSet
        self.unavailable: dict[str, str] = {}
        self.left_out: list[tuple[str, str, str]] = []
        self.failed: set[str] = set()

    def leave_out(self, component: str, what: str, why: str) -> None:
        """Record a part of a component that is not compiled (reported to the user)."""
        self.left_out.append((component, what, why))

    # -- reading the model so far ------------------------------------------------------
    def default_values(self) -> Mapping:
        """Parameter symbol → its default as a sympy Float (xreplace-safe): the model's
        parameters and those this component declared so far. Read-only; without parameters
        of its own the model's mapping itself (a copy per call, for every component, was
        quadratic in the number of parameters)."""
        if not self.parameters:
            return self.context.default_values
        values = dict(self.context.default_values)
        for p in self.parameters.values():
            values[p.symbol] = sp.Float(p.default)
        return values

    def known_variables(self):
        """The variables of the components lowered before this one, then this one's."""
        return itertools.chain(self.context.variables, self.variables)

    # -- variables ---------------------------------------------------------------------
    def add_state(self, component: str, local: str, span=None) -> tuple[sp.Symbol, sp.Symbol]:
        """A state ``component.local`` and its rate ``der(component.local)``."""
        name = f"{component}.{local}"
        sym = real_symbol(name)  # sympy's Symbol(name, real=True), made in bulk
        dsym = real_symbol(f"der({name})")
        self.variables.append(Variable(name, sym, True, "state", component, dsym, span))
        return sym, dsym

    def add_algebraic(self, component: str, local: str, role: str, span=None) -> sp.Symbol:
        """An algebraic variable ``component.local`` of `role` (flow, effort, multiplier, ...)."""
        name = f"{component}.{local}"
        sym = real_symbol(name)
        self.variables.append(Variable(name, sym, False, role, component, None, span))
        return sym

    # -- rows --------------------------------------------------------------------------
    def add_equation(self, expr: sp.Expr, component: str, kind: str, label: str, span=None, *,
                     derived: bool = False) -> None:
        """A residual row ``expr = 0`` of `component`. `derived`: :func:`phc.library.dirac.emit`
        derived it from the component's description; any other row makes the component's
        rows hand-written (compared with its description when compiling, :mod:`phc.checks.rows`)."""
        if not derived:
            self.hand_written.add(component)
        expr = expr if isinstance(expr, sp.Basic) else sp.Integer(expr)
        self.equations.append(Equation(expr, f"{component}.{label}", kind, component, span))

    def add_linear_rows(self, component: str, label: str, n_rows: int, terms, span=None, *,
                        derived: bool = False) -> list[int]:
        """Append `n_rows` rows whose residual is ``Σ terms`` (sparse) plus a sympy part (0 for now).

        Returns the row indices (within this component's rows) so that the caller can add
        sympy couplings with :meth:`add_to_row` (boundary ports of a discretized PDE).
        `derived`: as for :meth:`add_equation` (:func:`phc.library.dirac.emit_sparse`).
        """
        if not derived:
            self.hand_written.add(component)
        start = len(self.equations)
        for i in range(n_rows):
            self.equations.append(Equation(sp.Integer(0), f"{component}.{label}[{i}]", "linear", component, span))
        rows = range(start, start + n_rows)
        self.linear_blocks.append(LinearBlock(f"{component}.{label}", component, rows, tuple(terms), span))
        return list(rows)

    def add_to_row(self, row: int, expr: sp.Expr, *, derived: bool = False) -> None:
        """Add `expr` to the residual of this component's row `row` (from :meth:`add_linear_rows`)."""
        eq = self.equations[row]
        if not derived:
            self.hand_written.add(eq.component)
        self.equations[row] = Equation(eq.expr + expr, eq.label, eq.kind, eq.component, eq.span)

    def define(self, sym: sp.Symbol, expr: sp.Expr, *, derived: bool = False) -> None:
        """Give a port variable an explicit value (an output of its component). `derived`:
        as for :meth:`add_equation`."""
        self.definitions[sym] = expr
        if not derived:
            self.hand_written.add(self.component)

    # -- ports and invariants ----------------------------------------------------------
    def add_port(self, component: str, local: str, domain: str, dimension: int, frame=None,
                 span=None, position=None) -> Port:
        """A power port ``component.local`` with its flow and effort variables."""
        full = f"{component}.{local}"
        if full in self.ports or full in self.context.ports:
            self.diags.append(Diagnostic("PHC-E207", f"component `{component}` declares port `{local}` twice",
                                         span=span, hint="give each port its own name", path=full))
        if dimension == 1:
            f = [self.add_algebraic(component, f"{local}.f", "flow", span)]
            e = [self.add_algebraic(component, f"{local}.e", "effort", span)]
        else:
            f = [self.add_algebraic(component, f"{local}.f[{k}]", "flow", span) for k in range(dimension)]
            e = [self.add_algebraic(component, f"{local}.e[{k}]", "effort", span) for k in range(dimension)]
        port = Port(full, component, domain, dimension, frame, f, e, position, span)
        self.ports[full] = port
        return port

    def add_invariant(self, expr: sp.Expr, component: str, label: str, span=None, velocity=False) -> None:
        """A position (or, with `velocity`, velocity) invariant ``expr = 0`` of `component`."""
        inv = Invariant(f"{component}.{label}", expr, component, span)
        (self.velocity_invariants if velocity else self.invariants).append(inv)

    # -- the result --------------------------------------------------------------------
    def freeze(self) -> ComponentLowering:
        """What was recorded, as an immutable :class:`ComponentLowering`."""
        return ComponentLowering(
            component=self.component, variables=tuple(self.variables), equations=tuple(self.equations),
            linear_blocks=tuple(self.linear_blocks), definitions=tuple(self.definitions.items()),
            hand_written=frozenset(self.hand_written), ports=tuple(self.ports.values()),
            parameters=tuple(self.parameters.values()), descriptions=tuple(self.dirac),
            hamiltonian=tuple(self.hamiltonian), dissipation=tuple(self.dissipation),
            source_power=tuple(self.source_power), supplied=tuple(self.supplied),
            quadratic_energy=tuple(self.quadratic_energy),
            quadratic_dissipation=tuple(self.quadratic_dissipation), invariants=tuple(self.invariants),
            velocity_invariants=tuple(self.velocity_invariants), resistive_laws=tuple(self.resistive_laws),
            rigid_constraints=tuple(self.rigid_constraints), extra_outputs=tuple(self.extra_outputs.items()),
            signals=tuple(self.signals.items()),
            initial_relations=tuple(self.initial_relations), position_maps=tuple(self.position_maps),
            compile_time_parameters=frozenset(self.compile_time_parameters),
            initial_fields=tuple(self.initial_fields.items()), unavailable=tuple(self.unavailable.items()),
            left_out=tuple(self.left_out), failed=frozenset(self.failed), diagnostics=tuple(self.diags),
            field_dims=tuple((key, tuple(entries)) for key, entries in self.field_dims.items()))


def lower(lowerer: Callable, context: LoweringContext, ctx, name: str, spec: Any, path: Sequence
          ) -> ComponentLowering:
    """Lower one component: run `lowerer` (``lower_x(b, ctx, name, spec, path)``) on a fresh
    :class:`Recorder` and return what it recorded. `ctx` is the
    :class:`~phc.frontend.reporter.FileContext` the component is written in, `path` its entry there."""
    recorder = Recorder(name, context)
    lowerer(recorder, ctx, name, spec, path)
    return recorder.freeze()


# ---------------------------------------------------------------------------------------
# identical components: one lowering, renamed (issue 38)

SHAREABLE_TYPES = frozenset({"mass", "inductor", "spring", "capacitor", "damper", "resistor"})
"""Component types whose lowering depends on nothing but their spec, the parameters and
their own name (they read no other component): two entries of such a type with the same
fields are lowered once; the others' lowerings are the first one's with the names changed
(:class:`SharedLowerings`)."""

_NAME_PREFIXES = ("", "der(", "cert:")
"""How a component's own names start: ``k1.x``, ``der(k1.x)``, ``cert:k1.x``."""


class Unshareable(Exception):
    """A lowering that cannot be renamed faithfully (something in it is not understood)."""


_REAL = sp.Symbol("x", real=True).assumptions0


def _place_of(path: tuple, old: str) -> Optional[int]:
    """The one index of `path` holding `old` (None: none); :class:`Unshareable` for two."""
    at = [i for i, e in enumerate(path) if e == old]
    if len(at) > 1:
        raise Unshareable(f"path {path} names `{old}` twice")
    return at[0] if at else None


class _Template:
    """The lowering of component `old`, compiled once into steps (and those into one
    function, :meth:`_compile_function`) that build the same value for another component's
    name: every name of `old` (its variables, ports,
    rows' labels, paths: ``k1``, ``k1.x``, ``der(k1.x)``, ``cert:k1.x``) becomes the other
    one's, every source span the other one's span at the same path, and sympy sums and
    products are rebuilt from their renamed arguments in their order (``_from_args``, as
    sympy itself builds them after sorting) — sympy's canonical form as long as renaming
    keeps the order of all symbol names, which :meth:`build` checks. Whatever holds no name
    and no span is shared as it is. Raises :class:`Unshareable` for anything not understood."""

    def __init__(self, old: str, lowering, located) -> None:
        self.old = old
        self.prefixes = [p + old + "." for p in _NAME_PREFIXES]
        self.located = [p for p, _ in located]
        # each located path with the place of `old` in it (the component's own entry), None
        # where it has none: :meth:`SharedLowerings._instance` puts the new name there
        self.renamed_paths = [(p, _place_of(p, old)) for p in self.located]
        self.span_slot = {}
        for i, (_, span) in enumerate(located):
            self.span_slot.setdefault(id(span), i)
        self.values: list = []  # slot -> the template's value (constants stay)
        self.steps: list = []  # (slot, kind, data): computed in this order
        self.symbols: list = []  # (name as in the template, (prefix index, rest) or None)
        self.memo: dict[int, int] = {}
        self._function: Optional[Callable] = None  # :meth:`_compile_function`, made by the first :meth:`build`
        self._names: list = []  # the names renamed by each build: (prefix index, rest)
        self._computed: set[int] = set()  # slots built by a step
        self.root = self._slot(lowering)
        self.same_span = [(i, self.span_slot[id(span)]) for i, (_, span) in enumerate(located)
                          if self.span_slot[id(span)] != i]  # one span of the template at two paths
        # names as sorted in the template; :meth:`build` checks the new names keep this order
        self.symbols.sort(key=lambda item: item[0])
        # one entry per name: two equal symbols that are distinct objects (made on both sides
        # of a clear of sympy's cache, which tests/test_component_scaling.py does) are one
        # name, not a reordering; counted twice, every instance was refused
        self.symbols = [item for i, item in enumerate(self.symbols) if i == 0 or item[0] != self.symbols[i - 1][0]]

    def _rename(self, s: str):
        """(prefix index, rest) of one of `old`'s names, -1 for `old` itself, None otherwise."""
        if s == self.old:
            return (-1, "")
        for i, pre in enumerate(self.prefixes):
            if s.startswith(pre):
                return (i, s[len(pre):])
        if self.old in s:  # the name inside some other text: not something to guess at
            raise Unshareable(f"`{s}` holds `{self.old}`")
        return None

    def _const(self, v) -> int:
        self.values.append(v)
        return len(self.values) - 1

    def _step(self, v, kind, data) -> int:
        slot = self._const(v)
        self.steps.append((slot, kind, data))
        self._computed.add(slot)
        return slot

    def _slot(self, v) -> int:
        """The slot of `v` (added with the steps that build it, children first)."""
        hit = self.memo.get(id(v))
        if hit is not None:
            return hit
        slot = self._new_slot(v)
        self.memo[id(v)] = slot
        return slot

    def _new_slot(self, v) -> int:
        t = type(v)
        if v is None or t in (bool, int, float, range):  # a range: a sparse block's rows
            return self._const(v)
        if t is str:
            renamed = self._rename(v)
            return self._const(v) if renamed is None else self._step(v, "str", renamed)
        if isinstance(v, sp.Basic):
            if v.is_Symbol:
                if t is not sp.Symbol or v.assumptions0 != _REAL:
                    raise Unshareable(f"symbol {v!r} ({t.__name__}, {v.assumptions0})")
                renamed = self._rename(v.name)
                self.symbols.append((v.name, renamed))
                return self._const(v) if renamed is None else self._step(v, "sym", renamed)
            if not v.args:
                return self._const(v)
            args = [self._slot(a) for a in v.args]
            if not any(a in self._computed for a in args):
                return self._const(v)
            # sums and products from their arguments in order (see above); a power as it is
            # (its evaluation changes nothing of a canonical power of a renamed base); the rest
            # evaluated as sympy's ``xreplace`` does
            kind = "assoc" if t is sp.Add or t is sp.Mul else "pow" if t is sp.Pow else "func"
            return self._step(v, kind, (t if kind != "func" else v.func, args, v.is_commutative))
        if t is SourceSpan:
            try:
                return self._step(v, "span", self.span_slot[id(v)])
            except KeyError:
                raise Unshareable(f"span {v} not located by the lowering") from None
        if t is tuple or t is list or t is frozenset or t is set:
            items = [self._slot(x) for x in v]
            if not any(a in self._computed for a in items):
                return self._const(v)
            return self._step(v, "seq", (t, items))
        if t is dict:
            items = [(self._slot(k), self._slot(x)) for k, x in v.items()]
            if not any(a in self._computed or b in self._computed for a, b in items):
                return self._const(v)
            return self._step(v, "dict", items)
        if dataclasses.is_dataclass(v) and not isinstance(v, type):
            fields = dataclasses.fields(v)
            if any(not f.init for f in fields):
                raise Unshareable(f"{t.__name__} has fields set after construction")
            items = [(f.name, self._slot(getattr(v, f.name))) for f in fields]
            if not any(a in self._computed for _, a in items):
                return self._const(v)
            if hasattr(t, "__post_init__") or not (hasattr(v, "__dict__") or hasattr(t, "__slots__")):
                # (a slotted class's instances are their fields as well: made by its __init__)
                return self._step(v, "dataclass", (t, items))
            # every field given and nothing run after __init__: the instance is its fields,
            # set without the frozen class's __init__ (object.__setattr__ per field)
            return self._step(v, "fields", (t, tuple(f for f, _ in items), [a for _, a in items]))
        if t.__module__ == "phc.frontend.si_units":  # a dimension (field_dims): no names in it, never changed
            return self._const(v)
        raise Unshareable(f"a value of type {t.__name__}")

    def _compile_function(self) -> Callable:
        """:attr:`steps` as one Python function ``build(names, spans)``, straight-line code with
        one assignment per step (issue 38: the steps run ~70 times per component of a chain;
        as a loop testing each step's kind they were two thirds of the instances' cost). The
        text is phc's own, made here from the steps: local names ``v<slot>`` and indices into
        the lists it is given (the template's values ``C``, the classes and constants ``K``,
        the new names, the spans), never a name, value or text of the model. Sets
        :attr:`_names`, the renamed names in the order ``names`` holds them."""
        index: dict = {}  # a renamed name's (prefix index, rest) -> its place in `names`
        extra: list = []  # K: classes, field names, flags the code refers to
        extra_at: dict = {}
        computed: set = set()

        def obj(x) -> str:
            key = (type(x), x) if isinstance(x, (bool, tuple)) else id(x)
            if key not in extra_at:
                extra_at[key] = len(extra)
                extra.append(x)
            return f"K[{extra_at[key]}]"

        def ref(slot: int) -> str:
            return f"v{slot}" if slot in computed else f"C[{slot}]"

        def items(slots) -> str:
            refs = [ref(a) for a in slots]
            return "()" if not refs else f"({refs[0]},)" if len(refs) == 1 else f"({', '.join(refs)})"

        lines = ["def build(names, spans):"]
        for slot, kind, data in self.steps:
            if kind == "seq":
                t, args = data
                expr = items(args) if t is tuple else f"[{', '.join(ref(a) for a in args)}]" if t is list \
                    else f"{obj(t)}({items(args)})"
            elif kind == "fields":  # every field given, nothing run after __init__: set them
                t, names, args = data
                if t.__dictoffset__ == 0:  # a slotted class (Variable, Equation): its __init__, by position
                    lines.append(f"    v{slot} = {obj(t)}{items(args)}")
                else:
                    lines.append(f"    v{slot} = new({obj(t)})")
                    lines.append(f"    v{slot}.__dict__.update(zip({obj(tuple(names))}, {items(args)}))")
                computed.add(slot)
                continue
            elif kind == "dataclass":
                t, fields = data
                expr = f"{obj(t)}(**dict(zip({obj(tuple(f for f, _ in fields))}, {items([a for _, a in fields])})))"
            elif kind == "sym":
                expr = f"symbol(names[{index.setdefault(data, len(index))}])"
            elif kind == "str":
                expr = f"names[{index.setdefault(data, len(index))}]"
            elif kind == "span":
                expr = f"spans[{int(data)}]"
            elif kind == "assoc":  # sums and products from their arguments in order (see above)
                cls, args, comm = data
                expr = f"{obj(cls)}._from_args({items(args)}, {obj(comm)})"
            elif kind == "pow":
                _, (base, exp), comm = data
                expr = f"upow({ref(base)}, {ref(exp)}, {obj(comm)})"
            elif kind == "func":
                func, args, _ = data
                expr = f"{obj(func)}(*{items(args)})"
            else:  # dict
                expr = "{" + ", ".join(f"{ref(a)}: {ref(b)}" for a, b in data) + "}"
            lines.append(f"    v{slot} = {expr}")
            computed.add(slot)
        lines.append(f"    return {ref(self.root)}")
        namespace = {"C": self.values, "K": extra, "new": object.__new__, "symbol": real_symbol,
                     "upow": unevaluated_pow}
        exec(compile("\n".join(lines) + "\n",  # safe: phc's own text from slots and indices, no model text
                     f"<phc.frontend.lowering template of {len(self.steps)} steps>",
                     "exec", dont_inherit=True), namespace)
        self._names = list(index)
        return namespace["build"]

    def build(self, new: str, spans: Sequence):
        """The lowering for component `new` (`spans`: its spans at :attr:`located`), or None
        when renaming would change the order of the names (then sympy's order differs)."""
        pres = [p + new + "." for p in _NAME_PREFIXES]
        if self._function is None:
            self._function = self._compile_function()
            place = {r: i for i, r in enumerate(self._names)}
            # the symbols' names in the template's order: as written, or the place of the new one
            self._order = [(name, None if r is None else place[r]) for name, r in self.symbols]
        names = [new if r[0] < 0 else pres[r[0]] + r[1] for r in self._names]
        last = None
        for name, at in self._order:
            if at is not None:
                name = names[at]
            if last is not None and name <= last:
                return None
            last = name
        return self._function(names, spans)


MAX_TEMPLATES = 4
"""Templates kept per kind of component: a component that none of them can give (renaming
would reorder its names among the parameters', ``v3.x`` after ``k`` where the template's
``h1.x`` is before it) is lowered by its lowerer and kept as one more, up to this many
(the grid of bench_components.py lowered every vertical spring on its own: 13 of its 26
CPU seconds of validate)."""


class SharedLowerings:
    """Lowerings of identical components made once (issue 38): the elaborate pass asks
    :meth:`lookup` for a component's lowering before running its lowerer; the first of a
    kind (same type, same fields, same file and entry, no diagnostics) is kept as a template
    (one more for a component no template of its kind gives, up to :data:`MAX_TEMPLATES`),
    the next ones are a template renamed (:class:`_Template`) — the same
    variables, rows, ports, description and terms, equal term by term to what the lowerer
    gives, at a fraction of the cost of sympy arithmetic. Whenever that cannot be shown
    (a name outside the template's own, a span not found, renaming that reorders names, a
    port already declared) the component is lowered as usual."""

    def __init__(self) -> None:
        self.templates: dict = {}  # key -> its templates (at most MAX_TEMPLATES), or None: never shared

    @staticmethod
    def key(ctx, name: str, spec, path, n_defaults: int, n_unset: int):
        """The kind of a component, or None when it is never shared."""
        if getattr(spec, "type", None) not in SHAREABLE_TYPES or not path or path[-1] != name:
            return None
        try:  # pydantic's own serializer: a tenth of the cost of model_dump and json.dumps
            fields = spec.model_dump_json()
        except pydantic_core.PydanticSerializationError:  # a value JSON does not know: written as text
            import json

            fields = json.dumps(spec.model_dump(mode="json"), sort_keys=True, default=str)
        return (spec.type, fields, id(ctx), tuple(path[:-1]), n_defaults, n_unset)

    def lower(self, key, lowerer: Callable, context: LoweringContext, ctx, name: str, spec: Any,
              path: Sequence) -> ComponentLowering:
        """:func:`lower`, shared by `key` (from :meth:`key`; None: lowered as usual)."""
        if key is None:
            return lower(lowerer, context, ctx, name, spec, path)
        templates = self.templates.get(key)
        if templates is None and key in self.templates:  # a kind found unshareable
            return lower(lowerer, context, ctx, name, spec, path)
        for template in templates or ():
            out = self._instance(template, context, ctx, name)
            if out is not None:
                return out
        if templates is not None and len(templates) >= MAX_TEMPLATES:
            return lower(lowerer, context, ctx, name, spec, path)
        smap = ctx.smap
        located: list = []

        def locate(p, _locate=type(smap).locate):
            span = _locate(smap, p)
            located.append((p, span))
            return span

        smap.locate = locate  # what the lowerer locates: the spans to give each instance
        try:
            lowering = lower(lowerer, context, ctx, name, spec, path)
        finally:
            del smap.locate
        if templates is None:
            self.templates[key] = None
        if not lowering.diagnostics and not lowering.failed and all(type(p) is tuple for p, _ in located):
            try:
                template = _Template(name, lowering, located)
            except Unshareable:
                return lowering
            # a further template of a kind whose templates all refused this component (its
            # name sorts elsewhere among the parameters': `v1` and `h1` springs beside `k`)
            self.templates[key] = [*(templates or ()), template]
        return lowering

    @staticmethod
    def _instance(template: _Template, context: LoweringContext, ctx, name: str) -> Optional[ComponentLowering]:
        locate = ctx.smap.locate
        spans = [locate(p if at is None else (*p[:at], name, *p[at + 1:])) for p, at in template.renamed_paths]
        if any(spans[i] != spans[j] for i, j in template.same_span):
            return None  # one span of the template is two of this component
        out = template.build(name, spans)
        if out is None or any(port.name in context.ports for port in out.ports):
            return None  # renaming reorders names, or a port declared twice: the lowerer decides
        return out


__all__ = ["ComponentLowering", "LoweringContext", "ReadOnlySequence", "Recorder", "SharedLowerings", "lower"]
