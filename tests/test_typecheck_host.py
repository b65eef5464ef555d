"""tools/typecheck_host.py's hint check (make typecheck): what counts as public, what lacks a hint, and that the
tree it checks has every public function hinted but the files pyproject exempts (pyright itself runs in make
typecheck, not here: it takes minutes)."""
import importlib.util
import os

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
_spec = importlib.util.spec_from_file_location("typecheck_host", os.path.join(ROOT, "tools", "typecheck_host.py"))
typecheck_host = importlib.util.module_from_spec(_spec)
_spec.loader.exec_module(typecheck_host)

SOURCE = '''
def plain(a, b: int = 0):
    def nested(x):  # not public: another module cannot call it
        return x
    return nested(a)


def hinted(a: int, *rest: str, flag: bool = False, **kw: float) -> int:
    return a


def _private(a):
    return a


class Thing:
    def method(self, x: int):
        return x

    def __init__(self, n) -> None:
        self.n = n

    @classmethod
    def make(cls) -> "Thing":
        return cls(0)

    def _helper(self, y):
        return y


class _Hidden:
    def method(self, x):
        return x
'''


def test_missing_hints_names_each_unhinted_parameter_and_return_of_public_functions_only():
    missing = typecheck_host.missing_hints(SOURCE)
    assert missing == [
        "plain (line 2): a, return",
        "Thing.method (line 17): return",
        "Thing.__init__ (line 20): n",
    ]


def test_the_tree_has_every_public_function_hinted_but_the_exempt_files():
    hinted, exempt = typecheck_host.hinted_paths()
    assert set(hinted) >= {"host", "models_export"}
    missing = []
    for path in hinted:
        for rel in typecheck_host.python_files(path):
            if rel not in exempt:
                with open(os.path.join(ROOT, rel), encoding="utf-8") as fh:
                    missing += ["%s: %s" % (rel, m) for m in typecheck_host.missing_hints(fh.read())]
    assert missing == []
    assert all(os.path.exists(os.path.join(ROOT, rel)) for rel in exempt)  # an exemption names a real file
