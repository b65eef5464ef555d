"""MAX31865 and ADS122C04 drivers against register-level fakes."""
import pytest

from fwfakes import FakeSPI, FakePin, FakeMAX31865, FakeI2C, FakeADS122C04, pt100_ohm
from fwmax31865 import config_bit, decode_faults, set_config_bit
from firmware import max31865 as mx, ads122c04 as ads, rtd


def max_rig(rref=430.0, t=25.0, **kw):
    spi, pin, chip = FakeSPI(), FakePin(5), FakeMAX31865(rref_ohm=rref)
    chip.set_temperature(t)
    spi.attach(pin, chip)
    return mx.MAX31865(spi, pin, **kw), chip, spi, pin


def test_max31865_configuration_bits():
    d, chip, _, pin = max_rig(wires=3, filter_hz=50)
    c = chip.regs[0]
    assert c & mx._CONFIG_VBIAS and c & mx._CONFIG_AUTO and c & mx._CONFIG_3WIRE and c & mx._CONFIG_FILTER_50HZ
    assert c & (mx._CONFIG_1SHOT | mx._CONFIG_FAULT_CYCLE | mx._CONFIG_FAULT_CLEAR) == 0
    assert chip.fault_cycles == 1  # one automatic fault-detection cycle at start-up
    assert pin.v == 1  # chip deselected between transfers
    d2, chip2, _, _ = max_rig(wires=4, filter_hz=60)
    assert chip2.regs[0] & (mx._CONFIG_3WIRE | mx._CONFIG_FILTER_50HZ) == 0
    assert config_bit(d2, mx._CONFIG_VBIAS)
    set_config_bit(d2, mx._CONFIG_FILTER_50HZ, True)
    assert chip2.regs[0] & mx._CONFIG_FILTER_50HZ


@pytest.mark.parametrize("rref", [430.0, 400.0])
@pytest.mark.parametrize("t", [-50.0, 0.0, 23.4, 120.0, 200.0])
def test_max31865_reading_to_temperature(rref, t):
    d, chip, _, _ = max_rig(rref=rref, t=t, rref_mohm=int(rref * 1000))
    raw = d.read_rtd()
    assert raw & 1 == 0
    assert raw >> 1 == chip.code() == d.rtd
    got = rtd.temperature_mC(d.ratio(raw >> 1))
    # one code step is rref/32768 ohm = 0.034 degC at 430 ohm: quantisation bound
    assert abs(got - t * 1000) <= 0.5 * rref / 32768 / 0.38 * 1000 + 2


def test_max31865_ratio_is_exact_floor_of_product():
    d, _, _, _ = max_rig()
    for code in (0, 1, 7000, 7621, 16384, 32767):
        assert d.ratio(code) == (code * 430000 * 100 + 16384) // 32768


def test_max31865_thresholds_and_fault_decode():
    d, chip, _, _ = max_rig(t=25.0)
    lo, hi = rtd.ratio_of(-20000), rtd.ratio_of(80000)
    d.set_limits(lo, hi)
    assert d.low_threshold == d.code_of(lo)
    assert d.high_threshold == d.code_of(hi)
    assert chip.regs[3] == (d.code_of(hi) >> 7) & 0xFF and chip.regs[4] == (d.code_of(hi) << 1) & 0xFF
    assert d.read_rtd() & 1 == 0
    chip.set_temperature(95.0)  # above the high threshold
    assert d.read_rtd() & 1 == 1
    status = d.fault_status
    assert status & mx._FAULT_HIGH_THRESHOLD
    assert decode_faults(status) == ["rtd_high_threshold"]
    chip.set_temperature(25.0)
    d.clear_fault()
    assert chip.regs[7] == 0
    assert d.read_rtd() & 1 == 0
    assert decode_faults(0xFC) == ["rtd_high_threshold", "rtd_low_threshold", "refin_high",
                                      "refin_low_force_open", "rtdin_low_force_open", "over_under_voltage"]


def test_max31865_fault_clear_writes_d5_d3_d2_zero():
    d, chip, spi, _ = max_rig()
    writes = []
    orig = chip._write
    chip._write = lambda a, v: (writes.append((a, v)), orig(a, v))
    d.clear_fault()
    a, v = writes[-1]
    assert a == 0 and v & mx._CONFIG_FAULT_CLEAR and v & 0x2C == 0


def test_max31865_open_rtd_is_reported_by_fault_cycle():
    spi, pin, chip = FakeSPI(), FakePin(5), FakeMAX31865()
    chip.open_circuit = True
    spi.attach(pin, chip)
    d = mx.MAX31865(spi, pin)
    assert d.last_fault_cycle_status & mx._FAULT_OVUV
    assert d.read_rtd() & 1


