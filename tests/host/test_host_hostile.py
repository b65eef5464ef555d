"""The host verbs attacked as an attacker (or a tired user) would: issue 24 §2, holes 8-10.

Three classes, each run as a list of attacks that prints its counts (tried, refused, warned, wrongly
accepted, crashes) and fails on any wrong acceptance or crash:

- hole 8, outputs onto inputs: a walk over every verb's output flags against its input flags (and its other
  outputs), each spelled as the same path, a symbolic link, a hard link, a file inside an input folder, a folder
  holding an input, a path through '..'; plus the named cases (monitor's key, flash's table folder, a run written
  over an older one, select's plot);
- hole 9, tracebacks: every call that ended in one, and the options bounded since;
- hole 10, silent acceptances: each gets a clear error, or a warning the JSON records.

A property test per hole draws the same classes at random (hypothesis). Reduced form by default (every verb,
every flag pair, three spellings; 25 examples per property); TCOMP_SLOW=1 runs every spelling and 200 examples.
The link and firmware holes 1-7 are hil_tests/test_hil_hostile.py's. In-process through host.cli.main, as
test_host_safety.py.
"""
import argparse
import contextlib
import io
import json
import math
import os
import shutil
import stat
import time
import warnings

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from host.cli import build_parser, main

from host.errors import UserError
from host.cli.verbs import VERBS
from host.data.runs import Errors, Motion, Run, Temperatures, write_run

ROOT = os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__))))
DEMO_RUN = os.path.join(ROOT, "data", "demo", "v8000_r210_490")
SLOW = os.environ.get("TCOMP_SLOW") == "1"
EXAMPLES = 200 if SLOW else 25
PROPERTY = settings(max_examples=EXAMPLES, deadline=None,
                    suppress_health_check=[HealthCheck.function_scoped_fixture, HealthCheck.too_slow])


# ------------------------------------------------------------ running one attack

class Outcome:
    """What one call did: exit status, stderr, stdout, and the exception if it escaped main."""

    def __init__(self, rc, out, err, exc=None):
        self.rc, self.out, self.err, self.exc = rc, out, err, exc

    @property
    def crashed(self):
        return self.exc is not None or "Traceback" in self.err or self.rc not in (0, 1, 2)

    def refused(self, verb, words=()):
        """Exit 2 with one error line 'tcomp VERB: error: ...', the last one, holding every one of ``words``
        (a verb may say what it did before, e.g. flash's 'board key: FILE (new ...)')."""
        lines = self.err.strip().splitlines()
        errors = [ln for ln in lines if ln.startswith("tcomp %s: error: " % verb)]
        return (self.rc == 2 and len(errors) == 1 and lines[-1] == errors[0] and all(w in errors[0] for w in words))


def call(argv):
    out, err = io.StringIO(), io.StringIO()
    exc = None
    with contextlib.redirect_stdout(out), contextlib.redirect_stderr(err):
        try:
            rc = main(argv)
        except SystemExit as e:  # argparse
            rc = e.code
        except BaseException as e:
            rc, exc = None, e
    return Outcome(rc, out.getvalue(), err.getvalue(), exc)


class Tally:
    """Counts of one class of attacks; ``report()`` prints them and returns the wrong ones."""

    def __init__(self, name):
        self.name = name
        self.tried = self.refused = self.warned = 0
        self.wrong, self.crashes = [], []

    def add(self, label, outcome, ok, warned=False):
        self.tried += 1
        if outcome.crashed:
            self.crashes.append("%s: %s" % (label, outcome.exc or outcome.err[-400:]))
        elif not ok:
            self.wrong.append("%s: rc %s, %s" % (label, outcome.rc, (outcome.err or outcome.out).strip()[-400:]))
        elif warned:
            self.warned += 1
        else:
            self.refused += 1

    def report(self):
        line = ("hostile host, %s: tried %d, refused %d, warned %d, wrongly accepted %d, crashes %d"
                % (self.name, self.tried, self.refused, self.warned, len(self.wrong), len(self.crashes)))
        print(line)  # pytest -s (or a failure) shows it
        return self.wrong + self.crashes


def _tree(folder):
    """{relative path: bytes or 'dir'/'link'} of everything below ``folder``."""
    out = {}
    for root, dirs, files in os.walk(folder):
        for name in dirs + files:
            p = os.path.join(root, name)
            rel = os.path.relpath(p, folder)
            if os.path.islink(p):
                out[rel] = "link:" + os.readlink(p)
            elif os.path.isdir(p):
                out[rel] = "dir"
            else:
                with open(p, "rb") as fh:
                    out[rel] = fh.read()
    return out


# ------------------------------------------------------------ the inputs every attack starts from

def _small_run(with_motion=True, error_rows=None):
    t = np.arange(0.0, 7200.0, 120.0)
    vals = 20 + np.column_stack([np.sin(t / 3000.0 + k) + t / 3600.0 * (k + 1) for k in range(3)])
    st_, pos = np.arange(0.0, 7200.0, 600.0), np.linspace(0, 500, 6)
    et, ep = np.repeat(st_, pos.size), np.tile(pos, st_.size)
    ev = 0.004 * ep * (1 + et / 3600.0)
    if error_rows is not None:
        et, ep, ev = et[:error_rows], ep[:error_rows], ev[:error_rows]
    meta = {"format": "tcomp-run/1", "axis": "X", "stroke_mm": 500,
            "screw": {"length_mm": 600, "diameter_mm": 32, "lead_mm": 10, "fixed_end_mm": 0},
            "sensors": {"T1": {"role": "nut"}, "T2": {"role": "base"}, "T3": {"role": "ambient"}}}
    motion = Motion(np.array([0.0, 3000.0]), np.array([2000.0, 5000.0]), np.array([0.0, 100.0]),
                    np.array([500.0, 400.0]), np.array([8000.0, 6500.0])) if with_motion else None
    return Run(meta, Temperatures(t, ["T1", "T2", "T3"], vals), Errors(et, ep, ev), motion)


