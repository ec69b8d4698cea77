"""Exceptions and warnings: every one phc raises on purpose is defined here.

User mistakes are reported as diagnostics; these exceptions stop a stage. The command line
reports every :class:`PhcError` that reaches it as one line ``phc COMMAND: error: ...``
(most are turned into located diagnostics before that); anything else is an internal
error of phc and says so. The old homes (``phc.cli.UsageError``,
``phc.spec.expressions.ExpressionError``, ...) import the classes from here, so both
spellings name the same class.

Everything phc raises on purpose
    ``PhcError``
        base of everything phc raises on purpose.
    ``ModelError``
        the model has errors; ``.diagnostics`` holds them (one located line each).
    ``InconsistentInitialError``
        fixed initial values violate the equations; ``.problems`` names the equations.
    ``SimulationSetupError``
        invalid simulation options or missing optional dependency (also a ``ValueError``);
        ``PlotUnavailable`` (matplotlib missing), ``NothingToAnimate`` (no planar mechanism
        to draw) and ``SweepSetupError`` (a sweep that cannot start) are ones.
    ``CodegenError``
        the code generator met something it cannot print (a phc bug, never a user mistake).
    ``RegistryError``
        a component type :mod:`phc.library.registry` refuses (a field missing or wrong, a name taken).

What the user wrote
    ``ExpressionError`` (a malformed or forbidden expression), ``SpecError`` (a sweep
    SPEC that cannot be read), ``UnitError`` (a unit text phc does not know),
    ``DimensionError`` (parts of incompatible dimensions), ``UsageError`` (a wrong
    command-line argument): all but ``UsageError`` are also ``ValueError`` (pydantic
    validators locate a ``ValueError`` at the entry that raised it).

Files
    ``FileRefused`` (a referenced file phc will not read), ``TableError`` (an input table
    that cannot be used), ``NpzProblem`` (a matrices file that cannot be used),
    ``ReferenceValuesError`` (reference values that cannot be used, with where),
    ``OutputPathError`` (an output path that cannot be written; also a ``ValueError``).

Compiling and running
    ``SymbolicBudgetError`` (symbolic work above the budget), ``BackendUnavailable`` (the
    compiled backend cannot be used here: numba or a C compiler missing),
    ``BackendUnsupported`` (a ``CodegenError``: the model uses something the chosen back end
    does not print yet), ``BackendMismatch`` (compiled functions
    disagree with the reference module), ``ModelEvaluationError`` (a model expression
    outside its domain during a run: :mod:`phc.simulation.guard` raises it only for a
    domain error, ``ArithmeticError`` or a non-finite result; any other exception of the
    generated code is a bug of phc and reaches the user as an internal error),
    ``SwitchTimeError`` (the switching times of a condition in t cannot be located),
    ``ExportError`` (a model or options ``phc export`` cannot write as an FMU).

Not a ``PhcError``
    ``SimulationInterrupted`` is Ctrl-C during :func:`phc.simulate`: a
    ``KeyboardInterrupt`` carrying the partial result, so that ``except Exception`` does
    not catch it.

Warnings
    ``PhcWarning`` is the base of phc's warnings: ``IgnoredOptionWarning`` (an accuracy
    option the chosen solver does not use), ``CompiledBackendWarning`` (the NumPy module
    runs instead of the compiled backend), ``CompiledLoopWarning`` (the C back end's compiled
    step loop cannot run a simulation: the Python loop does), ``CacheWarning`` (the configured cache
    directory is unusable; a temporary one is used).

Private control flow, defined where it is used
    These never leave the module (or the pass) that raises them, so they are not
    ``PhcError``: ``phc.cli.report._Exit`` (leave a command with an exit code),
    ``phc.checks.compiled._NotNumeric`` (a node the numpy tree walk leaves to sympy),
    ``phc.ir.initial_fields._FieldError`` and its ``_Silent`` (a field problem turned into a
    diagnostic by the pass), ``phc.codegen.numba_cache.NotInCache`` (the full compile path
    has to run), ``phc.frontend.source._NotRegular`` (an ``OSError``: a model path that is not a
    regular file), ``phc.simulation.ida._Stop`` (phc's step hook ends an IDA run from inside
    IDA's loop; the run returns its message), ``phc.simulation.order.Switch`` (the step hook
    ends an IDA run to go on at another maximum BDF order; the IDA driver catches it),
    ``phc.simulation.events._ContactRest`` (a contact cannot go on: the switched driver
    stops the run with its message), ``phc.study.ode_form._Stop`` (a scipy run of the ODE form
    ends early; its row keeps the message), ``phc.ir.alike._Opaque`` (a row the renaming rebuild
    leaves to sympy). :data:`PRIVATE_CONTROL_FLOW` names them; ``tests/test_errors.py`` walks
    phc's modules and fails on any other exception defined outside this module.
"""

from __future__ import annotations

import os
import sys
from typing import TYPE_CHECKING, Optional

if TYPE_CHECKING:  # pragma: no cover
    from phc.simulation.result import SimResult
    from phc.frontend.source import SourceSpan

PLOT_INSTALL_HINT = 'pip install "port-hamiltonian-compiler[plot]"'


