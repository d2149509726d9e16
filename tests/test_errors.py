"""Every exception type lives in prp3mc.errors, and each names what went wrong."""

import ast
import sys
from pathlib import Path

import pytest

import prp3mc
from prp3mc import errors
from prp3mc.errors import MissingDependencyError, ParameterError, Prp3mcError

PACKAGE = Path(prp3mc.__file__).parent


def test_every_exception_type_is_defined_in_errors():
    """No module but errors.py defines an exception class (a class deriving from an ...Error or ...Exception)."""
    elsewhere = []
    for path in PACKAGE.rglob("*.py"):
        if path.name == "errors.py":
            continue
        for node in ast.walk(ast.parse(path.read_text(encoding="utf-8"))):
            if isinstance(node, ast.ClassDef) and any(
                    getattr(base, "id", getattr(base, "attr", "")).endswith(("Error", "Exception"))
                    for base in node.bases):
                elsewhere.append(f"{path.relative_to(PACKAGE)}: {node.name}")
    assert elsewhere == [], elsewhere
    assert set(errors.__all__) == {name for name in vars(errors) if isinstance(getattr(errors, name), type)}


@pytest.mark.parametrize("module, call", [
    ("openturns", lambda: __import__("prp3mc.model.interop", fromlist=["x"]).openturns_distribution(
        prp3mc.Budget.from_preset("paper"))),
    ("xarray", lambda: __import__("prp3mc.model.interop", fromlist=["x"]).to_xarray(None)),
])
def test_a_missing_optional_dependency_is_an_import_error_with_its_pip_line(module, call, monkeypatch):
    monkeypatch.setitem(sys.modules, module, None)          # as if it were not installed
    with pytest.raises(MissingDependencyError, match=f"{module} is not installed: pip install {module}") as info:
        call()
    assert isinstance(info.value, ImportError) and isinstance(info.value, Prp3mcError)
    assert info.value.install == f"pip install {module}" and info.value.name == module


def test_bad_arguments_of_an_analysis_are_parameter_errors_not_budget_errors():
    with pytest.raises(ParameterError, match="at least 32 samples"):
        prp3mc.monte_carlo(prp3mc.Geometry.from_preset("u-shape"), prp3mc.Budget.from_preset("paper"),
                           [0.0, 100.0, 0.0], 1)
    assert not issubclass(ParameterError, errors.BudgetError) and issubclass(ParameterError, ValueError)
