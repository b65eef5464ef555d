"""The board's code (docs/firmware.md). This file stays off the board (firmware/manifest.py NOT_ON_BOARD),
where firmware/ is a plain folder of modules.

Under CPython (the host, the exporter, the tests, the HIL rig's CPython board, a Linux board) it runs
before any firmware module and gives their ``from micropython import const`` the stand-in
firmware/micropython_standin.py, registered under that name only in this process.
"""
import sys

if sys.implementation.name != "micropython":
    from firmware import micropython_standin

    micropython_standin.install()
