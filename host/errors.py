"""User-facing errors and the checks on output paths that every verb runs before its work starts.

The bottom of the host: library modules (outputs, options, the board link) raise ``UserError``, and the CLI
(host/cli) prints it as one line without a traceback."""

from __future__ import annotations

from typing import IO, Any


class UserError(Exception):
    """A problem with the user's input (file, flag, data): printed without a traceback."""


def os_reason(exc: OSError) -> str:
    """The reason an OSError gives, for a one-line message."""
    return exc.strerror or str(exc)


def check_output(path: str, flag: str = "--out") -> None:
    """Raise UserError unless ``path`` can be created as a file; call it before long work starts."""
    import os

    if os.path.isdir(path):
        raise UserError("%s %s: is a folder, expected a file path" % (flag, path))
    parent = os.path.dirname(os.path.abspath(path))
    if not os.path.isdir(parent):
        raise UserError("%s %s: folder %s does not exist" % (flag, path, parent))
    if not os.access(parent, os.W_OK | os.X_OK) or (os.path.exists(path) and not os.access(path, os.W_OK)):
        raise UserError("%s %s: not writable" % (flag, path))


def check_output_dir(path: str, flag: str = "--out") -> None:
    """Raise UserError unless ``path`` is, or can be created as, a folder (parents included)."""
    import os

    if os.path.exists(path) and not os.path.isdir(path):
        raise UserError("%s %s: exists and is not a folder" % (flag, path))
    probe = os.path.abspath(path)
    while not os.path.exists(probe):
        probe = os.path.dirname(probe)
    if not os.path.isdir(probe):
        raise UserError("%s %s: %s is a file, not a folder" % (flag, path, probe))
    if not os.access(probe, os.W_OK | os.X_OK):
        raise UserError("%s %s: %s is not writable" % (flag, path, probe))


def open_output(path: str, mode: str = "w", **kwargs: Any) -> IO[Any]:
    """``open(path, mode)`` for an output file; an OSError becomes "cannot write PATH: reason"."""
    if "b" not in mode:
        kwargs.setdefault("encoding", "utf-8")
    try:
        return open(path, mode, **kwargs)
    except OSError as exc:
        raise UserError("cannot write %s: %s" % (path, os_reason(exc)))
