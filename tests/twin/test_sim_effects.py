"""Every catalog effect changes the twin's output in its documented direction."""
import numpy as np
import pytest

from host.twin import EFFECTS, NODES, STILL_AIR, resolve_effects, simulate

QUIET = dict(noise_um=0.0, temp_noise_K=0.0)
NAMES = ("ambient_expansion", "speed_dependent_heat", "bearing_heat", "moving_convection", "reversal_error", "sensor_lag")


def _far(sim, P=700.0):
    rows = sim.err_position_mm == P
    if sim.err_direction is not None:
        rows &= sim.err_direction == 1
    return sim.err_um[rows]


def test_catalog_has_exactly_the_contract_names_with_units_and_defaults():
    assert tuple(EFFECTS) == NAMES
    for e in EFFECTS.values():
        assert e.unit and e.description and e.direction and np.isfinite(e.default) and e.default > 0


def test_resolve_effects_accepts_names_mappings_and_strings():
    assert resolve_effects(None) == {}
    assert resolve_effects(["sensor_lag"]) == {"sensor_lag": EFFECTS["sensor_lag"].default}
    assert resolve_effects("bearing_heat, reversal_error") == {"bearing_heat": 5.0, "reversal_error": 4.0}
    assert resolve_effects({"bearing_heat": 2, "ambient_expansion": None}) == {"ambient_expansion": 1.0, "bearing_heat": 2.0}
    with pytest.raises(ValueError, match="unknown effect 'bearing'"):
        resolve_effects(["bearing"])
    with pytest.raises(ValueError, match="sensor_lag.*>= 0"):
        resolve_effects({"sensor_lag": -1})
    with pytest.raises(ValueError, match="must be a number"):
        resolve_effects({"bearing_heat": "lots"})


def test_ambient_expansion_follows_the_base_temperature():
    off = simulate("idle", None, **QUIET)
    on = simulate("idle", {"ambient_expansion": 2.0}, **QUIET)
    base = off.nodes_true_C[:, [n.role for n in NODES].index("base")]
    dbase = np.interp(off.err_time_s, off.t_s, base) - base[0]
    expected = 2.0 * off.params.alpha_um_mK * dbase * off.err_position_mm * 1e-3
    np.testing.assert_allclose(on.err_um - off.err_um, expected, atol=1e-12)
    assert abs(dbase).max() > 0.3  # the day-to-evening drift moves the base
    last = off.err_time_s == off.sweep_s[-1]
    assert np.sign((on.err_um - off.err_um)[last][-1]) == np.sign(dbase[last][-1])


@pytest.mark.parametrize("protocol,sign", [("v15000_r210_490", 1), ("v6500_r210_490", -1), ("v8000_r210_490", 0)])
def test_speed_dependent_heat_grows_with_feed(protocol, sign):
    off = simulate(protocol, None, **QUIET)
    on = simulate(protocol, ["speed_dependent_heat"], **QUIET)
    d = _far(on).max() - _far(off).max()
    if sign == 0:
        # at feed_ref only the sweeps' slow travel (700 mm/min) changes: a little less heat
        # (the sweeps bring ~2 % of the heat; measured -0.20 um of a 55 um peak)
        assert -0.01 * _far(off).max() < d < 0
        no_sweep = dict(QUIET, sweep_duration_min=0.0)
        d0 = _far(simulate(protocol, ["speed_dependent_heat"], **no_sweep)) - _far(simulate(protocol, None, **no_sweep))
        assert np.abs(d0).max() < 1e-9
    else:
        assert np.sign(d) == sign and abs(d) > 1.0


def test_bearing_heat_adds_error_everywhere_and_warms_the_bearing():
    off = simulate("v8000_r210_490", None, **QUIET)
    on = simulate("v8000_r210_490", {"bearing_heat": 5.0}, **QUIET)
    d = on.err_um - off.err_um
    moving = on.err_time_s > 0
    assert np.all(d[moving & (on.err_position_mm > 0)] > 0)
    assert np.all(d[on.err_position_mm == 0] == 0)
    # the bearing adds most of its expansion near the fixed end: the increase levels off with P
    last = on.err_time_s == 180 * 60
    dl = d[last]
    assert dl[5] > 0.5 * dl[-1]
    bearing = [i for i, n in enumerate(NODES) if n.location.startswith("fixed-end")][0]
    assert on.sensors_C[-1, bearing] >= off.sensors_C[-1, bearing]
    assert (on.sensors_C[:, bearing] - off.sensors_C[:, bearing]).max() > 2.0


