"""tcomp hil --run RUN_DIR --table table.bin [--model MODEL.json] [--duration S] [--interpreter micropython|cpython|qemu]
[--json OUT.json]

Judges the board: its answer at every errors.csv row against the measurement (the row's error) and, with
--model, against the host model's predict of that row: RMSE and largest residual per errors channel
(hil_judge.py; the JSON's ``judge`` block, docs/hil.md "Judging").

The simulated rig lives with the HIL tests (hil_tests/rig, hil_tests/sim). This verb reaches it through
the entry point group ``tcomp.rig`` (pyproject.toml; the rig's side is hil_tests/rig/entry.py), looked up
with importlib.metadata inside run(): host never imports hil_tests (tests/test_layers.py), and no other
verb, nor `tcomp --help`, loads the rig.
"""

from __future__ import annotations

import argparse
from typing import Any

import json
import re
import sys
import time
from importlib.metadata import entry_points

RIG_GROUP = "tcomp.rig"
RIG_ENTRY = "hil"

_FAULT = re.compile(r"^(open|short|stuck|absent):([^@]+)@([0-9.]+)-([0-9.]+)$")


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("--run", required=True, help="run folder (twin or measured) whose temperatures drive the chips")
    p.add_argument("--table", required=True, help="coefficient table (tcomp export)")
    p.add_argument("--interpreter", choices=("micropython", "cpython", "qemu"), default="micropython",
                   help="interpreter of the firmware process (default micropython; qemu: the emulated Cortex-M3 "
                        "board image make setup builds, docs/hil.md)")
    p.add_argument("--json", help="write {answers, frames, faults, ...} here")
    p.add_argument("--config", help="board config JSON (default: the table's sensors on MAX31865s, the last on an "
                                    "ADS122C04)")
    p.add_argument("--fault", action="append", default=[], metavar="KIND:SENSOR@START-END",
                   help="inject a sensor fault (open, short, stuck, absent) between two run times in s; repeatable")
    p.add_argument("--noise-uohm", type=int, default=2000, help="RTD noise, micro-ohm standard deviation")
    p.add_argument("--warmup-s", type=float, default=60.0, help="simulated seconds before the run's t=0")
    p.add_argument("--print-every", type=int, default=60,
                   help="print every Nth periodic O frame (all other frames are printed); 0: none")
    p.add_argument("--model", help="the model document the table was exported from: the board is also judged "
                                   "against its predict (host model) at every errors.csv row")
    p.add_argument("--duration", type=float, default=None, metavar="S",
                   help="simulate only the first S seconds of the run (from its first temperature sample)")
    p.add_argument("--raw", action="store_true",
                   help="print the frames as they arrive on the wire ($TC lines) instead of labelled lines")


def _faults(specs, sensors, end_s):
    """--fault specs -> dicts; a fault starting after the run ends is refused, one ending after it is cut there."""
    from host.errors import UserError
    out = []
    for s in specs:
        m = _FAULT.match(s)
        if not m:
            raise UserError("--fault %r: expected KIND:SENSOR@START-END, e.g. open:T1@600-900" % s)
        try:
            kind, sensor, a, b = m.group(1), m.group(2), float(m.group(3)), float(m.group(4))
        except ValueError:
            raise UserError("--fault %r: START and END must be numbers of seconds, e.g. open:T1@600-900" % s)
        if sensor not in sensors:
            raise UserError("--fault %r: sensor %s is not one of the table's %s" % (s, sensor, ", ".join(sensors)))
        if b <= a:
            raise UserError("--fault %r: end %.3g s is not after start %.3g s" % (s, b, a))
        if a >= end_s:
            raise UserError("--fault %r: starts at %.6g s, after the run ends at %.6g s (times are run times in s)" % (s, a, end_s))
        if b > end_s:
            print("tcomp hil: warning: --fault %r ends at %.6g s, after the run ends at %.6g s: the fault lasts to the "
                  "end of the run (the rig would otherwise keep simulating until %.6g s)" % (s, b, end_s, b), file=sys.stderr)
            b = end_s
        out.append({"kind": kind, "sensor": sensor, "start_s": a, "end_s": b})
    return out


