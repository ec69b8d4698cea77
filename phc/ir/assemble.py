"""The assemble pass: lowered, interconnected components into one flat :class:`~phc.ir.dae.Dae`.

Input: an :class:`phc.frontend.elaborate.Elaboration` and its :class:`phc.ir.interconnect.Interconnection`.
Output: ``(Dae or None, diagnostics)``. The elaboration is not changed.

Order matters:

1. (done by the interconnect pass: existence, compatibility, each port used once, no
   dangling port);
2. merge connected port variables by a signed union–find (``f₁ = f₂``, ``e₁ = −e₂``, the
   coupling condition of T. Berger, R. Hochdahl, T. Reis, R. Seifried, "Port-Hamiltonian
   modelling of coupled rigid/flexible multibody systems", section 2.2; a wire, a terminal
   of a two-terminal element joined to a port that reads power-in, ``e₁ = e₂``,
   ``f₁ = −f₂``: :mod:`phc.ir.wires`) and substitute component-defined port values;
3. add position invariants of connected ports with positions, and the GGL multipliers
   for all position invariants: the storage flow of each constrained configuration
   variable becomes ``ẋ + (∂g/∂x)ᵀη`` (Gear, Gupta & Leimkuhler 1985), which keeps
   ``g(x) = 0`` at position level with index 2;
4. top-level exposed ports get their inputs (default: free, zero effort);
5. the energy accumulator ``Ė = P_ports + P_diss`` so that
   ``H(t) − H(0) + E(t)`` is the energy-balance residual (the paper's remark on the
   energy balance); P_ports holds the work of moving constraints (−λᵀc_t, booked by the
   rigid lowerer) and an explicit time dependence of H (−∂H/∂t).
"""

from __future__ import annotations

import difflib
from typing import Optional

import sympy as sp

from phc.ir.dae import (STORED_ENERGY, T, Dae, Equation, InitialValue, Invariant, LinearBlock, PortInfo, TermSum,
                     Topology, Variable, shifted_rows)
from phc.ir.alike import AlikeReplacer
from phc.diagnostics import Diagnostic, DiagnosticList
from phc.frontend.inputs import SignalBuilder
from phc.spec.expressions import named_scope
from phc.spec.model import InitialSpec, OutputSpec, PieceSpec
from phc.frontend.state_hints import unknown_state
from phc.frontend.units import ResultUnits
from phc.ir.wires import BOND, WIRE, wire_labels


def _signed(sign: int, expr):
    """``sign·expr`` for a sign ±1, without sympy's product for +1 (on a 10⁴-component
    chain `1 * x` cost seconds in the alias resolution)."""
    return expr if sign == 1 else -expr


def _copied(port):
    """A shallow copy of a :class:`~phc.frontend.reporter.Port` (``dataclasses.replace(port)``:
    the same fields, no ``__init__`` run; measured about 0.04 s against 0.1 s for the 2·10⁴
    ports of a chain of 10⁴ components)."""
    new = object.__new__(type(port))
    new.__dict__.update(port.__dict__)
    return new


class _SignedUnionFind:
    """x = s·root bookkeeping for alias elimination."""

    def __init__(self) -> None:
        self.parent: dict[sp.Symbol, tuple[sp.Symbol, int]] = {}

    def find(self, x):
        parent = self.parent
        up = parent.get(x)  # one lookup a step (a symbol's hash is a Python call)
        if up is None:
            return x, 1
        root, sign = up
        up = parent.get(root)
        if up is None:  # x's parent is its root: nothing to compress (most calls)
            return root, sign
        path = [(x, 1)]
        while up is not None:
            path.append((root, sign))
            root, s = up
            sign *= s
            up = parent.get(root)
        for node, s0 in path:  # path compression
            parent[node] = (root, sign * s0)
        return root, sign

    def union(self, a, b, sign):
        """Impose a = sign·b. Returns (root_a, root_b, rel) with root_a = rel·root_b, or None if same class."""
        ra, sa = self.find(a)
        rb, sb = self.find(b)
        rel = sign * sb * sa
        if ra == rb:
            return ra, rb, rel
        self.parent[ra] = (rb, rel)
        return ra, rb, rel


