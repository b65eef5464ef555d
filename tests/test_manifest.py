"""One manifest says what goes on the board (firmware/manifest.py, built by host/board/fwbuild.py).

Every firmware file is either listed or explicitly left off; the loader follows MicroPython's
manifest API without importing firmware; the build is one option set in a content-keyed cache; and
`tcomp flash`, the firmware tests, the export tests and the HIL rig all get the same .mpy bytes.
"""
import ast
import os
import shutil

import pytest

from host.board import fwbuild
from host.board.fwbuild import BOARD_MANIFEST, BuildError, build, load_manifest, not_on_board

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))


def unlisted(fw_dir):
    """Files of ``fw_dir`` (a firmware/ folder) that its manifest neither lists nor leaves off on
    purpose, and NOT_ON_BOARD entries that name no file or a listed one."""
    manifest = os.path.join(fw_dir, "manifest.py")
    boards = load_manifest(manifest).names[os.path.abspath(manifest)]["BOARD_FILES"]
    listed = {e.target[len("firmware/"):] for e in load_manifest(manifest, boards=boards).entries}
    excluded = set(not_on_board(manifest))
    present = set()
    for folder, dirs, names in os.walk(fw_dir):
        dirs[:] = [d for d in dirs if d != "__pycache__"]
        present |= {os.path.relpath(os.path.join(folder, n), fw_dir).replace(os.sep, "/")
                    for n in names if n.endswith(".py")}
    return sorted(present - listed - excluded), sorted((excluded - present) | (excluded & listed))


def test_every_firmware_file_is_on_the_board_or_left_off_on_purpose():
    missing, stale = unlisted(os.path.join(ROOT, "firmware"))
    assert missing == [], "firmware files neither in firmware/manifest.py nor in its NOT_ON_BOARD: %s" % missing
    assert stale == [], "NOT_ON_BOARD entries that are no file or are listed anyway: %s" % stale


def test_the_unlisted_check_catches_a_new_module(tmp_path):
    fw = tmp_path / "firmware"
    shutil.copytree(os.path.join(ROOT, "firmware"), fw, ignore=shutil.ignore_patterns("__pycache__"))
    missing, stale = unlisted(str(fw))  # the checkout's own state (the test above judges it)
    (fw / "newdriver.py").write_text("X = 1\n")
    (fw / "boards" / "stm32.py").write_text("X = 1\n")
    os.remove(fw / "wire.py")  # a left-off file that no longer exists is a stale entry
    assert unlisted(str(fw)) == (sorted(missing + ["boards/stm32.py", "newdriver.py"]), sorted(stale + ["wire.py"]))
    # a board file is listed by naming it in BOARD_FILES (shipped when the boards option asks for it)
    text = (fw / "manifest.py").read_text().replace("BOARD_FILES = (", 'BOARD_FILES = ("stm32", ', 1)
    (fw / "manifest.py").write_text(text)
    assert unlisted(str(fw)) == (sorted(missing + ["newdriver.py"]), sorted(stale + ["wire.py"]))
    assert "firmware/boards/stm32.py" in {e.target for e in load_manifest(str(fw / "manifest.py"), boards=("stm32",)).entries}


def test_the_manifest_is_not_board_code():
    """No firmware module imports it, and it is not in any build."""
    for folder, _, names in os.walk(os.path.join(ROOT, "firmware")):
        for n in names:
            if n.endswith(".py"):
                with open(os.path.join(folder, n), encoding="utf-8") as f:
                    tree = ast.parse(f.read())
                for node in ast.walk(tree):
                    if isinstance(node, ast.ImportFrom):
                        assert node.module != "firmware.manifest" and not (
                            node.module == "firmware" and any(a.name == "manifest" for a in node.names)), n
                    elif isinstance(node, ast.Import):
                        assert all(a.name != "firmware.manifest" for a in node.names), n
    for manifest in (BOARD_MANIFEST, os.path.join(ROOT, "hil_tests", "manifest.py"),
                     os.path.join(ROOT, "tests", "firmware", "manifest.py")):
        assert "firmware/manifest.py" not in [e.target for e in load_manifest(manifest).entries]


