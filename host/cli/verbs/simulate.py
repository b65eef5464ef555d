"""tcomp simulate --out DIR [--protocol NAME] [--effects a,b=2] [--seed N]"""

from __future__ import annotations

import argparse
from collections.abc import Iterable
from typing import Any


def _epilog():
    from host.twin import EFFECTS, LITERATURE_STATES, PROTOCOLS

    lines = ["protocols (--protocol NAME, a comma list, 'literature' = %s, or 'all'):" % ",".join(LITERATURE_STATES)]
    lines += ["  %-17s %s" % (p.name, p.description) for p in PROTOCOLS.values()]
    lines.append("  %-17s %s" % ("FILE.csv", "your own schedule: header duration_min,feed_mm_min,from_mm,to_mm, one row per state "
                                              "(feed 0: idle), a laser sweep at the start and after each row"))
    lines.append("")
    lines.append("effects (--effects NAME or NAME=MAGNITUDE, comma-separated; all off by default):")
    lines += ["  %-21s %s [default %g %s]" % (e.name, e.description, e.default, e.unit) for e in EFFECTS.values()]
    lines.append("")
    lines.append("One protocol writes the run into DIR; several write DIR/<protocol>/. Same seed, same bytes.")
    lines.append("Model, parameters and equations: docs/twin.md.")
    return "\n".join(lines)


def add_arguments(p: argparse.ArgumentParser) -> None:
    import argparse

    p.formatter_class = argparse.RawDescriptionHelpFormatter
    p.epilog = _epilog()
    p.add_argument("--out", required=True, metavar="DIR", help="run folder (one protocol) or parent folder (several)")
    p.add_argument("--protocol", default="v8000_r210_490", metavar="NAME",
                   help="protocol name, FILE.csv, comma list, 'literature' or 'all' (default v8000_r210_490; list below)")
    p.add_argument("--effects", default="", metavar="LIST",
                   help="comma-separated effects to switch on, each NAME or NAME=MAGNITUDE (list below)")
    p.add_argument("--seed", type=int, default=0, help="random seed (ambient wander, sensor and laser noise); default 0")
    p.add_argument("--noise-um", type=float, default=None, metavar="UM",
                   help="laser measurement noise, standard deviation in um (default 0.5)")
    p.add_argument("--set", action="append", default=[], metavar="KEY=VALUE",
                   help="override an axis parameter (host.twin.AxisParams field, e.g. h_W_m2K=20); repeatable")
    p.add_argument("--error-reference", default="start", metavar="start|SENSOR",
                   help="errors.csv convention: 'start' (raw, relative to the machine at the run's start; default) or a sensor "
                        "(e.g. T3): errors corrected to its temperature, as a laser's material-temperature compensation does")
    p.add_argument("--json", metavar="PATH", help="write a summary (runs, folders, file sha256, peak errors) as JSON")


def parse_effects(text: str) -> dict[str, float | None]:
    """'a,b=2.5' -> {'a': None, 'b': 2.5}; raises ValueError naming the bad item (a magnitude that is not a
    finite number, an effect given twice)."""
    import math

    out, seen = {}, {}
    for item in (s.strip() for s in text.split(",")):
        if not item:
            continue
        name, eq, mag = item.partition("=")
        name = name.strip()
        if name in seen:
            raise ValueError("--effects: %s given twice (%s and %s)" % (name, seen[name], item))
        seen[name] = item
        if eq:
            try:
                out[name] = float(mag)
            except ValueError:
                raise ValueError("--effects item %r: magnitude %r is not a number" % (item, mag))
            if not math.isfinite(out[name]):
                raise ValueError("--effects item %r: magnitude %r is not a finite number" % (item, mag))
        else:
            out[name] = None
    return out


def parse_overrides(items: Iterable[str]) -> dict[str, Any]:
    """['h_W_m2K=20', 'positions_mm=0,100,700'] -> typed overrides for host.twin.make_params."""
    import dataclasses

    from host.twin import AxisParams

    types = {f.name: f.type for f in dataclasses.fields(AxisParams)}
    out = {}
    for item in items:
        key, eq, value = item.partition("=")
        key = key.strip()
        if not eq:
            raise ValueError("--set %r: expected KEY=VALUE" % item)
        if key not in types:
            raise ValueError("--set %r: unknown parameter %r; valid: %s" % (item, key, ", ".join(types)))
        kind = types[key]
        try:
            if kind in (tuple, "tuple"):
                out[key] = tuple(float(v) for v in value.split(",") if v.strip())
            elif kind in (int, "int"):
                out[key] = int(value)
            elif kind in (str, "str"):
                out[key] = value
            else:
                out[key] = float(value)
        except ValueError:
            raise ValueError("--set %r: %r is not a valid %s" % (item, value, getattr(kind, "__name__", kind)))
    return out


