"""Every screw-model effect reaches the board through its reduced form, or the export refuses naming it (issue 19 §3).

A screw model with the effect is fitted on a run of the independent twin (host/twin) with that effect hidden,
exported, and the run is played through the firmware's integer evaluator as the board's cycle drives it
(hil_tests/fixtures/boardplay.py: the feed/range state, latched start). The board must equal the host model
within the certificate: the integer arithmetic (certified) plus the reduction to the firmware's form (measured
on the training run, thermal.reduced.reduction_error_um, feed/range mode) plus the 1 mK rounding of the
temperatures the board reads. hil_tests/test_hil_effects.py does the same on the rig's MicroPython.
"""
import json
import warnings

import numpy as np
import pytest

from hil_tests.fixtures.boardplay import board_offsets, direction_split
from host.learning.screw.effects import make_effect
from host.learning.screw.screwmodel import ScrewModel
from host.twin import EFFECTS as TWIN_EFFECTS
from host.twin import simulate_run
from models_export import ExportError, export_model

RUN = "mixed"  # several feeds, bidirectional sweeps
CARRIED = ["bearing_heat", "ambient_expansion", "reversal_error", "ambient_expansion+bearing_heat", "speed_dependent_heat",
           "moving_convection", "moving_convection+speed_dependent_heat"]
# parameter values whose reduced form the firmware cannot carry (the effect's reduce refuses): a friction heat factor
# 1 + k(v/v_ref - 1) negative at rest (k > 1), and an extra convection loss per step above the state's own weight A_ii
UNREDUCIBLE = {"speed_dependent_heat": ({"speed_dependent_heat.k": 1.4}, None),
               "moving_convection": ({"moving_convection.k": 20.0}, 1.0e6)}
_CACHE = {}


def fitted(names, seed=19):
    """(run, model, document) for the effects ``names`` hidden in the twin and fitted by the screw model."""
    key = (names, seed)
    if key not in _CACHE:
        effects = names.split("+")
        run = simulate_run(RUN, effects={n: TWIN_EFFECTS[n].default for n in effects}, seed=seed, noise_um=0.5)
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            model = ScrewModel(segments=20, dt_s=20.0, ambient=False, geometric_degree=3,
                               effects=[make_effect(n) for n in effects]).fit([run])
        _CACHE[key] = (run, model, json.loads(json.dumps(model.to_document())))
    return _CACHE[key]


def bound_um(ex, doc, run, positions_mm):
    """Certificate (integer) + the reduction in the feed/range mode on this run + 1 mK temperature rounding."""
    red = doc["thermal"]["reduced"]
    fr = red["reduction_error_um"][run.name]["feed_range"]
    per_K = abs(red.get("ee_um_per_mm_per_K", 0.0)) + abs(red["alpha_um_per_mm_per_K"])
    return ex.report["max_error_um"] + fr["rows_max_um"] + per_K * 0.0005 * np.abs(positions_mm) + 0.01


