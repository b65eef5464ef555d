"""One module per ``tcomp`` verb.

Each module defines ``HELP`` (one line), ``add_arguments(parser)`` and
``run(args) -> int``. Keep module-level imports light: ``tcomp --help`` imports
every module here, so heavy imports (scipy, matplotlib) go inside ``run``.
"""
