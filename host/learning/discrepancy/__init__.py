"""Discrepancy workflow: where a physics model and measurements disagree, and which effect is missing.

``workflow.discover`` runs the loop (held-out base fit, candidate effects,
significance, repeat); ``family`` the candidates as configurations of
host/learning/screw's ScrewModel (its effects.py is the one catalog); ``localize`` the
residual map and variance shares; ``stats`` the held-out significance test;
``report`` writes the JSON, the plots and the final model document.
See docs/discrepancy.md.
"""
