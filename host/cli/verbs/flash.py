"""tcomp flash --port PORT [--table table.bin] [--config board.json | --board board.py] [--key board.key]"""

from __future__ import annotations

import argparse
from collections.abc import Iterable
from typing import Any, cast

import json
import os
import re
import shutil
import subprocess
import sys
import tempfile



def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("--port", required=True, help="serial port of the board (e.g. /dev/ttyACM0, or a pty)")
    p.add_argument("--table", help="coefficient table (tcomp export) installed as slot A and made active")
    g = p.add_mutually_exclusive_group()
    g.add_argument("--config", help="board config JSON (firmware/board.py format); generates tcomp_board.py "
                                    "around firmware/boards/rp2040.py's make_board")
    g.add_argument("--board", help="your board file, copied to the board root as tcomp_board.py")
    p.add_argument("--table-dir", help="table directory on the board (default: the config's table_dir, else /tables)")
    p.add_argument("--no-firmware", action="store_true", help="copy only the table and the board file")
    p.add_argument("--reset", action="store_true", help="soft-reset the board afterwards so that main.py runs "
                                                        "(not for a unix-port board: it would exit)")
    p.add_argument("--mpremote", default=None, help="mpremote executable (default: the one next to this Python)")
    p.add_argument("--dry-run", action="store_true", help="print the mpremote command instead of running it")
    p.add_argument("--key", metavar="FILE",
                   help="the board's key (64 hex digits, host/board/linkauth.py), written to the board's table directory "
                        "as key.bin; a new random key is created in FILE (mode 0600) when FILE does not exist. "
                        "Without a key the board refuses every command that changes its output (table upload, "
                        "L, X, Modbus enable/slew/timeout/latch). The key is never printed")


def _mpremote(explicit):
    if explicit:
        return explicit
    here = os.path.join(os.path.dirname(sys.executable), "mpremote")
    return here if os.path.exists(here) else (shutil.which("mpremote") or "mpremote")