class PhcError(Exception):
    """Base class of phc's exceptions."""


class ModelError(PhcError):
    """Raised by :func:`phc.load_model` / :func:`phc.compile_model` when the model has errors."""

    def __init__(self, diagnostics):
        self.diagnostics = diagnostics
        super().__init__("\n".join(d.render() for d in diagnostics if d.severity == "error"))


class InconsistentInitialError(PhcError):
    """Fixed initial values violate the model's equations or hidden constraints."""

    def __init__(self, problems: list[str]):
        self.problems = problems
        super().__init__("inconsistent initial values: " + "; ".join(problems))


class SimulationSetupError(PhcError, ValueError):
    """Invalid simulation options (raised before integrating)."""


class NotAnODE(SimulationSetupError):
    """The model has no explicit form ``ẋ = f(t, x)`` for scipy's ODE solvers
    (:mod:`phc.study.ode_form`: constraints, a singular ∂F/∂ẋ, state events); the message says why."""


class CodegenError(PhcError):
    """The code generator met an expression it has no printed form for."""


class TranslationError(CodegenError):
    """Python of phc's step logic outside the subset phc.codegen.c_translate prints as C (a
    bug of phc, found by its tests): the message names the file, line and function."""


# -- what the user wrote -----------------------------------------------------------------

class ExpressionError(PhcError, ValueError):
    """A malformed or forbidden expression.

    Parameters
    ----------
    message : str
        What is wrong, naming the offending construct.
    col : int
        0-based character offset in the expression text where the problem starts.
    hint : str or None
        Optional fix suggestion, e.g. ``"did you mean `theta`?"``.
    """

    def __init__(self, message: str, col: int = 0, hint: str | None = None):
        super().__init__(message)
        self.message, self.col, self.hint = message, col, hint

    def __str__(self) -> str:
        return self.message if self.hint is None else f"{self.message} ({self.hint})"

    def shifted(self, offset: int) -> "ExpressionError":
        """Return a copy whose column is moved right by `offset` characters."""
        return ExpressionError(self.message, self.col + offset, self.hint)


class SpecError(PhcError, ValueError):
    """A SPEC that cannot be read (the message says how to write it)."""


class UnitError(PhcError, ValueError):
    """A unit text that is malformed or names no known unit (`message` and `hint`)."""

    def __init__(self, message: str, hint: Optional[str] = None):
        super().__init__(message)
        self.message, self.hint = message, hint


class DimensionError(PhcError, ValueError):
    """An expression whose parts have incompatible dimensions."""


class UsageError(PhcError):
    """A wrong command-line argument."""


# -- files -------------------------------------------------------------------------------

class FileRefused(PhcError):
    """A referenced file phc will not read. `reason` is one of ``outside``, ``missing``,
    ``kind``, ``size``, ``unreadable``, ``name``; `message` and `hint` are for the user."""

    def __init__(self, reason: str, message: str, hint: Optional[str] = None) -> None:
        super().__init__(message)
        self.reason = reason
        self.message = message
        self.hint = hint


class TableError(PhcError):
    """A table file that cannot be used; `message` says why (never quoting the file's
    content beyond a column name of a header that parsed as one)."""


class NpzProblem(PhcError):
    """A matrices file, or an array in it, that phc will not use (`message` says why)."""


class ReferenceValuesError(PhcError):
    """A problem with reference values: `message`, and where (`span`, `path` of a scene entry)."""

    def __init__(self, message: str, span: Optional[SourceSpan] = None, hint: Optional[str] = None,
                 path: Optional[tuple] = None) -> None:
        super().__init__(message)
        self.message, self.span, self.hint, self.path = message, span, hint, path


class OutputPathError(PhcError, ValueError):
    """An output path that cannot be written (the message says why and what to do)."""


# -- compiling and running ---------------------------------------------------------------

class SymbolicBudgetError(PhcError):
    """An expression whose derivative (or whose CSE) would exceed the symbolic budget."""

    def __init__(self, expr, work: int, limit: int, what: str) -> None:
        self.expr, self.work, self.limit, self.what = expr, work, limit, what
        super().__init__(f"{what}: estimated {work:,} nodes, above the limit of {limit:,}")


class BackendUnavailable(PhcError):
    """The compiled backend cannot be used here (numba missing or too old, no C compiler); says why."""


class BackendMismatch(PhcError):
    """The compiled functions disagree with the reference module at the check point."""


class BackendUnsupported(CodegenError):
    """The model uses something a back end cannot print yet (the C back end: an input
    table); the message names it and where it is used."""


class ExportError(PhcError):
    """A model or options that cannot be exported as an FMU (:mod:`phc.export.fmu`): one line
    naming the file, what cannot be exported and what to do."""


class SweepSetupError(SimulationSetupError):
    """A sweep that cannot start (a wrong name or SPEC, results that do not match on resume);
    the command line reports it as a usage error."""


class PlotUnavailable(SimulationSetupError):
    """Drawing was asked for but matplotlib is not installed."""

    def __init__(self, what: str = "drawing"):
        super().__init__(f"{what} needs matplotlib, which is not installed; install it with: {PLOT_INSTALL_HINT}")


