"""Scenario 3b: who may change the output. Fuzz of authenticated frames on the running firmware.

Hypothesis draws commands that change the output (L, X, U,B, U,C, U,X) and
spoils them the ways someone on the line could: no counter and tag, a wrong
key, one flipped tag digit, a field changed after signing, a tag moved to
another command, a replayed or stale counter, a short tag. Interleaved with
properly authorised commands that leave the table alone (U,X with nothing
open; L on a table with fixed references, refused after authorisation). Each
spoiled line gets one E frame (8 auth, or 2/4 for a malformed one) and
changes nothing: no reset, the same table, the counter unchanged; each
authorised one is acknowledged (or refused for its state) and uses exactly
its counter. Then a tampered table whose CRC-32 is recomputed is refused
by a properly authorised upload (its certificate does not hold).
Runs on MicroPython and CPython (rig), or a real board (--port with --key).
"""
import hashlib
import os
import struct
import zlib

import pytest
from hypothesis import HealthCheck, given, settings, strategies as st

from firmware.wire import HELLO_COUNTER, HELLO_NONCE
from host.board.linkauth import LinkSigner, stream_line

N_EXAMPLES = 250 if os.environ.get("TCOMP_SLOW") else 50

_COMMANDS = [("L",), ("X",), ("U", "X"), ("U", "C"), ("U", "B", 200, "0000ABCD")]


@st.composite
def _spoiled(draw, signer):
    """(line, expected E code) for a command that must be refused and change nothing."""
    cmd = draw(st.sampled_from(_COMMANDS))
    how = draw(st.sampled_from(["unsigned", "key", "flip", "field", "moved", "replay", "short"]))
    probe = LinkSigner(signer._key, signer.counter, signer.nonce)  # what the next valid line would be
    fields = list(probe.stream_fields(*cmd))
    code = "8"  # auth
    if how == "unsigned":
        line = stream_line(cmd)
    elif how == "key":
        other = draw(st.binary(min_size=32, max_size=32))
        line = LinkSigner(other if other != signer._key else bytes(32), signer.counter, signer.nonce).stream_line(*cmd)
    elif how == "flip":
        i = draw(st.integers(0, 31))
        tag = fields[-1]
        fields[-1] = tag[:i] + ("0" if tag[i] != "0" else "1") + tag[i + 1:]
        line = stream_line(fields)
    elif how == "field":  # the counter changed after signing
        fields[-2] += draw(st.integers(1, 1000))
        line = stream_line(fields)
    elif how == "moved":  # a valid tag on another command
        cmd = draw(st.sampled_from([c for c in _COMMANDS if c != cmd]))
        line = stream_line(list(cmd) + fields[-2:])
    elif how == "replay":
        if signer.counter:  # a counter already used, properly signed
            # (drawn independently of the counter: hypothesis needs the same draws for the same choices)
            old = draw(st.integers(0, 1 << 20)) % signer.counter
            line = LinkSigner(signer._key, old, signer.nonce).stream_line(*cmd)
        else:  # counter 0 is never valid
            line = stream_line(list(cmd) + [0, fields[-1]])
            code = "4"
    else:  # a short tag
        line = stream_line(fields[:-1] + [fields[-1][:draw(st.integers(0, 31))]])
        code = "4"
    if cmd == ("U", "C"):
        code = "5"  # nothing is open to commit: refused before the tag is even looked at
    return line, code


def _but_counter(hello):
    """A hello's fields without the counter (fields are appended after it: docs/protocol.md)."""
    return hello.fields[:HELLO_COUNTER] + hello.fields[HELLO_NONCE + 1:]  # the counter and the session nonce move


def _hello(dut):
    h = dut.request("V", kinds=("H",))
    dut.signer.observe_hello(h.fields)
    return h


