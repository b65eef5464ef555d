"""Board configs and tables for the rig: the firmware's own config format (firmware/board.py)."""
import random

MAX_CS0 = 5


def rig_config(sensors, n_ads=1, mode="stream", **extra):
    """MAX31865s on spi0 (CS 5, 6, ...) for all but the last ``n_ads`` sensors, which sit on ADS122C04s on i2c1."""
    chans = []
    n_max = len(sensors) - n_ads
    for i, s in enumerate(sensors):
        if i < n_max:
            chans.append({"name": s, "driver": "max31865", "bus": "spi0", "cs": MAX_CS0 + i,
                          "rref_mohm": 430000, "wires": 3, "filter_hz": 50})
        else:
            chans.append({"name": s, "driver": "ads122c04", "bus": "i2c1", "address": 0x40 + i - n_max,
                          "rref_mohm": 1620000, "wires": 3, "idac_ua": 500})
    cfg = {"channels": chans, "serial": {"mode": mode, "baud": 115200, "address": 1},
           "table_dir": "tables", "watchdog_ms": 2000, "cycle_ms": 100, "frame_ms": 1000}
    cfg.update(extra)
    return cfg


def _finish(doc):
    from models_export.document import document_hash
    doc = dict(doc)
    doc.pop("provenance", None)
    doc["provenance"] = {"tcomp_version": "hil", "created_utc": "2026-01-01T00:00:00Z",
                         "sha256": document_hash(doc)}
    return doc


def _rename(doc, names):
    old = doc["sensors"]
    m = dict(zip(old, names))
    doc["sensors"] = list(names)
    doc["reference_C"] = {m[k]: v for k, v in doc["reference_C"].items()}
    env = doc["envelope"]["temperature_C"]
    doc["envelope"]["temperature_C"] = {m[k]: v for k, v in env.items()}
    th = doc["thermal"]
    for key in ("coefficients_um_per_mm_per_K", "coefficients_um_per_K"):
        if key in th:
            th[key] = {m[k]: v for k, v in th[key].items()}
    red = th.get("reduced")
    if red and red.get("base_sensor"):
        red["base_sensor"] = m[red["base_sensor"]]
    if red and red.get("air_sensor"):
        red["air_sensor"] = m[red["air_sensor"]]
    return doc


def poly_slope_for_run(run, sensors, seed=3, degree=2):
    """A poly_slope model document over ``sensors`` of ``run`` whose envelope covers the run."""
    from hil_tests.fixtures.samples import poly_slope_doc
    stroke = float(run.stroke_mm or 700.0)
    doc = _rename(poly_slope_doc(random.Random(seed), n_sensors=len(sensors), stroke_mm=stroke, degree=degree),
                  sensors)
    temps = run.temperatures
    for s in sensors:
        col = temps.column(s)
        doc["envelope"]["temperature_C"][s] = [float(col.min()) - 10.0, float(col.max()) + 10.0]
        doc["reference_C"][s] = round(float(col[0]), 3)
    doc["envelope"]["position_mm"] = [0.0, stroke]
    return _finish(doc)


def screw_doc(sensors=("T1", "T2"), seed=5):
    """A screw model document (reduced recurrence) with base sensor ``sensors[0]`` and air sensor
    ``sensors[1]`` (none when only one name is given)."""
    from hil_tests.fixtures.samples import screw_doc as sample
    doc = sample(random.Random(seed), segments=8, dt_s=1.0, length_mm=800.0, feed_max_mm_min=12000.0, base=True,
                 air=len(sensors) > 1)
    doc = _rename(doc, list(sensors)[:len(doc["sensors"])])
    return _finish(doc)


def export(doc):
    from models_export.export import export_model
    return export_model(doc)
