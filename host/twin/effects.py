"""The catalog of switchable twin effects.

Every effect is off in the base model and has one magnitude parameter when on.
The names are a contract: the discrepancy workflow (host/learning/discrepancy) and the
docs use exactly these keys.  ``EFFECTS[name]`` is an :class:`Effect` with the
default magnitude, its unit, a one-line physical definition and the sign of its
action on the output ("direction"), which tests/twin checks.
"""

from __future__ import annotations

from collections.abc import Iterable, Mapping
from dataclasses import dataclass


# what resolve_effects accepts: None, 'a,b', names, or {name: magnitude or None (the default)}
EffectsSpec = Mapping[str, 'float | None'] | Iterable[str] | str | None


@dataclass(frozen=True)
class Effect:
    name: str
    default: float
    unit: str
    description: str
    direction: str


EFFECTS = {
    e.name: e
    for e in (
        Effect(
            "ambient_expansion",
            1.0,
            "1 (share of the base's free expansion)",
            "screw and base follow the base temperature: error += m*alpha*(T_base - T_base(0))*P",
            "adds an error proportional to P with the sign of the base temperature change",
        ),
        Effect(
            "speed_dependent_heat",
            0.6,
            "1 (viscous share of nut friction at the reference feed)",
            "friction energy per mm of nut travel scales as (1 - m) + m*feed/feed_ref instead of being constant",
            "more screw heat (larger error) above feed_ref, less below, none at feed_ref",
        ),
        Effect(
            "bearing_heat",
            5.0,
            "W at the reference screw speed",
            "heat source in the screw segment at the fixed-end support bearing, m*n/n_ref watts while the screw turns",
            "larger error at every P > fixed end, and a warmer fixed-end bearing sensor",
        ),
        Effect(
            "moving_convection",
            1.0,
            "1 (relative rise of h at the reference feed)",
            "convection coefficient h*(1 + m*(feed/feed_ref)**0.8) while the screw turns, h at rest",
            "warm-up saturates lower and faster; cool-down unchanged",
        ),
        Effect(
            "reversal_error",
            4.0,
            "um (reversal value B)",
            "direction-dependent offset +B/2 approaching in +, -B/2 in -; sweeps become bidirectional (errors.csv 'direction')",
            "direction +1 rows minus direction -1 rows = +m at every target",
        ),
        Effect(
            "sensor_lag",
            300.0,
            "s (first-order time constant)",
            "every temperature sensor reads a first-order lagged version of the true temperature at its location",
            "readings trail the true temperatures: lower while warming, higher while cooling; errors unchanged",
        ),
    )
}


NON_NEGATIVE = ("ambient_expansion", "speed_dependent_heat", "bearing_heat", "sensor_lag")


def resolve_effects(effects: EffectsSpec) -> dict[str, float]:
    """Normalise ``effects`` to {name: magnitude} for the effects that are on.

    Accepts None, a comma-separated string, an iterable of names (default
    magnitudes) or a mapping name -> magnitude (None means default). A magnitude
    of 0 is kept (the effect is on with zero size, equivalent to off).
    """
    if effects is None:
        return {}
    if isinstance(effects, str):
        effects = [e.strip() for e in effects.split(",") if e.strip()]
    if isinstance(effects, dict):
        items = list(effects.items())
    else:
        items = [(name, None) for name in effects]
    out = {}
    for name, mag in items:
        if name not in EFFECTS:
            raise ValueError("unknown effect %r; known effects: %s" % (name, ", ".join(EFFECTS)))
        if mag is None:
            mag = EFFECTS[name].default
        try:
            mag = float(mag)
        except (TypeError, ValueError):
            raise ValueError("effect %r: magnitude must be a number (found %r)" % (name, mag))
        if mag != mag or mag in (float("inf"), float("-inf")):
            raise ValueError("effect %r: magnitude must be finite (found %r)" % (name, mag))
        # Shares, powers and time constants have no negative meaning; reversal_error's sign is the
        # sign of B and moving_convection only needs h > 0 (checked below).
        if name in NON_NEGATIVE and mag < 0:
            raise ValueError("effect %r: magnitude must be >= 0 (found %g; unit %s)" % (name, mag, EFFECTS[name].unit))
        if name == "moving_convection" and mag <= -1:
            raise ValueError("effect 'moving_convection': magnitude must be > -1 so h stays positive (found %g)" % mag)
        out[name] = mag
    return {name: out[name] for name in EFFECTS if name in out}