def assemble(elab, inter) -> tuple[Optional[Dae], DiagnosticList]:
    """The assemble pass. Input: an :class:`phc.frontend.elaborate.Elaboration` and its
    :class:`phc.ir.interconnect.Interconnection` (without errors). Output: the flat
    :class:`Dae` (None when assembly found errors) and the diagnostics it found (inputs,
    outputs and initial values are parsed here: they refer to the assembled variables).
    The elaboration is only read; what assembly extends (port positions, invariants,
    initial relations) are its own copies."""
    from phc.frontend.budget import check_assembled
    from phc.frontend.reporter import Reporter

    reporter = Reporter(elab.files)
    dae = _assemble(elab, reporter, elab.top, inter)
    if dae is not None:
        reporter.diags.extend(_reading_loops(dae))
        reporter.diags.extend(check_assembled(elab, dae))  # exact size and output arrays, before any code is generated
    return (None if reporter.diags.has_errors else dae), reporter.diags


def _reading_loops(dae: Dae) -> list[Diagnostic]:
    """PHC-E129 at each reading of a port variable that depends on its reader's own output
    within the same instant, PHC-E128 at each signal block output that depends on itself
    (:func:`phc.analysis.matching.reading_loops`)."""
    from phc.analysis.matching import reading_loops

    out = []
    for j, loop in reading_loops(dae):
        v = dae.variables[j]
        if v.role == "signal":
            # the blocks whose variables the loop's rows hold (an output substituted into
            # another block's row brings that block's states)
            blocks = {eq.component for eq in dae.equations if eq.kind == "signal"}
            owner = {x.symbol: x.component for x in dae.variables} | {
                x.dsymbol: x.component for x in dae.variables if x.dsymbol is not None}
            held = {owner[s] for i in loop for s in dae.equations[i].expr.free_symbols if s in owner}
            on = [v.component, *sorted(held & blocks - {v.component})]
            out.append(Diagnostic(
                "PHC-E128", f"the output `{v.name}` depends on itself at the same instant: the blocks "
                f"{', '.join(f'`{c}`' for c in on)} read each other with feedthrough all round (an algebraic loop)",
                span=v.span, path=f"components.{v.component}",
                hint="put a block without feedthrough (`D` zero: its output is its state's) in the loop, or write "
                "the blocks as one `state_space` block (its A, B, C, D combine theirs)"))
            continue
        read = v.name[len(v.component) + len(".reads("):-1]
        # the sources (and ratios) whose relation reads the reader's output, directly or through blocks
        drivers = [rel.component for rel in dae.topology.dirac
                   if any(str(s).startswith(v.component + ".") for s in rel.states)]
        on = [c for i in loop if (c := dae.equations[i].component) not in ("", "energy", v.component)]
        through = list(dict.fromkeys([*drivers, *on]))
        cycle = " → ".join(f"`{c}`" for c in [v.component, *through, read, v.component])
        out.append(Diagnostic(
            "PHC-E129", f"`{v.component}` reads `{read}`, on which its own output acts at the same instant: an "
            f"algebraic loop {cycle}", span=v.span, path=f"components.{v.component}",
            hint="read a variable that the output acts on only through a storage element (a state, a coil's "
            "current, a mass's velocity), or put a block without feedthrough (a lag, D = 0) in the loop"))
    return out


