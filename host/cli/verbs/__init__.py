"""The ``tcomp`` verbs: a registry read by host/cli/__init__.py (pip's commands dict).

Each verb maps to the module that implements it and a one-line summary. ``tcomp --help``
reads only this table; a verb's module (``add_arguments(parser)``, ``run(args) -> int``) is
imported when that verb is run, so heavy imports never slow the help text down. A new verb is one
module here plus one row below.
"""

# verb -> (module, one-line summary); listed alphabetically, as `tcomp --help` shows them
VERBS = {
    "board": ("host.cli.verbs.board", "start a simulated board (the firmware on simulated chips) on a pty, driven by a run's temperatures or a steady room, for monitor, record, linuxcnc"),
    "check": ("host.cli.verbs.check", "production check: a check run's errors uncompensated against compensated (the board's logged offsets or the model), pass/fail against a limit"),
    "compare": ("host.cli.verbs.compare", "fit MLR, PCR, stepwise, the sensor selectors, ANN, PPR and the dynamic model on one run, predict the others, with a robustness check"),
    "discrepancy": ("host.cli.verbs.discrepancy", "find where the screw model and the measurements disagree, name the missing physical effect(s), refit (held-out evidence)"),
    "export": ("host.cli.verbs.export", "quantise a model into the firmware's integer coefficient table, with a certificate of integer safety and accuracy"),
    "fit": ("host.cli.verbs.fit", "fit a thermal-error model (mlr, pcr, stepwise, cv-subset, ann, dynamic: host/learning/empirical; screw: host/learning/screw) and save it"),
    "flash": ("host.cli.verbs.flash", "copy the firmware, a board file and a table onto a MicroPython board with mpremote"),
    "hil": ("host.cli.verbs.hil", "run the firmware on the HIL rig, driven by a run folder; query it at every errors.csv row"),
    "import": ("host.cli.verbs.importlog", "turn a logger's CSV export into a run folder, or merge a laser's sweeps into one (--errors --into)"),
    "linuxcnc": ("host.cli.verbs.linuxcnc", "userspace HAL component: apply the board's offset through LinuxCNC external axis offsets"),
    "monitor": ("host.cli.verbs.monitor", "decode the $TC stream of a board (a real port or a pty) into a table, optionally logged as CSV"),
    "predict": ("host.cli.verbs.predict", "predict the error at every row of a run's errors.csv with any saved model"),
    "record": ("host.cli.verbs.record", "record a thermal test: poll the board's temperatures into a run folder, valid at every instant"),
    "report": ("host.cli.verbs.report", "ISO 230-3-style thermal drift report of runs (HTML with plots, JSON figures), before/after compensation with a model"),
    "select": ("host.cli.verbs.select", "choose temperature sensors (maximal-tree fuzzy clustering, stepwise partial F, hierarchical clustering + GA)"),
    "simulate": ("host.cli.verbs.simulate", "simulate thermal tests of a feed axis with the digital twin and write run folders"),
    "upload": ("host.cli.verbs.upload", "send a new coefficient table to a running board over its link, signed with its key; verified by the board's hello"),
    "validate": ("host.cli.verbs.validate", "check run folders against the tcomp-run/1 format and print every problem (exit 1 if any)"),
}