def stage(dest: str, table: str | None = None, config: str | None = None, board: str | None = None, table_dir: str | None = None,
          firmware: bool = True, key: bytes | None = None, new_key: bool = False) -> tuple[dict[str, list[str]], str]:
    """Lay out the board's flash under ``dest``; returns {remote dir: [local files]} and the table dir.
    ``key``: the board key (bytes), staged as ``<table dir>/key.bin`` (mode 0600); ``new_key``: it was
    just created, so ``auth.bin`` is staged too, starting its counters at 0 (re-provisioning,
    docs/protocol.md "Counters")."""
    from host.errors import UserError
    files = {}
    if firmware:
        # exactly the .mpy files firmware/manifest.py lists, as the tests and the HIL rig run them
        # (host/board/fwbuild.py), and main.py, which boots the compiled firmware/main.mpy
        from host.board.fwbuild import BOOT_MAIN, BuildError, build
        try:
            built = build()
        except BuildError as exc:
            raise UserError("cannot build the firmware: %s" % exc)
        for target, path in built.files:
            out = os.path.join(dest, target)
            os.makedirs(os.path.dirname(out), exist_ok=True)
            shutil.copy(path, out)
            files.setdefault(os.path.dirname(target), []).append(out)
        path = os.path.join(dest, "main.py")
        with open(path, "wb") as f:
            f.write(BOOT_MAIN)
        files.setdefault("", []).append(path)
    cfg = None
    if config:
        try:
            with open(config, encoding="utf-8") as f:
                cfg = json.load(f)
        except (OSError, json.JSONDecodeError) as exc:
            raise UserError("%s: cannot read the board config: %s" % (config, exc))
        try:
            from host.board.config import load_config
            load_config(cfg)
        except ValueError as exc:
            raise UserError("%s: %s" % (config, exc))
        path = os.path.join(dest, "tcomp_board.py")
        with open(path, "w", encoding="utf-8") as f:
            f.write('"""Board file written by tcomp flash from %s."""\n' % os.path.basename(config))
            f.write("CONFIG = %r\n\n\n" % (cfg,))
            f.write("def make_board(config=CONFIG):\n")
            f.write("    from firmware.boards.rp2040 import make_board as _make\n")
            f.write("    return _make(config)\n")
        files.setdefault("", []).append(path)
    elif board:
        if not os.path.isfile(board):
            raise UserError("%s: board file is missing" % board)
        path = os.path.join(dest, "tcomp_board.py")
        shutil.copy(board, path)
        files.setdefault("", []).append(path)
    if table_dir is not None:
        tdir = board_dir(table_dir, "--table-dir")
    elif cfg is not None and "table_dir" in cfg:
        tdir = board_dir(cfg["table_dir"], "%s: table_dir" % config)
    else:
        tdir = "tables"
    if table:
        try:
            with open(table, "rb") as f:
                data = f.read()
        except OSError as exc:
            raise UserError("%s: cannot read the table: %s" % (table, exc))
        try:
            from firmware.table import parse_table
            sensors = parse_table(data).sensors
        except Exception as exc:  # firmware.table.TableError or a malformed file
            raise UserError("%s: not a valid coefficient table: %s" % (table, exc))
        wiring, source = (cfg, config) if cfg is not None else (board_file_config(board), board) if board else (None, None)
        if wiring is None:
            # Without the board's config the check cannot be made here; the board refuses such a table at boot.
            print("tcomp flash: warning: the table's sensors (%s) are not checked against the board's channels: %s"
                  % (", ".join(sensors), "give --config" if not board else
                     "%s has no CONFIG dict that can be read without running the file" % board), file=sys.stderr)
        missing = unwired_sensors(sensors, wiring) if wiring is not None else []
        if missing:
            raise UserError("%s: table sensor(s) %s have no channel in the board config %s" % (table, ", ".join(missing), source))
        os.makedirs(os.path.join(dest, tdir), exist_ok=True)
        for name, content in (("table_a.bin", data), ("active", b"A")):
            p = os.path.join(dest, tdir, name)
            with open(p, "wb") as f:
                f.write(content)
            files.setdefault(tdir, []).append(p)
    if key is not None:
        os.makedirs(os.path.join(dest, tdir), exist_ok=True)
        p = os.path.join(dest, tdir, "key.bin")
        fd = os.open(p, os.O_WRONLY | os.O_CREAT | os.O_EXCL, 0o600)
        with os.fdopen(fd, "wb") as f:
            f.write(key)
        files.setdefault(tdir, []).append(p)
        if new_key:  # both names: the board reads a complete auth.bin.new first (firmware/auth.py)
            from host.board.linkauth import counter_mark
            for name in ("auth.bin", "auth.bin.new"):
                p = os.path.join(dest, tdir, name)
                with open(p, "wb") as f:
                    f.write(counter_mark(0))
                files[tdir].append(p)
    return files, tdir


_BOARD_NAME = re.compile(r"[A-Za-z0-9_.-]+\Z")


def board_dir(text: str, where: str) -> str:
    """A folder on the board's flash as mpremote names it (``tables``, ``/data/tables``), without the slashes
    around it; UserError for an empty path, '.' or '..' parts (the staged copy would land outside its folder:
    ``../../etc`` is /etc of this computer) or characters outside letters, digits and ``_.-``."""
    from host.errors import UserError
    if not isinstance(text, str) or not text.strip("/"):
        raise UserError("%s %r: expected a folder on the board, e.g. tables or /tables" % (where, text))
    parts = text.strip("/").split("/")
    for part in parts:
        if part in (".", "..") or not _BOARD_NAME.match(part):
            raise UserError("%s %r: %r is not a folder name on the board (letters, digits, _ . -; no '.' or '..')"
                            % (where, text, part))
    return "/".join(parts)


