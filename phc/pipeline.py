"""The compiler pipeline, one readable sequence of passes, each a function from one value
to the next (the module of each pass states its input and output types at its top):

=============  ==========================================  ===================================
pass           input → output                              module
=============  ==========================================  ===================================
load           file path → Scene or model path              :mod:`phc.frontend.scene`, :mod:`phc.frontend.source`
elaborate      path, Scene → Elaboration                    :mod:`phc.frontend.elaborate`, :mod:`phc.library`
interconnect   Elaboration → Interconnection (one graph)    :mod:`phc.ir.interconnect`
assemble       Elaboration, Interconnection → Dae           :mod:`phc.ir.assemble`
analyse        Dae → diagnostics (balance, matching)        :mod:`phc.analysis.matching`
check rows     Dae → diagnostics (hand-written rows)        :mod:`phc.checks.rows`
lower          Dae → ResidualIR (Jacobian, sparsity)        :mod:`phc.codegen.lower`
print          ResidualIR → Python source                   :mod:`phc.codegen.printer`
load           source → module (cached by content hash)     :mod:`phc.codegen.load`
describe       Dae, module → ModelDescription               :mod:`phc.codegen.description`
certify        CompiledModel → CompiledCertificate          :mod:`phc.checks.compiled`
=============  ==========================================  ===================================

The result is a :class:`~phc.codegen.compiled.CompiledModel`: the frozen, JSON-serializable
:class:`~phc.codegen.description.ModelDescription` (what a run needs: names, labels and their
places, options, units, initial values, outputs, the certificate's verdict) beside the
generated module, and the :class:`~phc.codegen.compiled.RunCache` of what its runs remember.

``phc check`` adds the structural certificate of the assembled model
(:mod:`phc.checks.certify`: Dirac structures, couplings, each component's rows against
its description).
"""

from __future__ import annotations

import contextlib
import gc
import os
import sys
import threading
import time
from dataclasses import replace
from types import ModuleType
from typing import Optional

from phc.analysis.matching import check_balance
from phc.codegen.compiled import CompiledModel, RunCache
from phc.ir.dae import Dae
from phc.codegen.description import (Connection, Initial, Labelled, LabelledRows, ModelDescription, Place, SceneRef,
                                     Verdict)
from phc.diagnostics import DiagnosticList
from phc.ir.assemble import assemble
from phc.frontend.elaborate import elaborate
from phc.ir.interconnect import interconnect
from phc.errors import ModelError
from phc.frontend.scene import Scene, is_scene_file, load_scene


FAST_SAMPLES = 1
"""Randomly perturbed consistent states of the certificate run by every compilation
(besides the initial state); `phc check` samples more."""
FAST_BALANCE_LIMIT = 1000
"""Above this many unknowns the certificate of every compilation checks passivity only:
sampling consistent states of a large model costs as much as several simulation starts
(`phc check` has no such limit)."""


_PAUSE_LOCK = threading.Lock()
_PAUSE = {"depth": 0, "ours": False}
"""Compilations running now (in any thread) and whether the first of them paused the collector."""


