"""Pt100 resistance of a temperature (IEC 60751 Callendar-Van Dusen), float, both interpreters."""

A = 3.9083e-3
B = -5.775e-7
C = -4.183e-12
R0_OHM = 100.0


def resistance_ohm(t_c, r0=R0_OHM):
    r = 1.0 + A * t_c + B * t_c * t_c
    if t_c < 0.0:
        r += C * (t_c - 100.0) * t_c * t_c * t_c
    return r0 * r


def resistance_uohm(t_c, r0=R0_OHM):
    """Resistance in integer micro-ohm: what the chips integrate with (no floats in the hot path)."""
    return int(resistance_ohm(t_c, r0) * 1e6 + 0.5)


def temperature_c(r_ohm, r0=R0_OHM):
    """Inverse for t >= 0 degC (closed form) and below 0 degC (Newton): test-side checks."""
    x = r_ohm / r0
    disc = A * A - 4.0 * B * (1.0 - x)
    t = (-A + disc ** 0.5) / (2.0 * B)
    if t >= 0.0:
        return t
    for _ in range(20):
        f = resistance_ohm(t, r0) / r0 - x
        d = A + 2.0 * B * t + C * (4.0 * t * t * t - 300.0 * t * t)
        t -= f / d
    return t