def _plain_expression(node):
    """True when expression ``node`` is data built without running anything of the file: literals, names bound
    by its own comprehensions, + - % on them, comprehensions over ``range`` of constants up to 1000 (as
    firmware/boards/rp2040.py's CONFIG). No attribute, subscript, call other than range, lambda or import: nothing
    that reaches Python's objects, so evaluating it cannot run code; no '*' and small ranges keep it small."""
    import ast

    bound = {g.target.id for c in ast.walk(node) if isinstance(c, (ast.ListComp, ast.DictComp))
             for g in c.generators if isinstance(g.target, ast.Name)}
    allowed = (ast.Expression, ast.Constant, ast.Dict, ast.List, ast.Tuple, ast.ListComp, ast.DictComp,
               ast.comprehension, ast.BinOp, ast.UnaryOp, ast.Add, ast.Sub, ast.Mod, ast.USub, ast.Load,
               ast.Store, ast.Name, ast.Call)
    for n in ast.walk(node):
        if not isinstance(n, allowed):
            return False
        if isinstance(n, ast.Name) and n.id not in bound | {"range"}:
            return False
        if isinstance(n, ast.Call) and not (isinstance(n.func, ast.Name) and n.func.id == "range" and not n.keywords
                                            and all(isinstance(a, ast.Constant) and isinstance(a.value, int)
                                                    and abs(a.value) <= 1000 for a in n.args)):
            return False
        if isinstance(n, ast.Constant) and isinstance(n.value, str) and re.search(r"%[-+ #0]*[0-9]{3,}", n.value):
            return False  # a field width that builds a huge string
        if isinstance(n, ast.comprehension) and (n.ifs or n.is_async):
            return False
    return True


def board_file_config(path: str) -> dict[str, Any] | None:
    """The ``CONFIG = {...}`` dict at the top level of board file ``path`` (firmware/boards/*.py have one), validated;
    None when the file has none that can be read without running the file. A file that is not Python is a UserError."""
    import ast

    from host.errors import UserError
    try:
        with open(path, encoding="utf-8") as fh:
            tree = ast.parse(fh.read(), path)
    except (OSError, UnicodeDecodeError, SyntaxError, ValueError) as exc:
        raise UserError("%s: cannot read the board file as Python: %s" % (path, exc))
    for node in tree.body:
        if isinstance(node, ast.Assign) and any(isinstance(t, ast.Name) and t.id == "CONFIG" for t in node.targets):
            try:
                cfg = ast.literal_eval(node.value)
            except ValueError:
                # Computed (firmware/boards/rp2040.py builds its channels with a comprehension): evaluated alone when
                # it is plain data (_plain_expression), never the file; anything more is left to the board's boot check.
                expression = ast.Expression(node.value)
                if not _plain_expression(expression):
                    return None
                try:
                    cfg = eval(compile(expression, path, "eval"), {"__builtins__": {}, "range": range})
                except Exception:  # e.g. "T%d" % "x": not a config the board could boot either
                    return None
            if not isinstance(cfg, dict):
                return None
            try:
                from host.board.config import load_config
                load_config(cfg)
            except ValueError as exc:
                raise UserError("%s: CONFIG: %s" % (path, exc))
            return cfg
    return None


def board_key(path: str, dry_run: bool = False) -> tuple[bytes, bool]:
    """The key in ``path``: (key, created). A missing file gets a new random key, which the caller writes to ``path``
    (write_key) only once the board holds it: a dry run or a failed flash leaves no key file behind."""
    from host.errors import UserError, check_output
    from host.board.linkauth import KeyFileError, generate_key, read_key
    if not os.path.lexists(path):
        if dry_run:
            raise UserError("--key %s: the file does not exist, and a dry run creates no key; give an existing key file, "
                            "or run without --dry-run to create it" % path)
        check_output(path, "--key")  # writable before the flash, written after it
        return generate_key(), True
    try:
        return read_key(path), False
    except KeyFileError as exc:
        raise UserError(str(exc))


def unwired_sensors(table_sensors: Iterable[str], cfg: dict[str, Any]) -> list[str]:
    """Table sensors without a channel of the same name in board config ``cfg`` (a dict), in table order.

    The firmware refuses such a table with its generic reason "sensor count mismatch"; checked here first,
    the user reads which sensor is missing.
    """
    wired = {c.get("name") for c in cfg.get("channels") or () if isinstance(c, dict)}
    return [s for s in table_sensors if s not in wired]


def command(port: str, files: dict[str, list[str]], mpremote: str = "mpremote", reset: bool = False) -> list[str]:
    """One mpremote invocation (``resume``: no soft reset on connect) that creates the directories
    and copies every file."""
    dirs = sorted({d for d in files if d})
    mk = "import os\nfor d in %r:\n    try:\n        os.mkdir(d)\n    except OSError:\n        pass\n" % (
        [p for d in dirs for p in _parents(d)],)
    argv = [mpremote, "connect", port, "resume", "exec", mk]
    for d in sorted(files):
        argv += ["+", "fs", "cp"] + files[d] + [":" + (d + "/" if d else "./")]
    if reset:
        argv += ["+", "soft-reset"]
    return argv


