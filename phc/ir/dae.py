"""The flat relation system every model is lowered to (pipeline stage "assemble").

A :class:`Dae` is ``F(t, y, ẏ, p) = 0``: variables (differential states and algebraic
variables), equations tagged with their origin, the Hamiltonian, the dissipated and
port powers for the energy balance (the paper's Remark 3 "Energy balance"), and the position
invariants that the stabilized formulation keeps. It holds sympy expressions of small
nonlinear parts only; it is frozen once built.
"""

from __future__ import annotations

import bisect
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any, Optional

import sympy as sp

from phc.codegen.description import freeze, thaw
from phc.frontend.source import SourceSpan

if TYPE_CHECKING:  # the annotations only: a model of lumped components never loads scipy to be validated
    import scipy.sparse as sps

T = sp.Symbol("t", real=True)
"""The time symbol shared by all expressions."""

STORED_ENERGY = sp.Symbol("<H>", real=True)
"""`H` in an output of a model with distributed components: the total stored energy, the
value of the generated module's ``hamiltonian`` (the lumped parts' H plus the sparse quadratic
energies :attr:`Dae.quadratic_energy`). The generated ``outputs`` evaluates it once per call,
as ``hamiltonian`` does, and the output expressions refer to that value: the energy is never
written out term by term (thousands of terms for a fine mesh). Its name is no identifier a
model can write."""


def _bulk_real_symbols():
    """The maker of :func:`real_symbol`: sympy's own ``Symbol(name, real=True)`` with the
    assumptions sympy derived once for a prototype, or None when this sympy's symbols are
    not built as that expects (then every symbol is made by sympy)."""
    proto = sp.Symbol("<real>", real=True)
    slots = ("_assumptions", "_assumptions_orig", "_assumptions0")
    if type(proto) is not sp.Symbol or not all(hasattr(proto, a) for a in slots):
        return None  # pragma: no cover - another sympy
    kb, orig, canonical = (getattr(proto, a) for a in slots)
    new = sp.Expr.__new__

    def make(name: str) -> sp.Symbol:
        obj = new(sp.Symbol)
        obj.name = name
        obj._assumptions, obj._assumptions_orig, obj._assumptions0 = kb, orig, canonical
        return obj

    probe = make("<probe>")
    same = probe == sp.Symbol("<probe>", real=True) and hash(probe) == hash(sp.Symbol("<probe>", real=True))
    return make if same and probe.is_real and probe.is_positive is None else None


_MAKE_REAL = _bulk_real_symbols()


def real_symbol(name: str) -> sp.Symbol:
    """``sp.Symbol(name, real=True)``, equal to it and hashing alike, made without sympy's
    per-symbol assumption work: every symbol made here shares one deduced-facts table (a
    symbol's facts follow from its assumptions alone, here all ``real=True``), and sympy's
    symbol cache is not consulted. A mesh of 10⁵ elements has 10⁵-odd states, rates and
    efforts: sympy's constructor took about 17 µs and 0.8 KiB for each, this about 2 µs and
    0.15 KiB (``tests/test_budget.py`` counts that no mesh unknown goes through sympy's)."""
    return _MAKE_REAL(name) if _MAKE_REAL is not None else sp.Symbol(name, real=True)


def _slotted_getstate(self) -> tuple:
    return tuple(getattr(self, name) for name in self.__slots__)


def _slotted_setstate(self, state) -> None:
    for name, value in zip(self.__slots__, state):
        object.__setattr__(self, name, value)


@dataclass(frozen=True, slots=True)
class Variable:
    """One unknown of the DAE (slotted, as :class:`Equation`: a mesh of 10⁵ elements has
    about 8·10⁵ of each, and an instance's ``__dict__`` was a third of its size).

    `role` is one of: ``state``, ``velocity``, ``flow``, ``effort``, ``multiplier``,
    ``resistive``, ``energy``. Differential variables are the energy (storage) states and
    the energy-balance accumulator; every other variable is algebraic.
    """

    name: str
    symbol: sp.Symbol
    differential: bool
    role: str
    component: str
    dsymbol: Optional[sp.Symbol] = None
    span: Optional[SourceSpan] = None

    # pickled as its fields in order (Python 3.10's first releases could not unpickle a
    # frozen slotted dataclass by themselves)
    __getstate__, __setstate__ = _slotted_getstate, _slotted_setstate


