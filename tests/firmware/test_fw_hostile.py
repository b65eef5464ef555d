"""Issue 24 §2, holes 1-7: one property test per hole, on the firmware over the register-level fakes.

Each draws what someone on the line (or a key holder's mistake) can send and checks the
firmware's answer against a rule written here from docs/protocol.md, not from the firmware's code:

1. a table with any bytes in its names is refused with TableError or carries printable names;
   no other exception (a signed upload of a non-UTF-8 name killed the firmware);
2. only the controller's valid P/Q (Modbus: a request to this slave answered normally) feeds the
   link watchdog: garbage, refused commands, broadcasts and other slaves' traffic do not;
3. a signed command held back is refused once the session nonce it was signed for has moved on
   twice (>= 2 SESSION_MS), and after a reboot; accepted within one SESSION_MS;
4. chunks that are not tagged for the open upload are refused before anything is written;
5. a counter more than COUNTER_WINDOW past the last one is refused; the hello never reports one
   above MAX_COUNTER;
6. a position report farther from the last accepted one than max_speed_mm_min allows in the time
   between (plus 200 ms) is refused, on the stream and on Modbus;
7. garbage cannot make the board send more than E_BURST error frames plus one per E_REFILL_MS, and
   the periodic offsets keep coming.
"""
import os
import struct
import tempfile
import zlib

from hypothesis import HealthCheck, given, settings, strategies as st

from fwhelpers import TEST_KEY, cmd, frames, make_table, modbus_auth_block, provision, rig_app, run_cycles, scmd, \
    tagged_chunk
from firmware import wire
from firmware.crc16 import crc16_modbus

N = 200 if os.environ.get("TCOMP_SLOW") else 40
SETTINGS = settings(max_examples=N, deadline=None, suppress_health_check=list(HealthCheck), derandomize=True)
SENSORS = ["T1", "T2", "T3"]


def small(serial_mode="stream", extra=None, key=TEST_KEY, table_kw=None, d=None):
    """A three-channel board (two MAX31865, one ADS122C04) with a poly_slope table, booted and run 1 s."""
    from pathlib import Path
    d = Path(d or tempfile.mkdtemp(prefix="tcomp-hostile-"))
    app, board = rig_app(d, n_max=2, n_ads=1, serial_mode=serial_mode, extra=extra, key=key, table_kw=table_kw)
    run_cycles(app, board, 10)
    board.serial.take()
    return app, board, d


def send(app, board, line):
    """The frames that answer ``line`` (periodic offset frames left out)."""
    board.serial.take()
    board.serial.feed(line)
    app.link.poll(board.clock.t)
    return [f for f in frames(board.serial.take()) if f[3] != "O"]


def rtu(body):
    c = crc16_modbus(body)
    return body + bytes([c & 0xFF, c >> 8])


def ask(app, board, req):
    board.serial.feed(req)
    app.link.poll(board.clock.t)
    board.clock.t += 5
    app.link.poll(board.clock.t)
    return board.serial.take()


# --- 1. table fields ------------------------------------------------------------------------------

def _with_name(data, off, size, name):
    b = bytearray(data)
    b[off:off + size] = name[:size] + bytes(size - len(name[:size]))
    struct.pack_into("<I", b, len(b) - 4, zlib.crc32(bytes(b[:-4])))
    return bytes(b)


@SETTINGS
@given(name=st.binary(min_size=1, max_size=16), where=st.integers(-1, 2))
def test_hole1_any_name_bytes_are_refused_or_printable(name, where):
    from firmware.table import TableError, parse_table
    data = make_table(kind="poly_slope", sensors=SENSORS)
    off, size = (44, 8) if where < 0 else (64 + 16 * where, 16)
    try:
        t = parse_table(_with_name(data, off, size, name))
    except TableError as e:
        assert e.reason in ("invalid field",), e
        return
    for n in [t.axis] + t.sensors:
        assert n and all(32 <= ord(c) <= 126 and c not in ",*$" for c in n), n