MAX_NOISE_UM = 1000.0  # 1 mm: a laser that noisy measures nothing; beyond, errors leave the run format's range


def check_protocol_list(text: str) -> None:
    """Refuse a protocol named twice in ``--protocol`` (directly, or by a name and a group that holds it):
    it would be simulated once, and one protocol writes the run into DIR itself, not DIR/<protocol>/."""
    from host.twin import LITERATURE_STATES, PROTOCOLS

    seen = {}
    for part in (p.strip() for p in text.split(",")):
        names = list(PROTOCOLS) if part == "all" else list(LITERATURE_STATES) if part == "literature" else [part]
        for n in names:
            if n and n in seen:
                raise ValueError("--protocol %s: protocol %s is named twice (by %s and by %s); name each protocol once"
                                 % (text, n, seen[n], part))
            seen[n] = part


def _sha256(path):
    import hashlib

    with open(path, "rb") as fh:
        return hashlib.sha256(fh.read()).hexdigest()


def run(args: argparse.Namespace) -> int:
    from host.outputs import Outputs

    from host.data.runs import RUN_FILES

    # a protocol file is an input: no output may be written over it
    with Outputs([p.strip() for p in args.protocol.split(",") if p.strip().lower().endswith(".csv")]) as out:
        out.folder(args.out, "--out", owned=RUN_FILES)
        if args.json:
            out.file(args.json, "--json")
        _simulate(args, out)
        out.commit()
    return 0


def _simulate(args, out):
    import json
    import os

    import numpy as np

    from host.errors import UserError
    from host.data.runs import RunFormatError, load_run
    from host.twin import DEFAULT_NOISE_UM, write_runs

    noise = DEFAULT_NOISE_UM if args.noise_um is None else args.noise_um
    if not 0 <= noise <= MAX_NOISE_UM:  # NaN too
        raise UserError("--noise-um %s: must be a laser noise of 0..%g um (standard deviation)" % (args.noise_um, MAX_NOISE_UM))
    try:
        check_protocol_list(args.protocol)
        effects = parse_effects(args.effects)
        overrides = parse_overrides(args.set)
        written = write_runs(out.path(args.out), args.protocol, effects, args.seed, noise, args.error_reference, **overrides)
    except ValueError as exc:
        raise UserError(str(exc))
    summary = {"seed": args.seed, "noise_um": noise, "runs": []}
    for name, folder in written:
        try:
            run_ = load_run(folder)  # what we wrote must load back
        except RunFormatError as exc:
            # Settings far outside a real axis (an effect magnitude of 1e9) make a run the format refuses.
            first = exc.problems[0].replace(folder, out.shown(folder)) if exc.problems else str(exc)
            raise UserError("protocol %s: the simulated run is not a valid run folder (%d problem%s, first: %s); "
                            "--effects magnitudes and --set values must stay within what a feed axis does"
                            % (name, len(exc.problems), "" if len(exc.problems) == 1 else "s", first))
        e = run_.errors
        files = sorted(f for f in os.listdir(folder) if f.endswith((".csv", ".json")))
        summary["runs"].append({
            "protocol": name,
            "folder": out.shown(folder),
            "effects": run_.meta["simulation"]["effects"],
            "duration_s": float(run_.temperatures.time_s[-1]),
            "temperature_samples": int(run_.temperatures.time_s.size),
            "sensors": list(run_.temperatures.names),
            "sweeps": len(e.sweeps()),
            "max_abs_error_um": round(float(np.max(np.abs(e.error_um))), 3),
            "sha256": {f: _sha256(os.path.join(folder, f)) for f in files},
        })
        print("%-17s -> %s (%d sweeps, %.1f h, max |error| %.1f um)"
              % (name, out.shown(folder), len(e.sweeps()), run_.temperatures.time_s[-1] / 3600.0, np.max(np.abs(e.error_um))))
    if args.json:
        with out.open(args.json) as fh:
            json.dump(summary, fh, indent=2)
            fh.write("\n")
