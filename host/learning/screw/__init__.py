"""Ball-screw segment heat-transfer model: physics core (heat), identified model
(model, identify), reduced firmware recurrence (reduced), CLI glue (cli).
See docs/screw-model.md."""
