"""`ModelSpec`: the top level of a model file (format version 1)."""

from __future__ import annotations

from typing import Annotated, Literal, Optional, Union

from pydantic import Discriminator, Field, Tag, field_validator, model_validator

from phc.options import DEFAULTS, RunOptions
from phc.spec.run import SOLVERS, Atol, MaxOrder, MaxSteps, NOut, Rtol, Step, TEnd
from phc.spec.base import Expr, Identifier, SpecModel, Unit, Vector
from phc.spec.components import ComponentSpec

FORMAT_VERSION = 1


class ParameterSpec(SpecModel):
    """A named parameter. Its value is a number or an expression of other parameters."""

    value: Expr
    unit: Optional[Unit] = None
    """Its unit (`N/m`, `kg*m^2`; `1` for a dimensionless number such as a gear ratio), checked
    against the fields that use it (docs/units.md)."""
    description: Optional[str] = None
    """What it is, for readers of the model (not used by phc)."""


class OutputSpec(SpecModel):
    """An output with its unit: `{value: slider.x, unit: m}`. The unit labels the results
    (CSV header `output.x [m]`, JSON, plot axes) and is checked against the dimension of
    `value` where that is known (docs/units.md)."""

    value: Expr
    unit: Optional[Unit] = None
    """The unit of the results (`m`, `mm`, `1`): the value is converted to it from the model's
    units where both are known (a length in m declared in mm is multiplied by 1000)."""
    description: Optional[str] = None
    """What it is, for readers of the model (not used by phc)."""


class ConnectionSpec(SpecModel):
    """Joins two ports: ``f₁ = f₂``, ``e₁ = −e₂`` (the paper's coupling conditions, eq. (2), Section 2.2)."""

    between: tuple[str, str]
    """The two ports, each as `component.port`."""
    description: Optional[str] = None

    @field_validator("between", mode="before")
    @classmethod
    def _two_ports(cls, value):
        if isinstance(value, (list, tuple)) and len(value) != 2:
            raise ValueError(f"a connection joins exactly 2 ports, got {len(value)}")
        return value


class ExposedPortSpec(SpecModel):
    """A port of an inner component made a port of this model."""

    port: str
    """The inner port, as `component.port`."""
    description: Optional[str] = None


class InitialSpec(SpecModel):
    """An initial value that is either fixed or only a guess for consistent initialization."""

    value: Expr
    guess: bool = False
    """When true, phc may change the value to satisfy the constraints (and says so)."""


class PieceSpec(SpecModel):
    """One piece of a piecewise signal: `value` until time `until` (the last piece may omit it)."""

    until: Optional[float] = None
    value: Expr


class TableSpec(SpecModel):
    """A signal from a CSV table with a header row, interpolated in time."""

    file: str
    """CSV file, relative to the file that names it."""
    column: str
    """Column of the values."""
    time_column: str = "t"
    interpolation: Literal["linear", "previous"] = "linear"
    """`linear` between rows, or `previous` (piecewise constant, zero-order hold). Outside
    the table the first or last value holds."""


_TABLE_KEYS = frozenset(TableSpec.model_fields)
"""Keys that make a mapping a table (`file`, `column`, ...), not a piece."""


def _signal_kind(value) -> str:
    """Which kind of signal `value` is, by its shape: a mapping is a table, a list the
    pieces, anything else an expression (so a typo in a piece is reported as an unknown
    key of the piece, not as the keys a table would miss). A validated value (when a spec
    is serialized) is classified by its type the same way."""
    if isinstance(value, (dict, TableSpec)):
        return "table"
    if isinstance(value, list):
        return "pieces"
    return "expression"


def _is_pieces(value) -> bool:
    """A list of mappings none of which has a table's key: the pieces of one signal."""
    return (isinstance(value, list) and bool(value)
            and all(isinstance(v, PieceSpec) or (isinstance(v, dict) and not _TABLE_KEYS & set(v)) for v in value))


Signal = Annotated[Union[Annotated[Expr, Tag("expression")], Annotated[list[PieceSpec], Tag("pieces")],
                         Annotated[TableSpec, Tag("table")]], Discriminator(_signal_kind)]
"""An input signal: an expression in `t`, a list of pieces `{until, value}`, or a table."""


def _signals_kind(value) -> str:
    """One signal, or one signal per component of a vector port (a list of signals); a list
    of mappings without a table's keys is the pieces of one signal."""
    return "vector" if isinstance(value, list) and not _is_pieces(value) else "signal"


Signals = Annotated[Union[Annotated[Signal, Tag("signal")], Annotated[list[Signal], Tag("vector")]],
                    Discriminator(_signals_kind)]


class InputSpec(SpecModel):
    """Drives an exposed port: give its effort or its flow as a function of `t` (an
    expression, a piecewise definition or a CSV table; one per component of a vector port)."""

    effort: Optional[Signals] = None
    flow: Optional[Signals] = None

    @model_validator(mode="after")
    def _exactly_one(self):
        if (self.effort is None) == (self.flow is None):
            raise ValueError("give exactly one of `effort` or `flow`")
        return self


