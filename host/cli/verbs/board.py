"""tcomp board [--port LINK] [--run RUN | --room-c C] [--interpreter micropython|qemu] [--config board.json]
[--table TABLE] [--key FILE]

A simulated board for a user: the unmodified firmware on the HIL rig's register-level chip simulators
(the 32-bit MicroPython port, or the emulated Cortex-M3), its serial port on a pseudo-terminal that
``tcomp monitor``, ``tcomp record``, ``tcomp linuxcnc`` or a Modbus master opens like /dev/ttyACM0.
Simulated time follows the wall clock; the sensors follow RUN's temperatures (then hold the last ones)
or a steady room. Runs until Ctrl-C (or SIGTERM) and then stops the board and removes the link.

The rig is reached through the entry point group ``tcomp.rig`` (as ``tcomp hil`` does,
host/cli/verbs/hil.py ``load_rig``): host never imports hil_tests (tests/test_layers.py).
"""
from __future__ import annotations

import argparse


import json
import math
import os
import signal
import sys
import time

TICK_S = 0.05  # wall time between two grants of simulated time
LAG_WARN_S = 5.0  # simulated time this far behind the wall clock is reported (once)


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("--port", metavar="LINK",
                   help="also make LINK a symlink to the board's pty (the pty's own path is printed either way); "
                        "an existing file is refused, a dangling symlink replaced")
    src = p.add_mutually_exclusive_group()
    src.add_argument("--run", help="run folder (twin or measured) whose temperatures.csv the sensors follow, "
                                   "from its first sample, in real time; after its last they hold")
    src.add_argument("--room-c", type=float, default=None,
                     help="steady room: every sensor at this temperature in deg C (default 20 without --run)")
    p.add_argument("--interpreter", choices=("micropython", "qemu"), default="micropython",
                   help="micropython: the 32-bit Linux port (make setup); qemu: the emulated Cortex-M3 board image "
                        "(make qemu-image, part of make setup)")
    p.add_argument("--config", help="board config JSON (docs/board-config.md, examples/boards/); default: the "
                                    "table's sensors on MAX31865s, the last on an ADS122C04 (as tcomp hil)")
    p.add_argument("--table", help="coefficient table (tcomp export) in the board's slot A; without one the board "
                                   "runs with no table (offset 0, status NO_TABLE)")
    p.add_argument("--key", metavar="FILE",
                   help="the board key (64 hex digits, as tcomp flash --key): an existing file is provisioned; a "
                        "missing one gets a new key, written (mode 0600) once the board runs. Without --key the "
                        "board has no key and refuses every signed command (L, X, uploads)")
    p.add_argument("--noise-uohm", type=int, default=2000, help="RTD noise, micro-ohm standard deviation")
    p.add_argument("--speed", type=float, default=1.0,
                   help="simulated seconds per wall second (default 1: a board in real time; at most 100)")


def _read_config(path, rig_config, table):
    """The board config: --config validated as the board's boot check does, else the rig's wiring of the
    table's sensors. The table's sensors must all have a channel."""
    from host.errors import UserError
    if not path:
        if table is None:
            raise UserError("give --config (the board's channels, docs/board-config.md) or --table (its sensors "
                            "are then wired as tcomp hil wires them)")
        sensors = list(table.sensors)
        return rig_config(sensors, n_ads=1 if len(sensors) > 1 else 0)
    try:
        with open(path, encoding="utf-8") as f:
            cfg = json.load(f)
    except (OSError, ValueError) as exc:
        raise UserError("--config %s: %s" % (path, exc))
    if not isinstance(cfg, dict):
        raise UserError("--config %s: a board config is a JSON object (docs/board-config.md), found %s"
                        % (path, type(cfg).__name__))
    from host.board.config import load_config
    try:
        load_config(cfg)
    except (ValueError, TypeError, AttributeError) as exc:
        raise UserError("--config %s: %s" % (path, exc))
    if table is not None:
        from host.cli.verbs.flash import unwired_sensors
        missing = unwired_sensors(list(table.sensors), cfg)
        if missing:
            raise UserError("--table: sensor(s) %s have no channel in the board config %s (channels: %s)" % (
                ", ".join(missing), path, ", ".join(str(c.get("name")) for c in cfg["channels"])))
    return cfg


