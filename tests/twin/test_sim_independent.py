"""The twin must not share code with the model it tests: no host/twin module imports host.learning.screw (issue 11)."""
import ast
import os
import subprocess
import sys

import pytest

ROOT = os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__))))
SIM = os.path.join(ROOT, "host", "twin")
FORBIDDEN = ("host.learning",)  # the whole learning room (docs/architecture.md)


def imported_modules(source, package="host.twin"):
    """Absolute names of every module a source imports (relative imports resolved against ``package``)."""
    names = []
    for node in ast.walk(ast.parse(source)):
        if isinstance(node, ast.Import):
            names.extend(a.name for a in node.names)
        elif isinstance(node, ast.ImportFrom):
            base = node.module or ""
            if node.level:
                parts = package.split(".")
                parent = ".".join(parts[: len(parts) - node.level + 1])
                base = parent + ("." + base if base else "")
            names.append(base)
            names.extend(base + "." + a.name for a in node.names)
    return names


def forbidden_in(source):
    return sorted({n for n in imported_modules(source) if any(n == f or n.startswith(f + ".") for f in FORBIDDEN)})


@pytest.mark.parametrize("source", [
    "from host.learning.screw import heat", "import host.learning.screw.heat as h", "from host.learning import screw",
    "from ..learning.screw.heat import simulate_segments", "def f():\n    from host.learning.discrepancy import catalog\n",
])
def test_the_import_check_catches_every_spelling(source):
    assert forbidden_in(source)


def test_no_twin_module_imports_the_model():
    files = sorted(f for f in os.listdir(SIM) if f.endswith(".py"))
    assert "screw.py" in files and "twin.py" in files
    for f in files:
        with open(os.path.join(SIM, f), encoding="utf-8") as fh:
            assert forbidden_in(fh.read()) == [], "host/twin/%s imports the model's code" % f


def test_running_the_twin_loads_no_model_module():
    code = ("import sys, host.twin; host.twin.simulate('mixed', list(host.twin.EFFECTS)); "
            "print(sorted(m for m in sys.modules if m.startswith('host.learning')))")
    out = subprocess.run([sys.executable, "-c", code], cwd=ROOT, capture_output=True, text=True, check=True)
    assert out.stdout.strip() == "[]"
