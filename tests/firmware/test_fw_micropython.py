"""The same firmware scenario on CPython and on the MicroPython unix port gives identical bytes.

The scenario boots an 11-channel board on fakes, runs cycles, sends position
reports, queries, temperature and hello requests, corrupt and unknown commands,
commands that change the output without authorisation, with a wrong key and
replayed, uploads a new table over the link with authorisation (two-slot
switch on the filesystem), changes temperatures and injects a sensor fault;
every byte the firmware writes to its
serial port, and the RTD conversion over a grid, must match between the two
interpreters bit for bit.
"""
import os
import subprocess
import sys

import pytest

from fwhelpers import compile_mpy, run_micropython, make_table, provision, HERE, ROOT

SCENARIO = r"""
import binascii
from fwfakes import make_rig
from firmware.app import App
from firmware.crc16 import crc16_ccitt
from firmware.crc32 import crc32
from firmware import rtd
state = [0, 0, 0]  # CRC-32 of every byte written, byte count, frame count
samples = []
def drain():
    b = board.serial.take()
    state[0] = crc32(b, state[0])
    state[1] += len(b)
    state[2] += b.count(b"$TC,")
    for key in (b",E,", b",Q,", b",T,", b",H,", b",A,U,C", b",A,L"):
        k = b.find(key)
        if k >= 0 and len(samples) < 40:
            e = b.find(b"\r\n", k)
            samples.append(b[b.rfind(b"$", 0, k):e])
def line(body):
    return b"$" + body + b"*" + (b"%04X" % crc16_ccitt(body)) + b"\r\n"
board = make_rig(table_dir=".", extra={"frame_ms": 500, "hold_ms": 1500})
app = App(board)
def cycles(n):
    for k in range(n):
        app.cycle()
        board.clock.t += 100
        drain()
def send(b):
    board.serial.feed(b)
    app.link.poll(board.clock.t)
    drain()
cycles(60)
send(line(b"TC,P,120000"))
cycles(5)
send(line(b"TC,Q,300000"))
send(line(b"TC,S"))
send(line(b"TC,V"))
send(b"$TC,P,5*0000\r\n")
send(line(b"TC,Z,1"))
send(b"\x00\xff garbage\r\n")
f = open("new.bin", "rb")
data = f.read()
f.close()
f = open("signed.txt", "rb")  # lines signed on the host (host/board/linkauth.py)
signed = [x + b"\r\n" for x in f.read().split(b"\n")]
f.close()
cycles(3)  # the error-frame budget refills (protocol.py: E frames are rate-limited)
# without authorisation: refused, nothing changes
for cmd in (b"TC,L", b"TC,X", b"TC,U,X", b"TC,U,B,%d,%08X" % (len(data), crc32(data))):
    send(line(cmd))
print("UNSIGNED", app.slot, app.store.uploading, app.auth.last)
cycles(3)
send(signed[0])  # U,B
for x in signed[6:]:  # the chunks, each tagged for this upload
    send(x)
send(signed[1])  # U,C over another table's sha256: refused, the upload stays open
send(signed[2])  # U,C
send(signed[2])  # replayed: nothing is open to commit
send(signed[3])  # L with a wrong key
send(signed[4])  # L: fixed references, refused after authorisation
send(signed[4])  # replayed
send(signed[5])  # a stale counter
cycles(40)
board.chips[3].open_circuit = True
cycles(40)
board.chips[3].open_circuit = False
board.chips[3].regs[7] = 0
board.chips[7].set_temperature(31.5)
cycles(60)
send(line(b"TC,S"))
for x in samples:
    print(x.decode())
print("OUT", "%08X" % state[0], state[1], state[2])
acc = 0
for r in range(1852008, 39048112, 9973):
    acc = (acc * 31 + rtd.temperature_mC(r)) & 0xFFFFFFF
print(acc, app.slot, app.cycles, "%08X" % app.status, app.auth.last)
"""


def _signed_lines(new, other):
    import hashlib
    from fwhelpers import TEST_KEY, TEST_NONCE
    from host.board.linkauth import LinkSigner
    up = LinkSigner(TEST_KEY, 0, TEST_NONCE).upload_lines(new, 40)  # U,B (counter 1), the tagged chunks, U,C
    s = LinkSigner(TEST_KEY, 1, TEST_NONCE)
    upload_id = TEST_NONCE + b"\x00\x00\x00\x01"
    lines = [up[0],
             s.stream_line("U", "C", extra=hashlib.sha256(other).digest(), bound=upload_id),
             s.stream_line("U", "C", extra=hashlib.sha256(new).digest(), bound=upload_id)]
    lines.append(LinkSigner(bytes(32), s.counter, TEST_NONCE).stream_line("L"))
    lines.append(s.stream_line("L"))
    lines.append(LinkSigner(TEST_KEY, 1, TEST_NONCE).stream_line("L"))
    lines += up[1:-1]  # the chunks, from signed[6] on
    return b"\n".join(x.rstrip(b"\r\n") for x in lines)


@pytest.mark.micropython
def test_same_bytes_on_cpython_and_micropython(tmp_path_factory):
    names = ["T%d" % i for i in range(1, 12)]
    results = []
    for interp in ("cpython", "micropython"):
        d = tmp_path_factory.mktemp(interp)
        (d / "table_a.bin").write_bytes(make_table(kind="poly_slope", sensors=names))
        new = make_table(kind="linear_direct", sensors=names, S0=777)
        (d / "new.bin").write_bytes(new)
        (d / "signed.txt").write_bytes(_signed_lines(new, make_table(kind="linear_direct", sensors=names, S0=1)))
        provision(d)
        if interp == "cpython":
            env = dict(os.environ, PYTHONPATH=ROOT + os.pathsep + HERE)
            p = subprocess.run([sys.executable, "-c", SCENARIO], cwd=d, env=env, capture_output=True,
                               text=True, timeout=120)
            assert p.returncode == 0, p.stderr
            results.append(p.stdout)
        else:
            mpy = compile_mpy(fakes=True)
            # the smallest that works plus a margin, per word size (interpreters.HEAPS, docs/firmware.md)
            from hil_tests.rig import interpreters
            results.append(run_micropython(SCENARIO, str(d), mpy, interpreters.heap("fw_scenario")))
    cpy, mpy = results
    assert cpy == mpy
    lines = cpy.splitlines()
    out = lines[-2].split()
    assert out[0] == "OUT" and int(out[3]) > 20  # frames written, all bytes hashed
    assert lines[-1].split()[1] == "1"  # the uploaded table is in slot B on both
    assert lines[-1].split()[4] == "4"  # counters 1..4 used; the refused and replayed ones were not
    text = "\n".join(lines)
    assert ",E,1,crc" in text and ",E,3,unknown" in text and ",A,U,C,B" in text
    assert "UNSIGNED 0 False 0" in text  # refused, and nothing changed
    assert text.count(",E,8,auth,unsigned") == 4
    assert text.count(",E,8,auth,bad tag") == 2  # another table's sha256; a wrong key
    assert text.count(",E,8,auth,replayed counter") == 2  # L replayed, a stale counter
    assert ",E,5,state,fixed references" in text
