"""The thin HAL layer of ``tcomp linuxcnc``: a userspace component whose pins feed ``Bridge.step``.

Only this module imports LinuxCNC's ``hal`` (Debian linuxcnc-uspace puts it in
/usr/lib/python3/dist-packages; ``make setup`` links it into the venv).
Pins (prefix = component name, default ``tcomp``) are listed in PINS and in docs/linuxcnc.md.
"""

from __future__ import annotations

from types import ModuleType
from typing import Any
from typing import TYPE_CHECKING
import sys

from host.board.linuxcnc.bridge import Inputs, run_loop

if TYPE_CHECKING:
    from host.board.linuxcnc.bridge import Bridge

# (pin, type, direction, Inputs/BridgeOutputs attribute)
PINS = (
    ("position", "FLOAT", "IN", "position"),
    ("machine-on", "BIT", "IN", "machine_on"),
    ("homed", "BIT", "IN", "homed"),
    ("eoffset-request", "FLOAT", "IN", "eoffset_request"),
    ("cold-start", "BIT", "IN", "cold_start"),
    ("latch", "BIT", "IN", "latch"),
    ("spindle-rpm", "FLOAT", "IN", "spindle_rpm"),
    ("velocity", "FLOAT", "IN", "velocity"),
    ("eoffset-counts", "S32", "OUT", "eoffset_counts"),
    ("eoffset-scale", "FLOAT", "OUT", "eoffset_scale"),
    ("eoffset-enable", "BIT", "OUT", "eoffset_enable"),
    ("offset-um", "FLOAT", "OUT", "offset_um"),
    ("board-offset-um", "FLOAT", "OUT", "board_offset_um"),
    ("board-status", "U32", "OUT", "board_status"),
    ("link-ok", "BIT", "OUT", "link_ok"),
    ("fault", "BIT", "OUT", "fault"),
    ("fault-code", "S32", "OUT", "fault_code"),
    ("tracking", "BIT", "OUT", "tracking"),
    ("latch-state", "S32", "OUT", "latch_state"),
)


def import_hal() -> ModuleType:
    try:
        import hal
    except ImportError as exc:
        raise ImportError("LinuxCNC's Python hal module is not importable (%s): install Debian's "
                          "linuxcnc-uspace (make setup does) and run tcomp from the venv make setup built" % exc)
    return hal


def component(name: str) -> Any:
    hal = import_hal()
    comp = hal.component(name)
    for pin, typ, direction, _ in PINS:
        comp.newpin(pin, getattr(hal, "HAL_" + typ), getattr(hal, "HAL_" + direction))
    return comp


def serve(comp: Any, bridge: Bridge, period_s: float) -> None:
    """Run until HAL unloads the component (KeyboardInterrupt) or SIGTERM."""
    ins = [(p, a) for p, _, d, a in PINS if d == "IN"]
    outs = [(p, a) for p, _, d, a in PINS if d == "OUT"]

    def read_inputs():
        return Inputs(**{a: comp[p] for p, a in ins})

    def write_outputs(o):
        for p, a in outs:
            comp[p] = getattr(o, a)

    write_outputs(bridge.out)
    comp.ready()
    try:
        run_loop(bridge, read_inputs, write_outputs, period_s)
    except KeyboardInterrupt:
        pass
    finally:
        sys.stdout.flush()
