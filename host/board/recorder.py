"""A thermal test recorded from the board into a run folder (``tcomp record``, docs/recording.md).

``RunWriter`` writes the folder so that it is a valid run (``tcomp validate``) at every instant of the recording:

- the folder appears whole with the first good sample: ``meta.json``, a header-only ``errors.csv`` (the laser's
  sweeps are merged later: ``tcomp import --errors --into``) and ``temperatures.csv`` with its header and that
  row are written (fsynced) into a hidden folder beside it, which is then renamed into place;
- ``temperatures.csv`` then grows by appending: every batch of rows is one ``write()`` of whole lines, then
  fsync. A process killed at any point (Ctrl-C, SIGTERM, SIGKILL) leaves whole lines only; a short or failed
  write (a full disk, a file-size limit) is cut back to the last whole line (ftruncate, which needs no free
  space) and the recording stops with a message;
- a file that starts later (``motion.csv``, ``spindle.csv``, ``board_faults.csv``) is created whole with its
  header and first rows (temporary file, fsync, rename), never empty or header-only, then appended to.

Why append rather than periodic atomic rewrites: a rewrite copies the whole file each time, O(n^2) over a
long test (a 24-hour test at 1 s is 86 400 rows), and loses everything since the last rewrite when killed;
an append costs one small write and one fsync per batch and loses only the batch in flight.

Samples with a faulty channel (``!XX`` in the T frame) cannot be a row of temperatures.csv (no empty cells,
docs/data-format.md): they go to ``board_faults.csv`` (time_s, channel, fault bits), written the same way,
and are counted in the summary; nothing is dropped unsaid.
"""
from __future__ import annotations

from collections.abc import Iterable, Sequence
import json
import os
from typing import Any

from host.data.runformat import ERROR_COLUMNS, ERRORS, FORMAT, META, ROLES, TEMPERATURES

FAULTS = "board_faults.csv"  # not a run file: tcomp validate ignores it (docs/data-format.md, "Other files")
FAULT_COLUMNS = ("time_s", "channel", "fault_bits")


class RecordStop(Exception):
    """The recording cannot go on (a full disk, a lost link, a restarted board); the run holds what came before."""


def _fsync_dir(folder):
    fd = os.open(folder, os.O_RDONLY)
    try:
        os.fsync(fd)
    except OSError:
        pass  # a file system without directory fsync: the rename is still atomic
    finally:
        os.close(fd)


def write_atomic(path: str, text: str) -> None:
    """``text`` into ``path`` whole or not at all (temporary file beside it, fsync, rename, fsync of the folder)."""
    tmp = os.path.join(os.path.dirname(path), ".%s.tmp-%d" % (os.path.basename(path), os.getpid()))
    try:
        with open(tmp, "w", encoding="utf-8", newline="") as fh:
            fh.write(text)
            fh.flush()
            os.fsync(fh.fileno())
        os.replace(tmp, path)
    finally:
        if os.path.exists(tmp):
            os.unlink(tmp)
    _fsync_dir(os.path.dirname(path) or ".")


class AppendFile:
    """A CSV file that exists only with its header and at least one row, and grows by whole lines only.

    Created whole (header and first rows into a temporary file, fsync, rename: never an empty or header-only
    file, which would not validate), then opened for appending: ``append(lines)`` is one write() and an fsync;
    a short write is cut back to the last whole line and raises RecordStop naming the file."""

    def __init__(self, path: str, header: Sequence[str], first_lines: Sequence[str]) -> None:
        self.path = path
        self.rows = 0
        write_atomic(path, "".join(line + "\n" for line in [",".join(header)] + list(first_lines)))
        self.fd: int | None = os.open(path, os.O_WRONLY | os.O_APPEND)
        self.size = os.fstat(self.fd).st_size
        self.rows = len(first_lines)

    def append(self, lines: Sequence[str]) -> None:
        assert self.fd is not None, "%s: appended to after close" % self.path  # a bug of the caller, not of the disk
        data = "".join(line + "\n" for line in lines).encode("ascii")
        try:
            n = os.write(self.fd, data)
            if n != len(data):
                raise OSError(28, "short write (%d of %d bytes): the disk is full" % (n, len(data)))
            os.fsync(self.fd)
        except OSError as exc:
            try:
                os.ftruncate(self.fd, self.size)  # back to the last whole line
                os.fsync(self.fd)
            except OSError:
                pass
            raise RecordStop("%s: cannot write (%s); the run holds the %d rows written before"
                             % (self.path, exc.strerror or exc, self.rows))
        self.size += len(data)
        self.rows += len(lines)

    def close(self) -> None:
        if self.fd is not None:
            os.close(self.fd)
            self.fd = None


def parse_sensor(text: str) -> tuple[str, dict[str, str]]:
    """``NAME=ROLE[:LOCATION]`` -> (name, {role, location}); ValueError naming what is wrong."""
    name, eq, rest = text.partition("=")
    role, _, location = rest.partition(":")
    if not eq or not name or not role:
        raise ValueError("%r: expected NAME=ROLE[:LOCATION], e.g. T1=nut:ball-screw nut" % text)
    if role not in ROLES:
        raise ValueError("%r: role %r is not one of %s" % (text, role, ", ".join(ROLES)))
    return name, {"role": role, "location": location or "not given"}


