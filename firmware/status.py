"""Status word bits, shared by the $TC stream (8 hex digits) and Modbus (two registers).

Bits 0..15: sensor i (channel order) is faulty and excluded. The flag bits
above say why the output is what it is. docs/protocol.md lists them.

This module is the reference for the host side and the tests; the firmware
modules that set bits (app.py, safety.py) keep ``_``-prefixed ``const()``
copies, which MicroPython folds into the bytecode, so a board does not load
this module at all (tests/firmware/test_fw_consts.py checks the copies).
"""

from micropython import const

SENSOR_MASK = const(0xFFFF)
CLAMPED = const(0x10000)  # a model input was clamped to the table's envelope
RATE_LIMITED = const(0x20000)  # an output moved at the slew limit this cycle
MAG_LIMITED = const(0x40000)  # an output is held at the maximum magnitude
HELD = const(0x80000)  # a sensor the model needs is faulty: its last good value is used
FALLBACK = const(0x100000)  # hold timed out, no table, or disabled: output ramps to / stays at zero
NO_TABLE = const(0x200000)  # no valid table in either slot
LINK_TIMEOUT = const(0x400000)  # no valid controller traffic within link_timeout_ms
NO_POSITION = const(0x800000)  # no position reported yet: the reference position is used
DISABLED = const(0x1000000)  # output disabled by the controller (Modbus holding register 0)
UPLOADING = const(0x2000000)  # a table upload is open
RECOVERING = const(0x4000000)  # ramping back from fallback to the model's output
REF_PENDING = const(0x8000000)  # a run-start table waits for an all-good cycle to latch its reference temperatures
