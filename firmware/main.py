"""Board entry point: ``tcomp flash`` ships it compiled (firmware/main.mpy) with a root main.py that
calls ``run([])`` (host/board/fwbuild.py BOOT_MAIN).

Looks for the user's board file ``tcomp_board.py`` at the root (a copy of one of
firmware/boards/), falling back to the RP2040 example. Under CPython:
``python -m firmware.main --board firmware.boards.linux``.
"""

import sys


def _board_module(name):
    if name:
        mod = __import__(name)
        for part in name.split(".")[1:]:
            mod = getattr(mod, part)
        return mod
    try:
        import tcomp_board  # type: ignore  # the user's board file, copied to the board root
        return tcomp_board
    except ImportError:
        from firmware.boards import rp2040
        return rp2040


def run(argv):
    name = None
    if len(argv) > 2 and argv[1] == "--board":
        name = argv[2]
    mod = _board_module(name)
    from firmware import app
    app.main(mod.make_board())


if __name__ == "__main__":
    run(getattr(sys, "argv", []))
