"""Scenario 7: the steady-state cycle runs under micropython.heap_lock() on the real interpreter:
the unix port (64-bit) and the emulated Cortex-M3 board (``qemu``: a 32-bit build, the firmware
frozen in its ROM, small ints stopping at 2**30 as on an MCU).

The rig process runs locked between two control-channel gates: the
firmware's cycles (chip reads over the simulated buses, conversion,
evaluation, limiting, $TC frames, parsing position reports and queries
from the pty) and the simulated clock and serial port. Only the simulated
chips' own work inside a transfer runs unlocked (hil_tests/sim/buses.py: they
stand for hardware; on the 32-bit port their integers pass 2**30). Any
allocation raises MemoryError inside the firmware and the DUT reports a crash.
"""
import os

import pytest

from hil_tests.rig.boards import export, poly_slope_for_run, rig_config

pytestmark = pytest.mark.rig


@pytest.mark.parametrize("interpreter", ["micropython", "qemu"])
@pytest.mark.parametrize("mode", ["stream", "modbus"])
def test_steady_state_cycle_allocates_nothing(tmp_path, demo_run, mode, interpreter):
    from hil_tests.rig import interpreters
    from hil_tests.rig.harness import Rig
    if interpreter == "micropython":
        interpreters.get().require()  # not there: the test fails (never skips)
    sensors = ["T1", "T2", "T4"]
    table = export(poly_slope_for_run(demo_run, sensors, seed=4)).table
    cfg = rig_config(sensors, mode=mode, frame_ms=100)
    locked_s = 600 if os.environ.get("TCOMP_SLOW") else 60
    with Rig(cfg, table, interpreter=interpreter, workdir=str(tmp_path / "rig"), noise_uohm=20000,
             temps={"T1": 23.0, "T2": 24.0, "T4": 22.0}, open_port=(mode == "stream")) as rig:
        rig.run(20000)  # boot, first conversions, limiter ramp: allocation allowed here
        if mode == "stream":
            rig.take_frames()
            for k in range(10):
                rig.send("P", 100000 + 1000 * k)
            rig.send("Q", 250000)
            rig.run(rig.t_ms + 1000, lock=True)
            n0 = len(rig.frames)
            rig.run(rig.t_ms + locked_s * 1000, temps={"T1": 25.0, "T2": 25.5, "T4": 23.0}, lock=True)
            frames = rig.take_frames()
            assert len(frames) >= locked_s * 10 - 1 + n0 // 2
            assert any(f.kind == "Q" for f in frames) and frames[-1].pos_um == 109000
            assert all(f.status & 0xFFFF == 0 for f in frames if f.kind == "O")
        else:
            import serial
            from hil_tests.test_hil_modbus import crc_modbus
            req = bytes((1, 4, 0, 16, 0, 35))  # temperatures, faults, authorisation state
            with serial.Serial(rig.port, 115200, timeout=0) as s:
                import time
                # a Modbus master sends its next request only after the answer to the last one: requests written back
                # to back can reach the emulated UART together on a loaded machine (its host side hands bytes over a
                # main-loop turn at a time) and then form one frame without the 3.5-character gap, which the board
                # rightly drops as a bad frame. So each request waits for its 75-byte answer, the board running
                # heap-locked meanwhile (30 s of wall time at most each).
                ans = b""
                for k in range(5):
                    s.write(req + crc_modbus(req))
                    deadline = time.monotonic() + 30.0
                    while len(ans) < (k + 1) * (3 + 70 + 2) and time.monotonic() < deadline:
                        rig.run(rig.t_ms + 100, lock=True)
                        ans += s.read(4096)
                rig.run(rig.t_ms + locked_s * 1000, lock=True)
                ans += s.read(4096)
            assert len(ans) == 5 * (3 + 70 + 2) and ans[:3] == bytes((1, 4, 70))
        st = rig.stats()
        assert st["impl"] == "micropython" and all(c["violations"] == 0 for c in st["chips"].values())
