"""Every output of one ``tcomp`` command: claimed before the work, staged beside its target, committed together.

A command names its inputs and claims each output (``file`` or ``folder``) before
any work. An output that resolves (symlinks followed, hard links compared) to an
input, to an existing file inside an input folder, to a folder holding an input,
or to another output of the same command is refused then, with one line naming both.

Writers get a staging path (``path``/``open``): a hidden temporary file or folder
in the target's own folder, so the final rename stays on one file system.
``commit()`` fsyncs every staged file and renames them all into place
(``os.replace``); until then no target is touched. Leaving the ``with`` block
without a commit (an error, disk full, Ctrl-C) removes every staged file, so a
failure leaves neither half an output nor some outputs without the others.
Targets that are not regular files (``/dev/stdout``, a FIFO, ``/dev/full``) cannot
be renamed onto: they are written first at commit, before any rename.
A folder output may name the files that make one whole (a run folder's): writing
it into an existing folder then removes the ones of the older whole it did not rewrite.
"""

from __future__ import annotations

from collections.abc import Iterable
from types import TracebackType
from typing import IO, Any, Literal
import errno
import os
import shutil
import stat
import tempfile

from host.errors import UserError, check_output, check_output_dir

_PART = ".tcomp-part-"


def _real(path):
    return os.path.realpath(os.path.abspath(path))


def _inside(path, folder):
    """True when real path ``path`` is ``folder`` or lies below it (both real paths)."""
    return path == folder or path.startswith(folder.rstrip(os.sep) + os.sep)


def _same(a, b):
    """Same file: equal real paths, or (both existing) the same inode, which also catches hard links."""
    if a == b:
        return True
    try:
        return os.path.samefile(a, b)
    except OSError:
        return False


def _is_device(path):
    try:
        mode = os.stat(path).st_mode
    except OSError:
        return False
    return not stat.S_ISREG(mode) and not stat.S_ISDIR(mode)


def _default_mode(folder):
    umask = os.umask(0)
    os.umask(umask)
    return (0o777 if folder else 0o666) & ~umask


def _fsync(path):
    fd = os.open(path, os.O_RDONLY)
    try:
        os.fsync(fd)
    except OSError as exc:
        if exc.errno not in (errno.EINVAL, errno.EROFS):  # a folder on a file system without directory fsync
            raise
    finally:
        os.close(fd)


class _Target:
    def __init__(self, flag, shown, folder):
        self.flag, self.shown, self.folder = flag, shown, folder
        self.real = _real(shown)
        self.device = not folder and _is_device(shown)
        self.stage = None
        self.owned: tuple[str, ...] = ()