def _assemble(elab, rep, ctx, inter) -> Optional[Dae]:
    """The assembled :class:`Dae` of `elab`; problems go to the reporter `rep`."""
    ports = {name: _copied(port) for name, port in elab.ports.items()}  # positions are given below
    position_invariants = list(elab.invariants)  # and those of connected ports with positions
    connections = [(ports[pa.name], ports[pb.name], span, label) for pa, pb, span, label in inter.connections]
    uf = _SignedUnionFind()
    defs = dict(elab.definitions)
    rows: list[Equation] = list(elab.equations)

    def merge(x, y, sign, label, span):
        ra, rb, rel = uf.union(x, y, sign)
        if ra == rb:
            return
        da, db = defs.pop(ra, None), defs.get(rb)
        if da is not None and db is not None:
            rows.append(Equation(da - _signed(rel, db), label, "coupling", "", span))
        elif da is not None:
            defs[rb] = _signed(rel, da)

    _propagate_positions(ports, elab.position_maps, connections, rep)
    # a terminal joined to a port that reads power-in is a wire (e_x = e_y, f_x = −f_y), every
    # other connection a bond (f_x = f_y, e_x = −e_y): phc.ir.wires, docs/signs.md
    wires = wire_labels(ports.values(), elab.component_specs, ((pa, pb, label) for pa, pb, _, label in connections))
    for pa, pb, span, label in connections:
        sf, se = WIRE if label in wires else BOND
        for k in range(pa.dimension):
            merge(pa.f[k], pb.f[k], sf, f"{label}.f[{k}]", span)
            merge(pa.e[k], pb.e[k], se, f"{label}.e[{k}]", span)
        if pa.position is not None and pb.position is not None:
            for k in range(pa.dimension):
                position_invariants.append(Invariant(f"{label}.position[{k}]", pa.position[k] - pb.position[k],
                                                     "", span))

    # Top-level exposed ports: inputs or free.
    sim = ctx.spec.simulation
    signals = SignalBuilder(elab)
    exposed_power = []  # f·e of each exposed port, summed once below (+= per port was quadratic)
    external = []
    for pname, (full, span) in inter.exposed.items():
        port = ports[full]
        external.append(pname)
        inp = sim.inputs.get(pname)
        path = ("simulation", "inputs", pname)
        if inp is None:
            targets, values = port.e, [0] * port.dimension
        else:
            which = "effort" if inp.effort is not None else "flow"
            targets = port.e if which == "effort" else port.f
            signals.expect, signals.scales = (port.domain, which, pname), dict(getattr(elab, "scales", {}) or {})
            values = _signals(rep, ctx, signals, getattr(inp, which), (*path, which), port.dimension,
                              f"input {which} of `{pname}`")
        for k, (sym, val) in enumerate(zip(targets, values)):
            root, sign = uf.find(sym)
            if root in defs:
                rows.append(Equation(sign * defs[root] - val, f"inputs.{pname}[{k}]", "input", "", span))
            else:
                defs[root] = sign * (val if isinstance(val, sp.Basic) else sp.Integer(val))
        exposed_power.extend(fk * ek for fk, ek in zip(port.f, port.e))
    for pname in sim.inputs:
        if pname not in inter.exposed:
            close = difflib.get_close_matches(pname, list(inter.exposed), n=1)
            rep.error("PHC-E209", f"input for `{pname}`, which is not an exposed port of the model", ctx,
                      ("simulation", "inputs", pname), key=True,
                      hint=f"did you mean `{close[0]}`?" if close else "expose the port under `ports:` first")

    subs = _resolve_definitions(uf, defs, rows)

    # GGL stabilization of position invariants.
    states = {v.symbol: v for v in elab.variables if v.differential}
    variables = [v for v in elab.variables if v.differential or (uf.find(v.symbol)[0] == v.symbol
                                                                and v.symbol not in defs)]
    corrections: dict[sp.Symbol, sp.Expr] = {}
    invariants = []
    for i, inv in enumerate(position_invariants):
        g = inv.expr.xreplace(subs)
        xs = sorted(g.free_symbols & set(states), key=lambda s: s.name)
        if not xs:
            continue
        invariants.append(Invariant(inv.label, g, inv.component, inv.span))
        eta = sp.Symbol(f"ggl.eta[{len(invariants) - 1}]", real=True)
        variables.append(Variable(eta.name, eta, False, "multiplier", inv.component or "ggl", None, inv.span))
        rows.append(Equation(g, f"{inv.label}", "position_constraint", inv.component, inv.span))
        for x in xs:
            corrections[x] = corrections.get(x, 0) + sp.diff(g, x) * eta
    dsubs = {states[x].dsymbol: states[x].dsymbol + c for x, c in corrections.items()}

    _contact_forces(elab, rows, states)

    alike = AlikeReplacer(subs)  # rows alike but for their names: one sympy rebuild per shape

    def final(expr):
        return alike(expr).xreplace(dsubs) if dsubs else alike(expr)

    equations = []
    new_index: dict[int, int] = {}
    constants = {T} | {p.symbol for p in elab.parameters.values()}  # once: per row it made assembly quadratic
    for i, eq in enumerate(rows):
        if eq.kind == "linear" and eq.expr is sp.S.Zero:  # a row of a sparse block (most rows of a mesh)
            new_index[i] = len(equations)
            equations.append(eq)
            continue
        ex = final(eq.expr)
        if ex.is_Number and ex == 0 and eq.kind != "linear":  # a sum or product is never `== 0`
            continue
        # is_number first: it stops at a row's first symbol, free_symbols walks the whole row
        if (eq.kind != "linear" and ex.is_number and ex != 0
                and not (ex.free_symbols - constants)):
            rep.diags.append(Diagnostic("PHC-E301", f"equation `{eq.label}` reduces to the contradiction "
                                        f"{ex} = 0", span=eq.span))
            continue
        new_index[i] = len(equations)
        equations.append(Equation(ex, eq.label, eq.kind, eq.component, eq.span))
    linear_blocks = []
    for block in elab.linear_blocks:
        for term in block.terms:
            for sym in term.symbols:  # sparse blocks refer to internal variables only
                if sym in subs and subs[sym] != sym:
                    raise AssertionError(f"linear block `{block.label}` refers to the port variable `{sym}`")
        linear_blocks.append(LinearBlock(block.label, block.component, shifted_rows(block.rows, new_index.__getitem__),
                                         block.terms, block.span))

    # sp.Add(*terms) is linear in the number of terms; Python's sum() re-canonicalizes
    # the growing Add at every step (quadratic, visible at a few hundred components).
    # The sum itself is built only when something reads it (a TermSum, phc.ir.dae): the
    # checks below read its terms, validation never needs it in sympy's canonical order.
    energy_terms = TermSum(final(h) for h in elab.hamiltonian)
    written_h = energy_terms.unevaluated()
    hamiltonian = energy_terms
    dissipation_terms = tuple((component, final(d), span) for component, d, span in elab.dissipation)
    dissipation = sp.Add(*[d for _, d, _ in dissipation_terms])
    port_power = final(sp.Add(*exposed_power, *elab.source_power))
    h_symbols = written_h.free_symbols
    if T in h_symbols:
        # An explicit time dependence of H (a potential V(q, t), a mass matrix M(t), a
        # coefficient k(t)) is energy exchanged with whatever varies it: dH/dt = ∇H·ẏ + ∂H/∂t,
        # so the model delivers −∂H/∂t and H(t) − H(0) + E(t) stays the balance residual.
        hamiltonian = energy_terms.build()
        port_power = port_power - sp.diff(hamiltonian, T)
    energy = sp.Symbol("energy.supplied", real=True)
    denergy = sp.Symbol("der(energy.supplied)", real=True)
    variables.append(Variable(energy.name, energy, True, "energy", "energy", denergy, None))
    equations.append(Equation(denergy - port_power - dissipation, "energy.balance", "energy", "energy", None))

    if isinstance(hamiltonian, TermSum) and any(
            "H" in str(ospec.value if isinstance(ospec, OutputSpec) else ospec) for ospec in sim.outputs.values()):
        hamiltonian = energy_terms.build()  # an output may read `H` (the text is not parsed yet)
    scope = _output_scope(elab, subs, hamiltonian)
    rates = _rate_scope(elab, subs)
    if elab.quadratic_energy:
        # the distributed components' H too: the generated `outputs` takes the value of the
        # module's `hamiltonian` (sparse quadratic forms), never a sum written out term by term
        scope["H"] = STORED_ENERGY
    outputs = []
    result_units = ResultUnits(rep, elab, variables, written_h, h_symbols)  # its unit: that of the terms
    for oname, ospec in sim.outputs.items():
        opath = ("simulation", "outputs", oname)
        oexpr, vpath = (ospec.value, (*opath, "value")) if isinstance(ospec, OutputSpec) else (ospec, opath)
        missing = [name for name in elab.unavailable if isinstance(oexpr, str) and name in oexpr]
        if missing:
            rep.error("PHC-E604", f"output `{oname}` uses `{missing[0]}`, but {elab.unavailable[missing[0]]}", ctx,
                      opath, hint="turn the effect on, or drop the output")
            continue
        oval = final(rep.expr(ctx, oexpr, vpath, scope, check_units=False, rates=rates))
        factor = result_units.output(ctx, oname, oexpr, vpath, getattr(ospec, "unit", None), (*opath, "unit"))
        outputs.append((oname, oval if factor is None else oval * sp.Float(factor)))  # into its declared unit
    # a contact's gap, its rate, normal and restitution are outputs the simulation reads at
    # impacts (phc.library.contact, phc.simulation.impacts)
    contacts = [name for name, cspec in elab.component_specs.items() if getattr(cspec, "type", None) == "contact"]
    taken = {name for name, _ in outputs}
    for name, expr in elab.extra_outputs.items():
        if any(name.startswith(c + ".") for c in contacts) and name not in taken:
            outputs.append((name, final(expr)))
    velocity_invariants = tuple(Invariant(v.label, final(v.expr), v.component, v.span)
                                for v in elab.velocity_invariants)
    states_named = {v.name for v in variables if v.differential}
    initial, initial_relations, compile_time = _initial_values(elab, rep, ctx, states_named, result_units)
    topology = Topology(
        components=tuple(elab.components),
        ports=tuple(PortInfo(p.name, p.component, p.domain, p.dimension, p.frame, p.span) for p in ports.values()),
        connections=tuple((pa.name, pb.name, label, span) for pa, pb, span, label in connections),
        wires=wires,
        exposed=tuple((pname, full) for pname, (full, _) in inter.exposed.items()),
        dirac=tuple(elab.descriptions),
        rows=tuple(elab.rows),
        specs=dict(elab.component_specs),
        rigid_constraints=tuple(elab.rigid_constraints),
        resistive_laws=tuple(elab.resistive_laws),
        parameter_defaults=dict(elab.default_values),
        initial={sp.Symbol(iv.name, real=True): iv.value for iv in initial},
    )
    return Dae(
        topology=topology,
        initial_relations=tuple(initial_relations),
        compile_time_parameters=tuple(sorted(_base_parameters(elab.parameters, compile_time))),
        name=ctx.spec.name or ctx.file.rsplit("/", 1)[-1].rsplit(".", 1)[0],
        variables=tuple(variables),
        equations=tuple(equations),
        parameters=tuple(elab.parameters.values()),
        hamiltonian=hamiltonian,
        dissipation=dissipation,
        dissipation_terms=dissipation_terms,
        supply_terms=tuple((component, port, final(power), span) for component, port, power, span in elab.supplied),
        port_power=port_power,
        invariants=tuple(invariants),
        velocity_invariants=velocity_invariants,
        outputs=tuple(outputs),
        initial=tuple(initial),
        external_ports=tuple(external),
        sources=tuple(elab.sources),
        linear_blocks=tuple(linear_blocks),
        quadratic_energy=tuple(elab.quadratic_energy),
        quadratic_dissipation=tuple(elab.quadratic_dissipation),
        input_tables=tuple(signals.tables),
        breakpoints=tuple(sorted(signals.breakpoints)),
        options={"t_start": sim.t_start, "t_end": sim.t_end, "n_out": sim.n_out, "rtol": sim.rtol,
                 "atol": sim.atol, "max_steps": sim.max_steps, "solver": sim.solver,
                 "max_order": sim.max_order, "step": sim.step,
                 "nominal": _nominal_scales(rep, ctx, {v.name for v in variables if v.differential}, elab)},
        units=dict(result_units.labels),
        left_out=elab.left_out,
        meshes=dict(elab.meshes),
    )


