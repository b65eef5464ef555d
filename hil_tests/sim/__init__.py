"""Simulated hardware, importable by CPython and by MicroPython (plain Python, no numpy).

Runs inside the firmware's process: ``world`` holds the simulated clock, the
stimulus, the chips and the buses; ``machine`` (hil_tests/mp/machine.py) and the
rig launcher (hil_tests/rig/dut.py) hand them to the firmware.
"""
