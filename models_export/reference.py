"""The float model the certificate compares against, on the firmware's inputs.

Evaluates a model document in double precision exactly as docs/model-format.md
defines it, with the firmware's input conventions (temperatures in milli-degC,
positions in um, clamped to the envelope the table declares) so that tests can
compare ``integer output x 0.01 um`` with it. Screw: ``Reference.step`` runs
the recurrence T <- A T + B u + c0 a0 + c1 a1 on the same per-step travel (um)
the firmware accumulated and the air it read.
"""


class Reference:
    def __init__(self, doc, table):
        """``table``: the firmware Table (its clamping envelope, integer refs are not used)."""
        self.doc = doc
        self.t = table
        self.kind = doc["kind"]
        th = doc.get("thermal") or {}
        self.sensors = list(doc.get("sensors") or [])
        refs = doc.get("reference_C") or {}
        self.ref = [float(refs[s]) for s in self.sensors]
        if self.kind == "poly_slope":
            c = th["coefficients_um_per_mm_per_K"]
            self.b0 = float(th.get("intercept_um_per_mm", 0.0))
            self.b = [float(c[s]) for s in self.sensors]
        elif self.kind == "linear_direct":
            c = th["coefficients_um_per_K"]
            self.b0 = float(th.get("intercept_um", 0.0))
            self.b = [float(c[s]) for s in self.sensors]
        else:
            red = th["reduced"]
            self.red = red
            self.b0 = 0.0
            self.b = [0.0] * len(self.sensors)
            if red.get("base_sensor"):
                i = self.sensors.index(red["base_sensor"])
                self.b[i] = float(red["alpha_um_per_mm_per_K"])
                self.ref[i] = float(red["base_ref_C"])
            self.A = [[float(v) for v in row] for row in red["A"]]
            self.B = [float(v) for v in red["B_K_per_mm"]]
            self.edges = [float(e) for e in red["edges_mm"]]
            self.fixed = float(red["fixed_end_mm"])
            self.alpha = float(red["alpha_um_per_mm_per_K"])
            self.T = [0.0] * len(self.B)
            self.air = red.get("air_sensor")
            M = len(self.B)
            self.c0 = [float(v) for v in (red.get("air_K0") or [0.0] * M)]
            self.c1 = [float(v) for v in (red.get("air_K1") or [0.0] * M)]
            self.a0 = 0.0
        if getattr(table, "ref_mode", 0) == 1:
            self.ref = [r / 1000.0 for r in table.ref]  # latched references: whole milli-degC, as the firmware holds them
        geo = doc.get("geometric") or {}
        self.g = [float(v) for v in (geo.get("coefficients_um") or [0.0])]
        # the firmware's start temperatures (Evaluator.__init__); update() replaces them as the firmware's update() does
        self.temps_now = [0 if lo <= 0 <= hi else lo for lo, hi in zip(table.env_lo, table.env_hi)]
        if self.kind == "screw":
            self.settle()

    def update(self, temps_mC):
        """The temperatures the firmware read last (the air the next step ends at)."""
        self.temps_now = list(temps_mC)

    def latch(self, refs_mC, temps_mC=None):
        """References latched by the firmware (Evaluator.ref), milli-degC, at the temperatures ``temps_mC``
        (a latch is a cold start: the screw state restarts in equilibrium with the air)."""
        self.ref = [r / 1000.0 for r in refs_mC]
        if temps_mC is not None:
            self.temps_now = list(temps_mC)
        if self.kind == "screw":
            self.settle()

    def temps_C(self, temps_mC):
        t = self.t
        return [min(max(v, t.env_lo[i]), t.env_hi[i]) / 1000.0 for i, v in enumerate(temps_mC)]

    def pos_mm(self, pos_um):
        t = self.t
        return min(max(pos_um, t.pos_lo), t.pos_hi) / 1000.0

    def linear(self, temps_mC):
        """s(T) in um/mm (poly_slope, screw base term) or the offset in um (linear_direct)."""
        return self.b0 + sum(b * (T - r) for b, T, r in zip(self.b, self.temps_C(temps_mC), self.ref))

    def geometric(self, P):
        acc = 0.0
        for c in reversed(self.g):
            acc = acc * P + c
        return acc

    def segments(self, P):
        x = P - self.fixed
        e = self.edges
        return self.alpha * sum(Ti * min(max(x - e[i], 0.0), e[i + 1] - e[i]) for i, Ti in enumerate(self.T))

    def offset(self, temps_mC, pos_um):
        """Total offset in um."""
        if self.kind == "linear_direct":
            return self.linear(temps_mC)
        P = self.pos_mm(pos_um)
        out = self.geometric(P) + self.linear(temps_mC) * P
        if self.kind == "screw":
            out += self.segments(P)
        return out

    def thermal(self, temps_mC, pos_um):
        """Thermal part (no geometric) in um."""
        if self.kind == "linear_direct":
            return self.linear(temps_mC)
        P = self.pos_mm(pos_um)
        out = self.linear(temps_mC) * P
        if self.kind == "screw":
            out += self.segments(P)
        return out

    def slope(self, temps_mC):
        """Thermal slope in um/m (screw: base term plus the chord over the envelope)."""
        if self.kind == "linear_direct":
            return 0.0
        s = self.linear(temps_mC) * 1000.0
        if self.kind == "screw":
            lo, hi = self.t.pos_lo / 1000.0, self.t.pos_hi / 1000.0
            if hi > lo:
                s += (self.segments(hi) - self.segments(lo)) / (hi - lo) * 1000.0
        return s

    def air_K(self, temps_mC):
        """The air over its reference (K, clamped to the envelope); 0 without an air sensor."""
        if not self.air:
            return 0.0
        i = self.sensors.index(self.air)
        return self.temps_C(temps_mC)[i] - self.ref[i]

    def settle(self, temps_mC=None):
        """Start state: in equilibrium with the air (the firmware's construction and latch)."""
        if temps_mC is not None:
            self.temps_now = list(temps_mC)
        a = self.air_K(self.temps_now)
        self.T = [a] * len(self.B)
        self.a0 = a

    def step(self, travel_um, temps_mC=None):
        """One recurrence step with per-segment travel in um and the temperatures at the step's end
        (default: the last ``update``)."""
        A, B, T = self.A, self.B, self.T
        if temps_mC is not None:
            self.temps_now = list(temps_mC)
        a1 = self.air_K(self.temps_now)
        self.T = [sum(A[i][j] * T[j] for j in range(len(T))) + B[i] * travel_um[i] / 1000.0
                  + self.c0[i] * self.a0 + self.c1[i] * a1 for i in range(len(T))]
        self.a0 = a1
