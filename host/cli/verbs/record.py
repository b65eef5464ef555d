"""tcomp record --port PORT --out RUN --sensor NAME=ROLE[:LOCATION]... [--config board.json] [--period S] [--duration S]

Polls the board's temperatures (``S`` -> ``T`` frame) every ``--period`` seconds into a run folder that is valid at
every instant (host/board/recorder.py, docs/recording.md). ``time_s`` is the board's clock (t_ms, followed across
its 2^30 ms wrap) from the first sample; meta.json holds the wall-clock time of that sample. Ctrl-C or SIGTERM end
the recording (exit 0); a silent or lost link, a restarted board or a full disk end it with a message (exit 1).
Either way the folder holds every sample written before.
"""
from __future__ import annotations

import argparse
import math
import re
import signal
import sys
import time

from host.data.runformat import MOTION, MOTION_COLUMNS, SPINDLE, SPINDLE_COLUMNS

DEFAULT_PERIOD_S = 1.0
_DECIMAL = re.compile(r"-?[0-9]{1,6}(\.[0-9]{1,6})?\Z")  # what the firmware prints for a good channel: degC.mmm


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("--port", required=True, help="serial port or pySerial URL of the board (e.g. /dev/ttyACM0, a pty)")
    p.add_argument("--baud", type=int, default=115200, help="baud rate (default 115200)")
    p.add_argument("--out", required=True, help="the run folder to create (new, or an empty folder)")
    p.add_argument("--sensor", action="append", default=[], metavar="NAME=ROLE[:LOCATION]",
                   help="one per board channel: its name in the run and its role (nut, base, ambient, bearing, motor, "
                        "structure), in channel order; with --config, by the config's channel names")
    p.add_argument("--config", help="the board config JSON (as given to tcomp flash --config): the channels' names "
                                    "come from it and are checked against the board's channel count")
    p.add_argument("--period", type=float, default=DEFAULT_PERIOD_S,
                   help="seconds between two samples (default %g; at least 0.05)" % DEFAULT_PERIOD_S)
    p.add_argument("--duration", type=float, default=0.0, help="stop after this many seconds (0: until Ctrl-C)")
    p.add_argument("--link-timeout", type=float, default=5.0,
                   help="seconds without an answer to S after which the link counts as lost (default 5)")
    p.add_argument("--notes", default="", help="free text kept in meta.json 'notes'")
    g = p.add_argument_group("LinuxCNC (--linuxcnc: sample HAL beside the temperatures into motion.csv and spindle.csv)")
    g.add_argument("--linuxcnc", action="store_true",
                   help="also read the axis position and velocity and the spindle speed from the running LinuxCNC's "
                        "HAL at every sample: moves into motion.csv, speeds into spindle.csv")
    g.add_argument("--hal-position", default="axis.x.pos-cmd", metavar="PIN",
                   help="the axis position pin (machine units; default axis.x.pos-cmd)")
    g.add_argument("--hal-velocity", default="joint.0.vel-cmd", metavar="PIN",
                   help="the axis velocity pin (machine units/s; default joint.0.vel-cmd)")
    g.add_argument("--hal-spindle", default="spindle.0.speed-out-abs", metavar="PIN",
                   help="the spindle speed pin (rpm; default spindle.0.speed-out-abs)")
    g.add_argument("--hal-name", default="tcomp-record", help="the HAL component this reader appears as "
                                                              "(default tcomp-record)")
    g.add_argument("--units", choices=("mm", "inch"), default="mm", help="the machine's linear units (default mm)")


class _Terminated(Exception):
    pass


def _on_sigterm(signum, frame):
    raise _Terminated()


def _check(args):
    from host.errors import UserError
    if not (math.isfinite(args.period) and args.period >= 0.05):
        raise UserError("--period %s: must be a number of seconds >= 0.05" % args.period)
    if not (math.isfinite(args.duration) and args.duration >= 0):
        raise UserError("--duration %s: must be a finite number of seconds >= 0 (0: until Ctrl-C)" % args.duration)
    if not (math.isfinite(args.link_timeout) and args.link_timeout > 0):
        raise UserError("--link-timeout %s: must be a positive number of seconds" % args.link_timeout)
    if not args.baud >= 1:
        raise UserError("--baud %s: must be a positive rate in bit/s" % args.baud)