class Outputs:
    """``with Outputs(inputs) as out:`` claim outputs, write through ``out.path``/``out.open``, then ``out.commit()``."""

    def __init__(self, inputs: Iterable[str | None] = ()) -> None:
        self._inputs = [(p, _real(p)) for p in inputs if p]
        self._targets = []
        self._committed = False

    # ------------------------------------------------------------ claims, before the work

    def file(self, path: str, flag: str = "--out") -> str:
        """Claim ``path`` as an output file; UserError when it cannot be written or would hit an input or output."""
        check_output(path, flag)
        return self._claim(_Target(flag, path, folder=False))

    def folder(self, path: str, flag: str = "--out", owned: Iterable[str] = ()) -> str:
        """Claim ``path`` as an output folder (created at commit; files already in it stay unless rewritten).

        ``owned``: file names that together make one thing the command writes whole (a run folder's files,
        host.data.runs.RUN_FILES). At commit, in every folder where the command wrote one of them, the others
        it did not write are removed: a run written over an older one never keeps the older motion.csv."""
        check_output_dir(path, flag)
        t = _Target(flag, path, folder=True)
        t.owned = tuple(owned)
        return self._claim(t)

    def log(self, path: str, flag: str) -> str:
        """Claim ``path`` as a log the command appends to as it goes (not staged: what was logged stays)."""
        check_output(path, flag)
        return self._claim(_Target(flag, path, folder=False))

    def _claim(self, t):
        for shown, real in self._inputs:
            if _same(t.real, real):
                raise UserError("%s %s: is the input %s; it would be overwritten (write the output elsewhere)" % (t.flag, t.shown, shown))
            if t.device:
                continue  # /dev/stdout and the like hold none of the user's files
            if t.folder and _inside(real, t.real):
                raise UserError("%s %s: the folder holds the input %s; write the output into a folder of its own" % (t.flag, t.shown, shown))
            if not t.folder and os.path.isdir(real) and _inside(t.real, real) and os.path.lexists(t.real):
                raise UserError("%s %s: would overwrite a file of the input folder %s (write the output elsewhere)" % (t.flag, t.shown, shown))
        for o in self._targets:
            if t.device and o.device:
                continue  # two outputs to /dev/null or a terminal do not overwrite each other
            if _same(t.real, o.real) or (o.folder and _inside(t.real, o.real)) or (t.folder and _inside(o.real, t.real)):
                raise UserError("%s %s and %s %s: the same place; every output needs its own" % (o.flag, o.shown, t.flag, t.shown))
        self._targets.append(t)
        return t.shown

    # ------------------------------------------------------------ staging, during the work

    def _target(self, path):
        for t in self._targets:
            if t.shown == path:
                return t
        raise KeyError("%s was not claimed as an output" % path)

    def path(self, path: str) -> str:
        """Where to write the claimed output ``path`` now (a hidden temporary beside it, same extension)."""
        t = self._target(path)
        if t.stage is None:
            try:
                t.stage = self._make_stage(t)
            except OSError as exc:
                raise UserError("cannot write %s: %s" % (t.shown, exc.strerror or exc))
        return t.stage

    def _make_stage(self, t):
        stem, ext = os.path.splitext(os.path.basename(t.real.rstrip(os.sep)))
        # Hidden, named after the target, and with the target's extension only (none if it has none):
        # matplotlib picks the image format from it.
        prefix = "%s%s-" % (_PART, stem.replace(".", "_"))
        if t.folder:
            # An existing folder stages inside itself (it may be a mount point); a new one in its nearest existing parent.
            anchor = t.real if os.path.isdir(t.real) else os.path.dirname(t.real)
            while not os.path.isdir(anchor):
                anchor = os.path.dirname(anchor)
            return tempfile.mkdtemp(prefix=prefix, dir=anchor)
        where = tempfile.gettempdir() if t.device else os.path.dirname(t.real)
        fd, stage = tempfile.mkstemp(prefix=prefix, suffix=ext, dir=where)
        os.close(fd)
        return stage

    def open(self, path: str, mode: str = "w", **kwargs: Any) -> IO[Any]:
        """``open`` on the staging file of the claimed output ``path``."""
        if "b" not in mode:
            kwargs.setdefault("encoding", "utf-8")
        return open(self.path(path), mode, **kwargs)

    def shown(self, staged: str) -> str:
        """The user's path for a path inside a staging folder (for messages and recorded paths)."""
        for t in self._targets:
            if t.folder and t.stage and _inside(staged, t.stage):
                return os.path.join(t.shown, os.path.relpath(staged, t.stage)) if staged != t.stage else t.shown
        return staged

    # ------------------------------------------------------------ commit or discard

    def commit(self) -> None:
        """Rename every staged output into place (devices written first); on failure remove what is staged."""
        current = None
        try:
            staged = [t for t in self._targets if t.stage is not None]
            for t in staged:
                current = t
                if t.device:
                    with open(t.stage, "rb") as src, open(t.shown, "wb") as dst:
                        shutil.copyfileobj(src, dst)
                elif t.folder:
                    for root, _, files in os.walk(t.stage):
                        for f in files:
                            _fsync(os.path.join(root, f))
                else:
                    _fsync(t.stage)
            for t in staged:
                current = t
                if not t.device:
                    self._place(t)
        except OSError as exc:
            self.discard()
            where = current.shown if current is not None else "the outputs"
            raise UserError("cannot write %s: %s; no output was written" % (where, exc.strerror or exc))
        self._committed = True
        self.discard()  # device stages and emptied folder stages

    def _place(self, t):
        if not t.folder:
            mode = stat.S_IMODE(os.stat(t.real).st_mode) if os.path.exists(t.real) else _default_mode(False)
            os.chmod(t.stage, mode)
            os.replace(t.stage, t.real)
            _fsync(os.path.dirname(t.real))
        elif not os.path.exists(t.real):
            os.makedirs(os.path.dirname(t.real), exist_ok=True)
            for root, dirs, files in os.walk(t.stage):
                for d in dirs:
                    os.chmod(os.path.join(root, d), _default_mode(True))
                for f in files:
                    os.chmod(os.path.join(root, f), _default_mode(False))
            os.chmod(t.stage, _default_mode(True))
            os.replace(t.stage, t.real)
            _fsync(os.path.dirname(t.real))
        else:
            for root, _, files in os.walk(t.stage):
                dest = os.path.join(t.real, os.path.relpath(root, t.stage))
                os.makedirs(dest, exist_ok=True)
                for f in files:
                    final = os.path.join(dest, f)
                    mode = stat.S_IMODE(os.stat(final).st_mode) if os.path.exists(final) else _default_mode(False)
                    os.chmod(os.path.join(root, f), mode)
                    os.replace(os.path.join(root, f), final)
                if set(files) & set(t.owned):
                    for f in t.owned:
                        stale = os.path.join(dest, f)
                        if f not in files and os.path.lexists(stale) and not os.path.isdir(stale):
                            os.remove(stale)  # part of the older whole this one replaces
                _fsync(dest)

    def discard(self) -> None:
        """Remove every staging file and folder (after a commit only the leftovers of devices and merged folders)."""
        for t in self._targets:
            if t.stage is None:
                continue
            if os.path.isdir(t.stage):
                shutil.rmtree(t.stage, ignore_errors=True)
            elif os.path.lexists(t.stage):
                try:
                    os.remove(t.stage)
                except OSError:
                    pass
            t.stage = None

    def __enter__(self) -> Outputs:
        return self

    def __exit__(self, kind: type[BaseException] | None, exc: BaseException | None, tb: TracebackType | None) -> Literal[False]:
        if not self._committed:
            self.discard()
        if isinstance(exc, OSError) and not isinstance(exc, UserError) and exc.errno in (errno.ENOSPC, errno.EDQUOT, errno.EFBIG, errno.EIO):
            # Disk full while a writer filled a staging file: nothing is left, say so in one line.
            shown = ", ".join(t.shown for t in self._targets)
            raise UserError("cannot write %s: %s; no output was written" % (shown, exc.strerror or exc)) from exc
        return False
