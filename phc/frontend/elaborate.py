"""The elaborate pass: model files to component descriptions.

Input: the path of a model file and optionally a :class:`phc.frontend.scene.Scene`. Output: an
immutable :class:`Elaboration` and the located diagnostics found.

What happens here, in order:

1. read each YAML file with positions and validate it (:mod:`phc.spec.load`) into a
   :class:`~phc.spec.ModelSpec`; nested ``type: model`` components are read the same
   way, relative to the file that uses them (cycles are errors);
2. apply the scene: parameter overrides, effects, meshes, pruning of components that
   cannot influence the requested outputs;
3. create parameters (derived ones stay expressions of the others, so one compiled
   module serves a whole parameter study);
4. lower each component (:mod:`phc.library`) to its description
   (:class:`~phc.ir.dae.ComponentDescription`: ports, storage, Dirac structure in kernel
   form, laws, H) and its rows — derived from the description, or checked against it
   by :mod:`phc.checks.rows`. Lowering is a function of the component's spec and a
   read-only context (:func:`phc.frontend.lowering.lower`); its frozen result is folded into this
   pass's state in the order the components are written, except that a component reading
   others' states (a feedback source, a modulated ratio, a signal block) comes after the
   ones it reads (:func:`phc.ir.interconnect.reading_order`).

The module is a little over 800 lines because the per-file walk (parameters, nested
files, scenes, lowering order) shares one state and reads best in one place.

Connections are checked by the interconnect pass (:mod:`phc.ir.interconnect`) and joined by
the assemble pass (:mod:`phc.ir.assemble`). Every problem becomes a located
:class:`~phc.diagnostics.Diagnostic`; nothing raises for a user mistake, and nothing is
evaluated: expressions go through :func:`phc.spec.expressions.parse_expression`.
"""

from __future__ import annotations

import dataclasses
import difflib
import itertools
import math
import os
from dataclasses import dataclass, field
from pathlib import Path
from types import MappingProxyType
from typing import Any, Mapping, Optional, Sequence

import sympy as sp

from phc.analysis.order import topological_order
from phc.frontend.budget import MeshLedger
from phc.ir.dae import Equation, Invariant, Parameter, Variable, shifted_rows
from phc.diagnostics import Diagnostic, DiagnosticList
from phc.ir.interconnect import MODULATED, reading_order, state_reads
from phc.frontend.files import MAX_INCLUDE_DEPTH, MAX_MODEL_INSTANCES, FileAccess, FileRefused
from phc.frontend.reporter import FileContext, Port, Reporter
from phc.frontend.scene import SceneApplication
from phc.frontend.source import SourceSpan
from phc.spec import ModelSpec
from phc.spec.components import ModelComponentSpec
from phc.spec.load import load_spec, load_spec_bytes  # noqa: F401  (load_spec: the public reader)
from phc.spec.model import ParameterSpec


