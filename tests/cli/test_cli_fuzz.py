"""Property: whatever bytes a user's files hold, every verb ends with exit 0 or 2 (validate: 1 for a listed
problem; hil: 1 for malformed frames), never a traceback, never a half-written or staged file, and never
touches its inputs.

Inputs are a small valid run folder, a model document fitted on it and its exported table; each example
either replaces one of them by random bytes or mutates it (a byte inserted, deleted or replaced with a
character that matters to CSV/JSON, or one JSON field set to an awkward value), then runs one verb
in-process through host.cli.main. The HIL rig itself is replaced by a stub that refuses to start: its
behaviour has its own tests (hil_tests/); here only what ``tcomp hil`` reads is under test.
"""
import contextlib
import io
import json
import math
import os
import tempfile

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from host.cli import main
from host.data.runs import Errors, Run, Temperatures, write_run

RUN_FILES = ("meta.json", "temperatures.csv", "errors.csv")
SPECIAL = ['"', ",", "\n", "\r", "\x00", "_", "\uff12", "\u00e9", "e", "-", ".", " ", "{", "]", "9" * 40]
AWKWARD = [None, True, -1, 0, 1e400, -1e400, float("nan"), "", "x", [], {}, [1, 2], 10 ** 30, "T1", ["T1", "T1"]]


def _small_run():
    t = np.arange(0.0, 7200.0, 120.0)
    vals = 20 + np.column_stack([np.sin(t / 3000.0 + k) + t / 3600.0 * (k + 1) for k in range(3)])
    st_, pos = np.arange(0.0, 7200.0, 600.0), np.linspace(0, 500, 6)
    et, ep = np.repeat(st_, pos.size), np.tile(pos, st_.size)
    ev = 0.004 * ep * (1 + et / 3600.0)
    meta = {"format": "tcomp-run/1", "axis": "X", "stroke_mm": 500,
            "screw": {"length_mm": 600, "diameter_mm": 32, "lead_mm": 10, "fixed_end_mm": 0},
            "sensors": {"T1": {"role": "nut"}, "T2": {"role": "base"}, "T3": {"role": "ambient"}}}
    return Run(meta, Temperatures(t, ["T1", "T2", "T3"], vals), Errors(et, ep, ev))


@pytest.fixture(scope="module")
def originals(tmp_path_factory):
    """{name: bytes} of the valid inputs every example starts from."""
    d = tmp_path_factory.mktemp("valid")
    run = write_run(_small_run(), str(d / "run"))
    assert main(["fit", "--model", "mlr", run, "--out", str(d / "m.json")]) == 0
    assert main(["export", str(d / "m.json"), "--out", str(d / "t.bin")]) == 0
    files = {"run/" + f: (d / "run" / f).read_bytes() for f in RUN_FILES}
    files["m.json"] = (d / "m.json").read_bytes()
    files["t.bin"] = (d / "t.bin").read_bytes()
    files["log.csv"] = (d / "run" / "temperatures.csv").read_bytes()
    return files


def _verbs(d):
    """(argv, primary outputs) of every verb that reads user files, on the inputs in folder ``d``."""
    run, model, table, out = os.path.join(d, "run"), os.path.join(d, "m.json"), os.path.join(d, "t.bin"), os.path.join(d, "out")
    return {
        "validate": (["validate", run, "--json", out + "/v.json"], ["v.json"]),
        "import": (["import", os.path.join(d, "log.csv"), "--time", "time_s", "--temp", "T1", "--temp", "T2",
                    "--error", "T3", "--out", out + "/imp", "--json", out + "/i.json"], ["imp", "i.json"]),
        "fit": (["fit", "--model", "mlr", run, "--out", out + "/m.json", "--json", out + "/f.json"], ["m.json", "f.json"]),
        "predict": (["predict", model, run, "--out", out + "/p.csv", "--json", out + "/p.json"], ["p.csv", "p.json"]),
        "export": (["export", model, "--out", out + "/t.bin", "--report", out + "/r.json", "--c-header", out + "/t.h"],
                   ["t.bin", "r.json", "t.h"]),
        "select": (["select", "--method", "stepwise", run, "--json", out + "/s.json"], ["s.json"]),
        "compare": (["compare", run, "--split-h", "1", "--methods", "mlr", "--sensors", "T1,T2", "--repeats", "1", "--json", out + "/c.json"], ["c.json"]),
        "hil": (["hil", "--run", run, "--table", table, "--interpreter", "cpython", "--json", out + "/h.json"], ["h.json"]),
        "flash": (["flash", "--port", "/dev/null", "--table", table, "--no-firmware", "--mpremote", "/bin/true"], []),
        # the small run has no motion.csv, so discrepancy always refuses it: what is fuzzed is how it reads the
        # run (meta.json's screw block, the CSVs) before that refusal, not the workflow (tests/learning/discrepancy/)
        "discrepancy": (["discrepancy", run, "--json", out + "/d.json", "--report", out + "/rep"], ["d.json", "rep"]),
    }