@SETTINGS
@given(st.lists(st.tuples(st.booleans(), st.integers(0, 10000), st.integers(0, 255)), min_size=1, max_size=6))
def test_hole1_any_field_bytes_refused_or_run(edits):
    """Any bytes anywhere in a table whose CRC is right (names or the rest): refused with TableError,
    or it loads and runs."""
    from firmware.table import TableError, parse_table
    data = bytearray(make_table(kind="poly_slope", sensors=SENSORS))
    for in_names, pos, v in edits:
        data[(44 + pos % (20 + 16 * len(SENSORS))) if in_names else 4 + pos % (len(data) - 8)] = v
    struct.pack_into("<I", data, len(data) - 4, zlib.crc32(bytes(data[:-4])))
    try:
        parse_table(bytes(data))
    except TableError:
        return
    d = tempfile.mkdtemp(prefix="tcomp-hostile-")
    with open(os.path.join(d, "table_a.bin"), "wb") as f:
        f.write(data)
    from pathlib import Path
    app, board = rig_app(Path(d), n_max=2, n_ads=1, table=False)
    run_cycles(app, board, 5)
    out = send(app, board, cmd(b"TC,Q,1000"))
    assert out and out[-1][3] == "Q", out


def test_hole1_signed_upload_of_a_non_utf8_name_is_refused_not_a_crash():
    app, board, _ = small()
    good = make_table(kind="poly_slope", sensors=SENSORS)
    bad = _with_name(good, 64, 16, b"T\xff\xfe")
    assert send(app, board, scmd(app, "U", "B", len(bad), "%08X" % zlib.crc32(bad)))[0][3:5] == ["A", "U"]
    for off in range(0, len(bad), 48):
        assert send(app, board, tagged_chunk(app, off, bad[off:off + 48]))[0][3] == "A"
    import hashlib
    out = send(app, board, scmd(app, "U", "C", extra=hashlib.sha256(bad).digest()))
    assert out[0][3:6] == ["E", "6", "table"] and "invalid field" in out[0][6], out
    assert app.slot == 0  # the old table stays


# --- 2. link watchdog -------------------------------------------------------------------------------

def _wrong_key_L(app):
    from host.board.linkauth import LinkSigner
    return LinkSigner(bytes(32), app.auth.last, app.auth.nonce()).stream_line("L")


STREAM_JUNK = {
    "unsigned L": lambda app: cmd(b"TC,L"),
    "wrong key L": _wrong_key_L,
    "garbage": lambda app: b"\x00\xffhello\r\n",
    "bad crc P": lambda app: b"$TC,P,5*0000\r\n",
    "unknown": lambda app: cmd(b"TC,Z,1"),
    "P out of range": lambda app: cmd(b"TC,P,999999999999"),
    "S": lambda app: cmd(b"TC,S"),
    "V": lambda app: cmd(b"TC,V"),
    "unsigned chunk": lambda app: cmd(b"TC,U,D,0,00"),
}


@SETTINGS
@given(st.lists(st.sampled_from(sorted(STREAM_JUNK)), min_size=1, max_size=40), st.booleans())
def test_hole2_stream_watchdog_fed_only_by_valid_P_or_Q(junk, query):
    app, board, _ = small(extra={"link_timeout_ms": 1000})
    send(app, board, cmd(b"TC,Q,100") if query else cmd(b"TC,P,100"))
    run_cycles(app, board, 1)
    assert not app.status & wire.LINK_TIMEOUT
    # the controller falls silent; someone else keeps talking, every 100 ms, for 2.5 s
    for i in range(25):
        send(app, board, STREAM_JUNK[junk[i % len(junk)]](app))
        run_cycles(app, board, 1)
    assert app.status & wire.LINK_TIMEOUT, junk
    send(app, board, cmd(b"TC,P,200"))  # the controller is back: cleared at the next cycle
    run_cycles(app, board, 1)
    assert not app.status & wire.LINK_TIMEOUT


