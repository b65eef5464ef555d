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
SETTLING = const(0x20000000)  # a dynamic table's lag states, or a screw table's segment states (format 6), were estimated from the sensors (observer, issue 21) less than its settle_s ago, or not yet: informational, the estimate's start error may still exceed its tolerance

# first field of the hello frame; `tcomp monitor` refuses any other. 2: authorised commands are bound to the
# board's session nonce (the hello's last field), U,D chunks carry a tag bound to their U,B (issue 24)
PROTOCOL_VERSION = const(2)
FIRMWARE_VERSION = "0.1.0"  # second field of the hello frame
# reference temperatures come from: - none, S stored, L latched now, U latched unsaved, N/C/O pending
# because the stored ones were missing/corrupt/foreign (firmware.app ref_state indexes this)
REF_LETTERS = b"-SLUNCO"
# hello fields (after the frame kind): the authorisation counter, the session nonce (issue 24), then the error
# reference (issue 19): "start" (the table's model was fitted on raw errors: offsets relative to the machine at its
# cold start), or the sensor the errors were corrected to (offsets for a workpiece at its temperature), "-" without
# a table
HELLO_COUNTER = const(9)
HELLO_NONCE = const(10)
HELLO_ERROR_REFERENCE = const(11)
ERROR_REFERENCE_START = "start"
FRAME_KINDS = "HOQTAE"  # hello, offsets, query answer, temperatures, acknowledgement, error
COMMANDS = "PMQRSVULXY"  # position, motion, query, reference, temperatures, hello, upload, latch, reset, supplied lag states
UPLOAD_STEPS = "BDCX"  # U,<step>: begin, data, commit, abort
# Commands that change the output (U,B U,C U,X L X) end with <counter>,<tag> (docs/protocol.md,
# "Who may change the output"; firmware/auth.py checks, host/board/linkauth.py signs)
SIGNED_COMMANDS = "XL"  # besides the upload's begin, commit and abort
TAG_BYTES = const(16)  # the tag: HMAC-SHA256's first TAG_BYTES bytes, sent as 2 * TAG_BYTES hex digits
MAX_COUNTER = const(999999999)  # largest counter: a small int on a 32-bit port even after auth's reserve block
# a counter may exceed the last one used by at most this much: no single command can spend the key's counters
# (docs/protocol.md, "Counters"); a key whose counter reached MAX_COUNTER is re-provisioned (tcomp flash --key)
COUNTER_WINDOW = const(1000)
# the session nonce (hello's last field, Modbus input registers 51-52) changes every SESSION_MS of uptime and at
# every boot; a command signed with the current or the previous nonce is accepted: it expires 1-2 SESSION_MS
# after the controller read the nonce
SESSION_MS = const(60000)
# error frames: at most E_BURST in a row, then one more per E_REFILL_MS (garbage cannot crowd out the offsets)
E_BURST = const(8)
E_REFILL_MS = const(25)
# refusal reasons of authorised commands: E,8,auth,<AUTH_REASONS[r]> (BUSY is E,9,busy), Modbus input register 50
AUTH_REASONS = ("", "no key", "bad tag", "replayed counter", "counter not stored", "busy", "unsigned",
                "counter jump", "counter exhausted")

# Lag states the controller supplies (issue 21, table format 7; docs/protocol.md "Supplied lag states"): a dynamic
# table's lag of the spindle speed, its square or the feed whose state the controller computes from its own record
# (host/board/supplied.py) and sends at the table's start. Per state the board's dictionary gives its source
# (-1 spindle rpm, -2 rpm squared, -3 feed mm/min), its time constant in ms and its scale: the value sent is
# round(lag in those input units x 2**scale), the board's state units.
MAX_SUPPLIED = const(4)  # supplied states per table (the exporter refuses more)
SUPPLY_DICT_REGS = const(4)
SUPPLY_NONE = const(0)  # no table, or none of its states is supplied
SUPPLY_AWAITED = const(1)  # the table's start waits for the controller's states (SETTLING is raised)
SUPPLY_SET = const(2)  # the states were set at this table's start; a later `Y` is acknowledged but not applied
SUPPLY_LETTERS = "-AS"  # the A,Y answer's state field, indexed by the codes above

