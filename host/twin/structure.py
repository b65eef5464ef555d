"""Machine-structure temperature points around the axis.

Each point is a first-order thermal node: it relaxes with its own time constant
towards the air temperature plus a weighted sum of the axis heat sources (nut
friction, motor, fixed-end bearing), tau dT/dt = T_air + offset + sum_s g_s P_s - T.
All points share the same few sources, which is what makes the candidates of a
sensor selection strongly collinear, as on a real machine. Gains (K/W) and time
constants are set so the steady-state rises match the ranges reported for
mid-size machining centres (nut 5-15 K, motor 10-20 K, bed < 2 K); see docs/twin.md.

A sensor is a small body of its own on the point it measures (a sheathed Pt100 in
a bore or a clamp, an air probe): its reading lags the point's temperature with the
sensor's own time constant ``sensor_s``, exact for a temperature linear between samples.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
import math
from dataclasses import dataclass

import numpy as np
from scipy.signal import lfilter

SOURCES = ("nut", "motor", "bearing")


@dataclass(frozen=True)
class Node:
    name: str
    role: str
    location: str
    tau_min: float  # 0 = follows its drive instantly
    gains: tuple = ()  # ((source, K/W), ...)
    offset_K: float = 0.0
    sensor_s: float = 60.0  # the sensor's own time constant on its body


NODES = (
    Node("T1", "nut", "ball-screw nut housing", 20.0, (("nut", 1.1),), sensor_s=45.0),
    Node("T2", "base", "machine bed under the fixed-end bearing block", 150.0, (("motor", 0.03), ("bearing", 0.15)),
         sensor_s=90.0),
    Node("T3", "ambient", "air 0.5 m beside the axis", 0.0, sensor_s=150.0),
    Node("T4", "bearing", "fixed-end support bearing housing", 25.0, (("bearing", 1.6), ("motor", 0.2)), sensor_s=45.0),
    Node("T5", "motor", "servo motor flange", 35.0, (("motor", 0.6),), sensor_s=60.0),
    Node("T6", "bearing", "free-end (floating) bearing housing", 40.0, (("nut", 0.15),), sensor_s=45.0),
    Node("T7", "structure", "table underside above the nut", 45.0, (("nut", 0.45),), sensor_s=75.0),
    Node("T8", "structure", "column, 0.3 m above the bed", 180.0, (("motor", 0.05), ("nut", 0.04)), sensor_s=90.0),
    Node("T9", "structure", "column, top", 240.0, (("motor", 0.03), ("nut", 0.02)), 0.3, sensor_s=90.0),
    Node("T10", "structure", "bed between the guideways, mid-stroke", 200.0, (("nut", 0.08), ("motor", 0.03)),
         sensor_s=90.0),
    Node("T11", "structure", "linear guide rail next to the nut range", 60.0, (("nut", 0.3),), sensor_s=60.0),
    Node("T12", "structure", "motor bracket and coupling housing", 40.0, (("motor", 0.35), ("bearing", 0.4)),
         sensor_s=60.0),
    Node("T13", "ambient", "air under the machine, near the floor", 10.0, (("nut", 0.03),), -0.4, sensor_s=150.0),
)


def node_temperatures(power_W: Mapping[str, np.ndarray], T_air_edges: np.ndarray, dt: float, nodes: Sequence[Node] = NODES) -> np.ndarray:
    """True node temperatures (n_steps + 1, len(nodes)) at the step edges.

    power_W: {source: (n_steps,)} held over each step; T_air_edges (n_steps + 1,)
    the air at the step edges (its step mean drives the nodes). Nodes start in
    equilibrium with the air and no heat. Exact zero-order-hold discretisation.
    """
    T_air_edges = np.asarray(T_air_edges, dtype=float)
    n = len(T_air_edges) - 1
    T_air_step = 0.5 * (T_air_edges[:-1] + T_air_edges[1:])
    drive = np.repeat(T_air_step[:, None], len(nodes), axis=1)
    edge_drive = np.repeat(T_air_edges[:, None], len(nodes), axis=1)
    start = np.full(len(nodes), T_air_edges[0])
    for j, node in enumerate(nodes):
        drive[:, j] += node.offset_K
        edge_drive[:, j] += node.offset_K
        start[j] += node.offset_K
        for src, g in node.gains:
            drive[:, j] += g * power_W[src]
            edge_drive[1:, j] += g * power_W[src]
    tau = np.array([nd.tau_min * 60.0 for nd in nodes])
    a = np.where(tau > 0, np.exp(-dt / np.where(tau > 0, tau, 1.0)), 0.0)
    T = np.empty((n + 1, len(nodes)))
    T[0] = start
    for k in range(n):
        T[k + 1] = a * T[k] + (1 - a) * drive[k]
    instant = tau == 0
    # air-like nodes follow the air at the edge itself, not the step mean
    T[:, instant] = edge_drive[:, instant]
    return T


def lagged(values: np.ndarray, tau_s: float | Sequence[float] | np.ndarray, dt: float) -> np.ndarray:
    """First-order lag (time constants ``tau_s``: a number or one per column) of ``values`` (n, k).

    Exact for an input linear between samples: y(k+1) = a*y(k) + (1-a)*u(k) + b*(u(k+1) - u(k)),
    a = exp(-dt/tau), b = 1 - tau*(1-a)/dt; the reading starts at the first value. tau = 0 passes through.
    """
    values = np.asarray(values, dtype=float)
    tau = np.broadcast_to(np.asarray(tau_s, dtype=float), values.shape[1:])
    out = values.copy()
    for j in np.flatnonzero(tau > 0):
        a = math.exp(-dt / tau[j])
        b = 1.0 - tau[j] * (1.0 - a) / dt
        u = values[:, j] - values[0, j]
        out[:, j] = values[0, j] + lfilter([b, 1.0 - a - b], [1.0, -a], u)
    return out
