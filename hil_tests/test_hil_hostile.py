"""Issue 24 §2: the hostile suite. The attacks that found holes 1-7, repeatable, on the running firmware.

Someone on the line (no key) or a key holder's mistake, by class:

- ``unsigned``: commands that change the output without a tag, or with another key's (stream L, X,
  U,B, U,X; Modbus writes of enable, slew, timeout, latch);
- ``expired``: a properly signed command held back for two session periods, then delivered (stream
  L; Modbus auth block + write), and one signed before a reboot (hole 3);
- ``jam``: chunks pushed into the controller's open upload, unsigned, forged or tagged for another
  upload; then the controller's own upload must go through (hole 4);
- ``watchdog``: after the controller falls silent, refused commands, garbage, broadcasts and other
  slaves' traffic keep coming; LINK_TIMEOUT must still be raised (hole 2);
- ``counter``: signed commands whose counter jumps past the window or to MAX (hole 5);
- ``position``: forged position reports farther than the axis can travel (hole 6);
- ``names``: a signed upload of a table whose names are not printable ASCII (hole 1);
- ``garbage``: bytes full of line ends; the error frames they cause must stay within the budget (hole 7).

Each attack is tried, and counted refused (the documented answer, nothing changed) or wrongly
accepted; a crash is a dead firmware process or a board that no longer answers. The counts are
printed per class and interpreter. Reduced in ``make test``; TCOMP_SLOW=1 runs the full form. On
the 32-bit port (the default interpreter) every class; on the emulated board (``qemu``) the
watchdog, expiry and jamming classes, short.
"""
import os
import struct
import zlib

import pytest

from firmware import wire
from hil_tests.rig.boards import export, poly_slope_for_run, rig_config
from host.board.link import body, command_line
from host.board.linkauth import LinkSigner

pytestmark = pytest.mark.rig
SLOW = bool(os.environ.get("TCOMP_SLOW"))
SENSORS = ["T1", "T2", "T4"]
TEMPS = {"T1": 23.0, "T2": 24.0, "T4": 22.0}
ROUNDS = 12 if SLOW else 3  # repetitions of each attack on the 32-bit port
SESSION_S = wire.SESSION_MS // 1000


class Tally:
    def __init__(self, label):
        self.label = label
        self.rows = {}

    def count(self, cls, refused, detail=""):
        r = self.rows.setdefault(cls, [0, 0, 0, 0, []])
        r[0] += 1
        if refused:
            r[1] += 1
        else:
            r[2] += 1
            r[4].append(detail)

    def crash(self, cls, detail):
        r = self.rows.setdefault(cls, [0, 0, 0, 0, []])
        r[3] += 1
        r[4].append(detail)

    def report(self):
        print("\nhostile suite on %s:" % self.label)
        print("  %-10s %6s %8s %17s %8s" % ("class", "tried", "refused", "wrongly accepted", "crashes"))
        for cls, (t, ok, bad, crashes, _) in sorted(self.rows.items()):
            print("  %-10s %6d %8d %17d %8d" % (cls, t, ok, bad, crashes))
        tot = [sum(r[i] for r in self.rows.values()) for i in range(4)]
        print("  %-10s %6d %8d %17d %8d" % ("total", tot[0], tot[1], tot[2], tot[3]))
        wrong = {c: r[4][:3] for c, r in self.rows.items() if r[2] or r[3]}
        assert not wrong, wrong


def _table(demo_run, seed=41):
    return export(poly_slope_for_run(demo_run, SENSORS, seed=seed)).table