class _Schedule:
    """Temperatures by channel over run time: the run's samples (linear in between), or one steady value."""

    def __init__(self, channels, run_dir=None, room_c=20.0):
        from host.errors import UserError
        self.channels = channels
        if run_dir is None:
            self.times = [0.0]
            self.rows = [{c: room_c for c in channels}]
            return
        # the temperatures file through the run loader (validated, units known); numpy lives in the science
        # install, which --run therefore needs
        from host.data.runs import RunFormatError, load_run
        try:
            run = load_run(run_dir)
        except RunFormatError as exc:
            raise UserError(str(exc))
        t = run.temperatures
        missing = [c for c in channels if c not in t.names]
        if missing:
            raise UserError("--run %s: the board's channel(s) %s are not columns of its temperatures.csv (%s)"
                            % (run_dir, ", ".join(missing), ", ".join(t.names)))
        cols = {c: t.column(c) for c in channels}
        self.times = [float(x) for x in t.time_s]
        self.rows = [{c: float(cols[c][i]) for c in channels} for i in range(len(self.times))]

    @property
    def length_s(self):
        return self.times[-1] - self.times[0]


def _claim_link(path):
    from host.errors import UserError
    if os.path.islink(path):
        if os.path.exists(path):
            raise UserError("--port %s: already a link to %s (another board running?); choose another path or "
                            "remove it" % (path, os.readlink(path)))
        os.unlink(path)  # a board that was killed left it dangling
    elif os.path.lexists(path):
        raise UserError("--port %s: exists and is not a symlink; the board's link is never put over a file" % path)
    parent = os.path.dirname(os.path.abspath(path))
    if not os.path.isdir(parent):
        raise UserError("--port %s: folder %s does not exist" % (path, parent))


def _key(path):
    """(key, created): the key of an existing FILE; a new one for a missing FILE (written once the board runs)."""
    from host.board.linkauth import KeyFileError, generate_key, read_key
    from host.errors import UserError, check_output
    if not path:
        return b"", False
    if not os.path.lexists(path):
        check_output(path, "--key")
        return generate_key(), True
    try:
        return read_key(path), False
    except KeyFileError as exc:
        raise UserError("--key %s" % exc)