@contextlib.contextmanager
def collector_paused():
    """Python's cyclic garbage collector paused while the block runs, and restored as it was
    found when the last block running ends (also on an error; a collector the caller had
    paused stays paused). The collector is one switch for the whole process, so blocks in
    several threads share one pause: the first to enter pauses a running collector, the last
    to leave starts it again; a thread that ended its block while another still compiled
    would otherwise leave the collector off for good, or start it under the other's feet.

    A compilation builds objects that live until it ends (sympy symbols and rows, one or more
    per unknown) and makes almost no cyclic garbage; with the collector running, each of
    its passes over the older generations walks every object made so far, so that their
    cost grows faster than the mesh (measured with ``benchmarks/bench_beam_scale.py
    --measure string 100000``: 48.8 → 34.4 CPU seconds of compile, docs/reference/limits.md). Nothing changes once the block has
    ended: what it left is collected by the collector's next pass as usual, except in the
    `phc` command (:data:`phc._entry.COMMAND`), which frees its model only at exit: there
    what the block left is frozen (:func:`gc.freeze`) rather than walked by the next
    collection of the youngest generation (1.4 CPU seconds after validating a chain of 10⁴
    components)."""
    with _PAUSE_LOCK:
        if _PAUSE["depth"] == 0:
            _PAUSE["ours"] = gc.isenabled()
            gc.disable()
        _PAUSE["depth"] += 1
    try:
        yield
    finally:
        with _PAUSE_LOCK:
            _PAUSE["depth"] -= 1
            if _PAUSE["depth"] == 0 and _PAUSE["ours"]:
                _PAUSE["ours"] = False
                entry = sys.modules.get("phc._entry")
                if entry is not None and entry.COMMAND:
                    gc.freeze()
                gc.enable()


def elaborate_file(path: str | os.PathLike, scene: Optional[Scene] = None) -> tuple[Optional[Dae], DiagnosticList]:
    """The passes load → elaborate → interconnect → assemble for a model file, or a scene
    file (its model with the scene applied). Returns ``(dae, diagnostics)``; `dae` is None
    when any error was found (wiring problems are reported even when components failed).
    A part (`kind: part`, :mod:`phc.frontend.parts`) is refused: it is not a complete model."""
    dae, diags, _, _ = _elaborate_file(path, scene)
    return dae, diags


def _elaborate_file(path, scene=None, allow_part: bool = False
                    ) -> tuple[Optional[Dae], DiagnosticList, str, Optional[Scene]]:
    """:func:`elaborate_file`, also returning the file's kind (``model``, ``part``, or
    ``scene``) and the scene applied (None for a model); with `allow_part` a part is
    elaborated with its exposed ports free."""
    from phc.frontend.parts import part_diagnostics

    kind = "model"
    if scene is None and is_scene_file(path):
        kind = "scene"
        scene, diags = load_scene(path)
        if scene is None:
            return None, DiagnosticList(diags).sorted(), kind, None
    elab, diags = elaborate(scene.model_path if scene is not None else path, scene)
    if elab is None:
        return None, diags.sorted(), kind, scene
    if elab.top.spec is not None and elab.top.spec.kind == "part":
        kind = "part" if kind == "model" else kind
        diags.extend(part_diagnostics(elab.top, allowed=allow_part and kind == "part"))
    inter = interconnect(elab)
    diags.extend(inter.diagnostics)
    if diags.has_errors:
        return None, DiagnosticList(dict.fromkeys(diags)).sorted(), kind, scene
    dae, found = assemble(elab, inter)
    diags.extend(found)
    if not diags.has_errors:
        from phc.checks.signs import sign_hints  # cheap: where the user is (validate, simulate, check)

        diags.extend(sign_hints(dae.topology))  # connections that turn the sign of a voltage (PHC-W230)
    return (None if diags.has_errors else dae), diags.sorted(), kind, scene


def build_dae(path: str | os.PathLike, scene: Optional[Scene] = None) -> tuple[Optional[Dae], DiagnosticList]:
    """Stages 1–7: read, elaborate, assemble and check one model file, or a scene file
    (then its model with the scene applied)."""
    dae, diags = elaborate_file(path, scene)
    if dae is not None:
        # Structural solvability before any code is generated.
        diags.extend(check_balance(dae))
        if diags.has_errors:
            dae = None
    return dae, DiagnosticList(diags).sorted()