def test_serial_modes_and_drivers_select_modules():
    def targets(**options):
        return {e.target for e in load_manifest(BOARD_MANIFEST, **options).entries}

    every = targets()
    stream, modbus = targets(serial="stream"), targets(serial="modbus")
    assert {"firmware/protocol.py", "firmware/frame.py", "firmware/modbus.py"} <= every
    assert "firmware/modbus.py" not in stream and "firmware/protocol.py" in stream
    assert "firmware/protocol.py" not in modbus and "firmware/frame.py" not in modbus
    assert stream | modbus == every
    only_max = targets(drivers=("max31865",))
    assert "firmware/max31865.py" in only_max and "firmware/ads122c04.py" not in only_max
    # the manifest's default drivers are the firmware's driver table (drivers.py: module per name)
    from firmware.drivers import DRIVERS
    assert {t for t in every if t[len("firmware/"):-3] in DRIVERS} == {"firmware/%s.py" % d for d in DRIVERS}
    assert "firmware/boards/rp2040.py" in every and "firmware/boards/rp2040.py" not in targets(boards=())
    with pytest.raises(BuildError, match="boards: 'pico' is not one of rp2040"):
        load_manifest(BOARD_MANIFEST, boards=("pico",))
    with pytest.raises(BuildError, match="serial must be stream or modbus"):
        load_manifest(BOARD_MANIFEST, serial="rtu")
    with pytest.raises(BuildError, match="firmware/pt1000.py: listed in .* does not exist"):
        load_manifest(BOARD_MANIFEST, drivers=("pt1000",))


def test_loader_follows_the_manifest_api(tmp_path):
    (tmp_path / "pkg" / "sub").mkdir(parents=True)
    for rel in ("pkg/a.py", "pkg/sub/b.py", "pkg/notes.txt", "top.py"):
        (tmp_path / rel).write_text("X = 1\n")
    (tmp_path / "inner").mkdir()
    (tmp_path / "inner" / "manifest.py").write_text(
        "options.defaults(extra=False)\nmetadata(description='inner')\n"
        "module('top.py', base_path='..')\nif options.extra:\n    package('pkg', files=['a.py'], base_path='..')\n")
    (tmp_path / "manifest.py").write_text(
        "metadata(description='outer', version='1')\ninclude('inner', extra=True)\ninclude('inner/manifest.py')\n"
        "package('pkg')\nSKIP = {'x': 'why'}\n")
    m = load_manifest(str(tmp_path / "manifest.py"))
    # include runs a folder's manifest.py once, with the options given; package() walks .py files
    assert [e.target for e in m.entries] == ["top.py", "pkg/a.py", "pkg/sub/b.py"]
    assert [e.module for e in m.entries] == ["top", "pkg.a", "pkg.sub.b"]
    assert m.metadata == {"description": "outer", "version": "1"}
    assert m.names[str(tmp_path / "manifest.py")] == {"SKIP": {"x": "why"}}
    (tmp_path / "req.py").write_text("require('aioble')\n")
    with pytest.raises(BuildError, match="require\\('aioble'\\): micropython-lib packages are not part"):
        load_manifest(str(tmp_path / "req.py"))
    (tmp_path / "twice.py").write_text("module('top.py')\nmodule('top.py', base_path='pkg/..', opt=0)\n")
    with pytest.raises(BuildError, match="top.py: listed twice"):
        load_manifest(str(tmp_path / "twice.py"))
    (tmp_path / "bad.py").write_text("module('top.py')\nundefined_call()\n")
    with pytest.raises(BuildError, match="bad.py: NameError"):
        load_manifest(str(tmp_path / "bad.py"))