@pytest.fixture(scope="module")
def valid(tmp_path_factory):
    """{name: bytes} of a small run (with motion), a model fitted on it, its table, a board config, a key."""
    from hil_tests.rig.boards import rig_config
    from host.board.linkauth import generate_key

    d = tmp_path_factory.mktemp("valid")
    run = write_run(_small_run(), str(d / "run"))
    assert call(["fit", "--model", "mlr", run, "--out", str(d / "m.json")]).rc == 0
    assert call(["export", str(d / "m.json"), "--out", str(d / "t.bin")]).rc == 0
    files = {"run/" + f: (d / "run" / f).read_bytes() for f in os.listdir(run)}
    files["m.json"] = (d / "m.json").read_bytes()
    files["t.bin"] = (d / "t.bin").read_bytes()
    files["cfg.json"] = json.dumps(rig_config(["T1", "T2"], n_ads=0)).encode()
    files["board.py"] = b'CONFIG = {"channels": [{"name": "T1", "driver": "max31865", "bus": "spi0", "cs": 5}, ' \
                        b'{"name": "T2", "driver": "max31865", "bus": "spi0", "cs": 6}]}\n'
    files["k.key"] = (generate_key().hex() + "\n").encode()
    files["log.csv"] = (d / "run" / "temperatures.csv").read_bytes()
    files["map.json"] = json.dumps({"time": "time_s", "temperatures": ["T1", "T2"], "errors": ["T3"]}).encode()
    files["corr.csv"] = b"T1,T2,T3\n1,0.9,0.5\n0.9,1,0.4\n0.5,0.4,1\n"
    files["tcorr.csv"] = b"sensor,r\nT1,0.9\nT2,0.5\nT3,0.1\n"
    files["board.csv"] = b"time_s,position_mm,offset_um\n" + b"".join(
        b"%g,%g,0\n" % (t, p) for t, p in zip(np.repeat(np.arange(0.0, 7200.0, 600.0), 6), np.tile(np.linspace(0, 500, 6), 12)))
    files["port"] = b""  # a port given as a plain file: it is read, so it is an input
    files["mpremote"] = b"#!/bin/sh\nexit 0\n"
    return files


def _lay_out(folder, files):
    for name, data in files.items():
        p = os.path.join(folder, name)
        os.makedirs(os.path.dirname(p), exist_ok=True)
        with open(p, "wb") as fh:
            fh.write(data)
    os.chmod(os.path.join(folder, "mpremote"), 0o755)
    os.chmod(os.path.join(folder, "k.key"), 0o600)


@pytest.fixture
def world(tmp_path, valid):
    folder = str(tmp_path / "w")
    _lay_out(folder, valid)
    return folder


# ------------------------------------------------------------ hole 8: every verb's outputs against its inputs

# Every flag of every verb, classified: inputs (read: file, folder or either), outputs (written: file, folder,
# log), and the rest. A verb or flag added without a row here fails test_every_flag_of_every_verb_is_classified,
# so the walk below always covers every verb.
FLAGS = {
    # tcomp board runs until Ctrl-C: not walked. --port is a symlink it makes, never over an existing file
    # (refused) or a live link (refused; a dangling one is replaced); --key is read, or created when missing
    "board": {"in": {"--run": "folder", "--table": "file", "--config": "file", "--key": "file"}, "out": {},
              "other": "--port --room-c --interpreter --noise-uohm --speed"},
    "check": {"in": {"--model": "file", "--run": "folder", "--board-log": "file"}, "out": {"--json": "file"},
              "other": "--board-t0-ms --max-dt-s --position-tol-mm --limit-um --allow-edited --t-min --t-max"},
    "compare": {"in": {"runs": "folder"}, "out": {"--json": "file", "--plots": "folder"},
                "other": "--channel --direct --sensors --methods --train --split-h --noise-C --offset-C --repeats "
                         "--reference --option --no-intercept"},
    "discrepancy": {"in": {"runs": "folder"}, "out": {"--json": "file", "--report": "folder"},
                    "other": "--base --air --candidates --alpha --min-gain --max-effects --jobs"},
    "export": {"in": {"model": "file"}, "out": {"--out": "file", "--report": "file", "--json": "file", "--c-header": "file"},
               "other": "--ref-position-mm --allow-edited --envelope --envelope-margin --reduction-limit"},
    "fit": {"in": {"runs": "folder"}, "out": {"--out": "file", "--json": "file"},
            "other": "--model --sensors --channel --direct --no-intercept --t-min --t-max --option"},
    # --key is created when missing (after the flash), else read: an output that is never written over anything
    "flash": {"in": {"--table": "file", "--config": "file", "--board": "file", "--port": "file", "--mpremote": "file"},
              "out": {"--key": "file"}, "other": "--table-dir --no-firmware --reset --dry-run"},
    "hil": {"in": {"--run": "folder", "--table": "file", "--config": "file", "--model": "file"}, "out": {"--json": "file"},
            "other": "--interpreter --fault --noise-uohm --warmup-s --print-every --duration --raw"},
    "import": {"in": {"source": "file", "--mapping": "file"}, "out": {"--out": "folder", "--json": "file"},
               # --errors (input) and --into (output folder) are the merge form, a second argv: its outputs against its
               # inputs are walked in tests/cli/test_cli_import.py
               "other": "--time --time-scale --temp --error --spindle --ignore --axis --error-reference --errors --into "
                        "--clock-offset --time-unit --time-format --timezone --header-line --delimiter --decimal --gaps --unit --location"},
    # --signal-record is the bridge's own state: read at start (created when missing), rewritten atomically every minute
    "linuxcnc": {"in": {"--port": "file", "--key": "file", "--signal-record": "file"}, "out": {},
                 "other": "--mode --baud --address --name --units --slew-um-per-s --period-ms --stale-ms --recover-ms "
                          "--cold-start --spindle --feed"},
    "monitor": {"in": {"--port": "file", "--key": "file"}, "out": {"--csv": "log", "--json": "file"},
                "other": "--baud --count --duration --hello --latch --temperatures --query --query-every"},
    "record": {"in": {"--port": "file", "--config": "file"}, "out": {"--out": "folder"},
               "other": "--baud --sensor --period --duration --link-timeout --notes --linuxcnc --hal-position "
                        "--hal-velocity --hal-spindle --hal-name --units"},
    "predict": {"in": {"model": "file", "run": "folder", "--history": "folder", "--controller-history": "folder"}, "out": {"--out": "file", "--json": "file"}, "other": "--allow-edited"},
    "report": {"in": {"runs": "folder", "--model": "file"}, "out": {"--out": "folder"}, "other": "--allow-edited"},
    "select": {"in": {"runs": "folder", "--corr": "file", "--target-corr": "file"}, "out": {"--json": "file", "--plot": "file"},
               "other": "--method --channel --target --sensors --split --option"},
    "simulate": {"in": {}, "out": {"--out": "folder", "--json": "file"}, "other": "--protocol --effects --seed --noise-um --set --error-reference"},
    # tcomp upload reads the table and the key and talks to the port; its one output is --json
    "upload": {"in": {"--port": "file", "--table": "file", "--key": "file"}, "out": {"--json": "file"},
               "other": "--baud --timeout"},
    "validate": {"in": {"runs": "folder"}, "out": {"--json": "file"}, "other": ""},
}