def validate_file(path: str | os.PathLike) -> tuple[Optional[Dae], DiagnosticList, str]:
    """What ``phc validate`` checks of one file: a model or scene as :func:`build_dae` does,
    a part (`kind: part`, see :mod:`phc.frontend.parts`) without its structural balance, which
    depends on what the model using it connects to its exposed ports. Nothing beyond the
    assembled system: no code is generated, and the code generator's modules are not imported
    (``tests/test_validate_large.py``).

    Returns
    -------
    dae : Dae or None
        The assembled system (of a part: with its exposed ports free), None on errors.
    diagnostics : DiagnosticList
        Located problems and warnings, sorted.
    kind : str
        ``"model"``, ``"part"`` or ``"scene"``.
    """
    with collector_paused():  # as compile_model
        dae, diags, kind, _ = _elaborate_file(path, allow_part=True)
        if dae is not None and kind != "part":
            diags.extend(check_balance(dae))
            if diags.has_errors:
                dae = None
        return dae, DiagnosticList(diags).sorted(), kind


def _coarse_dae(path, scene: Optional[Scene], mesh: dict[str, int]) -> Optional[Dae]:
    """The model assembled again with `mesh` overriding element counts (the coarse mesh on
    which :func:`phc.checks.rows.check_hand_written` compares a large component), or None
    when that variant does not assemble."""
    from phc.frontend.scene import scene_variant

    try:
        variant = scene_variant(scene if scene is not None else path, mesh=mesh)
    except ModelError:
        return None
    dae, _ = build_dae(variant.model_path, variant)
    return dae


def _rows_not_compared(dae: Dae, rows) -> list:
    """A warning (PHC-W452) for each component with hand-written rows that the rows check
    of this compilation could not compare with its description, saying why."""
    from phc.diagnostics import Diagnostic

    spans = {name: span for name, _, span in dae.topology.components} if dae.topology is not None else {}
    return [Diagnostic("PHC-W452", f"the equations compiled for `{name}` were not compared with its description "
                       f"when compiling: {why}", span=spans.get(name), severity="warning",
                       hint="the compiled energy balance is still certified; `phc check` lists what it compares")
            for name, why in [*rows.not_compared, *rows.inconclusive]]


def compile_model(path: str | os.PathLike, scene: Optional[Scene] = None, *, certify: bool = True,
                  backend: Optional[str] = None) -> CompiledModel:
    """Compile a model file (or a scene file: its model as the scene asks) to a loaded
    residual module. `scene` applies an in-memory scene instead (`path` is then unused).

    With `certify` (the default) the rows that lowerers write themselves (rather than
    derive from the component's description; see :data:`phc.library.registry.ROWS`) are compared
    with the description (:func:`phc.checks.rows.check_hand_written`; a mismatch is a fault
    in phc, ``PHC-E452`` at the component), and the compiled equations are certified before
    they are returned (:func:`phc.checks.compiled.certify_compiled`: the power balance at
    sampled consistent states, passivity of every dissipative term); a failure is a ModelError.

    `backend` chooses what runs the generated functions (:mod:`phc.codegen.backends`):
    ``auto`` (the default, or ``$PHC_BACKEND``) the ``c`` module when a C compiler is found
    and the C back end prints the model, else the ``numba`` module when numba is installed
    and the model has at least 16 unknowns, else the ``numpy`` module; ``c`` the functions
    compiled by the system C compiler (:mod:`phc.codegen.c_backend`);
    ``CompiledModel.backend`` says which.

    Raises
    ------
    ModelError
        When the model has errors (``err.diagnostics`` lists them, located).
    SimulationSetupError
        When `backend` is unknown, ``numba`` and numba cannot be imported, or ``c`` and
        no C compiler is found or the model uses something the C back end does not print.
    """
    with collector_paused():
        return _compile_model(path, scene, certify=certify, backend=backend)


def _compile_model(path, scene: Optional[Scene], *, certify: bool, backend: Optional[str]) -> CompiledModel:
    """:func:`compile_model` with the garbage collector already paused."""
    timings = {}
    t = time.perf_counter()
    if scene is None and is_scene_file(path):
        scene, diags = load_scene(path)
        if scene is None:
            raise ModelError(DiagnosticList(diags).sorted())
    dae, diags = build_dae(path, scene)
    timings["elaborate"] = time.perf_counter() - t
    if dae is None:
        raise ModelError(diags)
    return _compile_assembled(path, scene, dae, diags, certify=certify, backend=backend, timings=timings)