def test_build_is_keyed_by_content_and_leaves_nothing_half_built(tmp_path):
    fw = tmp_path / "src" / "firmware"
    shutil.copytree(os.path.join(ROOT, "firmware"), fw, ignore=shutil.ignore_patterns("__pycache__"))
    cache = tmp_path / "cache"
    first = build(str(fw / "manifest.py"), cache=str(cache))
    again = build(str(fw / "manifest.py"), cache=str(cache))
    assert again.root == first.root and sorted(os.listdir(cache)) == [os.path.basename(first.root)]
    before = {t: open(p, "rb").read() for t, p in first.files}
    with open(fw / "rtd.py", "a") as f:
        f.write("\n_NEW = 1\n")
    changed = build(str(fw / "manifest.py"), cache=str(cache))
    assert changed.root != first.root
    after = {t: open(p, "rb").read() for t, p in changed.files}
    assert [t for t in before if before[t] != after[t]] == ["firmware/rtd.mpy"]
    with open(fw / "rtd.py", "a") as f:
        f.write("def broken(:\n")
    with pytest.raises(BuildError, match="mpy-cross failed on .*rtd.py"):
        build(str(fw / "manifest.py"), cache=str(cache))
    assert sorted(os.listdir(cache)) == sorted([os.path.basename(first.root), os.path.basename(changed.root)])


def test_the_build_does_not_depend_on_where_the_checkout_is(tmp_path):
    """The source name in each .mpy is its board path (mpy-cross -s), so another checkout or an
    installed wheel builds the same bytes."""
    fw = tmp_path / "elsewhere" / "firmware"
    shutil.copytree(os.path.join(ROOT, "firmware"), fw, ignore=shutil.ignore_patterns("__pycache__"))
    here = build(cache=str(tmp_path / "c1"))
    there = build(str(fw / "manifest.py"), cache=str(tmp_path / "c2"))
    assert os.path.basename(here.root) == os.path.basename(there.root)
    for (t, p), (t2, p2) in zip(here.files, there.files):
        data = open(p, "rb").read()
        assert t == t2 and data == open(p2, "rb").read() and ROOT.encode() not in data
    # one option set: no manifest of ours overrides it for a file
    assert fwbuild.MPY_CROSS_ARGS == ("-O3",)
    for manifest in (BOARD_MANIFEST, os.path.join(ROOT, "hil_tests", "manifest.py"),
                     os.path.join(ROOT, "tests", "firmware", "manifest.py")):
        assert [e.target for e in load_manifest(manifest).entries if e.opt is not None] == []


def test_flash_tests_and_rig_get_the_same_firmware_bytes(tmp_path):
    """`tcomp flash` stages exactly the board build; the firmware tests', the export tests' and the
    HIL rig's builds hold the same firmware files, byte for byte."""
    import sys
    sys.path.insert(0, os.path.join(ROOT, "tests", "firmware"))
    try:
        from fwhelpers import compile_mpy
    finally:
        sys.path.pop(0)
    from hil_tests.rig.mpybuild import rig_build
    from host.cli.verbs.flash import stage
    from host.board.fwbuild import BOOT_MAIN

    board = {t: open(p, "rb").read() for t, p in build().files}
    files, _ = stage(str(tmp_path))
    staged = {os.path.relpath(p, tmp_path): open(p, "rb").read() for ps in files.values() for p in ps}
    assert staged.pop("main.py") == BOOT_MAIN
    assert staged == board
    for root in (compile_mpy(), compile_mpy(fakes=True), rig_build().root):
        for t in board:
            with open(os.path.join(root, t), "rb") as f:
                assert f.read() == board[t], (root, t)
    rig = {t for t, _ in rig_build().files}
    assert set(board) < rig and {t for t in rig - set(board)} == {
        t for t in rig if t.startswith("hil_tests/")}


def test_board_modules_for_a_freezer():
    mods = fwbuild.board_modules(serial="stream", drivers=("max31865",))
    names = [m for m, _ in mods]
    assert names[0] == "firmware.main" and "firmware.boards" in names and "firmware.boards.rp2040" in names
    assert "firmware.protocol" in names and "firmware.modbus" not in names and "firmware.ads122c04" not in names
    for m, p in mods:
        assert p.endswith(m.replace(".", "/") + ("/__init__.mpy" if m == "firmware.boards" else ".mpy")), (m, p)
    assert all(open(p, "rb").read(1) == b"M" for _, p in mods)  # .mpy files (header byte 'M')