def _signals(rep, ctx, signals, value, path, dimension, what) -> list:
    """The input signal(s) of a port: one per component (a scalar port takes one signal)."""
    scope = {"t": T, **ctx.params}
    is_vector = isinstance(value, list) and not (value and isinstance(value[0], PieceSpec))
    items = value if is_vector else [value]
    if len(items) != dimension:
        rep.error("PHC-E102", f"{what} has {len(items)} entries, expected {dimension}", ctx, path)
        return [sp.Integer(0)] * dimension
    return [signals.signal(rep, ctx, v, (*path, i) if is_vector else path, scope) for i, v in enumerate(items)]


def _base_parameters(parameters, symbols) -> set[str]:
    """Names of the base parameters (of `parameters`, by name) the given parameter symbols depend on."""
    by_symbol = {p.symbol: p for p in parameters.values()}
    out, todo = set(), [s for s in symbols if s in by_symbol]
    while todo:
        par = by_symbol[todo.pop()]
        if par.expr is None:
            out.add(par.name)
        else:
            todo.extend(s for s in par.expr.free_symbols if s in by_symbol)
    return out


def _propagate_positions(ports, position_maps, connections, rep) -> None:
    """Positions through orthogonal transforms: output ports (of `ports`, assembly's copies)
    get Q·r of the input's neighbour."""
    neighbour = {}
    for pa, pb, _, _ in connections:
        neighbour[pa.name], neighbour[pb.name] = pb, pa
    for _ in range(len(position_maps)):  # chains of transforms
        changed = False
        for a_name, outputs, Q in position_maps:
            nb = neighbour.get(a_name)
            if nb is None or nb.position is None or ports[outputs[0][0]].position is not None:
                continue
            if T in Q.free_symbols:
                # d/dt (Q(t) r) = Q ṙ + Q̇ r is not the flow Q f the transform passes on: the
                # position-level joint would contradict the velocity level (GGL would hide it).
                port = ports[a_name]
                rep.diags.append(Diagnostic(
                    "PHC-E127", f"`Q` of `{port.component}` depends on the time `t`, and the port "
                    f"`{nb.name}` connected to it has a position: the positions Q(t) r it would pass on "
                    "do not move with the flows Q(t) f", span=port.span, path=port.component,
                    hint="use a constant `Q` where positions pass through, or drop the `position` of the "
                    "neighbouring port"))
                continue
            r = Q * sp.Matrix(nb.position)
            for out_name, lo, hi in outputs:
                ports[out_name].position = [r[k] for k in range(lo, hi)]
            changed = True
        if not changed:
            break


