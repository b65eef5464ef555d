"""Learning: models fitted from runs. ``empirical`` (geometric polynomial, MLR/PCR/stepwise/ANN/PPR/dynamic,
sensor selectors), ``screw`` (the segment heat-transfer model and its identification), ``discrepancy`` (where the
screw model and the measurement disagree, and which effect closes the gap), ``documents`` (the model document
``tcomp-model/1``: save, load by kind, predict)."""