def _mb_junk(app):
    addr_other = 2
    return {
        "broadcast read": rtu(bytes([0, 4, 0, 0, 0, 2])),
        "other slave read": rtu(bytes([addr_other, 4, 0, 0, 0, 2])),
        "other slave position": rtu(bytes([addr_other, 16, 0, 3, 0, 2, 4, 0, 0, 0, 100])),
        "unsigned enable": rtu(bytes([1, 6, 0, 0, 0, 0])),
        "unmapped read": rtu(bytes([1, 4, 0, 15, 0, 1])),
        "bad crc read": bytes([1, 4, 0, 0, 0, 2, 0, 0]),
        "auth block": rtu(bytes([1, 16, 0, 8, 0, 10, 20]) + bytes(20)),
        "bad function": rtu(bytes([1, 7, 0, 0])),
    }


@SETTINGS
@given(st.lists(st.integers(0, 7), min_size=1, max_size=40))
def test_hole2_modbus_watchdog_fed_only_by_requests_it_answers(junk):
    app, board, _ = small(serial_mode="modbus", extra={"link_timeout_ms": 1000, "frame_ms": 0})
    kinds = sorted(_mb_junk(app))
    assert ask(app, board, rtu(bytes([1, 4, 0, 0, 0, 2])))[1] == 4  # the controller reads
    run_cycles(app, board, 1)
    assert not app.status & wire.LINK_TIMEOUT
    for i in range(25):
        ask(app, board, _mb_junk(app)[kinds[junk[i % len(junk)]]])
        run_cycles(app, board, 1)
    assert app.status & wire.LINK_TIMEOUT, [kinds[j] for j in junk]
    assert ask(app, board, rtu(bytes([1, 3, 0, 0, 0, 1])))[1] == 3
    run_cycles(app, board, 1)
    assert not app.status & wire.LINK_TIMEOUT


# --- 3. signed commands expire ------------------------------------------------------------------------

@SETTINGS
@given(phase_s=st.integers(0, 59), delay_s=st.integers(0, 200))
def test_hole3_held_back_L_expires(phase_s, delay_s):
    app, board, _ = small()
    run_cycles(app, board, phase_s, dt=1000)
    captured = scmd(app, "L")  # signed by the controller, held back by someone on the line
    run_cycles(app, board, delay_s, dt=1000)
    out = send(app, board, captured)
    # fixed references: an authorised L is refused for its state (E,5); an expired one for its tag (E,8)
    if delay_s < wire.SESSION_MS // 1000:
        assert out[0][3:5] == ["E", "5"], out
    elif delay_s >= 2 * wire.SESSION_MS // 1000:
        assert out[0][3:7] == ["E", "8", "auth", "bad tag"], out


@SETTINGS
@given(delay_s=st.integers(0, 200), value=st.integers(0, 1))
def test_hole3_held_back_modbus_write_expires(delay_s, value):
    app, board, _ = small(serial_mode="modbus", extra={"frame_ms": 0})
    req = bytes([1, 6, 0, 0, 0, value])  # enable / disable the output
    block = rtu(modbus_auth_block(app, req))
    run_cycles(app, board, delay_s, dt=1000)
    assert ask(app, board, block)[1] == 16
    out = ask(app, board, rtu(req))
    if delay_s < wire.SESSION_MS // 1000:
        assert out[1] == 6, out
    elif delay_s >= 2 * wire.SESSION_MS // 1000:
        assert out[1:3] == bytes([0x86, 4]) and app.auth.why == 2, out  # bad tag


def test_hole3_a_command_signed_before_a_reboot_is_refused_after_it(tmp_path):
    from fwfakes import make_rig
    from firmware.app import App
    (tmp_path / "table_a.bin").write_bytes(make_table(kind="poly_slope", sensors=SENSORS))
    provision(tmp_path)
    boots = iter([b"\x01\x02\x03\x04", b"\x0a\x0b\x0c\x0d"])
    for _ in range(2):
        board = make_rig(2, 1, table_dir=str(tmp_path), serial_size=1 << 20)
        board.entropy = lambda: next(boots)
        app = App(board)
        run_cycles(app, board, 3)
        board.serial.take()
        if _ == 0:
            captured = scmd(app, "L")
    out = send(app, board, captured)
    assert out[0][3:7] == ["E", "8", "auth", "bad tag"], out
    assert send(app, board, scmd(app, "L"))[0][3:5] == ["E", "5"]  # the controller's fresh one is authorised


