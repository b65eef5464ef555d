"""Hardware-in-the-loop rig (docs/hil.md): simulated chips and buses, the firmware in a real
MicroPython (or CPython) process on a pseudo-terminal, and the scenario tests."""