def test_moving_convection_saturates_lower_and_faster():
    # in still air, so the warm-up curve is the response to the nut's heat alone
    off = simulate("v8000_r210_490", None, **QUIET, **STILL_AIR)
    on = simulate("v8000_r210_490", ["moving_convection"], **QUIET, **STILL_AIR)
    warm = off.sweep_s <= 180 * 60
    a, b = _far(off)[warm], _far(on)[warm]
    a, b = a - a[0], b - b[0]
    assert b.max() < 0.8 * a.max()
    def t63(y):
        return off.sweep_s[warm][np.argmax(y >= 0.63 * y.max())]
    assert t63(b) < t63(a)
    # while the screw stands still h is the resting value: convection multiplier 1 in the cool-down,
    # except while a sweep turns the screw
    step = off.t_s[:-1]
    in_sweep = np.zeros(step.size, dtype=bool)
    for t0, t1 in on.sweep_motion[:, :2]:
        in_sweep |= (step + on.params.dt_s > t0) & (step < t1)
    cool = (step >= 180 * 60) & ~in_sweep
    np.testing.assert_array_equal(on.conv_mult[cool], 1.0)
    assert np.all(on.conv_mult[(step >= 180 * 60) & in_sweep] > 1.0)
    assert on.conv_mult.max() == pytest.approx(2.0)


def test_reversal_error_makes_bidirectional_sweeps_with_offset_B():
    on = simulate("v8000_r0_700", {"reversal_error": 6.0}, **QUIET)
    assert on.err_direction is not None and set(np.unique(on.err_direction)) == {-1, 1}
    fwd = on.err_direction == 1
    for t in on.sweep_s[:3]:
        f = (on.err_time_s == t) & fwd
        r = (on.err_time_s == t) & ~fwd
        assert np.all(np.diff(on.err_position_mm[f]) > 0) and np.all(np.diff(on.err_position_mm[r]) < 0)
        np.testing.assert_allclose(on.err_um[f] - on.err_um[r][::-1], 6.0, atol=1e-9)
    off = simulate("v8000_r0_700", None, **QUIET)
    assert off.err_direction is None


def test_sensor_lag_delays_readings_but_not_errors():
    off = simulate("v8000_r210_490", None, **QUIET)
    on = simulate("v8000_r210_490", {"sensor_lag": 600.0}, **QUIET)
    np.testing.assert_array_equal(on.err_um, off.err_um)
    np.testing.assert_array_equal(on.nodes_true_C, off.nodes_true_C)
    nut = 0
    d = on.sensors_C[:, nut] - off.sensors_C[:, nut]
    warm = (on.t_s > 600) & (on.t_s <= 180 * 60)
    cool = on.t_s > 180 * 60 + 600
    assert d[warm].mean() < -0.2 and d[cool].mean() > 0.2
    # the lagged reading peaks later than the true temperature: about tau for a smooth peak
    shift = on.t_s[np.argmax(on.sensors_C[:, nut])] - off.t_s[np.argmax(off.sensors_C[:, nut])]
    assert 0 < shift < 3 * 600.0
    # one more first-order stage on the sensor's own reading, exact for a reading linear between samples
    U, R = off.readings_true_C[:, nut], on.readings_true_C[:, nut]
    a = np.exp(-on.params.dt_s / 600.0)
    b = 1 - 600.0 * (1 - a) / on.params.dt_s
    np.testing.assert_allclose(R[1:], a * R[:-1] + (1 - a) * U[:-1] + b * (U[1:] - U[:-1]), atol=1e-9)


def test_all_effects_together_still_give_a_valid_simulation():
    sim = simulate("mixed", list(EFFECTS))
    assert np.all(np.isfinite(sim.err_um)) and np.all(np.isfinite(sim.sensors_C))
    assert sim.err_direction is not None
