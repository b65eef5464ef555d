"""tcomp host side: run-folder I/O, digital twin, model fitting, sensor selection.

Everything here runs on a PC (CPython + numpy/scipy). What runs beside the axis
lives in ``firmware/``; what turns a fitted model into an integer table lives in
``models_export/``.
"""
__version__ = "0.1.0"