def _contact_forces(elab, rows: list, states: dict) -> None:
    """The force λ of each `contact` (:mod:`phc.library.contact`) acts on the momenta its gap
    names: the row holding ṗ_j (a mass's or a rigid body's momentum balance, one row) gets
    ``ṗ_j = … + λ ∂g/∂x_j``. λ is zero while the contact is open; while it is closed its row
    holds ġ = 0, so the force does no work (λ ġ = 0 in both modes). In that row ġ = Σ n_j ẋ_j
    is written with each ẋ_j from the row that holds it (a mass's ẋ = p/m): a row without
    rates, like a velocity constraint, whose derivative (one differentiation, as consistent
    initialization takes it) determines λ. Friction (:func:`phc.library.contact._friction`)
    likewise: λ_t ∂s/∂x_j on the momenta, and the slip row ``v_t = ṡ`` in those velocities."""
    contacts = [c for c, spec in elab.component_specs.items() if getattr(spec, "type", None) == "contact"]
    if not contacts:
        return
    by_name = {v.name: v for v in states.values()}
    symbols = {v.name: v.symbol for v in elab.variables}
    rates = {v.dsymbol for v in states.values()}

    def holding(rate, skip=()):
        """The one row holding `rate` (affine in it, constant slope): (index, slope)."""
        found = [i for i, eq in enumerate(rows) if i not in skip and rate in eq.expr.free_symbols]
        slope = sp.diff(rows[found[0]].expr, rate) if len(found) == 1 else None
        if slope is None or not slope.is_number or slope == 0:
            raise AssertionError(f"contact: the rate `{rate}` is in {len(found)} rows (expected one, affine in it)")
        return found[0], slope

    contact_rows = {f"{c}.{r}" for c in contacts for r in ("closure", "slip")}
    for c in contacts:
        if f"{c}.force" not in symbols:
            continue  # the contact failed to lower (reported)
        # the normal force λ along ∂g/∂x_j; with friction the tangential force λ_t along ∂s/∂x_j
        for force, head, row in ((symbols[f"{c}.force"], f"{c}.normal.", f"{c}.closure"),
                                 (symbols.get(f"{c}.friction_force"), f"{c}.tangent.", f"{c}.slip")):
            if force is None:
                continue
            for name, normal in elab.extra_outputs.items():
                if name.startswith(head):
                    i, slope = holding(by_name[name[len(head):]].dsymbol)
                    eq = rows[i]
                    rows[i] = Equation(eq.expr - slope * force * normal, eq.label, eq.kind, eq.component, eq.span)
            closure = next(i for i, eq in enumerate(rows) if eq.label == row)
            # every contact's closure and slip rows hold rates before they are rewritten
            own = {i for i, eq in enumerate(rows) if eq.label in contact_rows}
            expr = rows[closure].expr
            for x in sorted(expr.free_symbols & rates, key=lambda s: s.name):
                i, slope = holding(x, skip=own)
                velocity = x - rows[i].expr / slope
                if velocity.free_symbols & rates:
                    raise AssertionError(f"contact `{c}`: the row holding `{x}` holds other rates")
                expr = expr.xreplace({x: velocity})
            eq = rows[closure]
            rows[closure] = Equation(expr, eq.label, eq.kind, eq.component, eq.span)