@dataclass(frozen=True, slots=True)
class Equation:
    """One residual row ``expr = 0`` with its origin (component, kind, label, source)."""

    expr: sp.Expr
    label: str
    kind: str
    component: str
    span: Optional[SourceSpan] = None

    __getstate__, __setstate__ = _slotted_getstate, _slotted_setstate  # as Variable's


@dataclass(frozen=True)
class Parameter:
    """A run-time parameter. `expr` is set for derived parameters (in other parameters)."""

    name: str
    symbol: sp.Symbol
    default: float
    expr: Optional[sp.Expr] = None
    unit: Optional[str] = None
    description: Optional[str] = None
    span: Optional[SourceSpan] = None


@dataclass(frozen=True)
class Invariant:
    """A position-level relation g(x, t) = 0 that the exact flow preserves."""

    label: str
    expr: sp.Expr
    component: str
    span: Optional[SourceSpan] = None


@dataclass(frozen=True)
class InitialValue:
    """An initial value; `expr` (in parameters) is re-evaluated with run-time parameters."""

    name: str
    value: float
    guess: bool
    span: Optional[SourceSpan] = None
    expr: Optional[sp.Expr] = None


@dataclass(frozen=True, eq=False)
class LinearTerm:
    """``coeff · A · v`` with v the values (or, if `derivative`, the time derivatives) of
    `symbols`; `coeff` depends on parameters only. Large linear parts (discretized PDEs,
    FE exports) stay sparse matrices instead of sympy scalars."""

    coeff: sp.Expr
    matrix: sps.csr_matrix
    symbols: tuple[sp.Symbol, ...]
    derivative: bool = False


@dataclass(frozen=True, eq=False)
class LinearBlock:
    """Rows `rows` of the residual get ``Σ terms`` added to their sympy part. `rows` is a
    ``range`` where they are consecutive (a mesh's: no Python int per row), else a tuple;
    :func:`shifted_rows` moves them."""

    label: str
    component: str
    rows: tuple[int, ...]
    terms: tuple[LinearTerm, ...]
    span: Optional[SourceSpan] = None


def shifted_rows(rows, index) -> "range | tuple[int, ...]":
    """`rows` (of a :class:`LinearBlock`) mapped by `index` (an offset added to each, or a
    callable on a row index): a ``range`` when the images are consecutive, else a tuple."""
    if isinstance(index, int):
        if isinstance(rows, range) and rows.step == 1:
            return range(rows.start + index, rows.stop + index)
        out = tuple(index + r for r in rows)
    else:
        out = tuple(index(r) for r in rows)
    if out and out[-1] - out[0] == len(out) - 1 and all(b - a == 1 for a, b in zip(out, out[1:])):
        return range(out[0], out[-1] + 1)
    return out


@dataclass(frozen=True, eq=False)
class QuadraticForm:
    """``coeff · xᵀ A x`` over `symbols` (A symmetric, sparse): energy or dissipation."""

    coeff: sp.Expr
    matrix: sps.csr_matrix
    symbols: tuple[sp.Symbol, ...]
    component: str = ""
    span: Optional[SourceSpan] = None


@dataclass(frozen=True, eq=False)
class Storage:
    """One storage pair of a component description bound to its state: the pair's flow
    is the state's rate, ``f = ẋ``, and its effort the co-energy, ``e = ∂H/∂x``
    (`gradient`, which may use the component's own algebraic variables fixed by its
    `laws`, e.g. rigid velocities ``M(q) v = p``)."""

    flow: sp.Symbol
    effort: sp.Symbol
    state: sp.Symbol
    rate: sp.Symbol
    gradient: sp.Expr


class SymbolVector(Sequence):
    """`n` real symbols ``stem[0]``, ..., ``stem[n-1]``, made when one of them is first
    read: the flows and efforts of a sparse description's storage and resistive vectors,
    which :func:`phc.library.dirac.emit_sparse` eliminates as whole vectors (by the
    vector, never symbol by symbol), so a mesh of 10⁵ elements does not make (and keep)
    10⁵ sympy symbols per vector that no expression ever holds. It is a key by identity
    (one vector, one object); its symbols are those ``sp.Symbol(f"{stem}[{i}]", real=True)``
    would give."""

    __slots__ = ("stem", "n", "_symbols")

    def __init__(self, stem: str, n: int) -> None:
        self.stem, self.n = stem, int(n)
        self._symbols: Optional[tuple] = None

    @property
    def made(self) -> bool:
        """Whether its symbols exist (an expression may hold them only then)."""
        return self._symbols is not None

    @property
    def symbols(self) -> tuple:
        if self._symbols is None:
            self._symbols = tuple(sp.Symbol(f"{self.stem}[{i}]", real=True) for i in range(self.n))
        return self._symbols

    def __len__(self) -> int:
        return self.n

    def __getitem__(self, index):
        return self.symbols[index]

    def __iter__(self):
        return iter(self.symbols)

    def __repr__(self) -> str:
        return f"SymbolVector({self.stem!r}, {self.n})"

    __hash__ = object.__hash__
    __eq__ = object.__eq__

    def __getstate__(self):
        return (self.stem, self.n, self._symbols)

    def __setstate__(self, state) -> None:
        self.stem, self.n, self._symbols = state


