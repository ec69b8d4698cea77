"""phc — a compiler for port-Hamiltonian models.

Public API::

    import phc
    compiled = phc.compile_model("models/pendulum.yaml")
    result = phc.simulate(compiled, t_end=10.0)
    result["pendulum.x"], result.H, result.energy_balance_error
"""

__version__ = "0.1.0"

# The public API, imported on first use (PEP 562): `import phc` and `phc --help` stay
# cheap, and the command line uses exactly these names.
_API = {
    # compile
    "load_model": ("phc.spec.load", "load_spec"),
    "build_dae": ("phc.pipeline", "build_dae"),
    "validate_file": ("phc.pipeline", "validate_file"),
    "compile_model": ("phc.pipeline", "compile_model"),
    "CompiledModel": ("phc.codegen.compiled", "CompiledModel"),
    # certify
    "certify_model": ("phc.checks", "certify_model"),
    "ModelCertificate": ("phc.checks", "ModelCertificate"),
    # simulate
    "simulate": ("phc.simulation", "simulate"),
    "SimResult": ("phc.simulation", "SimResult"),
    "estimate_errors": ("phc.study.accuracy", "estimate_errors"),
    # linearize
    "linearize_model": ("phc.study.linearize", "linearize_model"),
    "Linearization": ("phc.study.linearize", "Linearization"),
    # errors and warnings
    "PhcError": ("phc.errors", "PhcError"),
    "PhcWarning": ("phc.errors", "PhcWarning"),
    "IgnoredOptionWarning": ("phc.errors", "IgnoredOptionWarning"),
    "ModelError": ("phc.errors", "ModelError"),
    "InconsistentInitialError": ("phc.errors", "InconsistentInitialError"),
    "SimulationSetupError": ("phc.errors", "SimulationSetupError"),
    "CodegenError": ("phc.errors", "CodegenError"),
    "ModelEvaluationError": ("phc.errors", "ModelEvaluationError"),
    "SimulationInterrupted": ("phc.errors", "SimulationInterrupted"),
}

__all__ = ["__version__", *_API]


def __getattr__(name: str):
    target = _API.get(name)
    if target is None:
        raise AttributeError(f"module 'phc' has no attribute {name!r}")
    import importlib

    value = getattr(importlib.import_module(target[0]), target[1])
    globals()[name] = value
    return value


def __dir__():
    return sorted(__all__)
