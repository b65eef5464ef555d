"""Shared helpers for the firmware tests: fakes (fwfakes.py) and coefficient tables."""
import os
import sys

import pytest

HERE = os.path.dirname(os.path.abspath(__file__))
ROOT = os.path.dirname(os.path.dirname(HERE))
if HERE not in sys.path:
    sys.path.insert(0, HERE)
if ROOT not in sys.path:
    sys.path.insert(0, ROOT)

MICROPYTHON = os.path.join(ROOT, ".venv", "bin", "micropython")


def table_fields(kind="linear_direct", sensors=("T1", "T2"), b=None, shb=4, S0=0, pos=(0, 500000, 0),
                 axis="X"):
    """Fields for models_export.tableformat.pack of a small, integer-safe table."""
    n = len(sensors)
    f = {
        "kind": kind, "sensors": list(sensors), "axis": axis, "provenance": bytes(range(32)),
        "env_lo": [-20000] * n, "env_hi": [80000] * n, "ref": [20000] * n,
        "pos_lo": pos[0], "pos_hi": pos[1], "pos_ref": pos[2],
        "fo": 0, "Lt": 29, "nt": 1, "S0": S0, "fS": 0,
        "b": list(b) if b is not None else [1] * n, "shb": [shb] * n, "fb": [0] * n, "rL": 0,
    }
    if kind != "linear_direct":
        f.update({"Lw": 10, "nw": 2, "shw": 18, "KS": 1, "shK": 0, "fK": 0, "rK": 0, "rT": 0,
                  "degree": 1, "Lg": 10, "ng": 2, "G": [300, 1], "fG": [0, 0], "shg": [14], "rO": 0})
    return f


def make_table(**kw):
    from models_export.tableformat import pack
    return pack(table_fields(**kw))


@pytest.fixture
def table_bytes():
    return make_table


def need_micropython():
    if not os.path.exists(MICROPYTHON):
        pytest.skip("MicroPython unix port not installed")
    return MICROPYTHON
