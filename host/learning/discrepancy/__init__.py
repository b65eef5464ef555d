"""Discrepancy workflow: where a physics model and measurements disagree, and which effect is missing.

``workflow.discover`` runs the loop (held-out base fit, candidate effects,
significance, repeat); ``catalog`` holds the candidate effects; ``localize`` the
residual map and variance shares; ``stats`` the held-out significance test;
``report`` writes the JSON, the plots and the final model document.
See docs/discrepancy.md.
"""
