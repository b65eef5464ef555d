"""The emulated Cortex-M3 board (QEMU mps2-an385, ports/mps2): the image make setup builds.

The heap-locked cycle on it, in both serial modes, is in test_hil_heaplock.py. Here: the
firmware is frozen (imported from the image's ROM table, not from files), the image's 32-bit
arithmetic helper for the chip simulators agrees with Python's integers, the simulators' noise
generator gives the same sequence as the plain 32-bit xorshift, and mpremote reaches the
board's REPL on UART0 through a pty.
"""
import os
import random
import shutil
import subprocess
import sys
import tty

import pytest

from hil_tests.rig.harness import QEMU_IMAGE, ROOT

IMAGE = os.path.join(ROOT, "build", "mps2-cortex-m3", "firmware.elf")


def _need_image(path=IMAGE):
    if shutil.which("qemu-system-arm") is None or not os.path.exists(path):
        pytest.fail("QEMU board image missing (make setup installs qemu-system-arm and builds %s)" % path)


def _run(code, cwd, image=IMAGE, heap="64K"):
    """Run ``code`` on the board; returns (exit status, UART0 output, QEMU's stderr)."""
    with open(os.path.join(cwd, "_t.py"), "w") as f:
        f.write(code)
    p = subprocess.run(["qemu-system-arm", "-M", "mps2-an385", "-display", "none", "-monitor", "none",
                        "-nodefaults", "-net", "none", "-serial", "stdio", "-semihosting-config",
                        "enable=on,target=native", "-kernel", image, "-append",
                        "heap=%s -c exec(open('_t.py').read())" % heap],
                       cwd=cwd, capture_output=True, text=True, timeout=60)
    return p.returncode, p.stdout, p.stderr


def test_firmware_is_frozen_and_small_ints_are_31_bit(tmp_path):
    _need_image()
    code = ("import sys, gc, firmware.app, firmware.protocol, firmware.modbus, firmware.boards.mps2_an385\n"
            "print('FILE', firmware.app.__file__, firmware.boards.mps2_an385.__file__)\n"
            "print('SMALL', type(1 << 29).__name__, (1 << 30) - 1 == 0x3FFFFFFF)\n"
            "print('HEAP', gc.mem_alloc() + gc.mem_free())\n")
    rc, out, err = _run(code, str(tmp_path))
    assert rc == 0, out + err
    assert "FILE firmware/app.mpy firmware/boards/mps2_an385.mpy" in out, out
    assert "HEAP %d" % (64 * 1024) in out or "HEAP 6" in out, out
    # nothing was read from the host: the modules came from the ROM table
    assert not os.path.exists(tmp_path / "firmware")


def test_muldiv_matches_python_integers(tmp_path):
    _need_image()
    from hil_tests.sim.intmath import muldiv as py_muldiv
    rng = random.Random(5)
    cases = []
    for _ in range(300):
        a = rng.choice([rng.randrange(1 << 16), rng.randrange(1 << 31), rng.randrange(1 << 40)])
        b = rng.choice([rng.randrange(1, 1 << 16), 32768, rng.randrange(1 << 24)])
        d = rng.choice([rng.randrange(1, 1 << 20), 430000000, 3240000000, 2048000000000000])
        add = rng.choice([0, d // 2, d - 1])
        shift = rng.choice([0, 0, 23])
        if ((a * b) << shift) + add < (d << 62):
            cases.append((a, b, d, add, shift))
    code = "from simint import muldiv\nC = %r\nprint('R', [muldiv(*c) for c in C])\n" % (cases,)
    rc, out, err = _run(code, str(tmp_path), heap="256K")
    assert rc == 0, out + err
    got = eval(out.split("R ", 1)[1].strip())
    assert got == [py_muldiv(*c) for c in cases]


def test_noise_sequence_is_the_32_bit_xorshift():
    from hil_tests.sim.rng import XorShift32
    for seed in (1, 0, 7, 0xFFFFFFFF):
        s = (seed & 0xFFFFFFFF) or 0x9E3779B9
        r = XorShift32(seed)
        for _ in range(2000):
            s ^= (s << 13) & 0xFFFFFFFF
            s ^= s >> 17
            s ^= (s << 5) & 0xFFFFFFFF
            assert r.next() == s


def test_mpremote_runs_code_on_the_board_repl(tmp_path):
    _need_image()
    mpremote = os.path.join(os.path.dirname(sys.executable), "mpremote")
    if not os.path.exists(mpremote):
        pytest.fail("mpremote not installed in the venv")
    master, slave = os.openpty()
    tty.setraw(master)
    tty.setraw(slave)
    port = os.ttyname(slave)
    qemu = subprocess.Popen(["qemu-system-arm", "-M", "mps2-an385", "-display", "none", "-monitor", "none",
                             "-nodefaults", "-net", "none", "-add-fd", "fd=%d,set=1" % master,
                             "-chardev", "serial,id=uart0,path=/dev/fdset/1", "-serial", "chardev:uart0",
                             "-semihosting-config", "enable=on,target=native", "-kernel", IMAGE],
                            pass_fds=(master,), cwd=str(tmp_path), stderr=subprocess.DEVNULL)
    try:
        script = tmp_path / "on_board.py"
        script.write_text("import sys, firmware.crc16\nprint('board', sys.platform, "
                          "hex(firmware.crc16.crc16_ccitt(b'123456789')))\n")
        p = subprocess.run([mpremote, "connect", port, "run", str(script)], capture_output=True, text=True,
                           timeout=60)
        assert p.returncode == 0, p.stdout + p.stderr
        from firmware.crc16 import crc16_ccitt
        assert "board mps2 %s" % hex(crc16_ccitt(b"123456789")) in p.stdout, p.stdout
        p = subprocess.run([mpremote, "connect", port, "exec", "print(6 * 7)"], capture_output=True, text=True,
                           timeout=60)
        assert p.returncode == 0 and "42" in p.stdout, p.stdout + p.stderr
    finally:
        qemu.kill()
        qemu.wait()
        os.close(master)
        os.close(slave)


def test_rig_image_exists_for_tcomp_hil():
    _need_image(QEMU_IMAGE)
