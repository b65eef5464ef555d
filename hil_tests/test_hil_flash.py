"""Scenario 5: flashing as a user does it. ``tcomp flash`` (mpremote) copies the firmware, a board
file generated from a config and a table onto a simulated board (a MicroPython unix REPL on a
socat pty whose working directory is the board's flash); after a power cycle the board boots
main.py from those files: its hello names the flashed table and its sensors read good.
"""
import json
import os
import shutil
import time
import zlib

import pytest
import serial

from hil_tests.rig.boards import export, poly_slope_for_run, rig_config
from host.board.link import HELLO_COUNTER, StreamDecoder, command

pytestmark = [pytest.mark.rig, pytest.mark.micropython]


def _frames(ser, decoder, seconds, want=None):
    out = []
    end = time.monotonic() + seconds
    while time.monotonic() < end:
        data = ser.read(4096)
        if data:
            out += decoder.feed(data)
            if want and want(out):
                return out
        else:
            time.sleep(0.02)
    return out


def test_tcomp_flash_then_board_runs_from_flash(tmp_path, demo_run, capfd):
    from hil_tests.rig import interpreters
    from hil_tests.rig.socatboard import SocatBoard
    from host.cli import main as tcomp
    interpreters.get().require()  # not there: the test fails (never skips)
    if shutil.which("socat") is None:
        pytest.skip("socat is needed (make setup installs it)")
    sensors = ["T1", "T2", "T4"]
    table = export(poly_slope_for_run(demo_run, sensors, seed=41)).table
    (tmp_path / "table.bin").write_bytes(table)
    cfg = rig_config(sensors, watchdog_ms=0)
    cfg["channels"][-1]["bus"] = "i2c1"  # rp2040.make_board names its buses spi0 / i2c1
    (tmp_path / "board.json").write_text(json.dumps(cfg))
    flash = tmp_path / "flash"
    flash.mkdir()
    link = str(tmp_path / "ttyBOARD")
    with SocatBoard(str(flash), link):
        rc = tcomp(["flash", "--port", link, "--table", str(tmp_path / "table.bin"),
                    "--config", str(tmp_path / "board.json"), "--key", str(tmp_path / "board.key")])
        assert rc == 0
    from host.board.linkauth import LinkSigner, read_key
    key = read_key(str(tmp_path / "board.key"))  # created by tcomp flash, readable by its owner only
    assert os.stat(tmp_path / "board.key").st_mode & 0o777 == 0o600
    assert (flash / "tables" / "key.bin").read_bytes() == key
    out, err = capfd.readouterr()
    assert key.hex() not in (out + err).lower() and "board key: " in err  # named, never printed
    for rel in ("main.py", "tcomp_board.py", "firmware/app.mpy", "firmware/boards/rp2040.mpy", "tables/table_a.bin"):
        assert (flash / rel).is_file(), rel
    assert (flash / "tables" / "table_a.bin").read_bytes() == table
    # the board holds exactly the firmware files the rig ran (hil_tests/manifest.py includes the board
    # manifest), byte for byte, and no source of them
    from hil_tests.rig.mpybuild import rig_build
    ran = {t: open(p, "rb").read() for t, p in rig_build().files if t.startswith("firmware/")}
    flashed = {os.path.relpath(os.path.join(d, n), flash): open(os.path.join(d, n), "rb").read()
               for d, _, names in os.walk(flash / "firmware") for n in names}
    assert sorted(flashed) == sorted(ran) and flashed == ran
    assert not (flash / "firmware" / "linux_adapters.mpy").exists()
    spec = tmp_path / "world.json"
    spec.write_text(json.dumps({"config": cfg, "temps": {"T1": 23.0, "T2": 24.0, "T4": 22.0}}))
    with SocatBoard(str(flash), link, script="main.py", world_spec=str(spec)):  # power on: boot main.py
        with serial.Serial(link, 115200, timeout=0) as ser:
            dec = StreamDecoder()
            frames = _frames(ser, dec, 20.0, lambda fr: sum(f.kind == "O" and f.status & 0xFFFF == 0
                                                           for f in fr) >= 2)
            ser.write(command("V"))
            frames += _frames(ser, dec, 5.0, lambda fr: any(f.kind == "H" for f in fr))
            # the provisioned key authorises; without it the same command is refused
            signer = LinkSigner(key)
            signer.observe([f for f in frames if f.kind == "H"][-1].fields[HELLO_COUNTER])
            ser.write(command("U", "X"))
            ser.write(signer.stream_line("U", "X"))
            replies = _frames(ser, dec, 5.0, lambda fr: sum(f.kind in ("A", "E") for f in fr) >= 2)
            assert [(f.kind, f.fields[0]) for f in replies if f.kind in ("A", "E")] == [("E", "8"), ("A", "U")]
    assert not dec.bad, dec.bad[:3]
    hello = [f for f in frames if f.kind == "H"][-1]
    assert hello.fields[2] == "A" and hello.fields[3] == "%08X" % zlib.crc32(table[:-4]), hello.raw
    good = [f for f in frames if f.kind == "O" and f.status & 0xFFFF == 0]
    assert len(good) >= 2, [f.raw for f in frames[-5:]]
