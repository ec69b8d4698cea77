"""The run options as pydantic field types: the model's `simulation` section and a scene's
`t_end`, `n_out`, `solver` and `accuracy` are built from these, so that the ranges the
model language checks are the ones :class:`phc.options.RunOptions`, the command line and
:func:`phc.simulate` check (:data:`phc.names.RUN_LIMITS`)."""

from __future__ import annotations

import math
from typing import Annotated, Literal

from pydantic import Field

from phc.names import PEER_SOLVER_NAMES, RUN_LIMITS, SOLVER_NAMES


def _bounds(name: str) -> dict:
    """pydantic's constraints for the option `name` (:data:`phc.names.RUN_LIMITS`)."""
    kind, low, high = RUN_LIMITS[name]
    if kind == "count":
        return dict(ge=low, le=high)
    if kind == "fraction":
        return dict(gt=low, lt=high)
    return dict(gt=low) if high == math.inf else dict(gt=low, le=high)


SOLVERS = Literal[SOLVER_NAMES]
BENCH_SOLVERS = Literal[SOLVER_NAMES + PEER_SOLVER_NAMES]
TEnd = Annotated[float, Field(**_bounds("t_end"))]
NOut = Annotated[int, Field(**_bounds("n_out"))]
Rtol = Annotated[float, Field(**_bounds("rtol"))]
Atol = Annotated[float, Field(**_bounds("atol"))]
Step = Annotated[float, Field(**_bounds("step"))]
MaxSteps = Annotated[int, Field(**_bounds("max_steps"))]
MaxOrder = Annotated[int, Field(**_bounds("max_order"))]
TYPES = {"t_end": TEnd, "n_out": NOut, "rtol": Rtol, "atol": Atol, "step": Step, "max_steps": MaxSteps,
         "max_order": MaxOrder}
"""The constrained type of each numeric run option."""

__all__ = ["SOLVERS", "TYPES", "TEnd", "NOut", "Rtol", "Atol", "Step", "MaxSteps", "MaxOrder"]
