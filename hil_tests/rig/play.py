"""Play a run folder into the rig: temperatures ramp sample to sample, motion is reported (M: feed
and range), the spindle speed too (``spindle=True``: P,<position>,<rpm> at every change of
spindle.csv), and at every row of errors.csv the firmware is asked for the offset at that time and
position (Q).

Simulated time = run time + ``warmup_ms`` (the firmware boots and its
limiter settles on the run's first temperatures before t = 0).
"""
import math

from host.board.link import FALLBACK, HELD, RECOVERING


def sensor_rows(run, sensors):
    t = run.temperatures
    cols = [t.column(s) for s in sensors]
    for i in range(len(t.time_s)):
        yield float(t.time_s[i]), {s: float(c[i]) for s, c in zip(sensors, cols)}


def motion_events(run):
    """(time_s, feed_mm_min, lo_mm, hi_mm) at move starts and (time_s, 0, 0, 0) at move ends."""
    out = []
    m = run.motion
    if m is None:
        return out
    for i in range(len(m)):
        lo, hi = sorted((float(m.from_mm[i]), float(m.to_mm[i])))
        out.append((float(m.t_start_s[i]), float(m.feed_mm_min[i]), lo, hi))
        out.append((float(m.t_end_s[i]), 0.0, 0.0, 0.0))
    out.sort(key=lambda e: e[0])
    return out


def spindle_events(run):
    """(time_s, rpm) at the first row of spindle.csv and wherever the speed changes."""
    out = []
    sp = run.spindle
    if sp is None:
        return out
    last = None
    for t, rpm in zip(sp.time_s, sp.rpm):
        v = int(round(float(rpm)))
        if v != last:
            out.append((float(t), v))
            last = v
    return out


def play(rig, run, sensors, warmup_ms=60000, motion=True, on_answer=None, faults=None, spindle=False, latch=False,
         query_delay_ms=0):
    """Returns a list of answers (dict per errors.csv row, in file order).

    ``latch``: send the signed L at the run's start (its cold start: the reference temperatures, and a
    dynamic table's filters start there, as the host's do at the run's first sample). ``query_delay_ms``:
    ask each Q that much after its row's time (after a dynamic table's filter step at that sample)."""
    rows = list(sensor_rows(run, sensors))
    t0_ms = warmup_ms
    first = rows[0][1]
    rig.jump(first)
    if latch:  # just before t = 0, so the latch (at the board's next poll) is in place at the run's start
        rig.run(t0_ms - 50)
        n0 = len(rig.frames)
        rig.send_signed("L")
        rig.run(t0_ms)
        if not any(f.kind == "A" and f.fields[:1] == ["L"] for f in rig.frames[n0:]):
            raise RuntimeError("the board did not acknowledge the latch: %r" % (rig.frames[n0:],))
    rig.run(t0_ms)
    pos_um = int(round(float(run.errors.position_mm[0]) * 1000)) if len(run.errors) else 0
    events = []
    if spindle:
        for t, rpm in spindle_events(run):
            events.append((t, 0, ("spindle", rpm)))
    for t, temps in rows:
        events.append((t, 1, temps))
    if motion:
        for t, f, lo, hi in motion_events(run):
            events.append((t, 0, (f, lo, hi)))
    e = run.errors
    for i in range(len(e)):
        events.append((float(e.time_s[i]) + query_delay_ms / 1000.0, 2, i))
    for spec in faults or []:
        events.append((spec[0], 3, spec[1]))
    events.sort(key=lambda ev: (ev[0], ev[1]))
    answers = [None] * len(e)
    reached = 0  # temperature rows reached so far
    for t, kind, data in events:
        target = t0_ms + int(round(t * 1000))
        if target > rig.t_ms:
            # frames need not be read before a query: only the query's reply is waited for
            rig.run(target, sync=False)
        if kind == 1:
            # at a sample: head for the next one, so that any time in between sees the interpolation
            reached += 1
            if reached < len(rows):
                t_next, temps_next = rows[reached]
                rig.ramp(t0_ms + int(round(t_next * 1000)), temps_next)
            continue
        if kind == 0 and data[0] == "spindle":
            rig.send("P", pos_um, data[1])
        elif kind == 0:
            f, lo, hi = data
            rig.send("M", int(round(f)), int(round(lo * 1000)), int(round(hi * 1000)))
        elif kind == 3:
            data(rig)
        else:
            pos_um = int(round(float(e.position_mm[data]) * 1000))
            q = rig.request("Q", pos_um, kinds=("Q",))
            a = {"time_s": float(e.time_s[data]), "position_mm": float(e.position_mm[data]),
                 "offset_um": q.total_um, "status": "%08X" % q.status, "held": bool(q.status & HELD),
                 "fallback": bool(q.status & (FALLBACK | RECOVERING))}
            answers[data] = a
            if on_answer is not None:
                on_answer(a)
    return answers