def test_max31865_bad_configuration_is_valueerror():
    spi, pin = FakeSPI(), FakePin()
    with pytest.raises(ValueError, match="wires"):
        mx.MAX31865(spi, pin, wires=5)
    with pytest.raises(ValueError, match="filter_hz"):
        mx.MAX31865(spi, pin, filter_hz=55)
    with pytest.raises(ValueError, match="rref_mohm"):
        mx.MAX31865(spi, pin, rref_mohm=43)
    d, _, _, _ = max_rig()
    with pytest.raises(ValueError, match="threshold"):
        d.high_threshold = 40000


def test_max31865_bus_error_is_oserror_and_deselects():
    d, chip, spi, pin = max_rig()
    spi.fail = 1
    with pytest.raises(OSError):
        d.read_rtd()
    assert pin.v == 1


def test_max31865_missing_chip_reads_ff():
    d, chip, spi, pin = max_rig()
    chip.present = False
    assert d.read_rtd() == 0xFFFF  # stuck-high MISO: fault bit set, the channel layer excludes it


def ads_rig(wires=3, rref=1620.0, t=25.0, **kw):
    i2c, dev = FakeI2C(), FakeADS122C04(rref_ohm=rref)
    dev.set_temperature(t)
    i2c.attach(0x41, dev)
    return ads.ADS122C04(i2c, 0x41, rref_mohm=int(rref * 1000), wires=wires, **kw), dev, i2c


def test_ads122c04_registers_for_3_wire():
    d, dev, _ = ads_rig(wires=3, idac_ua=500)
    r0, r1, r2, r3 = dev.regs
    assert r0 >> 4 == ads._MUX_AIN0_AIN1
    assert 1 << ((r0 >> 1) & 7) == d.gain == 4
    assert r0 & ads._REG0_PGA_BYPASS == 0
    assert r1 & ads._REG1_CM_CONTINUOUS and (r1 >> 1) & 3 == ads._VREF_EXTERNAL and r1 >> 5 == 0
    assert ads.IDAC_UA[r2 & 7] == 500
    assert r3 >> 5 == ads._IMUX_AIN0 and (r3 >> 2) & 7 == ads._IMUX_AIN1
    assert dev.started


@pytest.mark.parametrize("wires, i1, i2", [(2, 1, 0), (4, 4, 0)])
def test_ads122c04_single_idac_wiring(wires, i1, i2):
    d, dev, _ = ads_rig(wires=wires)
    assert dev.regs[3] >> 5 == i1 and (dev.regs[3] >> 2) & 7 == i2
    assert d.gain == 2


@pytest.mark.parametrize("wires", [2, 3, 4])
@pytest.mark.parametrize("t", [-50.0, 0.0, 37.5, 200.0])
def test_ads122c04_ratiometric_conversion(wires, t):
    d, dev, _ = ads_rig(wires=wires, t=t)
    assert d.data_ready
    code = d.read_data()
    got = rtd.temperature_mC(d.ratio(code))
    assert abs(got - t * 1000) <= 3  # 24-bit: quantisation ~0.25 mdegC plus conversion bound


def test_ads122c04_ratio_split_arithmetic_is_exact():
    d, _, _ = ads_rig()
    k = (d._k1 << 12) | d._k0
    for code in (1, 4095, 4096, 1234567, 3000000, 8388607):
        exact = code * k >> 23
        assert abs(d.ratio(code) - exact) <= 1
    assert d.ratio(-5) == 0 and d.ratio(0) == 0


def test_ads122c04_absent_chip_and_bad_config():
    i2c = FakeI2C()
    with pytest.raises(OSError):
        ads.ADS122C04(i2c, 0x40)
    with pytest.raises(ValueError, match="address"):
        ads.ADS122C04(i2c, 0x20)
    with pytest.raises(ValueError, match="idac_ua"):
        ads.ADS122C04(i2c, 0x40, idac_ua=300)
    with pytest.raises(ValueError, match="wires"):
        ads.ADS122C04(i2c, 0x40, wires=1)


def test_ads122c04_register_readback_mismatch_is_oserror():
    i2c, dev = FakeI2C(), FakeADS122C04()
    i2c.attach(0x40, dev)
    orig = dev.write
    dev.write = lambda cmd, buf: None  # writes are lost on the bus
    with pytest.raises(OSError, match="register"):
        ads.ADS122C04(i2c, 0x40)
    dev.write = orig


def test_ads122c04_drdy_clears_on_read():
    d, dev, _ = ads_rig()
    dev.auto = False
    dev.convert()
    assert d.data_ready
    d.read_data()
    assert not d.data_ready


def test_pt100_helper_matches_reference_points():
    for t, ohm in [(-50, 80.31), (0, 100.0), (20, 107.79), (50, 119.40), (100, 138.51), (200, 175.86)]:
        assert abs(pt100_ohm(t) - ohm) < 0.006