def _parents(d):
    parts = d.split("/")
    return ["/".join(parts[:i + 1]) for i in range(len(parts))]


PROBE_TIMEOUT_S = 20.0  # a board answers mpremote's raw REPL in about a second; nobody answering is not worth 300 s
COPY_TIMEOUT_S = 300.0


def _run_mpremote(argv, port, timeout, what):
    from host.errors import UserError
    try:
        p = subprocess.run(argv, capture_output=True, text=True, timeout=timeout)
    except FileNotFoundError:
        raise UserError("mpremote not found (%s); install the dev extra" % argv[0])
    except subprocess.TimeoutExpired:
        raise UserError("mpremote did not %s within %g s on %s; nothing answered (is it the board's port, and "
                        "is the board's REPL free?)" % (what, timeout, port))
    if p.returncode != 0:
        raise UserError("mpremote failed on %s (exit %d): %s" % (port, p.returncode, (p.stderr or p.stdout).strip()[-800:]))
    return p


def probe(port: str, mpremote: str) -> None:
    """Ask the board on ``port`` to print a word through its REPL, within PROBE_TIMEOUT_S: a port nobody answers
    is an error in seconds, before any file is copied or any key written."""
    from host.errors import UserError
    p = _run_mpremote([mpremote, "connect", port, "resume", "exec", "print('tcomp-' + 'probe')"], port,
                      PROBE_TIMEOUT_S, "reach a MicroPython REPL")
    if "tcomp-probe" not in p.stdout:
        raise UserError("%s: no MicroPython REPL answered (mpremote printed %r)" % (port, p.stdout.strip()[-200:]))


def run(args: argparse.Namespace) -> int:
    from host.errors import UserError
    if not (args.table or args.config or args.board or args.key or not args.no_firmware):
        raise UserError("nothing to flash: give --table, --config, --board or --key, or drop --no-firmware")
    key, created = None, False
    if args.key:
        key, created = board_key(args.key, args.dry_run)
        print("board key: %s (%s)" % (args.key, "new, written once the board holds it" if created else "existing"),
              file=sys.stderr)
    tmp = tempfile.mkdtemp(prefix="tcomp-flash-")
    keep = False
    try:
        # A dry run keeps its staged files for the user: the key is never among them (no copy of a secret left in
        # a temporary folder); its command provisions no key, which the note below says.
        staged_key = None if args.dry_run else key
        files, tdir = stage(tmp, args.table, args.config, args.board, args.table_dir, not args.no_firmware,
                            staged_key, staged_key is not None and created)
        argv = command(args.port, files, _mpremote(args.mpremote), args.reset)
        if args.dry_run:
            # The printed command copies these staged files: they stay until the user has used (or dropped) it.
            keep = True
            print(" ".join(repr(a) if ("\n" in a or " " in a) else a for a in argv))
            print("tcomp flash: the files of this command are kept in %s; delete it when done" % tmp, file=sys.stderr)
            if key is not None:
                print("tcomp flash: the key of --key %s is not staged on a dry run: this command does not provision "
                      "it (run without --dry-run to do so)" % args.key, file=sys.stderr)
            return 0
        n = sum(len(v) for v in files.values())
        probe(args.port, _mpremote(args.mpremote))
        print("flashing %d files to %s (tables in /%s)" % (n, args.port, tdir))
        _run_mpremote(argv, args.port, COPY_TIMEOUT_S, "copy the files")
        if created:
            from host.board.linkauth import write_key
            try:
                write_key(args.key, cast(bytes, key))  # created: board_key made one
            except OSError as exc:
                raise UserError("the board now holds a new key, but --key %s cannot be written: %s; flash again with "
                                "a --key path you can write" % (args.key, exc.strerror or exc))
        print("done: %s" % ", ".join(sorted(os.path.relpath(f, tmp) for v in files.values() for f in v)))
        return 0
    finally:
        if not keep:
            shutil.rmtree(tmp, ignore_errors=True)
