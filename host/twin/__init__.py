"""Feed-axis digital twin: simulated thermal tests written as tcomp-run/1 folders.

Stable API (other packages and the HIL rig rely on it)::

    from host.twin import simulate_run, write_runs, PROTOCOLS, EFFECTS
    run = simulate_run(protocol="v8000_r210_490",          # a key of PROTOCOLS
                       effects={"bearing_heat": 5.0},      # or ["bearing_heat", ...] (default magnitudes) or None
                       seed=0,                             # same seed -> identical run
                       noise_um=0.5,                       # laser noise, standard deviation in um
                       h_W_m2K=15.0)                       # any AxisParams field as an override
    host.data.runs.write_run(run, "out/run")                    # or write_runs(DIR, "all", ...)

- ``simulate_run(...) -> host.data.runs.Run`` (meta.json carries the protocol, seed,
  effects and every parameter under ``meta["simulation"]``).
- ``simulate(...) -> Simulation``: the same run with the true values (screw
  segment temperatures, true node temperatures, heat sources, noise-free error).
- ``write_runs(out, protocols, effects, seed, noise_um, **overrides)``: one
  protocol writes into ``out``; several ("all", "literature", "a,b") write
  ``out/<protocol>/``.
- ``PROTOCOLS``: name -> Protocol (phases, start hour); ``LITERATURE_STATES``.
- ``EFFECTS``: name -> Effect(default magnitude, unit, description, direction);
  names ambient_expansion, speed_dependent_heat, bearing_heat, moving_convection,
  reversal_error, sensor_lag. ``resolve_effects`` normalises a user selection.
- ``AxisParams`` / ``make_params(**overrides)``: the physical parameters.
- ``NODES``: the 13 structure temperature points (sensor name, role, location, sensor lag).
- ``STILL_AIR``: overrides that hold the shop air constant (``simulate(..., **STILL_AIR)``).

The screw physics is the twin's own (host/twin/screw.py: finite volumes, Crank-Nicolson,
absolute temperature); it shares no code with the identified model (host/learning/screw), so a
test on twin data can find what the model misses. Equations, parameters, protocols and
effects: docs/twin.md.
"""
from host.twin.ambient import STILL_AIR
from host.twin.axis import AxisParams, make_params
from host.twin.effects import EFFECTS, Effect, resolve_effects
from host.twin.protocols import LITERATURE_STATES, PROTOCOLS, Phase, Protocol
from host.twin.structure import NODES
from host.twin.twin import DEFAULT_NOISE_UM, DEFAULT_PROTOCOL, Simulation, simulate, simulate_run, write_runs

__all__ = [
    "AxisParams", "make_params", "EFFECTS", "Effect", "resolve_effects", "LITERATURE_STATES", "PROTOCOLS",
    "Phase", "Protocol", "NODES", "DEFAULT_NOISE_UM", "DEFAULT_PROTOCOL", "Simulation", "simulate",
    "simulate_run", "write_runs", "STILL_AIR",
]