class Chained(Sequence):
    """The concatenation of `parts` (symbols and :class:`SymbolVector`), read as one
    sequence of symbols without making a vector's symbols before one of them is read."""

    __slots__ = ("parts", "_starts", "_n")

    def __init__(self, parts) -> None:
        self.parts = tuple(parts)
        starts, n = [], 0
        for part in self.parts:
            starts.append(n)
            n += len(part) if isinstance(part, SymbolVector) else 1
        self._starts, self._n = starts, n

    def __len__(self) -> int:
        return self._n

    def __iter__(self):
        for part in self.parts:
            if isinstance(part, SymbolVector):
                yield from part
            else:
                yield part

    def __getitem__(self, index):
        if isinstance(index, slice):
            return tuple(self)[index]
        if index < 0:
            index += self._n
        if not 0 <= index < self._n:
            raise IndexError(index)
        k = bisect.bisect_right(self._starts, index) - 1
        part = self.parts[k]
        return part[index - self._starts[k]] if isinstance(part, SymbolVector) else part

    def __eq__(self, other):
        return isinstance(other, (Chained, tuple, list)) and len(self) == len(other) and all(
            a == b for a, b in zip(self, other))

    __hash__ = None


@dataclass(frozen=True, eq=False)
class SparseRelations:
    """`n` relations ``= 0`` of a description kept sparse (discretized PDEs, matrix
    components): relation i is ``Σ_k coeff_k (A_k v_k)_i + Σ extra_i``, each term a
    :class:`LinearTerm` over the description's symbols (flows, efforts, multipliers, port
    variables; never `derivative`: flows are symbols of their own), `extra` sympy
    expressions added to single relations as ``(i, expr)`` (boundary couplings,
    modulations). `law` marks resistive or constitutive laws (like
    :attr:`ComponentDescription.laws`); otherwise they are relations of the Dirac structure."""

    label: str
    n: int
    terms: tuple[LinearTerm, ...]
    extra: tuple[tuple[int, sp.Expr], ...] = ()
    law: bool = False
    solve: Optional[tuple[sp.Symbol, ...]] = None
    """The vector of symbols these relations are solved for (it enters as the identity,
    once): :func:`phc.library.dirac.emit` eliminates it (an internal vector) or defines it
    (port variables); None: the relations are residual rows."""


@dataclass(frozen=True, eq=False)
class StorageVector:
    """Storage pairs bound to states, as vectors (the sparse counterpart of
    :class:`Storage`): ``f = ẋ`` and ``e = ∂H/∂x = Σ gradient`` — each term a
    :class:`LinearTerm` over `states`, i.e. a quadratic energy ``H = ½ xᵀQx`` with
    ``Q = Σ coeff·A``."""

    flows: tuple[sp.Symbol, ...]
    efforts: tuple[sp.Symbol, ...]
    states: tuple[sp.Symbol, ...]
    rates: tuple[sp.Symbol, ...]
    gradient: tuple[LinearTerm, ...]


