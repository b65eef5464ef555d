"""Local copies of cross-module constants agree with their source module.

On MicroPython a ``_``-prefixed ``const()`` is folded into the bytecode and
costs no space, but it cannot be imported; modules that need another module's
constant in the cycle (the table kind codes in evaluate.py and app.py) keep a
private copy. This test reads every firmware source and checks each copy
against the module that defines the value, and that the CPython public names
published by table.py and evaluate.py are the folded values.
"""
import os
import re

from fwhelpers import ROOT

FW = os.path.join(ROOT, "firmware")
CONST = re.compile(r"^(_?[A-Z][A-Z0-9_]*) = const\((-?(?:0x[0-9A-Fa-f]+|\d+))\)", re.M)

# copy in (module, private name) -> (source module, public name)
COPIES = {
    ("evaluate", "_KIND_LINEAR_DIRECT"): ("table", "KIND_LINEAR_DIRECT"),
    ("evaluate", "_KIND_SCREW_REDUCED"): ("table", "KIND_SCREW_REDUCED"),
    ("evaluate", "_REF_LATCHED"): ("table", "REF_LATCHED"),
    ("app", "_KIND_SCREW_REDUCED"): ("table", "KIND_SCREW_REDUCED"),
    ("protocol", "_MAX_LINE"): ("frame", "_MAX_LINE"),
    ("protocol", "_LINE_OK"): ("frame", "_LINE_OK"),
    ("protocol", "_LINE_CRC"): ("frame", "_LINE_CRC"),
    ("protocol", "_LINE_OVERFLOW"): ("frame", "_LINE_OVERFLOW"),
    ("protocol", "_TAG_BYTES"): ("auth", "TAG_BYTES"),
    ("protocol", "_MAX_COUNTER"): ("auth", "MAX_COUNTER"),
    ("protocol", "_AUTH_BUSY"): ("auth", "BUSY"),
    ("protocol", "_UNSIGNED"): ("auth", "UNSIGNED"),
    ("modbus", "_UNSIGNED"): ("auth", "UNSIGNED"),
}


def consts(module):
    with open(os.path.join(FW, module + ".py")) as f:
        return {k: int(v, 0) for k, v in CONST.findall(f.read())}


def test_private_copies_match_their_source():
    import importlib
    for (mod, name), (src, public) in COPIES.items():
        here = consts(mod)
        assert name in here, "%s.py no longer defines %s: update COPIES" % (mod, name)
        assert here[name] == getattr(importlib.import_module("firmware." + src), public), (mod, name)


def test_status_bit_copies_match_status_py():
    from firmware import status
    checked = 0
    for fn in sorted(os.listdir(FW)):
        if fn.endswith(".py") and fn != "status.py":
            for k, v in consts(fn[:-3]).items():
                if k.startswith("_") and hasattr(status, k[1:]):
                    assert v == getattr(status, k[1:]), (fn, k)
                    checked += 1
    assert checked >= 11  # app.py and safety.py use their own copies


def test_cpython_public_names_are_the_folded_values():
    from firmware import evaluate, table
    for mod in (evaluate, table):
        defined = consts(mod.__name__.split(".")[1])
        published = [k for k in defined if k.startswith("_")]
        assert len(published) >= 10
        for k in published:
            assert getattr(mod, k[1:]) == defined[k], (mod.__name__, k)


def test_every_cross_module_name_used_on_micropython_is_public():
    # a module imported by firmware code on the board must still define each name it is asked for
    imp = re.compile(r"^\s*from firmware\.(\w+) import ([\w, ]+)$", re.M)
    for fn in os.listdir(FW):
        if not fn.endswith(".py") or fn == "board_linux.py":
            continue
        with open(os.path.join(FW, fn)) as f:
            text = f.read()
        for src, names in imp.findall(text):
            if src == "boards":  # a package of example board files
                continue
            with open(os.path.join(FW, src + ".py")) as f:
                src_text = f.read()
            for n in (x.split()[0] for x in names.split(",")):
                assert re.search(r"^(class |def )?%s\b" % re.escape(n), src_text, re.M), (fn, src, n)
