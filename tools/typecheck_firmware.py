"""Type-check firmware/ with pyright against the MicroPython stubs in .stubs/ (``make typecheck``).

The Makefile installs micropython-rp2-stubs and micropython-stdlib-stubs into
.stubs/; the latter carries a MicroPython typeshed (.stubs/stdlib) that
replaces CPython's, so a call that exists only on CPython is an error here.
linux_adapters.py is CPython-only (fcntl, ctypes, pyserial, smbus2) and is
checked separately against the ordinary CPython typeshed.

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
CPYTHON_ONLY = ["firmware/linux_adapters.py", "firmware/boards/linux.py"]


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
    mp = dict(common, include=[os.path.join(ROOT, "firmware")],
              exclude=[os.path.join(ROOT, p) for p in CPYTHON_ONLY] + ["**/__pycache__"],
              typeshedPath=STUBS, stubPath=STUBS, pythonPlatform="Linux",
              extraPaths=[ROOT])
    cp = dict(common, include=[os.path.join(ROOT, p) for p in CPYTHON_ONLY], extraPaths=[ROOT],
              venvPath=ROOT, venv=".venv")
    rc = run(mp, "firmware vs MicroPython stubs")
    rc |= run(cp, "CPython-only board adapters")
    return rc


if __name__ == "__main__":
    sys.exit(main())
