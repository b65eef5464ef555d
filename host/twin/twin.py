"""The feed-axis digital twin: protocol + effects + seed -> one simulated run."""

from __future__ import annotations

from numpy.typing import ArrayLike
from typing import TYPE_CHECKING, Any
import dataclasses
import math
import os
import zlib
from dataclasses import dataclass

import numpy as np

from host.data import runs as _runs
from host.twin.ambient import air_C
from host.twin.axis import AxisParams, make_params
from host.twin.effects import resolve_effects
from host.twin.protocols import PROTOCOLS, Protocol, concrete, read_protocol_csv, resolve_protocols, schedule
from host.twin.screw import ScrewGrid, ScrewIntegrator, contact_travel, expansion_um
from host.twin.structure import NODES, lagged, node_temperatures

if TYPE_CHECKING:
    from host.data.runs import Run
    from host.twin.effects import EffectsSpec

DEFAULT_PROTOCOL = "v8000_r210_490"
DEFAULT_NOISE_UM = 0.5
START = _runs.START  # the raw-error convention (docs/data-format.md)
GENERATOR = "host.sim/2"  # 2: own screw core in absolute temperature, drifting air, lagged sensors


@dataclass
class Simulation:
    """Everything the twin computed for one run (true values, before the run-folder rounding)."""

    protocol: Protocol  # with the drawn phases for a drawn protocol ("random")
    params: AxisParams
    effects: dict
    seed: int
    noise_um: float
    t_s: np.ndarray  # (n+1,) step edges = temperature sample times
    air_C: np.ndarray  # (n+1,)
    screw_C: np.ndarray  # (n+1, N+1) screw temperature at the grid nodes (screw_x_mm)
    nodes_true_C: np.ndarray  # (n+1, len(NODES)) temperature of the body each sensor sits on
    sensors_C: np.ndarray  # (n+1, len(NODES)) what the sensors report (own lag, sensor_lag, noise)
    power_W: dict  # per-step sources: nut (total friction), screw (into the screw), motor, bearing
    conv_mult: np.ndarray  # (n,)
    motion: np.ndarray  # (k, 5) the protocol's moving states (motion.csv)
    sweep_s: np.ndarray
    err_time_s: np.ndarray
    err_position_mm: np.ndarray
    err_direction: np.ndarray | None  # int8 or None
    err_thermal_um: np.ndarray  # screw expansion + ambient_expansion, no noise
    err_geometric_um: np.ndarray
    err_um: np.ndarray  # what the interferometer reports (in the convention error_reference)
    screw_x_mm: np.ndarray | None = None  # (N+1,) node coordinates, screw coordinate (fixed end 0)
    readings_true_C: np.ndarray | None = None  # (n+1, len(NODES)) the sensor readings before noise
    sweep_motion: np.ndarray | None = None  # (s, 5) the sweeps' own travel (heats the axis, not in motion.csv)
    air_rise_K: float = 0.0  # the seeded warming of the air
    hvac_period_min: float = 0.0  # the seeded HVAC cycle
    error_reference: str = START  # "start" (raw errors) or the sensor the laser corrected them to


def _protocol(protocol):
    if isinstance(protocol, Protocol):
        return protocol
    if str(protocol).lower().endswith(".csv"):
        return read_protocol_csv(protocol)
    if protocol not in PROTOCOLS:
        raise ValueError("unknown protocol %r; known: %s" % (protocol, ", ".join(PROTOCOLS)))
    return PROTOCOLS[protocol]


def _rngs(seed, name):
    if not isinstance(seed, (int, np.integer)) or isinstance(seed, bool) or seed < 0:
        raise ValueError("seed must be an integer >= 0 (found %r)" % (seed,))
    # one stream per purpose, so e.g. changing the laser noise leaves the ambient unchanged;
    # the protocol name enters so each state of a suite has its own day
    ss = np.random.SeedSequence([int(seed), zlib.crc32(name.encode())])
    return [np.random.default_rng(s) for s in ss.spawn(4)]


def geometric_um(positions_mm: ArrayLike, params: AxisParams) -> np.ndarray:
    u = np.asarray(positions_mm, dtype=float) / params.stroke_mm
    return sum((c * u**k for k, c in enumerate(params.geometric_um)), np.zeros_like(u))


