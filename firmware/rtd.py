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

try:
    from micropython import const
except ImportError:  # CPython
    const = lambda x: x  # noqa: E731

RATIO_ONE = const(10000000)  # R/R0 = 1 in the ratio unit
T_UNDER = const(-999999)  # below -200 degC (shorted RTD or wiring fault)
T_OVER = const(999999)  # above +850 degC (open RTD)
_T0_MC = const(-200000)
_LAST = const(105)  # index of the last node

# R/R0 * 1e7 at -200, -190, ..., +850 degC
_NODES = (
    1852008, 2282548, 2709643, 3133505, 3554333, 3972318, 4387642, 4800475,
    5210978, 5619301, 6025584, 6429959, 6832545, 7233453, 7632784, 8030628,
    8427065, 8822166, 9215990, 9608588, 10000000, 10390252, 10779350, 11167292,
    11554080, 11939713, 12324190, 12707512, 13089680, 13470693, 13850550, 14229252,
    14606800, 14983192, 15358430, 15732512, 16105440, 16477212, 16847830, 17217292,
    17585600, 17952752, 18318750, 18683592, 19047280, 19409812, 19771190, 20131412,
    20490480, 20848392, 21205150, 21560753, 21915200, 22268492, 22620630, 22971612,
    23321440, 23670112, 24017630, 24363993, 24709200, 25053252, 25396150, 25737893,
    26078480, 26417912, 26756190, 27093312, 27429280, 27764092, 28097750, 28430252,
    28761600, 29091793, 29420830, 29748712, 30075440, 30401012, 30725430, 31048692,
    31370800, 31691752, 32011550, 32330192, 32647680, 32964012, 33279190, 33593212,
    33906080, 34217792, 34528350, 34837752, 35146000, 35453092, 35759030, 36063812,
    36367440, 36669912, 36971230, 37271393, 37570400, 37868252, 38164950, 38460492,
    38754880, 39048112,
)

# per segment: 2*(R_k + R_k+1) - 4*R(T_k + 5 degC), units of 1e-7 R0
_CURV = (
    -1777, -1669, -1566, -1468, -1375, -1287, -1204, -1127,
    -1054, -986, -923, -866, -813, -765, -723, -685,
    -652, -625, -602, -585, -578, -578, -578, -578,
    -578, -577, -578, -578, -577, -578, -578, -578,
    -578, -578, -578, -578, -578, -578, -578, -578,
    -577, -578, -578, -578, -578, -578, -577, -578,
    -578, -578, -577, -577, -578, -577, -578, -578,
    -578, -578, -578, -578, -578, -578, -577, -578,
    -577, -578, -578, -578, -577, -577, -578, -578,
    -578, -577, -578, -578, -578, -578, -578, -578,
    -577, -578, -578, -578, -578, -578, -577, -578,
    -578, -578, -578, -578, -578, -578, -578, -578,
    -578, -578, -577, -577, -578, -578, -578, -578,
    -578,
)


def temperature_mC(r):
    """Temperature in milli-degC of a Pt100 whose R/R0 is ``r`` * 1e-7.

    Returns ``T_UNDER`` / ``T_OVER`` outside -200..+850 degC.
    """
    nodes = _NODES
    if r < nodes[0]:
        return T_UNDER
    if r > nodes[_LAST]:
        return T_OVER
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