def test_authenticated_fuzz_refuses_everything_spoiled(dut):
    if dut.signer is None:
        pytest.skip("the board's key is needed (--key)")
    dut.advance(2000)
    first = _hello(dut)
    signer = dut.signer
    COUNT = {"spoiled": 0, "authorised": 0}

    def replies(n0):
        for _ in range(200):
            dut.advance(10)
            new = [f for f in dut.frames[n0:] if f.kind != "O"]
            if new:
                dut.advance(20)  # room for a wrong extra frame (a reset's hello) to show up
                return [f for f in dut.frames[n0:] if f.kind != "O"]
        return []

    @settings(max_examples=N_EXAMPLES, deadline=None, suppress_health_check=list(HealthCheck), derandomize=True)
    @given(st.data())
    def check(data):
        before = _hello(dut)
        for _ in range(data.draw(st.integers(1, 4))):
            n0 = len(dut.frames)
            if data.draw(st.booleans()):
                line, code = data.draw(_spoiled(signer))
                dut.write(line)
                new = replies(n0)
                assert [f.kind for f in new] == ["E"] and new[0].fields[0] == code, (line, [f.raw for f in new])
                COUNT["spoiled"] += 1
            else:
                cmd = data.draw(st.sampled_from([("U", "X"), ("L",)]))
                dut.write(signer.stream_line(*cmd))
                new = replies(n0)
                want = ["A", "U", "X"] if cmd == ("U", "X") else ["E", "5", "state", "fixed references"]
                assert len(new) == 1 and [new[0].kind] + new[0].fields[:3] == want[:4], [f.raw for f in new]
                COUNT["authorised"] += 1
        after = _hello(dut)
        # same table, slot and provenance; the counter moved by the authorised commands only
        assert _but_counter(after) == _but_counter(before)
        assert int(after.fields[HELLO_COUNTER]) == signer.counter

    check()
    last = _hello(dut)
    assert _but_counter(last) == _but_counter(first)
    print("authenticated fuzz: %d spoiled lines refused, %d authorised commands" % (COUNT["spoiled"], COUNT["authorised"]))


def _tampered(table):
    """Coefficients x 1000 (b[i], as the hostile test did), CRC-32 recomputed: valid CRC, broken certificate."""
    from firmware.table import parse_table
    t = parse_table(table)
    b = bytearray(table)
    words = 64 + 36 * t.n_sensors
    off = words + 4 * 8  # pos_lo pos_hi pos_ref fo Lt nt S0 fS, then b[0]
    for i in range(t.n_sensors):
        v = struct.unpack_from("<i", b, off + 12 * i)[0]
        struct.pack_into("<i", b, off + 12 * i, max(-(1 << 31), min((1 << 31) - 1, v * 1000)))
    struct.pack_into("<I", b, len(b) - 4, zlib.crc32(bytes(b[:-4])))
    return bytes(b)


@pytest.mark.rig
def test_tampered_table_with_valid_crc_is_refused(make_rig, demo_run):
    from hil_tests.rig.boards import export, poly_slope_for_run, rig_config
    sensors = ["T1", "T2", "T4"]
    good = export(poly_slope_for_run(demo_run, sensors, seed=41)).table
    bad = _tampered(good)
    rig = make_rig(rig_config(sensors), good, temps={"T1": 23.0, "T2": 24.0, "T4": 22.0})
    rig.run(2000)
    h0 = rig.request("V", kinds=("H",))
    for line in rig.upload_lines(bad):  # authorised: only the certificate can stop it
        k = len(rig.frames)
        rig.write(line)
        r = rig.wait_frames(lambda f: f.kind in ("A", "E") and rig.frames.index(f) >= k)
    assert r.kind == "E" and r.fields[:2] == ["6", "table"] and "certificate" in r.fields[2], r.raw
    assert _but_counter(rig.request("V", kinds=("H",))) == _but_counter(h0)
    # the same bytes put straight into the slot files (someone with the flash): refused at boot
    with open(os.path.join(rig.flash, "tables", "table_a.bin"), "wb") as f:
        f.write(bad)
    k = len(rig.frames)
    rig.restart()
    rig.run(300)
    h = rig.wait_real(lambda f: f.kind == "H", 15.0, k)
    assert h.fields[2] == "-", h.raw  # no table rather than the tampered one
    e = rig.wait_real(lambda f: f.kind == "E", 15.0, k)
    assert e.fields[:2] == ["6", "table"] and "certificate" in e.fields[2], e.raw
    assert hashlib.sha256(bad).digest() != hashlib.sha256(good).digest()