def _resolve_definitions(uf, defs, rows) -> dict:
    """Substitution symbol → expression for every aliased or defined port variable.

    A definition may refer to other defined symbols; they are resolved recursively.
    A cycle (a junction port wired back to the same junction) turns the definition
    back into an equation.
    """
    cache: dict = {}
    bounds: dict = {}  # resolved root -> a superset of its value's free symbols
    visiting: set = set()
    all_syms = set(uf.parent) | set(defs)

    def resolve_root(root):
        if root in cache:
            return cache[root]
        if root not in defs:
            cache[root] = root
            return root
        if root in visiting:
            return root
        visiting.add(root)
        expr = defs[root]
        free = expr.free_symbols
        rule = {s: value(s) for s in free if s in all_syms}
        if rule:  # else the definition is already resolved (a state's: -k·x), its symbols known
            expr = expr.xreplace(rule)  # small rules of short rows: sympy's (AlikeReplacer measured slower here)
            # what the value can hold: the symbols not replaced and those of the values put in
            # (a superset: a sum may cancel); walked again only when it holds `root`
            bound = free - rule.keys()
            for s in rule:
                r = uf.find(s)[0]
                bound.update(bounds.get(r, (r,)))
            free = expr.free_symbols if root in bound else bound
        visiting.discard(root)
        if root in free:
            rows.append(Equation(root - expr, f"{root.name}.definition", "coupling", "", None))
            del defs[root]
            cache[root] = root
            return root
        cache[root] = expr
        bounds[root] = free
        return expr

    values: dict = {}

    def value(sym):
        out = values.get(sym)
        if out is None:
            root, sign = uf.find(sym)
            out = resolve_root(root)
            out = _signed(sign, out)
            if root in cache:  # resolved (not a root met again on a cycle being resolved)
                values[sym] = out
        return out

    return {s: value(s) for s in all_syms}


