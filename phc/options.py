"""One object for the options of a run: :class:`RunOptions`.

The options' names, defaults and ranges are defined once: the names and defaults here, the
ranges in :data:`phc.names.RUN_LIMITS`. The model's `simulation` section
(:class:`phc.spec.model.SimulationSpec`) and a scene's `t_end`, `n_out`, `solver` and
`accuracy` are pydantic fields built from them (:mod:`phc.spec.run`) and give a
:class:`RunOptions` (:meth:`SimulationSpec.run_options
<phc.spec.model.SimulationSpec.run_options>`); the command line checks its numeric options
against the same ranges with the same words (:func:`phc.names.option_problem`);
:func:`phc.simulate` makes one from the compiled model's options and the call's overrides
(:meth:`RunOptions.with_overrides`) and hands it to the integrator, which returns a typed
:class:`~phc.simulation.backend.BackendRun`.

This module imports neither pydantic nor numpy: a run from the cached front end (`phc
simulate` on an unchanged model) does not load the model language's validators.
"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass
from typing import Any, Mapping, Optional

from phc.names import RUN_LIMITS, SOLVER_NAMES, option_problem


@dataclass(frozen=True)
class RunOptions:
    """The options of a run (the defaults of `phc simulate` on a model), checked when made
    through :meth:`of` or :meth:`with_overrides`."""

    t_end: float = 1.0
    """End time of the run."""
    t_start: float = 0.0
    """Start time of the run (before `t_end`)."""
    n_out: int = 201
    """Number of output points (including both ends)."""
    rtol: float = 1e-8
    """Relative tolerance of IDA."""
    atol: float = 1e-10
    """Absolute tolerance of IDA, relative to each variable's nominal scale."""
    max_steps: int = 1_000_000
    """Maximum number of solver steps over the whole run."""
    solver: str = "ida"
    """One of :data:`phc.names.SOLVER_NAMES`."""
    step: Optional[float] = None
    """Step size of the fixed-step solvers (None: the output interval)."""
    max_order: Optional[int] = None
    """Maximum BDF order of IDA; None: phc chooses (5, or 2 where undamped oscillations hold
    the steps of orders 3–5, :mod:`phc.simulation.order`)."""

    @classmethod
    def names(cls) -> tuple[str, ...]:
        """The options' names."""
        return tuple(f.name for f in dataclasses.fields(cls))

    @classmethod
    def of(cls, options: Mapping[str, Any]) -> "RunOptions":
        """The run options among `options` (a compiled model's, which hold more keys),
        checked as :meth:`with_overrides` checks them."""
        names = cls.names()
        return cls().with_overrides(**{k: v for k, v in options.items() if k in names})

    def with_overrides(self, **given) -> "RunOptions":
        """These options with the values in `given` that are not None, checked as the model
        file's are (the ranges of :data:`phc.names.RUN_LIMITS`).

        Raises
        ------
        phc.errors.SimulationSetupError
            One message per wrong value ("`rtol` must be a number between 0 and 1
            (exclusive), got 2"), in the words the command line uses for its options.
        TypeError
            For a name that is not a run option.
        """
        from phc.errors import SimulationSetupError

        update = {k: v for k, v in given.items() if v is not None}
        unknown = sorted(set(update) - set(self.names()))
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
        for name, value in update.items():
            kind = RUN_LIMITS.get(name, ("",))[0]
            update[name] = value if name == "solver" else int(value) if kind == "count" else float(value)
        new = dataclasses.replace(self, **update)
        if not (math.isfinite(new.t_end - new.t_start) and new.t_end > new.t_start):
            raise SimulationSetupError(f"`t_end` ({new.t_end}) must be a finite time greater than the start "
                                       f"time ({new.t_start})")
        return new

    def replace(self, **changes) -> "RunOptions":
        """A copy with `changes`, unchecked (for values already checked)."""
        return dataclasses.replace(self, **changes)


DEFAULTS = RunOptions()
"""The defaults of the model language's `simulation` section."""

__all__ = ["RunOptions", "DEFAULTS"]
