"""The image's freezer: compile the manifest's modules with mpy-cross into a C ROM table.

    python ports/mps2/freeze.py --set firmware|rig --mpy-cross PATH --out romfs.c

MicroPython's own freezing (tools/mpy-tool.py) is not in the core source tcomp builds on,
so the image carries the .mpy files themselves in a table (path, bytes) that the port's
import hooks (files.c) serve from flash: the loader reads them with MP_READER_IS_ROM, so
bytecode, strings and bytes run in place and only the objects (functions, classes, dicts)
take heap, as with stock frozen modules.

``firmware``: the modules firmware/manifest.py lists (its micropython-lib style calls
``module``, ``package``, ``include``, ``metadata``, ``options``; ``require`` of a
micropython-lib package is refused: the board needs none) plus this image's board file
firmware/boards/mps2_an385.py. ``rig``: that plus the HIL rig's board side (the chip
simulators, the control channel and the launcher), for ``tcomp hil --interpreter qemu``.
"""
import argparse
import os
import subprocess
import sys
import tempfile

PORT = os.path.dirname(os.path.abspath(__file__))
ROOT = os.path.dirname(os.path.dirname(PORT))
MANIFEST = os.path.join(ROOT, "firmware", "manifest.py")
BOARD_FILE = ("firmware/boards/mps2_an385.py", "firmware/boards/__init__.py")
RIG_DIRS = ("hil_tests/sim",)
RIG_FILES = ("hil_tests/__init__.py", "hil_tests/rig/__init__.py", "hil_tests/rig/dut.py",
             "hil_tests/rig/qemu_board.py", "hil_tests/rig/minijson.py")


class ManifestError(Exception):
    pass


def read_manifest(path):
    """[(source file, path in the image, opt)] from a micropython-lib style manifest."""
    out = []
    state = {"opt": None}

    def here():
        return os.path.dirname(os.path.abspath(path))

    def base(base_path):
        return os.path.normpath(os.path.join(here(), base_path))

    def module(module_path, base_path=".", opt=None):
        src = os.path.join(base(base_path), module_path)
        if not os.path.isfile(src):
            raise ManifestError("%s: module %s not found" % (path, src))
        out.append((src, module_path, opt if opt is not None else state["opt"]))

    def package(package_path, files=None, base_path=".", opt=None):
        top = os.path.join(base(base_path), package_path)
        if files is None:
            files = []
            for d, _, names in os.walk(top):
                files += [os.path.relpath(os.path.join(d, n), top) for n in sorted(names) if n.endswith(".py")]
        for f in files:
            src = os.path.join(top, f)
            if not os.path.isfile(src):
                raise ManifestError("%s: %s not found" % (path, src))
            out.append((src, os.path.join(package_path, f).replace(os.sep, "/"),
                        opt if opt is not None else state["opt"]))

    def include(manifest_path, **kw):
        out.extend(read_manifest(base(manifest_path)))

    def require(name, **kw):
        raise ManifestError("%s: require(%r): the mps2 image has no micropython-lib" % (path, name))

    def options(**kw):
        pass

    def metadata(**kw):
        pass

    def freeze(*a, **kw):
        raise ManifestError("%s: freeze() is the old manifest style; use module()/package()" % path)

    with open(path) as f:
        src = f.read()
    g = {"module": module, "package": package, "include": include, "require": require,
         "metadata": metadata, "options": options, "freeze": freeze, "__file__": path}
    exec(compile(src, path, "exec"), g)
    return out


def modules(which):
    mods = read_manifest(MANIFEST) if os.path.exists(MANIFEST) else _interim_list()
    have = {m[1] for m in mods}
    for rel in BOARD_FILE:
        if rel not in have:
            mods.append((os.path.join(ROOT, rel), rel, None))
    if which == "rig":
        for d in RIG_DIRS:
            for n in sorted(os.listdir(os.path.join(ROOT, d))):
                if n.endswith(".py"):
                    mods.append((os.path.join(ROOT, d, n), d + "/" + n, 0))
        for rel in RIG_FILES:
            mods.append((os.path.join(ROOT, rel), rel, 0))
    return mods


def _interim_list():
    """Until firmware/manifest.py exists: every board-side firmware module (not the CPython adapters)."""
    out = []
    for n in sorted(os.listdir(os.path.join(ROOT, "firmware"))):
        if n.endswith(".py") and n != "linux_adapters.py":
            out.append((os.path.join(ROOT, "firmware", n), "firmware/" + n, None))
    return out


def compile_all(mods, cross, work):
    table = []
    for src, rel, opt in mods:
        dest = os.path.join(work, rel[:-3] + ".mpy")
        os.makedirs(os.path.dirname(dest), exist_ok=True)
        argv = [cross, "-o", dest, "-s", rel]
        if opt:
            argv.append("-O%d" % opt)
        p = subprocess.run(argv + [src], capture_output=True, text=True)
        if p.returncode != 0:
            raise ManifestError("mpy-cross %s: %s" % (rel, p.stderr.strip()))
        with open(dest, "rb") as f:
            table.append((rel[:-3] + ".mpy", f.read()))
    return table


def emit(table, out):
    lines = ["// Generated by ports/mps2/freeze.py: the image's .mpy files, run in place.",
             '#include "romfs.h"', ""]
    for i, (_, data) in enumerate(table):
        body = ",".join(str(b) for b in data)
        lines.append("static const uint8_t rom_%d[%d] __attribute__((aligned(4))) = {%s};" % (i, len(data), body))
    lines.append("const mps2_rom_file_t mps2_rom_files[] = {")
    for i, (path, data) in enumerate(table):
        lines.append('    {"%s", rom_%d, %d},' % (path, i, len(data)))
    lines.append("};")
    lines.append("const size_t mps2_rom_count = %d;" % len(table))
    text = "\n".join(lines) + "\n"
    if os.path.exists(out):
        with open(out) as f:
            if f.read() == text:
                return  # unchanged: keep the timestamp, no relink
    tmp = out + ".tmp"
    with open(tmp, "w") as f:
        f.write(text)
    os.replace(tmp, out)


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--set", choices=("firmware", "rig"), default="firmware")
    ap.add_argument("--mpy-cross", default="mpy-cross")
    ap.add_argument("--out", required=True)
    ap.add_argument("--list", action="store_true", help="print the image's paths and sizes")
    a = ap.parse_args(argv)
    try:
        mods = modules(a.set)
        with tempfile.TemporaryDirectory() as work:
            table = compile_all(mods, a.mpy_cross, work)
    except ManifestError as e:
        print("freeze.py: %s" % e, file=sys.stderr)
        return 2
    os.makedirs(os.path.dirname(os.path.abspath(a.out)), exist_ok=True)
    emit(table, a.out)
    if a.list:
        for path, data in table:
            print("%6d %s" % (len(data), path))
    return 0


if __name__ == "__main__":
    sys.exit(main())