# where each input lives in the world, and a valid call naming every input ({FLAG}) and output ({@FLAG})
INPUT_FILES = {"runs": "run", "run": "run", "--history": "run", "--controller-history": "run", "--run": "run", "model": "m.json", "--table": "t.bin", "--config": "cfg.json",
               "--board": "board.py", "--port": "port", "--mpremote": "mpremote", "source": "log.csv",
               "--mapping": "map.json", "--corr": "corr.csv", "--target-corr": "tcorr.csv", "--key": "k.key",
               "--model": "m.json", "--board-log": "board.csv"}
OUTPUT_NAMES = {"--json": "o.json", "--plots": "plots", "--report": "report", "--out": "out", "--c-header": "t.h",
                "--key": "new.key", "--csv": "log2.csv", "--plot": "p.png"}
BASE = {
    "check": ["check", "--model", "{--model}", "--run", "{--run}", "--board-log", "{--board-log}", "--limit-um", "100",
              "--json", "{@--json}"],
    "compare": ["compare", "{runs}", "--split-h", "1", "--methods", "mlr", "--json", "{@--json}", "--plots", "{@--plots}"],
    "discrepancy": ["discrepancy", "{runs}", "--json", "{@--json}", "--report", "{@--report}"],
    "export": ["export", "{model}", "--out", "{@--out}", "--report", "{@--report}", "--json", "{@--json}", "--c-header", "{@--c-header}"],
    "fit": ["fit", "--model", "mlr", "{runs}", "--out", "{@--out}", "--json", "{@--json}"],
    "flash": ["flash", "--port", "{--port}", "--table", "{--table}", "{config}", "--mpremote", "{--mpremote}",
              "--key", "{@--key}", "--dry-run", "--no-firmware"],
    "hil": ["hil", "--run", "{--run}", "--table", "{--table}", "--config", "{--config}", "--model", "{--model}",
            "--json", "{@--json}"],
    "import": ["import", "{source}", "--mapping", "{--mapping}", "--out", "{@--out}", "--json", "{@--json}"],
    "upload": ["upload", "--port", "{--port}", "--table", "{--table}", "--key", "{--key}", "--json", "{@--json}"],
    "monitor": ["monitor", "--port", "{--port}", "--key", "{--key}", "--duration", "0.2", "--csv", "{@--csv}", "--json", "{@--json}"],
    "record": ["record", "--port", "{--port}", "--config", "{--config}", "--sensor", "T1=nut", "--duration", "0.2",
               "--out", "{@--out}"],
    "predict": ["predict", "{model}", "{run}", "--out", "{@--out}", "--json", "{@--json}"],
    "report": ["report", "{runs}", "--model", "{--model}", "--out", "{@--out}"],
    "select": ["select", "--method", "maxtree", "{runs}", "--corr", "{--corr}", "--target-corr", "{--target-corr}",
               "--json", "{@--json}", "--plot", "{@--plot}"],
    "simulate": ["simulate", "--protocol", "idle", "--out", "{@--out}", "--json", "{@--json}"],
    "validate": ["validate", "{runs}", "--json", "{@--json}"],
}
# what the one line of a refusal says, whichever rule refused it
REFUSED = ("is the input", "would overwrite a file of the input folder", "the folder holds the input", "the same place",
           "is a folder, expected a file path", "exists and is not a folder", "not a board key")


def _spellings(target, kind, out_kind, world):
    """Paths that all lead to ``target`` (an input of ``kind``) or hold it, for an output of ``out_kind``."""
    links = os.path.join(world, "links")
    os.makedirs(links, exist_ok=True)
    parent = os.path.dirname(target)
    out = {"same": target,
           "dotdot": os.path.join(parent, "..", os.path.basename(parent), os.path.basename(target))}
    sym = os.path.join(links, "sym-" + os.path.basename(target))
    if not os.path.lexists(sym):
        os.symlink(target, sym)
    out["symlink"] = sym
    if kind == "file":
        hard = os.path.join(links, "hard-" + os.path.basename(target))
        if not os.path.lexists(hard):
            os.link(target, hard)
        out["hardlink"] = hard
    if kind == "folder" and out_kind != "folder":
        out["inside"] = os.path.join(target, sorted(os.listdir(target))[0])
    if out_kind == "folder":
        out["parent"] = parent
    if not SLOW:  # reduced: one plain, one through a link, one through the folder
        keep = ("same", "symlink", "inside" if "inside" in out else "parent" if "parent" in out else "hardlink")
        out = {k: v for k, v in out.items() if k in keep}
    return out


def _argv(verb, world, paths, use_board=False):
    fmt = {k: os.path.join(world, v) for k, v in INPUT_FILES.items()}
    fmt.update({"@" + k: os.path.join(world, "o", v) for k, v in OUTPUT_NAMES.items()})
    fmt.update({"@" + k: v for k, v in paths.items()})
    argv = []
    for word in BASE[verb]:
        if word == "{config}":
            argv += ["--board", fmt["--board"]] if use_board else ["--config", fmt["--config"]]
        else:
            argv.append(word.format(**fmt) if word.startswith("{") else word)
    return argv


def _attacks():
    """(verb, output flag, what it is aimed at, spelling) for every verb: each output onto each input and onto
    each other output."""
    for verb in sorted(BASE):
        spec = FLAGS[verb]
        for oflag, okind in spec["out"].items():
            for iflag, ikind in spec["in"].items():
                yield verb, oflag, ("input", iflag, ikind)
            for other in spec["out"]:
                if other != oflag:
                    yield verb, oflag, ("output", other, spec["out"][other])


