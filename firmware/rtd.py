"""Pt100 resistance to temperature in integer arithmetic (IEC 60751 Callendar-Van Dusen).

R(T)/R0 = 1 + A*T + B*T^2 (+ C*(T - 100)*T^3 below 0 degC), A = 3.9083e-3,
B = -5.775e-7, C = -4.183e-12. The inverse is taken segment-wise: R/R0 at
every 10 degC from -200 to +850 degC is tabulated (``_NODES``) together with the
segment's curvature ``_CURV`` (2*(R_k + R_k+1) - 4*R(mid), which is exactly
B*R0*h^2 above 0 degC). Inside a segment the chord estimate is refined by one
step of the quadratic inverse, which leaves an error far below 0.002 degC
(tests/firmware/test_fw_rtd.py checks it against the exact inverse).

Every intermediate stays below 2**30 so a 32-bit MicroPython port never
allocates a big integer: ratios are in units of 1e-7 (R/R0 * 10**7, at most
3.9e7), segment fractions in 2**-20.

The tables were generated from the floating-point relation;
tests/firmware/test_fw_rtd.py recomputes and checks every entry.
"""

from micropython import const

_RATIO_ONE = const(10000000)  # R/R0 = 1 in the ratio unit
_T_UNDER = const(-999999)  # below -200 degC (shorted RTD or wiring fault)
_T_OVER = const(999999)  # above +850 degC (open RTD)
_T0_MC = const(-200000)
_LAST = const(105)  # index of the last node

# The tables, packed to keep the .mpy small (1.7 kB as tuples, 0.6 kB as bytes):
# R/R0 * 1e7 at -200 degC, then the 105 increments to -190, ..., +850 degC as
# 3-byte little-endian integers; per segment 2*(R_k + R_k+1) - 4*R(T_k + 5 degC)
# in 1e-7 R0 as 2-byte little-endian signed integers.
_NODE0 = const(1852008)
_DELTAS = (
    b"\xcc\x91\x06W\x84\x06\xb6w\x06\xdck\x06\xc1`\x06\\V\x06\xa1L\x06\x87C"
    b"\x06\x03;\x06\x0b3\x06\x97+\x06\x9a$\x06\x0c\x1e\x06\xe3\x17\x06\x14\x12"
    b"\x06\x95\x0c\x06]\x07\x06`\x02\x06\x96\xfd\x05\xf4\xf8\x05l\xf4\x05\xea"
    b"\xef\x05f\xeb\x05\xe4\xe6\x05a\xe2\x05\xdd\xdd\x05Z\xd9\x05\xd8\xd4\x05U"
    b"\xd0\x05\xd1\xcb\x05N\xc7\x05\xcc\xc2\x05H\xbe\x05\xc6\xb9\x05B\xb5\x05"
    b"\xc0\xb0\x05<\xac\x05\xba\xa7\x056\xa3\x05\xb4\x9e\x050\x9a\x05\xae\x95"
    b"\x05*\x91\x05\xa8\x8c\x05$\x88\x05\xa2\x83\x05\x1e\x7f\x05\x9cz\x05\x18v"
    b"\x05\x96q\x05\x13m\x05\x8fh\x05\x0cd\x05\x8a_\x05\x06[\x05\x84V\x05\x00R"
    b"\x05~M\x05\xfbH\x05wD\x05\xf4?\x05r;\x05\xef6\x05k2\x05\xe8-\x05f)\x05"
    b"\xe2$\x05` \x05\xdc\x1b\x05Z\x17\x05\xd6\x12\x05T\x0e\x05\xd1\t\x05M\x05"
    b"\x05\xca\x00\x05H\xfc\x04\xc4\xf7\x04B\xf3\x04\xbe\xee\x04<\xea\x04\xb8"
    b"\xe5\x046\xe1\x04\xb2\xdc\x040\xd8\x04\xac\xd3\x04*\xcf\x04\xa6\xca\x04$"
    b"\xc6\x04\xa0\xc1\x04\x1e\xbd\x04\x9a\xb8\x04\x18\xb4\x04\x94\xaf\x04\x12"
    b"\xab\x04\x8e\xa6\x04\x0c\xa2\x04\x88\x9d\x04\x06\x99\x04\x83\x94\x04\xff"
    b"\x8f\x04|\x8b\x04\xfa\x86\x04v\x82\x04\xf4}\x04py\x04"
)
_CURVS = (
    b"\x0f\xf9{\xf9\xe2\xf9D\xfa\xa1\xfa\xf9\xfaL\xfb\x99\xfb\xe2\xfb&\xfce"
    b"\xfc\x9e\xfc\xd3\xfc\x03\xfd-\xfdS\xfdt\xfd\x8f\xfd\xa6\xfd\xb7\xfd\xbe"
    b"\xfd\xbe\xfd\xbe\xfd\xbe\xfd\xbe\xfd\xbf\xfd\xbe\xfd\xbe\xfd\xbf\xfd\xbe"
    b"\xfd\xbe\xfd\xbe\xfd\xbe\xfd\xbe\xfd\xbe\xfd\xbe\xfd\xbe\xfd\xbe\xfd\xbe"
    b"\xfd\xbe\xfd\xbf\xfd\xbe\xfd\xbe\xfd\xbe\xfd\xbe\xfd\xbe\xfd\xbf\xfd\xbe"
    b"\xfd\xbe\xfd\xbe\xfd\xbf\xfd\xbf\xfd\xbe\xfd\xbf\xfd\xbe\xfd\xbe\xfd\xbe"
    b"\xfd\xbe\xfd\xbe\xfd\xbe\xfd\xbe\xfd\xbe\xfd\xbf\xfd\xbe\xfd\xbf\xfd\xbe"
    b"\xfd\xbe\xfd\xbe\xfd\xbf\xfd\xbf\xfd\xbe\xfd\xbe\xfd\xbe\xfd\xbf\xfd\xbe"
    b"\xfd\xbe\xfd\xbe\xfd\xbe\xfd\xbe\xfd\xbe\xfd\xbf\xfd\xbe\xfd\xbe\xfd\xbe"
    b"\xfd\xbe\xfd\xbe\xfd\xbf\xfd\xbe\xfd\xbe\xfd\xbe\xfd\xbe\xfd\xbe\xfd\xbe"
    b"\xfd\xbe\xfd\xbe\xfd\xbe\xfd\xbe\xfd\xbe\xfd\xbf\xfd\xbf\xfd\xbe\xfd\xbe"
    b"\xfd\xbe\xfd\xbe\xfd\xbe\xfd"
)


