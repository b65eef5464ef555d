"""The wire contract, one source: status bits, frame kinds, command letters, reference-state
letters, protocol and firmware versions, the authorised commands' counter and tag sizes
(docs/protocol.md).

The host decodes with this module (host/board/link.py, `tcomp monitor`). The firmware modules that use a
value in the cycle keep a ``_``-prefixed ``const()`` copy, which MicroPython folds into the bytecode,
so a board loads this module only to answer ``V`` and ``L`` (tests/firmware/test_fw_consts.py checks
every copy against this file).

Status word, shared by the $TC stream (8 hex digits) and Modbus (two registers): bits 0..15:
sensor i (channel order) is faulty and excluded; the flag bits above say why the output is what it is.
Every single-bit constant above SENSOR_MASK here is a status flag (host/board/link.py lists them by that).
"""

from micropython import const

SENSOR_MASK = const(0xFFFF)
CLAMPED = const(0x10000)  # a model input was clamped to the table's certified envelope (beyond the machine's operating range)
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
EXTRAPOLATING = const(0x10000000)  # a temperature is outside the model's training range (inside the certified envelope it is evaluated, not clamped): informational, not a fault

PROTOCOL_VERSION = const(1)  # first field of the hello frame; `tcomp monitor` refuses any other
FIRMWARE_VERSION = "0.1.0"  # second field of the hello frame
# reference temperatures come from: - none, S stored, L latched now, U latched unsaved, N/C/O pending
# because the stored ones were missing/corrupt/foreign (firmware.app ref_state indexes this)
REF_LETTERS = b"-SLUNCO"
# hello fields (after the frame kind): the counter's index, then the error reference appended after it (issue 19):
# "start" (the table's model was fitted on raw errors: offsets relative to the machine at its cold start), or the
# sensor the errors were corrected to (offsets for a workpiece at its temperature), "-" without a table
HELLO_COUNTER = const(9)
HELLO_ERROR_REFERENCE = const(10)
ERROR_REFERENCE_START = "start"
FRAME_KINDS = "HOQTAE"  # hello, offsets, query answer, temperatures, acknowledgement, error
COMMANDS = "PMQRSVULX"  # position, motion, query, reference, temperatures, hello, upload, latch, reset
UPLOAD_STEPS = "BDCX"  # U,<step>: begin, data, commit, abort
# Commands that change the output (U,B U,C U,X L X) end with <counter>,<tag> (docs/protocol.md,
# "Who may change the output"; firmware/auth.py checks, host/board/linkauth.py signs)
SIGNED_COMMANDS = "XL"  # besides the upload's begin, commit and abort
TAG_BYTES = const(16)  # the tag: HMAC-SHA256's first TAG_BYTES bytes, sent as 2 * TAG_BYTES hex digits
MAX_COUNTER = const(999999999)  # largest counter: a small int on a 32-bit port even after auth's reserve block
