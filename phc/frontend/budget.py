"""Resource budget: estimate the cost of a model before doing the work, refuse above a budget.

A model file is data, and a few characters of it (``elements: 200000``, ``n_out: 1e7``,
a Hamiltonian that is a product of sixty exponentials) can ask for more memory or
symbolic work than a laptop has. phc estimates both before spending them and refuses
with a located error that gives the estimate and what drives it.

**Memory.** Before anything is elaborated, the components of the model (every copy of a
nested model file counted) are counted from the files alone, at :data:`BYTES_PER_COMPONENT`
each (:func:`admit_components`), so a model of 10⁴ components too large for the budget is
refused in the seconds it takes to read it. Each distributed component is then estimated
from its type and element count *before* it is discretized (:func:`admit_mesh`, called by
the elaborator), on top of the components: unknowns
and Jacobian nonzeros per element are those of phc's own discretizations (the ``cost``
of each type's entry in :mod:`phc.library.registry`), and the
compile peak is about :data:`BYTES_PER_UNKNOWN` per unknown plus
:data:`BYTES_PER_NONZERO` per nonzero on top of :data:`BASE_BYTES`, fitted to the peaks of
strings (4 unknowns and 16 nonzeros per element) and Euler–Bernoulli beams (8 and 54) of
10⁴ to 10⁵ elements, NumPy back end, ten midpoint steps included, less their output arrays
(``PHC_MAX_MEMORY=8G python benchmarks/bench_beam_scale.py --measure KIND N``, which prints
the estimate with those outputs and the measured peak side by side): the peak grows by about
2.2 KiB per unknown on both, outputs included (the nonzeros add little of their own); the
constants round up, so that the estimate stays above the measured peak, within about 1.1
times it at 10⁵ elements and 1.3 times at 10⁴ (where the base, charged in full, weighs more).
After assembly (:func:`check_assembled`) the count is exact and the output arrays are
added: ``n_out × (2·variables + outputs + invariants + 4)`` doubles (values and
derivatives of every variable, the outputs, the invariants, H and the three power
columns). The budget is :data:`DEFAULT_MAX_MEMORY` unless ``PHC_MAX_MEMORY`` or the
command-line option ``--max-memory SIZE`` says otherwise (:func:`override`).

**Symbolic work.** Differentiation and common-subexpression elimination are the only
symbolic steps whose cost is not linear in the input. Before sympy differentiates an
expression, :func:`derivative_work` bounds the size of the result from the tree alone
(the product and chain rules copy the whole node once per argument that depends on the
variable; ``min``/``max`` of k arguments rebuild a ``max`` of k − 1 arguments for each,
with pairwise comparisons: weighted k²); above :data:`DIFF_LIMIT` the expression is
refused (:class:`SymbolicBudgetError`). The expressions handed to CSE are bounded in
total by :data:`CSE_LIMIT` nodes. The limits are 150 and 30 times what the shipped models
need (a derivative bound of 652; 30 000 nodes in one module) and keep the refused cases
to a few seconds of sympy work.
"""

from __future__ import annotations

import math
import os
import re
import sys
from contextlib import contextmanager
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Callable, Iterator, Optional

from phc.errors import SymbolicBudgetError

if TYPE_CHECKING:
    from phc.diagnostics import Diagnostic


class _Sympy:
    """sympy, imported on first use: `phc simulate` reads the memory figures of this module
    without ever building an expression (a cached front end, :mod:`phc.codegen.fastpath`)."""

    def __getattr__(self, name: str):
        import sympy

        globals()["sp"] = sympy  # later uses go straight to the module
        return getattr(sympy, name)


sp = _Sympy()

DEFAULT_MAX_MEMORY = 2 * 2**30
"""Default budget: 2 GiB, what a laptop can give one process without swapping."""
ENV_VAR = "PHC_MAX_MEMORY"

