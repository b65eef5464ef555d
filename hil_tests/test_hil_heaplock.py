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
                # As a Modbus master does: one request at a time, and a request with no answer after 1 s (of the board's
                # time) is sent again. On a loaded machine the emulated UART hands the host's bytes to the board one
                # QEMU main-loop turn at a time while the board's clock (instruction count) runs on, so a request can
                # reach it with gaps over 3.5 characters inside, which RTU framing rightly drops as broken frames.
                # Whether the board answers each request exactly once is test_hil_modbus's subject; here it is the
                # cycle's allocations while it answers: every answer is checked whole (length, header, CRC).
                ans = b""
                frame = 3 + 70 + 2
                for k in range(5):
                    deadline = time.monotonic() + 60.0
                    while len(ans) < (k + 1) * frame and time.monotonic() < deadline:
                        if len(ans) <= k * frame:  # nothing of this answer in yet: (re)send
                            s.write(req + crc_modbus(req))
                        for _ in range(10):
                            rig.run(rig.t_ms + 100, lock=True)
                            ans += s.read(4096)
                            if len(ans) >= (k + 1) * frame:
                                break
                rig.run(rig.t_ms + locked_s * 1000, lock=True)
                ans += s.read(4096)
            answers = [ans[i:i + frame] for i in range(0, len(ans), frame)]
            assert len(answers) >= 5 and len(ans) % frame == 0, len(ans)
            assert all(a[:3] == bytes((1, 4, 70)) and crc_modbus(a[:-2]) == a[-2:] for a in answers)
        st = rig.stats()
        assert st["impl"] == "micropython" and all(c["violations"] == 0 for c in st["chips"].values())