def sensor_names(channels: int, sensors: dict[str, dict[str, str]], config_names: Sequence[str] | None = None) -> list[str]:
    """The run's sensor names in the board's channel order: the board config's names when given, else the
    ``--sensor`` names in their order; ValueError when the count or the names do not match the board's."""
    if config_names is not None:
        if len(config_names) != channels:
            raise ValueError("the board config names %d channels (%s) but the board reports %d"
                             % (len(config_names), ", ".join(config_names), channels))
        missing = [n for n in config_names if n not in sensors]
        unknown = [n for n in sensors if n not in config_names]
        if missing or unknown:
            raise ValueError("every board channel needs one --sensor NAME=ROLE: %s%s"
                             % ("missing %s" % ", ".join(missing) if missing else "",
                                ("; " if missing else "") + "not a channel of the board config: %s" % ", ".join(unknown)
                                if unknown else ""))
        return list(config_names)
    names = list(sensors)
    if len(names) != channels:
        raise ValueError("the board reports %d channels; give one --sensor NAME=ROLE per channel, in channel order "
                         "(%d given: %s)" % (channels, len(names), ", ".join(names) or "none"))
    return names


class RunWriter:
    """One recorded run folder, valid at every instant (module doc). It appears whole with its first good sample:
    meta.json, errors.csv, temperatures.csv (header and that row) and board_faults.csv (faulty samples before it)
    are written into a hidden folder beside ``folder``, which is then renamed to ``folder`` (an empty one is
    replaced). Every later row is appended."""

    def __init__(self, folder: str, names: Iterable[str], meta: dict[str, Any], time_s: float, values: Sequence[str],
                 faults: Sequence[tuple[str, str, str]] = ()) -> None:
        folder = os.path.normpath(folder)
        if os.path.lexists(folder) and (not os.path.isdir(folder) or os.listdir(folder)):
            raise RecordStop("%s: exists and is not an empty folder; a recording is written into a new folder, never "
                             "over another run" % folder)
        parent = os.path.dirname(os.path.abspath(folder))
        os.makedirs(parent, exist_ok=True)
        stage = os.path.join(parent, ".%s.recording-%d" % (os.path.basename(folder), os.getpid()))
        self.folder = folder
        self.names = list(names)
        self.faults: AppendFile | None = None
        self.faulty_samples = len({t for t, _, _ in faults})
        self.temperatures: AppendFile | None = None  # an AppendFile once __init__ returns
        self.extra: dict[str, AppendFile] = {}  # motion.csv, spindle.csv: AppendFile once they have a row
        doc = {"format": FORMAT, "errors_pending": True}
        doc.update(meta)
        os.mkdir(stage)
        try:
            write_atomic(os.path.join(stage, META), json.dumps(doc, indent=2) + "\n")
            write_atomic(os.path.join(stage, ERRORS), ",".join(ERROR_COLUMNS) + "\n")
            self.temperatures = AppendFile(os.path.join(stage, TEMPERATURES), ("time_s",) + tuple(self.names),
                                           [self._row(time_s, values)])
            if faults:
                self.faults = AppendFile(os.path.join(stage, FAULTS), FAULT_COLUMNS, ["%s,%s,%s" % f for f in faults])
            _fsync_dir(stage)
            os.replace(stage, folder)  # the run appears whole; an empty folder of that name is replaced
            _fsync_dir(parent)
        except BaseException:
            self.close()
            import shutil
            shutil.rmtree(stage, ignore_errors=True)
            raise
        for f in (self.temperatures, self.faults):  # the open files are the same inodes in their new folder
            if f is not None:
                f.path = os.path.join(folder, os.path.basename(f.path))

    @staticmethod
    def _row(time_s, values):
        return ",".join(["%.3f" % time_s] + list(values))

    def sample(self, time_s: float, values: Sequence[str]) -> bool:
        """One sample: ``values`` as the board sent them (``°C.mmm`` or ``!XX``), in channel order. True when it
        became a row of temperatures.csv, False when a faulty channel sent it to board_faults.csv."""
        bad = faulty_channels(self.names, time_s, values)
        if not bad:
            assert self.temperatures is not None  # __init__ made it or raised
            self.temperatures.append([self._row(time_s, values)])
            return True
        lines = ["%s,%s,%s" % f for f in bad]
        if self.faults is None:
            self.faults = self.create(FAULTS, FAULT_COLUMNS, lines)
        else:
            self.faults.append(lines)
        self.faulty_samples += 1
        return False

    def create(self, name: str, header: Sequence[str], lines: Sequence[str]) -> AppendFile:
        """A further file of the run (motion.csv, spindle.csv, board_faults.csv), created whole with its first rows."""
        try:
            f = AppendFile(os.path.join(self.folder, name), header, lines)
        except OSError as exc:
            raise RecordStop("%s: cannot write (%s)" % (os.path.join(self.folder, name), exc.strerror or exc))
        _fsync_dir(self.folder)
        return f

    def append(self, name: str, header: Sequence[str], lines: Sequence[str]) -> None:
        """Rows of motion.csv or spindle.csv (created with its first rows)."""
        if not lines:
            return
        if name not in self.extra:
            self.extra[name] = self.create(name, header, lines)
        else:
            self.extra[name].append(lines)

    def close(self) -> None:
        for f in [self.temperatures, self.faults] + list(self.extra.values()):
            if f is not None:
                f.close()


def faulty_channels(names: Sequence[str], time_s: float, values: Sequence[str]) -> list[tuple[str, str, str]]:
    """[(time text, channel, fault bits)] of the channels a T frame reports faulty (``!XX``)."""
    return [("%.3f" % time_s, n, v[1:]) for n, v in zip(names, values) if v.startswith("!")]
