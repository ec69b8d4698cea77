"""Exceptions. User mistakes are reported as diagnostics; these stop a stage.

``PhcError``
    base of everything phc raises on purpose.
``ModelError``
    the model has errors; ``.diagnostics`` holds them (one located line each).
``InconsistentInitialError``
    fixed initial values violate the equations; ``.problems`` names the equations.
``SimulationSetupError``
    invalid simulation options or missing optional dependency.
``CodegenError``
    the code generator met something it cannot print (a phc bug, never a user mistake).
``PhcWarning``
    base of phc's warnings; ``IgnoredOptionWarning``: :func:`phc.simulate` was given an
    accuracy option the chosen solver does not use.

Defined beside the code that raises them, and all ``PhcError``:
``phc.spec.expressions.ExpressionError`` (a malformed or forbidden expression),
``phc.inputs.TableError`` (an input table that cannot be used),
``phc.library.linear.NpzProblem`` (a matrices file that cannot be used),
``phc.files.FileRefused`` (a referenced file phc will not read),
``phc.budget.SymbolicBudgetError`` (symbolic work above the budget),
``phc.io.OutputPathError`` (an output path that cannot be written),
``phc.cli.UsageError`` (a wrong command-line argument),
``phc.simulation.guard.ModelEvaluationError`` (a model expression outside its domain
during a run), ``phc.viz.PlotUnavailable`` (a ``SimulationSetupError``: matplotlib
missing). ``phc.simulation.result.SimulationInterrupted`` stays a ``KeyboardInterrupt``.
These are reported to users as located diagnostics; the exceptions reach only API callers.
"""

from __future__ import annotations


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


class PhcWarning(UserWarning):
    """Base of phc's warnings (the CLI prints them as one line `phc: warning: ...`)."""


class IgnoredOptionWarning(PhcWarning):
    """A simulation option was given that the chosen solver does not use (``rtol``/``atol``
    to a fixed-step solver, ``step`` to IDA): the run is not the one the option asks for.
    ``warnings.simplefilter("error", phc.IgnoredOptionWarning)`` makes it an error (phc's
    own test suite does, in ``pyproject.toml``)."""


class CodegenError(PhcError):
    """The code generator met an expression it has no printed form for."""