def _actions(faults):
    acts = []
    for f in faults:
        s = f["sensor"]
        if f["kind"] == "absent":
            acts.append((f["start_s"], lambda r, s=s: r.chip(s, present=False)))
            acts.append((f["end_s"], lambda r, s=s: r.chip(s, present=True)))
        else:
            acts.append((f["start_s"], lambda r, s=s, k=f["kind"]: r.sensor(s, k)))
            acts.append((f["end_s"], lambda r, s=s: r.sensor(s, "ok")))
    return acts


def load_rig() -> Any:
    """The rig's module (``Rig``, ``RigError``, ``play``, ``rig_config``) by its entry point; a UserError
    when no installed distribution offers it (``python -m host`` from a tree that was never installed)."""
    from host.errors import UserError
    found = [ep for ep in entry_points(group=RIG_GROUP) if ep.name == RIG_ENTRY]
    if not found:
        raise UserError("no HIL rig installed: no entry point %r in group %r (install tcomp from the checkout: "
                        "make setup, or pip install -e .)" % (RIG_ENTRY, RIG_GROUP))
    try:
        return found[0].load()
    except ImportError as exc:
        raise UserError("the HIL rig's entry point %s does not import: %s" % (found[0].value, exc))


def run(args: argparse.Namespace) -> int:
    from host.outputs import Outputs

    with Outputs([args.run, args.table, args.config, args.model]) as out:
        if args.json:
            out.file(args.json, "--json")
        rc = _hil(args, out)
        out.commit()
    return rc


