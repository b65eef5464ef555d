"""tcomp linuxcnc --port PORT [--mode stream|modbus] ...: the LinuxCNC bridge (docs/linuxcnc.md)."""

from __future__ import annotations

import argparse


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("--port", required=True, help="serial port of the board (e.g. /dev/ttyACM0)")
    p.add_argument("--mode", choices=("stream", "modbus"), default="stream",
                   help="the board's serial mode (its config serial.mode; default stream)")
    p.add_argument("--baud", type=int, default=115200, help="baud rate (default 115200)")
    p.add_argument("--address", type=int, default=1, help="Modbus slave address (default 1)")
    p.add_argument("--name", default="tcomp", help="HAL component name, the pins' prefix (default tcomp)")
    p.add_argument("--units", choices=("mm", "inch"), default="mm", help="the machine's linear units (default mm)")
    p.add_argument("--slew-um-per-s", type=float, default=None,
                   help="ramp rate on a fault, um/s: the board's slew limit (its config slew_um_per_s; "
                        "Modbus: read from the board when not given; default: the firmware default)")
    p.add_argument("--period-ms", type=int, default=50, help="bridge period, ms (default 50)")
    p.add_argument("--stale-ms", type=int, default=1000,
                   help="no new frame for this long is a fault (default 1000)")
    p.add_argument("--recover-ms", type=int, default=1000,
                   help="a fault ends after this long without any fault reason (default 1000)")
    p.add_argument("--key", help="the board's key file (tcomp flash --key): signs L; without it a keyed "
                                "board refuses L")
    p.add_argument("--cold-start", action="store_true",
                   help="this start is a cold start: send L when the machine is first switched on "
                        "(as the cold-start pin)")
    p.add_argument("--signal-record", metavar="FILE",
                   help="keep the controller's record of the spindle speed in FILE (written atomically every minute and at "
                        "exit; created if missing) and send a dynamic table the lag states it asks the controller to supply "
                        "(table format 7, fit option spindle_states=controller; docs/linuxcnc.md). Needs --spindle")
    p.add_argument("--spindle", action="store_true",
                   help="send the spindle-rpm pin to the board with the position (P,<pos>,<rpm>, or holding "
                        "registers 18-19): for dynamic tables that use the spindle speed")
    p.add_argument("--feed", action="store_true",
                   help="send the axis feed from the velocity pin (commanded axis velocity, machine units/s) as M,<mm/min>,<pos>,<pos> "
                        "when a move starts, when its feed changes by more than 2 %%, and feed 0 when it ends: for dynamic "
                        "tables that use the feed (feed_m_min). Stream mode only (Modbus has no feed register); with "
                        "--signal-record the record keeps the feed too")


def _check(args):
    from host.errors import UserError
    if not 1 <= args.period_ms <= 1000:
        raise UserError("--period-ms %d: must be 1..1000" % args.period_ms)
    if args.stale_ms < 2 * args.period_ms or args.recover_ms < 0:
        raise UserError("--stale-ms %d: must be at least twice --period-ms (%d); --recover-ms %d must be >= 0"
                        % (args.stale_ms, args.period_ms, args.recover_ms))
    if args.slew_um_per_s is not None and not 0 < args.slew_um_per_s <= 10000:
        raise UserError("--slew-um-per-s %g: must be in (0, 10000] (the firmware's range)" % args.slew_um_per_s)
    if not 1 <= args.address <= 247:
        raise UserError("--address %d: must be 1..247" % args.address)
    if args.feed and args.mode == "modbus":
        raise UserError("--feed needs --mode stream: the board's Modbus map has no register for the axis feed (M is a "
                        "stream command; docs/protocol.md)")
    if args.signal_record and not args.spindle:
        raise UserError("--signal-record %s needs --spindle: the board's own lag filters read the speed the bridge sends"
                        % args.signal_record)


def _log(msg):
    import sys
    import time
    print("tcomp linuxcnc %s: %s" % (time.strftime("%H:%M:%S"), msg), file=sys.stderr, flush=True)


def run(args: argparse.Namespace) -> int:
    import serial

    from firmware.bootcfg import TOP
    from host.errors import UserError
    from host.board.linuxcnc import halcomp
    from host.board.linuxcnc.bridge import Bridge, ModbusLink, StreamLink

    _check(args)
    record = None
    if args.signal_record:
        import time
        from host.board.supplied import SignalRecord, SupplyError
        try:
            record = SignalRecord.load(args.signal_record, time.time())
        except SupplyError as exc:
            raise UserError(str(exc))
        _log("signal record %s: %d events%s" % (args.signal_record, len(record.events),
                                                 "" if record.events else " (new: the lags start at the first speed)"))
    from host.board.linkauth import signer_for_option
    signer = signer_for_option(args.key)
    try:
        comp = halcomp.component(args.name)
    except ImportError as exc:
        raise UserError(str(exc))
    except Exception as exc:  # _hal raises RuntimeError/ValueError for a duplicate name or no HAL running
        raise UserError("cannot create HAL component %r: %s (is LinuxCNC or halrun running?)" % (args.name, exc))
    slew = args.slew_um_per_s
    if args.mode == "stream":
        def open_port():
            return serial.serial_for_url(args.port, args.baud, timeout=0, write_timeout=0.5)  # a device path or a pySerial URL
        try:
            open_port().close()
        except (serial.SerialException, OSError) as exc:
            raise UserError("cannot open %s: %s" % (args.port, exc))
        link = StreamLink(open_port, signer=signer)
    else:
        from pymodbus.client import ModbusSerialClient
        client = ModbusSerialClient(args.port, baudrate=args.baud, timeout=0.2, retries=0)
        if not client.connect():
            raise UserError("cannot open %s (Modbus RTU)" % args.port)
        link = ModbusLink(client, args.address, signer)
        if slew is None:
            slew = link.slew_um_per_s()
            if slew is not None:
                _log("board slew limit %d um/s (holding register 1)" % slew)
    if slew is None:
        slew = dict((k, d) for k, d, _, _ in TOP)["slew_um_per_s"]
        _log("slew limit: firmware default %g um/s (give --slew-um-per-s if the board's config differs)" % slew)
    bridge = Bridge(link, slew, units=args.units, stale_s=args.stale_ms / 1000.0,
                    recover_s=args.recover_ms / 1000.0, cold_start=args.cold_start, log=_log,
                    max_dt_s=2 * args.period_ms / 1000.0, send_spindle=args.spindle, record=record,
                    record_path=args.signal_record, send_feed=args.feed)
    _log("%s on %s (%s), period %d ms" % (args.name, args.port, args.mode, args.period_ms))
    try:
        halcomp.serve(comp, bridge, args.period_ms / 1000.0)
    finally:
        bridge.save_record()
        link.close()
    return 0
