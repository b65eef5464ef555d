"""CPython stand-in for MicroPython's ``micropython`` module, in Adafruit Blinka's manner: only ``const``.

Every firmware module says ``from micropython import const``. On MicroPython the built-in module answers
and the compiler folds each ``_NAME = const(value)`` into the bytecode; this file never goes on a board
(firmware/manifest.py NOT_ON_BOARD). On CPython, firmware/__init__.py registers this module under the
name ``micropython`` (``install``) the first time anything imports the firmware package, so no top-level
``micropython`` module is installed to shadow a real one (docs/architecture.md, "const"). Firmware code
that must know where it runs asks ``sys.implementation.name``, not whether ``micropython`` imports.
"""
import importlib.util
import sys


def const(value):
    """The value itself: CPython has no constant folding to ask for."""
    return value


def install():
    """Make ``micropython`` importable as this stand-in, unless a ``micropython`` module is already loaded
    or importable from the path (a real one wins; it has ``const`` too)."""
    if "micropython" in sys.modules or importlib.util.find_spec("micropython") is not None:
        return
    sys.modules["micropython"] = sys.modules[__name__]