def _attack(world, verb, oflag, aim, spelling=None):
    """Run one attack in ``world``; returns [(label, outcome, ok)]."""
    os.makedirs(os.path.join(world, "o"), exist_ok=True)
    what, flag, kind = aim
    if what == "input":
        target = os.path.join(world, INPUT_FILES[flag])
        spellings = _spellings(target, kind, FLAGS[verb]["out"][oflag], world)
    else:
        spellings = {"same": os.path.join(world, "o", OUTPUT_NAMES[flag])}
    results = []
    for name, path in spellings.items():
        if spelling and name != spelling:
            continue
        paths = {oflag: path}  # output flags
        if what == "output":
            paths[flag] = path
        before = {k: v for k, v in _tree(world).items() if not k.startswith(("o" + os.sep, "links"))}
        outcome = call(_argv(verb, world, paths, use_board=flag == "--board"))
        after = {k: v for k, v in _tree(world).items() if not k.startswith(("o" + os.sep, "links"))}
        # refused, in one line naming a rule; nothing of the inputs touched; nothing written or staged
        ok = (outcome.refused(verb) and any(w in outcome.err for w in REFUSED) and after == before
              and not os.listdir(os.path.join(world, "o")))
        results.append(("%s %s onto %s %s (%s)" % (verb, oflag, what, flag, name), outcome, ok))
    return results


def test_every_flag_of_every_verb_is_classified():
    """The walk below covers every verb: each flag is an input, an output or neither, in FLAGS."""
    assert sorted(FLAGS) == sorted(VERBS)
    for verb in VERBS:
        sub = [a for a in build_parser(verb)._actions if isinstance(a, argparse._SubParsersAction)][0].choices[verb]
        flags = {a.option_strings[0] if a.option_strings else a.dest for a in sub._actions
                 if not isinstance(a, argparse._HelpAction)}
        spec = FLAGS[verb]
        known = set(spec["in"]) | set(spec["out"]) | set(spec["other"].split())
        assert flags == known, (verb, sorted(flags ^ known))
        assert verb in BASE or not spec["out"], verb  # every verb with an output is walked


def test_hole8_every_output_against_every_input(tmp_path, valid):
    tally = Tally("hole 8, outputs onto inputs (%s walk)" % ("full" if SLOW else "reduced"))
    for verb, oflag, aim in _attacks():
        world = str(tmp_path / ("w%d" % tally.tried))
        _lay_out(world, valid)
        for label, outcome, ok in _attack(world, verb, oflag, aim):
            tally.add(label, outcome, ok)
        shutil.rmtree(world)
    assert not tally.report()
    pairs = list(_attacks())  # 65 (output, input-or-output) pairs over 12 verbs: reduced 139 calls, full 178
    assert {v for v, _, _ in pairs} == {v for v in FLAGS if FLAGS[v]["out"]} and tally.tried > 2 * len(pairs)


@PROPERTY
@given(data=st.data())
def test_property_hole8_no_output_lands_on_an_input(valid, tmp_path, data):
    attacks = list(_attacks())
    verb, oflag, aim = data.draw(st.sampled_from(attacks), label="attack")
    spelling = data.draw(st.sampled_from(["same", "symlink", "hardlink", "inside", "parent", "dotdot"]), label="spelling")
    world = os.path.join(str(tmp_path), "w-%d" % data.draw(st.integers(0, 10 ** 9)))
    _lay_out(world, valid)
    try:
        for label, outcome, ok in _attack(world, verb, oflag, aim, spelling):
            assert not outcome.crashed and ok, (label, outcome.rc, outcome.err[-400:])
    finally:
        shutil.rmtree(world)


# ------------------------------------------------------------ hole 8: the named cases

def test_monitor_never_writes_over_its_key(world):
    key = os.path.join(world, "k.key")
    before = open(key, "rb").read()
    tally = Tally("hole 8, monitor onto its key")
    for flag in ("--json", "--csv"):
        outcome = call(["monitor", "--port", os.path.join(world, "port"), "--key", key, "--duration", "0.2", flag, key])
        tally.add("monitor %s KEY" % flag, outcome, outcome.refused("monitor", ["%s %s: is the input %s" % (flag, key, key)]))
    assert not tally.report()
    assert open(key, "rb").read() == before


@pytest.mark.parametrize("table_dir", ["../../escape", "../escape", "tables/../../escape", "", "/", ".", "a b"])
def test_flash_writes_only_under_its_staging_folder(tmp_path, world, monkeypatch, table_dir):
    import tempfile

    stage = tmp_path / "stage" / "deeper"
    stage.mkdir(parents=True)
    monkeypatch.setattr(tempfile, "tempdir", str(stage))
    outcome = call(["flash", "--port", "/dev/null", "--table", os.path.join(world, "t.bin"), "--table-dir", table_dir,
                    "--dry-run", "--no-firmware"])
    assert outcome.refused("flash", ["--table-dir %r" % table_dir]), outcome.err
    assert not (tmp_path / "escape").exists() and not (tmp_path / "stage" / "escape").exists()
    assert os.listdir(str(stage)) == []  # nothing kept: there is no command to use it


def test_flash_config_table_dir_outside_is_refused(tmp_path, world):
    cfg = json.loads(open(os.path.join(world, "cfg.json")).read())
    cfg["table_dir"] = "../../etc"
    path = os.path.join(world, "bad.json")
    with open(path, "w") as fh:
        json.dump(cfg, fh)
    outcome = call(["flash", "--port", "/dev/null", "--table", os.path.join(world, "t.bin"), "--config", path,
                    "--dry-run", "--no-firmware"])
    assert outcome.refused("flash", ["%s: table_dir '../../etc'" % path]), outcome.err