def _compile_assembled(path, scene: Optional[Scene], dae: Dae, diags: DiagnosticList, *, certify: bool = True,
                       backend: Optional[str] = None, timings: Optional[dict] = None) -> CompiledModel:
    """:func:`compile_model` from the model already assembled and checked (`dae` with its
    `diags`, from `path` and `scene`): ``phc check`` compiles what it has certified
    without reading and assembling the model again."""
    # the code generator's passes, imported here: `phc validate` never loads them
    # (tests/test_validate_large.py)
    from phc.codegen import backends
    from phc.codegen.load import load_generated
    from phc.codegen.lower import lower_residual
    from phc.codegen.printer import print_module

    timings = {} if timings is None else timings
    if certify:
        from phc.checks.rows import check_hand_written

        t = time.perf_counter()
        rows = check_hand_written(dae, rebuild=lambda mesh: _coarse_dae(path, scene, mesh))
        timings["certify_rows"] = time.perf_counter() - t
        if rows.diagnostics.has_errors:
            raise ModelError(DiagnosticList(list(diags) + list(rows.diagnostics)).sorted())
        diags = DiagnosticList(list(diags) + _rows_not_compared(dae, rows)).sorted()
    t = time.perf_counter()
    ir = lower_residual(dae)
    timings["lower"] = time.perf_counter() - t
    t = time.perf_counter()
    source = print_module(ir)
    timings["print"] = time.perf_counter() - t
    compiled_functions = backends.check_choice(backend) != "numpy"  # (phc.codegen.backends)
    if not compiled_functions:
        # printed, and no compiled functions to build from it: the lowered system is freed
        # before the module makes its arrays (the compile's peak, for a mesh)
        del ir
    t = time.perf_counter()
    name = scene.name if scene is not None else dae.name
    module, module_path = load_generated(source, name)
    timings["load"] = time.perf_counter() - t
    if compiled_functions:
        t = time.perf_counter()
        module, _ = backends.select(ir, module, source, backend)
        timings["backend"] = time.perf_counter() - t
        del ir  # freed before the description is made
    t = time.perf_counter()
    description = describe(name, dae, module, scene)
    timings["describe"] = time.perf_counter() - t
    compiled = CompiledModel(description, module, source, module_path, diags, dae, scene,
                             cache=RunCache(timings=timings), backend_request=backends.check_choice(backend))
    from phc.simulation.events import locate_switch_times  # conditions in t: their switching times exist

    unlocated = locate_switch_times(compiled)
    if unlocated:
        raise ModelError(DiagnosticList(list(diags) + unlocated).sorted())
    if certify:
        from phc.checks.compiled import certify_compiled

        t = time.perf_counter()
        certificate = certify_compiled(compiled, n_random=FAST_SAMPLES, max_unknowns=FAST_BALANCE_LIMIT)
        timings["certify"] = time.perf_counter() - t
        if certificate.diagnostics.has_errors:
            raise ModelError(DiagnosticList(list(diags) + list(certificate.diagnostics)).sorted())
        verdict = Verdict(certificate.summary(), certificate.to_dict())
        compiled = replace(compiled, certificate=certificate, description=replace(description, certificate=verdict))
    return compiled