# --- 4. upload jamming ---------------------------------------------------------------------------------

@SETTINGS
@given(st.lists(st.sampled_from(["unsigned", "forged tag", "other upload", "short tag"]), min_size=1, max_size=30))
def test_hole4_jamming_chunks_refused_before_any_flash_write(jam):
    import hashlib
    app, board, d = small()
    data = make_table(kind="linear_direct", sensors=SENSORS, S0=77)
    old_id = b"\x00" * 8
    assert send(app, board, scmd(app, "U", "B", len(data), "%08X" % zlib.crc32(data)))[0][3:5] == ["A", "U"]
    f = app.store._up[0]
    writes = []
    real = f.write
    f.write = lambda b: writes.append(len(b)) or real(b)
    for k, how in enumerate(jam):
        piece = bytes([k & 0xFF]) * (1 + k % 5)
        if how == "unsigned":
            line = cmd(b"TC,U,D,0,%s" % piece.hex().upper().encode())
        elif how == "forged tag":
            line = cmd(b"TC,U,D,0,%s,%s" % (piece.hex().upper().encode(), (b"%02X" % k) * 16))
        elif how == "other upload":  # a chunk properly tagged for another upload (an old capture)
            from host.board.link import body, command_line
            from host.board.linkauth import LinkSigner
            fs = ("U", "D", 0, piece.hex().upper())
            line = command_line(*(fs + (LinkSigner(TEST_KEY).tag(body(fs), b"", old_id).hex().upper(),)))
        else:
            line = cmd(b"TC,U,D,0,%s,ABCD" % piece.hex().upper().encode())
        out = send(app, board, line)
        assert all(o[3] == "E" for o in out), out
        run_cycles(app, board, 1)  # time for the next error frame
    assert writes == [] and os.path.getsize(os.path.join(str(d), "table_b.bin")) == 0
    for off in range(0, len(data), 48):  # the controller's own upload goes through
        assert send(app, board, tagged_chunk(app, off, data[off:off + 48]))[0][3:5] == ["A", "U"]
    out = send(app, board, scmd(app, "U", "C", extra=hashlib.sha256(data).digest()))
    assert out[0][3:7] == ["A", "U", "C", "B"], out
    assert sum(writes) == len(data)


# --- 5. counters -----------------------------------------------------------------------------------------

@SETTINGS
@given(first=st.integers(1, wire.COUNTER_WINDOW), jump=st.integers(1, wire.MAX_COUNTER))
def test_hole5_counter_jumps_beyond_the_window_are_refused(first, jump):
    app, board, _ = small()
    assert send(app, board, scmd(app, "L", counter=first))[0][3:5] == ["E", "5"]  # authorised (fixed refs)
    c = first + jump
    if c > wire.MAX_COUNTER:
        return  # not a valid counter field at all (E,4, the existing range check)
    out = send(app, board, scmd(app, "L", counter=c))
    if jump <= wire.COUNTER_WINDOW:
        assert out[0][3:5] == ["E", "5"], out
        assert app.auth.last == c
    else:
        assert out[0][3:7] == ["E", "8", "auth", "counter jump"], out
        assert app.auth.last == first


