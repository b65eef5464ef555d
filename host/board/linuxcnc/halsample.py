"""``tcomp record --linuxcnc``: the axis position and velocity and the spindle speed, read from HAL beside the
temperatures, as motion.csv intervals and spindle.csv samples (docs/recording.md, docs/data-format.md).

``HalReader`` reads named pins (any pin, parameter or signal) through LinuxCNC's Python ``hal`` module
(``hal.get_value``; the module needs a component of this process in HAL, an empty one named ``--hal-name``).
``MotionSegmenter`` turns position/velocity samples into the run format's motion intervals. It is plain Python,
unit-tested without LinuxCNC; the whole chain runs in a real LinuxCNC in hil_tests/test_hil_linuxcnc.py.
"""

from __future__ import annotations

from collections.abc import Iterable

# a move is the bridge's (--feed) and the recording's alike: IDLE_MM_PER_S is one constant
from host.board.linuxcnc.bridge import IDLE_MM_PER_S, UM_PER_UNIT

# LinuxCNC pins of a machine's X axis, spindle 0 (checked in LinuxCNC 2.9's motmod: docs/linuxcnc.md)
DEFAULT_POSITION = "axis.x.pos-cmd"  # commanded axis position, machine units (without the external offsets)
DEFAULT_VELOCITY = "joint.0.vel-cmd"  # commanded joint velocity, machine units per second
DEFAULT_SPINDLE = "spindle.0.speed-out-abs"  # commanded spindle speed, rpm


class HalReader:
    """Reads ``pins`` from HAL each ``read()``; ValueError naming a pin HAL does not have."""

    def __init__(self, pins: Iterable[str], name: str = "tcomp-record") -> None:
        from host.board.linuxcnc.halcomp import import_hal
        hal = import_hal()
        self.hal = hal
        try:
            self.comp = hal.component(name)
        except Exception as exc:  # _hal raises RuntimeError/ValueError: no HAL running, a duplicate name
            raise ValueError("cannot create HAL component %r: %s (is LinuxCNC running, and RTAPI_FIFO_PATH/RTAPI_UID "
                             "those of its session?)" % (name, exc))
        self.comp.ready()
        self.pins = list(pins)
        for p in self.pins:
            try:
                hal.get_value(p)
            except Exception as exc:  # _hal: RuntimeError "Pin/param/signal not found" (its words vary)
                self.close()
                raise ValueError("HAL has no pin, parameter or signal %r (%s)" % (p, exc))

    def read(self) -> list[float]:
        return [float(self.hal.get_value(p)) for p in self.pins]

    def close(self) -> None:
        try:
            self.comp.exit()
        except Exception:  # already gone with its HAL session
            pass


class MotionSegmenter:
    """Position and velocity samples -> motion.csv intervals (t_start_s, t_end_s, from_mm, to_mm, feed_mm_min).

    A move starts at the last standing sample before the axis moves and ends at the first standing sample after
    it, or where the velocity changes sign (a reversal starts the next move there). Its feed is the mean of the
    sampled |velocity|: the times are as fine as the sampling period."""

    def __init__(self, units: str = "mm", idle_mm_per_s: float = IDLE_MM_PER_S) -> None:
        self.mm_per_unit = UM_PER_UNIT[units] / 1000.0
        self.idle = idle_mm_per_s
        self.move: list[float] | None = None  # [t_start, from_mm, sign, sum of |v|, samples]
        self.last: tuple[float, float] | None = None  # (t, pos_mm) of the previous sample

    def sample(self, t: float, position: float, velocity: float) -> list[tuple[float, float, float, float, float]]:
        """One sample (machine units, units/s); the intervals it closed, as tuples."""
        pos = position * self.mm_per_unit
        v = velocity * self.mm_per_unit
        out = []
        moving = abs(v) > self.idle
        sign = 1 if v > 0 else -1
        if self.move is not None and (not moving or sign != self.move[2]):
            out += self._close(t, pos)
        if moving:
            if self.move is None:
                t0, p0 = self.last if self.last is not None and not out else (t, pos)
                self.move = [t0, p0, sign, 0.0, 0]
            self.move[3] += abs(v)
            self.move[4] += 1
        self.last = (t, pos)
        return out

    def _close(self, t, pos):
        assert self.move is not None  # called with a move open (sample, finish check it)
        t0, p0, _, vsum, n = self.move
        self.move = None
        if t <= t0 or not n:
            return []
        return [(t0, t, p0, pos, 60.0 * vsum / n)]

    def finish(self) -> list[tuple[float, float, float, float, float]]:
        """The move still open at the end of the recording, closed at the last sample."""
        if self.move is None or self.last is None:
            return []
        return self._close(*self.last)