BASE_BYTES = 224 * 2**20
"""The interpreter with numpy, scipy, sympy, networkx and the solvers loaded (135–150 MiB
measured), plus the solvers' working memory; the intercept of the measured peaks of
Euler–Bernoulli beams of 2·10⁴ and 10⁵ elements is about 154 MiB, rounded up so that small
meshes are charged more than they take (a string of 1 000 elements, 4 004 unknowns, compiled
and run ten midpoint steps with ``energy: H``, peaks at 166–205 MiB;
``benchmarks/bench_beam_scale.py --measure string 1000``). It was 304 MiB until the
unknowns of a mesh were made in bulk (issue 35)."""
BYTES_PER_UNKNOWN = 2130
"""Compile peak per unknown (about 2.1 KiB): its sympy symbols (y and ẏ, made in bulk by
:func:`phc.ir.dae.real_symbol`), the variable and its row, the names and the generated module's
index tables, and in the run its share of the iteration matrix's sparse LU and of the cached
linear blocks. With :data:`BYTES_PER_NONZERO`, fitted (and rounded up) to the peaks of one
process, ``backend="numpy"``, no certificate, consistent initialization and ten midpoint steps
(``PHC_MAX_MEMORY=8G python benchmarks/bench_beam_scale.py --measure KIND N``, the large-mesh
table of ``benchmarks/results/beam_scale.md``; issue 35), less the run's output arrays
(:func:`output_bytes`, which :func:`check_assembled` charges beside this: 11 points there, 176
bytes an unknown): strings of 10⁴ and 10⁵ elements 240 and 1 036 MiB (40 004 and 400 004
unknowns), Euler–Bernoulli beams of 10⁴ and 10⁵ elements 307 and 1 830 MiB (80 007 and 800 007
unknowns, 5.4·10⁵ and 4.8·10⁶ nonzeros), estimated with their outputs at 313, 1 116, 404 and
2 020 MiB (1.30, 1.08, 1.32 and 1.10 times). History: 8 KiB until the per-unknown names were
printed as runs (``_indexed``; Python's compiler alone took about 0.9 KiB per name of
VARIABLES, ROLES and EQUATIONS); 4 KiB until measured peaks at 10⁵ elements replaced the growth
from 10³ to 10⁴ as the fit; 3 KiB until sympy's symbol constructor (0.8 KiB and its assumption
work per symbol) and the Jacobian pattern as tuples of Python ints (72 bytes a nonzero) left the
compile (the peaks were 1 736 and 3 530 MiB); 2.625 KiB, with 144 bytes a nonzero, until the run
kept one LU at a time, the lowered system was freed before the module is loaded and the fit was
made again (the beam's peak had been 2 828 MiB, then 2 494); 2.5 KiB, with 16 bytes a nonzero
and the output arrays inside, until the module's own index arrays became int32, the fixed-step
solvers' monitor stopped copying its looks' factors and a look no longer sat beside Newton's
factors (the beam's peak had been 2 019 MiB)."""
BYTES_PER_NONZERO = 8
"""Compile peak per Jacobian nonzero beyond what :data:`BYTES_PER_UNKNOWN` charges (see there;
strings and beams, 4 and 6 nonzeros per unknown, grow by about the same 2.2–2.3 KiB per unknown:
the nonzeros' own arrays are within that). It was 640 bytes, then 256 until the Jacobian pattern
became arrays, then 144, then 16."""
BYTES_PER_COMPONENT = 54 * 2**10
"""Compile peak per component on top of its unknowns and nonzeros: its spec, description,
lowering and generated statements (chains of 3 000 and 10 000 springs and masses, one unknown
each: 54.7 KiB per component in all, measured when a component's unknown was charged 8 KiB;
with 3 KiB per unknown this was raised by 5 KiB so that a chain is charged no less, and by
1 KiB more with 2.625 KiB per unknown; not measured again since)."""

DIFF_LIMIT = 100_000
"""Largest bound on the size of one derivative (nodes): about 3 s of sympy work."""
CSE_LIMIT = 1_000_000
"""Largest total size (nodes) of the expressions of one generated module."""
MINMAX_WEIGHT = 3
"""Extra weight of a min/max node of k arguments: MINMAX_WEIGHT · k² · its size."""

MAX_SIZE = 2**60
"""The largest memory size :func:`parse_size` accepts (1 EiB)."""

_override: list[Optional[int]] = [None]


# -- the budget ----------------------------------------------------------------------------

_UNITS = {"": 1, "b": 1, "k": 2**10, "kb": 10**3, "kib": 2**10, "m": 2**20, "mb": 10**6, "mib": 2**20,
          "g": 2**30, "gb": 10**9, "gib": 2**30, "t": 2**40, "tb": 10**12, "tib": 2**40}
_SIZE = re.compile(r"\s*([0-9]+(?:\.[0-9]*)?|\.[0-9]+)\s*([a-zA-Z]*)\s*")