@SETTINGS
@given(mark=st.integers(wire.MAX_COUNTER - 70, 0xFFFFFFFF))
def test_hole5_hello_never_reports_a_counter_above_max(mark):
    from firmware.crc16 import crc16_ccitt
    d = tempfile.mkdtemp(prefix="tcomp-hostile-")
    b = b"TA\x01" + struct.pack("<I", mark)
    with open(os.path.join(d, "auth.bin"), "wb") as f:  # what an older firmware left after counter 999,999,999
        f.write(b + struct.pack("<H", crc16_ccitt(b)))
    from pathlib import Path
    app, board = rig_app(Path(d), n_max=2, n_ads=1)
    hello = frames(board.serial.take())[0]
    assert int(hello[4 + wire.HELLO_COUNTER]) <= wire.MAX_COUNTER  # frames() keeps TC, seq, status, kind first
    from host.board.linkauth import LinkSigner
    s = LinkSigner(TEST_KEY)
    s.observe_hello(hello[4:])  # the host takes it (no traceback in tcomp monitor --latch)
    if s.counter >= wire.MAX_COUNTER:
        out = send(app, board, LinkSigner(TEST_KEY, wire.MAX_COUNTER - 1, app.auth.nonce()).stream_line("L"))
        assert out[0][3:7] == ["E", "8", "auth", "counter exhausted"] or out[0][3:7] == ["E", "8", "auth",
                                                                                          "replayed counter"], out


@given(st.one_of(st.text(max_size=12), st.integers(wire.MAX_COUNTER + 1, 1 << 40).map(str)))
def test_hole5_host_refuses_a_bad_hello_counter_with_a_clear_error(counter):
    import pytest
    from host.board.linkauth import CounterError, LinkSigner
    s = LinkSigner(TEST_KEY)
    if counter == "-" or (counter.isascii() and counter.isdigit() and int(counter) <= wire.MAX_COUNTER):
        s.observe(counter)
        return
    with pytest.raises(CounterError, match="counter"):
        s.observe(counter)


# --- 6. positions ----------------------------------------------------------------------------------------------

V_MM_MIN = 30000


def plausible(d_um, dt_ms, v=V_MM_MIN):
    # docs/protocol.md: |dP| <= v * (dt + 200 ms); v mm/min is v/60 um/ms
    return abs(d_um) * 60 <= v * (dt_ms + 200)


@SETTINGS
@given(st.lists(st.tuples(st.integers(0, 3000), st.integers(-3000000, 3000000)), min_size=1, max_size=12))
def test_hole6_stream_positions_checked_against_the_last_and_the_speed(reports):
    app, board, _ = small(extra={"max_speed_mm_min": V_MM_MIN, "frame_ms": 0})
    last_pos, last_t = 0, board.clock.t
    assert send(app, board, cmd(b"TC,P,0")) == []
    for dt, pos in reports:
        board.clock.t += dt
        out = send(app, board, cmd(b"TC,P,%d" % pos))
        if plausible(pos - last_pos, board.clock.t - last_t):
            assert out == [] and app.pos == pos, (out, pos, last_pos)
            last_pos, last_t = pos, board.clock.t
        else:
            assert out[0][3:7] == ["E", "4", "range", "implausible position"] and app.pos == last_pos, out


@SETTINGS
@given(st.lists(st.tuples(st.integers(0, 3000), st.integers(-3000000, 3000000)), min_size=1, max_size=12))
def test_hole6_modbus_positions_checked_against_the_last_and_the_speed(reports):
    app, board, _ = small(serial_mode="modbus", extra={"max_speed_mm_min": V_MM_MIN, "frame_ms": 0})

    def write(pos):
        p = pos & 0xFFFFFFFF
        return ask(app, board, rtu(bytes([1, 16, 0, 3, 0, 2, 4]) + struct.pack(">HH", p >> 16, p & 0xFFFF)))

    assert write(0)[1] == 16
    last_pos, last_t = 0, board.clock.t - 5
    for dt, pos in reports:
        board.clock.t += dt
        t = board.clock.t
        out = write(pos)
        if plausible(pos - last_pos, t - last_t):
            assert out[1] == 16 and app.pos == pos, (out, pos, last_pos)
            last_pos, last_t = pos, t
        else:
            assert out[1:3] == bytes([0x90, 3]) and app.pos == last_pos, out


# --- 7. reply amplification ---------------------------------------------------------------------------------------

_TOKENS = [b"\n", b"$", b"\r\n", b"x", b"$TC,P,1*0000\r\n", b"\xff\n", b"$TC,L*0000\n"]