def run(args: argparse.Namespace) -> int:
    from host.cli.verbs.hil import load_rig
    from host.errors import UserError

    if not (0 < args.speed <= 100) or not math.isfinite(args.speed):
        raise UserError("--speed %g: must be above 0 and at most 100 (simulated seconds per wall second)" % args.speed)
    if args.noise_uohm < 0:
        raise UserError("--noise-uohm must be >= 0 (found %d)" % args.noise_uohm)
    if args.room_c is not None and not math.isfinite(args.room_c):
        raise UserError("--room-c %g: must be a finite temperature in deg C" % args.room_c)
    rig = load_rig()
    problem = rig.board_problem(args.interpreter)
    if problem:
        raise UserError("tcomp board --interpreter %s: %s" % (args.interpreter, problem))
    from host.cli.tablefile import read_table

    data, table = read_table(args.table) if args.table else (None, None)
    cfg = _read_config(args.config, rig.rig_config, table)
    channels = [c["name"] for c in cfg["channels"]]
    lo_mC, hi_mC = cfg.get("plausible_mC", (-20000, 80000))
    if args.room_c is not None and not lo_mC <= args.room_c * 1000 <= hi_mC:
        raise UserError("--room-c %g: outside the board's plausible range %g..%g deg C (config plausible_mC): every "
                        "channel would read as faulty" % (args.room_c, lo_mC / 1000.0, hi_mC / 1000.0))
    schedule = _Schedule(channels, args.run, 20.0 if args.room_c is None else args.room_c)
    if args.port:
        _claim_link(args.port)
    key, created = _key(args.key)

    board = rig.LiveBoard(cfg, data, interpreter=args.interpreter, temps=schedule.rows[0], key=key,
                          noise_uohm=args.noise_uohm, dynamic=table is not None and table.kind == "dynamic")
    stop = {"signal": None}

    def on_term(signum, frame):
        stop["signal"] = signum
        raise KeyboardInterrupt

    # Both installed here: a shell starts a background job with SIGINT ignored, and Ctrl-C in a terminal
    # reaches the board's process too (same process group), which may end before this one hears of it.
    previous = {s: signal.signal(s, on_term) for s in (signal.SIGINT, signal.SIGTERM)}
    linked = False
    try:
        try:
            board.start()
        except rig.RigError as exc:
            raise UserError("the simulated board did not start: %s" % exc)
        if args.port:
            os.symlink(board.port, args.port)
            linked = True
        if created:
            from host.board.linkauth import write_key
            write_key(args.key, key)
        mode = (cfg.get("serial") or {}).get("mode", "stream")
        print("board: %s%s (%s, %s at %d baud; %s; %s)" % (
            board.port, " <- " + args.port if args.port else "", args.interpreter, mode,
            (cfg.get("serial") or {}).get("baud", 115200),
            "table %s %08X" % (table.kind, table.crc) if table is not None else "no table",
            ("key %s" % args.key) if key else "no key: signed commands are refused"))
        print("sensors: %s; %s. Ctrl-C stops the board." % (
            ", ".join(channels),
            "temperatures of %s (%.0f s, then held)" % (args.run, schedule.length_s) if args.run
            else "steady room at %g deg C" % schedule.rows[0][channels[0]]))
        sys.stdout.flush()
        _serve(board, schedule, args.speed)
    except KeyboardInterrupt:
        pass
    except (rig.RigError, UserError) as exc:
        if stop["signal"] is None:  # not the board ending on the user's Ctrl-C along with this process
            raise UserError("the simulated board stopped: %s" % exc)
    finally:
        for s, handler in previous.items():
            signal.signal(s, handler)
        board.close()
        if linked and os.path.islink(args.port):
            os.unlink(args.port)
    print("board stopped (%.0f s simulated%s)" % (board.t_ms / 1000.0,
                                                  ", %d unread serial bytes dropped" % board.dropped_bytes
                                                  if board.dropped_bytes else ""))
    return 0


def _serve(board, schedule, speed):
    """Grant simulated time at ``speed`` times the wall clock; the sensors ramp from sample to sample."""
    times, rows = schedule.times, schedule.rows
    t_first = times[0]
    wall0 = time.monotonic()
    nxt = 1  # the next sample the sensors head for
    if nxt < len(times):
        board.head_for((times[nxt] - t_first) * 1000.0, rows[nxt])
    held = len(times) == 1
    warned = False
    while True:
        if not board.alive:
            raise _board_died(board)
        target_ms = (time.monotonic() - wall0) * speed * 1000.0
        while nxt < len(times) and (times[nxt] - t_first) * 1000.0 <= target_ms:
            board.step((times[nxt] - t_first) * 1000.0)
            nxt += 1
            if nxt < len(times):
                board.head_for((times[nxt] - t_first) * 1000.0, rows[nxt])
        if not held and nxt >= len(times):
            held = True
            print("run ended at %.0f s: the sensors hold its last temperatures" % (times[-1] - t_first))
            sys.stdout.flush()
        board.step(target_ms)
        lag_s = (time.monotonic() - wall0) * speed - board.t_ms / 1000.0
        if lag_s > LAG_WARN_S and not warned:
            warned = True
            print("tcomp board: warning: the board runs %.0f s behind the wall clock (too slow for --speed %g on "
                  "this machine)" % (lag_s, speed), file=sys.stderr)
        time.sleep(TICK_S)


def _board_died(board):
    from host.errors import UserError
    return UserError("its process ended:\n%s" % board.log()[-2000:])