def _rate_scope(elab, subs) -> dict:
    """The states' rates by name, for ``der(x)`` in outputs: ẋ is part of the solution."""
    return named_scope((v.name, subs.get(v.dsymbol, v.dsymbol)) for v in elab.variables
                       if v.differential and v.dsymbol is not None)


def _output_scope(elab, subs, hamiltonian) -> dict:
    scope: dict = {"t": T, "H": hamiltonian}
    scope.update(named_scope((v.name, subs.get(v.symbol, v.symbol)) for v in elab.variables))
    for p in elab.parameters.values():
        scope[p.name] = p.symbol
    vectors_extra: dict[str, dict[int, sp.Expr]] = {}
    for name, expr in elab.extra_outputs.items():  # component outputs such as a beam's w(ξ)
        value = expr.xreplace(subs)
        if name.endswith("]"):
            base, idx = name[:-1].rsplit("[", 1)
            vectors_extra.setdefault(base, {})[int(idx)] = value
        else:
            scope[name] = value
    for base, items in vectors_extra.items():
        scope[base] = [items[i] for i in sorted(items)]
    return scope


def _nominal_scales(rep, ctx, state_names: set[str], elab) -> dict[str, float]:
    """`simulation.nominal`: the user's nominal scales by state (docs/tolerances.md)."""
    out = {}
    for name, value in ctx.spec.simulation.nominal.items():
        if name not in state_names or name == "energy.supplied":
            extra, hint = unknown_state(name, elab, state_names)
            rep.error("PHC-E210", f"`{name}` is not a state of the model (nominal scales are given for states)"
                      f"{extra}", ctx, ("simulation", "nominal", name), key=True, hint=hint)
            continue
        out[name] = float(value)
    return out


