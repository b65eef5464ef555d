"""The rig: ``dut.py`` runs inside the firmware's process; ``harness`` is the test/controller side."""
