"""Empirical thermal-error models (issue 3).

Modules: ``targets`` (what is modelled: sweep slopes, direct errors, temperature
features), ``geometric`` (cold polynomial), ``regression`` (MLR, PCR, stepwise
estimators), ``model`` (the ``poly_slope`` and ``linear_direct`` model documents),
``scoring`` (cross-run evaluation, robustness), ``compare`` (``tcomp compare``),
``plots``, ``cli`` (``tcomp fit`` for mlr/pcr/stepwise) and ``selectors/``
(sensor selection). docs/empirical.md explains methods and thresholds.
"""


class EmpiricalDataError(ValueError):
    """Data that cannot give a sound empirical model (too few samples, NaN,
    constant or collinear sensors, missing channel...). The message names what
    is wrong and where; the CLI shows it without a traceback."""
