"""tcomp monitor --port PORT [--csv LOG] [--count N] [--duration S] [--latch] [--temperatures S]
              [--query MM[,MM...] [--query-every S]]"""

from __future__ import annotations

import argparse
from typing import TYPE_CHECKING, Any

import csv
import math
import re
import sys
import time

if TYPE_CHECKING:
    from host.board.link import Frame
    pass

LATCH_WAIT_S = 5.0  # the firmware answers L within one cycle (cycle_ms, 100 ms by default)
COLUMNS: tuple[str, ...] = ("seq", "kind", "status", "flags", "t_ms", "pos_um", "total_um", "ref_offset_um", "slope_um_per_m",
           "fields")


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("--port", required=True, help="serial port or pySerial URL (e.g. /dev/ttyACM0, socket://host:port, spy:///dev/ttyACM0, loop://)")
    p.add_argument("--baud", type=int, default=115200, help="baud rate (default 115200)")
    p.add_argument("--csv", help="append every decoded frame to this CSV file")
    p.add_argument("--count", type=int, default=0, help="stop after this many frames (0: never)")
    p.add_argument("--duration", type=float, default=0.0, help="stop after this many seconds (0: never)")
    p.add_argument("--hello", action="store_true", help="ask the board for its hello frame (V) first")
    p.add_argument("--latch", action="store_true",
                   help="declare a cold start: send L (re-latch the reference temperatures, docs/protocol.md) and "
                        "report the answer; without --count/--duration stop at the answer (exit 1 if refused)")
    p.add_argument("--key", help="the board's key file (tcomp flash --key): --latch signs L with it (the board "
                                "refuses an unsigned L when it has a key)")
    p.add_argument("--temperatures", type=float, default=0.0, metavar="SECONDS",
                   help="ask for the temperatures (S) every SECONDS: T frames are shown and logged with the others "
                        "(t_ms, then the channels' degC in the fields column). To record a thermal test into a run "
                        "folder use tcomp record")
    p.add_argument("--query", metavar="MM[,MM...]",
                   help="ask for the offsets at these axis positions (mm; Q commands, docs/protocol.md) every "
                        "--query-every seconds: Q frames are shown and logged with the others. For a board whose "
                        "controller reports no positions (a tcomp board, a bench), so that a log holds the offsets "
                        "at a laser's target positions (tcomp check)")
    p.add_argument("--query-every", type=float, default=1.0, metavar="SECONDS",
                   help="with --query: seconds between two rounds of queries (default 1, at least 0.05)")
    p.add_argument("--json", help="write {frames, malformed, rows: [decoded frames], bad: [reasons]} as JSON at the end")


_INTEGER = re.compile(r"-?[0-9]+\Z")
_DECIMAL = re.compile(r"-?[0-9]+(\.[0-9]+)?\Z")  # what the firmware prints: an integer model, no nan/inf/exponent
MAX_FIELD_CHARS = 24  # a 32-bit integer and its decimals print in 12; 400 digits would read as inf
OFFSET_FIELDS = (("t_ms", _INTEGER), ("pos_um", _INTEGER), ("total_um", _DECIMAL), ("ref_offset_um", _DECIMAL),
                 ("slope_um_per_m", _DECIMAL))


def offset_problem(f: Frame) -> str | None:
    """Why an O or Q frame's fields are not the offsets docs/protocol.md defines (None when they are).

    A frame with a good CRC can still carry 'nan' or '1e999' (a faulty or foreign board): such a frame is
    counted as malformed, never written into the CSV or JSON rows as if it were an offset."""
    if f.kind not in ("O", "Q"):
        return None
    if len(f.fields) != len(OFFSET_FIELDS):
        return "%s frame seq %d: %d fields, expected %d (%s)" % (f.kind, f.seq, len(f.fields), len(OFFSET_FIELDS),
                                                               ",".join(n for n, _ in OFFSET_FIELDS))
    for (name, pattern), value in zip(OFFSET_FIELDS, f.fields):
        if len(value) > MAX_FIELD_CHARS or not pattern.match(value):
            return "%s frame seq %d: %s %r is not a finite %s" % (f.kind, f.seq, name, value[:40],
                                                                 "integer" if pattern is _INTEGER else "decimal number")
    return None


