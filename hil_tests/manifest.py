# The HIL rig's device under test (docs/hil.md): the board's firmware, exactly as firmware/manifest.py
# lists it, plus the simulation that stands in for the hardware around it. host/board/fwbuild.py builds it
# (hil_tests/rig/mpybuild.py); the simulated machine module (hil_tests/mp/machine.py) stays source,
# as the "ROM" of the simulated board.
metadata(description="tcomp HIL rig: the firmware and the simulated board it runs on", version="0.1.0")

include("../firmware/manifest.py")

package("hil_tests", files=("__init__.py", "rig/__init__.py", "rig/dut.py"), base_path="..")
package("hil_tests/sim", base_path="..")  # register-level chips, buses, clock, stimulus, world
