"""One object for the options of a run: :class:`RunOptions`.

The model's `simulation` section is a :class:`RunOptions` (plus initial values, inputs and
outputs: :class:`phc.spec.model.SimulationSpec` extends it), a scene's `t_end`, `n_out`,
`solver` and `accuracy` are its fields made optional (:data:`Optional fields <OPTIONAL>`),
the command line checks its numeric options against the same ranges
(:data:`phc.names.RUN_LIMITS`, importable without pydantic), and :func:`phc.simulate`
builds one from the compiled model's options and the call's overrides
(:meth:`RunOptions.with_overrides`) and hands it to the integrator, which returns a typed
:class:`~phc.simulation.backend.BackendRun`.
"""

from __future__ import annotations

import math
from typing import Annotated, Any, Literal, Mapping, Optional

from pydantic import BaseModel, ConfigDict, Field, field_validator

from phc.names import RUN_LIMITS, SOLVER_NAMES, option_problem

SOLVERS = Literal[SOLVER_NAMES]


def _bounds(name: str) -> dict:
    """pydantic's constraints for the option `name` (:data:`phc.names.RUN_LIMITS`)."""
    kind, low, high = RUN_LIMITS[name]
    if kind == "count":
        return dict(ge=low, le=high)
    if kind == "fraction":
        return dict(gt=low, lt=high)
    return dict(gt=low) if high == math.inf else dict(gt=low, le=high)


TEnd = Annotated[float, Field(**_bounds("t_end"))]
NOut = Annotated[int, Field(**_bounds("n_out"))]
Rtol = Annotated[float, Field(**_bounds("rtol"))]
Atol = Annotated[float, Field(**_bounds("atol"))]
Step = Annotated[float, Field(**_bounds("step"))]
MaxSteps = Annotated[int, Field(**_bounds("max_steps"))]
MaxOrder = Annotated[int, Field(**_bounds("max_order"))]
OPTIONAL = {"t_end": TEnd, "n_out": NOut, "rtol": Rtol, "atol": Atol, "step": Step, "max_steps": MaxSteps,
            "max_order": MaxOrder}
"""The constrained type of each numeric option, for specs that make it optional (a scene)."""


class RunOptions(BaseModel):
    """The options of a run (the defaults of `phc simulate` on a model)."""

    model_config = ConfigDict(extra="forbid", allow_inf_nan=False, frozen=True, use_attribute_docstrings=True,
                              populate_by_name=True, defer_build=True)

    t_end: TEnd = 1.0
    t_start: float = 0.0
    """Start time of the run (before `t_end`)."""
    n_out: NOut = 201
    """Number of output points (including both ends)."""
    rtol: Rtol = 1e-8
    atol: Atol = 1e-10
    max_steps: MaxSteps = 1_000_000
    """Maximum number of solver steps over the whole run (at most 2³¹ − 1: IDA keeps it in a C long)."""
    solver: SOLVERS = "ida"
    """`ida`: SUNDIALS IDA (variable-order BDF, error control by `rtol`/`atol`); `midpoint`:
    the implicit midpoint rule with fixed `step`, whose discrete energy balance is exact for
    quadratic Hamiltonians; `discrete_gradient`: a discrete-gradient step with fixed `step`,
    exact for any Hamiltonian (the midpoint rule when H is quadratic); `midpoint4`: three
    midpoint substeps composed to order 4 (Yoshida/Suzuki triple jump) with fixed `step`,
    energy balance exact for quadratic Hamiltonians like the midpoint rule (its middle substep
    runs backwards, so dissipation is not monotone step by step)."""
    step: Optional[Step] = None
    """Step size of the fixed-step solvers `midpoint`, `discrete_gradient` and `midpoint4`
    (default: the output interval)."""
    max_order: MaxOrder = 5
    """Maximum BDF order of IDA. 2 (A-stable) suits undamped stiff oscillations such as
    fine beam meshes: orders 3–5 must resolve the highest modes to stay stable."""

    @field_validator("t_start")
    @classmethod
    def _start_before_end(cls, value, info):
        end = info.data.get("t_end")
        if end is not None and not value < end:
            raise ValueError(f"`t_start` ({value}) must be before `t_end` ({end}); set t_end to the time the "
                             "run should reach")
        return value

    @classmethod
    def of(cls, options: Mapping[str, Any]) -> "RunOptions":
        """The run options among `options` (a compiled model's, which hold more keys),
        checked as :meth:`with_overrides` checks them."""
        return cls.model_construct().with_overrides(**{k: v for k, v in options.items() if k in cls.model_fields})

    def with_overrides(self, **given) -> "RunOptions":
        """These options with the values in `given` that are not None, checked as the model
        file's are: the same ranges (:data:`phc.names.RUN_LIMITS`), without building
        pydantic's validator (a cached `phc simulate` does not pay for it).

        Raises
        ------
        phc.errors.SimulationSetupError
            One message per wrong value ("`rtol` must be a number between 0 and 1
            (exclusive), got 2"), in the words the command line uses for its options.
        """
        from phc.errors import SimulationSetupError

        update = {k: v for k, v in given.items() if v is not None}
        unknown = sorted(set(update) - set(RunOptions.model_fields))
        if unknown:
            raise TypeError(f"unknown run option(s): {', '.join(unknown)}")
        problems = [f"`{name}` {problem}" for name, value in update.items() if name in RUN_LIMITS
                    for problem in [option_problem(*RUN_LIMITS[name], value)] if problem]
        if "solver" in update and update["solver"] not in SOLVER_NAMES:
            problems.append(f"unknown solver `{update['solver']}`; choose one of {', '.join(SOLVER_NAMES)}")
        if "t_start" in update and option_problem("fraction", -math.inf, math.inf, update["t_start"]):
            problems.append(f"`t_start` must be a finite number, got {update['t_start']}")
        if problems:
            raise SimulationSetupError("; ".join(problems))
        values = {name: getattr(self, name) for name in RunOptions.model_fields}
        for name, value in update.items():
            kind = RUN_LIMITS.get(name, ("",))[0]
            values[name] = int(value) if kind == "count" else float(value) if name != "solver" else value
        if not (math.isfinite(values["t_end"] - values["t_start"]) and values["t_end"] > values["t_start"]):
            raise SimulationSetupError(f"`t_end` ({values['t_end']}) must be a finite time greater than the start "
                                       f"time ({values['t_start']})")
        return RunOptions.model_construct(**values)


__all__ = ["RunOptions", "SOLVERS", "OPTIONAL", "TEnd", "NOut", "Rtol", "Atol", "Step", "MaxSteps", "MaxOrder"]