def describe(name: str, dae: Dae, module: ModuleType, scene: Optional[Scene] = None) -> ModelDescription:
    """The description of a compiled model (:mod:`phc.codegen.description`): what a run needs of
    `dae` besides the generated `module`. Initial values written in parameters are
    evaluated at the default parameters (as :func:`phc.simulation.initial_values` does), and
    the places of the outputs are read from the scene or model file."""
    from phc.simulation import parameter_vector

    initial = []
    symbols = {par.symbol: par for par in dae.parameters}
    by_name: Optional[dict] = None
    memo: dict = {}
    for iv in dae.initial:
        if iv.expr is None:
            initial.append(Initial(iv.name, float(iv.value), bool(iv.guess), Place.of(iv.span), ()))
            continue
        if by_name is None:
            import sympy as sp

            p = parameter_vector(module)
            slot = {pname: i for i, pname in enumerate(module.PARAMETERS)}  # not .index per parameter
            by_name = {par.symbol: sp.Float(float(p[slot[par.name]])) for par in dae.parameters}
        from phc.ir.initial_fields import evaluate

        try:
            value = float(evaluate(iv.expr, by_name, memo))
        except (TypeError, ValueError, ArithmeticError):  # not a number there: refused at the start of a run
            value = float("nan")
        initial.append(Initial(iv.name, value, bool(iv.guess), Place.of(iv.span), _parameters_in(iv.expr, symbols)))
    topology = dae.topology
    outputs = tuple(module.OUTPUTS)
    places: dict = {}  # id(span) -> (span, its Place): a mesh's rows share one span

    def place(span) -> Optional[Place]:
        hit = places.get(id(span))
        if hit is None:
            hit = places[id(span)] = (span, Place.of(span))  # the span kept: its id stays its own
        return hit[1]

    return ModelDescription(
        name=name, model=dae.name, n_states=dae.n_states - 1, options=dae.options, units=dict(dae.units or {}),
        equations=LabelledRows((eq.label, eq.component, place(eq.span)) for eq in dae.equations),
        invariants=tuple(Labelled(x.label, x.component, Place.of(x.span)) for x in dae.invariants),
        velocity_invariants=tuple(Labelled(x.label, x.component, Place.of(x.span)) for x in dae.velocity_invariants),
        initial=tuple(initial), outputs=outputs, output_spans=_output_spans(scene, dae, outputs),
        connections=tuple(Connection(a, b, lab, Place.of(s))
                          for a, b, lab, s in (topology.connections if topology is not None else ())),
        left_out=dae.left_out, sources=tuple(str(s) for s in dae.sources),
        scene=SceneRef(scene.name, str(scene.spec.model)) if scene is not None else None)


def _parameters_in(expr, symbols: dict) -> Optional[tuple[str, ...]]:
    """The parameters `expr` is written in, through derived ones; None when it holds a
    symbol that is not a parameter (or is not an expression)."""
    if not hasattr(expr, "free_symbols"):
        return None
    found: set = set()
    todo = list(expr.free_symbols)
    while todo:
        par = symbols.get(todo.pop())
        if par is None:
            return None
        if par.name not in found:
            found.add(par.name)
            if par.expr is not None:
                todo.extend(par.expr.free_symbols)
    return tuple(sorted(found))


def _output_spans(scene: Optional[Scene], dae: Dae, outputs: tuple[str, ...]) -> dict:
    """Output name -> where it is written: the scene's `outputs`/`reference`, else the
    model's `simulation.outputs` (None where not found)."""
    spans: dict = {}
    try:
        rest = list(outputs)
        if scene is not None:
            spec, rest = scene.spec, []
            for name in outputs:
                base = name.removesuffix("_reference")
                if name in (spec.outputs or {}):
                    spans[name] = scene.smap.locate_key(("outputs", name))
                elif base != name and base in (spec.reference or {}):
                    spans[name] = scene.smap.locate_key(("reference", base))
                else:
                    rest.append(name)
            path = scene.model_path
        else:
            path = dae.sources[-1] if dae.sources else None
        if rest and path is not None:
            from phc.frontend.source import _read_parsed

            data, smap, _ = _read_parsed(path)  # read only (parsed when the model was read)
            written = ((data or {}).get("simulation") or {}).get("outputs", {}) if isinstance(data, dict) else {}
            for name in rest:
                if smap is not None and name in written:
                    spans[name] = smap.locate_key(("simulation", "outputs", name))
    except Exception:  # noqa: BLE001 — a location is a courtesy, never a new failure
        pass
    return {name: Place.of(spans.get(name)) for name in outputs}