def _config_names(path):
    import json

    from host.board.config import load_config
    from host.errors import UserError
    try:
        with open(path, encoding="utf-8") as fh:
            cfg = load_config(json.load(fh))
    except (OSError, ValueError) as exc:  # json.JSONDecodeError is a ValueError, as are the config's findings
        raise UserError("--config %s: %s" % (path, exc))
    return [c.name for c in cfg.channels]


def run(args: argparse.Namespace) -> int:
    from host.board.recorder import parse_sensor
    from host.errors import UserError, check_output_dir
    _check(args)
    sensors = {}
    for text in args.sensor:
        try:
            name, info = parse_sensor(text)
        except ValueError as exc:
            raise UserError("--sensor %s" % exc)
        if name in sensors:
            raise UserError("--sensor %s: given twice" % name)
        sensors[name] = info
    from host.outputs import Outputs
    # the claim's checks only (never over the port or the config); the folder is written as it records, not staged
    with Outputs([args.port, args.config]) as outputs:
        outputs.folder(args.out)
    check_output_dir(args.out)
    config_names = _config_names(args.config) if args.config else None
    previous = signal.signal(signal.SIGTERM, _on_sigterm)
    # SIGINT ends a recording too, even when the recorder inherited it ignored: a shell script's background job
    # (`tcomp record ... &`, then `kill -INT`) starts with SIGINT ignored, and Python then never raises
    # KeyboardInterrupt, so the run could only be killed, not ended
    previous_int = signal.signal(signal.SIGINT, signal.default_int_handler)
    try:
        return _record(args, sensors, config_names)
    finally:
        signal.signal(signal.SIGTERM, previous)
        signal.signal(signal.SIGINT, previous_int)


def _motion_row(r):
    return "%.3f,%.3f,%.4f,%.4f,%.3f" % r


def _sample_hal(writer, hal, motion, t):
    """One HAL sample at host time ``t`` (s since time_s 0): closed moves into motion.csv, the speed into spindle.csv."""
    position, velocity, rpm = hal.read()
    writer.append(MOTION, MOTION_COLUMNS, [_motion_row(r) for r in motion.sample(t, position, velocity)])
    writer.append(SPINDLE, SPINDLE_COLUMNS, ["%.3f,%.3f" % (t, abs(rpm))])


