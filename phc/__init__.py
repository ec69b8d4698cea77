"""phc — a compiler for port-Hamiltonian models.

Public API::

    import phc
    compiled = phc.compile_model("models/pendulum.yaml")
    result = phc.simulate(compiled, t_end=10.0)
    result["pendulum.x"], result.H, result.energy_balance_error
"""

import os as _os

# phc's dense matrices are small (initialization, certification) and its sparse ones are
# factorized by single-threaded SuperLU: a multi-threaded BLAS only adds thread start-up
# and, on a loaded machine, spin-waiting (measured: consistent initialization 10× slower,
# IDA runs burning 2× the CPU). Default to one thread unless the user chose otherwise;
# this takes effect when phc is imported before numpy (the `phc` command).
for _var in ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS"):
    _os.environ.setdefault(_var, "1")

__version__ = "0.1.0"

from phc.pipeline import CompiledModel, build_dae, compile_model  # noqa: E402
from phc.simulation import SimResult, simulate  # noqa: E402
from phc.elaborate import load_spec as load_model  # noqa: E402
from phc.errors import (  # noqa: E402
    CodegenError, InconsistentInitialError, ModelError, PhcError, SimulationSetupError,
)

__all__ = ["__version__", "load_model", "build_dae", "compile_model", "simulate", "CompiledModel", "SimResult",
           "PhcError", "ModelError", "InconsistentInitialError", "SimulationSetupError", "CodegenError"]