@dataclass(frozen=True, eq=False)
class ComponentDescription:
    """What one component is, in one immutable value: its ports, its Dirac structure in
    kernel form, its storage bound to its states and its Hamiltonian, its resistive and
    source laws. The equation rows compiled for the component are derived from it
    (:func:`phc.library.dirac.emit`) or, where a lowerer writes them directly, checked
    against it at sampled states (:mod:`phc.checks.rows`).

    ``relations`` are ``F f + E e + G λ = b(t)``: linear in `flows`, `efforts` and
    `multipliers` (the kernel representation of a Dirac structure, with its ∃λ, in
    T. Berger, R. Hochdahl, T. Reis, R. Seifried, "Port-Hamiltonian modelling of coupled
    rigid/flexible multibody systems", section 2); their coefficients may depend on
    `states` (modulation) and parameters, and an affine part ``b(t)`` is a source's value
    (the Dirac structure is the linear part). `ports` maps each port name to the indices of
    its flow and effort entries in `flows`/`efforts`; the other entries are the storage
    pairs (`storage`) and the resistive or environment pairs. `laws` are the remaining
    relations ``= 0`` — resistive laws between a resistive pair's flow and effort,
    constitutive relations of auxiliary variables — and may be nonlinear.

    `flows`, `efforts` and `internal` are sequences of symbols: tuples, or a :class:`Chained`
    where they hold a sparse description's vectors (:class:`SymbolVector`, whose symbols are
    made when first read).

    `complete` is False for a description that is only the projection of the structure
    onto the ports (large discretized components); such a projection carries the complete
    description it projects as `structure`, against which the rows are compared.
    """

    component: str
    kind: str
    flows: tuple[sp.Symbol, ...]
    efforts: tuple[sp.Symbol, ...]
    multipliers: tuple[sp.Symbol, ...]
    relations: tuple[sp.Expr, ...]
    ports: dict
    states: tuple[sp.Symbol, ...] = ()
    span: Optional[SourceSpan] = None
    note: str = ""
    storage: tuple[Storage, ...] = ()
    laws: tuple[sp.Expr, ...] = ()
    hamiltonian: Optional[sp.Expr] = None
    resistive: tuple[tuple[sp.Symbol, sp.Symbol], ...] = ()
    """Resistive pairs (f_R, e_R): the dissipated power is Σ f_R·e_R ≥ 0."""
    complete: bool = False
    order: tuple = ()
    """How the rows are derived (:func:`phc.library.dirac.emit`): ``(relation or law,
    index, symbol solved for or None, row kind, row label, row span or None)`` in
    declaration order."""
    internal: Optional[tuple[sp.Symbol, ...]] = None
    """The flows and efforts of the internal pairs (storage, resistive, auxiliary ones that
    :func:`phc.library.dirac.emit` eliminates); the others are port variables or variables
    of the model (a kernel-form ``phs``'s resistive ports). A :class:`DiracBuilder` always
    gives them, maybe none (a ``phs`` without states); None: a description made otherwise,
    whose every pair that is not a port's counts as internal."""
    blocks: tuple[SparseRelations, ...] = ()
    """Relations and laws kept as sparse matrices over symbol vectors (they belong to the
    description as `relations` and `laws` do)."""
    storage_vectors: tuple[StorageVector, ...] = ()
    """Storage bound to states as vectors (sparse counterpart of `storage`)."""
    structure: Optional["ComponentDescription"] = None
    """For a port projection (``kind="port_projection"``, what the Dirac and coupling
    certificate uses): the complete description it is the projection of — the
    semi-discrete pH system of a discretized PDE or matrix component, kept sparse
    (`blocks`, `storage_vectors`). :mod:`phc.checks.rows` compares the component's rows
    with it."""


DiracRelations = ComponentDescription
"""The former name (the certificate reads only the Dirac part)."""


class FieldTuples(Sequence):
    """``tuple((getattr(o, a) for a in names) for o in objects)``, made when read: a
    component's rows (:class:`ComponentRows`) as views of its :class:`Equation` and
    :class:`Variable` objects, which the DAE holds anyway, instead of a tuple of tuples per
    row (10⁵ elements: about 8·10⁵ rows and as many variables). It reads as a tuple of
    tuples: indexing, iteration, ``len``, ``==`` with one."""

    __slots__ = ("objects", "names")

    def __init__(self, objects, names: tuple[str, ...]) -> None:
        self.objects, self.names = tuple(objects), tuple(names)

    def _item(self, o) -> tuple:
        return tuple(getattr(o, a) for a in self.names)

    def __len__(self) -> int:
        return len(self.objects)

    def __getitem__(self, index):
        if isinstance(index, slice):
            return tuple(self._item(o) for o in self.objects[index])
        return self._item(self.objects[index])

    def __iter__(self):
        return (self._item(o) for o in self.objects)

    def __eq__(self, other):
        return isinstance(other, (FieldTuples, tuple, list)) and len(self) == len(other) and all(
            a == b for a, b in zip(self, other))

    __hash__ = None

    def __repr__(self) -> str:
        return repr(tuple(self))

    def __getstate__(self):
        return (self.objects, self.names)

    def __setstate__(self, state) -> None:
        self.objects, self.names = state


