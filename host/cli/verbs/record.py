"""tcomp record --port PORT --out RUN --sensor NAME=ROLE[:LOCATION]... [--config board.json] [--period S] [--duration S]

Polls the board's temperatures (``S`` -> ``T`` frame) every ``--period`` seconds into a run folder that is valid at
every instant (host/board/recorder.py, docs/recording.md). ``time_s`` is the board's clock (t_ms, followed across
its 2^30 ms wrap) from the first sample; meta.json holds the wall-clock time of that sample. Ctrl-C or SIGTERM end
the recording (exit 0); a silent or lost link, a restarted board or a full disk end it with a message (exit 1).
Either way the folder holds every sample written before.
"""
import math
import re
import signal
import sys
import time

DEFAULT_PERIOD_S = 1.0
_DECIMAL = re.compile(r"-?[0-9]{1,6}(\.[0-9]{1,6})?\Z")  # what the firmware prints for a good channel: degC.mmm


def add_arguments(p):
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


def run(args):
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
    try:
        return _record(args, sensors, config_names)
    finally:
        signal.signal(signal.SIGTERM, previous)


def _record(args, sensors, config_names):
    import datetime

    import serial

    from host.board.client import BoardLink, ClockError, LinkError
    from host.board.recorder import RecordStop, RunWriter, sensor_names
    from host.errors import UserError

    try:
        link = BoardLink.open(args.port, args.baud)
        hello = link.read_hello(timeout=args.link_timeout)
    except LinkError as exc:
        raise UserError(str(exc))
    writer = None
    stop = None  # why the recording ended early (exit 1), None for the end asked for
    n = skipped = 0
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
        due = start
        last_ms = None
        while not (args.duration and time.monotonic() - start >= args.duration):
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
                ms = link.clock.extend(f.fields[0])
            except (ClockError, ValueError) as exc:
                stop = "%s: %s" % (args.port, exc)
                break
            if writer is None:
                t0_ms = int(f.fields[0])
                wall = datetime.datetime.now(datetime.timezone.utc).isoformat(timespec="milliseconds")
                meta = {"sensors": {nm: sensors[nm] for nm in names},
                        "notes": args.notes,
                        "source": "tcomp record",
                        "record": {"started_utc": wall, "port": args.port, "period_s": args.period,
                                   "t_ms_at_time_0": t0_ms,
                                   "time_s": "the board's clock (t_ms, followed across its 2^30 ms wrap) since the "
                                             "first sample, taken at started_utc"},
                        "board": dict(hello.as_dict(), channel_names=names)}
                try:
                    writer = RunWriter(args.out, names, meta)
                except RecordStop as exc:
                    raise UserError(str(exc))
                except OSError as exc:
                    raise UserError("--out %s: cannot write: %s" % (args.out, exc.strerror or exc))
            elif ms <= last_ms:
                continue  # the same cycle's temperatures again (a period shorter than the board's cycle)
            last_ms = ms
            try:
                if writer.sample(ms / 1000.0, values):
                    n += 1
            except RecordStop as exc:
                stop = str(exc)
                break
            due += args.period
            delay = due - time.monotonic()
            if delay > 0:
                time.sleep(delay)
            else:
                due = time.monotonic()
    except (KeyboardInterrupt, _Terminated):
        pass
    finally:
        link.close()
        if writer is not None:
            writer.close()
    faulty = writer.faulty_samples if writer else 0
    if writer is None:
        print("record: no sample recorded; %s not written" % args.out, file=sys.stderr)
    else:
        print("%d samples in %s%s%s" % (n, args.out,
                                         ", %d with a faulty channel in %s" % (faulty, "board_faults.csv") if faulty else "",
                                         ", %d malformed frames skipped" % skipped if skipped else ""))
    if stop:
        print("record: %s; the run holds every sample recorded before" % stop, file=sys.stderr)
        return 1
    return 0 if writer is not None else 1