class NothingToAnimate(SimulationSetupError):
    """The model has no planar mechanism that :func:`phc.study.viz.animate` knows how to draw."""


class ModelEvaluationError(PhcError):
    """A generated function could not be evaluated (a domain error, an overflow, a
    non-finite value). ``str(err)`` is the one-line message; the attributes carry the parts.

    Attributes
    ----------
    function : str
        ``residual``, ``jacobian``, ``outputs``, ...
    label : str or None
        The residual row, output or invariant label, when identified.
    t : float
        The time of the evaluation.
    parameters : dict
        Parameters the failing expression uses, with their values.
    """

    def __init__(self, message: str, *, function: str, t: float, label: Optional[str] = None,
                 parameters: Optional[dict] = None, variables: Optional[dict] = None, subject: str = "",
                 reason: str = "", expression: str = ""):
        super().__init__(message)
        self.message = message
        self.function, self.t, self.label = function, float(t), label
        self.parameters = dict(parameters or {})
        self.variables = dict(variables or {})
        self.subject, self.reason, self.expression = subject or function, reason, expression
        """What failed (with its place in the model file), why, and the expression in model names."""


class SwitchTimeError(PhcError):
    """The switching times of a condition in t cannot be located."""

    def __init__(self, k: int, message: str):
        super().__init__(message)
        self.k, self.message = k, message


class SimulationInterrupted(KeyboardInterrupt):
    """Ctrl-C during :func:`phc.simulate`: a ``KeyboardInterrupt`` that carries the partial
    result (``.result``, ``success`` False, ``interrupted`` True) so that a caller can keep
    what was computed; a caller that does not look at it stops as on any Ctrl-C."""

    def __init__(self, result: SimResult):
        super().__init__(result.message)
        self.result = result


# -- warnings ----------------------------------------------------------------------------

class PhcWarning(UserWarning):
    """Base of phc's warnings (the CLI prints them as one line `phc: warning: ...`)."""


class IgnoredOptionWarning(PhcWarning):
    """A simulation option was given that the chosen solver does not use (``rtol``/``atol``
    to a fixed-step solver, ``step`` to IDA): the run is not the one the option asks for.
    ``warnings.simplefilter("error", phc.IgnoredOptionWarning)`` makes it an error (phc's
    own test suite does, in ``pyproject.toml``)."""


class CompiledBackendWarning(PhcWarning):
    """The compiled backend was asked for (or chosen) but the NumPy module is used instead."""


class CompiledLoopWarning(PhcWarning):
    """A compiled step loop the run's backend offers (the C back end's fixed-step loops) cannot
    run this simulation: the Python step loop runs it instead — the same steps, more time
    per step. Said once per process and reason."""


class CacheWarning(PhcWarning):
    """A cache problem, never the model's: the configured cache directory is unusable or not
    private (a temporary one is used), or a cache entry does not verify or disagrees with
    the model (a miss: compiled again)."""


class RegistryError(PhcError):
    """A component type that cannot be registered (:mod:`phc.library.registry`: a field missing or
    wrong, a name taken)."""


PRIVATE_CONTROL_FLOW = ("phc.cli.report._Exit", "phc.frontend.lowering.Unshareable", "phc.checks.compiled._NotNumeric", "phc.ir.initial_fields._FieldError",
                        "phc.ir.initial_fields._Silent", "phc.codegen.numba_cache.NotInCache",
                        "phc.frontend.source._NotRegular", "phc.codegen.c_translate._Unknown", "phc.simulation.ida._Stop", "phc.simulation.order.Switch",
                        "phc.simulation.events._ContactRest", "phc.study.ode_form._Stop",
                        "phc.ir.alike._Opaque")
"""Exceptions that never leave the code that raises them, defined there (qualified names)."""

__all__ = ["BackendMismatch", "BackendUnavailable", "BackendUnsupported", "CacheWarning", "CodegenError", "TranslationError",
           "CompiledBackendWarning", "CompiledLoopWarning",
           "DimensionError", "ExportError", "ExpressionError", "FileRefused", "IgnoredOptionWarning",
           "InconsistentInitialError",
           "ModelError", "ModelEvaluationError", "NotAnODE", "NothingToAnimate", "NpzProblem", "OutputPathError",
           "PhcError", "PhcWarning", "PlotUnavailable", "ReferenceValuesError", "RegistryError",
           "SimulationInterrupted",
           "SimulationSetupError", "SpecError", "SweepSetupError", "SwitchTimeError", "SymbolicBudgetError",
           "TableError", "UnitError", "UsageError"]


_PACKAGE = os.path.dirname(os.path.abspath(__file__)) + os.sep


def caller_stacklevel() -> int:
    """The ``stacklevel`` for :func:`warnings.warn` that names the first frame outside phc:
    a warning points at the user's line that called phc, however deep inside phc it is raised
    (a fixed level points into phc when the call path changes). Call it in the ``warn`` call."""
    frame, level = sys._getframe(1), 1
    while frame is not None and frame.f_code.co_filename.startswith(_PACKAGE):
        frame, level = frame.f_back, level + 1
    return level
