"""Writes the example exports of this folder (synthetic values from the formulas below, not measurements).

Run from the repository root: ``python examples/import/make_examples.py``. The files it writes are committed;
the script says how their numbers were made. An X axis (stroke 700 mm, steel screw, 11.5e-6/K) warms
for two hours; the nut follows a first-order rise, the laser sees the screw's expansion from position 0,
plus a reversal offset and a little noise (fixed seed)."""
import math
import os
import random
from datetime import datetime, timedelta, timezone

HERE = os.path.dirname(os.path.abspath(__file__))
CET = timezone(timedelta(hours=1))
START = datetime(2026, 11, 26, 8, 0, 0, tzinfo=CET)
ALPHA = 11.5e-6  # 1/K, steel


def nut_c(t_s):
    return 20.0 + 9.0 * (1 - math.exp(-t_s / 2400.0))


def bearing_c(t_s):
    return 20.0 + 4.0 * (1 - math.exp(-t_s / 3600.0))


def air_c(t_s):
    return 20.0 + 0.3 * math.sin(2 * math.pi * t_s / 1800.0)


def f(degc):
    return degc * 9 / 5 + 32


def logger_iso():
    """ISO 8601 date-times with their offset, temperatures in degF, one empty cell (the mapping drops that row)."""
    lines = ["timestamp,nut_degF,bearing_degF,air_degF,spindle_rpm,note"]
    for k in range(121):
        t = 60.0 * k
        air = "" if k == 37 else "%.2f" % f(air_c(t))
        note = "start" if k == 0 else ("sensor cable touched" if k == 37 else "")
        lines.append("%s,%.2f,%.2f,%s,%d,%s" % ((START + timedelta(seconds=t)).isoformat(), f(nut_c(t)), f(bearing_c(t)), air,
                                               3000 if t < 6000 else 0, note))
    return lines


def laser_sweeps():
    """One row per point: six bidirectional runs 0..700 mm every 100 mm, 4 s per point, errors in um (raw: NTE off),
    after a preamble of settings (the mapping's header_line skips it)."""
    rnd = random.Random(22)
    lines = ["Linear positioning test export (ISO 230-2 style)", "Machine,Example mill,X axis", "Operator,-",
             "Material expansion coefficient (ppm/°C),0.000", "Material temperature compensation,off", ""]
    lines += ["Run,Point,Target (mm),Direction,Date/Time,Error (µm),Air temp (°C),Material temp (°C),Pressure (mbar),Humidity (%)"]
    for run in range(1, 7):
        t = 120.0 + (run - 1) * 1200.0
        point = 0
        for direction, targets in (("Forward", range(0, 701, 100)), ("Reverse", range(700, -1, -100))):
            for x in targets:
                point += 1
                err = ALPHA * (nut_c(t) - nut_c(0)) * x * 1000.0 + (-2.5 if direction == "Reverse" else 0.0) + rnd.gauss(0, 0.2)
                lines.append("%d,%d,%.3f,%s,%s,%.2f,%.2f,%.2f,%.1f,%.0f" % (
                    run, point, x, direction, (START + timedelta(seconds=t)).isoformat(), err, air_c(t), bearing_c(t), 1013.2, 45))
                t += 4.0
    return lines


def logger_semicolon():
    """A European logger: ';' between cells, decimal commas, local date-times (Europe/Berlin), a probe in mm,
    one empty cell (the mapping interpolates it)."""
    lines = ["Datum Zeit;T1 Mutter °C;T2 Festlager °C;T3 Luft °C;Sonde Z mm;Status"]
    for k in range(121):
        t = 30.0 * k
        t2 = "" if k == 50 else ("%.2f" % bearing_c(t)).replace(".", ",")
        probe = 0.001 * (4.0 * (nut_c(t) - nut_c(0)) + 1.5 * (bearing_c(t) - bearing_c(0)))  # mm of axial growth at 350 mm
        lines.append(";".join([(START + timedelta(seconds=t)).strftime("%d.%m.%Y %H:%M:%S"),
                               ("%.2f" % nut_c(t)).replace(".", ","), t2, ("%.2f" % air_c(t)).replace(".", ","),
                               ("%.4f" % probe).replace(".", ","), "OK"]))
    return lines


if __name__ == "__main__":
    for name, lines in (("logger_iso.csv", logger_iso()), ("laser_sweeps.csv", laser_sweeps()),
                        ("logger_semicolon.csv", logger_semicolon())):
        with open(os.path.join(HERE, name), "w", encoding="utf-8", newline="") as fh:
            fh.write("\r\n".join(lines) + "\r\n")  # CRLF, as Windows software writes
