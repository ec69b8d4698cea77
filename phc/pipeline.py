"""The compiler pipeline, one readable sequence of passes, each a function from one value
to the next (the module of each pass states its input and output types at its top):

=============  ==========================================  ===================================
pass           input → output                              module
=============  ==========================================  ===================================
load           file path → Scene or model path              :mod:`phc.scene`, :mod:`phc.source`
elaborate      path, Scene → Elaboration                    :mod:`phc.elaborate`, :mod:`phc.library`
interconnect   Elaboration → Interconnection (one graph)    :mod:`phc.interconnect`
assemble       Elaboration, Interconnection → Dae           :mod:`phc.assemble`
analyse        Dae → diagnostics (balance, matching)        :mod:`phc.analysis.matching`
check rows     Dae → diagnostics (hand-written rows)        :mod:`phc.checks.rows`
lower          Dae → ResidualIR (Jacobian, sparsity)        :mod:`phc.codegen.lower`
print          ResidualIR → Python source                   :mod:`phc.codegen.printer`
load           source → module (cached by content hash)     :mod:`phc.codegen.load`
certify        CompiledModel → CompiledCertificate          :mod:`phc.checks.compiled`
=============  ==========================================  ===================================

``phc check`` adds the structural certificate of the assembled model
(:mod:`phc.checks.certify`: Dirac structures, couplings, each component's rows against
its description).
"""

from __future__ import annotations

import os
import time
from dataclasses import dataclass, field
from pathlib import Path
from types import ModuleType
from typing import Optional

from phc.analysis.matching import check_balance
from phc.codegen import backends
from phc.codegen.load import load_generated
from phc.codegen.lower import lower_residual
from phc.codegen.printer import print_module
from phc.dae import Dae
from phc.diagnostics import DiagnosticList
from phc.assemble import assemble
from phc.elaborate import elaborate
from phc.interconnect import interconnect
from phc.errors import ModelError
from phc.scene import Scene, is_scene_file, load_scene


FAST_SAMPLES = 1
"""Randomly perturbed consistent states of the certificate run by every compilation
(besides the initial state); `phc check` samples more."""
FAST_BALANCE_LIMIT = 1000
"""Above this many unknowns the certificate of every compilation checks passivity only:
sampling consistent states of a large model costs as much as several simulation starts
(`phc check` has no such limit)."""


@dataclass
class CompiledModel:
    """A compiled model: the assembled DAE, the generated module and its source."""

    name: str
    dae: Dae
    module: ModuleType
    source: str
    module_path: Path
    diagnostics: DiagnosticList
    timings: dict[str, float] = field(default_factory=dict)
    scene: Optional[Scene] = None
    """The scene this was compiled for (None for a plain model file)."""
    certificate: Optional[object] = None
    """The fast certificate of the compiled equations (:mod:`phc.checks.compiled`), or None
    when compiled with ``certify=False``."""
    start_state: Optional[tuple] = field(default=None, repr=False, compare=False)
    """The consistent state at t₀ last solved for (:func:`phc.simulation.start_state`): the
    certificate's initial sample, which `simulate` with the same values starts from."""

    @property
    def n_states(self) -> int:
        return self.dae.n_states - 1  # without the energy accumulator

    @property
    def n_equations(self) -> int:
        return len(self.dae.equations)

    @property
    def jacobian_nnz(self) -> int:
        return len(self.module.JAC_ROWS)

    @property
    def left_out(self) -> tuple[tuple[str, str, str], ...]:
        """What was not compiled, as (component, what, why)."""
        return self.dae.left_out

    @property
    def backend(self) -> str:
        """What runs the generated functions: ``numba`` (compiled) or ``numpy`` (the reference
        module; :mod:`phc.codegen.backends`)."""
        return backends.name_of(self.module)

    @property
    def compile_time(self) -> float:
        """Seconds spent compiling (the certificates' own times are `timings["certify"]` and
        `timings["certify_rows"]`)."""
        return sum(v for k, v in self.timings.items() if not k.startswith("certify"))

    def size(self) -> dict[str, int]:
        return {"states": self.n_states, "equations": self.n_equations, "jacobian_nnz": self.jacobian_nnz}

    def full_size(self) -> Optional[dict[str, int]]:
        """Size of the scene's model compiled with its own settings (everything on, nothing
        pruned), for comparison; None for a plain model or when nothing was left out."""
        if self.scene is None or not self.left_out:
            return None
        full = compile_model(self.scene.model_path, certify=False, backend="numpy")
        return full.size()

    # -- pickling by value, between phc's own processes (the workers of `phc sweep`) ------
    def __getstate__(self) -> dict:
        """Everything but the module object: the generated source and the metadata. The
        locations of the outputs are resolved here, so a worker never reads a model file.
        A pickle is code to whoever loads it: phc sends it only to its own worker processes
        (a local pool, or Dask workers the user runs) and never reads one from a file."""
        from phc.simulation import _output_span

        state = dict(self.__dict__)
        state.pop("module", None)
        state["phc_version"] = _phc_version()
        state["module_backend"] = getattr(self.module, "BACKEND", "numpy")
        state["output_spans"] = {name: _output_span(self, name) for name in self.module.OUTPUTS}
        return state

    def __setstate__(self, state: dict) -> None:
        """Rebuild the module from the source text (:func:`phc.codegen.load.load_generated`:
        executed from memory, a copy written to this machine's private cache), and a compiled
        backend from it when the model ran on one (:func:`phc.codegen.backends.for_compiled`)."""
        version = state.pop("phc_version", None)
        if version != _phc_version():
            raise RuntimeError(f"this compiled model comes from phc {version}, but phc {_phc_version()} is "
                               "installed here; install the same phc version on every worker")
        backend = state.pop("module_backend", "numpy")
        self.__dict__.update(state)
        self.module, self.module_path = load_generated(self.source, self.name)
        if backend != "numpy":
            from phc.codegen import backends

            self.module = backends.for_compiled(self, backend)