# which inputs each verb reads (a mutation elsewhere changes nothing for it)
READS = {"validate": RUN_FILES, "import": ("log.csv",), "fit": RUN_FILES, "predict": RUN_FILES + ("m.json",),
         "export": ("m.json",), "select": RUN_FILES, "compare": RUN_FILES, "hil": RUN_FILES + ("t.bin",), "flash": ("t.bin",),
         "discrepancy": RUN_FILES}


@st.composite
def cases(draw):
    verb = draw(st.sampled_from(sorted(READS)))
    target = draw(st.sampled_from(READS[verb]))
    target = "run/" + target if target in RUN_FILES else target
    how = draw(st.sampled_from(["bytes", "edit", "json"] if target.endswith(".json") else ["bytes", "edit"]))
    if how == "bytes":
        change = ("bytes", draw(st.binary(max_size=200)))
    elif how == "edit":
        change = ("edit", draw(st.integers(0, 10 ** 6)), draw(st.sampled_from(["insert", "delete", "replace"])),
                  draw(st.sampled_from(SPECIAL)))
    else:
        change = ("json", draw(st.integers(0, 10 ** 6)), draw(st.sampled_from(AWKWARD)))
    return verb, target, change


def _leaves(doc, path=()):
    """JSON paths of every value in ``doc`` (containers included)."""
    out = [path]
    items = doc.items() if isinstance(doc, dict) else enumerate(doc) if isinstance(doc, list) else ()
    for k, v in items:
        out += _leaves(v, path + (k,))
    return out


def _mutate(data, change):
    kind = change[0]
    if kind == "bytes":
        return change[1]
    if kind == "edit":
        _, where, op, text = change
        raw = text.encode("utf-8")
        i = where % (len(data) + 1)
        if op == "insert":
            return data[:i] + raw + data[i:]
        if op == "delete":
            return data[:i] + data[i + 1:]
        return data[:i] + raw + data[i + len(raw):]
    _, where, value = change
    doc = json.loads(data)
    paths = [p for p in _leaves(doc) if p]
    path = paths[where % len(paths)]
    parent = doc
    for k in path[:-1]:
        parent = parent[k]
    parent[path[-1]] = value
    return json.dumps(doc).encode()


class _NoRig:
    """Stands in for hil_tests.rig.harness.Rig: reaching it means every input was accepted."""

    def __init__(self, *args, **kwargs):
        from hil_tests.rig.harness import RigError

        raise RigError("stub rig (the fuzz test checks the inputs only)")


@settings(max_examples=120, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture, HealthCheck.too_slow])
@given(case=cases())
def test_every_verb_survives_mutated_inputs(originals, monkeypatch, case):
    import hil_tests.rig.harness as harness

    monkeypatch.setattr(harness, "Rig", _NoRig)
    verb, target, change = case
    with tempfile.TemporaryDirectory(prefix="tcomp-fuzz-") as d:
        for name, data in originals.items():
            os.makedirs(os.path.dirname(os.path.join(d, name)), exist_ok=True)
            with open(os.path.join(d, name), "wb") as fh:
                fh.write(_mutate(data, change) if name == target else data)
        os.makedirs(os.path.join(d, "out"))
        inputs = {name: open(os.path.join(d, name), "rb").read() for name in originals}
        argv, primary = _verbs(d)[verb]
        stdout, stderr = io.StringIO(), io.StringIO()
        with contextlib.redirect_stdout(stdout), contextlib.redirect_stderr(stderr):
            try:
                rc = main(argv)
            except SystemExit as exc:  # argparse
                rc = exc.code
        err = stderr.getvalue()
        allowed = {0, 2} | ({1} if verb in ("validate", "hil") else set())
        assert rc in allowed, (verb, target, change, rc, err[-500:])
        assert "Traceback" not in err
        if rc == 2:  # warnings may come first, then the error (which may list several problems below it)
            rest = err[err.index("tcomp %s: error: " % verb):] if "tcomp %s: error: " % verb in err else err
            before = err[:len(err) - len(rest)].splitlines()
            assert rest.startswith("tcomp %s: error: " % verb), err[-500:]
            assert all(ln.startswith(("tcomp %s: warning: " % verb, " ")) for ln in before), err[-500:]
        left = sorted(os.path.relpath(os.path.join(r, f), d) for r, ds, fs in os.walk(d) for f in fs + ds)
        assert not [f for f in left if ".tcomp-part-" in f], left
        if rc == 2 and not (verb == "compare" and "every method failed" in err):  # compare keeps the details
            assert os.listdir(os.path.join(d, "out")) == [], (verb, change, err[-300:])
        elif verb != "flash":
            assert all(os.path.exists(os.path.join(d, "out", p)) for p in primary)
        assert {name: open(os.path.join(d, name), "rb").read() for name in originals} == inputs


def test_the_mutations_land_where_they_say():
    doc = {"a": {"b": [1.0, 2.0]}}
    out = json.loads(_mutate(json.dumps(doc).encode(), ("json", 1, "x")))
    assert out == {"a": {"b": "x"}}
    assert _mutate(b"abc", ("edit", 1, "insert", '"')) == b'a"bc'
    assert _mutate(b"abc", ("edit", 1, "delete", '"')) == b"ac"
    assert math.isnan(json.loads(_mutate(json.dumps(doc).encode(), ("json", 2, float("nan"))))["a"]["b"][0])
