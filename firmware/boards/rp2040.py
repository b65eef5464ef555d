"""RP2040 (Raspberry Pi Pico) example: MAX31865 breakouts on SPI0, ADS122C04 on I2C1, UART0.

Copy to the board root as ``tcomp_board.py`` and edit the pins and channels;
``main.py`` calls ``make_board()``. Wiring assumed here:
SPI0 SCK=GP18 MOSI=GP19 MISO=GP16, chip-selects GP5..GP13 (one per MAX31865);
I2C1 SDA=GP2 SCL=GP3 with two ADS122C04 at 0x40 and 0x41; UART0 TX=GP0 RX=GP1
to the controller.
"""

CONFIG = {
    "channels": [
        {"name": "T%d" % (i + 1), "driver": "max31865", "bus": "spi0", "cs": 5 + i,
         "rref_mohm": 430000, "wires": 3, "filter_hz": 50}
        for i in range(9)
    ] + [
        {"name": "T10", "driver": "ads122c04", "bus": "i2c1", "address": 0x40,
         "rref_mohm": 1620000, "wires": 3, "idac_ua": 500, "filter_hz": 50},
        {"name": "T11", "driver": "ads122c04", "bus": "i2c1", "address": 0x41,
         "rref_mohm": 1620000, "wires": 3, "idac_ua": 500, "filter_hz": 50},
    ],
    "serial": {"mode": "stream", "baud": 115200, "address": 1},
    "plausible_mC": [-20000, 80000],
    "max_rate_mC_per_s": 2000,
    "slew_um_per_s": 5,
    "max_offset_um": 300,
    "hold_ms": 60000,
    "cycle_ms": 100,
    "frame_ms": 1000,
    "watchdog_ms": 2000,
    "table_dir": "/tables",
}


def make_board(config=CONFIG):
    from machine import Pin, SPI, I2C, UART, WDT, reset
    from firmware.board import Board

    spi = SPI(0, baudrate=1000000, polarity=0, phase=1,
              sck=Pin(18), mosi=Pin(19), miso=Pin(16))
    i2c = I2C(1, sda=Pin(2), scl=Pin(3), freq=400000)
    ser = config.get("serial") or {}
    uart = UART(0, baudrate=ser.get("baud", 115200), tx=Pin(0), rx=Pin(1),
                timeout=0, rxbuf=512)

    def pin(cs):
        return Pin(cs, Pin.OUT, value=1)

    wdt = WDT(timeout=config["watchdog_ms"]) if config.get("watchdog_ms") else None
    return Board(config, {"spi0": spi, "i2c1": i2c}, pin, uart, watchdog=wdt, reset=reset)
