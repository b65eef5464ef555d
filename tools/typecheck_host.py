"""Type-check host/ and models_export/ (``make typecheck``, after the firmware's check).

Two checks (pyproject.toml names the folders):
1. every public function of [tool.tcomp.typecheck] ``hinted`` (but the files listed in ``exempt``) has type hints: each parameter (but
   self/cls) and the return. Public means a name without a leading underscore (dunders count) in a
   module or class without one, nested functions aside: what another module may call.
2. pyright (pinned in constraints.txt) in its basic mode over [tool.pyright] ``include`` checks the
   hints against the code and the calls against the hints.

Exit status: 0 when both pass, 1 otherwise (2 if the MicroPython stubs are missing).
"""
import ast
import os
import subprocess
import sys
import tomllib

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
PYRIGHT = os.path.join(ROOT, ".venv", "bin", "pyright")


def hinted_paths():
    """(the files and folders whose public functions must all have hints, the files exempt from it), pyproject.toml."""
    with open(os.path.join(ROOT, "pyproject.toml"), "rb") as fh:
        table = tomllib.load(fh)["tool"]["tcomp"]["typecheck"]
    return table["hinted"], table.get("exempt", [])


def public_functions(source):
    """[(qualified name, FunctionDef)] of the public functions of one module's source."""
    out = []

    def visit(body, prefix):
        for node in body:
            if isinstance(node, ast.ClassDef) and not node.name.startswith("_"):
                visit(node.body, prefix + node.name + ".")
            elif isinstance(node, (ast.FunctionDef, ast.AsyncFunctionDef)):
                dunder = node.name.startswith("__") and node.name.endswith("__")
                if dunder or not node.name.startswith("_"):
                    out.append((prefix + node.name, node))

    visit(ast.parse(source).body, "")
    return out


def missing_hints(source):
    """['name: what lacks a hint'] for one module's source; [] when every public function is hinted."""
    bad = []
    for name, node in public_functions(source):
        a = node.args
        params = a.posonlyargs + a.args + a.kwonlyargs + [p for p in (a.vararg, a.kwarg) if p]
        lacking = [p.arg for p in params if p.annotation is None and p.arg not in ("self", "cls")]
        if node.returns is None:
            lacking.append("return")
        if lacking:
            bad.append("%s (line %d): %s" % (name, node.lineno, ", ".join(lacking)))
    return bad


def python_files(path):
    if path.endswith(".py"):
        yield path
        return
    for here, dirs, files in os.walk(os.path.join(ROOT, path)):
        dirs[:] = sorted(d for d in dirs if d != "__pycache__")
        for f in sorted(files):
            if f.endswith(".py"):
                yield os.path.relpath(os.path.join(here, f), ROOT)


def micropython_stub():
    """.stubs/cpython-side/micropython.pyi, MicroPython's own (make setup installs .stubs), for [tool.pyright]
    stubPath (tools/typecheck_firmware.py's CPython-side check uses it too): the firmware modules host imports say ``from micropython import const``; without the stub the
    constants they define would be Unknown to pyright. False (with the reason printed) when .stubs is missing."""
    stubs = os.path.join(ROOT, ".stubs")
    if not os.path.exists(os.path.join(stubs, "micropython.pyi")):
        print("MicroPython stubs missing in %s: run `make setup`" % stubs)
        return False
    os.makedirs(os.path.join(stubs, "cpython-side"), exist_ok=True)
    with open(os.path.join(stubs, "micropython.pyi"), "rb") as fh:
        data = fh.read()
    target = os.path.join(stubs, "cpython-side", "micropython.pyi")
    if os.path.exists(target):
        with open(target, "rb") as fh:
            if fh.read() == data:
                return True
    # written beside and renamed: make typecheck runs this script and tools/typecheck_firmware.py at once,
    # and either's pyright may be reading the stub while the other installs it
    tmp = "%s.%d.tmp" % (target, os.getpid())
    with open(tmp, "wb") as fh:
        fh.write(data)
    os.replace(tmp, target)
    return True


def main():
    if not micropython_stub():
        return 2
    missing = []
    hinted, exempt = hinted_paths()
    for rel in exempt:
        print("%s: exempt from the hint check (pyproject.toml [tool.tcomp.typecheck] exempt says why)" % rel)
    for path in hinted:
        for rel in python_files(path):
            if rel in exempt:
                continue
            with open(os.path.join(ROOT, rel), encoding="utf-8") as fh:
                missing += ["%s: %s" % (rel, m) for m in missing_hints(fh.read())]
    for m in missing:
        print("%s lacks a type hint" % m)
    print("type hints: %d public functions without full hints" % len(missing))
    p = subprocess.run([PYRIGHT if os.path.exists(PYRIGHT) else "pyright", "-p", os.path.join(ROOT, "pyproject.toml")],
                       cwd=ROOT)
    return 1 if missing or p.returncode else 0


if __name__ == "__main__":
    sys.exit(main())
