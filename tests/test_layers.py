"""The packages form layers (docs/architecture.md): a module imports only its own layer or the ones below,
and no production module imports a test package. Imports are read with ast from every source file,
including imports inside functions."""
import ast
import os

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))

# bottom to top; a package may import its own layer and the layers before it
LAYERS = ("firmware", "models_export", "host")
PRODUCT = set(LAYERS)
TEST_SIDE = ("hil_tests", "tests", "tools")
# No production -> test-side edge: `tcomp hil` reaches the simulated rig through the entry point group
# tcomp.rig (pyproject.toml, host/cli/verbs/hil.py), not by importing hil_tests.


def imports(source):
    """[(imported module, lineno, at module level)] of one source text."""
    tree = ast.parse(source)
    top = {id(node) for node in tree.body}
    out = []
    for node in ast.walk(tree):
        if isinstance(node, ast.Import):
            out += [(a.name, node.lineno, id(node) in top) for a in node.names]
        elif isinstance(node, ast.ImportFrom) and node.module and not node.level:
            out.append((node.module, node.lineno, id(node) in top))
    return out


def violations(module, source):
    """Layer rule breaches of ``module`` (dotted name) with ``source``; [] when it keeps the rules."""
    package = module.partition(".")[0]
    if package not in PRODUCT:
        return []
    allowed = set(LAYERS[:LAYERS.index(package) + 1])
    bad = []
    for name, line, _ in imports(source):
        target = name.partition(".")[0]
        if target in allowed or (target not in PRODUCT and target not in TEST_SIDE):
            continue  # own layer or below, or not one of ours (stdlib, numpy, machine, ...)
        bad.append("%s:%d imports %s" % (module, line, name))
    return bad


def _sources(package):
    for folder, dirs, files in os.walk(os.path.join(ROOT, package)):
        dirs[:] = [d for d in dirs if not d.startswith((".", "__pycache__"))]
        for f in sorted(files):
            if f.endswith(".py"):
                path = os.path.join(folder, f)
                rel = os.path.relpath(path, ROOT)[:-3].replace(os.sep, ".")
                yield rel[:-len(".__init__")] if rel.endswith(".__init__") else rel, path


def test_every_production_module_keeps_to_its_layer():
    bad = []
    for package in LAYERS:
        for module, path in _sources(package):
            with open(path, encoding="utf-8") as fh:
                bad += violations(module, fh.read())
    assert bad == []


def test_the_checker_catches_each_kind_of_breach():
    assert violations("firmware.app", "from host.board.link import STATUS_BITS\n") == ["firmware.app:1 imports host.board.link"]
    assert violations("models_export.export", "def f():\n    from host.learning.documents import x\n") == [
        "models_export.export:2 imports host.learning.documents"]
    assert violations("host.cli.verbs.monitor", "import hil_tests.rig.harness\n") == [
        "host.cli.verbs.monitor:1 imports hil_tests.rig.harness"]
    assert violations("host.x", "from hil_tests.fixtures.samples import screw_doc\n") != []
    # no exception, not even inside a function: the rig is reached by its entry point
    assert violations("host.cli.verbs.hil", "from hil_tests.rig.play import play\n") != []
    assert violations("host.cli.verbs.hil", "def run():\n    from hil_tests.rig.play import play\n") != []
    assert violations("host.learning.empirical.fit", "import numpy\nfrom models_export import export_model\n") == []


def test_tcomp_hil_reaches_the_rig_by_its_entry_point():
    # the group and name host/cli/verbs/hil.py looks up are installed (pyproject.toml's entry point, make
    # setup's editable install), and what it loads offers what the verb uses
    from host.cli.verbs.hil import load_rig
    module = load_rig()
    assert module.__name__ == "hil_tests.rig.entry"
    assert all(callable(getattr(module, name)) for name in ("Rig", "play", "rig_config"))
    assert issubclass(module.RigError, Exception)


# Rooms inside host/ (docs/architecture.md), each with what it may import of ours and of the scientific stack.
# "base" is host's bottom: the package itself (version), errors, options, outputs. A room may import its own
# modules. The board side runs on the controller with the board-side install: no numpy, scipy or matplotlib.
SCIENCE = ("numpy", "scipy", "matplotlib")
BASE = ("host", "host.errors", "host.options", "host.outputs")
HOST_ROOMS = {
    "base": (BASE, ()),
    "host.data": (BASE, SCIENCE),
    "host.twin": (BASE + ("host.data",), SCIENCE),  # never the learning room: the twin must disagree on its own
    "host.learning": (BASE + ("host.data", "models_export", "firmware"), SCIENCE),
    # the run-folder format's names (numpy-free) for the recorder (tcomp record), none of host.data's code
    "host.board": (BASE + ("firmware", "models_export", "host.data.runformat"), ()),
    "host.cli": None,  # the top: any room
}


def host_room(module):
    """The room of a host module: 'base', 'host.data', ..., by its dotted name."""
    parts = module.split(".")
    if module in BASE or len(parts) < 2 or module == "host.__main__":
        return "base" if module != "host.__main__" else "host.cli"
    return "host." + parts[1]


def room_violations(module, source):
    """Room rule breaches of a host module; [] when it keeps them."""
    rule = HOST_ROOMS[host_room(module)]
    if rule is None:
        return []
    allowed, science = rule
    room = host_room(module)
    bad = []
    for name, line, _ in imports(source):
        top = name.partition(".")[0]
        if top == "host":
            ok = host_room(name) == room or name in allowed or any(
                name.startswith(a + ".") for a in allowed if a.startswith("host."))
        elif top in SCIENCE:
            ok = top in science
        elif top in ("models_export", "firmware"):
            ok = top in allowed
        else:
            continue
        if not ok:
            bad.append("%s:%d imports %s" % (module, line, name))
    return bad


def test_every_host_module_keeps_to_its_room():
    bad = []
    for module, path in _sources("host"):
        with open(path, encoding="utf-8") as fh:
            bad += room_violations(module, fh.read())
    assert bad == []


def test_the_room_checker_catches_each_kind_of_breach():
    assert room_violations("host.board.link", "import numpy as np\n") == ["host.board.link:1 imports numpy"]
    assert room_violations("host.board.linuxcnc.bridge", "def f():\n    from host.data.runs import load_run\n") == [
        "host.board.linuxcnc.bridge:2 imports host.data.runs"]
    assert room_violations("host.twin.screw", "from host.learning.screw import heat\n") != []
    assert room_violations("host.learning.screw.heat", "from host.cli import main\n") != []
    assert room_violations("host.errors", "import numpy\n") != []
    assert room_violations("host.data.runs", "from host.errors import UserError\nimport numpy\n") == []
    assert room_violations("host.cli.verbs.fit", "import numpy\nfrom host.twin import simulate_run\n") == []