def power_cut_without_lags(rig, temps):
    """Cut the board's power (SIGKILL) and restart it on the same flash without its stored lag states (lags.bin: a
    restart that shows the start itself, not a restore), its sensors at ``temps``, its clock going on."""
    import os
    rig.kill()
    lags = os.path.join(rig.flash, rig.config["table_dir"], "lags.bin")
    if os.path.exists(lags):
        os.remove(lags)
    rig.spec["start_ms"] = rig.t_ms
    rig.spec["temps"] = temps
    rig.start()


def judge_restart(answers, hosted, uninterrupted, times, start_s, bound, host):
    """A restarted board's answers against the host's prediction ``hosted`` (the host's board switched on at the restart,
    ``host`` names it in the failure) within ``bound`` um, skipping the start ramp (fallback, rate-limited); never held
    or clamped. Returns (indices compared, worst |board - hosted|, largest |board - uninterrupted|, [(seconds after the
    restart, SETTLING)] per answer)."""
    from firmware.wire import CLAMPED, SETTLING
    from host.board.link import RATE_LIMITED
    compared, worst, dev, settling = [], 0.0, 0.0, []
    for i, (a, p, u, t) in enumerate(zip(answers, hosted, uninterrupted, times)):
        st = int(a["status"], 16)
        assert not a["held"] and not st & CLAMPED, a
        settling.append((t - start_s, bool(st & SETTLING)))
        if a["fallback"] or st & RATE_LIMITED:  # the start ramp after the restart
            continue
        compared.append(i)
        err = abs(a["offset_um"] - p)
        worst = max(worst, err)
        assert err <= bound, "%.0f s after the reset: board %.3f um, host (%s) %.3f um, bound %.3f um" % (
            t - start_s, a["offset_um"], host, p, bound)
        dev = max(dev, abs(a["offset_um"] - u))
    assert len(compared) >= 0.8 * len(answers), (len(compared), len(answers))
    return compared, worst, dev, settling


def rtd_bound_K(run, sensors, horizon_s=0.3):
    """Worst temperature error of the measurement chain per sensor, in K.

    MAX31865 half LSB with R_REF = 430 ohm at the Pt100's smallest slope in
    range (0.379 ohm/K at 80 degC): 0.0173 K; the firmware's integer inverse:
    < 0.002 K; a conversion up to ``horizon_s`` older than the query times
    the run's fastest temperature rate. The ADS122C04's LSB is far smaller.
    """
    t = run.temperatures
    out = {}
    for s in sensors:
        c = t.column(s)
        rate = 0.0
        for i in range(1, len(c)):
            dt = float(t.time_s[i] - t.time_s[i - 1])
            if dt > 0:
                rate = max(rate, abs(float(c[i] - c[i - 1])) / dt)
        out[s] = 0.0173 + 0.002 + rate * horizon_s
    return out


def poly_slope_bound_um(doc, run, sensors, pos_mm):
    """RTD chain bound propagated through a poly_slope model at position ``pos_mm``."""
    coef = doc["thermal"]["coefficients_um_per_mm_per_K"]
    dT = rtd_bound_K(run, sensors)
    return sum(abs(coef[s]) * dT[s] for s in sensors) * abs(pos_mm)


def finite(x):
    return x is not None and math.isfinite(x)
