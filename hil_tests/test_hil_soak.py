"""Scenario 6: soak. Hours of simulated time with the twin run's temperatures (repeated to fill
the duration) and random faults injected and cleared: heap use flat (gc.mem_free after a
collection, sampled every simulated hour on MicroPython), frame sequence numbers contiguous,
no frame lost (one offset frame per frame_ms) and none malformed.

CI runs 1.5 simulated hours per interpreter; TCOMP_SLOW=1 runs the full 24 h.
"""
import os
import random

import pytest

from hil_tests.rig.boards import export, poly_slope_for_run, rig_config

pytestmark = [pytest.mark.rig, pytest.mark.slow]
HOURS = 24 if os.environ.get("TCOMP_SLOW") else 1.5
SAMPLE_MS = 300000  # heap sample every 5 simulated minutes
SENSORS = ["T1", "T2", "T4"]

TRANSIENT = [
    ("open", lambda r: r.sensor("T1", "open"), lambda r: r.sensor("T1", "ok")),
    ("short", lambda r: r.sensor("T2", "short"), lambda r: r.sensor("T2", "ok")),
    ("stuck", lambda r: r.sensor("T1", "stuck"), lambda r: r.sensor("T1", "ok")),
    ("spi_eio_burst", lambda r: r.bus_fault("spi0", "eio", 5, None), lambda r: None),
    ("i2c_timeout", lambda r: r.bus_fault("i2c1", "etimedout", 2, 0x40), lambda r: None),
    ("corrupt", lambda r: r.bus_fault("spi0", "corrupt", 4, None), lambda r: None),
    ("miso_ff", lambda r: r.bus_fault("spi0", "misoff", -1, None), lambda r: r.bus_fault("spi0", "none")),
    ("ads_gone", lambda r: r.chip("T4", present=False), lambda r: r.chip("T4", present=True)),
    ("max_gone", lambda r: r.chip("T2", present=False), lambda r: r.chip("T2", present=True)),
]


def test_soak_heap_flat_frames_contiguous(make_rig, demo_run, interpreter):
    run = demo_run
    doc = poly_slope_for_run(run, SENSORS, seed=9)
    table = export(doc).table
    t = run.temperatures
    cols = [t.column(s) for s in SENSORS]
    period_s = float(t.time_s[-1]) + float(t.time_s[1] - t.time_s[0])
    rig = make_rig(rig_config(SENSORS, stuck_ms=600000), table, noise_uohm=20000,
                   temps={s: float(c[0]) for s, c in zip(SENSORS, cols)})
    rig.send("P", 350000)
    rng = random.Random(2024)
    end_ms = int(HOURS * 3600 * 1000)
    faults = []
    t_fault = rng.randrange(60, 120) * 1000
    warm_end = end_ms
    clear_at = None
    clear_fn = None
    hour = 0
    k = 0
    while rig.t_ms < end_ms:
        i = k % len(t.time_s)
        cycle = k // len(t.time_s)
        target = int((cycle * period_s + float(t.time_s[i])) * 1000) + 10000
        k += 1
        if target <= rig.t_ms:
            continue
        sample = rig.t_ms // SAMPLE_MS > hour
        if clear_at is not None and clear_at <= target:
            rig.run(clear_at)
            clear_fn(rig)
            clear_at = None
        elif clear_at is None and t_fault <= target:
            rig.run(t_fault)
            # every kind once first (its code paths, interned names and bounded diagnostics then
            # exist), afterwards at random
            warm = len(faults) < len(TRANSIENT)
            name, inject, clear_fn = TRANSIENT[len(faults) if warm else rng.randrange(len(TRANSIENT))]
            inject(rig)
            faults.append(name)
            clear_at = t_fault + rng.randrange(1, 60 if warm else 180) * 1000
            t_fault = clear_at + rng.randrange(30, 90 if warm else 900) * 1000
            if len(faults) == len(TRANSIENT):
                warm_end = clear_at + 60000
        rig.run(target, temps={s: float(c[i]) for s, c in zip(SENSORS, cols)}, gc=sample, sync=False)
        if sample:
            hour = rig.t_ms // SAMPLE_MS
    rig.run(rig.t_ms + 100)
    frames = rig.take_frames()
    assert not rig.reader.decoder.bad, rig.reader.decoder.bad[:3]
    seqs = [f.seq for f in frames]
    gaps = [(a, b) for a, b in zip(seqs, seqs[1:]) if b != (a + 1) & 0xFFFF]
    assert not gaps, gaps[:5]
    o = [f for f in frames if f.kind == "O"]
    dts = [b.t_ms - a.t_ms for a, b in zip(o, o[1:])]
    assert min(dts) >= 900 and max(dts) <= 1100, (min(dts), max(dts))
    assert len(o) >= end_ms // 1000 - 20
    assert len(faults) >= 2 * HOURS
    st = rig.stats()
    violations = {n: c["violation_text"] for n, c in st["chips"].items() if c["violations"]}
    assert not violations, violations  # datasheet rules kept even with corrupted bus data
    final = o[-1]
    assert final.status & 0xFFFF == 0 or clear_at is not None
    if interpreter == "micropython":
        mem = [m for _, m in rig.mem]
        assert len(mem) >= int(HOURS * 3600000) // SAMPLE_MS - 2
        # after the warm-up (every fault kind seen once) free heap has no downward trend: the lowest
        # sample of the last quarter is not below the lowest of the first
        steady = [m for t, m in rig.mem if t >= warm_end]
        assert len(steady) >= 4, (warm_end, rig.mem)
        q = max(1, len(steady) // 4)
        assert min(steady[-q:]) >= min(steady[:q]) - 256, "heap shrinking: %s" % mem
        assert max(steady) - min(steady) <= 2048, "heap wandering: %s" % mem
    print("soak %s: %.1f h simulated, %d frames, %d faults injected (%s), mem_free samples %s" % (
        interpreter, HOURS, len(frames), len(faults), ",".join(sorted(set(faults))), [m for _, m in rig.mem]))
