"""examples/boards/: one board.json per board the firmware supports, each valid for the host's check and the
board's boot check, on buses its board offers; docs/board-config.md documents every configuration key.
(The rig's examples are also booted: hil_tests/test_hil_board.py.)"""
import ast
import json
import os
import re

import pytest

from firmware import bootcfg
from host.board.config import load_config

ROOT = os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__))))
EXAMPLES = os.path.join(ROOT, "examples", "boards")
BOARDS = os.path.join(ROOT, "firmware", "boards")
# the rig's board (hil_tests/rig/boards.py, tcomp board / tcomp hil on the 32-bit port) is one more board
RIG_BOARDS = {"rig"}


def _board_files():
    return sorted(n[:-3] for n in os.listdir(BOARDS) if n.endswith(".py") and n != "__init__.py")


def _examples():
    return sorted(n[:-5] for n in os.listdir(EXAMPLES) if n.endswith(".json"))


def test_one_example_per_supported_board():
    assert _examples() == sorted(set(_board_files()) | RIG_BOARDS)


def _buses_of(board):
    """The bus names a board file's make_board hands the firmware (a dict literal of string keys), None when
    the board takes them from its caller (the rig's simulated chips, Linux device paths)."""
    tree = ast.parse(open(os.path.join(BOARDS, board + ".py")).read())
    for node in ast.walk(tree):
        if isinstance(node, ast.Call) and getattr(node.func, "id", None) == "Board" and len(node.args) >= 2:
            buses = node.args[1]
            if isinstance(buses, ast.Dict) and all(isinstance(k, ast.Constant) for k in buses.keys):
                return {k.value for k in buses.keys}
    return None


@pytest.mark.parametrize("name", _examples())
def test_example_is_valid_on_host_and_board(name):
    cfg = json.load(open(os.path.join(EXAMPLES, name + ".json")))
    host = load_config(cfg)
    board = bootcfg.load_config(cfg)
    assert [c.name for c in host.channels] == [c.name for c in board.channels]
    buses = {c["bus"] for c in cfg["channels"]}
    if name in RIG_BOARDS or name == "mps2_an385":
        # hil_tests/sim/world.py builds spiN / i2cN for the chips the channels name
        assert all(re.fullmatch(r"(spi|i2c)\d+", b) for b in buses), buses
        assert all((c["driver"] == "max31865") == c["bus"].startswith("spi") for c in cfg["channels"])
    elif name == "linux":
        assert all(c["bus"].startswith("/dev/spidev") and "cs" not in c for c in cfg["channels"]
                   if c["driver"] == "max31865")
        assert all(c["bus"].startswith("/dev/i2c-") for c in cfg["channels"] if c["driver"] == "ads122c04")
    else:
        offered = _buses_of(name)
        assert offered and buses <= offered, (buses, offered)
    for c in cfg["channels"]:  # the ADS122C04's excitation is one of its datasheet steps (the driver refuses others)
        if c["driver"] == "ads122c04":
            from firmware.ads122c04 import IDAC_UA
            assert c.get("idac_ua", 250) in IDAC_UA[1:]


def _documented_keys():
    text = open(os.path.join(ROOT, "docs", "board-config.md"), encoding="utf-8").read()
    sections = re.split(r"^## ", text, flags=re.M)
    out = {}
    for sec in sections:
        title = sec.splitlines()[0].strip()
        out[title] = set(re.findall(r"^\| `([a-z_A-Z]+)` \|", sec, flags=re.M))
    return out


def test_every_configuration_key_is_documented():
    doc = _documented_keys()
    top = {k for k, *_ in bootcfg.TOP} | set(bootcfg.TOP_MORE)
    chan = {k for k, *_ in bootcfg.CHAN} | set(bootcfg.CHAN_MORE)
    serial = {k for k, *_ in bootcfg.SERIAL} | {"mode"}
    assert doc["Top level"] == top
    assert doc["`channels[i]`"] == chan
    assert doc["`serial`"] == serial


def test_documented_defaults_are_the_boot_checks():
    """Each integer key's default and range as docs/board-config.md states them (digits only, spaces dropped)."""
    text = open(os.path.join(ROOT, "docs", "board-config.md"), encoding="utf-8").read()
    for table in (bootcfg.TOP, bootcfg.CHAN, bootcfg.SERIAL):
        for key, default, lo, hi in table:
            rows = [line for line in text.splitlines() if line.startswith("| `%s` |" % key)]
            assert rows, key
            cells = [c.strip() for c in rows[-1 if key == "address" and table is bootcfg.SERIAL else 0].split("|")]
            default_cell = cells[4].replace(" ", "").replace("\u202f", "")
            assert str(default) in default_cell or hex(default) in default_cell, (key, default, cells[4])
            range_cell = cells[5].replace(" ", "")
            assert str(lo) in range_cell.replace("\u2212", "-"), (key, lo, cells[5])
            assert str(hi) in range_cell, (key, hi, cells[5])


def test_host_check_refuses_an_excitation_between_the_chips_steps():
    """idac_ua 300 passes the 10..1500 range but the ADS122C04 has steps: the board's driver would stop the boot;
    the host check says so before anything is flashed. A MAX31865 channel ignores the key."""
    cfg = json.load(open(os.path.join(EXAMPLES, "rig.json")))
    cfg["channels"][2]["idac_ua"] = 300
    with pytest.raises(ValueError, match=r"channels\[2\]\.idac_ua: 300 is not one of the ADS122C04's excitation "
                                         r"steps 10, 50, 100, 250, 500, 1000, 1500 uA"):
        load_config(cfg)
    cfg["channels"][2]["idac_ua"] = 1000
    assert load_config(cfg).channels[2].idac_ua == 1000
