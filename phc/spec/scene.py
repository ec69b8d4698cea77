"""`SceneSpec`: one simulation scenario of a model (``models/scenes/*.yaml``).

A model says what a system *is*; a scene says what one simulation *needs*: the time span
and output grid, the initial state, inputs on exposed ports, parameter overrides, which
effects are on, the requested outputs, the accuracy target and the solver. phc compiles
only what the scene calls for and reports what it left out.
"""

from __future__ import annotations

from typing import Annotated, Literal, Optional, Union

from pydantic import Field, model_validator

from phc.spec.base import Expr, Identifier, SpecModel, Switch
from phc.spec.run import BENCH_SOLVERS, SOLVERS, Atol, MaxOrder, NOut, Rtol, Step, TEnd
from phc.spec.model import InitialSpec, InputSpec
from phc.spec.sweep import SweepSpec

Elements = Annotated[int, Field(ge=1, le=200_000)]
"""An element count: the same bounds as a distributed component's own `elements`."""


class AccuracySpec(SpecModel):
    """Accuracy target: solver tolerances, step, and mesh sizes."""

    rtol: Optional[Rtol] = None
    atol: Optional[Atol] = None
    step: Optional[Step] = None
    """Step size of the fixed-step solvers."""
    max_order: Optional[MaxOrder] = None
    mesh: dict[str, Elements] = {}
    """Number of elements per distributed component (`component: elements`), overriding
    the model's `elements`."""


class BenchSpec(SpecModel):
    """The sweep of `phc bench` (a work-precision study of this scene)."""

    solvers: Optional[list[BENCH_SOLVERS]] = None
    """Solvers to compare (default: all of phc's). ``scipy_Radau``, ``scipy_BDF`` and
    ``scipy_DOP853`` add scipy's methods given the same residual, where the model is an ODE
    after solving for its rates (a constrained DAE gets a row saying it is not)."""
    tolerances: list[Rtol] = Field([1e-4, 1e-6, 1e-8], min_length=1)
    """Relative tolerances of the error-controlled solvers (atol = rtol/100)."""
    steps: list[Step] = []
    """Step sizes of the fixed-step solvers (default: derived from the output interval)."""
    meshes: dict[str, list[Elements]] = {}
    """Element counts to sweep per distributed component."""
    repeats: int = Field(1, ge=1, le=20)
    """Runs per point; the CPU time reported is the minimum."""


class ReferenceValuesSpec(SpecModel):
    """Reference values of requested outputs at given times (a published reference
    solution, measurements): `phc bench` measures the errors of those outputs at these
    times. Give either a CSV `file` or the values inline (`t` and `values`)."""

    file: Optional[str] = None
    """CSV file, relative to the scene file (inside the scene's tree, like a table): a header
    row with the time column and one column per output, one row per time; lines starting
    with `#` are comments (cite the source there); an empty cell is no value."""
    time_column: str = "t"
    """Name of the time column of `file`."""
    t: Optional[list[float]] = None
    """Inline: the times (increasing, within the run)."""
    values: dict[Identifier, list[Optional[float]]] = {}
    """Inline: per output, one value per time in `t` (`null`: no value at that time)."""
    source: Optional[str] = None
    """Where the values come from (shown in `phc bench`'s report)."""

    @model_validator(mode="after")
    def _file_or_inline(self):
        if (self.file is None) == (self.t is None):
            raise ValueError("give either `file` (a CSV file) or the values inline (`t` and `values`)")
        if self.file is not None and self.values:
            raise ValueError("`values` belong to inline reference values (with `t`), not to a `file`")
        if self.t is not None and not self.values:
            raise ValueError("inline reference values need `values`: per output, one value per time in `t`")
        return self


EffectValue = Union[Switch, int]


class SceneSpec(SpecModel):
    """A simulation scenario: a model plus what this run needs."""

    format_version: Literal[1] = 1
    model: str
    """The model file, relative to this scene file."""
    name: Optional[Identifier] = None
    description: Optional[str] = None
    parameters: dict[Identifier, Union[int, float]] = {}
    """Overrides of the model's top-level parameters (numbers)."""
    effects: dict[str, dict[Identifier, EffectValue]] = {}
    """Effects per component (`component: {effect: on|off|k}`; nested components by dotted
    name). Effects left out keep the model's values."""
    t_start: Optional[float] = None
    t_end: Optional[TEnd] = None
    n_out: Optional[NOut] = None
    initial: dict[str, Union[Expr, InitialSpec]] = {}
    """Initial values by state name, merged over the model's (a value here wins), or initial
    fields of distributed components as functions of `xi` (`rod.w: "0.001*sin(pi*xi/L)"`,
    docs/how-to/initial-fields.md). phc completes the rest by consistent initialization and
    reports what it chose."""
    nominal: dict[str, Annotated[float, Field(gt=0, allow_inf_nan=False)]] = {}
    """Nominal scales by state name, merged over the model's `simulation.nominal` (a value
    here wins): the size `atol` and the Newton tests measure the state against."""
    initial_shape: dict[str, Literal["straight", "free"]] = {}
    """Initial shape per moving beam (`component: straight|free`), overriding the model's
    `initial_shape`."""
    inputs: dict[str, InputSpec] = {}
    """Inputs on exposed ports, merged over the model's."""
    outputs: dict[Identifier, Expr] = {}
    """Requested outputs (replace the model's when given): expressions over states, port
    variables, component outputs such as a beam's `w[i]`, `t` and `H`."""
    accuracy: AccuracySpec = AccuracySpec()
    solver: Optional[SOLVERS] = None
    reference: dict[Identifier, Expr] = {}
    """Closed forms of requested outputs (expressions in `t` and parameters): `phc bench` and
    `--estimate-error` measure errors against them instead of a reference run."""
    reference_values: Optional[ReferenceValuesSpec] = None
    """Reference values of requested outputs at given times (e.g. a published reference
    solution), from a CSV file or inline: `phc bench` measures those outputs' errors at
    these times (docs/how-to/accuracy.md)."""
    bench: BenchSpec = BenchSpec()
    sweep: SweepSpec = SweepSpec()
    """The parameter study of `phc sweep` (see docs/parameter-studies.md)."""
    prune: bool = True
    """Leave out the subsystems that cannot influence the requested outputs (components
    not connected to any component an output refers to)."""
