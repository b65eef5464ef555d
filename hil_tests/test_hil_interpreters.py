"""The interpreter switch (hil_tests/rig/interpreters.py) and the 32-bit port it chooses in make test.

The firmware's promise "small ints stop at 2**30" is only tested when the interpreter really is a
32-bit MicroPython: the first test fails when TCOMP_MICROPYTHON points at the 64-bit unix wheel.
"""
import os
import subprocess

import pytest

from hil_tests.rig import interpreters

pytestmark = pytest.mark.micropython

# Under heap_lock a long int cannot be made: 2**30 - 1 is the largest small int of a 32-bit port,
# one more raises MemoryError there; on a 64-bit port small ints go up to 2**62 - 1.
SMALL_INT_LIMIT = r"""
import micropython, sys
a = (1 << 30) - 2
b = 0
r = "none"
micropython.heap_lock()
try:
    b = a + 1  # 2**30 - 1: a small int on every port
    r = "small"
    b = b + 1  # 2**30: a long int on a 32-bit port, which cannot be made under the lock
    r = "no-MemoryError"
except MemoryError:
    r = "MemoryError"
micropython.heap_unlock()
print(r, b, sys.maxsize)
"""


def _run(interp, script, heap="64K"):
    p = subprocess.run(interp.argv(heap) + ["-c", script], capture_output=True, text=True, timeout=60)
    assert p.returncode == 0, p.stdout + p.stderr
    return p.stdout.split()


def test_chosen_interpreter_is_32_bit():
    """Fails on a 64-bit MicroPython: make test must run the firmware on the 32-bit port."""
    it = interpreters.get()
    try:
        it.require()
    except interpreters.InterpreterMissing as e:
        pytest.fail(str(e))
    out = _run(it, SMALL_INT_LIMIT)
    assert out == ["MemoryError", str((1 << 30) - 1), str((1 << 31) - 1)], (it, out)
    assert it.bits == 32


def test_the_check_tells_64_bit_apart():
    """The same script on the 64-bit unix wheel runs through: the check above can fail."""
    it = interpreters.get("unix64")
    try:
        it.require()
    except interpreters.InterpreterMissing as e:
        pytest.fail(str(e))
    out = _run(it, SMALL_INT_LIMIT)
    assert out == ["no-MemoryError", str(1 << 30), str((1 << 63) - 1)], out


def test_switch_resolves_names_and_paths(monkeypatch, tmp_path):
    monkeypatch.delenv(interpreters.ENV, raising=False)
    assert interpreters.get() is interpreters.KINDS[interpreters.DEFAULT]
    monkeypatch.setenv(interpreters.ENV, "unix64")
    assert interpreters.get().kind == "unix64" and interpreters.heap("rig") == interpreters.HEAPS["rig"][64]
    monkeypatch.setenv(interpreters.ENV, interpreters.KINDS["linux32"].path)
    assert interpreters.get().kind == "linux32" and interpreters.heap("rig") == interpreters.HEAPS["rig"][32]
    monkeypatch.setenv(interpreters.ENV, "nosuchkind")
    with pytest.raises(interpreters.InterpreterMissing, match="nosuchkind"):
        interpreters.get()


def test_missing_interpreter_fails_not_skips(monkeypatch, tmp_path):
    """A switch pointing at nothing raises (the fixtures turn that into a failure, never a skip)."""
    monkeypatch.setenv(interpreters.ENV, str(tmp_path / "micropython"))
    it = interpreters.get()
    assert it.kind == "custom" and not it.exists()
    with pytest.raises(interpreters.InterpreterMissing, match=str(tmp_path)):
        it.argv("64K")
    from hil_tests.rig.harness import RigError, interpreter_cmd
    with pytest.raises(RigError):
        interpreter_cmd("micropython")


NOISE = r"""
import micropython, sys
from hil_tests.sim.rng import XorShift32
r = XorShift32(12345)
out = [0] * 30
k = 0
micropython.heap_lock()
for k in range(30):
    out[k] = r.noise(20000) if k % 2 else r.below(1000)
micropython.heap_unlock()
print(" ".join(str(v) for v in out))
"""


def _xorshift32_reference(seed, n):
    """Plain 32-bit xorshift (13, 17, 5) on CPython ints: what the simulated noise must follow."""
    x = (seed & 0xFFFFFFFF) or 0x9E3779B9
    for _ in range(n):
        x ^= (x << 13) & 0xFFFFFFFF
        x ^= x >> 17
        x ^= (x << 5) & 0xFFFFFFFF
        yield x


def test_sim_noise_is_xorshift32_and_allocation_free_on_32_bit():
    """The simulated chips' noise: xorshift32 exactly (two 16-bit halves), drawn under heap_lock on 32 bits."""
    ref = _xorshift32_reference(12345, 200)
    want = []
    for k in range(30):
        if k % 2:
            s = sum(next(ref) & 0xFFF for _ in range(4))
            want.append(((s - 8190) * 20000) // 2365)
        else:
            want.append(next(ref) % 1000)
    root = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
    it = interpreters.get().require()
    p = subprocess.run(it.argv("64K") + ["-c", NOISE], capture_output=True, text=True, timeout=60,
                       env=dict(os.environ, MICROPYPATH=root))
    assert p.returncode == 0, p.stdout + p.stderr
    assert [int(v) for v in p.stdout.split()] == want


def test_json_round_trips_with_cpython(tmp_path):
    """The rig's control channel: what CPython's json writes, the chosen MicroPython reads and writes
    back unchanged (the 32-bit port's json is ours: ports/common/modjson.c, lib/json.py)."""
    import json
    docs = [{"op": "run", "until_ms": 123456789, "temps": {"T1": 23.5, "T2": -0.00125, "T4": 1e-05}, "gc": False,
             "lock": True},
            {"ev": "stats", "chips": {"T1": {"violations": 0, "violation_text": "a \"quoted\" \\ line\n\u00e9"}},
             "uart": [1, 2], "wdt_feeds": None, "big": 2 ** 40, "neg": -(2 ** 31)},
            [], {}, "\u00b0C \U0001f600"]
    src = tmp_path / "in.json"
    src.write_text("\n".join(json.dumps(d) for d in docs) + "\n")
    script = ("import json\nf = open(%r)\nfor line in f:\n    print(json.dumps(json.loads(line)))\nf.close()\n"
              % str(src))
    it = interpreters.get().require()
    p = subprocess.run(it.argv("64K") + ["-c", script], capture_output=True, text=True, timeout=60)
    assert p.returncode == 0, p.stdout + p.stderr
    assert [json.loads(line) for line in p.stdout.splitlines()] == docs
    bad = subprocess.run(it.argv("64K") + ["-c", "import json\njson.loads('{\"a\": [1,]}')"],
                         capture_output=True, text=True, timeout=60)
    assert bad.returncode == 1 and "ValueError" in bad.stderr
