"""What `tcomp hil` says of the board's answers: the run cut to its first seconds (``--duration``), the host
model's predict (``--model``), the residuals per errors channel, and the frames labelled by name.

Residuals (docs/hil.md, "Judging"): against the measurement, measured − board (what would remain of the
error once the board's offset is applied, as `tcomp predict` reports measured − predicted); against the host
model, board − host (what the integer table on the board adds to the model's own error). Per channel: rows,
RMSE, largest |residual|, largest and smallest residual.
"""

from __future__ import annotations

from collections.abc import Sequence
import dataclasses
import math
from typing import TYPE_CHECKING, Any

from host.errors import UserError

if TYPE_CHECKING:  # for the hints only: numpy stays imported where it is used, as before
    import numpy as np

    from host.board.link import Frame
    from host.data.runs import Run


def first_seconds(run: Run, seconds: float, where: str) -> Run:
    """``run`` cut to its first ``seconds`` (from its first temperature sample): temperatures, errors rows,
    moves (a move running at the cut ends there) and spindle samples up to the cut."""
    import numpy as np
    if not (seconds > 0 and math.isfinite(seconds)):
        raise UserError("--duration %g: must be a positive number of seconds" % seconds)
    t = run.temperatures
    start = float(t.time_s[0])
    end = start + seconds
    keep = t.time_s <= end
    e = run.errors
    rows = e.time_s <= end
    if not rows.any():
        raise UserError("--duration %g: %s has no errors.csv row in its first %g s (its first is at %g s, "
                        "%g s after the first temperature sample)" % (seconds, where, seconds, float(e.time_s.min()),
                                                                       float(e.time_s.min()) - start))
    temps = dataclasses.replace(t, time_s=t.time_s[keep], values=t.values[keep])
    errors = dataclasses.replace(e, time_s=e.time_s[rows], position_mm=e.position_mm[rows], error_um=e.error_um[rows],
                                 direction=None if e.direction is None else e.direction[rows],
                                 channel=None if e.channel is None else e.channel[rows])
    motion = run.motion
    if motion is not None:
        m = motion.t_start_s < end
        motion = dataclasses.replace(motion, t_start_s=motion.t_start_s[m], t_end_s=np.minimum(motion.t_end_s[m], end),
                                     from_mm=motion.from_mm[m], to_mm=motion.to_mm[m],
                                     feed_mm_min=motion.feed_mm_min[m])
    spindle = run.spindle
    if spindle is not None:
        m = spindle.time_s <= end
        spindle = dataclasses.replace(spindle, time_s=spindle.time_s[m], rpm=spindle.rpm[m])
    return dataclasses.replace(run, temperatures=temps, errors=errors, motion=motion, spindle=spindle)


def read_model(path: str) -> tuple[dict[str, Any], Any]:
    """The host model of ``--model`` (as `tcomp predict` reads it; an edited document is refused)."""
    from host.learning.documents import ModelFormatError, load_model, read_document
    from models_export.document import edited_reason, provenance
    try:
        doc = read_document(path)
        model = load_model(doc)
    except ModelFormatError as exc:
        raise UserError("--model %s: %s" % (path, exc))
    actual, declared = provenance(doc)
    if declared is not None and declared != actual:
        raise UserError("--model %s: %s" % (path, edited_reason(declared, actual)))
    return doc, model


def host_predict(model: tuple[dict[str, Any], Any], run: Run, model_path: str, run_path: str,
                 table_sensors: Sequence[str]) -> np.ndarray:
    """The host model's prediction at every errors.csv row (NaN on another channel's rows)."""
    import numpy as np
    doc, m = model
    if list(doc.get("sensors") or ()) != list(table_sensors):
        raise UserError("--model %s: its sensors (%s) are not the table's (%s): not the document the table was "
                        "exported from" % (model_path, ", ".join(doc.get("sensors") or ()), ", ".join(table_sensors)))
    try:
        pred = np.asarray(m.predict(run), dtype=float)
    except ValueError as exc:
        raise UserError("%s cannot be predicted with --model %s: %s" % (run_path, model_path, exc))
    if pred.shape != (len(run.errors),):
        raise UserError("--model %s returned %s predictions for %d rows" % (model_path, pred.shape, len(run.errors)))
    channel = doc.get("channel")
    if channel and run.errors.channel is not None:
        pred = np.where(run.errors.channel == channel, pred, np.nan)
    return pred


def error_ref_code(reference: str, sensors: Sequence[str]) -> int | None:
    """The table's code (firmware/table.py ``error_ref``) of a run's error reference; None when none fits."""
    if reference == "start":
        return 0
    return 1 + list(sensors).index(reference) if reference in sensors else None


def error_ref_name(code: int, sensors: Sequence[str]) -> str:
    return "start" if code == 0 else sensors[code - 1] if 0 < code <= len(sensors) else "code %d" % code


def output_name(run: Run, model: tuple[dict[str, Any], Any] | None) -> str:
    """The name of the output channel the table computes: the model's errors channel, else the run's only
    channel, else the run's axis (meta.json), else "error"."""
    if model is not None and model[0].get("channel"):
        return model[0]["channel"]
    channels = run.errors.channels()
    if len(channels) == 1:
        return str(channels[0])
    return str(run.meta.get("axis") or "error")


def _row_channels(run, model):
    e = run.errors
    if e.channel is not None:
        return [str(c) for c in e.channel]
    return [output_name(run, model)] * len(e)


