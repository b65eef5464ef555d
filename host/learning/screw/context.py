"""Per-run precomputation for the screw model: the time grid, nut travel per segment
and step, the error rows and their interpolation weights, sensor rises.

Built once per run and reused for every parameter set the identification tries,
so a model evaluation is one simulation plus a few array products.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np

from host.learning.screw import heat

if TYPE_CHECKING:
    from host.data.runs import Motion, Run

# Largest time-steps x segments grid of one run (a float array of it is 160 MB; several are held at once).
MAX_GRID_CELLS = 20_000_000


def run_motion(run: Run) -> Motion:
    """``run.motion``; ValueError naming the run when it has none or an empty one."""
    if run.motion is None or len(run.motion) == 0:
        raise ValueError("%s: the run has no motion (motion.csv missing or empty); the screw model is driven by the nut's "
                         "travel" % (run.path or run.name))
    return run.motion


def check_screw_run(run: Run, geometry: heat.ScrewGeometry | None = None, require_nut: bool = True) -> heat.ScrewGeometry:
    """ValueError naming what makes ``run`` unusable for the screw model.

    require_nut: identification needs a sensor with role 'nut' (diagnostic and
    optional residual); prediction does not read it."""
    name = run.path or run.name
    motion = run_motion(run)
    if not np.any(np.abs(motion.to_mm - motion.from_mm) > heat.MIN_RANGE_MM):
        raise ValueError("%s: motion.csv has no travel (every interval has from_mm == to_mm)" % name)
    if require_nut and not run.sensors_with_role("nut"):
        raise ValueError("%s: meta.json has no sensor with role 'nut' (sensors: %s); the screw model needs the nut temperature"
                         % (name, ", ".join("%s=%s" % (k, v.get("role")) for k, v in run.sensors.items())))
    if require_nut and not any(n in run.temperatures.names for n in run.sensors_with_role("nut")):
        raise ValueError("%s: the nut sensor(s) %s declared in meta.json have no column in temperatures.csv"
                         % (name, ", ".join(run.sensors_with_role("nut"))))
    if geometry is None:
        try:
            geometry = heat.ScrewGeometry.from_meta(run.meta)
        except (KeyError, TypeError, ValueError) as exc:
            raise ValueError("%s: meta.json 'screw' block is unusable: %s" % (name, exc))
    lo_x = geometry.fixed_end_mm
    hi_x = geometry.fixed_end_mm + geometry.length_mm
    used = np.concatenate([motion.from_mm, motion.to_mm, run.errors.position_mm])
    stroke = run.stroke_mm
    top = max(float(used.max()), float(stroke) if stroke else -np.inf)
    if top > hi_x + 1e-9 or float(used.min()) < lo_x - 1e-9:
        raise ValueError("%s: the screw (fixed end at %g mm, length %g mm, so it covers %g..%g mm) is shorter than the stroke "
                         "(positions used %g..%g mm%s)" % (name, lo_x, geometry.length_mm, lo_x, hi_x, float(used.min()), top,
                                                          ", stroke_mm %g" % stroke if stroke else ""))
    return geometry


class RunContext:
    """Everything about one run the model needs, on the model's grid.

    Attributes: run_name, edges_mm, M, t_grid (n_steps+1), n_steps, dt,
    travel_mm (n_steps, M), step_speed_m_min (n_steps,), rows (indices into
    run.errors), n_rows, positions_mm, direction (or None), measured_um,
    overlap_mm (n_rows, M), base_sensor, ambient_sensor, nut_sensor."""

    def __init__(self, run: Run, geometry: heat.ScrewGeometry, dt_s: float, rows: np.ndarray | None = None, edges_mm: np.ndarray | None = None, t_end: float | None = None) -> None:
        self.run = run
        self.run_name = run.path or run.name
        self.geometry = geometry
        self.edges_mm = geometry.edges_mm if edges_mm is None else np.asarray(edges_mm, dtype=float)
        self.M = self.edges_mm.size - 1
        e = run.errors
        self.rows = np.arange(len(e)) if rows is None else np.asarray(rows)
        self.n_rows = self.rows.size
        starts = [run.temperatures.time_s[0], e.time_s[0]]
        if run.motion is not None and len(run.motion):
            starts.append(run.motion.t_start_s[0])
        t0 = float(min(starts))
        t1 = float(max(run.temperatures.time_s[-1], e.time_s[-1])) if t_end is None else float(t_end)
        if not (np.isfinite(dt_s) and dt_s > 0):
            raise ValueError("dt_s must be a positive number of seconds (found %r)" % (dt_s,))
        n = max(1, int(np.ceil((t1 - t0) / dt_s - 1e-9)))
        if n * self.M > MAX_GRID_CELLS:
            # Several float arrays of this size are held per run: past the limit a typo costs gigabytes.
            raise ValueError("%s: %d time steps (dt_s %g s over %g s) x %d segments = %d grid cells, more than %d; "
                             "raise dt_s or lower segments" % (self.run_name, n, dt_s, t1 - t0, self.M, n * self.M,
                                                                MAX_GRID_CELLS))
        self.t_grid = t0 + dt_s * np.arange(n + 1)
        self.n_steps = n
        self.dt = np.diff(self.t_grid)
        self.travel_mm = heat.nut_travel_per_segment(run.motion, self.edges_mm, geometry.fixed_end_mm, self.t_grid)
        self.step_speed_m_min = self.travel_mm.sum(axis=1) / self.dt * 60.0 / 1000.0
        t = e.time_s[self.rows]
        k = np.clip(np.searchsorted(self.t_grid, t, side="right") - 1, 0, n - 1)
        self.row_k = k
        self.row_w = np.clip((t - self.t_grid[k]) / self.dt[k], 0.0, 1.0)
        self.row_time_s = t
        self.positions_mm = e.position_mm[self.rows]
        self.direction = None if e.direction is None else e.direction[self.rows].astype(float)
        self.measured_um = e.error_um[self.rows]
        self.overlap_mm = heat.overlap_mm(self.edges_mm, self.positions_mm - geometry.fixed_end_mm)
        roles = {r: run.sensors_with_role(r) for r in ("base", "ambient", "nut")}
        names = run.temperatures.names
        self.base_sensor = next((s for s in roles["base"] if s in names), None)
        self.ambient_sensor = next((s for s in roles["ambient"] if s in names), None)
        self.nut_sensor = next((s for s in roles["nut"] if s in names), None)

    def sensor_at_rows(self, name: str) -> np.ndarray:
        tt = self.run.temperatures
        late = self.row_time_s[(self.row_time_s < tt.time_s[0]) | (self.row_time_s > tt.time_s[-1])]
        if late.size:
            # np.interp would hold the end value: a term driven by a temperature nobody measured
            raise ValueError("%s: errors.csv time %g s is outside the temperature log %g..%g s (sensor %s; no extrapolation)"
                             % (self.run_name, late[0], tt.time_s[0], tt.time_s[-1], name))
        return np.interp(self.row_time_s, tt.time_s, tt.column(name))

    def sensor_rise_at_rows(self, name: str) -> np.ndarray:
        """Sensor temperature at the error rows minus its first reading."""
        return self.sensor_at_rows(name) - self.run.temperatures.column(name)[0]

    def at_rows(self, grid_values: np.ndarray) -> np.ndarray:
        """(n_steps+1, M) values on the grid -> (n_rows, M) linearly interpolated at the rows' times."""
        w = self.row_w[:, None]
        return grid_values[self.row_k] * (1.0 - w) + grid_values[self.row_k + 1] * w

    def nut_rise_measured(self) -> np.ndarray:
        """Nut sensor rise over the air (ambient, else base sensor) relative to the start, on the grid."""
        tt = self.run.temperatures
        # callers ask only for runs with a nut sensor (check_screw_run(require_nut=...), screwmodel's nut_sensor test)
        assert self.nut_sensor is not None
        nut = np.interp(self.t_grid, tt.time_s, tt.column(self.nut_sensor))
        ref_name = self.ambient_sensor or self.base_sensor
        rise = nut - nut[0]
        if ref_name is not None:
            ref = np.interp(self.t_grid, tt.time_s, tt.column(ref_name))
            rise = rise - (ref - ref[0])
        return rise

    def nut_rise_predicted(self, rises: np.ndarray) -> np.ndarray:
        """Screw temperature under the nut: travel-weighted mean over the segments the nut
        covered in the last moving step (held while idle)."""
        tot = self.travel_mm.sum(axis=1)
        moving = tot > 0
        idx = np.where(moving, np.arange(self.n_steps), -1)
        idx = np.maximum.accumulate(idx)
        w = np.zeros((self.n_steps, self.M))
        ok = idx >= 0
        w[ok] = self.travel_mm[idx[ok]] / tot[idx[ok]][:, None]
        out = np.zeros(self.n_steps + 1)
        out[1:] = np.sum(rises[1:] * w, axis=1)
        return out
