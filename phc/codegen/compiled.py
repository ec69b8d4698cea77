"""The compiled model: a frozen :class:`~phc.codegen.description.ModelDescription` beside the
generated module, and the explicit :class:`RunCache` of what runs of it remember.

Input: what :func:`phc.pipeline.compile_model` produced, or a stored description and the
generated source (:meth:`CompiledModel.from_description`, the cached front end of
:mod:`phc.codegen.fastpath`). Output: a :class:`CompiledModel`, the one type
:func:`phc.simulate`, the command line and ``phc sweep`` take.

A compiled model is frozen: its fields cannot be reassigned and its description's
mappings are read-only. What runs remember — the consistent start state last solved for,
the checks of parameter overrides, the size of a scene's full model, what compiling and
loading cost — lives in its :class:`RunCache` (``compiled.cache``), an object of its own
whose contents never change a run's numbers (a cached start state is the same solve's
result). This module imports neither sympy nor the compiler's passes.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path
from types import MappingProxyType, ModuleType
from typing import TYPE_CHECKING, Any, Mapping, Optional, Sequence

from phc.codegen.description import ModelDescription

if TYPE_CHECKING:  # pragma: no cover
    from phc.ir.dae import Dae
    from phc.frontend.scene import Scene


@dataclass
class RunCache:
    """What runs of one compiled model remember (mutable, owned by the model's
    :attr:`CompiledModel.cache`, never part of its description).

    Adding a field? It must not change the numbers of a run (a cache, or a record of
    cost), and :meth:`CompiledModel.__getstate__` sends it to worker processes as it is.
    """

    start_state: Optional[tuple] = None
    """(key, InitialResult): the consistent state at t₀ last solved for
    (:func:`phc.simulation.start_state`; the certificate of every compilation solves it
    for the model's own values and `simulate` with those values starts from it)."""
    parameter_checks: dict = field(default_factory=dict)
    """Parameter overrides -> the problems elaborating the model with them found
    (:func:`phc.simulation.check_parameters`)."""
    full_size: Optional[tuple] = None
    """(size,) of the scene's full model once compiled (:meth:`CompiledModel.full_size`)."""
    timings: dict = field(default_factory=dict)
    """Seconds spent per compilation pass (``elaborate``, ``lower``, ``print``, ``load``,
    ``backend``, ``certify``); a backend built later for a run adds to ``backend``."""
    run_modules: dict = field(default_factory=dict)
    """Backend name -> the module built for runs of a model compiled for another
    (:func:`phc.codegen.backends.for_run`: ``auto`` on a long fixed-step run), so that a
    parameter study builds it once. Not pickled (a module is rebuilt where it runs)."""
    rebuilt: bool = False
    """True for a model rebuilt from its pickle (a worker of ``phc sweep``): it never reads
    the model's files, which may not exist where it runs (the parameter values it runs
    were checked where it was compiled: `parameter_checks`)."""

    def __getstate__(self) -> dict:
        """Everything but `run_modules` (modules do not pickle; built again where needed)."""
        return {**self.__dict__, "run_modules": {}}


@dataclass(frozen=True, eq=False)
class CompiledModel:
    """A compiled model: its description, the generated module and its source.

    Parameters
    ----------
    description : ModelDescription
        What a run needs besides the module (:mod:`phc.codegen.description`).
    module : module
        The loaded generated module (or its compiled backend, :mod:`phc.codegen.backends`).
    source : str
        The generated module's source text.
    module_path : Path
        Where a copy of the source was written.
    diagnostics : sequence
        The compilation's warnings (as :class:`~phc.diagnostics.Diagnostic`).
    dae : Dae, optional
        The assembled system it was compiled from; None for a model loaded from its
        description (then initial values written in parameters cannot follow overrides of
        those parameters, and no other backend can be built).
    scene : Scene, optional
        The scene it was compiled for, as read (None for a plain model file, and for a
        model loaded from its description: ``description.scene`` names it).
    certificate : CompiledCertificate, optional
        The full certificate of the compiled equations (:mod:`phc.checks.compiled`), None
        when compiled with ``certify=False`` or loaded from a description (whose
        ``description.certificate`` keeps the verdict).
    cache : RunCache
        What runs of it remember.
    backend_request : str, optional
        The backend asked for when it was compiled (``auto``, ``numpy``, ``numba`` or ``c``,
        after ``$PHC_BACKEND``); None when not known. Under ``auto`` a long fixed-step run of
        a model that runs on NumPy may run on a compiled step loop
        (:func:`phc.codegen.backends.for_run`).
    """

    description: ModelDescription
    module: ModuleType
    source: str
    module_path: Path
    diagnostics: Sequence = ()
    dae: Optional["Dae"] = None
    scene: Optional["Scene"] = None
    certificate: Optional[Any] = None
    cache: RunCache = field(default_factory=RunCache, repr=False)
    backend_request: Optional[str] = None

    @classmethod
    def from_description(cls, description: ModelDescription, source: str, module: Optional[ModuleType] = None,
                         module_path: Optional[Path] = None, diagnostics: Sequence = (),
                         cache: Optional[RunCache] = None,
                         backend_request: Optional[str] = None) -> "CompiledModel":
        """A compiled model from its description and generated source; the module is
        loaded from the source (:func:`phc.codegen.load.load_generated`) unless given."""
        if module is None:
            from phc.codegen.load import load_generated

            module, module_path = load_generated(source, description.name)
        return cls(description, module, source, Path(module_path) if module_path is not None else Path(),
                   tuple(diagnostics), cache=cache if cache is not None else RunCache(),
                   backend_request=backend_request)

    @property
    def name(self) -> str:
        return self.description.name

    @property
    def options(self) -> Mapping[str, Any]:
        """The simulation options (read-only)."""
        return self.description.options

    @property
    def n_states(self) -> int:
        return self.description.n_states

    @property
    def n_equations(self) -> int:
        return len(self.description.equations)

    @property
    def jacobian_nnz(self) -> int:
        return len(self.module.JAC_ROWS)

    @property
    def left_out(self) -> tuple[tuple[str, str, str], ...]:
        """What was not compiled, as (component, what, why)."""
        return self.description.left_out

    @property
    def backend(self) -> str:
        """What runs the generated functions: ``numba`` or ``c`` (compiled) or ``numpy`` (the
        reference module; :mod:`phc.codegen.backends`)."""
        return getattr(self.module, "BACKEND", "numpy")

    @property
    def timings(self) -> Mapping[str, float]:
        """Seconds per compilation pass (read-only view of ``cache.timings``)."""
        return MappingProxyType(self.cache.timings)

    @property
    def compile_time(self) -> float:
        """Seconds spent compiling (the certificates' own times are `timings["certify"]` and
        `timings["certify_rows"]`)."""
        return sum(v for k, v in self.cache.timings.items() if not k.startswith("certify"))

    def size(self) -> dict[str, int]:
        return {"states": self.n_states, "equations": self.n_equations, "jacobian_nnz": self.jacobian_nnz}

    def full_size(self) -> Optional[dict[str, int]]:
        """Size of the scene's model compiled with its own settings (everything on, nothing
        pruned), for comparison; None for a plain model or when nothing was left out.
        Compiled once (remembered in ``cache.full_size``)."""
        if self.description.scene is None or not self.left_out:
            return None
        if self.cache.full_size is None:
            if self.scene is None:
                return None  # loaded from a description without it
            from phc.pipeline import compile_model

            self.cache.full_size = (compile_model(self.scene.model_path, certify=False, backend="numpy").size(),)
        size = self.cache.full_size[0]
        return dict(size) if size is not None else None

    # -- pickling by value, between phc's own processes (the workers of `phc sweep`) ------
    def __getstate__(self) -> dict:
        """Everything but the module object: the generated source, the description (as
        JSON), the assembled system and the cache. A pickle is code to whoever loads it: phc
        sends it only to its own worker processes (a local pool, or Dask workers the user
        runs) and never reads one from a file."""
        state = {f: getattr(self, f) for f in ("description", "source", "module_path", "diagnostics", "dae",
                                                 "scene", "certificate", "cache", "backend_request")}
        state["phc_version"] = _phc_version()
        state["module_backend"] = getattr(self.module, "BACKEND", "numpy")
        return state

    def __setstate__(self, state: dict) -> None:
        """Rebuild the module from the source text (:func:`phc.codegen.load.load_generated`:
        executed from memory, a copy written to this machine's private cache), and a compiled
        backend from it when the model ran on one (:func:`phc.codegen.backends.for_compiled`)."""
        from phc.codegen.load import load_generated

        version = state.pop("phc_version", None)
        if version != _phc_version():
            raise RuntimeError(f"this compiled model comes from phc {version}, but phc {_phc_version()} is "
                               "installed here; install the same phc version on every worker")
        backend = state.pop("module_backend", "numpy")
        for key, value in state.items():
            object.__setattr__(self, key, value)
        self.cache.rebuilt = True  # the files it was compiled from are not read here
        module, module_path = load_generated(self.source, self.description.name)
        object.__setattr__(self, "module", module)
        object.__setattr__(self, "module_path", module_path)
        if backend != "numpy":
            from phc.codegen import backends

            object.__setattr__(self, "module", backends.for_compiled(self, backend))


def _phc_version() -> str:
    from phc import __version__

    return __version__


__all__ = ["CompiledModel", "RunCache"]