def sweep_travel(sweeps: np.ndarray, params: AxisParams, t_end: float) -> np.ndarray:
    """The sweeps' own motion (s, 5): the nut runs from the first to the last target and back.

    A sweep stops at every target for the laser reading; its heat is that of
    ``sweep_trips`` round trips spread over the sweep window (an equivalent feed
    of 2*trips*span/window).
    """
    busy = params.sweep_duration_min * 60.0
    pos = np.asarray(params.positions_mm, dtype=float)
    span = pos.max() - pos.min()
    if busy <= 0 or span <= 0 or params.sweep_trips <= 0:
        return np.zeros((0, 5))
    feed = 2.0 * params.sweep_trips * span / busy * 60.0
    rows = [(s, min(s + busy, t_end), pos.min(), pos.max(), feed) for s in sweeps if s < t_end]
    return np.asarray(rows, dtype=float).reshape(-1, 5)


def heat_sources(t: np.ndarray, motion: np.ndarray, params: AxisParams, eff: dict[str, float]) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Per-step heat of the axis from its motion rows (k, 5).

    Returns (screw_J (n, N+1) friction energy into each screw volume, speed (n,)
    mean screw speed / reference, nut_W (n,) total nut friction power, conv (n,)).
    """
    dt = np.diff(t)
    n = len(dt)
    grid = ScrewGrid(params)
    screw_J = np.zeros((n, grid.n_nodes))
    if not len(motion):
        return screw_J, np.zeros(n), np.zeros(n), np.ones(n)
    feed = motion[:, 4]
    duty = _step_overlaps(t, motion[:, 0], motion[:, 1]) / dt[:, None]  # share of each step in each interval
    m_v = eff.get("speed_dependent_heat", 0.0)
    e_mm = params.friction_J_per_mm * np.clip((1 - m_v) + m_v * feed / params.feed_ref_mm_min, 0.0, None)
    speed = duty @ (feed / params.feed_ref_mm_min)
    nut_W = duty @ (e_mm * feed / 60.0)
    conv = 1.0 + eff.get("moving_convection", 0.0) * (duty @ (feed / params.feed_ref_mm_min) ** 0.8)
    for (t0, t1, a, b, f), e in zip(motion, e_mm):
        travel = contact_travel(grid.bounds_mm + params.fixed_end_mm, t, t0, t1, a, b, f, params.nut_length_mm)
        screw_J += params.screw_share * e * travel
    return screw_J, speed, nut_W, conv


def simulate(protocol: str | Protocol = DEFAULT_PROTOCOL, effects: EffectsSpec = None, seed: int = 0, noise_um: float = DEFAULT_NOISE_UM,
             error_reference: str = START, **overrides: Any) -> Simulation:
    """Run the twin; returns a :class:`Simulation` (see simulate_run for the arguments)."""
    proto = _protocol(protocol)
    names = [nd.name for nd in NODES]
    if error_reference != START and error_reference not in names:
        raise ValueError("error reference %r: expected %r or a sensor of the twin (%s)" % (error_reference, START, ", ".join(names)))
    params = make_params(**overrides)
    eff = resolve_effects(effects)
    if not (isinstance(noise_um, (int, float)) and math.isfinite(noise_um) and noise_um >= 0):
        raise ValueError("noise_um must be a number >= 0 (found %r)" % (noise_um,))
    rng_air, rng_temp, rng_laser, rng_protocol = _rngs(seed, proto.name)
    proto = concrete(proto, rng_protocol, params.stroke_mm)

    sweeps, motion = schedule(proto, params)
    dt = params.dt_s
    n = int(math.ceil(proto.duration_s(params) / dt - 1e-9))
    t = np.arange(n + 1) * dt
    air = air_C(t, proto.start_hour, params, rng_air)

    # ---- heat sources per step: the protocol's moving states and the sweeps' own travel
    sweep_rows = sweep_travel(sweeps, params, t[-1])
    heat_J, speed, nut_W, conv = heat_sources(t, np.concatenate([motion, sweep_rows]), params, eff)
    grid = ScrewGrid(params)
    screw_W = heat_J / dt
    bearing_extra = eff.get("bearing_heat", 0.0) * speed
    screw_W[:, 0] += bearing_extra  # node 0 is the fixed end (x = 0) with the support bearing
    power = {
        "nut": nut_W,
        "screw": screw_W.sum(axis=1),
        "motor": params.motor_idle_W + params.motor_W_at_ref * speed,
        "bearing": params.bearing_W_at_ref * speed + bearing_extra,
    }

    # ---- temperatures: the twin's own screw core (host/twin/screw.py) in absolute temperature
    T_screw = ScrewIntegrator(grid, dt, params.time_constant_s).run(air.C, screw_W, conv)
    nut_node = dict(power, nut=(1 - params.screw_share) * nut_W)
    nodes = node_temperatures(nut_node, air.C, dt)
    readings = lagged(nodes, [params.sensor_tau_scale * nd.sensor_s for nd in NODES], dt)
    readings = lagged(readings, eff.get("sensor_lag", 0.0), dt)
    noisy = readings
    if params.temp_noise_K > 0:
        noisy = readings + rng_temp.normal(0.0, params.temp_noise_K, readings.shape)

    # ---- positioning errors at the sweeps
    pos = np.asarray(params.positions_mm, dtype=float)
    dirs = (1, -1) if "reversal_error" in eff else (None,)
    rows_t, rows_p, rows_d = [], [], []
    for s in sweeps:
        for d in dirs:
            p = pos if d != -1 else pos[::-1]
            rows_t.append(np.full(p.size, s))
            rows_p.append(p)
            rows_d.append(np.full(p.size, 1 if d is None else d, dtype=np.int8))
    et, ep, ed = np.concatenate(rows_t), np.concatenate(rows_p), np.concatenate(rows_d)
    # the screw grows from its temperature at the cold sweep (t = 0); a sweep is an instant
    T_sweep = np.stack([np.interp(sweeps, t, T_screw[:, i]) for i in range(grid.n_nodes)], axis=1)
    E_sweep = expansion_um(grid.x_mm, T_sweep, T_screw[0], pos - params.fixed_end_mm, params.alpha_um_mK)
    per_row = []
    for i in range(len(sweeps)):
        for d in dirs:
            per_row.append(E_sweep[i] if d != -1 else E_sweep[i][::-1])
    thermal = np.concatenate(per_row)
    if "ambient_expansion" in eff:
        base = nodes[:, [nd.role for nd in NODES].index("base")]
        dbase = np.interp(et, t, base) - base[0]
        thermal = thermal + eff["ambient_expansion"] * params.alpha_um_mK * dbase * ep * 1e-3
    if error_reference != START:
        # The laser's material-temperature compensation: the displacement it measured from its datum (axis 0) is
        # scaled to the material at the reference sensor's temperature, so the screw's expansion over that
        # temperature is what remains (S004 Eq. 9). The laser reads its own probe at that point: the sensor's
        # lagged temperature without the logger's noise. The screw starts uniform at T_screw[0].
        probe = readings[:, [nd.name for nd in NODES].index(error_reference)]
        thermal = thermal - params.alpha_um_mK * (np.interp(et, t, probe) - T_screw[0, 0]) * ep * 1e-3
    geo = geometric_um(ep, params)
    err = thermal + geo
    if "reversal_error" in eff:
        err = err + 0.5 * eff["reversal_error"] * ed
    if noise_um > 0:
        err = err + rng_laser.normal(0.0, noise_um, err.shape)

    return Simulation(
        proto, params, eff, int(seed), float(noise_um), t, air.C, T_screw, nodes, noisy, power, conv, motion,
        sweeps, et, ep, ed if "reversal_error" in eff else None, thermal, geo, err,
        screw_x_mm=grid.x_mm, readings_true_C=readings, sweep_motion=sweep_rows, air_rise_K=air.rise_K,
        hvac_period_min=air.hvac_period_min, error_reference=error_reference,
    )


def _step_overlaps(t_edges, t_start, t_end):
    """Seconds of each interval (columns) inside each step (rows)."""
    a = np.maximum(t_edges[:-1, None], t_start[None, :])
    b = np.minimum(t_edges[1:, None], t_end[None, :])
    return np.clip(b - a, 0.0, None)


def _plain(v):
    if isinstance(v, tuple):
        return [_plain(x) for x in v]
    return v


def to_run(sim: Simulation) -> Run:
    """The tcomp-run/1 :class:`host.data.runs.Run` of a :class:`Simulation`."""
    p = sim.params
    meta = {
        "format": _runs.FORMAT,
        "axis": p.axis,
        "stroke_mm": p.stroke_mm,
        "screw": {
            "length_mm": p.screw_length_mm,
            "diameter_mm": p.screw_diameter_mm,
            "lead_mm": p.lead_mm,
            "fixed_end_mm": p.fixed_end_mm,
        },
        "sensors": {nd.name: {"role": nd.role, "location": nd.location} for nd in NODES},
        "notes": "digital twin (host/twin, docs/twin.md): protocol %s (%s), effects %s, seed %d"
        % (sim.protocol.name, sim.protocol.description, ",".join(sim.effects) or "none", sim.seed),
        "simulation": {
            "generator": GENERATOR,
            "protocol": sim.protocol.name,
            "start_hour": sim.protocol.start_hour,
            "seed": sim.seed,
            "noise_um": sim.noise_um,
            "effects": dict(sim.effects),
            "params": {k: _plain(v) for k, v in dataclasses.asdict(p).items()},
        },
    }
    if sim.error_reference != START:  # absent means "start" (docs/data-format.md): raw runs keep their bytes
        meta["error_reference"] = sim.error_reference
    if sim.protocol.drawn or sim.protocol.source:
        # the drawn moving states (what the seed produced) or the states read from the user's file
        meta["simulation"]["phases"] = [dataclasses.asdict(ph) for ph in sim.protocol.phases]
    temps = _runs.Temperatures(sim.t_s.copy(), [nd.name for nd in NODES], sim.sensors_C.copy())
    errors = _runs.Errors(sim.err_time_s.copy(), sim.err_position_mm.copy(), sim.err_um.copy(),
                          None if sim.err_direction is None else sim.err_direction.copy())
    motion = None
    if len(sim.motion):
        motion = _runs.Motion(*(sim.motion[:, j].copy() for j in range(5)))
    return _runs.Run(meta, temps, errors, motion, None, path=None, name=sim.protocol.name)


def simulate_run(protocol: str | Protocol = DEFAULT_PROTOCOL, effects: EffectsSpec = None, seed: int = 0, noise_um: float = DEFAULT_NOISE_UM,
                 error_reference: str = START, **overrides: Any) -> Run:
    """Simulate one thermal test of the feed axis and return it as a :class:`host.data.runs.Run`.

    protocol: a name from PROTOCOLS (or a Protocol); effects: None, a list of
    names from EFFECTS (default magnitudes) or {name: magnitude}; seed: integer
    >= 0, same seed -> same run; noise_um: laser measurement noise (standard
    deviation, um); error_reference: "start" (raw errors, relative to the
    machine at the run's start) or a sensor name (errors corrected to that
    sensor's temperature, as a laser's material-temperature compensation does);
    overrides: any AxisParams field (e.g. h_W_m2K=20, segments=40, temp_noise_K=0).
    """
    return to_run(simulate(protocol, effects, seed, noise_um, error_reference, **overrides))


def write_runs(out: str, protocols: str | Protocol = DEFAULT_PROTOCOL, effects: EffectsSpec = None, seed: int = 0,
               noise_um: float = DEFAULT_NOISE_UM, error_reference: str = START, **overrides: Any) -> list[tuple[str, str]]:
    """Simulate and write run folders; returns [(protocol name, folder)].

    One protocol writes the run into ``out`` itself; several ('all',
    'literature', a comma list) write ``out/<protocol>/`` each.
    """
    protos = resolve_protocols(protocols)
    written = []
    for proto in protos:
        folder = out if len(protos) == 1 else os.path.join(out, proto.name)
        run = simulate_run(proto, effects, seed, noise_um, error_reference, **overrides)
        _runs.write_run(run, folder)
        written.append((proto.name, folder))
    return written
