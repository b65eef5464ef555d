"""Board config validation: every mistake is a ValueError naming the key."""
import copy

import pytest

from firmware import bootcfg
from host.board.config import load_config
from firmware.boards import rp2040, linux

BASE = {"channels": [{"name": "T1", "driver": "max31865", "bus": "spi0", "cs": 5}]}


def with_(path, value):
    d = copy.deepcopy(BASE)
    cur = d
    for k in path[:-1]:
        cur = cur[k]
    cur[path[-1]] = value
    return d


def test_defaults():
    c = load_config(BASE)
    ch = c.channels[0]
    assert (ch.rref_mohm, ch.wires, ch.lead_mohm, ch.cal_mC, ch.filter_hz) == (430000, 3, 0, 0, 50)
    assert c.serial_mode == "stream" and c.baud == 115200 and c.modbus_address == 1
    assert (c.plausible_lo_mC, c.plausible_hi_mC) == (-20000, 80000)
    assert c.reference_um is None and c.table_dir == "tables"


def test_example_boards_are_valid():
    assert len(load_config(rp2040.CONFIG).channels) == 11
    assert load_config(linux.CONFIG).channels[2].driver == "ads122c04"


@pytest.mark.parametrize("path, value, match", [
    (("channels", 0, "wires"), 5, r"channels\[0\].wires: 5 outside 2..4"),
    (("channels", 0, "driver"), "pt1000", r"channels\[0\].driver"),
    (("channels", 0, "rref_mohm"), 430.0, r"channels\[0\].rref_mohm: expected an integer"),
    (("channels", 0, "filter_hz"), 55, r"filter_hz: must be 50 or 60"),
    (("channels", 0, "lead_mohm"), 500, r"lead_mohm: lead correction is for 2-wire"),
    (("channels", 0, "colour"), 1, r"channels\[0\].colour: unknown key"),
    (("channels", 0, "name"), "a,b", r"channels\[0\].name"),
    (("channels", 0, "address"), 0x20, r"address: 32 outside"),
    (("slew_um_per_s",), True, r"slew_um_per_s: expected an integer"),
    (("max_offset_um",), 0, r"max_offset_um: 0 outside"),
    (("serial",), {"mode": "can"}, r"serial.mode"),
    (("serial",), {"baud": 12}, r"serial.baud"),
    (("serial",), {"parity": "E"}, r"serial.parity: unknown key"),
    (("plausible_mC",), [50000, 0], r"plausible_mC: low must be below high"),
    (("plausible_mC",), [1], r"plausible_mC: expected"),
    (("watchdog_ms",), 150, r"watchdog_ms: 150 is shorter than two cycles"),
    (("table_dir",), "", r"table_dir"),
    (("channelz",), [], r"channelz: unknown key"),
    (("channels",), [], r"channels: expected a list of 1..16"),
])
def test_errors_name_the_key(path, value, match):
    with pytest.raises(ValueError, match=match):
        load_config(with_(path, value))
    # the board's terse check refuses the same config and names the same key
    key = match.split(":")[0]
    with pytest.raises(ValueError, match=r"^config (\S*\.)?" + key):
        bootcfg.load_config(with_(path, value))


def test_missing_and_duplicate():
    d = copy.deepcopy(BASE)
    del d["channels"][0]["bus"]
    with pytest.raises(ValueError, match=r"channels\[0\].bus: missing"):
        load_config(d)
    with pytest.raises(ValueError, match=r"^config channels\[0\].bus: 'missing'"):
        bootcfg.load_config(d)
    d = copy.deepcopy(BASE)
    d["channels"].append(dict(d["channels"][0]))
    with pytest.raises(ValueError, match=r"channels\[1\].name: 'T1' used twice"):
        load_config(d)
    with pytest.raises(ValueError, match=r"^config channels\[1\].name: 'T1'"):
        bootcfg.load_config(d)


@pytest.mark.parametrize("cfg", [BASE, rp2040.CONFIG, linux.CONFIG,
                                 with_(("channels", 0, "wires"), 2), with_(("serial",), {"mode": "modbus", "address": 7}),
                                 with_(("plausible_mC",), [-1000, 1000]), with_(("reference_um",), -5000)])
def test_board_check_gives_the_same_settings(cfg):
    full, terse = load_config(cfg), bootcfg.load_config(cfg)
    chans = [vars(c) for c in full.channels], [vars(c) for c in terse.channels]
    assert chans[0] == chans[1]
    assert {k: v for k, v in vars(full).items() if k != "channels"} == \
        {k: v for k, v in vars(terse).items() if k != "channels"}


@pytest.mark.parametrize("bad", [None, 3, "x", [], {"channels": [3]}, {"channels": [{"name": 1}]},
                                 {"channels": [{"name": "T1", "driver": "max31865", "bus": "s", "wires": None}]},
                                 {"channels": BASE["channels"], "serial": 5},
                                 {"channels": BASE["channels"], "plausible_mC": ["a", 3]},
                                 {"channels": BASE["channels"], "table_dir": 7}])
def test_board_check_refuses_garbage_with_a_value_error(bad):
    # a corrupt config must stop the boot with a named ValueError, never another exception
    with pytest.raises(ValueError, match=r"^config "):
        bootcfg.load_config(bad)