@pytest.mark.parametrize("names", CARRIED)
def test_every_effect_with_a_reduced_form_reaches_the_board(names):
    run, model, doc = fitted(names)
    red = doc["thermal"]["reduced"]
    assert "omitted_effects" not in red
    ex = export_model(doc)
    rep = ex.report
    assert rep["table_format"] == 8
    assert rep["reduction"]["rms_um"] <= 0.5 and rep["reduction"]["omitted_effects"] == []
    assert rep["total_max_error_um"] == pytest.approx(rep["max_error_um"] + rep["reduction"]["max_um"])
    board = board_offsets(ex.table, run)
    host = model.predict(run)
    err = np.abs(board - host)
    bound = bound_um(ex, doc, run, run.errors.position_mm)
    worst = int(np.argmax(err - bound))
    assert np.all(err <= bound), "t=%.0f s P=%.0f mm: board %.3f um, host %.3f um, bound %.3f um" % (
        run.errors.time_s[worst], run.errors.position_mm[worst], board[worst], host[worst], bound[worst])
    if names != "reversal_error":  # (the feed/range mode has no direction: its bound holds the reversal term)
        # the effect is really in the output: the host model without it is far from the board
        assert np.max(np.abs(host - _without_effects(model, run))) > 5 * np.max(bound)
    if "reversal_error" in names:
        # position reports ending in + and in -: the board's difference is the host's b (+b/2 vs -b/2)
        t = float(run.errors.time_s[len(run.errors) // 2])
        up, down = direction_split(ex.table, run, t, 400.0)
        b = model.values_["reversal_error.b_um"]
        assert abs(b) > 1.0
        assert abs((up - down) - b) <= 2 * rep["max_error_um"] + 0.02


def _without_effects(model, run):
    """The same fitted model with its effects' parameters at zero (what a table without them predicts)."""
    saved = dict(model.values_)
    try:
        for k in model.values_:
            if "." in k:
                model.values_[k] = 0.0
        model.params_, model.effect_params_ = model._split(model.values_)
        return model.predict(run)
    finally:
        model.values_ = saved
        model.params_, model.effect_params_ = model._split(saved)


@pytest.mark.parametrize("names", ["bearing_heat", "ambient_expansion", "speed_dependent_heat", "moving_convection"])
def test_a_table_without_the_effect_term_leaves_the_bound(names):
    """The negative control: the effect's reduced form removed from the same document, the board misses."""
    run, model, doc = fitted(names)
    d = json.loads(json.dumps(doc))
    red = d["thermal"]["reduced"]
    if names == "bearing_heat":
        red["travel_heat_K_per_mm"] = [0.0] * red["segments"]
    elif names == "speed_dependent_heat":
        del red["heat_scale0"], red["heat_scale_per_mm"]
    elif names == "moving_convection":
        del red["convection_per_mm"]
    else:
        red["ee_um_per_mm_per_K"] = 0.0
    d.pop("provenance", None)
    ex = export_model(d)
    err = np.abs(board_offsets(ex.table, run) - model.predict(run))
    assert np.max(err - bound_um(ex, doc, run, run.errors.position_mm)) > 5.0


def unreducible(name):
    """(run, model, document) of the fitted model with the effect's parameter moved where its reduced form is refused
    (UNREDUCIBLE), the reduced block and its reduction certificate rebuilt as the fit builds them."""
    from host.learning.screw.reduced import build_reduced, reduction_certificate
    run, model, _ = fitted(name)
    values, feed_max = UNREDUCIBLE[name]
    saved = (dict(model.values_), model.reduced_)
    try:
        model.values_.update(values)
        model.params_, model.effect_params_ = model._split(model.values_)
        model.reduced_ = build_reduced(model, model.reduced_segments, model.reduced_dt_s,
                                       feed_max_mm_min=feed_max or model.reduced_["feed_max_mm_min"])
        model.reduced_["reduction_error_um"] = reduction_certificate(model, [run])
        doc = json.loads(json.dumps(model.to_document()))
        host = model.predict(run)
    finally:
        model.values_, model.reduced_ = saved
        model.params_, model.effect_params_ = model._split(model.values_)
    return run, host, doc


@pytest.mark.parametrize("name", sorted(UNREDUCIBLE))
def test_an_effect_without_a_reduced_form_is_refused_by_name(name):
    run, host, doc = unreducible(name)
    red = doc["thermal"]["reduced"]
    assert red["omitted_effects"] == [name] and name in red["omitted_reasons"]
    with pytest.raises(ExportError) as exc:
        export_model(doc)
    msg = str(exc.value)
    assert name in msg and "um RMS" in msg and "--reduction-limit" in msg and run.name in msg
    if name == "moving_convection":
        # the top feed at which the explicit convection step stops being a convex combination (D_i·umax > A_ii) is
        # beyond the travel per step a table holds: that refusal comes first
        with pytest.raises(ExportError, match="travel per step too large"):
            export_model(doc, reduction_limit_um=1000.0)
        return
    # the refusal is right: with the limit raised the board leaves the host model by micrometres
    ex = export_model(doc, reduction_limit_um=1000.0)
    assert ex.report["reduction"]["omitted_effects"] == [name]
    err = np.abs(board_offsets(ex.table, run) - host)
    assert np.max(err) > 2.0 and np.max(err) <= ex.report["max_error_um"] + \
        red["reduction_error_um"][run.name]["feed_range"]["rows_max_um"] + 0.1


@pytest.mark.parametrize("field, value, message", [
    ("convection_per_mm", 1.0, "convection_per_mm\\[0\\]: the extra loss per step at the top feed"),
    ("heat_scale0", -0.2, "friction heat factor is negative"),
])
def test_the_exporter_refuses_a_speed_term_it_cannot_certify(field, value, message):
    """A document whose convection weight exceeds A_ii at the top feed, or whose friction heat factor is negative,
    has no certified state bound: refused naming the field."""
    name = "moving_convection" if field == "convection_per_mm" else "speed_dependent_heat"
    _, _, doc = fitted(name)
    d = json.loads(json.dumps(doc))
    red = d["thermal"]["reduced"]
    red[field] = [value] * red["segments"] if field == "convection_per_mm" else value
    d.pop("provenance", None)
    with pytest.raises(ExportError, match=message):
        export_model(d)


def test_reduction_error_is_required_of_a_fitted_document_and_not_of_a_reduced_one():
    import random

    from hil_tests.fixtures.samples import screw_doc
    _, _, doc = fitted("bearing_heat")
    d = json.loads(json.dumps(doc))
    del d["thermal"]["reduced"]["reduction_error_um"]
    with pytest.raises(ExportError, match="reduction_error_um is missing"):
        export_model(d)
    rep = export_model(screw_doc(random.Random(4))).report  # the recurrence alone: it is its own full model
    assert rep["reduction"]["rms_um"] == 0.0 and "reduced form only" in rep["reduction"]["status"]


def test_cli_reduction_limit(tmp_path, capsys):
    from host.cli import main
    _, _, doc = unreducible("speed_dependent_heat")
    from host.learning.documents import save_model
    path = tmp_path / "model.json"
    save_model(doc, str(path))
    out = str(tmp_path / "t.bin")
    assert main(["export", str(path), "--out", out]) == 2
    assert "speed_dependent_heat" in capsys.readouterr().err
    assert main(["export", str(path), "--out", out, "--reduction-limit", "-1"]) == 2
    assert "--reduction-limit" in capsys.readouterr().err
    assert main(["export", str(path), "--out", out, "--reduction-limit", "1000", "--json", str(tmp_path / "r.json")]) == 0
    rep = json.loads((tmp_path / "r.json").read_text())
    assert rep["reduction"]["limit_um"] == 1000.0 and rep["reduction"]["omitted_effects"] == ["speed_dependent_heat"]
    assert "left out: speed_dependent_heat" in capsys.readouterr().out
