"""phc — a compiler for port-Hamiltonian models.

Public API::

    import phc
    compiled = phc.compile_model("models/pendulum.yaml")
    result = phc.simulation(compiled, t_end=10.0)
    result["pendulum.x"], result.H, result.energy_balance_error
"""

__version__ = "0.1.0"

from phc.pipeline import CompiledModel, build_dae, compile_model  # noqa: E402
from phc.simulation import SimResult, simulate  # noqa: E402
from phc.elaborate import load_spec as load_model  # noqa: E402

__all__ = ["__version__", "load_model", "build_dae", "compile_model", "simulate", "CompiledModel", "SimResult"]
