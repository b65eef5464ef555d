# What goes on a board: the one list of the firmware's files (docs/firmware.md, "Building").
#
# A MicroPython manifest in micropython-lib's style (docs.micropython.org, reference/manifest):
# metadata() first, then package()/module() calls; include() another manifest, passing options.
# host/board/fwbuild.py evaluates it with its own small implementation of those functions (it never
# imports a firmware module), compiles the listed files with mpy-cross and hands the same .mpy
# files to `tcomp flash`, the tests, the HIL rig, the benchmarks and the QEMU image. The firmware
# never imports this file (it is not board code: tests/test_manifest.py keeps it off the board).
#
# options (include("firmware/manifest.py", serial="stream", drivers=("max31865",))):
#   serial   "stream" ($TC frames) or "modbus" (RTU slave): only that link's modules; unset: both,
#            which is what `tcomp flash` ships (the board file may pick either mode)
#   drivers  sensor driver names of firmware/drivers.py DRIVERS: only those chips' modules;
#            unset: every driver
#   boards   example board files of firmware/boards/ to ship (names in BOARD_FILES); unset:
#            rp2040, main.py's fallback and the board `tcomp flash --config` generates around

metadata(description="tcomp firmware: thermal-error compensation on the board", version="0.1.0", license="MIT")

# the example board files that run on MicroPython (boards/linux.py runs under CPython: NOT_ON_BOARD)
BOARD_FILES = ("rp2040", "mps2_an385")  # mps2_an385: the QEMU board image (ports/mps2)

options.defaults(serial=None, drivers=None, boards=("rp2040",))

if options.serial not in (None, "stream", "modbus"):
    raise ValueError("serial must be stream or modbus, got %r" % (options.serial,))

# every board: boot (main, board file support, config check), the cycle, tables and authorisation.
# sha256.py is loaded only where the port has no hashlib; it is shipped because that is not known here.
package("firmware", files=(
    "main.py", "board.py", "bootcfg.py", "app.py", "channels.py", "drivers.py", "rtd.py",
    "evaluate.py", "table.py", "crc32.py", "slots.py", "warmstate.py", "safety.py", "auth.py", "sha256.py", "crc16.py",
    "boards/__init__.py",
), base_path="..")
for board in options.boards:
    if board not in BOARD_FILES:
        raise ValueError("boards: %r is not one of %s" % (board, ", ".join(BOARD_FILES)))
    package("firmware", files=("boards/%s.py" % board,), base_path="..")

# the serial link: app.py imports one of them, by the config's serial mode
if options.serial in (None, "stream"):
    package("firmware", files=("protocol.py", "frame.py"), base_path="..")
if options.serial in (None, "modbus"):
    package("firmware", files=("modbus.py",), base_path="..")

# sensor drivers: channels.py imports a driver's module only when a channel names it
for driver in options.drivers or ("max31865", "ads122c04"):
    package("firmware", files=(driver + ".py",), base_path="..")

# firmware/ files that never go on a board, and why (tests/test_manifest.py: every other file
# of firmware/ must be listed above, so a new module cannot silently miss the board)
NOT_ON_BOARD = {
    "manifest.py": "this list (build input, not board code)",
    "wire.py": "the host's copy of the wire contract; board modules keep folded const copies",
    "linux_adapters.py": "CPython adapters of a Linux board (fcntl, ctypes, pyserial, smbus2)",
    "boards/linux.py": "the Linux board file, run under CPython (python -m firmware.main)",
    "__init__.py": "CPython only: installs the const() stand-in (on the board firmware/ is a plain folder)",
    "micropython_standin.py": "CPython's stand-in for the built-in micropython module (const)",
}
