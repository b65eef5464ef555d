# The firmware tests on MicroPython (test_fw_heaplock.py, test_fw_micropython.py, ...): the board's
# firmware, exactly as firmware/manifest.py lists it, plus the register-level fakes the scripts
# import as top-level modules. Built by host/board/fwbuild.py (fwhelpers.compile_mpy).
metadata(description="tcomp firmware tests: the firmware and its register-level fakes", version="0.1.0")

include("../../firmware/manifest.py")

module("fwfakes.py")
