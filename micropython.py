"""CPython stand-in for MicroPython's ``micropython`` module, in Adafruit Blinka's manner.

Only ``const``. On MicroPython this file is never imported (the built-in module comes first) and the
compiler folds each ``_NAME = const(value)`` into the bytecode; on CPython ``const`` returns its
argument, so every firmware module imports it with the one line ``from micropython import const``.
Firmware code that must know where it runs asks ``sys.implementation.name``, not whether this
module imports.
"""


def const(value):
    return value