class _Elaborator(Reporter):
    """The elaborate pass's working state, private to this module: the files read, the
    parameters created, the scene applied, and the lowerings of the components folded in
    order (:meth:`_fold` of each :class:`phc.frontend.lowering.ComponentLowering`). :func:`_finish`
    turns it into the pass's output, an immutable :class:`Elaboration`. Lowerers never see
    it: each writes its own :class:`phc.frontend.lowering.Recorder` and reads a read-only
    :class:`phc.frontend.lowering.LoweringContext`."""

    def __init__(self) -> None:
        super().__init__()
        self._pairs: dict = {}  # (id(want), id(dim)) -> pint's comparisons (_compared)
        self._kinds: dict = {}  # (component kind, port domains) -> (scale terms, expected fields)
        self._fields_clean: set = set()  # component kinds whose field units passed (_check_field_units)
        self._context = None  # the last LoweringContext and what it was made of (_lowering_context)
        self.variables: list[Variable] = []
        self.equations: list[Equation] = []
        self.parameters: dict[str, Parameter] = {}
        self.definitions: dict[sp.Symbol, sp.Expr] = {}
        self.defined_by: dict[sp.Symbol, str] = {}  # definition -> the component whose lowerer wrote it
        self.hand_written: set[str] = set()  # components with a row not derived from their description (emit)
        self.component_specs: dict[str, Any] = {}  # full name -> its spec as lowered (overrides applied)
        self.ports: dict[str, Port] = {}
        self.ports_of: dict[str, list[Port]] = {}  # component -> the ports its lowering declared
        self.port_aliases: dict[str, str] = {}
        self.hamiltonian: list[sp.Expr] = []
        self.dissipation: list[tuple[str, sp.Expr, Optional[SourceSpan]]] = []  # (component, P_diss, source)
        self.source_power: list[sp.Expr] = []
        self.supplied: list = []  # declared controlled sources (ComponentLowering.supplied)
        self.linear_blocks: list = []
        self.quadratic_energy: list = []
        self.quadratic_dissipation: list = []
        self.invariants: list[Invariant] = []
        self.velocity_invariants: list[Invariant] = []
        self.connections: list[tuple[str, str, Optional[SourceSpan], str]] = []
        self.exposed_top: dict[str, tuple[str, Optional[SourceSpan]]] = {}
        self.sources: list[str] = []
        self._file_stack: list[str] = []
        self.failed: set[str] = set()
        self.components: list[tuple[str, str, Optional[SourceSpan]]] = []
        self.dirac: list = []
        self.resistive_laws: list = []
        self.rigid_constraints: list = []
        self.extra_outputs: dict = {}
        self.signals: dict = {}  # signal blocks' outputs by name, read by later components
        self.initial_relations: list = []
        self.position_maps: list = []
        self.compile_time_parameters: set = set()
        self.mesh_ledger = MeshLedger()  # the distributed components admitted so far (phc.frontend.budget)
        self.applied = SceneApplication(None, None)  # the scene's overrides and pruning (none without a scene)
        self.written_meshes: dict[str, int] = {}  # distributed component -> `elements` as in its model file
        self.initial_fields: dict = {}  # distributed component -> phc.ir.initial_fields.FieldSet
        self.meshes: dict[str, tuple[str, int]] = {}  # distributed component -> (type, elements)
        self.scene = None
        self.left_out: list[tuple[str, str, str]] = []
        self.unavailable: dict[str, str] = {}  # name -> why (an effect that is off)
        self._specs: dict[str, tuple] = {}  # resolved path -> (spec, smap) of a nested file, read once
        from phc.frontend.lowering import SharedLowerings

        self.shared = SharedLowerings()  # identical components lowered once (issue 38)
        self._default_values: dict = {}  # parameter symbol -> its default as Float (see default_values)
        self.unset_parameters: set = set()  # parameters whose value had an error (their default 0 means nothing)

    def component_rows(self) -> tuple:
        """Each lowered component's rows as its lowerer emitted them (before assembly
        substitutes definitions and merges ports): what :mod:`phc.checks.rows` compares
        with the component's description."""
        from phc.ir.dae import ComponentRows, FieldTuples

        equations: dict[str, list] = {}
        for eq in self.equations:  # the Equation objects: read as (label, expr) pairs
            equations.setdefault(eq.component, []).append(eq)
        sparse = {blk.component for blk in self.linear_blocks}
        definitions: dict[str, list] = {}
        for sym, expr in self.definitions.items():
            owner = self.defined_by.get(sym)
            if owner is not None:
                definitions.setdefault(owner, []).append((sym, expr))
        variables: dict[str, list] = {}
        for v in self.variables:  # read as (symbol, dsymbol, role)
            variables.setdefault(v.component, []).append(v)
        return tuple(ComponentRows(name, FieldTuples(equations.get(name, ()), ("label", "expr")),
                                   tuple(definitions.get(name, ())),
                                   FieldTuples(variables.get(name, ()), ("symbol", "dsymbol", "role")), name in sparse,
                                   derived=name not in self.hand_written)
                     for name, _, _ in self.components if name not in self.failed)

    # -- parameters -------------------------------------------------------------------
    def default_values(self) -> dict:
        """Parameter symbol → its default as a sympy Float (xreplace-safe), a copy."""
        self._sync_defaults()
        return dict(self._default_values)

    def _sync_defaults(self) -> None:
        """Bring :attr:`_default_values` up to date. Before every lowering: parameters are
        only ever added, so the Floats of those seen before are kept and only new ones are
        converted (linear in the model's size)."""
        if len(self._default_values) != len(self.parameters):
            start = len(self._default_values)
            for p in itertools.islice(list(self.parameters.values()), start, None):
                self._default_values[p.symbol] = sp.Float(p.default)

    def add_parameters(self, ctx: FileContext, entries: dict[str, tuple[Any, Sequence, Optional[FileContext]]],
                       units: dict[str, tuple]) -> None:
        """Create parameters `ctx.prefix + name`; values may use each other (acyclic)."""
        symbols = {name: sp.Symbol(ctx.prefix + name, real=True) for name in entries}
        ctx.params.update(symbols)
        declared = self._declare_units(ctx, entries, units, symbols)
        exprs: dict[str, sp.Expr] = {}
        for name, (value, path, value_ctx) in entries.items():
            vctx = value_ctx or ctx
            scope = dict(vctx.params) if value_ctx is not None else dict(symbols)
            n_diags = len(self.diags)
            exprs[name] = self.expr(vctx, value, path, scope, check_units=False)  # checked in order below
            if len(self.diags) > n_diags:  # reported: checks of values that use it would only echo it
                self.unset_parameters.add(symbols[name])
        edges = [(dep, symbols[name]) for name, ex in exprs.items() for dep in ex.free_symbols & set(symbols.values())]
        order = topological_order(symbols.values(), edges)
        if order is None:
            import networkx as nx  # only to name the cycle: networkx costs 0.3 s to import

            graph = nx.DiGraph()
            graph.add_nodes_from(symbols.values())
            graph.add_edges_from(edges)
            cycle = nx.find_cycle(graph)
            names = " -> ".join(str(a) for a, _ in cycle)
            first = str(cycle[0][0]).rsplit(".", 1)[-1]
            self.error("PHC-E103", f"parameters depend on each other in a cycle: {names}", ctx,
                       entries[first][1], hint="give one of them a number")
            return
        values: dict[sp.Symbol, float] = {}
        by_symbol = {s: n for n, s in symbols.items()}
        for sym in order:
            name = by_symbol[sym]
            ex = exprs[name]
            # Only the symbols the value uses (all defaults at each parameter: quadratic).
            known = {}
            for s in ex.free_symbols:
                known_p = self.parameters.get(s.name)
                if known_p is not None and known_p.symbol == s:
                    known[s] = sp.Float(known_p.default)
                elif s in values:
                    known[s] = sp.Float(values[s])
            try:
                val = float(ex.xreplace(known).evalf())
            except (TypeError, ValueError):
                val = math.nan
            path = entries[name][1]
            if not math.isfinite(val):
                self.error("PHC-E104", f"parameter `{name}` does not evaluate to a finite number "
                           f"(got {ex})", entries[name][2] or ctx, path)
                val = 0.0
                self.unset_parameters.add(sym)
            if ex.free_symbols & self.unset_parameters:
                self.unset_parameters.add(sym)
            values[sym] = val
            if self.units and sym not in self.unset_parameters:
                self._parameter_dimension(entries[name][2] or ctx, name, sym, entries[name], ex, declared)
            unit, desc = units.get(name, (None, None))
            derived = ex if not ex.is_Number else None
            self.parameters[sym.name] = Parameter(sym.name, sym, val, derived, unit, desc,
                                                  (entries[name][2] or ctx).smap.locate(tuple(path)))

    def _declare_units(self, ctx: FileContext, entries: dict, units: dict, symbols: dict) -> dict:
        """Parse the `unit:` of this file's parameters (PHC-E170, W172) and warn when
        some plain-number parameters have a unit and others not (PHC-W170). Returns
        name -> the declared unit (a pint quantity, or None without pint)."""
        from phc.frontend.units import UnitError, have_pint, is_coherent, parse_unit

        declared = {}
        for name, (unit, _) in units.items():
            if unit is None:
                continue
            path = ("parameters", name, "unit")
            try:
                quantity = parse_unit(unit)
            except UnitError as err:
                self.error("PHC-E170", f"parameter `{name}`: {err.message}", ctx, path, hint=err.hint)
                continue
            declared[name] = quantity
            if quantity is None:
                continue
            self.units_declared = True
            self.units_si = self.units_si and is_coherent(quantity)
            self.units[symbols[name]] = quantity
            self.unit_text[symbols[name]] = unit
        if not any(unit is not None for unit, _ in units.values()):
            return declared
        if declared and not have_pint():
            first = next(iter(declared))
            self.error("PHC-W172", "units are not checked: pint is not installed, so phc only checks their "
                       "spelling", ctx, ("parameters", first, "unit"), severity="warning",
                       hint="pint is a dependency of phc that this installation lacks (installed with --no-deps?); "
                       "`pip install pint` to check dimensions")
        without = [name for name in entries if name not in declared and units.get(name, (None,))[0] is None
                   and isinstance(entries[name][0], (int, float)) and entries[name][2] is None]
        if declared and without:
            shown = ", ".join(f"`{n}`" for n in without[:6]) + (f" and {len(without) - 6} more" if len(without) > 6 else "")
            path = ("parameters", without[0])
            self.error("PHC-W170", f"parameter{'s' if len(without) > 1 else ''} {shown} "
                       f"ha{'ve' if len(without) > 1 else 's'} no unit while others have one: expressions "
                       "that use them are not checked for dimensions", ctx, path, severity="warning",
                       hint="give every parameter a `unit:` (`1` for a dimensionless one), or none at all", key=True)
        return declared

    def _parameter_dimension(self, ctx: FileContext, name: str, sym: sp.Symbol, entry: tuple, ex: sp.Expr,
                             declared: dict) -> None:
        """Check a parameter's value against its declared unit (PHC-E172); a derived parameter
        without a unit gets the dimension of its value."""
        from phc.frontend.units import NUMBER, describe

        value, path, _ = entry
        dim = self.dimension(ctx, value, path, ex)
        unit = declared.get(name)
        if unit is not None and dim is not None and dim is not NUMBER and unit.dimensionality != dim.dimensionality:
            self.error("PHC-E172", f"parameter `{name}` is declared in {describe(unit, self.unit_text.get(sym))} "
                       f"but its value `{value}` is in {describe(dim)}", ctx, path,
                       hint="correct the value's expression or the parameter's `unit:`")
        elif name not in declared and dim is not None and dim is not NUMBER:
            self.units[sym] = dim

    # -- files ------------------------------------------------------------------------
    def load_file(self, path: Path, prefix: str, overrides: dict, parent: Optional[FileContext],
                  ref_path: Sequence = (), real: Optional[Path] = None, ref: str = "") -> Optional[FileContext]:
        """Elaborate one model file: the top-level one (`parent` None) or a nested one, whose
        resolved path `real` comes from :meth:`_nested_ref` (read once, see :meth:`_nested_spec`)."""
        key = str(real if real is not None else path.resolve())
        if key in self._file_stack:
            self.error("PHC-E106", f"model `{path}` includes itself (nesting cycle)", parent, ref_path)
            return None
        if parent is None:
            spec, smap, diags = load_spec(path)
            self.diags.extend(diags)
        else:
            spec, smap = self._nested_spec(Path(key), path, ref or str(path), parent, ref_path)
        if spec is None:
            return None
        if parent is None:
            # Files the model refers to must lie in its directory (or the scene's).
            self.files.add_root(Path(key).parent)
            if self.scene is not None:
                self.files.add_root(Path(os.path.realpath(self.scene.path)).parent)
        if parent is None and self.scene is not None:
            self.applied = self.scene.apply(self.files, spec, smap)
            spec, smap = self.applied.spec, self.applied.smap
            self.diags.extend(self.applied.diagnostics)
            self.left_out.extend(self.applied.left_out)
            sctx = FileContext(str(self.scene.path), self.scene.smap, "", None)
            overrides = {k: (v, ("parameters", k), sctx) for k, v in self.scene.spec.parameters.items()}
            self.sources.append(str(self.scene.path))
        if parent is None and overrides and self.scene is not None:
            self.override_note = ", ".join(
                f"the scene's `{k}` = {v} ({_where(octx.smap.locate(tuple(opath)))})"
                for k, (v, opath, octx) in overrides.items() if k not in self.param_overrides)
        if parent is None and self.param_overrides:
            # values from outside the files (`--param`, `simulate(params=...)`, a sweep's point):
            # checked like values written in the file (phc.simulation.check_parameters)
            overrides = {**overrides, **{k: (float(v), ("parameters", k), None)
                                         for k, v in self.param_overrides.items()}}
        self.sources.append(str(path))
        ctx = FileContext(str(path), smap, prefix, spec)
        if parent is None and not self._check_expansion(ctx, key):
            return None
        self._file_stack.append(key)
        try:
            self._elaborate_file(ctx, overrides)
        finally:
            self._file_stack.pop()
        return ctx

    def _nested_ref(self, ctx: FileContext, ref: str, path: Sequence, report: bool = True
                    ) -> Optional[tuple[Path, Path]]:
        """``(shown, real)`` of a nested model file named at `path` of `ctx` (see
        :class:`phc.frontend.files.FileAccess`); a refusal is reported at that `file:` key."""
        try:
            found = self.files.resolve(ctx.file, ref, "model")
        except FileRefused as err:
            if report:
                self.error("PHC-E107" if err.reason == "missing" else "PHC-E116", err.message, ctx, path,
                           hint=err.hint)
            return None
        if report and len(self._file_stack) > MAX_INCLUDE_DEPTH:
            self.error("PHC-E117", f"model files nest more than {MAX_INCLUDE_DEPTH} levels deep", ctx, path,
                       hint="a chain of `type: model` includes this long is likely a mistake; flatten some levels")
            return None
        return found

    def _nested_spec(self, real: Path, shown: Path, ref: str, parent: FileContext, ref_path: Sequence):
        """``(spec, smap)`` of a nested model file, read and validated once per resolved path
        (a file included many times is parsed once and its problems are reported once)."""
        key = str(real)
        if key not in self._specs:
            try:
                raw = self.files.read_bytes(real, ref, "model")
            except FileRefused as err:
                self.error("PHC-E116", err.message, parent, ref_path, hint=err.hint)
                self._specs[key] = (None, None)
                return self._specs[key]
            spec, smap, diags = load_spec_bytes(raw, shown)
            self.diags.extend(diags)
            self._specs[key] = (spec, smap)
        return self._specs[key]

    def _check_expansion(self, ctx: FileContext, key: str) -> bool:
        """Before anything is lowered: count the copies of nested model files the top-level
        file expands to and refuse more than :data:`~phc.frontend.files.MAX_MODEL_INSTANCES`; count
        the components of all copies and refuse a model whose estimated compile memory is
        above the budget (:func:`phc.frontend.budget.admit_components`), so a model too large is
        refused in the time it takes to read its files.

        Each ``type: model`` entry is its own copy (its own states), so a file included
        twice at each of 18 levels ("diamonds") expands to 2¹⁸ copies although each file is
        read only once. Counting is memoized per file, so it is linear in the number of
        files and references however large the expansion."""
        from phc.frontend.budget import Estimate, admit_components

        memo: dict[str, tuple[int, int]] = {}

        def copies(fctx: FileContext, fkey: str, stack: set, depth: int) -> tuple[int, int]:
            """(copies of nested files, components of every copy) of one file."""
            if fkey in memo:
                return memo[fkey]
            total, leaves = 0, 0
            if depth <= MAX_INCLUDE_DEPTH:  # deeper: elaboration reports the depth
                for cname, comp in fctx.spec.components.items():
                    if isinstance(comp, ModelComponentSpec):
                        n, k = child(fctx, cname, comp, stack, depth)
                        total, leaves = total + n, leaves + k
                    else:
                        leaves += 1
            memo[fkey] = (total, leaves)
            return memo[fkey]

        def child(fctx: FileContext, cname: str, comp, stack: set, depth: int) -> tuple[int, int]:
            path = ("components", cname, "file")
            found = self._nested_ref(fctx, comp.file, path, report=False)
            if found is None or str(found[1]) in stack:
                return 0, 0  # elaboration reports refusals and cycles
            spec, smap = self._nested_spec(found[1], found[0], comp.file, fctx, path)
            if spec is None:
                return 0, 0
            sub = str(found[1])
            stack.add(sub)
            try:
                n, k = copies(FileContext(str(found[0]), smap, "", spec), sub, stack, depth + 1)
                return 1 + n, k
            finally:
                stack.discard(sub)

        per_entry, leaves = {}, 0
        for cname, comp in ctx.spec.components.items():
            if cname in self.applied.skip:
                continue
            if isinstance(comp, ModelComponentSpec):
                per_entry[cname] = child(ctx, cname, comp, {key}, 1)
                leaves += per_entry[cname][1]
            else:
                leaves += 1
        total = sum(n for n, _ in per_entry.values())
        if total > MAX_MODEL_INSTANCES:
            worst = max(per_entry, key=lambda c: per_entry[c][0])
            self.error("PHC-E117", f"nested models expand to {total:,} copies of model files, above the limit of "
                       f"{MAX_MODEL_INSTANCES:,}; `{worst}` brings {per_entry[worst][0]:,} of them", ctx,
                       ("components", worst, "file"),
                       hint="every `type: model` entry is a separate copy, so a file included twice at each level "
                       "doubles the copies per level; include fewer copies or flatten the model")
            return False
        most = max(per_entry, key=lambda c: per_entry[c][1], default=None)
        problem = admit_components(leaves, None if most is None else (most, per_entry[most][1]))
        if problem is not None:
            self.error("PHC-E700", problem[0], ctx, ("components",), hint=problem[1], key=True)
            return False
        self.mesh_ledger = MeshLedger(Estimate(components=leaves))  # meshes are admitted on top of this
        return True

    def _elaborate_file(self, ctx: FileContext, overrides: dict) -> None:
        from phc.library import LOWERERS

        spec = ctx.spec
        entries, units = {}, {}
        for name, p in spec.parameters.items():
            if isinstance(p, ParameterSpec):
                entries[name] = (p.value, ("parameters", name, "value"), None)
                units[name] = (p.unit, p.description)
            else:
                entries[name] = (p, ("parameters", name), None)
        for name, (value, path, octx) in overrides.items():
            if name not in entries:
                close = difflib.get_close_matches(name, list(entries), n=1)
                self.error("PHC-E105", f"{'nested ' if ctx.prefix else ''}model `{ctx.file}` has no parameter `{name}`", octx, path,
                           hint=f"did you mean `{close[0]}`?" if close else
                           f"its parameters are: {', '.join(sorted(entries)) or 'none'}", key=True)
                continue
            entries[name] = (value, path, octx)
        self.add_parameters(ctx, entries, units)
        deferred = []
        for cname, comp in spec.components.items():
            full = ctx.prefix + cname
            path = ("components", cname)
            if full in self.applied.skip:
                continue
            if isinstance(comp, ModelComponentSpec):
                found = self._nested_ref(ctx, comp.file, (*path, "file"))
                if found is None:
                    self.failed.add(full)
                    continue
                sub, real = found
                ov = {k: (v, (*path, "parameters", k), ctx) for k, v in comp.parameters.items()}
                sub_ctx = self.load_file(sub, full + ".", ov, ctx, (*path, "file"), real, comp.file)
                if sub_ctx is None:
                    self.failed.add(full)
                else:
                    for pname, exposed in sub_ctx.spec.ports.items():
                        self.port_aliases[f"{full}.{pname}"] = sub_ctx.prefix + exposed.port
                continue
            if comp.type in MODULATED or state_reads(comp):  # reads other components' states: lower it last
                deferred.append((cname, comp, full, path))
                continue
            self._lower(LOWERERS, ctx, full, comp, path)
        for cname, comp, full, path in self._reading_order(ctx, deferred):
            self._lower(LOWERERS, ctx, full, comp, path)
        for i, conn in enumerate(spec.connections):
            if self._skipped(ctx, conn.between[0]):
                continue
            a, b = (ctx.prefix + ref for ref in conn.between)
            # labelled as the user finds it: `connections[0]` at the top level, `inner.connections[0]`
            # in the file nested as `inner` (unique across the model: certificates are keyed by it)
            self.connections.append((a, b, ctx.smap.locate(("connections", i)), f"{ctx.prefix}connections[{i}]"))
        self._check_refs(ctx)

    def _reading_order(self, ctx: FileContext, deferred: list) -> list:
        """The deferred components in the order :func:`phc.ir.interconnect.reading_order` gives;
        PHC-E128 at each one on a cycle (those and the ones reading them are not lowered).
        Signal blocks may read each other in a cycle: a block read before it is lowered has
        its outputs as variables of the model (placeholders in :attr:`signals` until it is
        lowered, :func:`phc.library.signal.lower_state_space`); an algebraic loop among them
        is refused once the model is assembled (PHC-E128, :func:`phc.ir.assemble.assemble`)."""
        from phc.library.signal import output_names
        from phc.library.registry import find

        blocks = {cname for cname, comp, *_ in deferred if (entry := find(comp.type)) is not None and entry.signal}
        order, cycles, early = reading_order([(cname, comp) for cname, comp, *_ in deferred],
                                             cut=lambda reader, read: reader in blocks and read in blocks)
        for cname, comp, full, path in deferred:
            if cname in early:  # read before it is lowered: its outputs are variables (phc.library.signal)
                self.signals.update((name, sp.Symbol(name, real=True)) for name in output_names(full, comp))
        placed = set(order)
        for cname, comp, full, path in deferred:
            if cname in placed:
                continue
            self.failed.add(full)
            if cname in cycles:
                self.error("PHC-E128", f"`{cname}` is on a cycle of components that read each other "
                           f"({', '.join(f'`{r}`' for r in cycles[cname])}): phc lowers a component after the "
                           "ones it reads, and a cycle has no such order", ctx, path,
                           hint="write blocks that feed each other as one `state_space` block (its A, B, C, D "
                           "combine theirs), reading the plant only")
        by_name = {item[0]: item for item in deferred}
        return [by_name[cname] for cname in order]

    def _lower(self, lowerers, ctx, full, comp, path) -> None:
        if full in self.applied.effects:
            from phc.frontend.effects import apply_overrides

            overrides, span = self.applied.effects[full]
            comp, problem = apply_overrides(comp, overrides)
            if problem:
                self.diags.append(Diagnostic("PHC-E601", f"effects of `{full}`: {problem}", span=span,
                                             path=f"effects.{full}"))
                self.failed.add(full)
                return
        if _has_field(comp, "elements"):
            self.written_meshes[full] = comp.elements  # what per-dof initial values were written for
        if full in self.applied.shapes:
            shape, span = self.applied.shapes[full]
            if "initial_shape" not in type(comp).model_fields:
                self.diags.append(Diagnostic("PHC-E603", f"`{full}` ({comp.type}) has no `initial_shape`; a scene's "
                                             "`initial_shape` applies to moving beams", span=span))
                self.failed.add(full)
                return
            comp = comp.model_copy(update={"initial_shape": shape})
        if full in self.applied.meshes:
            elements, span = self.applied.meshes[full]
            if not _has_field(comp, "elements"):
                self.diags.append(Diagnostic("PHC-E603", f"`{full}` ({comp.type}) has no mesh; `accuracy.mesh` "
                                             "applies to distributed components", span=span))
                self.failed.add(full)
                return
            comp = comp.model_copy(update={"elements": elements})
        if _has_field(comp, "elements"):
            self.meshes[full] = (comp.type, comp.elements)
            from phc.frontend.budget import admit_mesh

            # estimated before any discretization
            self.mesh_ledger, refused = admit_mesh(self.mesh_ledger, ctx, full, comp, path,
                                                   self.applied.meshes.get(full))
            if refused is not None:
                self.diags.append(refused)
                self.failed.add(full)
                return
        self.components.append((full, comp.type, ctx.smap.locate(path)))
        self.component_specs[full] = comp
        context = self._lowering_context()
        key = self.shared.key(ctx, full, comp, path, len(self._default_values), len(self.unset_parameters))
        lowering = self.shared.lower(key, lowerers[comp.type], context, ctx, full, comp, path)
        self._fold(lowering)
        if lowering.errors:
            self.failed.add(full)  # its ports may be missing: do not report them again
        elif self.units:
            self._check_field_units(ctx, full, comp, path, key)

    def _lowering_context(self):
        """What the next lowerer may read of the model so far: read-only views, no copies
        (nothing changes them while it runs)."""
        from phc.frontend.lowering import LoweringContext, ReadOnlySequence

        self._sync_defaults()  # the defaults of parameters added since
        # its views are live, so the last context serves while what it copied is unchanged
        made_of = (len(self.unset_parameters), self.override_note, self.files)
        if self._context is not None and self._context[0] == made_of:
            return self._context[1]
        ro = MappingProxyType
        context = LoweringContext(default_values=ro(self._default_values), variables=ReadOnlySequence(self.variables),
                               ports=ro(self.ports), unset_parameters=frozenset(self.unset_parameters),
                               units=ro(self.units), unit_text=ro(self.unit_text), override_note=self.override_note,
                               files=self.files, signals=ro(self.signals))
        self._context = (made_of, context)
        return context

    def _fold(self, lowering) -> None:
        """Append one component's :class:`~phc.frontend.lowering.ComponentLowering` to the model:
        its rows after the rows so far (its sparse blocks' row indices shifted with them),
        its definitions, ports, terms and diagnostics."""
        self.diags.extend(lowering.diagnostics)
        for key, entries in lowering.field_dims:
            self.field_dims.setdefault(key, []).extend(entries)
        start = len(self.equations)
        self.variables.extend(lowering.variables)
        self.equations.extend(lowering.equations)
        self.linear_blocks.extend(dataclasses.replace(block, rows=shifted_rows(block.rows, start))
                                  for block in lowering.linear_blocks)
        for sym, expr in lowering.definitions:
            self.definitions[sym] = expr
            self.defined_by[sym] = lowering.component
        self.hand_written |= lowering.hand_written
        self.ports.update((port.name, port) for port in lowering.ports)
        for port in lowering.ports:
            self.ports_of.setdefault(port.component, []).append(port)
        self.parameters.update((p.name, p) for p in lowering.parameters)
        self.dirac.extend(lowering.descriptions)
        self.hamiltonian.extend(lowering.hamiltonian)
        self.dissipation.extend(lowering.dissipation)
        self.source_power.extend(lowering.source_power)
        self.supplied.extend(lowering.supplied)
        self.quadratic_energy.extend(lowering.quadratic_energy)
        self.quadratic_dissipation.extend(lowering.quadratic_dissipation)
        self.invariants.extend(lowering.invariants)
        self.velocity_invariants.extend(lowering.velocity_invariants)
        self.resistive_laws.extend(lowering.resistive_laws)
        self.rigid_constraints.extend(lowering.rigid_constraints)
        self.extra_outputs.update(lowering.extra_outputs)
        self.signals.update(lowering.signals)
        self.initial_relations.extend(lowering.initial_relations)
        self.position_maps.extend(lowering.position_maps)
        self.compile_time_parameters |= lowering.compile_time_parameters
        self.initial_fields.update(lowering.initial_fields)
        self.unavailable.update(lowering.unavailable)
        self.left_out.extend(lowering.left_out)
        self.failed |= lowering.failed

    def _check_field_units(self, ctx: FileContext, full: str, comp, path, kind=None) -> None:
        """Fields whose dimension the component knows from its domain (a spring's `k` is
        effort per displacement) must have it when their expression's dimension is known
        (PHC-E172). `kind`: the component's key among identical ones
        (:meth:`phc.frontend.lowering.SharedLowerings.key`, None: none), whose expected fields and
        scale terms are found once. Once a component of a kind has passed without a word, the
        next ones of that kind pass too (the same fields, expressions and domains; what the
        first one added to the system of units is there, and adding it again changes
        nothing), and are not checked again (issue 38)."""
        from phc.frontend.units import NUMBER, ScaleSystem, describe, expected_fields, scale_terms

        if kind is not None and kind in self._fields_clean:
            return  # one of its kind (so with the same ports and domains) passed: so does this one
        domains = {port.name[len(full) + 1:]: port.domain for port in self.ports_of.get(full, ())
                   if self.ports.get(port.name) is port}  # its own ports, not a scan of all
        found = None if kind is None else self._kinds.get((kind, frozenset(domains.items())))
        if found is None:
            found = (scale_terms(comp, domains), expected_fields(comp, domains))
            if kind is not None:
                self._kinds[(kind, frozenset(domains.items()))] = found
        terms, expected = found
        n_diags = len(self.diags)
        for field_name, want, meaning in expected:
            prefix = (*path, field_name)
            for where, dim in self.field_dims.get((id(ctx.smap), prefix[:3]), ()):
                if where[:len(prefix)] != prefix or dim is None or dim is NUMBER:
                    continue
                self.fields_checked = True
                same, other_dimension, factor = self._compared(want, dim)
                if not same:
                    self.fields_si = False  # e.g. N/mm, MPa: the states are not in the domain's SI units
                if other_dimension:  # the scale is the model's choice (MPa, cm³)
                    value = getattr(comp, field_name, None)
                    shown = value if not isinstance(value, list) else "…"
                    self.error("PHC-E172", f"`{field_name}` of `{full}` ({comp.type}) must be {meaning}, but "
                               f"`{shown}` is in {describe(dim)}", ctx, where,
                               hint="check the units of the parameters it uses (or the component's `domain`)")
                    break
                if field_name in terms:
                    if self.scale_system is None:
                        self.scale_system = ScaleSystem()
                    self._check_scale(ctx, full, comp, field_name, where, want, dim, terms[field_name], factor)
        if kind is not None and len(self.diags) == n_diags:
            self._fields_clean.add(kind)

    def _compared(self, want, dim) -> tuple[bool, bool, float]:
        """(same dimension and scale, another dimension, :func:`~phc.frontend.units.scale_factor`) of a
        field's quantity `dim` and the one its type wants: pint's arithmetic once per pair (a
        chain's springs share both)."""
        from phc.frontend.units import same_dimension, scale_factor

        memo = self._pairs
        hit = memo.get((id(want), id(dim)))
        if hit is None:  # the quantities are kept with the answer: their ids stay theirs
            hit = memo[(id(want), id(dim))] = (same_dimension(want, dim),
                                               want.dimensionality != dim.dimensionality,
                                               scale_factor(dim, want), want, dim)
        return hit[0], hit[1], hit[2]

    def _check_scale(self, ctx: FileContext, full: str, comp, field_name: str, where, want, dim, coeffs,
                     factor: float) -> None:
        """A field's scale must fit the model's one system of units (phc.frontend.units.ScaleSystem):
        `k` in N/mm beside a mass in kg, or a speed in rpm, is refused with the factor
        (PHC-E172), since phc does not convert units. `factor`: `dim` over `want`
        (:func:`~phc.frontend.units.scale_factor`)."""
        from phc.frontend.units import scaled_label

        scale = math.log10(factor) if factor > 0 else float("nan")
        if not math.isfinite(scale):
            return
        expected = self.scale_system.add(coeffs, scale)
        if expected is None:
            return
        need = want * (10.0 ** expected)
        need_text = scaled_label(need)
        ratio = factor / 10.0 ** expected
        value = getattr(comp, field_name, None)
        sym = ctx.params.get(value.strip()) if isinstance(value, str) else None
        written = self.unit_text.get(sym) if isinstance(sym, sp.Symbol) else None
        shown = written or scaled_label(dim)
        param = self.parameters.get(sym.name) if isinstance(sym, sp.Symbol) else None
        if param is not None and written:
            hint = (f"give {value.strip()} in {need_text}: {param.default:g} {written} = {param.default * ratio:.4g} "
                    f"{need_text}")
        else:
            hint = f"give it in {need_text}: multiply the number by {ratio:.4g}"
        others = "in the units of the other fields of this model" if self.scale_system.rows else "in SI units"
        self.error("PHC-E172", f"`{field_name}` of `{full}` ({comp.type}) is in {shown}, but {others} it must be "
                   f"in {need_text}: the same dimension in another scale, and phc does not convert units "
                   f"(1 {shown} = {ratio:.4g} {need_text})", ctx, where,
                   hint=hint + " (docs/units.md: one system of units per model)")

    def _skipped(self, ctx: FileContext, ref: str) -> bool:
        return ctx.prefix + ref.split(".", 1)[0] in self.applied.skip

    def _check_refs(self, ctx: FileContext) -> None:
        """Check that connections and exposed ports of this file name existing ports."""
        spec = ctx.spec
        for i, conn in enumerate(spec.connections):
            if self._skipped(ctx, conn.between[0]):
                continue
            for j, ref in enumerate(conn.between):
                self._resolve_port(ctx, ref, ("connections", i, "between", j))
        for pname, exposed in spec.ports.items():
            self._resolve_port(ctx, exposed.port, ("ports", pname, "port"))

    def _resolve_port(self, ctx: FileContext, ref: str, path) -> Optional[Port]:
        full = self.resolve_alias(ctx.prefix + ref)
        if full in self.ports:
            return self.ports[full]
        if ctx.prefix + ref.split(".", 1)[0] in self.failed:
            return None
        local = [n[len(ctx.prefix):] for n in list(self.ports) + list(self.port_aliases)
                 if n.startswith(ctx.prefix) and "." not in n[len(ctx.prefix):].split(".", 1)[-1]]
        close = difflib.get_close_matches(ref, local, n=1)
        if "." not in ref:
            msg = f"`{ref}` is not a port reference; write `component.port`"
        else:
            msg = f"unknown port `{ref}`"
        self.error("PHC-E201", msg, ctx, path,
                   hint=f"did you mean `{close[0]}`?" if close else
                   (f"known ports: {', '.join(sorted(local)[:8])}" if local else None))
        return None

    def resolve_alias(self, name: str) -> str:
        return resolve_alias(self.port_aliases, name)