def _record(args, sensors, config_names):
    import datetime

    import serial

    from host.board.client import BoardLink, ClockError, LinkError
    from host.board.recorder import RecordStop, RunWriter, faulty_channels, sensor_names
    from host.errors import UserError

    hal = motion = None
    if args.linuxcnc:
        from host.board.linuxcnc.halsample import HalReader, MotionSegmenter
        try:
            hal = HalReader([args.hal_position, args.hal_velocity, args.hal_spindle], args.hal_name)
        except (ImportError, ValueError) as exc:
            raise UserError("--linuxcnc: %s" % exc)
        motion = MotionSegmenter(args.units)
    try:
        link = BoardLink.open(args.port, args.baud)
        hello = link.read_hello(timeout=args.link_timeout)
    except LinkError as exc:
        if hal is not None:
            hal.close()
        raise UserError(str(exc))
    writer = None
    stop = None  # why the recording ended early (exit 1), None for the end asked for
    skipped = 0
    try:
        try:
            names = sensor_names(hello.channels or 0, sensors, config_names)
        except ValueError as exc:
            raise UserError("%s: %s" % (args.port, exc))
        link.take_frames()
        print("recording %s (firmware %s, %d channels: %s) every %g s into %s; Ctrl-C ends it"
              % (args.port, hello.firmware, hello.channels, ", ".join(names), args.period, args.out))
        sys.stdout.flush()
        start = time.monotonic()
        started_utc = datetime.datetime.now(datetime.timezone.utc).isoformat(timespec="milliseconds")
        due = start
        last_ms = t0_ms = host_t0 = None
        early_faults = []
        faulty_before = 0
        while not (args.duration and time.monotonic() - start >= args.duration):
            delay = due - time.monotonic()  # every request on the period's beat, whatever the last one brought
            if delay > 0:
                time.sleep(delay)
            due = max(due, time.monotonic() - args.period) + args.period
            try:
                f = link.request("S", kinds="TH", timeout=args.link_timeout)
            except LinkError:
                stop = ("no answer to S from %s within %g s: the link is lost (board off, unplugged or restarted?)"
                        % (args.port, args.link_timeout))
                break
            except (serial.SerialException, OSError) as exc:
                stop = "%s: the link is lost: %s" % (args.port, exc)
                break
            link.take_frames()  # the periodic O frames and this answer: nothing else is kept
            if t0_ms is None:  # the wall clock of the first answer (time_s 0), within the link's latency
                started_utc = datetime.datetime.now(datetime.timezone.utc).isoformat(timespec="milliseconds")
            if f.kind == "H":
                stop = "%s: the board restarted (a boot hello arrived); its clock started again" % args.port
                break
            values = f.fields[1:]
            if len(values) != len(names) or not all(_DECIMAL.match(v) or re.match(r"![0-9A-Fa-f]{2}\Z", v)
                                                    for v in values):
                print("record: malformed T frame skipped: %r" % f.raw[:80], file=sys.stderr)
                skipped += 1
                continue
            try:
                if t0_ms is None:
                    t0_ms, host_t0 = int(f.fields[0]), f.arrival  # time_s 0: the board's and this host's clock
                ms = link.clock.extend(f.fields[0])
            except (ClockError, ValueError) as exc:
                stop = "%s: %s" % (args.port, exc)
                break
            if last_ms is not None and ms <= last_ms:
                continue  # the same cycle's temperatures again (a period shorter than the board's cycle)
            last_ms = ms
            time_s = ms / 1000.0
            try:
                if writer is None:
                    bad = faulty_channels(names, time_s, values)
                    if bad:  # the run appears with its first good sample; these go into it then
                        early_faults += bad
                        faulty_before += 1
                        continue
                    meta = {"sensors": {nm: sensors[nm] for nm in names},
                            "notes": args.notes,
                            "source": "tcomp record",
                            "start_time": started_utc,
                            "record": {"port": args.port, "period_s": args.period,
                                       "t_ms_at_time_0": t0_ms,
                                       "time_s": "the board's clock (t_ms, followed across its 2^30 ms wrap) since "
                                                 "the first answer, taken at start_time"},
                            "board": dict(hello.as_dict(), channel_names=names)}
                    if hal is not None:
                        meta["record"]["linuxcnc"] = {
                            "pins": dict(zip(("position", "velocity", "spindle"), hal.pins)), "units": args.units,
                            "time_s": "this host's monotonic clock since the first answer (the board's and the "
                                      "host's clocks drift apart by their crystals' tolerance, ~50 ppm)"}
                    try:
                        writer = RunWriter(args.out, names, meta, time_s, values, early_faults)
                    except OSError as exc:
                        raise UserError("--out %s: cannot write: %s" % (args.out, exc.strerror or exc))
                else:
                    writer.sample(time_s, values)
                if hal is not None:
                    assert host_t0 is not None  # set with t0_ms by the first answer, before any sample
                    _sample_hal(writer, hal, motion, time.monotonic() - host_t0)
            except RecordStop as exc:
                if writer is None:
                    raise UserError(str(exc))
                stop = str(exc)
                break
    except (KeyboardInterrupt, _Terminated):
        pass
    finally:
        link.close()
        if writer is not None and hal is not None:
            assert motion is not None  # made with hal
            try:
                writer.append(MOTION, MOTION_COLUMNS, [_motion_row(r) for r in motion.finish()])
            except RecordStop as exc:
                stop = stop or str(exc)
        if hal is not None:
            hal.close()
        if writer is not None:
            writer.close()
    faulty = writer.faulty_samples if writer else faulty_before
    if writer is None:
        print("record: no sample with every channel good (%d with a faulty channel); %s not written"
              % (faulty, args.out), file=sys.stderr)
    else:
        assert writer.temperatures is not None  # RunWriter made it or raised
        # the rows the file holds: a Ctrl-C between a sample's write and a counter's increment cannot make them disagree
        print("%d samples in %s%s%s" % (writer.temperatures.rows, args.out,
                                         ", %d with a faulty channel in %s" % (faulty, "board_faults.csv") if faulty else "",
                                         ", %d malformed frames skipped" % skipped if skipped else ""))
    if stop:
        print("record: %s; the run holds every sample recorded before" % stop, file=sys.stderr)
        return 1
    return 0 if writer is not None else 1