@pytest.mark.parametrize("verb", ["simulate", "import"])
def test_a_run_written_over_an_older_run_keeps_none_of_its_files(world, verb):
    """The older run had motion.csv and spindle.csv; the new one has neither; validate must see the new run."""
    out = os.path.join(world, "o", "r")
    write_run(_small_run(), out)
    with open(os.path.join(out, "spindle.csv"), "w") as fh:
        fh.write("time_s,rpm\n0,0\n60,100\n")
    with open(os.path.join(out, "notes.txt"), "w") as fh:
        fh.write("the user's own file\n")
    assert os.path.exists(os.path.join(out, "motion.csv"))
    if verb == "simulate":
        argv = ["simulate", "--protocol", "idle", "--out", out]
    else:
        argv = ["import", os.path.join(world, "log.csv"), "--mapping", os.path.join(world, "map.json"), "--out", out]
    outcome = call(argv)
    assert outcome.rc == 0, outcome.err
    assert sorted(os.listdir(out)) == ["errors.csv", "meta.json", "notes.txt", "temperatures.csv"]
    assert call(["validate", out]).rc == 0


@pytest.mark.parametrize("plot", ["p", "p.", "/dev/full"])
def test_select_plot_needs_an_image_name(world, plot):
    plot = plot if plot.startswith("/") else os.path.join(world, "o", plot)
    os.makedirs(os.path.join(world, "o"), exist_ok=True)
    outcome = call(["select", "--method", "maxtree", "--corr", os.path.join(world, "corr.csv"), "--json",
                    os.path.join(world, "o", "s.json"), "--plot", plot])
    assert outcome.refused("select", ["--plot %s: name the image format by the file's extension" % plot]), outcome.err
    assert os.listdir(os.path.join(world, "o")) == []


def test_outputs_remove_only_the_stale_files_of_the_whole_they_replace(tmp_path):
    from host.outputs import Outputs

    folder = tmp_path / "r"
    (folder / "sub").mkdir(parents=True)
    for name in ("a", "b", "c"):
        (folder / name).write_text("old")
        (folder / "sub" / name).write_text("old")
    with Outputs() as out:
        out.folder(str(folder), owned=("a", "b"))
        stage = out.path(str(folder))
        with open(os.path.join(stage, "a"), "w") as fh:
            fh.write("new")
        os.mkdir(os.path.join(stage, "sub2"))
        out.commit()
    # b went with the old whole; c is not part of it; sub/ was not written: its files stay
    assert sorted(os.listdir(str(folder))) == ["a", "c", "sub", "sub2"] and (folder / "a").read_text() == "new"
    assert sorted(os.listdir(str(folder / "sub"))) == ["a", "b", "c"]


# ------------------------------------------------------------ hole 9: tracebacks

def _one_row_run(world, rows=1):
    return write_run(_small_run(error_rows=rows), os.path.join(world, "short%d" % rows))


def _pty_board(frames):
    """A pty standing in for a board that answers the monitor's first command (V) with ``frames`` (bytes).
    Answering, not sending at a time: pySerial empties the input when it opens the port."""
    import select
    import threading
    import tty

    master, slave = os.openpty()
    tty.setraw(slave)

    def answer():
        if select.select([master], [], [], 30.0)[0]:
            os.read(master, 4096)
            for f in frames:
                os.write(master, f)

    threading.Thread(target=answer, daemon=True).start()
    return os.ttyname(slave), (master, slave)


def _hello(counter):
    from firmware.wire import PROTOCOL_VERSION
    from host.board.link import command_line

    return command_line(3, "00000000", "H", str(PROTOCOL_VERSION), "0.1.0", "A", "0ABCAE5F", "0001020304050607", "poly_slope",
                   "X", "11", "-", counter, "0A0B0C0D")


HOLE9 = [
    # (label, argv template, words of the one line)
    ("fit --model screw on one error row", ["fit", "--model", "screw", "{short1}", "--out", "{o}/s.json"],
     ["1 error row to identify"]),
    ("fit --model screw on five error rows, degree 0", ["fit", "--model", "screw", "{short5}", "--out", "{o}/s.json",
                                                        "--option", "geometric_degree=0", "--option", "free=q,h,lambda,alpha,c"],
     ["5 error rows to identify 6 unknowns"]),
    ("--option segments=100000", ["fit", "--model", "screw", "{run}", "--out", "{o}/s.json", "--option", "segments=100000"],
     ["--option segments='100000': must be <= 1000"]),
    ("--option dt_s=1e-9", ["fit", "--model", "screw", "{run}", "--out", "{o}/s.json", "--option", "dt_s=1e-9"],
     ["--option dt_s='1e-9': must be >= 0.1"]),
    ("--option reduced_segments=100", ["fit", "--model", "screw", "{run}", "--out", "{o}/s.json", "--option",
                                       "reduced_segments=100"], ["must be <= 32"]),
    ("--option max_nfev=-5", ["fit", "--model", "screw", "{run}", "--out", "{o}/s.json", "--option", "max_nfev=-5"],
     ["must be >= 1"]),
    ("simulate --noise-um 1e12", ["simulate", "--protocol", "idle", "--out", "{o}/sim", "--noise-um", "1e12"],
     ["--noise-um 1000000000000.0: must be a laser noise of 0..1000 um"]),
    ("simulate --noise-um nan", ["simulate", "--protocol", "idle", "--out", "{o}/sim", "--noise-um", "nan"], ["--noise-um nan"]),
    ("simulate effect magnitude 1e9", ["simulate", "--protocol", "idle", "--out", "{o}/sim", "--effects", "reversal_error=1e9"],
     ["protocol idle: the simulated run is not a valid run folder", "{o}/sim/errors.csv line 2"]),
    ("simulate effect magnitude inf", ["simulate", "--protocol", "idle", "--out", "{o}/sim", "--effects", "reversal_error=inf"],
     ["magnitude 'inf' is not a finite number"]),
    ("simulate --set h_W_m2K=1e308", ["simulate", "--protocol", "idle", "--out", "{o}/sim", "--set", "h_W_m2K=1e308"],
     ["h_W_m2K must be within +-1e+09 (found 1e+308)"]),
    ("simulate --set h_W_m2K=1e9", ["simulate", "--protocol", "idle", "--out", "{o}/sim", "--set", "h_W_m2K=1e9"],
     ["sub-steps per 10 s step, more than 100000"]),
    ("simulate --set screw_diameter_mm=1e-300", ["simulate", "--protocol", "idle", "--out", "{o}/sim", "--set",
                                                 "screw_diameter_mm=1e-300"], ["screw_diameter_mm must be at least 1e-09"]),
    ("simulate --set segments=100000", ["simulate", "--protocol", "idle", "--out", "{o}/sim", "--set", "segments=100000"],
     ["segments must be an integer in 2..1000"]),
]


