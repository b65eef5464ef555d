"""The empirical methods, one registry on top of the estimators: the names `tcomp fit --model`,
`tcomp compare --methods`, `tcomp select --method` and `--option` all read.

Imports no numpy (the CLI builds its parsers from it); the estimator classes are imported when one
is made. Below it: regression.py, ann.py, ppr.py, dynamic.py, and at the bottom checks.py, which
they all share. docs/empirical.md describes the methods.
"""

from __future__ import annotations

from typing import Any

import importlib

from host.learning.empirical import EmpiricalDataError

# method -> estimator class (module:name). Every estimator has the one fit signature
# fit(X, y, names=None, groups=None) -> self (groups: cross-validation groups, read by the methods
# in CROSS_VALIDATED; dynamic's X are its lag-filtered candidates and names its (signal, tau) terms).
ESTIMATORS = {
    "mlr": "host.learning.empirical.regression:MLR",
    "pcr": "host.learning.empirical.regression:PCR",
    "stepwise": "host.learning.empirical.regression:Stepwise",
    "cv-subset": "host.learning.empirical.regression:BestSubsetCV",
    "ann": "host.learning.empirical.ann:ANN",
    "ppr": "host.learning.empirical.ppr:PPR",
    "dynamic": "host.learning.empirical.dynamic:DynamicRegression",
    "mr-poly": "host.learning.empirical.mrpoly:MRPoly",  # S004 Eq. 12 (its columns: nut and base rises)
}
CROSS_VALIDATED = ("cv-subset", "ann", "dynamic")  # fit reads groups (host/learning/empirical/fitting.py cv_groups)
# estimators whose fitted model has no model-document kind yet: `tcomp compare` runs them, `tcomp fit` cannot save them
NO_DOCUMENT: dict[str, str] = {}  # method -> why (none left since ppr got its kind)
FIT_METHODS = tuple(m for m in ESTIMATORS if m not in NO_DOCUMENT)  # `tcomp fit --model` (besides screw)

SELECTORS = ("maxtree", "stepwise", "hclust-ga")  # `tcomp select --method` (host/learning/empirical/selectors)
# `tcomp compare`: a selector alone means selector, then MLR; a pipeline is a selector, then an estimator
COMPARE_SELECTORS = ("maxtree", "hclust-ga")
PIPELINES = {"maxtree-mlr": ("maxtree", "mlr"), "maxtree-pcr": ("maxtree", "pcr"), "maxtree-ann": ("maxtree", "ann")}
COMPARE_METHODS = ("mlr", "pcr", "stepwise", "maxtree", "hclust-ga", "cv-subset", "ann", "ppr", "maxtree-mlr", "maxtree-pcr",
                   "maxtree-ann", "dynamic", "mr-poly")
# fitting options of a method beyond its estimator's parameters: how fit_model builds its candidates
# (host/learning/empirical/fitting.py _fit_dynamic)
CANDIDATE_OPTIONS = {"dynamic": ("taus_s", "use_spindle", "use_feed", "observer", "tau_max_fraction", "forward_blocks",
                                 "forward_state", "static_fallback", "settle_max_s", "average_structures",
                                 "average_members", "observer_sensors", "spindle_states", "controller_scoring", "settle_without_record_max_s"),
                     "mr-poly": ("nut", "base")}
COMPARE_DEFAULT = tuple(m for m in COMPARE_METHODS if m != "maxtree-mlr")  # maxtree-mlr is maxtree under the paper's name


def estimator_class(method: str) -> type:
    """The estimator class of ``method`` (a key of ESTIMATORS)."""
    if method not in ESTIMATORS:
        raise EmpiricalDataError("unknown regression method %r (known: %s)" % (method, ", ".join(ESTIMATORS)))
    module, _, name = ESTIMATORS[method].partition(":")
    return getattr(importlib.import_module(module), name)


def make_estimator(method: str, fit_intercept: bool = True, **options: Any) -> Any:
    """Estimator for ``method`` in ESTIMATORS with method-specific options (e.g. f_enter=100)."""
    return estimator_class(method)(fit_intercept=fit_intercept, **options)


def estimator_parameters(method: str) -> tuple[str, ...]:
    """The keyword parameters of ``method``'s estimator besides fit_intercept: what `--option` may set for it."""
    import inspect
    params = inspect.signature(estimator_class(method).__init__).parameters
    return tuple(k for k, p in params.items() if p.kind == p.KEYWORD_ONLY and k != "fit_intercept")


def method_options(method: str) -> tuple[str, ...]:
    """Everything `--option` may set for ``method``: its estimator's parameters, its CANDIDATE_OPTIONS and,
    when it cross-validates, cv_blocks (fit_model's cross-validation groups)."""
    return estimator_parameters(method) + CANDIDATE_OPTIONS.get(method, ()) + (("cv_blocks",) if method in CROSS_VALIDATED else ())
