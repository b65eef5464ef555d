"""One simulated board: clock, sensors, chips and buses built from the firmware's own board config.

The config's channels say which chip sits where (driver, bus name, CS pin or
I2C address, reference resistor, wiring); ``World`` builds exactly that
hardware around the firmware, so a config error in the board file shows up
in the rig as it would on the bench. ``current()`` is the process's world,
for ``machine.py``.

Bus names: ``spiN`` / ``i2cN`` (N = the ``machine.SPI``/``machine.I2C`` id);
any other name gets an SPI bus if its channels are MAX31865, I2C otherwise.
"""

from hil_tests.sim.ads122c04 import ADS122C04
from hil_tests.sim.buses import I2CBus, Pin, SPIBus
from hil_tests.sim.clock import SimClock
from hil_tests.sim.max31865 import MAX31865
from hil_tests.sim.stimulus import Rtd

_WORLD = None


def current():
    """The process's world; built on first use from the JSON spec named by the environment
    variable TCOMP_HIL_WORLD (a flashed board booting main.py), on real time."""
    global _WORLD
    if _WORLD is None:
        import os
        path = os.getenv("TCOMP_HIL_WORLD")
        spec = {"config": {"channels": []}}
        if path:
            import json
            with open(path) as f:
                spec = json.load(f)
        from hil_tests.sim.clock import WallClock
        _WORLD = World(spec["config"], spec.get("temps"), spec.get("noise_uohm", 0), spec.get("seed", 1),
                       clock=WallClock())
    return _WORLD


def set_current(w):
    global _WORLD
    _WORLD = w


class WatchdogExpired(Exception):
    pass


class SimWDT:
    """``machine.WDT``: ``feed()``; ``check()`` (called by the rig as time passes) raises when starved."""

    def __init__(self, clock, timeout_ms):
        self.clock = clock
        self.timeout_us = timeout_ms * 1000
        self.last_us = clock.us
        self.feeds = 0
        clock.on_epoch(self)

    def shift_epoch(self, shift):
        # a feed older than the new epoch's start (4.5 min) starved the watchdog long ago either way
        self.last_us = self.last_us - shift if self.last_us >= shift else 0

    def feed(self):
        self.last_us = self.clock.us
        self.feeds += 1

    def check(self):
        if self.clock.us - self.last_us > self.timeout_us:
            raise WatchdogExpired("watchdog not fed for %d ms" % ((self.clock.us - self.last_us) // 1000))


class World:
    def __init__(self, config, temps=None, noise_uohm=0, seed=1, start_ms=0, clock=None):
        self.config = config
        self.clock = clock if clock is not None else SimClock(start_ms)
        self.rtds = {}
        self.chips = {}
        self.buses = {}
        self.pins = {}
        self.wdt = None
        self.uart = None
        temps = temps or {}
        for i, ch in enumerate(config.get("channels", [])):
            name = ch["name"]
            wires = ch.get("wires", 3)
            lead = ch.get("lead_mohm", 0) * 1000 if wires == 2 else 0
            rtd = Rtd(name, temps.get(name, 20.0), noise_uohm, seed + 101 * i, lead)
            self.rtds[name] = rtd
            bus = self.bus(ch["bus"], ch["driver"])
            if ch["driver"] == "max31865":
                chip = MAX31865(self.clock, rtd, ch.get("rref_mohm", 430000) / 1000.0, name)
                bus.attach(self.pin(ch.get("cs")), chip)
            else:
                chip = ADS122C04(self.clock, rtd, ch.get("rref_mohm", 1620000) / 1000.0,
                                 ch.get("address", 0x40), wires, name)
                bus.attach(chip)
            self.chips[name] = chip

    def bus(self, name, driver="max31865"):
        b = self.buses.get(name)
        if b is None:
            spi = name.startswith("spi") or (not name.startswith("i2c") and driver == "max31865")
            ident = name[3:] if name[3:].isdigit() else name
            b = SPIBus(self.clock, ident, 1000000, 0, 1) if spi else I2CBus(self.clock, ident)
            self.buses[name] = b
        return b

    def pin(self, ident):
        p = self.pins.get(ident)
        if p is None:
            p = Pin(ident, Pin.OUT, value=1)
            self.pins[ident] = p
        return p

    def spi(self, ident):
        return self.bus("spi%s" % ident, "max31865")

    def i2c(self, ident):
        return self.bus("i2c%s" % ident, "ads122c04")

    def watchdog(self, timeout_ms):
        self.wdt = SimWDT(self.clock, timeout_ms)
        return self.wdt

    def make_uart(self):
        from hil_tests.sim.uart import StdioUART
        self.uart = StdioUART()
        return self.uart

    # --- stimulus and faults (the control channel calls these) ----------------------
    def ramp(self, until_ms, temps):
        now = self.clock.now_ms()
        for name in temps:
            self.rtds[name].ramp_to(now, until_ms, temps[name])

    def jump(self, temps):
        now = self.clock.now_ms()
        for name in temps:
            self.rtds[name].set_now(now, temps[name])

    def stats(self):
        chips = {}
        for name in self.chips:
            c = self.chips[name]
            chips[name] = {"conversions": c.conversions, "violations": c.violation_count,
                           "violation_text": list(c.violations), "present": c.present}
            if isinstance(c, MAX31865):
                chips[name]["fault_cycles"] = c.fault_cycles
                chips[name]["clears"] = c.clears
                chips[name]["ignored_clears"] = c.ignored_clears
        buses = {}
        for name in self.buses:
            b = self.buses[name]
            buses[name] = {"faulted_transfers": b.faults.injected, "transfers": b.faults.transfers}
            if isinstance(b, SPIBus):
                buses[name]["contention"] = b.contention
                buses[name]["mode_errors"] = b.mode_errors
        return {"chips": chips, "buses": buses}