def _phc_version() -> str:
    from phc import __version__

    return __version__


def elaborate_file(path: str | os.PathLike, scene: Optional[Scene] = None) -> tuple[Optional[Dae], DiagnosticList]:
    """The passes load → elaborate → interconnect → assemble for a model file, or a scene
    file (its model with the scene applied). Returns ``(dae, diagnostics)``; `dae` is None
    when any error was found (wiring problems are reported even when components failed).
    A part (`kind: part`, :mod:`phc.parts`) is refused: it is not a complete model."""
    dae, diags, _ = _elaborate_file(path, scene)
    return dae, diags


def _elaborate_file(path, scene=None, allow_part: bool = False) -> tuple[Optional[Dae], DiagnosticList, str]:
    """:func:`elaborate_file`, also returning the file's kind (``model``, ``part``, or
    ``scene``); with `allow_part` a part is elaborated with its exposed ports free."""
    from phc.parts import part_diagnostics

    kind = "model"
    if scene is None and is_scene_file(path):
        kind = "scene"
        scene, diags = load_scene(path)
        if scene is None:
            return None, DiagnosticList(diags).sorted(), kind
    elab, diags = elaborate(scene.model_path if scene is not None else path, scene)
    if elab is None:
        return None, diags.sorted(), kind
    if elab.top.spec is not None and elab.top.spec.kind == "part":
        kind = "part" if kind == "model" else kind
        diags.extend(part_diagnostics(elab.top, allowed=allow_part and kind == "part"))
    inter = interconnect(elab)
    diags.extend(inter.diagnostics)
    if diags.has_errors:
        return None, DiagnosticList(dict.fromkeys(diags)).sorted(), kind
    dae, found = assemble(elab, inter)
    diags.extend(found)
    return (None if diags.has_errors else dae), diags.sorted(), kind


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
    a part (`kind: part`, see :mod:`phc.parts`) without its structural balance, which
    depends on what the model using it connects to its exposed ports.

    Returns
    -------
    dae : Dae or None
        The assembled system (of a part: with its exposed ports free), None on errors.
    diagnostics : DiagnosticList
        Located problems and warnings, sorted.
    kind : str
        ``"model"``, ``"part"`` or ``"scene"``.
    """
    dae, diags, kind = _elaborate_file(path, allow_part=True)
    if dae is not None and kind != "part":
        diags.extend(check_balance(dae))
        if diags.has_errors:
            dae = None
    return dae, DiagnosticList(diags).sorted(), kind


def _coarse_dae(path, scene: Optional[Scene], mesh: dict[str, int]) -> Optional[Dae]:
    """The model assembled again with `mesh` overriding element counts (the coarse mesh on
    which :func:`phc.checks.rows.check_hand_written` compares a large component), or None
    when that variant does not assemble."""
    from phc.scene import scene_variant

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
    derive from the component's description; see :data:`phc.registry.ROWS`) are compared
    with the description (:func:`phc.checks.rows.check_hand_written`; a mismatch is a fault
    in phc, ``PHC-E452`` at the component), and the compiled equations are certified before
    they are returned (:func:`phc.checks.compiled.certify_compiled`: the power balance at
    sampled consistent states, passivity of every dissipative term); a failure is a ModelError.

    `backend` chooses what runs the generated functions (:mod:`phc.codegen.backends`):
    ``auto`` (the default, or ``$PHC_BACKEND``) the compiled ``numba`` module when numba is
    installed and the model has at least 16 unknowns, else the ``numpy`` module;
    ``CompiledModel.backend`` says which.

    Raises
    ------
    ModelError
        When the model has errors (``err.diagnostics`` lists them, located).
    SimulationSetupError
        When `backend` is unknown, or ``numba`` and numba cannot be imported.
    """
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
    t = time.perf_counter()
    name = scene.name if scene is not None else dae.name
    module, module_path = load_generated(source, name)
    timings["load"] = time.perf_counter() - t
    if backends.check_choice(backend) != "numpy":  # compiled functions (phc.codegen.backends)
        t = time.perf_counter()
        module, _ = backends.select(ir, module, source, backend)
        timings["backend"] = time.perf_counter() - t
    compiled = CompiledModel(name, dae, module, source, module_path, diags, timings, scene)
    from phc.simulation.events import locate_switch_times  # conditions in t: their switching times exist

    unlocated = locate_switch_times(compiled)
    if unlocated:
        raise ModelError(DiagnosticList(list(diags) + unlocated).sorted())
    if certify:
        from phc.checks.compiled import certify_compiled

        t = time.perf_counter()
        compiled.certificate = certify_compiled(compiled, n_random=FAST_SAMPLES, max_unknowns=FAST_BALANCE_LIMIT)
        timings["certify"] = time.perf_counter() - t
        if compiled.certificate.diagnostics.has_errors:
            raise ModelError(DiagnosticList(list(diags) + list(compiled.certificate.diagnostics)).sorted())
    return compiled