def _stats(residuals):
    import numpy as np
    r = np.asarray(residuals, dtype=float)
    r = r[np.isfinite(r)]
    if not r.size:
        return None
    return {"rows": int(r.size), "rmse_um": float(np.sqrt(np.mean(r ** 2))), "max_abs_um": float(np.max(np.abs(r))),
            "max_um": float(r.max()), "min_um": float(r.min())}


def judge(run: Run, answers: Sequence[dict[str, Any]], host_um: np.ndarray | None,
          model: tuple[dict[str, Any], Any] | None = None) -> dict[str, Any]:
    """{"output": the channel the board computes, "residuals": what each is, "channels": {name: {rows,
    held_or_fallback, against_measurement, against_host_model, host_model_against_measurement}}}
    (docs/hil.md, "Judging")."""
    import numpy as np
    e = run.errors
    board = np.array([a["offset_um"] for a in answers], dtype=float)
    measured = np.asarray(e.error_um, dtype=float)
    names = _row_channels(run, model)
    out = {}
    for name in dict.fromkeys(names):
        rows = np.array([n == name for n in names])
        entry = {"rows": int(rows.sum()),
                 "held_or_fallback": int(sum(1 for a, r in zip(answers, rows) if r and (a["held"] or a["fallback"]))),
                 "against_measurement": _stats(measured[rows] - board[rows]),
                 "against_host_model": None, "host_model_against_measurement": None}
        if host_um is not None:
            entry["against_host_model"] = _stats(board[rows] - host_um[rows])
            entry["host_model_against_measurement"] = _stats(measured[rows] - host_um[rows])
        out[name] = entry
    return {"output": output_name(run, model),
            "residuals": {"against_measurement": "measured - board (um)",
                          "against_host_model": "board - host model (um)",
                          "host_model_against_measurement": "measured - host model (um)"},
            "channels": out}


def answer_rows(run: Run, answers: Sequence[dict[str, Any]], host_um: np.ndarray | None,
                model: tuple[dict[str, Any], Any] | None = None) -> list[dict[str, Any]]:
    """The JSON's answers: time, position, the board's offset and status, as before; and the row's channel,
    its measured error and residual, and the host model's prediction when there is one."""
    e = run.errors
    names = _row_channels(run, model)
    out = []
    for i, a in enumerate(answers):
        row = {k: a[k] for k in ("time_s", "position_mm", "offset_um", "status")}
        row["channel"] = names[i]
        row["measured_um"] = float(e.error_um[i])
        row["residual_um"] = float(e.error_um[i]) - a["offset_um"]
        if host_um is not None:
            row["host_um"] = None if not math.isfinite(host_um[i]) else float(host_um[i])
        out.append(row)
    return out


def report_lines(verdict: dict[str, Any]) -> list[str]:
    """The printout: one line per channel and comparison."""
    lines = []
    for name, c in verdict["channels"].items():
        extra = ", %d held or in fallback" % c["held_or_fallback"] if c["held_or_fallback"] else ""
        if name != verdict["output"]:
            extra += " (the board computes %s)" % verdict["output"]
        lines.append("channel %s: %d rows%s" % (name, c["rows"], extra))
        for key, what in (("against_measurement", "board vs measured (measured - board)"),
                          ("host_model_against_measurement", "host model vs measured (measured - host)"),
                          ("against_host_model", "board vs host model (board - host)")):
            s = c[key]
            if s is not None:
                lines.append("  %-42s RMSE %8.3f um  max |r| %8.3f um  (max %+.3f, min %+.3f; %d rows)"
                             % (what, s["rmse_um"], s["max_abs_um"], s["max_um"], s["min_um"], s["rows"]))
    return lines


def label(frame: Frame, channel_names: Sequence[str], output: str) -> str:
    """One frame as a labelled line: the output channel's name on offsets, the board's channel names on
    temperatures and on the faulty-sensor bits of the status word."""
    from host.board.link import SENSOR_MASK, STATUS_BITS
    flags = [n for bit, n in STATUS_BITS.items() if frame.status & bit]
    faulty = [channel_names[i] if i < len(channel_names) else "channel %d" % i
              for i in range(16) if frame.status & SENSOR_MASK & (1 << i)]
    if faulty:
        flags.append("faulty " + " ".join(faulty))
    tail = ("  [%s]" % "; ".join(flags)) if flags else ""
    f = frame.fields
    try:
        if frame.kind in ("O", "Q") and len(f) >= 5:
            return "%s %6d  t=%.3f s  %s at %.3f mm: %s um (at ref %s um, slope %s um/m)%s" % (
                frame.kind, frame.seq, int(f[0]) / 1000.0, output, int(f[1]) / 1000.0, f[2], f[3], f[4], tail)
        if frame.kind == "T" and len(f) >= 1:
            cells = ["%s %s" % (channel_names[i] if i < len(channel_names) else "channel %d" % i,
                                ("fault %s" % v[1:]) if v.startswith("!") else v + " C") for i, v in enumerate(f[1:])]
            return "T %6d  t=%.3f s  %s%s" % (frame.seq, int(f[0]) / 1000.0, ", ".join(cells), tail)
    except ValueError:
        pass  # a field that is not a number: shown as it came
    return "%s %6d  %s%s" % (frame.kind, frame.seq, ",".join(f), tail)