@SETTINGS
@given(st.lists(st.integers(0, len(_TOKENS) - 1), min_size=100, max_size=1500), st.integers(1, 11))
def test_hole7_garbage_cannot_crowd_out_the_offsets(tokens, per_ms):
    app, board, _ = small(extra={"frame_ms": 100, "cycle_ms": 100})
    garbage = b"".join(_TOKENS[k] for k in tokens)  # plenty of line ends: one E frame each, without a limit
    t0 = board.clock.t
    sent = 0
    n_o = 0
    e_bytes = 0
    # the garbage arrives at most as fast as a 115200-baud UART carries it (11.5 bytes/ms): per_ms bytes/ms
    while sent < len(garbage):
        k = min(per_ms * 100, len(garbage) - sent)
        board.serial.feed(garbage[sent:sent + k])
        sent += k
        app.cycle()
        board.clock.t += 100
        out = board.serial.take()
        for line in out.split(b"\r\n"):
            if b",E," in line[:20]:
                e_bytes += len(line) + 2
            elif b",O," in line[:20]:
                n_o += 1
    elapsed = board.clock.t - t0
    longest = 2 + wire.E_BURST  # not used below: kept for the message
    bound = (wire.E_BURST + elapsed // wire.E_REFILL_MS + 1) * 64  # an E frame is < 64 bytes with its detail
    assert e_bytes <= bound, (e_bytes, bound, longest)
    assert n_o >= elapsed // 100 - 1  # every periodic offset frame still went out


def test_hole5_reprovisioning_with_a_new_key_starts_its_counters_again(tmp_path):
    """A board whose counter reached MAX: `tcomp flash --key NEWFILE` stages the new key with an auth.bin
    (and auth.bin.new) at 0, and the board then accepts the new key's commands; an existing key file
    leaves the board's counter store alone."""
    from host.cli.verbs.flash import board_key, stage
    from host.board.linkauth import LinkSigner
    from firmware.crc16 import crc16_ccitt
    tables = tmp_path / "board" / "tables"
    tables.mkdir(parents=True)
    (tables / "table_a.bin").write_bytes(make_table(kind="poly_slope", sensors=SENSORS))
    provision(tables)
    b = b"TA\x01" + struct.pack("<I", wire.MAX_COUNTER)
    (tables / "auth.bin").write_bytes(b + struct.pack("<H", crc16_ccitt(b)))
    from fwfakes import make_rig
    from firmware.app import App
    board = make_rig(2, 1, table_dir=str(tables), serial_size=1 << 20)
    app = App(board)
    run_cycles(app, board, 3)
    board.serial.take()
    assert app.auth.last == wire.MAX_COUNTER
    out = send(app, board, LinkSigner(TEST_KEY, wire.MAX_COUNTER - 1, app.auth.nonce()).stream_line("L"))
    assert out[0][3:7] == ["E", "8", "auth", "replayed counter"], out
    key, created = board_key(str(tmp_path / "new.key"))
    assert created
    files, tdir = stage(str(tmp_path / "stage"), key=key, new_key=created, firmware=False, table_dir="tables")
    for p in files[tdir]:  # what mpremote copies onto the board
        (tables / os.path.basename(p)).write_bytes(open(p, "rb").read())
    from host.board.linkauth import write_key
    write_key(str(tmp_path / "new.key"), key)  # tcomp flash writes the key file once the board holds it
    board = make_rig(2, 1, table_dir=str(tables), serial_size=1 << 20)
    app = App(board)
    run_cycles(app, board, 3)
    assert app.auth.last == 0
    assert send(app, board, LinkSigner(key, 0, app.auth.nonce()).stream_line("L"))[0][3:5] == ["E", "5"]
    _, created = board_key(str(tmp_path / "new.key"))  # the same file again: not new, no counter store
    files, tdir = stage(str(tmp_path / "stage2"), key=key, new_key=created, firmware=False, table_dir="tables")
    assert not created and sorted(os.path.basename(p) for p in files[tdir]) == ["key.bin"]