def parse_size(text: str) -> int:
    """Bytes in a size such as ``2G``, ``1.5GiB``, ``512M``, ``800MB`` or ``100000`` (bytes).

    K, M, G, T and KiB … TiB are binary (2G = 2 GiB); KB, MB, GB, TB decimal. From 1 MiB
    to 1 EiB (:data:`MAX_SIZE`).

    Raises
    ------
    ValueError
        With a message saying what is expected.
    """
    match = _SIZE.fullmatch(str(text))
    unit = match.group(2).lower() if match else None
    if match is None or unit not in _UNITS:
        raise ValueError(f"`{text}` is not a memory size; write e.g. 2G, 1.5GiB, 512M or 800MB")
    value = float(match.group(1)) * _UNITS[unit]  # inf for a number of 309 digits or more
    if not value >= 2**20:
        raise ValueError(f"`{text}` is below 1 MiB; write e.g. 2G, 1.5GiB or 512M")
    if not value <= MAX_SIZE:
        raise ValueError(f"`{text}` is above 1 EiB; write e.g. 2G, 64G or 1T")
    return int(value)


def max_memory() -> int:
    """The memory budget in bytes: :func:`override`, else ``PHC_MAX_MEMORY``, else 2 GiB."""
    if _override[0] is not None:
        return _override[0]
    env = os.environ.get(ENV_VAR)
    if env:
        try:
            return parse_size(env)
        except ValueError as err:
            raise ValueError(f"{ENV_VAR}: {err}") from None
    return DEFAULT_MAX_MEMORY


@contextmanager
def override(size: Optional[int | str]) -> Iterator[None]:
    """Use `size` (bytes, or a size string) as the budget inside the block (None: no change)."""
    if size is None:
        yield
        return
    previous = _override[0]
    _override[0] = parse_size(size) if isinstance(size, str) else int(size)
    try:
        yield
    finally:
        _override[0] = previous


def format_bytes(n: float) -> str:
    for unit, scale in (("GiB", 2**30), ("MiB", 2**20), ("KiB", 2**10)):
        if n >= scale:
            return f"{n / scale:.1f} {unit}"
    return f"{int(n)} B"


def peak_memory() -> int:
    """Peak resident memory of this process so far, in bytes (``getrusage``; 0 if unknown)."""
    try:
        import resource

        peak = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss
    except (ImportError, OSError, ValueError):  # pragma: no cover - no `resource` on Windows
        return 0
    return int(peak if sys.platform == "darwin" else peak * 1024)  # bytes on macOS, KiB on Linux


def _raise_hint(need: int) -> str:
    return (f"or raise the budget (now {format_bytes(max_memory())}) with `--max-memory SIZE` or the environment "
            f"variable {ENV_VAR}, e.g. `--max-memory {math.ceil(need / 2**30)}G`")


# -- memory: estimate ----------------------------------------------------------------------

@dataclass
class Estimate:
    """Unknowns and Jacobian nonzeros of (part of) a model, and the bytes they need."""

    unknowns: int = 0
    nonzeros: int = 0
    components: int = 0

    @property
    def compile_bytes(self) -> int:
        return (BASE_BYTES + BYTES_PER_UNKNOWN * self.unknowns + BYTES_PER_NONZERO * self.nonzeros
                + BYTES_PER_COMPONENT * self.components)


def output_bytes(n_out: int, n_columns: int) -> int:
    """Bytes of the output arrays: `n_out` times `n_columns` doubles."""
    return 8 * int(n_out) * int(n_columns)


def output_columns(variables: int, outputs: int, invariants: int = 0) -> int:
    """The columns of a run's output arrays: each variable's value and derivative, the outputs,
    the invariants, H and the three power columns."""
    return 2 * int(variables) + int(outputs) + int(invariants) + 4


def mesh_estimate(comp) -> Estimate:
    """Unknowns and Jacobian nonzeros of a distributed component from its spec alone: the
    ``cost`` of its type's registry entry (:mod:`phc.library.registry`; per element of phc's
    discretizations, P1/P0 for strings and Timoshenko beams, Hermite/DP1 for
    Euler–Bernoulli and moving beams, states and co-energies)."""
    from phc.library.registry import get

    cost = get(comp.type).cost(comp)
    if cost is None:
        raise ValueError(f"`{comp.type}` has no mesh to estimate; its variables are counted after assembly")
    return Estimate(*cost)


@dataclass(frozen=True)
class MeshLedger:
    """What the distributed components admitted so far cost, and where each is written:
    :func:`admit_mesh` returns the ledger with one more component."""

    total: Estimate = field(default_factory=Estimate)
    meshes: tuple = ()
    """(component, Estimate, span, elements) in the order admitted."""

    @property
    def spans(self) -> dict:
        """Distributed component -> where its mesh is written."""
        return {name: span for name, _, span, _ in self.meshes}