def query_positions(text: str | None) -> list[int] | None:
    """``--query`` "0,50,100.5" (mm) -> [0, 50000, 100500] (the integer µm of the Q command); None without it;
    UserError naming the cell that is not a finite number."""
    from host.errors import UserError
    if text is None:
        return None
    out = []
    for cell in text.split(","):
        try:
            mm = float(cell)
        except ValueError:
            mm = math.nan
        if not math.isfinite(mm) or abs(mm) > 1e6:
            raise UserError("--query %s: %r is not a position in mm (comma-separated numbers, e.g. 0,50,100)"
                            % (text, cell.strip()))
        out.append(int(round(mm * 1000.0)))
    return out


def row(f: Frame) -> dict[str, Any]:
    """A decoded frame as the monitor's columns."""
    from host.board.link import SENSOR_MASK, STATUS_BITS
    flags = [n for bit, n in STATUS_BITS.items() if f.status & bit]
    if f.status & SENSOR_MASK:
        flags.append("sensors:%04X" % (f.status & SENSOR_MASK))
    r = {"seq": f.seq, "kind": f.kind, "status": "%08X" % f.status, "flags": "|".join(flags),
         "t_ms": "", "pos_um": "", "total_um": "", "ref_offset_um": "", "slope_um_per_m": "",
         "fields": ",".join(f.fields)}
    if f.kind == "T" and f.fields:  # temperatures (docs/protocol.md): t_ms, then degC.mmm or !<fault bits> per channel
        r.update(t_ms=f.fields[0], fields=",".join(f.fields[1:]))
    if f.kind in ("O", "Q") and len(f.fields) >= 5:
        r.update(t_ms=f.fields[0], pos_um=f.fields[1], total_um=f.fields[2], ref_offset_um=f.fields[3],
                 slope_um_per_m=f.fields[4], fields="")
    return r


def error_reference_line(frame: Frame) -> str:
    """The line `tcomp monitor` prints for a hello: which errors the board's table compensates."""
    from host.board.link import describe_error_reference, hello_error_reference

    return "error reference %s" % describe_error_reference(hello_error_reference(frame))


def run(args: argparse.Namespace) -> int:
    from host.errors import UserError
    from host.outputs import Outputs

    if not (math.isfinite(args.temperatures) and (args.temperatures == 0 or args.temperatures >= 0.05)):
        raise UserError("--temperatures %s: must be a number of seconds >= 0.05 (0: never ask)" % args.temperatures)
    for flag, value in (("--baud", args.baud), ("--count", args.count), ("--duration", args.duration)):
        if not value >= (1 if flag == "--baud" else 0):
            raise UserError("%s %s: must be %s" % (flag, value, "a positive rate in bit/s" if flag == "--baud" else ">= 0 (0: no limit)"))
    args.query_um = query_positions(args.query)
    if not (math.isfinite(args.query_every) and args.query_every >= 0.05):
        raise UserError("--query-every %s: must be a number of seconds >= 0.05" % args.query_every)
    if not math.isfinite(args.duration):  # inf would never stop; 0 is the way to say "no limit"
        raise UserError("--duration %s: must be a finite number of seconds (0: no limit, Ctrl-C stops)" % args.duration)
    # The key is an input too: --csv KEY or --json KEY would overwrite the board's key.
    with Outputs([args.port, args.key]) as outputs:
        if args.csv:
            outputs.log(args.csv, "--csv")
        if args.json:
            outputs.file(args.json, "--json")
        rc = _monitor(args, outputs)
        outputs.commit()
    return rc


