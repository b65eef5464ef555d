"""A thermal test recorded from the board into a run folder (``tcomp record``, docs/recording.md).

``RunWriter`` writes the folder so that it is a valid run (``tcomp validate``) at every instant of the recording:

- ``meta.json`` and a header-only ``errors.csv`` (the laser's sweeps are merged later: ``tcomp import --errors
  --into``) are written atomically (temporary file, fsync, rename, fsync of the folder) before any sample;
- ``temperatures.csv`` is created with its header (fsynced), then grows by appending: every batch of rows is
  one ``write()`` of whole lines, then fsync. A process killed at any point (Ctrl-C, SIGTERM, SIGKILL) leaves
  whole lines only; a short or failed write (a full disk, a file-size limit) is cut back to the last whole
  line (ftruncate, which needs no free space) and the recording stops with a message.

Why append rather than periodic atomic rewrites: a rewrite copies the whole file each time, O(n^2) over a
long test (a 24-hour test at 1 s is 86 400 rows), and loses everything since the last rewrite when killed;
an append costs one small write and one fsync per batch and loses only the batch in flight.

Samples with a faulty channel (``!XX`` in the T frame) cannot be a row of temperatures.csv (no empty cells,
docs/data-format.md): they go to ``board_faults.csv`` (time_s, channel, fault bits), written the same way,
and are counted in the summary; nothing is dropped unsaid.
"""
import json
import os

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


def write_atomic(path, text):
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
    """A CSV file that grows by whole lines only: ``append(lines)`` is one write() and an fsync; a short write is
    cut back to the last whole line and raises RecordStop naming the file."""

    def __init__(self, path, header):
        self.path = path
        self.fd = os.open(path, os.O_WRONLY | os.O_CREAT | os.O_EXCL | os.O_APPEND, 0o666)
        self.size = 0
        self.rows = 0
        self.append([",".join(header)], header=True)
        _fsync_dir(os.path.dirname(path) or ".")

    def append(self, lines, header=False):
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
        if not header:
            self.rows += len(lines)

    def close(self):
        if self.fd is not None:
            os.close(self.fd)
            self.fd = None


def parse_sensor(text):
    """``NAME=ROLE[:LOCATION]`` -> (name, {role, location}); ValueError naming what is wrong."""
    name, eq, rest = text.partition("=")
    role, _, location = rest.partition(":")
    if not eq or not name or not role:
        raise ValueError("%r: expected NAME=ROLE[:LOCATION], e.g. T1=nut:ball-screw nut" % text)
    if role not in ROLES:
        raise ValueError("%r: role %r is not one of %s" % (text, role, ", ".join(ROLES)))
    return name, {"role": role, "location": location or "not given"}


def sensor_names(channels, sensors, config_names=None):
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
    """One recorded run folder, valid at every instant (module doc)."""

    def __init__(self, folder, names, meta):
        if os.path.lexists(folder) and (not os.path.isdir(folder) or os.listdir(folder)):
            raise RecordStop("%s: exists and is not an empty folder; a recording is written into a new folder, never "
                             "over another run" % folder)
        os.makedirs(folder, exist_ok=True)
        self.folder = folder
        self.names = list(names)
        doc = {"format": FORMAT, "errors_pending": True}
        doc.update(meta)
        write_atomic(os.path.join(folder, META), json.dumps(doc, indent=2) + "\n")
        write_atomic(os.path.join(folder, ERRORS), ",".join(ERROR_COLUMNS) + "\n")
        self.temperatures = AppendFile(os.path.join(folder, TEMPERATURES), ("time_s",) + tuple(self.names))
        self.faults = None
        self.faulty_samples = 0

    def sample(self, time_s, values):
        """One sample: ``values`` as the board sent them (``°C.mmm`` or ``!XX``), in channel order."""
        t = "%.3f" % time_s
        bad = [(n, v[1:]) for n, v in zip(self.names, values) if v.startswith("!")]
        if not bad:
            self.temperatures.append([",".join([t] + list(values))])
            return True
        if self.faults is None:
            self.faults = AppendFile(os.path.join(self.folder, FAULTS), FAULT_COLUMNS)
        self.faults.append(["%s,%s,%s" % (t, n, bits) for n, bits in bad])
        self.faulty_samples += 1
        return False

    def close(self):
        self.temperatures.close()
        if self.faults is not None:
            self.faults.close()