def test_hole9_no_call_ends_in_a_traceback(world):
    tally = Tally("hole 9, tracebacks")
    fmt = {"o": os.path.join(world, "o"), "run": os.path.join(world, "run"), "short1": _one_row_run(world, 1),
           "short5": _one_row_run(world, 5)}
    os.makedirs(fmt["o"])
    for label, argv, words in HOLE9:
        outcome = call([a.format(**fmt) for a in argv])
        tally.add(label, outcome, outcome.refused(argv[0], [w.format(**fmt) for w in words])
                  and os.listdir(fmt["o"]) == [])
    key = os.path.join(world, "k.key")
    from host.board.linkauth import MAX_COUNTER
    for counter, words in (("abc", "counter 'abc' is not a number"), ("-5", "counter '-5' is not a number"),
                           (str(MAX_COUNTER + 64), "counter %d is above the largest, %d" % (MAX_COUNTER + 64, MAX_COUNTER)),
                           (str(MAX_COUNTER), "counter reached %d, the largest" % MAX_COUNTER)):
        port, fds = _pty_board([_hello(counter)])
        try:
            outcome = call(["monitor", "--port", port, "--latch", "--key", key])
        finally:
            for fd in fds:
                os.close(fd)
        tally.add("monitor --latch on hello counter %s" % counter, outcome, outcome.refused("monitor", [words]))
    assert not tally.report()


@PROPERTY
@given(key=st.sampled_from(["segments", "dt_s", "nut_weight", "reduced_segments", "reduced_dt_s", "feed_max_mm_min",
                            "max_nfev", "air_lag_s"]),
       text=st.one_of(st.floats(allow_nan=True, allow_infinity=True).map(repr), st.integers(-10 ** 30, 10 ** 30).map(str),
                      st.text(max_size=12)))
def test_property_hole9_screw_options_are_bounded(key, text):
    """Whatever the text, an option is refused in one line, or a finite value that sizes nothing beyond the model's
    bounds (segments <= 1000, dt_s >= 0.1 s: the grid's size), and that has the sign its physics needs."""
    from host import options
    from host.cli.fit_screw import OPTIONS

    try:
        value = options.parse_options(["%s=%s" % (key, text)], OPTIONS)[key]
    except UserError as exc:
        assert str(exc).startswith("--option %s=" % key)
        return
    assert math.isfinite(value)
    limits = {"segments": (2, 1000), "dt_s": (0.1, 600), "nut_weight": (0, 1e6), "reduced_segments": (1, 32),
              "reduced_dt_s": (0.001, 3600), "feed_max_mm_min": (1, 1e6), "max_nfev": (1, 100000),
              "air_lag_s": (0, 3600)}
    lo, hi = limits[key]
    assert lo <= value <= hi


@PROPERTY
@given(key=st.sampled_from(["h_W_m2K", "conductivity_W_mK", "density_kg_m3", "heat_capacity_J_kgK", "screw_diameter_mm",
                            "dt_s", "segments"]),
       value=st.one_of(st.floats(min_value=1e-300, max_value=1e308), st.integers(2, 10 ** 7)))
def test_property_hole9_twin_parameters_refused_or_stepped(key, value):
    """Any positive value of a screw parameter of the twin: a ValueError naming it, or a step map of at most
    MAX_SUBSTEPS sub-steps; never an OverflowError or ZeroDivisionError."""
    from host.twin import make_params
    from host.twin.screw import MAX_SUBSTEPS, ScrewGrid, ScrewIntegrator

    if key == "segments":
        value = int(value)
    try:
        params = make_params(**{key: value})
        grid = ScrewGrid(params)
        n = ScrewIntegrator(grid, params.dt_s, params.time_constant_s).substeps(1.0)
    except ValueError:
        return
    assert 1 <= n <= MAX_SUBSTEPS


@PROPERTY
@given(n=st.integers(1, 12), p=st.integers(1, 6), n_linear=st.integers(0, 5))
def test_property_hole9_identification_refuses_fewer_residuals_than_unknowns(n, p, n_linear):
    """The screw identification on n residuals and p + n_linear unknowns: a ValueError when n is smaller,
    never an IndexError; otherwise a result with a standard error per parameter."""
    from host.learning.screw.effects import ParamSpec
    from host.learning.screw.identify import IdentifiabilityWarning, fit_parameters

    specs = [ParamSpec("p%d" % k, 1.0, 0.01, 100.0, "-", True) for k in range(p)]
    x = np.linspace(0.0, 1.0, n)

    def residual(values):
        return np.array([sum(v * xi ** k for k, v in enumerate(values)) - (1.0 + xi) for xi in x])

    try:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", IdentifiabilityWarning)  # a poorly identified parameter is reported, not raised
            res = fit_parameters(residual, specs, max_nfev=20, n_linear=n_linear)
    except ValueError as exc:
        assert n < p + n_linear and "underdetermined" in str(exc)
        return
    assert n >= p + n_linear and len(res["std"]) == p


# ------------------------------------------------------------ hole 10: silent acceptances

def _fake_mpremote(world, script):
    path = os.path.join(world, "fake-mpremote")
    with open(path, "w") as fh:
        fh.write("#!/bin/sh\n" + script + "\n")
    os.chmod(path, 0o755)
    return path


def _edited_model(world, factor=1e30):
    doc = json.loads(open(os.path.join(world, "m.json")).read())
    coefs = doc["thermal"]["coefficients_um_per_mm_per_K"]
    coefs[sorted(coefs)[0]] = factor
    path = os.path.join(world, "edited.json")
    with open(path, "w") as fh:
        json.dump(doc, fh)
    return path


def _demo_rows(world, rows):
    """The demo run with only its first ``rows`` error rows (the same axis as the demo run, so only the rows differ)."""
    folder = os.path.join(world, "demo%d" % rows)
    shutil.copytree(DEMO_RUN, folder)
    path = os.path.join(folder, "errors.csv")
    with open(path) as fh:
        lines = fh.read().splitlines()[:1 + rows]
    with open(path, "w") as fh:
        fh.write("\n".join(lines) + "\n")
    return folder


