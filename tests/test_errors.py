"""phc raises one family of exceptions: everything it raises on purpose is a PhcError
(:mod:`phc.errors` lists them), so an API caller can tell phc's refusals from bugs."""

import pytest

import phc
from phc.budget import SymbolicBudgetError
from phc.cli import UsageError
from phc.files import FileRefused
from phc.inputs import TableError
from phc.io import OutputPathError
from phc.library.linear import NpzProblem
from phc.simulation.guard import ModelEvaluationError
from phc.spec.expressions import ExpressionError, parse_expression
from phc.viz import PlotUnavailable


@pytest.mark.parametrize("cls", [phc.ModelError, phc.InconsistentInitialError, phc.SimulationSetupError,
                                 phc.CodegenError, ExpressionError, TableError, NpzProblem, FileRefused,
                                 SymbolicBudgetError, OutputPathError, UsageError, ModelEvaluationError,
                                 PlotUnavailable])
def test_every_exception_phc_raises_on_purpose_is_a_phc_error(cls):
    assert issubclass(cls, phc.PhcError)


def test_an_expression_error_is_caught_as_a_phc_error():
    with pytest.raises(phc.PhcError):
        parse_expression("__import__('os')", {})