def _element_limit(comp) -> Optional[int]:
    for meta in type(comp).model_fields["elements"].metadata:
        if getattr(meta, "le", None) is not None:
            return int(meta.le)
    return None


def admit_mesh(ledger: MeshLedger, ctx, full: str, comp, path, override_=None
               ) -> tuple[MeshLedger, Optional[Diagnostic]]:
    """Admit a distributed component before it is discretized: ``(ledger, None)`` with the
    component added to `ledger`, or ``(ledger, error)`` saying why not.

    Checks the element count against the component's own limit (a scene's
    ``accuracy.mesh`` must not bypass it) and the estimated compile memory of all
    distributed components so far against the budget. The error is located at the
    ``elements`` key (or at the scene's ``accuracy.mesh`` entry that set it, `override_`:
    ``(elements, span)``).
    """
    from phc.diagnostics import Diagnostic
    from phc.frontend.source_map import path_text

    if override_ is not None:
        span, where = override_[1], f"accuracy.mesh.{full}"
    else:
        key = (*path, "elements")
        has = getattr(ctx.smap, "has", None)
        span = ctx.smap.locate_key(key) if has is None or has(key) else ctx.smap.locate(path)
        where = path_text(key)
    n = int(comp.elements)
    limit = _element_limit(comp)
    if limit is not None and n > limit:
        return ledger, Diagnostic(
            "PHC-E701", f"`{full}` ({comp.type}) has {n:,} elements, above its limit of {limit:,}", span=span,
            hint="use fewer elements", path=where)
    est = mesh_estimate(comp)
    total = Estimate(ledger.total.unknowns + est.unknowns, ledger.total.nonzeros + est.nonzeros,
                     ledger.total.components)
    budget = max_memory()
    if total.compile_bytes > budget:
        others = ledger.total
        per = mesh_estimate(comp.model_copy(update={"elements": 1000}))
        spare = budget - others.compile_bytes
        cost_per_element = (BYTES_PER_UNKNOWN * per.unknowns + BYTES_PER_NONZERO * per.nonzeros) / 1000
        fit = int(spare / cost_per_element) if spare > 0 else 0
        together = (f" (with the {len(ledger.meshes)} distributed component(s) before it: {total.unknowns:,} "
                    f"unknowns, {total.nonzeros:,} Jacobian nonzeros)" if ledger.meshes else "")
        return ledger, Diagnostic(
            "PHC-E700", f"`{full}` ({comp.type}, {n:,} elements) needs an estimated {format_bytes(total.compile_bytes)} "
            f"to compile ({est.unknowns:,} unknowns, {est.nonzeros:,} Jacobian nonzeros){together}, above the "
            f"memory budget of {format_bytes(budget)}", span=span, path=where,
            hint=(f"use at most about {fit:,} elements " if fit >= 1 else "use fewer elements ")
            + _raise_hint(total.compile_bytes))
    return MeshLedger(total, (*ledger.meshes, (full, est, span, n))), None