def _monitor(args, outputs):
    import serial

    from firmware.wire import E_AUTH, E_BUSY, E_STATE
    from host.board.client import BoardLink, LinkError, check_protocol
    from host.errors import UserError
    try:
        link = BoardLink.open(args.port, args.baud, timeout=0.1)
    except LinkError as exc:
        raise UserError(str(exc))
    out = None
    writer = None
    rows = []
    bad_reasons = []
    if args.csv:
        try:
            out = open(args.csv, "a", newline="", encoding="utf-8")
        except OSError as exc:
            raise UserError("cannot write %s: %s" % (args.csv, exc))
        writer = csv.DictWriter(out, COLUMNS)
        if out.tell() == 0:
            writer.writeheader()
    dec = link.decoder
    n = 0
    bad = 0
    start = time.monotonic()
    next_s = start  # when temperatures (S) are asked for next, with --temperatures
    next_q = start  # when the offsets at the --query positions (Q) are asked for next
    print("%6s %1s %8s %10s %10s %9s %9s %9s  %s" % ("seq", "", "status", "t_ms", "pos_um", "total_um",
                                                      "ref_um", "slope", "flags / fields"))
    latch = None  # the board's answer to L: "ok" or "refused"
    until_answer = args.latch and not (args.count or args.duration)
    from host.board.linkauth import signer_for_option
    signer = link.signer = signer_for_option(args.key)
    latch_sent = False
    try:
        if args.hello or signer is not None and args.latch:
            link.send("V")  # a signed L needs the board's last counter, the hello's last field
        if args.latch and signer is None:
            link.send("L")
            latch_sent = True
        while not (args.count and n >= args.count) and not (args.duration and time.monotonic() - start
                                                               >= args.duration):
            if until_answer and latch:
                break
            if until_answer and time.monotonic() - start >= LATCH_WAIT_S:
                raise UserError("%s: no answer to L within %g s" % (args.port, LATCH_WAIT_S))
            if args.temperatures and time.monotonic() >= next_s:
                link.send("S")
                next_s += args.temperatures
            if args.query_um and time.monotonic() >= next_q:
                for pos_um in args.query_um:
                    link.send("Q", pos_um)
                next_q += args.query_every
            try:
                new = link.receive()
            except serial.SerialException as exc:
                raise UserError("%s: %s" % (args.port, exc))
            link.take_frames()  # printed and logged here as they come; nothing is kept
            for f in new:
                why = offset_problem(f)
                if why:
                    dec.bad.append((f.raw, why))
                    continue
                if f.kind == "H":
                    try:
                        check_protocol(f, args.port)
                    except LinkError as exc:
                        raise UserError(str(exc))
                r = row(f)
                if f.kind == "H":
                    print(error_reference_line(f))
                print("%6d %1s %8s %10s %10s %9s %9s %9s  %s" % (
                    f.seq, f.kind, r["status"], r["t_ms"], r["pos_um"], r["total_um"], r["ref_offset_um"],
                    r["slope_um_per_m"], (r["flags"] + " " + r["fields"]).strip()))
                if args.latch and not latch_sent and f.kind == "H" and signer is not None:  # (no signer: L sent above)
                    try:
                        line = link.signed_line("L")  # for the session of this hello (the newest)
                    except ValueError as exc:  # host.board.linkauth.CounterError: the hello's counter or nonce
                        raise UserError("%s: --latch: %s" % (args.port, exc))
                    link.write(line)
                    latch_sent = True
                if latch_sent and latch is None and (f.kind == "A" and f.fields[:1] == ["L"]
                                                     or f.kind == "E" and f.fields[:1] in (["%d" % E_STATE], ["%d" % E_AUTH],
                                                                                           ["%d" % E_BUSY])):
                    latch = "ok" if f.kind == "A" else "refused"
                    print("L acknowledged, references %s" % ",".join(f.fields[1:]) if f.kind == "A"
                          else "L refused: %s" % ",".join(f.fields[2:] if f.fields[0] == "%d" % E_STATE else f.fields[1:]))
                if writer:
                    writer.writerow(r)
                if args.json:
                    rows.append(r)
                n += 1
                if args.count and n >= args.count or until_answer and latch:
                    break
            while dec.bad:
                line, why = dec.bad.pop(0)
                bad += 1
                if args.json:
                    bad_reasons.append(str(why))
                print("bad frame: %s" % why, file=sys.stderr)
            sys.stdout.flush()
    except KeyboardInterrupt:
        pass
    finally:
        link.close()
        if out:
            out.close()
    print("%d frames, %d malformed" % (n, bad))
    if args.json:
        import json

        with outputs.open(args.json) as fh:
            json.dump({"port": args.port, "frames": n, "malformed": bad, "rows": rows, "bad": bad_reasons}, fh, indent=1)
    return 1 if latch == "refused" else 0