def _map(world, **errors):
    path = os.path.join(world, "map-%s.json" % "-".join("%s=%s" % kv for kv in sorted(errors.items())))
    with open(path, "w") as fh:
        json.dump({"time": "time_s", "temperatures": ["T1", "T2"], "errors": {"T3": errors}}, fh)
    return path


def test_hole10_nothing_is_accepted_silently(world, monkeypatch):
    from host.cli.verbs import flash

    tally = Tally("hole 10, silent acceptances")
    o = os.path.join(world, "o")
    os.makedirs(o)
    run, log, table, key = (os.path.join(world, n) for n in ("run", "log.csv", "t.bin", "k.key"))
    unwired = os.path.join(world, "unwired.py")
    with open(unwired, "w") as fh:  # a board file whose CONFIG is computed, as firmware/boards/rp2040.py's is
        fh.write('CONFIG = {"channels": [{"name": "S%d" % i, "driver": "max31865", "bus": "spi0", "cs": 5 + i} '
                 'for i in range(3)]}\n')
    imp = ["import", log, "--time", "time_s", "--error", "T3", "--ignore", "T2", "--out", o + "/imp"]
    cases = [
        ("flash --dry-run, table sensors not on the --board", ["flash", "--port", "/dev/null", "--table", table,
                                                               "--board", unwired, "--dry-run", "--no-firmware"],
         ["table sensor(s) T1, T2, T3 have no channel in the board config %s" % unwired]),
        ("flash --dry-run --key NEW", ["flash", "--port", "/dev/null", "--table", table, "--dry-run", "--no-firmware",
                                       "--key", o + "/new.key"], ["a dry run creates no key"]),
        ("import --time-scale 1e300", imp + ["--temp", "T1", "--time-scale", "1e300"], ["x time_scale 1e+300"]),
        ("import the same --temp twice", imp + ["--temp", "T1", "--temp", "T1=other"],
         ["--temp T1=other: column 'T1' is already mapped by --temp T1"]),
        ("import a mapping with a string scale", ["import", log, "--mapping", _map(world, scale="1000"), "--out", o + "/imp"],
         ["errors.T3.scale must be a number, found '1000' (a string"]),
        ("import a mapping with an error scale of 0", ["import", log, "--mapping", _map(world, scale=0), "--out", o + "/imp"],
         ["errors.T3.scale is 0"]),
        ("simulate --protocol idle,idle", ["simulate", "--protocol", "idle,idle", "--out", o + "/sim"],
         ["protocol idle is named twice"]),
        ("simulate --effects a,a", ["simulate", "--protocol", "idle", "--effects", "sensor_lag,sensor_lag=2", "--out", o + "/sim"],
         ["sensor_lag given twice"]),
        ("discrepancy with a one-row run", ["discrepancy", DEMO_RUN, _demo_rows(world, 1), "--json", o + "/d.json"],
         ["has only 1 sweep; each run is held out once and needs at least 2"]),
        ("predict with an edited model", ["predict", _edited_model(world), run, "--out", o + "/p.csv"],
         ["does not match the document", "--allow-edited"]),
        ("export --envelope T1=-300:1000", ["export", os.path.join(world, "m.json"), "--out", o + "/t.bin", "--envelope",
                                            "T1=-300:1000"], ["outside -200..850 degC, the range of a Pt100"]),
        ("export --envelope-margin 500", ["export", os.path.join(world, "m.json"), "--out", o + "/t.bin",
                                          "--envelope-margin", "500"], ["--envelope-margin 500: widens"]),
        ("fit --option feed_max_mm_min=-1", ["fit", "--model", "screw", run, "--out", o + "/s.json", "--option",
                                             "feed_max_mm_min=-1"], ["feed_max_mm_min='-1': must be >= 1"]),
        ("monitor --duration inf", ["monitor", "--port", os.path.join(world, "port"), "--duration", "inf"],
         ["--duration inf: must be a finite number"]),
    ]
    for label, argv, words in cases:
        outcome = call(argv)
        tally.add(label, outcome, outcome.refused(argv[0], words) and os.listdir(o) == [])

    # flash on a port nobody answers: refused within the probe's bound, no key file
    monkeypatch.setattr(flash, "PROBE_TIMEOUT_S", 1.0)
    silent = _fake_mpremote(world, "exec sleep 30")
    start = time.monotonic()
    outcome = call(["flash", "--port", "/dev/null", "--table", table, "--no-firmware", "--mpremote", silent,
                    "--key", o + "/new.key"])
    tally.add("flash on a silent port", outcome, outcome.refused("flash", ["within 1 s on /dev/null"])
              and time.monotonic() - start < 10 and os.listdir(o) == [])
    # a flash that fails after the probe leaves no key file either
    failing = _fake_mpremote(world, 'case "$*" in *"fs cp"*) echo "copy failed" >&2; exit 1;; *) echo tcomp-probe;; esac')
    outcome = call(["flash", "--port", "/dev/null", "--table", table, "--no-firmware", "--mpremote", failing,
                    "--key", o + "/new.key"])
    tally.add("failed flash --key NEW", outcome, outcome.refused("flash", ["copy failed"]) and os.listdir(o) == [])
    # ... and a flash that works writes it, once the board holds it
    working = _fake_mpremote(world, "echo tcomp-probe")
    outcome = call(["flash", "--port", "/dev/null", "--table", table, "--no-firmware", "--mpremote", working,
                    "--key", o + "/new.key"])
    tally.add("flash --key NEW", outcome, outcome.rc == 0 and os.listdir(o) == ["new.key"]
              and stat.S_IMODE(os.stat(o + "/new.key").st_mode) == 0o600, warned=True)
    os.remove(o + "/new.key")

    # predict --allow-edited: accepted, and the JSON says so
    outcome = call(["predict", _edited_model(world, 0.01), run, "--out", o + "/p.csv", "--json", o + "/p.json", "--allow-edited"])
    ok = outcome.rc == 0 and "was edited after it was saved" in outcome.err
    tally.add("predict --allow-edited", outcome, ok and json.load(open(o + "/p.json"))["provenance"] == "edited", warned=True)
    for f in os.listdir(o):
        os.remove(os.path.join(o, f))

    # NaN offsets from a board: counted as malformed, recorded in the JSON, never written as rows
    from host.board.link import command_line
    frames = [command_line(1, "00000000", "O", "1000", "0", "nan", "0.0", "0.00"),
              command_line(2, "00000000", "O", "1100", "5", "2.5", "inf", "0.00"),
              command_line(3, "00000000", "Q", "1200", "5", "1e999", "0.1", "0.00"),
              command_line(4, "00000000", "O", "1300", "5", "2.5", "0.1", "0.00")]
    port, fds = _pty_board(frames)
    try:
        outcome = call(["monitor", "--port", port, "--hello", "--duration", "2", "--json", o + "/m.json", "--csv", o + "/m.csv"])
    finally:
        for fd in fds:
            os.close(fd)
    ok = outcome.rc == 0
    if ok:
        doc = json.load(open(o + "/m.json"))
        text = open(o + "/m.csv").read().lower()
        ok = (doc["frames"] == 1 and doc["malformed"] == 3 and [r["seq"] for r in doc["rows"]] == [4]
              and "total_um 'nan' is not a finite decimal number" in doc["bad"][0] and "nan" not in text and "inf" not in text)
    tally.add("NaN offsets into monitor's CSV and JSON", outcome, ok, warned=True)
    assert not tally.report()