def _unpack():
    nodes = [_NODE0] * (_LAST + 1)
    curv = [0] * _LAST
    r = _NODE0
    for k in range(_LAST):
        r += _DELTAS[3 * k] | (_DELTAS[3 * k + 1] << 8) | (_DELTAS[3 * k + 2] << 16)
        nodes[k + 1] = r
        c = _CURVS[2 * k] | (_CURVS[2 * k + 1] << 8)
        curv[k] = c - 65536 if c > 32767 else c
    # tuples: indexing them is about three times faster than arrays on MicroPython
    return tuple(nodes), tuple(curv)


_NODES, _CURV = _unpack()


def temperature_mC(r):
    """Temperature in milli-degC of a Pt100 whose R/R0 is ``r`` * 1e-7.

    Returns -999999 / 999999 (``_T_UNDER`` / ``_T_OVER``) outside -200..+850 degC.
    """
    nodes = _NODES
    if r < nodes[0]:
        return _T_UNDER
    if r > nodes[_LAST]:
        return _T_OVER
    lo = 0
    hi = _LAST
    while hi - lo > 1:  # nodes[lo] <= r <= nodes[hi]
        mid = (lo + hi) >> 1
        if r < nodes[mid]:
            hi = mid
        else:
            lo = mid
    rk = nodes[lo]
    d = nodes[hi] - rk
    dr = r - rk
    # chord fraction u0 = dr/d in 2**-20, split in two divisions to stay < 2**30
    x = dr << 10
    q = x // d
    u = (q << 10) + (((x - q * d) << 10) + (d >> 1)) // d
    # quadratic inverse step: R = R_k + u*d + c*(u^2 - u)  =>  u = u0 + c*u*(1-u)/d
    u15 = u >> 5
    p = (u15 * (32768 - u15)) >> 15
    u += (_CURV[lo] * p * 32 + (d >> 1)) // d
    # 10 degC = 10000 mdegC = 625 * 16
    return _T0_MC + lo * 10000 + ((u * 625 + 32768) >> 16)


def ratio_of(t_mC):
    """R/R0 * 1e7 at ``t_mC``, from the same tables (start-up only: may exceed 2**30)."""
    if t_mC <= _T0_MC:
        return _NODES[0]
    k = (t_mC - _T0_MC) // 10000
    if k >= _LAST:
        return _NODES[_LAST]
    rk = _NODES[k]
    d = _NODES[k + 1] - rk
    u = ((t_mC - _T0_MC - k * 10000) << 20) // 10000  # fraction in 2**-20
    return rk + ((d * u + (1 << 19)) >> 20) - ((_CURV[k] * u * ((1 << 20) - u)) >> 40)
