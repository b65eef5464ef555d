"""tcomp upload --port PORT --table table.bin --key KEY [--baud N] [--timeout S] [--json OUT]

A new table for a running board over its link (docs/protocol.md, the U commands): U,B signed with the board's key,
the U,D chunks and U,C bound to that U,B (host/board/linkauth.py ``LinkSigner.upload_lines``), each line sent after
the board acknowledged the one before. Verified by the board's hello after the commit: it must report the new
table's CRC. Refusals (another key, a replayed counter, the flash-write budget, an open upload, a table the board
rejects) end it with one line naming the cause. Until U,C succeeds the old table stays in force; an interrupted
upload (Ctrl-C, a lost link) leaves it in force (the half-written slot is the one not in force, firmware/slots.py).

`tcomp flash` copies files with mpremote through a board's REPL; this verb needs no REPL: a board in production,
a `tcomp board` simulated board, a board whose REPL is not free.
"""
from __future__ import annotations

import argparse
import sys
from collections.abc import Callable
from typing import Any

DEFAULT_TIMEOUT_S = 15.0  # per line; the commit checks the table's SHA-256 on the board (seconds on a Cortex-M0+)


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("--port", required=True, help="serial port of the running board (a device, a pty, a pySerial URL)")
    p.add_argument("--table", required=True, help="coefficient table to upload (tcomp export)")
    p.add_argument("--key", required=True, metavar="FILE",
                   help="the board's key file (64 hex digits: the one tcomp board --key or tcomp flash --key provisioned)")
    p.add_argument("--baud", type=int, default=115200, help="baud rate (default 115200)")
    p.add_argument("--timeout", type=float, default=DEFAULT_TIMEOUT_S,
                   help="seconds to wait for the board's answer to each line (default %g)" % DEFAULT_TIMEOUT_S)
    p.add_argument("--json", help="write {port, table, table_crc, kind, bytes, lines, uploaded, before: hello, after: hello} as JSON")


class UploadRefused(Exception):
    """The board answered a line with an E frame: ``cause`` says why in the user's words."""

    def __init__(self, cause: str, frame: Any) -> None:
        super().__init__(cause)
        self.cause = cause
        self.frame = frame


def refusal_cause(frame: Any, step: str, key_path: str) -> str:
    """One sentence for the board's E frame answering upload step ``step`` (B, D, C)."""
    from firmware.wire import E_AUTH, E_BUSY, E_STATE, E_TABLE
    code = frame.fields[0] if frame.fields else "?"
    detail = ",".join(frame.fields[2:])
    if code == "%d" % E_AUTH:
        if detail == "bad tag":
            return ("the board refused the signature (E,8,auth,bad tag): %s is not this board's key, or the line was "
                    "changed on the way" % key_path)
        if detail == "replayed counter":
            return ("the board refused a replayed counter (E,8,auth,replayed counter): another controller signed a "
                    "command with this key meanwhile; run tcomp upload again (it reads the board's counter anew)")
        if detail == "no key":
            return ("the board has no key (E,8,auth,no key): provision one (tcomp board --key FILE, tcomp flash --key "
                    "FILE) and upload with that file")
        if detail == "counter exhausted":
            return ("the board's counter is exhausted (E,8,auth,counter exhausted): provision a new key "
                    "(tcomp flash --key NEWFILE)")
        return "the board refused the authorisation (E,8,auth,%s; docs/protocol.md, Error codes)" % detail
    if code == "%d" % E_BUSY:
        return ("the board is busy (E,9,busy): its flash-write budget is used up (docs/protocol.md, Flash wear: one "
                "write a minute refills it); retry in a minute")
    if code == "%d" % E_STATE and step == "B" and detail == "upload open":
        return ("another upload is open on the board (E,5,state,upload open): it ends with its commit or 60 s after "
                "its last chunk; retry then")
    if code == "%d" % E_TABLE:
        return "the board refused the table (E,6,table,%s); its old table stays in force" % detail
    return "the board answered U,%s with %s" % (step, frame.raw.decode("ascii", "replace").strip())


def _answer(link, since, timeout, what):
    """The first A or E frame from index ``since`` of the link's frames (others, such as O, pass by)."""
    return link.wait(lambda f: f.kind in ("A", "E"), timeout, since, what=what)


def send_upload(link: Any, table: bytes, timeout: float,
                progress: Callable[[int, int], None] | None = None) -> tuple[Any, int]:
    """Every line of the upload, each after the board acknowledged the previous one; the A,U,C frame.
    UploadRefused (with the board's E frame) when a line is refused; LinkError when the board does not answer."""
    lines = link.upload_lines(table)
    steps = ["B"] + ["D"] * (len(lines) - 2) + ["C"]
    sent = 0
    for i, (line, step) in enumerate(zip(lines, steps)):
        with link.lock:
            n0 = len(link.frames)
        link.write(line)
        a = _answer(link, n0, timeout, "answer to U,%s (line %d of %d)" % (step, i + 1, len(lines)))
        if a.kind == "E":
            raise UploadRefused(step, a)
        if a.fields[:2] != ["U", step]:
            raise UploadRefused(step, a)
        if step == "D":
            sent = int(a.fields[2]) if len(a.fields) > 2 and a.fields[2].isdigit() else sent
            if progress is not None:
                progress(sent, len(table))
    return a, len(lines)


