"""Physical parameters of the simulated feed axis (one frozen dataclass).

Defaults describe a mid-size machining-centre X axis: 700 mm stroke, a steel
ball screw 800 mm x 32 mm with 10 mm lead fixed at axis position 0. Values and
their sources are listed in docs/twin.md. Any field can be overridden by
keyword through ``simulate_run(**overrides)``.
"""

from __future__ import annotations

from typing import Any
import dataclasses
import math
from dataclasses import dataclass

MAX_MAGNITUDE = 1e9  # any number of the axis: far beyond a machine, far inside float range once squared
MIN_POSITIVE = 1e-9  # a positive quantity the physics divides by
MAX_SEGMENTS = 1000  # the twin's grid: the step maps are (segments + 1)^2 and built per convection level


@dataclass(frozen=True)
class AxisParams:
    axis: str = "X"
    stroke_mm: float = 700.0
    # ball screw: occupies screw coordinate x = P - fixed_end_mm in [0, length]
    screw_length_mm: float = 800.0
    screw_diameter_mm: float = 32.0
    lead_mm: float = 10.0
    fixed_end_mm: float = 0.0
    segments: int = 80  # grid intervals of the twin's screw (nodes at both ends: segments + 1)
    density_kg_m3: float = 7850.0
    heat_capacity_J_kgK: float = 460.0
    conductivity_W_mK: float = 45.0
    h_W_m2K: float = 15.0
    alpha_um_mK: float = 11.5
    # nut friction: energy per mm of nut travel (torque * 2*pi / lead), share into the screw
    friction_J_per_mm: float = 0.12
    screw_share: float = 0.35
    nut_length_mm: float = 90.0  # the nut's friction heat is spread evenly over this length
    feed_ref_mm_min: float = 8000.0
    # other heat sources feeding the structure nodes (W)
    motor_idle_W: float = 3.0
    motor_W_at_ref: float = 18.0
    bearing_W_at_ref: float = 3.0
    # cold geometric error: sum_k c_k * (P / stroke)^k, um
    geometric_um: tuple = (0.0, 6.0, -9.0, 4.0)
    # time base and measurement
    dt_s: float = 10.0
    sweep_every_min: float = 15.0
    sweep_duration_min: float = 2.0
    positions_mm: tuple = tuple(float(p) for p in range(0, 701, 50))
    sweep_trips: float = 1.0  # round trips over the targets per sweep (their heat); 0 = the sweeps heat nothing
    temp_noise_K: float = 0.01
    sensor_tau_scale: float = 1.0  # multiplies every sensor's own time constant (structure.NODES); 0 = ideal sensors
    # ambient air: seeded warming drift, HVAC ripple, slow wander (optional daily cosine)
    ambient_mean_C: float = 20.0
    ambient_day_amplitude_K: float = 0.0
    ambient_peak_hour: float = 15.0
    ambient_wander_K: float = 0.05
    ambient_rise_min_K: float = 1.6
    ambient_rise_max_K: float = 2.8
    ambient_rise_hours: float = 8.0
    ambient_hold_hours: float = 2.0
    ambient_fall_hours: float = 8.0
    hvac_ripple_K: float = 0.15
    hvac_period_min_min: float = 20.0
    hvac_period_max_min: float = 45.0

    # ---------------------------------------------------------- derived

    @property
    def section_m2(self) -> float:
        return math.pi * (self.screw_diameter_mm * 1e-3) ** 2 / 4

    @property
    def perimeter_m(self) -> float:
        return math.pi * self.screw_diameter_mm * 1e-3

    @property
    def time_constant_s(self) -> float:
        """Convective time constant of a uniformly warm screw at rest, rho*c*d/(4*h)."""
        return self.density_kg_m3 * self.heat_capacity_J_kgK * self.screw_diameter_mm * 1e-3 / (4 * self.h_W_m2K)

    def fin_parameter_per_m(self) -> float:
        """m = sqrt(h*perimeter/(lambda*A)) of the 1-D fin equation."""
        return math.sqrt(self.h_W_m2K * self.perimeter_m / (self.conductivity_W_mK * self.section_m2))

    def checked(self) -> AxisParams:
        problems = []
        positive = (
            "stroke_mm", "screw_length_mm", "screw_diameter_mm", "lead_mm", "density_kg_m3",
            "heat_capacity_J_kgK", "conductivity_W_mK", "h_W_m2K", "alpha_um_mK", "feed_ref_mm_min",
            "dt_s", "sweep_every_min", "ambient_rise_hours", "hvac_period_min_min", "hvac_period_max_min",
        )
        for k in positive:
            v = getattr(self, k)
            if not isinstance(v, (int, float)) or isinstance(v, bool) or not math.isfinite(v) or v <= 0:
                problems.append("%s must be a positive number (found %r)" % (k, v))
            elif v < MIN_POSITIVE:
                problems.append("%s must be at least %g (found %r): the twin divides by it" % (k, MIN_POSITIVE, v))
        for f in dataclasses.fields(self):
            values = getattr(self, f.name)
            for v in values if isinstance(values, tuple) else (values,):
                if isinstance(v, (int, float)) and not isinstance(v, bool) and math.isfinite(v) and abs(v) > MAX_MAGNITUDE:
                    # squared or multiplied together, such a value overflows the float arithmetic of the physics
                    problems.append("%s must be within +-%g (found %r)" % (f.name, MAX_MAGNITUDE, v))
                    break
        for k in ("friction_J_per_mm", "motor_idle_W", "motor_W_at_ref", "bearing_W_at_ref", "sweep_duration_min",
                  "temp_noise_K", "ambient_wander_K", "nut_length_mm", "ambient_rise_min_K", "ambient_rise_max_K",
                  "ambient_hold_hours", "ambient_fall_hours", "hvac_ripple_K", "sweep_trips", "sensor_tau_scale"):
            v = getattr(self, k)
            if not isinstance(v, (int, float)) or isinstance(v, bool) or not math.isfinite(v) or v < 0:
                problems.append("%s must be a number >= 0 (found %r)" % (k, v))
        if not isinstance(self.segments, int) or isinstance(self.segments, bool) or not 2 <= self.segments <= MAX_SEGMENTS:
            problems.append("segments must be an integer in 2..%d (found %r)" % (MAX_SEGMENTS, self.segments))
        if not 0 <= self.screw_share <= 1:
            problems.append("screw_share must be within 0..1 (found %r)" % (self.screw_share,))
        if not problems:
            if self.ambient_rise_min_K > self.ambient_rise_max_K:
                problems.append("ambient_rise_min_K (%g) must not exceed ambient_rise_max_K (%g)"
                                % (self.ambient_rise_min_K, self.ambient_rise_max_K))
            if self.hvac_period_min_min > self.hvac_period_max_min:
                problems.append("hvac_period_min_min (%g) must not exceed hvac_period_max_min (%g)"
                                % (self.hvac_period_min_min, self.hvac_period_max_min))
            if self.fixed_end_mm > 0 or self.fixed_end_mm + self.screw_length_mm < self.stroke_mm:
                problems.append(
                    "the screw (axis positions %g..%g mm from fixed_end_mm=%g, screw_length_mm=%g) must cover the stroke 0..%g mm"
                    % (self.fixed_end_mm, self.fixed_end_mm + self.screw_length_mm, self.fixed_end_mm,
                       self.screw_length_mm, self.stroke_mm))
            if self.sweep_duration_min >= self.sweep_every_min:
                problems.append("sweep_duration_min (%g) must be shorter than sweep_every_min (%g)"
                                % (self.sweep_duration_min, self.sweep_every_min))
            bad = [p for p in self.positions_mm if not 0 <= p <= self.stroke_mm]
            if not self.positions_mm:
                problems.append("positions_mm must list at least one target position")
            elif bad:
                problems.append("positions_mm %s lie outside the stroke 0..%g mm" % (bad, self.stroke_mm))
        if problems:
            raise ValueError("; ".join(problems))
        return self


FIELDS = tuple(f.name for f in dataclasses.fields(AxisParams))


def make_params(**overrides: Any) -> AxisParams:
    """AxisParams with ``overrides`` applied; unknown names raise ValueError listing the valid ones."""
    unknown = sorted(k for k in overrides if k not in FIELDS)
    if unknown:
        raise ValueError("unknown parameter(s) %s; valid: %s" % (", ".join(unknown), ", ".join(FIELDS)))
    if "positions_mm" in overrides:
        overrides["positions_mm"] = tuple(float(p) for p in overrides["positions_mm"])
    if "geometric_um" in overrides:
        overrides["geometric_um"] = tuple(float(c) for c in overrides["geometric_um"])
    return AxisParams(**overrides).checked()