@dataclass(frozen=True, eq=False)
class ComponentRows:
    """The rows a lowerer emitted for one component, before assembly: residual rows
    ``expr = 0`` as ``(label, expr)``, explicit definitions ``symbol = expr`` and the component's own variables
    as ``(symbol, rate symbol or None, role)`` (each may be a :class:`FieldTuples`, a view
    of the rows' :class:`Equation` and :class:`Variable` objects). `sparse` is True when some rows have
    sparse matrix parts (:class:`LinearBlock`). `derived` is True when every row was
    derived from the component's description (:func:`phc.library.dirac.emit`); rows a
    lowerer wrote itself are compared with the description when compiling
    (:mod:`phc.checks.rows`)."""

    component: str
    equations: tuple[tuple[str, sp.Expr], ...]
    definitions: tuple[tuple[sp.Symbol, sp.Expr], ...]
    variables: tuple[tuple[sp.Symbol, Optional[sp.Symbol], str], ...]
    sparse: bool = False
    derived: bool = False


@dataclass(frozen=True)
class PortInfo:
    name: str
    component: str
    domain: str
    dimension: int
    frame: Optional[str]
    span: Optional[SourceSpan] = None


@dataclass(frozen=True)
class Topology:
    """Components, ports and connections as written (after nesting is flattened)."""

    components: tuple[tuple[str, str, Optional[SourceSpan]], ...]
    ports: tuple[PortInfo, ...]
    connections: tuple[tuple[str, str, str, Optional[SourceSpan]], ...]
    exposed: tuple[tuple[str, str], ...]
    dirac: tuple[ComponentDescription, ...] = ()
    rows: tuple[ComponentRows, ...] = ()
    """Each component's rows as its lowerer emitted them (before assembly)."""
    specs: dict = field(default_factory=dict)
    """Full name -> the component's spec as lowered (scene overrides and effects applied)."""
    rigid_constraints: tuple = ()
    resistive_laws: tuple = ()
    parameter_defaults: dict = field(default_factory=dict)
    initial: dict = field(default_factory=dict)
    wires: frozenset = frozenset()
    """The labels of the connections joined as wires, ``e_x = e_y``, ``f_x = −f_y`` (a
    terminal joined to a port that reads power-in, :mod:`phc.ir.wires`); the others are bonds,
    ``f_x = f_y``, ``e_x = −e_y``."""


class TermSum:
    """``sp.Add(*terms)``, built when first needed: a :attr:`Dae.hamiltonian` given as a
    TermSum is summed on its first read (issue 38: sympy sorts the 10⁴ terms of a chain of
    10⁴ components into its canonical order, 0.25 CPU seconds that ``phc validate`` does not
    need; compiling reads the sum, and pays the same as before)."""

    __slots__ = ("terms",)

    def __init__(self, terms) -> None:
        self.terms = tuple(terms)

    def build(self) -> sp.Expr:
        return sp.Add(*self.terms)

    def unevaluated(self) -> sp.Expr:
        """The sum as written, not canonicalized (for walks that only read its terms: their
        units, whether they hold the time); a number or a single term as it is."""
        return sp.Add(*self.terms, evaluate=False)


class _SumOnRead:
    """The data descriptor of :attr:`Dae.hamiltonian`: a :class:`TermSum` stored in the
    instance is replaced by its sum when the attribute is first read (also by
    ``dataclasses.replace``, ``==`` and pickling, which read it)."""

    def __init__(self, name: str) -> None:
        self.name = name

    def __get__(self, obj, owner=None):
        if obj is None:
            return self
        value = obj.__dict__[self.name]
        if type(value) is TermSum:
            value = obj.__dict__[self.name] = value.build()
        return value

    def __set__(self, obj, value) -> None:
        obj.__dict__[self.name] = value


