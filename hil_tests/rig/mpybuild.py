"""The rig's .mpy files: hil_tests/manifest.py (the board's firmware as firmware/manifest.py lists it,
plus the simulation) built by host/board/fwbuild.py, the builder `tcomp flash` ships from.

The unix port compiling .py at import needs several times the heap the code itself takes; a board
ships .mpy for the same reason. The build lives in the shared content-keyed cache (host/board/fwbuild.py),
so the firmware files the rig runs are byte for byte the ones `tcomp flash` copies to a board.
"""
import os

from host.board.fwbuild import build

ROOT = os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__))))
MANIFEST = os.path.join(ROOT, "hil_tests", "manifest.py")

_BUILDS = {}


def rig_build():
    """The rig's Build (compiled once per process; rebuilt only when a source changed)."""
    if "rig" not in _BUILDS:
        _BUILDS["rig"] = build(MANIFEST)
    return _BUILDS["rig"]
