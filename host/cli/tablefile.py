"""Reading a coefficient table file for the board verbs (tcomp board, tcomp upload): the bytes and the parsed table,
or one line naming the flag, the file and what is wrong."""
from __future__ import annotations

from typing import Any


def read_table(path: str, flag: str = "--table") -> tuple[bytes, Any]:
    """(the table's bytes, firmware.table's parse of them); UserError when the file cannot be read or is no valid table."""
    from firmware.table import TableError, parse_table
    from host.errors import UserError
    try:
        with open(path, "rb") as f:
            data = f.read()
    except OSError as exc:
        raise UserError("%s %s: %s" % (flag, path, exc.strerror or exc))
    try:
        return data, parse_table(data)
    except TableError as exc:
        raise UserError("%s %s: not a valid coefficient table: %s" % (flag, path, exc))
