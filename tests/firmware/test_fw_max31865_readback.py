"""MAX31865: configuration writes never depend on a (possibly corrupted) read-back.

A bus error that injects garbage into the configuration register's read-back
must not make the driver switch V_BIAS off or change the wiring, filter or
conversion mode when it clears a fault, starts a one-shot conversion, runs a
fault-detection cycle or sets a bit.
"""
import pytest

from fwfakes import FakeSPI, FakePin, FakeMAX31865
from fwmax31865 import one_shot, set_config_bit
from firmware import max31865 as mx


class CorruptConfigReadMAX31865(FakeMAX31865):
    """Reads of the configuration register return ``garbage`` once ``corrupt`` is set."""

    def __init__(self, **kw):
        super().__init__(**kw)
        self.corrupt = False
        self.garbage = 0x00
        self.writes = []

    def transfer(self, wbuf, rbuf):
        super().transfer(wbuf, rbuf)
        if self.corrupt and rbuf is not None and not wbuf[0] & 0x80 and wbuf[0] == 0:
            rbuf[1] = self.garbage

    def _write(self, a, v):
        if a == 0:
            self.writes.append(v)
        super()._write(a, v)


KEEP = mx._CONFIG_VBIAS | mx._CONFIG_3WIRE | mx._CONFIG_FILTER_50HZ


def rig(wires, filter_hz):
    spi, pin, chip = FakeSPI(), FakePin(5), CorruptConfigReadMAX31865()
    spi.attach(pin, chip)
    d = mx.MAX31865(spi, pin, wires=wires, filter_hz=filter_hz)
    chip.writes.clear()
    chip.corrupt = True
    return d, chip


# garbage that turns every kept bit the other way, and all-ones / all-zeros (MISO stuck)
@pytest.mark.parametrize("wires,filter_hz", [(3, 50), (4, 60), (2, 50)])
@pytest.mark.parametrize("garbage", [0x00, 0xFF, 0x6E, 0x13])
def test_fault_clear_one_shot_and_bit_set_ignore_corrupted_readback(wires, filter_hz, garbage):
    d, chip = rig(wires, filter_hz)
    chip.garbage = garbage
    want = mx._CONFIG_VBIAS | mx._CONFIG_AUTO | (mx._CONFIG_3WIRE if wires == 3 else 0) | (
        mx._CONFIG_FILTER_50HZ if filter_hz == 50 else 0)
    assert d.configuration == garbage  # the corruption really reaches the driver
    d.clear_fault()
    assert chip.writes[-1] == want | mx._CONFIG_FAULT_CLEAR  # D5, D3, D2 zero, the rest as configured
    one_shot(d)
    assert chip.writes[-1] == want | mx._CONFIG_1SHOT
    set_config_bit(d, mx._CONFIG_AUTO, False)
    assert chip.writes[-1] == want & ~mx._CONFIG_AUTO
    set_config_bit(d, mx._CONFIG_AUTO, True)
    assert chip.writes[-1] == want
    assert chip.regs[0] == want  # the chip ends as configured: V_BIAS on, wiring and filter unchanged


@pytest.mark.parametrize("garbage", [0x00, 0x13, 0x61])  # D3:D2 = 0: the poll sees the cycle end
def test_fault_cycle_restores_driver_configuration_not_readback(garbage):
    d, chip = rig(3, 50)
    chip.garbage = garbage
    status = d.run_fault_detection()
    start, end = chip.writes[0], chip.writes[-1]
    # the cycle runs with V_BIAS on, auto off, wiring and filter as configured
    assert start == KEEP | mx._FAULT_CYCLE_AUTO
    assert end == KEEP | mx._CONFIG_AUTO
    assert chip.regs[0] == KEEP | mx._CONFIG_AUTO
    assert status == 0


def test_fault_cycle_that_never_ends_is_oserror_and_writes_nothing_wild():
    d, chip = rig(3, 50)
    chip.garbage = 0x0C  # read-back claims the cycle is still running
    with pytest.raises(OSError):
        d.run_fault_detection()
    assert all(w & KEEP == KEEP for w in chip.writes)