_FIELDS: dict = {}
"""Spec class -> the names of its fields (pydantic's ``model_fields``, read once per class:
its lookup on the class is a descriptor call, three per component)."""


def _has_field(spec, name: str) -> bool:
    """Whether the spec's class has the field `name`."""
    cls = type(spec)
    names = _FIELDS.get(cls)
    if names is None:
        names = _FIELDS[cls] = frozenset(cls.model_fields)
    return name in names


def resolve_alias(aliases: Mapping[str, str], name: str) -> str:
    """The port a (nested model's exposed) port name stands for, following `aliases`."""
    seen = set()
    while name in aliases and name not in seen:
        seen.add(name)
        name = aliases[name]
    return name


@dataclass(frozen=True, eq=False)
class Elaboration:
    """The output of the elaborate pass: every component lowered (its description, rows,
    variables and ports), with parameters, connections as written and what was left out.
    Read by :func:`phc.ir.interconnect.interconnect` and :func:`phc.ir.assemble.assemble`; no
    pass changes it (mappings are read-only views, ports are copied where assembly gives
    them positions)."""

    top: FileContext
    """The top-level file (its spec and source map locate `simulation:` entries)."""
    scene: Any
    variables: tuple[Variable, ...]
    equations: tuple[Equation, ...]
    parameters: Mapping[str, Parameter]
    default_values: Mapping
    definitions: Mapping
    ports: Mapping[str, Port]
    port_aliases: Mapping[str, str]
    hamiltonian: tuple
    dissipation: tuple
    source_power: tuple
    supplied: tuple
    """Declared controlled sources (:attr:`phc.frontend.lowering.ComponentLowering.supplied`)."""
    linear_blocks: tuple
    quadratic_energy: tuple
    quadratic_dissipation: tuple
    invariants: tuple
    velocity_invariants: tuple
    connections: tuple
    """As written: (port a, port b, source span, label), before aliases are resolved."""
    components: tuple
    component_specs: Mapping
    """Full name -> the component's spec as lowered (scene overrides and effects applied)."""
    failed: frozenset
    descriptions: tuple
    rows: tuple
    rigid_constraints: tuple
    resistive_laws: tuple
    initial_relations: tuple
    position_maps: tuple
    extra_outputs: Mapping
    compile_time_parameters: frozenset
    meshes: Mapping
    mesh_spans: Mapping
    """Distributed component -> the span of its mesh (for size diagnostics)."""
    left_out: tuple
    unavailable: Mapping
    sources: tuple
    files: FileAccess
    initial_fields: Mapping = field(default_factory=lambda: MappingProxyType({}))
    """Distributed component -> its :class:`phc.ir.initial_fields.FieldSet` (what initial fields project onto)."""
    written_meshes: Mapping = field(default_factory=lambda: MappingProxyType({}))
    """Distributed component -> `elements` as its model file gives it (per-dof initial values belong to it)."""
    units: Mapping = field(default_factory=lambda: MappingProxyType({}))
    """Parameter symbol -> its unit (a pint quantity in SI base units; :mod:`phc.frontend.units`)."""
    unit_text: Mapping = field(default_factory=lambda: MappingProxyType({}))
    """Parameter symbol -> its unit as written."""
    units_si: bool = False
    """Some parameters have units and all of them are coherent SI units: port variables and
    storage states then carry their domain's SI units (docs/units.md)."""
    fields_si: bool = False
    """Some component fields have a known dimension and all of them are in coherent SI units
    (a spring's `k` in N/m, not N/mm): the lumped storage states are then in their domain's
    SI units, and an initial value in another scale (mm) is refused (docs/units.md)."""
    scales: Mapping = field(default_factory=lambda: MappingProxyType({}))
    """The model's system of units solved from its fields' units (phc.frontend.units.ScaleSystem):
    log10 of its time unit in s (`"T"`) and of each domain's effort and flow unit in SI
    (`("E", domain)`, `("F", domain)`); what no field fixes is SI."""

    def resolve_alias(self, name: str) -> str:
        return resolve_alias(self.port_aliases, name)