def _initial_values(elab, rep, ctx, state_names: set[str], result_units=None
                    ) -> tuple[list[InitialValue], tuple, frozenset]:
    """`simulation.initial`: the initial values, with the elaboration's initial relations
    and compile-time parameters as the initial fields change them."""
    from phc.ir.initial_fields import FieldInitializer

    fields = FieldInitializer(elab, rep, ctx)  # fields of ξ of distributed components; per-dof values' mesh
    field_entries = []
    out = []
    scope, defaults = dict(ctx.params), dict(elab.default_values)  # once, not per initial value
    for name, spec in ctx.spec.simulation.initial.items():
        path = ("simulation", "initial", name)
        if name not in state_names and fields.field_key(name) is not None:
            field_entries.append((name, spec))
            continue
        if name in state_names and not fields.check_dof(name, path):
            continue
        if name not in state_names:
            extra, hint = unknown_state(name, elab, state_names)
            rep.error("PHC-E210", f"`{name}` is not a state of the model (initial values are given for states)"
                      f"{extra}", ctx, path, key=True, hint=hint)
            continue
        value, guess = (spec.value, spec.guess) if isinstance(spec, InitialSpec) else (spec, False)
        vpath = (*path, "value") if isinstance(spec, InitialSpec) else path
        ex = rep.expr(ctx, value, vpath, scope)
        if result_units is not None:
            result_units.initial(ctx, name, vpath)
        num = ex.xreplace(defaults)
        try:
            val = float(num)
        except TypeError:
            rep.error("PHC-E211", f"initial value of `{name}` must be a number or an expression of parameters",
                      ctx, vpath)
            continue
        out.append(InitialValue(name, val, guess, ctx.smap.locate(vpath), None if ex.is_Number else ex))
    values = fields.apply(field_entries, out)
    return values, fields.initial_relations, fields.compile_time_parameters
