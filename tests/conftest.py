import json
import os

import numpy as np
import pytest

from host.data.runs import Errors, Motion, Run, Temperatures, write_run


def _make_run(bidirectional=False, channels=None):
    t = np.arange(0.0, 3600.0 * 2, 60.0)
    names = ["T1", "T2", "T3", "T4"]
    vals = 20 + np.column_stack([np.sin(t / 3000.0 + k) for k in range(4)])
    sweep_t = np.arange(0.0, 7200.0, 900.0)
    pos = np.linspace(0, 700, 8)
    et, ep = np.repeat(sweep_t, pos.size), np.tile(pos, sweep_t.size)
    direction = None
    if bidirectional:
        et, ep = np.repeat(et, 2), np.repeat(ep, 2)
        direction = np.tile(np.array([1, -1], dtype=np.int8), et.size // 2)
    ev = 0.01 * ep * (1 + et / 7200.0)
    channel = None
    if channels:
        channel = np.array([channels[i % len(channels)] for i in range(et.size)], dtype=object)
    meta = {
        "format": "tcomp-run/1",
        "axis": "X",
        "stroke_mm": 700,
        "screw": {"length_mm": 800, "diameter_mm": 32, "lead_mm": 10, "fixed_end_mm": 0},
        "sensors": {"T1": {"role": "nut", "location": "nut"}, "T2": {"role": "base", "location": "base"},
                    "T3": {"role": "ambient", "location": "air"}, "T4": {"role": "structure", "location": "column"}},
        "notes": "unit-test run",
        "operator_extra": {"kept": True},
    }
    motion = Motion(np.array([0.0, 3000.0]), np.array([2000.0, 5000.0]), np.array([210.0, 0.0]),
                    np.array([490.0, 700.0]), np.array([8000.0, 6500.0]))
    return Run(meta, Temperatures(t, names, vals), Errors(et, ep, ev, direction, channel), motion)


@pytest.fixture
def run_dir(tmp_path):
    return write_run(_make_run(), str(tmp_path / "run"))


def _edit_csv(folder, name, fn):
    path = os.path.join(folder, name)
    with open(path) as fh:
        lines = fh.read().splitlines()
    lines = fn(lines)
    with open(path, "w") as fh:
        fh.write("\n".join(lines) + "\n")


def _edit_meta(folder, fn):
    path = os.path.join(folder, "meta.json")
    with open(path) as fh:
        meta = json.load(fh)
    fn(meta)
    with open(path, "w") as fh:
        json.dump(meta, fh)


@pytest.fixture
def make_run():
    return _make_run


@pytest.fixture
def edit_csv():
    return _edit_csv


@pytest.fixture
def edit_meta():
    return _edit_meta