def _replies(rig, n0, want=1, max_ms=2000):
    """Non-O frames after index ``n0``, once ``want`` of them came (or ``max_ms`` of device time)."""
    for _ in range(max_ms // 20):
        new = [f for f in rig.frames[n0:] if f.kind != "O"]
        if len(new) >= want:
            rig.advance(30)  # room for a wrong extra frame
            return [f for f in rig.frames[n0:] if f.kind != "O"]
        rig.advance(20)
    return [f for f in rig.frames[n0:] if f.kind != "O"]


def _say(rig, line, want=1, max_ms=2000):
    n0 = len(rig.frames)
    rig.write(line)
    return _replies(rig, n0, want, max_ms)


def _hello(rig):
    h = rig.request("V", kinds=("H",))
    rig.signer.observe_hello(h.fields)
    return h


def _alive(rig, tally, cls):
    try:
        ok = rig.alive and rig.request("V", kinds=("H",), timeout=30.0).kind == "H"
    except Exception as exc:  # the rig's own error: no answer
        ok = False
        tally.crash(cls, repr(exc)[:200])
        return False
    if not ok:
        tally.crash(cls, "the firmware process ended")
    return ok


def _last_status(rig, n0):
    o = [f for f in rig.frames[n0:] if f.kind == "O"]
    return o[-1].status if o else None


# --- stream attacks -------------------------------------------------------------------------------------------

def _but_nonce(h):
    """A hello's fields without the session nonce, which moves on with time."""
    return h.fields[:wire.HELLO_NONCE] + h.fields[wire.HELLO_NONCE + 1:]


def stream_unsigned(rig, tally):
    h0 = _hello(rig)
    other = LinkSigner(bytes(range(32)), rig.signer.counter, rig.signer.nonce)
    for line in (command_line("L"), command_line("X"), command_line("U", "X"), command_line("U", "B", 200, "0000ABCD"),
                 other.stream_line("L"), other.stream_line("X"), other.stream_line("U", "B", 200, "0000ABCD")):
        new = _say(rig, line)
        h = _hello(rig)
        ok = [f.kind for f in new] == ["E"] and new[0].fields[0] == "8" and _but_nonce(h) == _but_nonce(h0)
        tally.count("unsigned", ok, (line, [f.raw for f in new]))


def stream_expired(rig, tally, rounds=1):
    for _ in range(rounds):
        _hello(rig)
        captured = rig.signer.stream_line("L")  # the table has fixed references: authorised -> E,5
        rig.advance(2 * wire.SESSION_MS + 1000)
        new = _say(rig, captured)
        ok = [(f.kind, f.fields[:3]) for f in new] == [("E", ["8", "auth", "bad tag"])]
        tally.count("expired", ok, [f.raw for f in new])
    # the control: a fresh one is authorised (refused for its state, E,5), so the refusals above are the expiry
    _hello(rig)
    new = _say(rig, rig.signer.stream_line("L"))
    assert [f.kind for f in new] == ["E"] and new[0].fields[0] == "5", [f.raw for f in new]


def _open_upload(rig, table):
    """U,B for ``table`` accepted (waiting for the flash budget when it says busy); (its reply, the other lines)."""
    for _ in range(6):
        _hello(rig)
        steps = rig.signer.upload_lines(table)
        begin = _say(rig, steps[0])
        if begin and begin[0].kind == "E" and begin[0].fields[0] == "9":
            rig.advance(61000)  # one flash-write token a minute (docs/protocol.md, "Flash wear")
            continue
        assert begin and begin[0].kind == "A", [f.raw for f in begin]
        return begin, steps[1:]
    raise AssertionError("the flash budget never came back")


def stream_jam(rig, tally, new_table, rounds=1, junk_per_round=6):
    import hashlib
    for r in range(rounds):
        begin, steps = _open_upload(rig, new_table)
        slot = begin[0].fields[2]
        path = os.path.join(rig.flash, "tables", "table_%s.bin" % slot.lower())
        size0 = os.path.getsize(path)
        old = LinkSigner(rig.signer._key).tag(body(("U", "D", 0, "00")), b"", b"\0" * 8).hex().upper()
        for k in range(junk_per_round):
            piece = bytes([k]) * (1 + k % 4)
            line = (command_line("U", "D", 0, piece.hex().upper()) if k % 3 == 0
                    else command_line("U", "D", 0, piece.hex().upper(), ("%02X" % k) * 16) if k % 3 == 1
                    else command_line("U", "D", 0, "00", old))
            new = _say(rig, line)
            ok = [f.kind for f in new] == ["E"] and os.path.getsize(path) == size0
            tally.count("jam", ok, (line, [f.raw for f in new], os.path.getsize(path)))
        # the controller's own upload still goes through: nothing was written by the junk
        for line in steps:
            last = _say(rig, line)
        assert last and last[0].kind == "A" and last[0].fields[:2] == ["U", "C"], [f.raw for f in last]
        assert hashlib.sha256(open(path, "rb").read()).digest() == hashlib.sha256(new_table).digest()


def stream_watchdog(rig, tally, rounds=1):
    # the rig's config: link_timeout_ms 1000
    junk = [command_line("L"), b"\x00\xffjunk\r\n", command_line("Z", 1), command_line("P", 10 ** 12), command_line("S"),
            command_line("V"), command_line("U", "D", 0, "00"), b"$TC,P,5*0000\r\n"]
    for r in range(rounds):
        rig.send("P", 1000 + r)
        rig.advance(300)
        n0 = len(rig.frames)
        for k in range(12):  # 2.4 s of someone else's traffic, the controller silent
            rig.write(junk[(k + r) % len(junk)])
            rig.advance(200)
        st = _last_status(rig, n0)
        tally.count("watchdog", st is not None and bool(st & wire.LINK_TIMEOUT), "status %r" % st)
    rig.send("P", 1000)  # the controller is back
    rig.advance(1200)
    assert not _last_status(rig, len(rig.frames) - 2) & wire.LINK_TIMEOUT


def stream_counter(rig, tally):
    for jump in (wire.COUNTER_WINDOW + 1, 10 ** 6, wire.MAX_COUNTER):
        _hello(rig)
        last = rig.signer.counter
        c = min(last + jump, wire.MAX_COUNTER)
        s = LinkSigner(rig.signer._key, c - 1, rig.signer.nonce)
        new = _say(rig, s.stream_line("L"))
        h = _hello(rig)
        ok = [f.kind for f in new] == ["E"] and new[0].fields[:3] == ["8", "auth", "counter jump"] \
            and int(h.fields[9]) == last
        tally.count("counter", ok, [f.raw for f in new])


def stream_position(rig, tally):
    rig.send("P", 100000)
    rig.advance(1100)
    for far in (-90000000, 90000000, 50000000):
        new = _say(rig, command_line("P", far))
        rig.advance(1100)
        o = [f for f in rig.frames if f.kind == "O"][-1]
        ok = [f.kind for f in new] == ["E"] and new[0].fields[:3] == ["4", "range", "implausible position"] \
            and o.pos_um == 100000
        tally.count("position", ok, ([f.raw for f in new], o.raw))


def stream_names(rig, tally, table):
    from firmware.table import parse_table
    t = parse_table(table)
    for bad in (b"T\xff", b"\xc3(", b"T,1"):
        b = bytearray(table)
        b[64:80] = bad + bytes(16 - len(bad))
        struct.pack_into("<I", b, len(b) - 4, zlib.crc32(bytes(b[:-4])))
        _, steps = _open_upload(rig, bytes(b))
        for line in steps:
            last = _say(rig, line)
        ok = [f.kind for f in last] == ["E"] and last[0].fields[:2] == ["6", "table"] and rig.alive
        tally.count("names", ok, [f.raw for f in last])
    assert t.sensors[0] == SENSORS[0]


def stream_garbage(rig, tally, n_bytes=1000):
    rig.advance(200)
    n0 = len(rig.frames)
    junk = (b"$x\n\xff\r\n" * (n_bytes // 6 + 1))[:n_bytes]
    t0 = rig.t_ms
    for k in range(0, len(junk), 100):  # 100 bytes every 10 ms: about a 115200-baud line's rate
        rig.write(junk[k:k + 100])
        rig.advance(10)
    rig.advance(100)
    e = [f for f in rig.frames[n0:] if f.kind == "E"]
    assert e, "no E frame at all: the garbage did not reach the board"
    e_bytes = sum(len(f.raw) + 2 for f in e)
    elapsed = rig.t_ms - t0
    bound = (wire.E_BURST + elapsed // wire.E_REFILL_MS + 2) * 64
    tally.count("garbage", e_bytes <= bound, "%d bytes of E frames for %d bytes of garbage (bound %d)"
                % (e_bytes, n_bytes, bound))
    print("garbage: %d bytes in, %d bytes of E frames out in %d ms" % (n_bytes, e_bytes, elapsed))


# --- Modbus attacks -----------------------------------------------------------------------------------------------

def _rtu(b):
    from firmware.crc16 import crc16_modbus
    c = crc16_modbus(b)
    return bytes(b) + bytes([c & 0xFF, c >> 8])


def _mb(rig, req, wait_ms=60):
    rig.take_raw()
    rig.write(_rtu(req))
    out = b""
    for _ in range(wait_ms // 10):
        rig.advance(10)
        out += rig.take_raw()
        if len(out) >= 5:
            break
    return out


def _mb_status(rig):
    r = _mb(rig, bytes([1, 4, 0, 0, 0, 2]))
    return struct.unpack(">HH", r[3:7]) if len(r) >= 9 and r[1] == 4 else None


def _mb_observe(rig):
    r = _mb(rig, bytes([1, 4, 0, 48, 0, 5]))
    w = struct.unpack(">5H", r[3:13])
    rig.signer.observe(w[0] << 16 | w[1], w[3] << 16 | w[4])


def modbus_unsigned(rig, tally):
    before = _mb(rig, bytes([1, 3, 0, 0, 0, 3]))[3:9]
    for req in (bytes([1, 6, 0, 0, 0, 0]), bytes([1, 6, 0, 1, 0, 9]), bytes([1, 6, 0, 2, 0, 1]),
                bytes([1, 6, 0, 7, 0, 1]), bytes([0, 6, 0, 0, 0, 0])):
        out = _mb(rig, req)
        ok = (out[1:3] == bytes([0x86, 4]) if req[0] else out == b"") and \
            _mb(rig, bytes([1, 3, 0, 0, 0, 3]))[3:9] == before
        tally.count("unsigned", ok, (req, out))


def modbus_expired(rig, tally, rounds=1):
    for _ in range(rounds):
        _mb_observe(rig)
        req = bytes([1, 6, 0, 0, 0, 0])  # disable the output
        block = bytes([1, 16, 0, 8, 0, 10, 20]) + b"".join(
            v.to_bytes(2, "big") for v in rig.signer.modbus_auth(1, 0, [0]))
        rig.advance(2 * wire.SESSION_MS + 1000)
        _mb(rig, block)
        out = _mb(rig, req)
        enabled = _mb(rig, bytes([1, 3, 0, 0, 0, 1]))[3:5] == bytes([0, 1])
        tally.count("expired", out[1:3] == bytes([0x86, 4]) and enabled, out)


def modbus_watchdog(rig, tally, rounds=1):
    junk = [bytes([0, 4, 0, 0, 0, 2]), bytes([2, 4, 0, 0, 0, 2]), bytes([1, 6, 0, 0, 0, 0]),
            bytes([1, 16, 0, 8, 0, 10, 20]) + bytes(20), bytes([1, 4, 0, 15, 0, 1])]
    for r in range(rounds):
        _mb_status(rig)  # the controller reads, then falls silent
        rig.advance(100)
        for k in range(12):
            rig.write(_rtu(junk[(k + r) % len(junk)]))
            rig.advance(200)
        rig.take_raw()
        # the status is read by the controller coming back: that read itself counts from the next cycle on
        st = _mb_status(rig)
        tally.count("watchdog", st is not None and bool((st[1] << 16) & wire.LINK_TIMEOUT), "status %r" % (st,))


def modbus_counter(rig, tally):
    _mb_observe(rig)
    last = rig.signer.counter
    for jump in (wire.COUNTER_WINDOW + 1, wire.MAX_COUNTER - last):
        s = LinkSigner(rig.signer._key, last + jump - 1, rig.signer.nonce)
        block = bytes([1, 16, 0, 8, 0, 10, 20]) + b"".join(v.to_bytes(2, "big") for v in s.modbus_auth(1, 1, [7]))
        _mb(rig, block)
        out = _mb(rig, bytes([1, 6, 0, 1, 0, 7]))
        why = _mb(rig, bytes([1, 4, 0, 50, 0, 1]))[3:5]
        tally.count("counter", out[1:3] == bytes([0x86, 4]) and why == bytes([0, 7]), (out, why))


def modbus_position(rig, tally):
    def write(p):
        p &= 0xFFFFFFFF
        return _mb(rig, bytes([1, 16, 0, 3, 0, 2, 4]) + struct.pack(">HH", p >> 16, p & 0xFFFF))
    assert write(100000)[1] == 16
    for far in (-90000000, 90000000):
        out = write(far)
        r = _mb(rig, bytes([1, 4, 0, 6, 0, 2]))
        rig.advance(200)
        r = _mb(rig, bytes([1, 4, 0, 6, 0, 2]))
        pos = struct.unpack(">i", r[3:7])[0] if len(r) >= 9 else None
        tally.count("position", out[1:3] == bytes([0x90, 3]) and pos == 100000, (out, pos))


# --- the suites -----------------------------------------------------------------------------------------------------

def _stream_rig(make_rig, demo_run, table):
    rig = make_rig(rig_config(SENSORS, link_timeout_ms=1000, max_speed_mm_min=60000), table, temps=TEMPS)
    rig.advance(1500)
    return rig


def _modbus_rig(make_rig, table):
    rig = make_rig(rig_config(SENSORS, mode="modbus", link_timeout_ms=1000, max_speed_mm_min=60000), table,
                   temps=TEMPS)
    rig.advance(1500)
    return rig


@pytest.mark.parametrize("interpreter", ["micropython"])
def test_hostile_suite_on_the_32bit_port(make_rig, demo_run, interpreter):
    table, other = _table(demo_run, 41), _table(demo_run, 42)
    tally = Tally("the 32-bit port (%s)" % interpreter)
    rig = _stream_rig(make_rig, demo_run, table)
    for _ in range(ROUNDS):
        stream_unsigned(rig, tally)
        stream_position(rig, tally)
        stream_garbage(rig, tally)
    stream_expired(rig, tally, ROUNDS)
    stream_jam(rig, tally, other, ROUNDS)
    stream_watchdog(rig, tally, ROUNDS)
    stream_counter(rig, tally)
    stream_names(rig, tally, table)
    _alive(rig, tally, "stream")
    mb = _modbus_rig(make_rig, table)
    for _ in range(ROUNDS):
        modbus_unsigned(mb, tally)
        modbus_position(mb, tally)
    modbus_expired(mb, tally, ROUNDS)
    modbus_watchdog(mb, tally, ROUNDS)
    modbus_counter(mb, tally)
    if not mb.alive:
        tally.crash("modbus", "the firmware process ended")
    tally.report()


@pytest.mark.parametrize("interpreter", ["qemu"])
def test_hostile_watchdog_expiry_and_jamming_on_the_emulated_board(make_rig, demo_run, interpreter):
    """The classes that depend on the board's time and flash, on the frozen image on the emulated Cortex-M3."""
    table, other = _table(demo_run, 41), _table(demo_run, 42)
    tally = Tally("the emulated board (qemu)")
    rig = _stream_rig(make_rig, demo_run, table)
    stream_watchdog(rig, tally)
    stream_expired(rig, tally)
    stream_jam(rig, tally, other, 1, junk_per_round=3)
    _alive(rig, tally, "stream")
    mb = _modbus_rig(make_rig, table)
    modbus_watchdog(mb, tally)
    modbus_expired(mb, tally)
    if not mb.alive:
        tally.crash("modbus", "the firmware process ended")
    tally.report()