@dataclass(frozen=True)
class Dae:
    """The assembled system. See the module docstring. `hamiltonian` may be given as a
    :class:`TermSum` (assembly does): the sum is built when it is first read."""

    name: str
    variables: tuple[Variable, ...]
    equations: tuple[Equation, ...]
    parameters: tuple[Parameter, ...]
    hamiltonian: sp.Expr
    dissipation: sp.Expr
    port_power: sp.Expr
    invariants: tuple[Invariant, ...] = ()
    velocity_invariants: tuple[Invariant, ...] = ()
    outputs: tuple[tuple[str, sp.Expr], ...] = ()
    initial: tuple[InitialValue, ...] = ()
    external_ports: tuple[str, ...] = ()
    sources: tuple[str, ...] = ()
    options: Mapping[str, Any] = field(default_factory=dict)
    """The simulation options as the model (and scene) write them, read-only (a
    ``MappingProxyType``; ``dae.options["rtol"] = 0.5`` raises ``TypeError``). Runs of a
    compiled model read the copy in its description
    (:attr:`phc.codegen.compiled.CompiledModel.options`)."""
    linear_blocks: tuple[LinearBlock, ...] = ()
    quadratic_energy: tuple[QuadraticForm, ...] = ()
    quadratic_dissipation: tuple[QuadraticForm, ...] = ()
    topology: Optional[Topology] = None
    compile_time_parameters: tuple[str, ...] = ()
    """Parameters whose values were used at compile time (mesh length, ξ-dependent
    coefficients): overriding them at run time is refused."""

    def __post_init__(self):
        object.__setattr__(self, "options", freeze(self.options))

    # a MappingProxyType does not pickle: the state carries a plain copy (Dask, the caches)
    def __getstate__(self):
        state = dict(self.__dict__)
        state["options"] = thaw(self.options)
        state["hamiltonian"] = self.hamiltonian  # built, if it was still a TermSum
        state.pop("_row_symbols", None)  # found again when read
        return state

    def __setstate__(self, state):
        for name, value in state.items():
            object.__setattr__(self, name, value)
        object.__setattr__(self, "options", freeze(self.options))
    initial_relations: tuple[tuple, ...] = ()
    """Linear relations Σ c_v·v = r imposed only at t₀ (e.g. a beam starting straight and
    moving rigidly), as (label, {variable symbol: coefficient}) with r = 0, or (label,
    {variable symbol: coefficient}, r) (a moving beam's initial elastic velocity field)."""
    input_tables: tuple = ()
    """Input tables as (times, values, interpolation) (:mod:`phc.frontend.inputs`)."""
    breakpoints: tuple[float, ...] = ()
    """Times where an input is not smooth: the integrators stop and restart there."""
    left_out: tuple[tuple[str, str, str], ...] = ()
    """What was not compiled, as (component, what, why): effects that are off, components
    pruned by a scene."""
    dissipation_terms: tuple[tuple[str, sp.Expr, Optional[SourceSpan]], ...] = ()
    """Each component's dissipated power (its terms of `dissipation`), as (component, P_diss,
    source) — what the passivity certificate checks one by one."""
    supply_terms: tuple[tuple[str, str, sp.Expr, Optional[SourceSpan]], ...] = ()
    """Declared controlled sources (a ``phs`` resistive port with ``kind: source``), as
    (component, port, power the model delivers to it, source): their terms of `port_power`,
    which the certificate lists as supplied power instead of checking them for passivity."""
    meshes: dict = field(default_factory=dict)
    """Distributed components: full name -> (type, number of elements)."""
    units: dict = field(default_factory=dict)
    """Unit labels of variables, outputs and `H` where known (`output.x` is keyed `x`), for
    result headers, JSON and plot axes (:mod:`phc.frontend.units`, docs/units.md)."""

    @property
    def n_states(self) -> int:
        return sum(1 for v in self.variables if v.differential)

    def row_symbols(self) -> tuple:
        """The free symbols of each equation's expression, in the order of `equations` (an
        empty set for a number: the rows of sparse blocks), read only. Found once per system:
        the memory budget's count of nonzeros and the structural check's incidence both read
        them (a walk of every row each, measured 0.04 CPU s for a chain of 10⁴ components)."""
        found = self.__dict__.get("_row_symbols")
        if found is None:
            found = equation_symbols(self.equations)
            object.__setattr__(self, "_row_symbols", found)  # equations is a tuple of frozen rows
        return found


def equation_symbols(equations) -> tuple:
    """The free symbols of each row's expression (an empty set for a number), as
    :meth:`Dae.row_symbols` keeps them: for a system that is not a :class:`Dae`."""
    empty = frozenset()
    return tuple(empty if getattr(eq.expr, "is_Number", True) else eq.expr.free_symbols for eq in equations)


Dae.hamiltonian = _SumOnRead("hamiltonian")  # after @dataclass: the field stays one without a default
