"""Arm MPS2 AN385 (Cortex-M3) under QEMU: the board the firmware image for ``qemu-system-arm
-M mps2-an385`` carries (ports/mps2, frozen into its ROM; docs/hil.md).

UART0 is the serial link to the controller (QEMU ``-serial``; the REPL's port too), UART1
the HIL rig's control channel. The AN385 has no SPI or I2C peripheral QEMU emulates with
sensors on it, so the buses, chip-select pins and the watchdog come from whoever builds the
board: the HIL rig passes its simulated chips (hil_tests/rig/qemu_board.py), real hardware
would pass its drivers. The board's flash is the host directory QEMU runs in (semihosting).
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
    "table_dir": "tables",
}

SERIAL_UART = 0
CONTROL_UART = 1


def make_board(config=CONFIG, buses=None, pin=None, clock=None, watchdog=None):
    """``buses``/``pin``/``watchdog``: the chips' side (simulated in the rig); ``clock``: None for
    the board's own ticks (firmware.board.SystemClock), the rig's simulated clock otherwise."""
    from machine import UART, reset
    from firmware.board import Board

    ser = config.get("serial") or {}
    uart = UART(SERIAL_UART, baudrate=ser.get("baud", 115200))
    return Board(config, buses or {}, pin, uart, clock=clock, watchdog=watchdog, reset=reset)
