"""Type-check firmware/ with pyright against the MicroPython stubs in .stubs/ (``make typecheck``).

The Makefile installs micropython-rp2-stubs and micropython-stdlib-stubs into
.stubs/; the latter carries a MicroPython typeshed (.stubs/stdlib) that
replaces CPython's, so a call that exists only on CPython is an error here.
The files checked against MicroPython are the ones firmware/manifest.py puts
on a board (host/board/fwbuild.py reads it); the files it leaves off (NOT_ON_BOARD:
linux_adapters.py and boards/linux.py, CPython-only with fcntl, ctypes,
pyserial, smbus2; wire.py, which the host reads) are checked separately
against the ordinary CPython typeshed. The manifest itself is build input
(its module()/package() names come from the loader) and is not checked.

Exit status: 0 when pyright reports no errors, 1 otherwise (2 if the stubs
are missing).
"""
import json
import os
import subprocess
import sys
import tempfile

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
STUBS = os.path.join(ROOT, ".stubs")
PYRIGHT = os.path.join(ROOT, ".venv", "bin", "pyright")


def _rel(config, d):
    """pyright ignores absolute include/exclude entries: make paths relative to the config."""
    out = {}
    for k, v in config.items():
        if k in ("include", "exclude", "extraPaths"):
            v = [os.path.relpath(x, d) if os.path.isabs(x) else x for x in v]
        elif k in ("typeshedPath", "stubPath", "venvPath"):
            v = os.path.relpath(v, d)
        out[k] = v
    return out


def run(config, label):
    # the config lives in the git-ignored stubs folder: pyright resolves its paths from there
    with tempfile.TemporaryDirectory(dir=STUBS) as d:
        path = os.path.join(d, "pyrightconfig.json")
        with open(path, "w") as f:
            json.dump(_rel(config, d), f)
        p = subprocess.run([PYRIGHT if os.path.exists(PYRIGHT) else "pyright", "-p", path, "--outputjson"],
                           cwd=ROOT, capture_output=True, text=True)
    try:
        report = json.loads(p.stdout)
    except ValueError:
        print(p.stdout + p.stderr)
        return 1
    diags = report.get("generalDiagnostics", [])
    errors = [x for x in diags if x["severity"] == "error"]
    for x in diags:
        if x["severity"] in ("error", "warning"):
            rel = os.path.relpath(x["file"], ROOT)
            print("%s:%d: %s: %s" % (rel, x["range"]["start"]["line"] + 1, x["severity"], x["message"]))
    s = report.get("summary", {})
    print("%s: %d files, %d errors, %d warnings" % (label, s.get("filesAnalyzed", 0), len(errors),
                                                   s.get("warningCount", 0)))
    return 1 if errors else 0


def main():
    if not os.path.isdir(os.path.join(STUBS, "stdlib")):
        print("MicroPython stubs missing in %s: run `make setup`" % STUBS)
        return 2
    common = {"pythonVersion": "3.10", "reportMissingModuleSource": "none",
              "reportAttributeAccessIssue": "error", "reportOptionalMemberAccess": "error"}
    sys.path.insert(0, ROOT)
    from host.board.fwbuild import BOARD_MANIFEST, load_manifest, not_on_board
    board = [e.source for e in load_manifest(BOARD_MANIFEST).entries]
    host_side = [os.path.join(ROOT, "firmware", p) for p in sorted(not_on_board()) if p != "manifest.py"]
    mp = dict(common, include=board, typeshedPath=STUBS, stubPath=STUBS, pythonPlatform="Linux",
              extraPaths=[ROOT])
    # `from micropython import const` under CPython: the stand-in firmware/micropython_standin.py is
    # registered under that name only at run time (firmware/__init__.py), so pyright gets a one-module stub
    # folder holding just MicroPython's micropython.pyi (the rest of .stubs would shadow CPython's time etc.)
    cpython_stubs = os.path.join(STUBS, "cpython-side")
    from typecheck_host import micropython_stub  # this folder is on sys.path: the script's own
    if not micropython_stub():
        return 2
    cp = dict(common, include=host_side, extraPaths=[ROOT], venvPath=ROOT, venv=".venv", stubPath=cpython_stubs)
    rc = run(mp, "board files (firmware/manifest.py) vs MicroPython stubs")
    rc |= run(cp, "files left off the board (CPython)")
    return rc


if __name__ == "__main__":
    sys.exit(main())
