"""One registry of empirical methods (host/learning/empirical/methods.py) on top, the shared checks at the
bottom (checks.py): no import knot, one fit signature, and `tcomp fit`, `compare`, `select` and `--option`
all reading the registry."""
import ast
import inspect
from pathlib import Path

import pytest

from host.learning.empirical import methods

EMPIRICAL = Path(methods.__file__).resolve().parent
ESTIMATOR_MODULES = ("regression", "ann", "ppr", "dynamic")


def _imports(module):
    """Every module our code imports in ``module`` (top level and inside functions)."""
    tree = ast.parse((EMPIRICAL / (module + ".py")).read_text())
    out = set()
    for node in ast.walk(tree):
        if isinstance(node, ast.ImportFrom) and node.module:
            out.add(node.module)
        elif isinstance(node, ast.Import):
            out.update(a.name for a in node.names)
    return out


def test_no_knot_between_the_estimators():
    pkg = "host.learning.empirical."
    for mod in ESTIMATOR_MODULES:
        others = {pkg + m for m in ESTIMATOR_MODULES if m != mod} | {pkg + "methods"}
        assert not _imports(mod) & others, mod
        assert pkg + "checks" in _imports(mod), mod
    assert not {i for i in _imports("checks") if i.startswith(pkg)}, "checks.py is the bottom: it imports no estimator"


def test_every_estimator_has_the_one_fit_signature():
    for method in methods.ESTIMATORS:
        params = list(inspect.signature(methods.estimator_class(method).fit).parameters)
        assert params == ["self", "X", "y", "names", "groups"], (method, params)


def test_fit_compare_and_select_read_the_registry():
    from host.cli.verbs import compare, fit, select
    from host.learning.empirical import compare as comparing
    from host.learning.empirical import selectors

    assert set(methods.FIT_METHODS) | set(methods.NO_DOCUMENT) == set(methods.ESTIMATORS)
    assert fit.EMPIRICAL is methods.FIT_METHODS
    assert select.METHODS is selectors.METHODS is methods.SELECTORS
    assert comparing.METHODS is methods.COMPARE_METHODS and comparing.PIPELINES is methods.PIPELINES
    import argparse
    p = argparse.ArgumentParser()
    compare.add_arguments(p)
    assert p.get_default("methods").split(",") == list(methods.COMPARE_DEFAULT)
    assert set(methods.COMPARE_METHODS) >= set(methods.ESTIMATORS) | set(methods.COMPARE_SELECTORS) | set(methods.PIPELINES)


def test_every_fit_option_is_a_method_option_or_a_fit_model_parameter():
    from host.cli.fit_empirical import OPTIONS
    from host.learning.empirical.fitting import fit_model

    owned = {k for m in methods.FIT_METHODS for k in methods.method_options(m)}
    general = set(inspect.signature(fit_model).parameters) | {"t_min_s", "t_max_s"}  # the window, split by fit_command
    assert not set(OPTIONS) - owned - general, sorted(set(OPTIONS) - owned - general)


def test_an_option_of_another_method_is_refused():
    from host.cli.fit_empirical import parse_options
    from host.errors import UserError

    assert parse_options(["max_sensors=3"], "dynamic") == {"max_sensors": 3}
    assert parse_options(["cv_blocks=3"], "ann") == {"cv_blocks": 3}
    with pytest.raises(UserError, match="--option cv_blocks applies to --model cv-subset, not mlr"):
        parse_options(["cv_blocks=3"], "mlr")  # mlr reads no groups: before, the setting was dropped without a word
    with pytest.raises(UserError, match="--option ridge applies to --model dynamic, not pcr"):
        parse_options(["ridge=0.1"], "pcr")