class SimulationSpec(SpecModel):
    """Defaults for `phc simulate` on this model: time span, output grid, solver and
    tolerances, initial values, inputs and outputs."""

    t_end: TEnd = DEFAULTS.t_end
    t_start: float = DEFAULTS.t_start
    """Start time of the run (before `t_end`)."""
    n_out: NOut = DEFAULTS.n_out
    """Number of output points (including both ends)."""
    rtol: Rtol = DEFAULTS.rtol
    atol: Atol = DEFAULTS.atol
    max_steps: MaxSteps = DEFAULTS.max_steps
    """Maximum number of solver steps over the whole run (at most 2³¹ − 1: IDA keeps it in a C long)."""
    solver: SOLVERS = DEFAULTS.solver
    """`ida`: SUNDIALS IDA (variable-order BDF, error control by `rtol`/`atol`); `midpoint`:
    the implicit midpoint rule with fixed `step`, whose discrete energy balance is exact for
    quadratic Hamiltonians; `discrete_gradient`: a discrete-gradient step with fixed `step`,
    exact for any Hamiltonian (the midpoint rule when H is quadratic); `midpoint4`: three
    midpoint substeps composed to order 4 (Yoshida/Suzuki triple jump) with fixed `step`,
    energy balance exact for quadratic Hamiltonians like the midpoint rule (its middle substep
    runs backwards, so dissipation is not monotone step by step)."""
    step: Optional[Step] = DEFAULTS.step
    """Step size of the fixed-step solvers `midpoint`, `discrete_gradient` and `midpoint4`
    (default: the output interval)."""
    max_order: Optional[MaxOrder] = DEFAULTS.max_order
    """Maximum BDF order of IDA (1–5). Unset, phc chooses: IDA's default 5, or 2 (A-stable)
    from where undamped oscillations, such as the high modes of a fine beam mesh, hold the
    steps of orders 3–5 (which are stable for them only at steps that resolve them) and
    order 2 makes longer steps; the run's message says so (docs/how-to/solvers.md)."""
    initial: dict[str, Union[Expr, InitialSpec]] = {}
    """Initial values by variable name (`component.state`), or initial fields of strings and
    beams as functions of `xi` (`rod.w: "0.001*sin(pi*xi/L)"`), projected onto whatever mesh
    is compiled (docs/how-to/initial-fields.md). Unlisted states start as a guess of 0 and
    are solved for by consistent initialization."""
    nominal: dict[str, Annotated[float, Field(gt=0, allow_inf_nan=False)]] = {}
    """Nominal scales by state name (`component.state: typical size`, in the state's unit):
    the size against which `atol` and the Newton tests measure this state. phc
    finds one for every state (from the start, a short probe and the equations,
    docs/tolerances.md); set it where you know better, e.g. for a state that starts at 0 and
    grows far beyond what the first instants show."""
    inputs: dict[str, InputSpec] = {}
    """Inputs on exposed ports. An exposed port without input is free (zero effort)."""
    outputs: dict[Identifier, Union[Expr, OutputSpec]] = {}
    """Named output expressions over variables (`component.x`), `t` and `H`; either
    `name: expression` or `name: {value, unit, description}`."""

    @field_validator("t_start")
    @classmethod
    def _start_before_end(cls, value, info):
        end = info.data.get("t_end")
        if end is not None and not value < end:
            raise ValueError(f"`t_start` ({value}) must be before `t_end` ({end}); set t_end to the time the "
                             "run should reach")
        return value

    def run_options(self) -> RunOptions:
        """The run options this section sets (:class:`phc.options.RunOptions`)."""
        return RunOptions.of({name: getattr(self, name) for name in RunOptions.names()})


class ModelSpec(SpecModel):
    """A port-Hamiltonian model: components, how their ports are connected, and exposed ports."""

    format_version: Literal[1] = Field(
        1, description="Version of the model language. Only 1 exists."
    )
    name: Optional[Identifier] = None
    description: Optional[str] = None
    kind: Literal["model", "part"] = "model"
    """`model` (the default): a complete model, compiled and simulated on its own. `part`: a
    reusable piece that other models nest (`type: model`, `file: ...`); `phc validate`
    checks it without closing its exposed ports (their terminations come from the model
    that uses it), and `phc compile`/`simulate` refuse it. A part exposes at least one port
    and has no `simulation` section."""
    parameters: dict[Identifier, Union[ParameterSpec, Expr]] = {}
    """Parameters, either `name: value` or `name: {value, unit, description}`."""
    components: dict[Identifier, ComponentSpec] = Field(min_length=1)
    connections: list[ConnectionSpec] = []
    ports: dict[Identifier, ExposedPortSpec] = {}
    """Ports exposed to the outside (for nesting, or driven by `simulation.inputs`)."""
    simulation: SimulationSpec = SimulationSpec()

    @field_validator("connections", mode="before")
    @classmethod
    def _short_connections(cls, value):
        # `- [a.p, b.q]` is shorthand for `- {between: [a.p, b.q]}`.
        if isinstance(value, list):
            return [
                {"between": item} if isinstance(item, (list, tuple)) else item for item in value
            ]
        return value