def _finish(b: _Elaborator, ctx: FileContext) -> Elaboration:
    ro = MappingProxyType
    return Elaboration(
        top=ctx, scene=b.scene, variables=tuple(b.variables), equations=tuple(b.equations),
        parameters=ro(dict(b.parameters)), default_values=ro(b.default_values()),
        definitions=ro(dict(b.definitions)), ports=ro(dict(b.ports)), port_aliases=ro(dict(b.port_aliases)),
        hamiltonian=tuple(b.hamiltonian), dissipation=tuple(b.dissipation), source_power=tuple(b.source_power),
        supplied=tuple(b.supplied), linear_blocks=tuple(b.linear_blocks), quadratic_energy=tuple(b.quadratic_energy),
        quadratic_dissipation=tuple(b.quadratic_dissipation), invariants=tuple(b.invariants),
        velocity_invariants=tuple(b.velocity_invariants), connections=tuple(b.connections),
        components=tuple(b.components), component_specs=ro(dict(b.component_specs)), failed=frozenset(b.failed), descriptions=tuple(b.dirac),
        rows=b.component_rows(), rigid_constraints=tuple(b.rigid_constraints),
        resistive_laws=tuple(b.resistive_laws), initial_relations=tuple(b.initial_relations),
        position_maps=tuple(b.position_maps), extra_outputs=ro(dict(b.extra_outputs)),
        compile_time_parameters=frozenset(b.compile_time_parameters), meshes=ro(dict(b.meshes)),
        mesh_spans=ro(b.mesh_ledger.spans), left_out=tuple(b.left_out), unavailable=ro(dict(b.unavailable)),
        sources=tuple(b.sources), files=b.files, initial_fields=ro(dict(b.initial_fields)),
        written_meshes=ro(dict(b.written_meshes)), units=ro(dict(b.units)), unit_text=ro(dict(b.unit_text)),
        units_si=b.units_declared and b.units_si,
        fields_si=b.units_declared and b.fields_checked and b.fields_si,
        scales=ro(b.scale_system.solution() if b.scale_system is not None else {}))


def _where(span) -> str:
    return f"{span.file}:{span.line}:{span.col}" if span is not None else "the scene"


def elaborate(path: str | os.PathLike, scene=None, params: Optional[Mapping[str, float]] = None
              ) -> tuple[Optional[Elaboration], DiagnosticList]:
    """The elaborate pass: read a model file (and the files it nests), apply `scene` (a
    :class:`phc.frontend.scene.Scene`: overrides, effects, pruning) and lower every component.
    `params` overrides top-level parameters by name (over the scene's), as values from
    outside the files: the checks of values written in the file apply to them too.

    Returns ``(elaboration, diagnostics)``; `elaboration` is None only when the top-level
    file could not be read. With errors it is still returned, so that the interconnect
    pass can report wiring problems too (components that failed are skipped there).
    """
    state = _Elaborator()
    state.scene = scene
    state.param_overrides = dict(params or {})
    ctx = state.load_file(Path(path), "", {}, None)
    if ctx is None:
        return None, state.diags.sorted()
    return _finish(state, ctx), state.diags
