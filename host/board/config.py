"""Validation of the board config dict (keys and units documented in firmware/board.py).

``load_config(d)`` returns a ``Config`` whose attributes are the validated
values, or raises ValueError naming the key, e.g.
``config channels[3].wires: 5 outside 2..4``. Unknown keys are errors so that
a typo never silently falls back to a default.

This is the friendly validator, run on the host (``tcomp flash --config``,
``tcomp hil --config``) and by the tests, so it lives in host/ (it was
firmware/config.py, a name too close to bootcfg.py). The board runs firmware/bootcfg.py
instead: the same keys, ranges and rules with terse messages (``config
<key>: <value>``), 0.5 kB less .mpy than this module was with the tables;
the key tables live there, so both read the same ranges.
"""

from __future__ import annotations

from typing import Any

from firmware.bootcfg import CHAN as _CHAN, DRIVERS, SERIAL as _SERIAL, TOP as _TOP, Channel, Config


def _err(where, msg):
    return ValueError("config %s: %s" % (where, msg))


def _int(where, v, lo, hi):
    if not isinstance(v, int) or isinstance(v, bool):
        raise _err(where, "expected an integer, got %r" % (v,))
    if v < lo or v > hi:
        raise _err(where, "%d outside %d..%d" % (v, lo, hi))
    return v


def _fill(obj, where, d, spec, extra):
    if not isinstance(d, dict):
        raise _err(where or "top level", "expected a dict")
    keys = [s[0] for s in spec] + list(extra)
    for k in d:
        if k not in keys:
            raise _err(where + k, "unknown key")
    for k, dflt, lo, hi in spec:
        setattr(obj, k, _int(where + k, d.get(k, dflt), lo, hi))


def _channel(i, d):
    w = "channels[%d]." % i
    c = Channel()
    _fill(c, w, d, _CHAN, ("name", "driver", "bus", "cs"))
    for k in ("name", "driver", "bus"):
        if k not in d:
            raise _err(w + k, "missing")
    c.name = d["name"]
    if not isinstance(c.name, str) or not c.name or "," in c.name or "*" in c.name:
        raise _err(w + "name", "expected a non-empty string without ',' or '*'")
    c.driver = d["driver"]
    if c.driver not in DRIVERS:
        raise _err(w + "driver", "%r is not max31865 or ads122c04" % (c.driver,))
    c.bus = d["bus"]
    c.cs = d.get("cs")
    if c.filter_hz not in (50, 60):
        raise _err(w + "filter_hz", "must be 50 or 60")
    if c.driver == "ads122c04" and "idac_ua" in d:
        # the range check above admits any value in 10..1500; the chip has steps, and the driver refuses the
        # others when the board builds the channel, which stops the boot (said here, before anything is flashed)
        from firmware.ads122c04 import IDAC_UA
        if c.idac_ua not in IDAC_UA[1:]:
            raise _err(w + "idac_ua", "%d is not one of the ADS122C04's excitation steps %s uA"
                       % (c.idac_ua, ", ".join(str(v) for v in IDAC_UA[1:])))
    if c.lead_mohm and c.wires != 2:
        raise _err(w + "lead_mohm", "lead correction is for 2-wire sensors (wires=%d)" % c.wires)
    return c


def load_config(d: dict[str, Any]) -> Config:
    cfg = Config()
    _fill(cfg, "", d, _TOP, ("channels", "serial", "plausible_mC", "reference_um", "table_dir"))
    ch = d.get("channels")
    if not isinstance(ch, (list, tuple)) or not 1 <= len(ch) <= 16:
        raise _err("channels", "expected a list of 1..16 channels")
    cfg.channels = [_channel(i, c) for i, c in enumerate(ch)]
    names = [c.name for c in cfg.channels]
    for i in range(len(names)):
        if names[i] in names[:i]:
            raise _err("channels[%d].name" % i, "%r used twice" % names[i])
    s = d.get("serial") or {}
    _fill(cfg, "serial.", s, _SERIAL, ("mode",))
    cfg.modbus_address = cfg.address
    cfg.serial_mode = s.get("mode", "stream")
    if cfg.serial_mode not in ("stream", "modbus"):
        raise _err("serial.mode", "%r is not stream or modbus" % (cfg.serial_mode,))
    p = d.get("plausible_mC", (-20000, 80000))
    if not isinstance(p, (list, tuple)) or len(p) != 2:
        raise _err("plausible_mC", "expected [low, high]")
    cfg.plausible_lo_mC = _int("plausible_mC[0]", p[0], -200000, 850000)
    cfg.plausible_hi_mC = _int("plausible_mC[1]", p[1], -200000, 850000)
    if p[0] >= p[1]:
        raise _err("plausible_mC", "low must be below high")
    r = d.get("reference_um")
    cfg.reference_um = None if r is None else _int("reference_um", r, -100000000, 100000000)
    cfg.table_dir = d.get("table_dir", "tables")
    if not isinstance(cfg.table_dir, str) or not cfg.table_dir:
        raise _err("table_dir", "expected a directory path")
    if cfg.watchdog_ms and cfg.watchdog_ms < 2 * cfg.cycle_ms:
        raise _err("watchdog_ms", "%d is shorter than two cycles (cycle_ms=%d)" % (cfg.watchdog_ms, cfg.cycle_ms))
    return cfg
