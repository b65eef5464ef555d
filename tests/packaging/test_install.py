"""The install: what the wheel ships (the product only) and what the board-side install runs without the
scientific stack (pyproject.toml, README "Install", docs/architecture.md "Install and wheel").

The wheel is built once, from a copy of the files a clean clone has (so no stale build/ folder of the
checkout can leak into it), with the dev venv's setuptools (no build isolation: offline and quick).
"""
import os
import shutil
import subprocess
import sys
import zipfile

import pytest

ROOT = os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__))))
PRODUCT = ("host", "models_export", "firmware")
BUILD_FILES = ("pyproject.toml", "setup.py", "README.md", "LICENSE")
# of hil_tests, the wheel holds what `tcomp hil` runs: the rig, the simulated chips, the simulated machine
# module and the rig image's manifest
HIL_SHIPPED_FILES = ("hil_tests/__init__.py", "hil_tests/manifest.py")
HIL_SHIPPED_FOLDERS = ("hil_tests/rig", "hil_tests/sim", "hil_tests/mp")
DIST_INFO = "tcomp-0.1.0.dist-info"
BOARD_VERBS = ("monitor", "linuxcnc", "flash", "record")


def _py_files(folder):
    """Repository-relative paths of the .py files under ``folder`` (no caches)."""
    out = []
    for here, dirs, files in os.walk(os.path.join(ROOT, folder)):
        dirs[:] = [d for d in dirs if d != "__pycache__"]
        out += [os.path.relpath(os.path.join(here, f), ROOT).replace(os.sep, "/") for f in files if f.endswith(".py")]
    return out


def expected_wheel_files():
    """The product's files, by the rules pyproject.toml states."""
    files = set(HIL_SHIPPED_FILES)
    for folder in PRODUCT + HIL_SHIPPED_FOLDERS:
        files.update(_py_files(folder))
    files.update("%s/%s" % (DIST_INFO, name) for name in
                 ("METADATA", "WHEEL", "RECORD", "entry_points.txt", "top_level.txt", "licenses/LICENSE"))
    return files


@pytest.fixture(scope="module")
def wheel(tmp_path_factory):
    """Path of the tcomp wheel built from a copy of the product's and the build's files."""
    tree = tmp_path_factory.mktemp("tree")
    for name in BUILD_FILES:
        shutil.copy(os.path.join(ROOT, name), tree / name)
    for folder in PRODUCT + ("hil_tests",):
        shutil.copytree(os.path.join(ROOT, folder), tree / folder,
                        ignore=shutil.ignore_patterns("__pycache__", "*.pyc", "*.mpy"))
    out = tmp_path_factory.mktemp("wheel")
    res = subprocess.run([sys.executable, "-m", "pip", "wheel", "--no-deps", "--no-build-isolation", "-q",
                          "-w", str(out), str(tree)], capture_output=True, text=True, timeout=600)
    assert res.returncode == 0, res.stderr[-3000:]
    built = [f for f in os.listdir(out) if f.endswith(".whl")]
    assert len(built) == 1, built
    return os.path.join(out, built[0])


def test_the_wheel_ships_the_product_only(wheel):
    names = set(zipfile.ZipFile(wheel).namelist())
    assert names == expected_wheel_files(), (sorted(names - expected_wheel_files()),
                                             sorted(expected_wheel_files() - names))
    # what must never be there, said directly (the expected set's rules could drift)
    assert {n.split("/")[0] for n in names} == {"host", "models_export", "firmware", "hil_tests", DIST_INFO}
    assert not [n for n in names if os.path.basename(n).startswith(("test_", "conftest"))]
    assert not [n for n in names if n.startswith(("hil_tests/fixtures/", "hil_tests/lcnc/", "tests/", "tools/"))]
    assert "micropython.py" not in names
    entry_points = zipfile.ZipFile(wheel).read(DIST_INFO + "/entry_points.txt").decode()
    assert "[tcomp.rig]\nhil = hil_tests.rig.entry" in entry_points and "tcomp = host.cli:main" in entry_points


@pytest.fixture(scope="module")
def board_venv(wheel, tmp_path_factory):
    """bin/ of a fresh virtual environment with only the board-side install (the wheel, no extra)."""
    venv = tmp_path_factory.mktemp("board-venv")
    subprocess.run([sys.executable, "-m", "venv", str(venv)], check=True, timeout=300)
    bin_ = venv / "bin"
    res = subprocess.run([str(bin_ / "pip"), "install", "-q", "--disable-pip-version-check",
                          "-c", os.path.join(ROOT, "constraints.txt"), wheel],
                         capture_output=True, text=True, timeout=900)
    assert res.returncode == 0, res.stderr[-3000:]
    return bin_


def _run(bin_, *argv, cwd):
    return subprocess.run([str(bin_ / argv[0])] + list(argv[1:]), capture_output=True, text=True, timeout=300,
                          cwd=cwd, env={k: v for k, v in os.environ.items() if k != "PYTHONPATH"})


def test_the_board_side_install_runs_the_board_verbs_without_numpy(board_venv, tmp_path):
    for verb in BOARD_VERBS:
        res = _run(board_venv, "tcomp", verb, "--help", cwd=tmp_path)
        assert res.returncode == 0 and res.stdout.startswith("usage: tcomp %s" % verb), (verb, res.stderr)
    res = _run(board_venv, "tcomp", "--help", cwd=tmp_path)
    assert res.returncode == 0 and "simulate" in res.stdout, res.stderr
    # record's run imports (link client, run writer, the run format's names) reach the port without numpy
    res = _run(board_venv, "tcomp", "record", "--port", "nosuch://x", "--out", str(tmp_path / "rec"), "--sensor",
               "T1=nut", cwd=tmp_path)
    assert res.returncode == 2 and res.stderr.strip() == "tcomp record: error: cannot open nosuch://x: invalid URL, " \
        "protocol 'nosuch' not known", res.stderr
    for module in ("numpy", "scipy", "matplotlib", "micropython"):
        res = _run(board_venv, "python", "-c", "import " + module, cwd=tmp_path)
        assert res.returncode == 1 and "ModuleNotFoundError" in res.stderr, module
    # the firmware's const() still reaches it under CPython, without a top-level micropython module
    res = _run(board_venv, "python", "-c", "import firmware.wire, sys; print(sys.modules['micropython'].__name__)",
               cwd=tmp_path)
    assert res.returncode == 0 and res.stdout.strip() == "firmware.micropython_standin", res.stderr


def test_a_verb_of_the_science_extra_names_the_extra_to_install(board_venv, tmp_path):
    # their --help parses without numpy (the verbs import it in run()); running them names the extra
    for argv in (("validate", os.path.join(ROOT, "data", "fl_thermal")), ("simulate", "--out", str(tmp_path / "x"))):
        res = _run(board_venv, "tcomp", *argv, cwd=tmp_path)
        assert res.returncode == 2, (argv, res.stdout, res.stderr)
        assert "pip install 'tcomp[science]'" in res.stderr and "Traceback" not in res.stderr, res.stderr
