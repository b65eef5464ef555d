"""Linux single-board computer example (CPython): spidev, smbus2, pyserial.

Each MAX31865 sits on its own spidev node (the kernel drives the chip-select),
so channels name the node as their bus and leave ``cs`` unset. The ADS122C04
sits on /dev/i2c-1. The controller link is /dev/ttyUSB0. Run with
``python -m firmware.main --board firmware.boards.linux`` or copy and edit.
"""

CONFIG = {
    "channels": [
        {"name": "T1", "driver": "max31865", "bus": "/dev/spidev0.0", "rref_mohm": 430000, "wires": 3},
        {"name": "T2", "driver": "max31865", "bus": "/dev/spidev0.1", "rref_mohm": 430000, "wires": 3},
        {"name": "T3", "driver": "ads122c04", "bus": "/dev/i2c-1", "address": 0x40,
         "rref_mohm": 1620000, "wires": 3, "idac_ua": 500},
    ],
    "serial": {"mode": "stream", "baud": 115200},
    "plausible_mC": [-20000, 80000],
    "slew_um_per_s": 5,
    "max_offset_um": 300,
    "cycle_ms": 100,
    "frame_ms": 1000,
    "watchdog_ms": 0,
    "table_dir": "/var/lib/tcomp/tables",
}

PORT = "/dev/ttyUSB0"


def make_board(config=CONFIG, port=PORT):
    from firmware.linux_adapters import make_linux_board
    return make_linux_board(config, port)
