"""The verb registry (host/cli/verbs/__init__.py): `tcomp --help` imports no verb module, every verb resolves."""
import importlib
import os
import subprocess
import sys

from host.cli.verbs import VERBS

ROOT = os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__))))

# A fresh interpreter: the test process has long since imported every verb module.
_PROBE = """
import sys
from host.cli import main
try:
    main(%r)
except SystemExit:
    pass
print("LOADED:" + ",".join(sorted(m for m in sys.modules if m.startswith("host.cli.verbs."))))
"""


def _loaded_after(argv):
    out = subprocess.run([sys.executable, "-c", _PROBE % (argv,)], cwd=ROOT, capture_output=True, text=True,
                         check=True).stdout
    loaded = out.rpartition("LOADED:")[2].strip()
    return loaded.split(",") if loaded else []


def test_help_imports_no_verb_module():
    assert _loaded_after(["--help"]) == []


def test_a_verb_imports_only_its_own_module():
    # the probe itself must be able to see an import: `tcomp import --help` loads exactly one module
    assert _loaded_after(["import", "--help"]) == ["host.cli.verbs.importlog"]


def test_every_verb_module_has_arguments_and_run_and_every_module_is_registered():
    for verb, (module_name, summary) in VERBS.items():
        module = importlib.import_module(module_name)
        assert callable(module.add_arguments) and callable(module.run), verb
        assert summary and "\n" not in summary, verb
    files = {f[:-3] for f in os.listdir(os.path.join(ROOT, "host", "cli", "verbs"))
             if f.endswith(".py") and not f.startswith("_")}
    assert files == {m.rpartition(".")[2] for m, _ in VERBS.values()}