# Error frames E,<code>,<word>[,<detail>] (docs/protocol.md, "Error codes")
E_CRC = const(1)  # crc: the line's CRC-16 does not match
E_SYNTAX = const(2)  # syntax: not $TC,...*XXXX, wrong field count, bad characters
E_UNKNOWN = const(3)  # unknown: command letter or upload step
E_RANGE = const(4)  # range: a number malformed or out of range
E_STATE = const(5)  # state: not possible now (no upload open, no table; for L: fixed references, sensor faulty)
E_TABLE = const(6)  # table: a table refused (firmware/table.py reason)
E_OVERFLOW = const(7)  # overflow: the line is longer than the receive buffer
E_AUTH = const(8)  # auth: a command that changes the output is not authorised (firmware/auth.py)
E_BUSY = const(9)  # busy: the flash-write budget is used up; retry later

# Modbus RTU register map (docs/protocol.md, firmware/modbus.py). Input registers:
IR_STATUS_LO = const(0)  # the status word's low and high halves
IR_STATUS_HI = const(1)
IR_SEQUENCE = const(2)
IR_TOTAL = const(3)  # 0.1 um, int16, at the reported position
IR_REF_OFFSET = const(4)  # 0.1 um, int16, at the reference position
IR_SLOPE = const(5)  # 0.01 um/m, int16
IR_POSITION = const(6)  # int32 um, high word first
IR_REFERENCE = const(8)  # int32 um
IR_TABLE_CRC = const(10)  # uint32
IR_SLOT = const(12)  # 0 none, 1 A, 2 B
IR_CHANNELS = const(13)
IR_REF_STATE = const(14)  # index into REF_LETTERS: where the reference temperatures come from
IR_UNMAPPED = const(15)  # the one hole in the map: exception 02
IR_TEMPS = const(16)  # 16 x int16 0.01 degC, NO_VALUE when faulty
IR_FAULTS = const(32)  # 16 x channel fault bits (firmware.channels F_*)
IR_AUTH_COUNTER = const(48)  # uint32: the last counter used (firmware.auth)
IR_AUTH_WHY = const(50)  # the last refusal (firmware.auth reason code)
IR_NONCE = const(51)  # the session nonce (firmware.auth), high word first: every auth block's tag starts with it
IR_ERROR_REF = const(53)  # the table's error reference (header byte 58): 0 start (or no table), 1 + i sensor i
# the lag states the controller supplies (table format 7, `Y` on the stream; docs/protocol.md "Supplied lag states"):
IR_SUPPLY_STATE = const(54)  # SUPPLY_NONE / SUPPLY_AWAITED / SUPPLY_SET
IR_SUPPLY_COUNT = const(55)  # k, the supplied states of the table (0..MAX_SUPPLIED)
IR_SUPPLY_DICT = const(56)  # per supplied state SUPPLY_DICT_REGS registers: source (int16), tau_ms (uint32, high word first), scale (int16)
N_INPUT = const(72)
# holding registers
HR_ENABLE = const(0)  # 0/1
HR_SLEW = const(1)  # um/s, 1..10000
HR_LINK_TIMEOUT = const(2)  # ms, 0 = off
HR_POSITION = const(3)  # int32 um, high word first: writing it is a position report
HR_REFERENCE = const(5)  # int32 um
HR_LATCH = const(7)  # write 1: latch the reference temperatures now (reads 0)
N_VALUES = const(8)  # registers 0..7 hold values; the auth block reads 0
HR_AUTH = const(8)  # N_AUTH registers: counter (uint32), tag (TAG_BYTES bytes); written whole with FC16
N_AUTH = const(10)
HR_SPINDLE = const(18)  # int32 rpm, high word first, written whole with FC16: a spindle speed report
HR_SUPPLY = const(20)  # MAX_SUPPLIED x int32 (high word first): the supplied lag states, the table's k written whole with one FC16 (reads 0)
N_HOLDING = const(28)
PROTECTED = const(0x87)  # bit r: holding register r needs authorisation (0 enable, 1 slew, 2 timeout, 7 latch)
NO_VALUE = const(-32768)  # an int16 register with no value (a faulty channel's temperature)
# Modbus exception codes the board answers with
EX_ILLEGAL_FUNCTION = const(1)
EX_ILLEGAL_ADDRESS = const(2)
EX_ILLEGAL_VALUE = const(3)
EX_DEVICE_FAILURE = const(4)  # also: a protected write refused by the authorisation (the reason in IR_AUTH_WHY)
