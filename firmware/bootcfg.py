"""The board's boot-time config check: every rule of host/board/config.py, terse messages.

The friendly validator (``host.board.config.load_config``: messages that state
the rule) runs on the host, in ``tcomp flash --config`` and ``tcomp hil
--config``; the board imports only this module (and drops it after boot), so
its flash and RAM do not pay for the explanations. It still refuses every bad
config the friendly one refuses, with ``ValueError("config <key>: <value>")``
naming the key (tests/firmware/test_fw_config.py holds both to the same
cases), so a corrupt config never crashes the firmware nor yields an offset.
The key tables are shared: host/board/config.py imports them from here, and the
driver names come from the driver table, firmware/drivers.py.
"""
from firmware.drivers import DRIVERS

# (key, default, lo, hi)
TOP = (
    ("max_rate_mC_per_s", 2000, 1, 1000000),
    ("stuck_ms", 0, 0, 86400000),
    ("slew_um_per_s", 5, 1, 10000),
    ("max_offset_um", 300, 1, 100000),
    ("hold_ms", 60000, 0, 86400000),
    ("cycle_ms", 100, 1, 60000),
    ("frame_ms", 1000, 0, 3600000),
    ("watchdog_ms", 2000, 0, 8388),
    ("link_timeout_ms", 0, 0, 65535),
    ("max_speed_mm_min", 120000, 0, 1000000),
)
CHAN = (
    ("rref_mohm", 430000, 100000, 10000000),
    ("wires", 3, 2, 4),
    ("lead_mohm", 0, 0, 50000),
    ("cal_mC", 0, -10000, 10000),
    ("filter_hz", 50, 50, 60),
    ("idac_ua", 250, 10, 1500),
    ("address", 0x40, 0x40, 0x4F),
)
SERIAL = (("baud", 115200, 1200, 4000000), ("address", 1, 1, 247))
TOP_MORE = ("channels", "serial", "plausible_mC", "reference_um", "table_dir")
CHAN_MORE = ("name", "driver", "bus", "cs")
MODES = ("stream", "modbus")
PLAUSIBLE = (-20000, 80000)
PLAUSIBLE_LIMIT = 850000  # |plausible_mC| bound (the -200..850 degC of IEC 60751)
POS_LIMIT = 100000000  # |reference_um| (100 m)


class Config:
    """Checked top-level settings (annotations are for the type checker only)."""
    channels: list
    max_rate_mC_per_s: int
    stuck_ms: int
    slew_um_per_s: int
    max_offset_um: int
    hold_ms: int
    cycle_ms: int
    frame_ms: int
    watchdog_ms: int
    link_timeout_ms: int
    max_speed_mm_min: int
    baud: int
    address: int
    modbus_address: int
    serial_mode: str
    plausible_lo_mC: int
    plausible_hi_mC: int
    reference_um: "int | None"
    table_dir: str


class Channel:
    """Checked settings of one sensor channel."""
    name: str
    driver: str
    bus: str
    cs: object
    rref_mohm: int
    wires: int
    lead_mohm: int
    cal_mC: int
    filter_hz: int
    idac_ua: int
    address: int


def _bad(key, v):
    return ValueError("config %s: %r" % (key, v))


def _int(key, v, lo, hi):
    # type() rather than isinstance(): a bool is not a setting
    if type(v) is not int or v < lo or v > hi:
        raise _bad(key, v)
    return v


def _fill(obj, w, d, spec, more):
    if type(d) is not dict:
        raise _bad(w or "top level", d)
    for k in d:
        if k not in more and not [s for s in spec if s[0] == k]:
            raise _bad(w + k, "unknown key")
    for k, dflt, lo, hi in spec:
        setattr(obj, k, _int(w + k, d.get(k, dflt), lo, hi))


def load_config(d):
    cfg = Config()
    _fill(cfg, "", d, TOP, TOP_MORE)
    chans = d.get("channels")
    if type(chans) not in (list, tuple) or not 1 <= len(chans) <= 16:
        raise _bad("channels", chans)
    cfg.channels = []
    names = []
    for i in range(len(chans)):
        w = "channels[%d]." % i
        c = Channel()
        d_ = chans[i]
        _fill(c, w, d_, CHAN, CHAN_MORE)
        n = c.name = d_.get("name")
        if type(n) is not str or not n or "," in n or "*" in n or n in names:
            raise _bad(w + "name", n)
        names.append(n)
        c.driver = d_.get("driver")
        if c.driver not in DRIVERS:
            raise _bad(w + "driver", c.driver)
        if "bus" not in d_:
            raise _bad(w + "bus", "missing")
        c.bus = d_["bus"]
        c.cs = d_.get("cs")
        if c.filter_hz not in (50, 60):
            raise _bad(w + "filter_hz", c.filter_hz)
        if c.lead_mohm and c.wires != 2:
            raise _bad(w + "lead_mohm", c.lead_mohm)
        cfg.channels.append(c)
    s = d.get("serial") or {}
    _fill(cfg, "serial.", s, SERIAL, ("mode",))
    cfg.modbus_address = cfg.address
    m = cfg.serial_mode = s.get("mode", "stream")
    if m not in MODES:
        raise _bad("serial.mode", m)
    p = d.get("plausible_mC", PLAUSIBLE)
    if type(p) not in (list, tuple) or len(p) != 2:
        raise _bad("plausible_mC", p)
    cfg.plausible_lo_mC = _int("plausible_mC[0]", p[0], -200000, PLAUSIBLE_LIMIT)
    cfg.plausible_hi_mC = _int("plausible_mC[1]", p[1], p[0] + 1, PLAUSIBLE_LIMIT)
    r = cfg.reference_um = d.get("reference_um")
    if r is not None:
        _int("reference_um", r, -POS_LIMIT, POS_LIMIT)
    t = cfg.table_dir = d.get("table_dir", "tables")
    if type(t) is not str or not t:
        raise _bad("table_dir", t)
    if cfg.watchdog_ms and cfg.watchdog_ms < 2 * cfg.cycle_ms:
        raise _bad("watchdog_ms", cfg.watchdog_ms)
    return cfg
