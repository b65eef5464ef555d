"""Validation of the board config dict (keys and units documented in firmware/board.py).

``load_config(d)`` returns a ``Config`` whose attributes are the validated
values, or raises ValueError naming the key, e.g.
``config channels[3].wires: 5 outside 2..4``. Unknown keys are errors so that
a typo never silently falls back to a default.
"""

# (key, default, lo, hi); default None = required / optional as noted
_TOP = (
    ("max_rate_mC_per_s", 2000, 1, 1000000),
    ("stuck_ms", 0, 0, 86400000),
    ("slew_um_per_s", 5, 1, 10000),
    ("max_offset_um", 300, 1, 100000),
    ("hold_ms", 60000, 0, 86400000),
    ("cycle_ms", 100, 1, 60000),
    ("frame_ms", 1000, 0, 3600000),
    ("watchdog_ms", 2000, 0, 8388),
    ("link_timeout_ms", 0, 0, 65535),
)
_CHAN = (
    ("rref_mohm", 430000, 100000, 10000000),
    ("wires", 3, 2, 4),
    ("lead_mohm", 0, 0, 50000),
    ("cal_mC", 0, -10000, 10000),
    ("filter_hz", 50, 50, 60),
    ("idac_ua", 250, 10, 1500),
    ("address", 0x40, 0x40, 0x4F),
)
_SERIAL = (("baud", 115200, 1200, 4000000), ("address", 1, 1, 247))
DRIVERS = ("max31865", "ads122c04")


class Config:
    """Validated top-level settings (annotations are for the type checker only)."""
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
    baud: int
    address: int
    modbus_address: int
    serial_mode: str
    plausible_lo_mC: int
    plausible_hi_mC: int
    reference_um: "int | None"
    table_dir: str


class Channel:
    """Validated settings of one sensor channel."""
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
    if c.lead_mohm and c.wires != 2:
        raise _err(w + "lead_mohm", "lead correction is for 2-wire sensors (wires=%d)" % c.wires)
    return c


def load_config(d):
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
