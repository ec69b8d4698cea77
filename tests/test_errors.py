"""phc raises one family of exceptions: everything it raises on purpose is a PhcError
(:mod:`phc.errors` lists them), so an API caller can tell phc's refusals from bugs."""

import pytest

import phc
from phc.frontend.budget import SymbolicBudgetError
from phc.cli import UsageError
from phc.frontend.files import FileRefused
from phc.frontend.inputs import TableError
from phc.io import OutputPathError
from phc.library.linear import NpzProblem
from phc.simulation.guard import ModelEvaluationError
from phc.spec.expressions import ExpressionError, parse_expression
from phc.study.viz import PlotUnavailable


@pytest.mark.parametrize("cls", [phc.ModelError, phc.InconsistentInitialError, phc.SimulationSetupError,
                                 phc.CodegenError, ExpressionError, TableError, NpzProblem, FileRefused,
                                 SymbolicBudgetError, OutputPathError, UsageError, ModelEvaluationError,
                                 PlotUnavailable])
def test_every_exception_phc_raises_on_purpose_is_a_phc_error(cls):
    assert issubclass(cls, phc.PhcError)


def test_an_expression_error_is_caught_as_a_phc_error():
    with pytest.raises(phc.PhcError):
        parse_expression("__import__('os')", {})


def _phc_modules():
    import importlib
    import pkgutil

    for info in pkgutil.walk_packages(phc.__path__, "phc."):
        if info.name == "phc.__main__":  # runs the command line when imported
            continue
        yield importlib.import_module(info.name)


def test_every_exception_phc_defines_is_in_phc_errors():
    """One module holds phc's exceptions and warnings; the only others are the private
    control-flow exceptions that phc.errors' docstring lists."""
    from phc import errors

    strays, seen = [], set()
    for module in _phc_modules():
        for name, obj in vars(module).items():
            if not (isinstance(obj, type) and issubclass(obj, BaseException)):
                continue
            if not obj.__module__.startswith("phc") or obj in seen:
                continue
            seen.add(obj)
            where = f"{obj.__module__}.{obj.__qualname__}"
            if where in errors.PRIVATE_CONTROL_FLOW:
                assert obj.__module__ != "phc.errors"
                continue
            if obj.__module__ != "phc.errors" or getattr(errors, obj.__name__, None) is not obj:
                strays.append(f"{where} (seen in {module.__name__})")
            elif not (issubclass(obj, (errors.PhcError, errors.PhcWarning)) or obj is errors.SimulationInterrupted):
                strays.append(f"{where} is neither a PhcError nor a PhcWarning")
    assert not strays
    assert seen >= {getattr(errors, name) for name in errors.__all__}
    for where in errors.PRIVATE_CONTROL_FLOW:  # the list names what exists
        module, name = where.rsplit(".", 1)
        assert issubclass(getattr(__import__(module, fromlist=[name]), name), Exception), where


@pytest.mark.parametrize("old_home, name", [
    ("phc.cli", "UsageError"), ("phc.spec.expressions", "ExpressionError"), ("phc.spec.sweep", "SpecError"),
    ("phc.frontend.units", "UnitError"), ("phc.frontend.units", "DimensionError"), ("phc.library.linear", "NpzProblem"),
    ("phc.frontend.inputs", "TableError"), ("phc.study.viz", "PlotUnavailable"), ("phc.study.viz", "NothingToAnimate"),
    ("phc.frontend.files", "FileRefused"), ("phc.io", "OutputPathError"), ("phc.frontend.budget", "SymbolicBudgetError"),
    ("phc.codegen.numba_cache", "BackendUnavailable"), ("phc.codegen.numba_cache", "BackendMismatch"),
    ("phc.codegen.numba_cache", "CompiledBackendWarning"), ("phc.codegen.load", "CacheWarning"),
    ("phc.sweep", "SweepSetupError"), ("phc.simulation.guard", "ModelEvaluationError"),
    ("phc.simulation", "ModelEvaluationError"), ("phc.simulation", "SimulationInterrupted"),
    ("phc.simulation.result", "SimulationInterrupted"), ("phc.frontend.reference_values", "ReferenceValuesError"),
    ("phc.simulation.events", "SwitchTimeError")])
def test_an_exception_is_still_importable_from_its_old_home(old_home, name):
    import importlib

    from phc import errors

    assert getattr(importlib.import_module(old_home), name) is getattr(errors, name)