@PROPERTY
@given(fields=st.lists(st.one_of(st.sampled_from(["nan", "inf", "-inf", "1e999", "1e3", "+1", "0x10", " 1", "1.", ".5",
                                                   "", "-", "--1", "1_0", "\uff11", "12", "-3", "2.50", "-0.1", "9" * 30]),
                                 st.text(alphabet="0123456789.-+eE", max_size=6)), min_size=5, max_size=5),
       kind=st.sampled_from(["O", "Q"]))
def test_property_hole10_only_finite_decimal_offsets_reach_the_rows(fields, kind):
    """An O/Q frame reaches monitor's rows only when every field is what the firmware prints: integers for t_ms and
    pos_um, plain decimals for the rest (checked here with float(), written independently of the monitor's regexes)."""
    from host.cli.verbs.monitor import offset_problem
    from host.board.link import Frame

    def plain(text, integer):
        body = text[1:] if text.startswith("-") else text
        if not body or not body.isascii() or len(text) > 24:
            return False
        if integer:
            return body.isdigit()
        whole, dot, frac = body.partition(".")
        return whole.isdigit() and (not dot or frac.isdigit()) and math.isfinite(float(text))

    good = all(plain(v, i < 2) for i, v in enumerate(fields))
    problem = offset_problem(Frame(7, 0, kind, list(fields), b""))
    assert (problem is None) == good, (fields, problem)


@PROPERTY
@given(text=st.one_of(st.integers(-10 ** 12, 10 ** 12).map(str), st.text(max_size=12), st.just("-")))
def test_property_hole10_hello_counters_are_numbers_below_max(text):
    # the one parser of the hello's counter (monitor --latch and the bridge go through it)
    from host.board.linkauth import MAX_COUNTER, CounterError, LinkSigner

    signer = LinkSigner(bytes(32))
    try:
        signer.observe(text)
    except CounterError:
        assert not (text.isascii() and text.isdigit() and int(text) <= MAX_COUNTER)
        return
    if text == "-":
        assert signer.counter == 0
    else:
        assert text.isascii() and text.isdigit() and signer.counter == int(text) <= MAX_COUNTER


@PROPERTY
@given(scale=st.one_of(st.floats(allow_nan=True, allow_infinity=True), st.integers(-10 ** 400, 10 ** 400),
                       st.text(max_size=6), st.booleans(), st.none()),
       time_scale=st.one_of(st.floats(min_value=1e-12, max_value=1e308), st.just(1.0)))
def test_property_hole10_import_scales(tmp_path, scale, time_scale):
    """Any error scale and time scale in a mapping: refused by name, or a run whose errors and times are finite,
    within the run format, and scaled exactly as asked."""
    from host.data.importer import LogImportError, import_csv

    src = tmp_path / "log.csv"
    src.write_text("time_s,T1,e\n0,20,1.5\n60,21,2.5\n120,22,-0.5\n")
    mapping = {"time": "time_s", "time_scale": time_scale, "temperatures": ["T1"], "errors": {"e": {"scale": scale}}}
    try:
        run = import_csv(str(src), mapping, "map.json")
    except LogImportError as exc:
        assert str(exc).startswith(("map.json: ", str(src)))
        return
    assert isinstance(scale, (int, float)) and not isinstance(scale, bool) and scale != 0
    assert np.all(np.isfinite(run.temperatures.time_s)) and run.temperatures.time_s[-1] <= 366 * 86400
    assert np.allclose(run.errors.error_um, np.array([1.5, 2.5, -0.5]) * float(scale))
    assert np.all(np.abs(run.errors.error_um) <= 10000)


def test_flash_reads_a_board_files_config_without_running_it(world, tmp_path):
    """The table's sensors are checked against a --board file's CONFIG (firmware/boards/rp2040.py builds it with a
    comprehension); a CONFIG that would need the file to run is never evaluated: a warning says nothing was checked."""
    table = os.path.join(world, "t.bin")
    rp2040 = os.path.join(ROOT, "firmware", "boards", "rp2040.py")
    outcome = call(["flash", "--port", "/dev/null", "--table", table, "--board", rp2040, "--dry-run", "--no-firmware"])
    kept = outcome.err.split("kept in ")[-1].split(";")[0]
    shutil.rmtree(kept, ignore_errors=True)
    assert outcome.rc == 0 and "warning" not in outcome.err, outcome.err  # T1..T3 are channels of rp2040.py
    marker = tmp_path / "ran"
    evil = tmp_path / "evil.py"
    for config in ('__import__("os").mkdir(%r)' % str(marker), '[c for c in ().__class__.__base__.__subclasses__()]',
                   '{"channels": [{"name": "T%d" % i} for i in range(10 ** 9)]}', '"%0999999999d" % 1'):
        evil.write_text("CONFIG = %s\n" % config)
        outcome = call(["flash", "--port", "/dev/null", "--table", table, "--board", str(evil), "--dry-run", "--no-firmware"])
        shutil.rmtree(outcome.err.split("kept in ")[-1].split(";")[0], ignore_errors=True)
        assert outcome.rc == 0 and "has no CONFIG dict that can be read without running the file" in outcome.err, outcome.err
        assert not marker.exists()