def admit_components(count: int, nested: Optional[tuple[str, int]]) -> Optional[tuple[str, str]]:
    """Before anything is elaborated: the problem with a model of `count` components (every
    copy of a nested model file's components included) as ``(message, hint)``, or None within
    budget. `nested` is the ``type: model`` entry of the top-level file that brings the most
    of them, with how many, or None. Meshes are admitted one by one later
    (:func:`admit_mesh`), on top of this."""
    need = Estimate(components=count).compile_bytes
    budget = max_memory()
    if need <= budget:
        return None
    most = (f"; `{nested[0]}` brings {nested[1]:,} of them" if nested is not None and nested[1] > 0 else "")
    fit = max(0, (budget - BASE_BYTES) // BYTES_PER_COMPONENT)
    return (f"the model has {count:,} components{most}, an estimated {format_bytes(need)} to compile before "
            f"any mesh is counted, above the memory budget of {format_bytes(budget)}",
            f"use at most about {fit:,} components " + _raise_hint(need))


def check_assembled(elab, dae) -> list[Diagnostic]:
    """After assembly: the exact size plus the output arrays against the budget. Returns a
    located error when above: at `n_out` when the outputs drive it, else at the component
    with the most unknowns. `elab` is the :class:`phc.frontend.elaborate.Elaboration` assembled."""
    from phc.diagnostics import Diagnostic

    n_var = len(dae.variables)
    nonzeros = sum(term.matrix.nnz for block in dae.linear_blocks for term in block.terms)
    nonzeros += sum(map(len, dae.row_symbols()))  # a number (a row of a sparse block) has none
    compile_est = Estimate(n_var, nonzeros, len(elab.components))
    n_out = int(dae.options.get("n_out", 0) or 0)
    columns = output_columns(n_var, len(dae.outputs), len(dae.invariants) + len(dae.velocity_invariants))
    outputs = output_bytes(n_out, columns)
    total = compile_est.compile_bytes + outputs
    budget = max_memory()
    if total <= budget:
        return []
    what = (f"an estimated {format_bytes(total)} ({format_bytes(compile_est.compile_bytes)} to compile "
            f"{n_var:,} unknowns with {nonzeros:,} Jacobian nonzeros in {len(elab.components):,} components, "
            f"{format_bytes(outputs)} for the output "
            f"arrays: {n_out:,} points × {columns:,} columns)")
    if outputs >= compile_est.compile_bytes:
        scene = elab.scene
        if scene is not None and scene.spec.n_out is not None:
            span, where = scene.locate("n_out"), "n_out"
        else:
            span, where = elab.top.smap.locate(("simulation", "n_out")), "simulation.n_out"
        fit = max(2, int((budget - compile_est.compile_bytes) / (8 * columns)))
        return [Diagnostic(
            "PHC-E700", f"the output grid needs {what}, above the memory budget of {format_bytes(budget)}",
            span=span, path=where, hint=f"use fewer output points (at most about {fit:,}) " + _raise_hint(total))]
    counts: dict[str, int] = {}
    for v in dae.variables:
        counts[v.component] = counts.get(v.component, 0) + 1
    driver = max(counts, key=counts.get) if counts else None
    span = elab.mesh_spans[driver] if driver in elab.mesh_spans else next(
        (s for name, _, s in elab.components if name == driver), None)
    return [Diagnostic(
        "PHC-E700", f"the model needs {what}, above the memory budget of {format_bytes(budget)}; "
        f"`{driver}` has the most unknowns ({counts.get(driver, 0):,})", span=span,
        hint="make the model smaller " + _raise_hint(total))]


def check_output_arrays(n_out: int, n_columns: int, what: str = "n_out") -> Optional[str]:
    """The problem with `n_out` output points of `n_columns` doubles, or None within budget."""
    need = output_bytes(n_out, n_columns)
    budget = max_memory()
    if need <= budget:
        return None
    return (f"{what} = {n_out:,} output points × {n_columns:,} columns need {format_bytes(need)} for the output "
            f"arrays, above the memory budget of {format_bytes(budget)}; use fewer points (at most about "
            f"{max(2, budget // (8 * n_columns)):,}) " + _raise_hint(need))


# -- symbolic work -------------------------------------------------------------------------

class SizeCache:
    """Tree sizes of sympy nodes (shared subtrees counted once per occurrence, as sympy's
    own tree walks do), memoized across the expressions of one compilation."""

    def __init__(self) -> None:
        self.size: dict = {}
        self.work: dict = {}

    def tree_size(self, expr) -> int:
        self._walk(expr)
        return self.size[expr]

    def derivative_work(self, expr) -> int:
        """Bound on the size of d(expr)/dx for any x (every symbol may be x)."""
        self._walk(expr)
        return self.work[expr]

    def _walk(self, expr) -> None:
        _walk(expr, self.size, self.work, lambda leaf: bool(leaf.free_symbols))


def _walk(expr, size: dict, work: dict, depends: Callable) -> None:
    """Fill `size` and `work` (derivative-size bound) for every node of `expr`, children
    first, without recursion; a leaf costs 1 when ``depends(leaf)``."""
    stack = [(expr, False)]
    while stack:
        node, expanded = stack.pop()
        if node in size:
            continue
        args = node.args
        if not args:
            size[node] = 1
            work[node] = 1 if depends(node) else 0
            continue
        if not expanded:
            stack.append((node, True))
            stack.extend((a, False) for a in args if a not in size)
            continue
        s = 1 + sum(size[a] for a in args)
        size[node] = s
        work[node] = _node_work(node, s, [work[a] for a in args])


def _node_work(node, s: int, child_work: list[int]) -> int:
    if isinstance(node, sp.Add):
        return 1 + sum(child_work) if any(child_work) else 0
    dependent = [w for w in child_work if w]
    if not dependent:
        return 0
    work = sum(s + 4 + w for w in dependent)  # + 4: f'(g) may be a little larger than f(g) (tan, atan)
    if isinstance(node, (sp.Min, sp.Max)):
        work += MINMAX_WEIGHT * len(dependent) ** 2 * s
    return work


def derivative_work(expr, wrt=None, cache: Optional[SizeCache] = None) -> int:
    """Bound on the tree size of ``d expr / d wrt`` (any symbol when `wrt` is None).

    Computed from the tree without differentiating (iteratively: no recursion limit):
    a sum costs the sum of its terms' derivatives; any other node (product, power,
    function, piecewise) costs a copy of itself plus the derivative of each argument
    that depends on the variable; ``min``/``max`` of k dependent arguments add
    MINMAX_WEIGHT · k² copies. The bound is 2–5 × the size sympy actually returns
    on the shipped models; its purpose is to tell 10³ from 10⁶ before sympy starts.
    """
    if wrt is None:
        return (cache or SizeCache()).derivative_work(expr)
    size: dict = {}
    work: dict = {}
    _walk(expr, size, work, lambda leaf: leaf == wrt)
    return work[expr]


def drop_deltas(expr):
    """Replace Dirac deltas (derivatives of sign, abs' and heaviside) by 0, their value
    almost everywhere: a Jacobian is a Newton matrix, and generated code cannot print a
    distribution."""
    if not expr.has(sp.DiracDelta):
        return expr
    return expr.replace(lambda e: isinstance(e, sp.DiracDelta), lambda e: sp.S.Zero)


def derivative(expr, x):
    """``sp.diff(expr, x)``: the very same expression, with the common terms taken directly.
    A sum is differentiated term by term (as sympy does); a term free of `x` gives 0, `x`
    itself 1, a product with `x` as one plain factor the product of the other factors
    (sympy's product rule gives the same canonical product); other products, powers with an
    exponent free of `x` and ``sin``/``cos`` by the product, power and chain rules written as
    sympy writes them (its expression exactly: tests/test_budget.py compares); any other term
    goes to ``sp.diff``. sympy's derivative machinery costs about a millisecond per call: a
    tenth of a lumped component's lowering and of the Jacobian of its rows, and 0.2-0.3 of
    the 0.25-0.4 s CPU of the flexible slider-crank's lowering (now 0.07-0.11 s)."""
    if expr.is_Add:
        return sp.Add(*[_term_derivative(term, x) for term in expr.args])
    return _term_derivative(expr, x)


def _term_derivative(term, x):
    if not term.has(x):
        return sp.S.Zero
    if term == x:
        return sp.S.One
    if term.is_Mul:
        rest = [a for a in term.args if a != x]
        if len(rest) == len(term.args) - 1 and not any(a.has(x) for a in rest):
            return sp.Mul(*rest)
        # the product rule as sympy writes it for a first derivative (the general Leibniz
        # rule at order 1: one product per factor that holds x, in the order of the factors)
        args = term.args
        return sp.Add(*[sp.Mul(*args[:i], derivative(a, x), *args[i + 1:]) for i, a in enumerate(args) if a.has(x)])
    if term.is_Pow and not term.exp.has(x):
        # sympy's b**e * (de * log(b) + db * e / b) with de = 0
        return term * (derivative(term.base, x) * term.exp / term.base)
    if type(term) in (sp.sin, sp.cos):
        # the chain rule as sympy writes it for a function of one argument: f'(u) * du
        return sp.Add(term.fdiff(1) * derivative(term.args[0], x))
    return sp.diff(term, x)



def checked_diff(expr, x, what: str, cache: Optional[SizeCache] = None):
    """``sp.diff(expr, x)`` after checking :func:`derivative_work` against DIFF_LIMIT.

    Raises
    ------
    SymbolicBudgetError
        Before differentiating, when the bound is above the limit.
    """
    work = (cache or SizeCache()).derivative_work(expr)
    if work > DIFF_LIMIT:  # the cheap bound over all symbols is too large: look at x alone
        work = derivative_work(expr, x)
        if work > DIFF_LIMIT:
            raise SymbolicBudgetError(expr, work, DIFF_LIMIT, what)
    return drop_deltas(derivative(expr, x))


def symbolic_hint() -> str:
    return ("write it with fewer factors or arguments (a sum of terms differentiates term by term; a product or "
            "a `min`/`max` of many terms does not), or split it across components")