def _hil(args, out):
    from firmware.table import TableError, parse_table
    from host.data.runs import RunFormatError, load_run
    from host.errors import UserError

    rig_module = load_rig()
    Rig, RigError, play, rig_config = rig_module.Rig, rig_module.RigError, rig_module.play, rig_module.rig_config

    if args.print_every < 0:
        raise UserError("--print-every %d: must be >= 0 (every Nth periodic frame; 0: none)" % args.print_every)
    try:
        run_ = load_run(args.run)
    except RunFormatError as exc:
        raise UserError(str(exc))
    from host.cli import hil_judge
    if args.duration is not None:
        run_ = hil_judge.first_seconds(run_, args.duration, args.run)
    model = hil_judge.read_model(args.model) if args.model else None
    try:
        with open(args.table, "rb") as f:
            data = f.read()
        table = parse_table(data)
    except OSError as exc:
        raise UserError("%s: %s" % (args.table, exc))
    except TableError as exc:
        raise UserError("%s: not a valid table: %s" % (args.table, exc))
    if not args.warmup_s >= 0:
        raise UserError("--warmup-s must be >= 0 (found %g)" % args.warmup_s)
    end_s = max(float(run_.temperatures.time_s[-1]), float(run_.errors.time_s.max()))
    # The warm-up only lets the firmware's filters settle on the first temperatures; longer than the run
    # itself (or the 60 s default on a short run) is simulated time nobody asked to see.
    longest = max(end_s - float(run_.temperatures.time_s[0]), 60.0)
    if args.warmup_s > longest:
        raise UserError("--warmup-s %g: longer than the run %s itself (%.6g s); the warm-up only settles the "
                        "firmware's filters on the first temperatures" % (args.warmup_s, args.run, longest))
    if not args.noise_uohm >= 0:
        raise UserError("--noise-uohm must be >= 0 (found %g)" % args.noise_uohm)
    sensors = list(table.sensors)
    missing = [s for s in sensors if s not in run_.temperatures.names]
    if missing:
        raise UserError("%s: the table's sensors %s are not columns of %s/temperatures.csv"
                        % (args.table, ", ".join(missing), args.run))
    if args.config:
        try:
            with open(args.config, encoding="utf-8") as f:
                cfg = json.load(f)
        except (OSError, json.JSONDecodeError) as exc:
            raise UserError("%s: %s" % (args.config, exc))
        # The firmware's own boot-time validator, run here so a bad config is named before the rig starts.
        from host.board.config import load_config
        if not isinstance(cfg, dict):
            raise UserError("%s: a board config is a JSON object (firmware/board.py), found %s" % (args.config, type(cfg).__name__))
        try:
            load_config(cfg)
        except (ValueError, TypeError, AttributeError) as exc:
            raise UserError("%s: %s" % (args.config, exc))
        from host.cli.verbs.flash import unwired_sensors
        missing = unwired_sensors(sensors, cfg)
        if missing:
            raise UserError("%s: table sensor(s) %s have no channel in the board config %s (channels: %s)" % (
                args.table, ", ".join(missing), args.config, ", ".join(str(c.get("name")) for c in cfg["channels"])))
    else:
        cfg = rig_config(sensors, n_ads=1 if len(sensors) > 1 else 0)
    faults = _faults(args.fault, sensors, end_s)
    if model is not None:
        host_um = hil_judge.host_predict(model, run_, args.model, args.run, sensors)
    else:
        host_um = None
    if table.error_ref != hil_judge.error_ref_code(run_.error_reference, sensors):
        print("tcomp hil: warning: the table's error reference (%s) is not the run's (%s): the residual against "
              "the measurement compares different errors" % (hil_judge.error_ref_name(table.error_ref, sensors),
                                                             run_.error_reference), file=sys.stderr)
    channel_names = [c.get("name") for c in cfg["channels"]]
    output_name = hil_judge.output_name(run_, model)
    screw = table.kind == "screw_reduced"
    dyn = table.kind == "dynamic"  # its inputs: the run's spindle speed (P) and feed (M); filters from the run's start (L)
    every = args.print_every
    count = {"O": 0}

    def show(f):
        if f.kind == "O":
            count["O"] += 1
            if not every or count["O"] % every:
                return
        print(f.raw.decode("ascii", "replace") if args.raw else hil_judge.label(f, channel_names, output_name))
        sys.stdout.flush()

    t0 = time.monotonic()
    temps = {s: float(run_.temperatures.column(s)[0]) for s in sensors}
    try:
        with Rig(cfg, data, interpreter=args.interpreter, temps=temps, noise_uohm=args.noise_uohm) as rig:
            rig.reader.on_frame = show
            answers = play(rig, run_, sensors, warmup_ms=int(args.warmup_s * 1000), motion=screw or dyn,
                           faults=_actions(faults), spindle=dyn,
                           # a run-start table latches at the run's start; a fixed-reference one (an observer's) refuses L
                           latch=dyn and table.ref_mode == 1 and rig.signer is not None,
                           query_delay_ms=200 if dyn else 0)
            n = len(rig.frames)
            bad = len(rig.reader.decoder.bad)
            sim_s = rig.t_ms / 1000.0
    except RigError as exc:
        raise UserError("the firmware did not survive: %s" % exc)
    wall = time.monotonic() - t0
    judge = hil_judge.judge(run_, answers, host_um, model)
    summary = {"answers": hil_judge.answer_rows(run_, answers, host_um, model),
           "frames": n, "faults": faults, "malformed_frames": bad, "interpreter": args.interpreter,
           "table": {"kind": table.kind, "crc32": "%08X" % table.crc, "sensors": sensors},
           "simulated_s": sim_s, "wall_s": round(wall, 3),
           "duration_s": args.duration, "model": args.model, "judge": judge}
    print("%s: %d answers, %d frames (%d malformed), %.0f s simulated in %.1f s on %s" % (
        args.run, len(answers), n, bad, sim_s, wall, args.interpreter))
    for line in hil_judge.report_lines(judge):
        print(line)
    if args.json:
        with out.open(args.json) as f:
            json.dump(summary, f, indent=1)
            f.write("\n")
    return 0 if bad == 0 else 1