def run(args: argparse.Namespace) -> int:
    import math

    from host.errors import UserError
    from host.outputs import Outputs

    if not (math.isfinite(args.timeout) and args.timeout > 0):
        raise UserError("--timeout %s: must be a positive number of seconds" % args.timeout)
    if args.baud < 1:
        raise UserError("--baud %d: must be a positive rate in bit/s" % args.baud)
    with Outputs([args.port, args.table, args.key]) as outputs:
        if args.json:
            outputs.file(args.json, "--json")
        rc, summary = _upload(args)
        if args.json:
            import json
            with outputs.open(args.json) as fh:
                json.dump(summary, fh, indent=1)
        outputs.commit()
    return rc


def _upload(args):
    from host.board.client import BoardLink, LinkError
    from host.board.linkauth import CounterError, signer_for_option
    from host.errors import UserError

    from host.cli.tablefile import read_table

    data, table = read_table(args.table)
    crc = "%08X" % table.crc
    signer = signer_for_option(args.key)
    try:
        link = BoardLink.open(args.port, args.baud, signer=signer, timeout=0.05)
    except LinkError as exc:
        raise UserError(str(exc))
    summary = {"port": args.port, "table": args.table, "table_crc": crc, "kind": table.kind, "bytes": len(data)}
    try:
        try:
            before = link.read_hello(timeout=args.timeout)
        except LinkError as exc:
            raise UserError("%s; nothing was sent to change the table" % exc)
        summary["before"] = before.as_dict()
        if before.counter in ("-", None):
            raise UserError("%s: the board has no key (its hello's counter is '-'), so it refuses every upload: "
                            "start it with tcomp board --key FILE, or provision one with tcomp flash --key FILE"
                            % args.port)
        if before.table_crc == crc:
            print("%s: the board already runs table %s (slot %s); nothing sent" % (args.port, crc, before.slot))
            summary.update(after=before.as_dict(), lines=0, uploaded=False)
            return 0, summary
        # a board without a table says "-" for its slot and CRC (docs/protocol.md, frame H)
        old = "table %s in slot %s" % (before.table_crc, before.slot) if before.table_crc not in (None, "", "-") \
            else "no table"
        print("%s: board %s (%s); uploading %s table %s, %d bytes" % (
            args.port, before.firmware, old, table.kind, crc, len(data)))
        sys.stdout.flush()
        try:
            ack, n_lines = send_upload(link, data, args.timeout)
        except CounterError as exc:
            raise UserError("%s: %s" % (args.port, exc))
        except UploadRefused as exc:
            _abort(link, args.timeout)
            raise UserError("%s: %s; the board keeps its old table (%s)" % (
                args.port, refusal_cause(exc.frame, exc.cause, args.key), old))
        except (LinkError, OSError) as exc:  # no answer, or the port failed (pyserial's errors are OSErrors)
            raise UserError("%s: the link failed mid-upload (%s); the upload is incomplete, so the board keeps its "
                            "old table (%s) and discards the upload 60 s after its last chunk" % (args.port, exc, old))
        except KeyboardInterrupt:
            _abort(link, 2.0)
            raise UserError("interrupted: the upload is incomplete, so the board keeps its old table (%s)" % old)
        try:
            after = link.read_hello(timeout=args.timeout)
        except LinkError as exc:
            raise UserError("%s: the board acknowledged the commit (slot %s) but gave no hello after it: %s"
                            % (args.port, ack.fields[2] if len(ack.fields) > 2 else "?", exc))
        summary.update(after=after.as_dict(), lines=n_lines, uploaded=True)
        if after.table_crc != crc:
            raise UserError("%s: the board acknowledged the commit, but its hello reports table %s, not %s"
                            % (args.port, after.table_crc, crc))
        print("%s: table %s in force in slot %s (was %s)" % (args.port, crc, after.slot, old))
        return 0, summary
    finally:
        link.close()


def _abort(link, timeout):
    """Best effort: close an upload this verb opened (U,X, signed), so the board is not UPLOADING for 60 s."""
    from host.board.client import LinkError
    from host.board.linkauth import CounterError
    try:
        with link.lock:
            n0 = len(link.frames)
        link.send_signed("U", "X")
        _answer(link, n0, timeout, "answer to U,X")
    except (LinkError, CounterError, OSError):
        pass
