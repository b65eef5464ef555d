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
    ("channels", "_NO_DATA"): ("drivers", "NO_DATA"),
    ("channels", "_FAULT"): ("drivers", "FAULT"),
    ("ads122c04", "_NO_DATA"): ("drivers", "NO_DATA"),
    ("max31865", "_FAULT"): ("drivers", "FAULT"),
    ("protocol", "_AUTH_BUSY"): ("auth", "BUSY"),
    ("protocol", "_BAD_TAG"): ("auth", "BAD_TAG"),
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


def test_every_kind_code_copy_is_the_tables():
    # the table's kind codes are owned by firmware/table.py; any module's folded _KIND_* copy must agree
    from firmware import table
    checked = 0
    for fn in sorted(os.listdir(FW)):
        if fn.endswith(".py") and fn != "table.py":
            for k, v in consts(fn[:-3]).items():
                if k.startswith("_KIND_"):
                    assert hasattr(table, k[1:]), (fn, k)
                    assert v == getattr(table, k[1:]), (fn, k)
                    checked += 1
    assert checked >= 5  # evaluate.py's three, app.py's two


def test_wire_contract_copies_match_wire_py():
    from firmware import wire
    checked = 0
    for fn in sorted(os.listdir(FW)):
        if fn.endswith(".py") and fn != "wire.py":
            for k, v in consts(fn[:-3]).items():
                if k.startswith("_") and hasattr(wire, k[1:]):
                    assert v == getattr(wire, k[1:]), (fn, k)
                    checked += 1
    assert checked >= 16  # app.py's and safety.py's status bits, protocol.py's version, tag and counter sizes
    # the authorisation's sizes are folded where they are used, on both sides of the check
    for fn in ("auth", "protocol"):
        assert {"_TAG_BYTES", "_MAX_COUNTER"} <= set(consts(fn)), fn


def test_auth_reasons_are_the_wire_contract():
    # E,8,auth,<reason> and Modbus input register 50 (firmware/auth.py REASONS, firmware/wire.py AUTH_REASONS)
    from firmware import auth, wire
    assert [r.decode() for r in auth.REASONS] == list(wire.AUTH_REASONS)
    assert (auth.JUMP, auth.EXHAUSTED) == (wire.AUTH_REASONS.index("counter jump"),
                                           wire.AUTH_REASONS.index("counter exhausted"))


BYTES_CONST = re.compile(r"^(_[A-Z][A-Z0-9_]*) = const\(b\"([^\"]*)\"\)", re.M)


def test_protocol_letters_and_texts_are_the_wire_contract():
    from firmware import wire
    with open(os.path.join(FW, "protocol.py")) as f:
        text = f.read()
    letters = {k[1:]: v for k, v in consts("protocol").items() if len(k) == 2}
    # every one-letter const is a frame kind, a command or an upload step, with its own ASCII code
    assert letters and all(chr(v) == k for k, v in letters.items()), letters
    assert set(letters) == set(wire.FRAME_KINDS) | set(wire.COMMANDS) | set(wire.UPLOAD_STEPS)
    texts = dict(BYTES_CONST.findall(text))
    assert texts["_FIRMWARE_VERSION"].encode() == wire.FIRMWARE_VERSION.encode()
    assert texts["_REF_LETTERS"].encode() == wire.REF_LETTERS
    assert texts["_UPLOAD_STEPS"] == wire.UPLOAD_STEPS  # the U sub-commands the parser knows
    assert not re.search(r"b\"[%s]{2,}\"" % wire.UPLOAD_STEPS, text.replace('_UPLOAD_STEPS = const(b"', "")), \
        "a literal copy of the upload steps outside _UPLOAD_STEPS"
    for name in ("_ONE_POSITION", "_NO_ARGUMENT", "_SIGNED"):  # command groups the parser dispatches on
        group = re.search(r"^%s = b\"(\w+)\"" % name, text, re.M).group(1)
        assert set(group) <= set(wire.COMMANDS), name
        if name == "_SIGNED":
            assert group == wire.SIGNED_COMMANDS


def test_host_signer_sizes_are_the_wire_contract():
    # the host signs with the sizes the board checks (one source: firmware/wire.py)
    from firmware import wire
    from host.board import linkauth
    assert (linkauth.TAG_BYTES, linkauth.MAX_COUNTER) == (wire.TAG_BYTES, wire.MAX_COUNTER)


def test_protocol_does_not_import_app():
    # app.py picks its link (protocol.py or modbus.py); the link takes the contract from wire.py, not app.py
    for fn in ("protocol.py", "modbus.py"):
        with open(os.path.join(FW, fn)) as f:
            assert not re.search(r"^\s*(from firmware\.app import|from firmware import app|import firmware\.app)",
                                 f.read(), re.M), fn


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
        if not fn.endswith(".py") or fn == "linux_adapters.py":
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


def test_no_module_tells_cpython_by_a_failing_micropython_import():
    # firmware/micropython_standin.py (the CPython shim for const) makes `import micropython` succeed on CPython too:
    # a module that must know where it runs asks sys.implementation.name
    for fn in sorted(os.listdir(FW)):
        if fn.endswith(".py"):
            with open(os.path.join(FW, fn)) as f:
                assert not re.search(r"try:\s*\n\s*(import micropython|from micropython import const)\s*\n\s*except",
                                     f.read()), fn


def test_modbus_map_and_error_codes_are_the_wire_contract():
    # the register map, the exception codes and the E-frame codes are owned by firmware/wire.py; the
    # board's folded copies are checked against it above, and none may exist only in a board module
    from firmware import wire
    private = {k for fn in ("modbus", "protocol") for k in consts(fn)
               if re.match(r"_(IR|HR|EX|E|N)_", k) or k in ("_PROTECTED", "_NO_VALUE")}
    assert len(private) >= 40
    missing = sorted(k for k in private if not hasattr(wire, k[1:]))
    assert not missing, "board-only register or error constants (put them in firmware/wire.py): %s" % missing


def test_host_link_users_retype_no_register_or_error_number():
    # the bridge and tcomp monitor address registers and compare error codes by firmware/wire.py's names
    import ast
    registers = {"read_input_registers", "read_holding_registers", "write_registers", "write_register"}
    for rel in ("host/board/linuxcnc/bridge.py", "host/cli/verbs/monitor.py"):
        with open(os.path.join(ROOT, rel)) as f:
            text = f.read()
        for node in ast.walk(ast.parse(text)):
            if isinstance(node, ast.Call) and getattr(node.func, "attr", None) in registers:
                assert not isinstance(node.args[0], ast.Constant), (rel, node.lineno, "register address as a number")
            if isinstance(node, ast.Constant) and isinstance(node.value, str) and node.value.isdigit():
                raise AssertionError("%s line %d: error code %r typed as a number" % (rel, node.lineno, node.value))
        assert not re.search(r"status & 0x[Ff]{4}\b", text), rel  # the sensor bits are wire.SENSOR_MASK
