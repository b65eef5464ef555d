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
# The one production -> test-side edge: `tcomp hil` drives the simulated rig that lives with the HIL
# tests. It is imported inside run(), so no other verb (nor `tcomp --help`) loads the rig.
LAZY_EXCEPTIONS = {("host.commands.hil", "hil_tests.rig")}


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
    for name, line, at_top in imports(source):
        target = name.partition(".")[0]
        if target in allowed or (target not in PRODUCT and target not in TEST_SIDE):
            continue  # own layer or below, or not one of ours (stdlib, numpy, machine, ...)
        exception = any(module == m and (name == t or name.startswith(t + ".")) for m, t in LAZY_EXCEPTIONS)
        if exception and not at_top:
            continue
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
    assert violations("firmware.app", "from host.link import STATUS_BITS\n") == ["firmware.app:1 imports host.link"]
    assert violations("models_export.export", "def f():\n    from host.models import x\n") == [
        "models_export.export:2 imports host.models"]
    assert violations("host.commands.monitor", "import hil_tests.rig.harness\n") == [
        "host.commands.monitor:1 imports hil_tests.rig.harness"]
    assert violations("host.x", "from hil_tests.fixtures.samples import screw_doc\n") != []
    # the exception is lazy only: at module level it is a breach too
    assert violations("host.commands.hil", "from hil_tests.rig.play import play\n") != []
    assert violations("host.commands.hil", "def run():\n    from hil_tests.rig.play import play\n") == []
    assert violations("host.empirical.fit", "import numpy\nfrom models_export import export_model\n") == []


def test_the_lazy_exception_is_still_needed():
    for module, target in LAZY_EXCEPTIONS:
        with open(os.path.join(ROOT, *module.split(".")) + ".py", encoding="utf-8") as fh:
            names = [name for name, _, at_top in imports(fh.read())]
        assert any(n == target or n.startswith(target + ".") for n in names), (module, target)
