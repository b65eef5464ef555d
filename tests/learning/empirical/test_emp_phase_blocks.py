"""forward_blocks="phases" (issue 21; the default with a spindle log since stop 30): a forward-chaining block per running
and per stopped phase of the spindle, its edges on a schedule written out by hand, forward_blocks="cycles" (the default
before), and what is refused (a misspelt value, a run without spindle.csv) by name."""
import numpy as np
import pytest

from host.cli.fit_empirical import parse_options
from host.data.runs import Errors, Spindle
from host.errors import UserError
from host.learning.empirical import EmpiricalDataError
from host.learning.empirical.dynamic import lag_filter, signals
from host.learning.empirical.fitting import fit_model
from host.learning.empirical.forward import forward_blocks, phase_edges
from host.learning.empirical.targets import training_arrays

# (start s, rpm) of a 10 h schedule on the 60 s grid of make_direct: a short stop before the first start, a speed change
# while running (no edge), a 10 min stop (a phase under a quarter of the longest, 3 h: joins the one before it)
SCHEDULE = [(0, 0), (600, 1000), (4200, 2000), (6000, 0), (13200, 1500), (18000, 0), (18600, 3000), (25200, 0)]
# worked out by hand from SCHEDULE, not by the code under test
EDGES_S = [600, 6000, 13200, 18000, 18600, 25200]  # every start from standstill and every stop to standstill
# blocks after merging: 0-10 min joins the first running phase (nothing before it), 300-310 min joins 220-300 min
BLOCK_STARTS_S = [0, 6000, 13200, 18600, 25200]
BLOCK_ENDS_S = [5940, 13140, 18540, 25140, 35940]  # the last target time (60 s grid) before the next block


def _run(make_direct, spindle=True):
    run = make_direct(spindle=True, n_sensors=3, channels=("ch1",))
    t = run.temperatures.time_s
    rpm = np.zeros(t.size)
    for t0, speed in SCHEDULE:
        rpm[t >= t0] = speed
    run.spindle = Spindle(t.copy(), rpm)
    # ch1 = 3·lag(t1 rise, 1 h) + 2·lag(krpm, 30 min): something the dynamic model finds, on the schedule above
    ts, sig = signals(run, ["t1"])
    y = 3 * lag_filter(ts, sig["T:t1"], 3600) + 2 * lag_filter(ts, sig["spindle_krpm"], 1800)
    y = y + np.random.default_rng(1).normal(0, 0.02, ts.size)
    run.errors = Errors(ts.copy(), np.zeros(ts.size), y, None, np.array(["ch1"] * ts.size, dtype=object))
    if not spindle:
        run.spindle = None
    return run


def test_phase_blocks_cut_at_every_start_and_stop_of_the_spindle(make_direct):
    run = _run(make_direct)
    assert phase_edges(run) == EDGES_S
    arrays = training_arrays([run], "direct", "ch1")
    labels, blocks = forward_blocks([run], arrays, "phases")
    assert [b["t_start_s"] for b in blocks] == BLOCK_STARTS_S
    assert [b["t_end_s"] for b in blocks] == BLOCK_ENDS_S
    assert np.unique(labels).tolist() == list(range(len(BLOCK_STARTS_S)))
    # the default with a spindle log is the phases rule
    default_labels, default_blocks = forward_blocks([run], arrays)
    assert default_blocks == blocks and np.array_equal(default_labels, labels)
    # the cycles rule on the same run cuts at the starts only: 3 blocks
    _, cycle_blocks = forward_blocks([run], arrays, "cycles")
    assert [b["t_start_s"] for b in cycle_blocks] == [0, 13200, 18600]
    # through fit_model: the dynamic model's forward chaining is scored on those blocks (4 scored; filters running since the
    # run start, so the test stays fast: the blocks, not the observer, are under test)
    model = fit_model([run], "dynamic", target="direct", channel="ch1", taus_s=(0.0, 1800.0, 3600.0), forward_state="continuous",
                      forward_blocks="phases")
    fc = model.statistics["forward_chaining"]
    assert fc["blocks"] == 5
    assert [s["t_start_s"] for s in fc["scored"]] == BLOCK_STARTS_S[1:]


def test_bad_forward_blocks_values_are_refused_by_name(make_direct):
    run = _run(make_direct)
    arrays = training_arrays([run], "direct", "ch1")
    with pytest.raises(EmpiricalDataError, match='forward_blocks must be an integer >= 3, "phases" or "cycles", got \'phase\''):
        forward_blocks([run], arrays, "phase")
    assert parse_options(["forward_blocks=phases"], "dynamic") == {"forward_blocks": "phases"}
    assert parse_options(["forward_blocks=cycles"], "dynamic") == {"forward_blocks": "cycles"}
    assert parse_options(["forward_blocks=5"], "dynamic") == {"forward_blocks": 5}
    with pytest.raises(UserError, match="forward_blocks='phase': expected phases or cycles, or a number"):
        parse_options(["forward_blocks=phase"], "dynamic")


def test_phase_blocks_of_a_run_without_spindle_log_are_refused_naming_the_run(make_direct):
    run = _run(make_direct, spindle=False)
    arrays = training_arrays([run], "direct", "ch1")
    with pytest.raises(EmpiricalDataError, match='drun: forward_blocks="phases" .* no spindle.csv'):
        forward_blocks([run], arrays, "phases")
    with pytest.raises(EmpiricalDataError, match="dynamic: drun: .*no spindle.csv"):
        fit_model([run], "dynamic", target="direct", channel="ch1", taus_s=(0.0,), forward_blocks="phases")
    with pytest.raises(EmpiricalDataError, match='drun: forward_blocks="cycles" .* no spindle.csv'):
        forward_blocks([run], arrays, "cycles")
    # the default without a spindle log: 4 equal time blocks
    labels, _ = forward_blocks([run], arrays)
    assert np.unique(labels).tolist() == [0, 1, 2, 3]
