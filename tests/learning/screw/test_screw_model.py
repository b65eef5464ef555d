"""The fitted model: document contract, CLI, prediction, validation on unseen states,
the reduced firmware recurrence, the effect extension point."""
import json
import os

import numpy as np
import pytest

from host.cli import main as tcomp
from host.learning.documents import ModelFormatError, load_model, read_document
from host.data.runs import write_run
from host.learning.screw import synth
from host.learning.screw.effects import BearingHeat, Effect, ParamSpec, ReversalEffect
from host.learning.screw.screwmodel import ScrewModel
from host.learning.screw.reduced import build_reduced, reduction_error, state_bound
from host.learning.screw.crossstate import fit_models, state_errors, summary

DEMO_FIT = "v8000_r210_490"  # the fitting state of the literature's protocol (tests/learning/screw/conftest.py loads it)


def test_document_round_trip_and_reduced_contract(synth_model, synth_run):
    doc = synth_model.to_document()
    json.dumps(doc)  # plain JSON types only
    assert doc["kind"] == "screw" and doc["geometric"]["degree"] <= 4
    red = doc["thermal"]["reduced"]
    M = red["segments"]
    assert 8 <= M <= 16
    assert np.shape(red["A"]) == (M, M) and len(red["B_K_per_mm"]) == M and len(red["edges_mm"]) == M + 1
    assert red["edges_mm"][0] == 0 and np.all(np.diff(red["edges_mm"]) > 0)
    assert np.min(red["A"]) >= 0 and np.max(np.sum(red["A"], axis=1)) < 1
    assert red["alpha_um_per_mm_per_K"] == pytest.approx(1e3 * synth_model.params_.alpha_per_K)
    again = ScrewModel.from_document(doc)
    np.testing.assert_allclose(again.predict(synth_run), synth_model.predict(synth_run), atol=1e-9)


def test_a_fixed_reference_document_without_its_base_reference_is_refused_at_load():
    # base_ref "fixed" reads E_e's reference from thermal.base_ref_C: without it the model predicted None - a float
    # (a TypeError at predict); it is refused by name when the document is read, as a missing air_ref_C is
    run = synth.make_run(heat_s=3600.0, cool_s=600.0, sweep_every_s=600.0)
    doc = ScrewModel(ambient=True, base_ref="fixed", free="q").fit([run], reduce=False).to_document()
    assert doc["thermal"]["base_sensor"] is not None and doc["thermal"]["base_ref"] == "fixed"
    del doc["thermal"]["base_ref_C"]
    with pytest.raises(ModelFormatError, match="thermal.base_ref_C"):
        ScrewModel.from_document(doc)


def test_error_is_zero_at_the_fixed_end(synth_model, synth_run):
    t, E = synth_model.predict_grid(synth_run, [0.0, 350.0, 700.0])
    geo = synth_model.geometric_um(np.array([0.0, 350.0, 700.0]))
    np.testing.assert_allclose(E[:, 0] - geo[0], 0.0, atol=1e-12)
    assert np.max(E[:, 2] - geo[2]) > 10.0


def test_cli_fit_and_predict(tmp_path):
    runs = []
    for i, (f, lo, hi) in enumerate([(8000, 210, 490), (12000, 0, 700)]):
        runs.append(write_run(synth.make_run(f, lo, hi, heat_s=7200.0, cool_s=3600.0, noise_um=0.2, seed=i), str(tmp_path / ("r%d" % i))))
    out, rep = str(tmp_path / "m.json"), str(tmp_path / "fit.json")
    assert tcomp(["fit", "--model", "screw", runs[0], "--out", out, "--json", rep, "--option", "reduced_segments=10", "--option", "ambient=on",
                  "--option", "fit_window=:7200"]) == 0
    doc = read_document(out)
    assert doc["kind"] == "screw" and doc["thermal"]["reduced"]["segments"] == 10
    assert doc["training"]["fit_window_s"] == [None, 7200.0]
    assert doc["provenance"]["sha256"]
    assert json.load(open(rep))["statistics"]["runs"][0]["rmse_um"] < 0.4
    pred = str(tmp_path / "p.csv")
    assert tcomp(["predict", out, runs[1], "--out", pred, "--json", str(tmp_path / "p.json")]) == 0
    assert json.load(open(tmp_path / "p.json"))["rmse_um"] < 0.5
    assert len(open(pred).read().splitlines()) == 1 + len(load_model(out).predict(synth.make_run(12000, 0, 700, heat_s=7200.0, cool_s=3600.0)))


def test_cli_bad_input_is_a_user_error(tmp_path, capsys):
    run = synth.make_run(heat_s=3600.0, cool_s=600.0)
    meta = dict(run.meta, screw=dict(run.meta["screw"], length_mm=500))
    run.meta = meta
    folder = write_run(run, str(tmp_path / "short"))
    assert tcomp(["fit", "--model", "screw", folder, "--out", str(tmp_path / "m.json")]) == 2
    assert "shorter than the stroke" in capsys.readouterr().err
    os.remove(os.path.join(folder, "motion.csv"))
    assert tcomp(["fit", "--model", "screw", folder, "--out", str(tmp_path / "m.json")]) == 2
    assert "no motion" in capsys.readouterr().err
    assert tcomp(["fit", "--model", "screw", folder, "--out", str(tmp_path / "m.json"), "--option", "segmnts=3"]) == 2
    assert "segments" in capsys.readouterr().err
    assert tcomp(["fit", "--model", "screw", folder, "--out", str(tmp_path / "m.json"), "--option", "fit_window=100"]) == 2
    assert "LO:HI" in capsys.readouterr().err


def test_screw_beats_mlr_on_unseen_states_of_the_bundled_runs(demo_runs):
    fit_run = demo_runs[DEMO_FIT]
    others = [demo_runs[n] for n in ("v15000_r210_490", "v8000_r0_210", "mixed") if n in demo_runs]
    models = fit_models(fit_run)
    rows = state_errors(models, fit_run, others)
    s = summary(rows)
    screw = s["screw (base sensor + motion)"]
    for name, v in s.items():
        if name.startswith("MLR"):
            assert screw["mean_unseen_rmse_um"] < 0.5 * v["mean_unseen_rmse_um"], (name, s)
    for r in rows:
        if r["seen"] or not r["model"].startswith("screw"):
            continue
        mlr = [x["rmse_um"] for x in rows if x["state"] == r["state"] and x["model"].startswith("MLR")]
        if "cool-down" in r["state"]:
            # same range as the fit: the 5-sensor MLR is on par here (docs/screw-model.md);
            # the screw model must stay at the laser-noise level (0.5 um in the demo runs)
            assert r["rmse_um"] < 1.0, r
        else:  # every other moving state on its own
            assert r["rmse_um"] < 0.5 * min(mlr), r["state"]


def test_screw_beats_mlr_on_synthetic_unseen_states():
    fit_run = synth.make_run(noise_um=0.3, seed=5)
    others = [synth.make_run(12000, 0, 210, noise_um=0.3, seed=6)]
    s = summary(state_errors(fit_models(fit_run), fit_run, others))
    assert s["screw (base sensor + motion)"]["mean_unseen_rmse_um"] < min(v["mean_unseen_rmse_um"] for k, v in s.items() if k.startswith("MLR"))


@pytest.mark.parametrize("spread", [False, True], ids=["position-reports", "feed-range-state"])
def test_reduction_error_on_bundled_runs_below_half_a_micron(demo_model, demo_runs, spread):
    for name, run in demo_runs.items():
        e = reduction_error(demo_model, run, spread=spread)
        assert e["rms_um"] < 0.5, (name, e)
        assert e["full_max_um"] > 10.0  # the comparison is over a real thermal error


def test_state_bound_holds_for_adversarial_travel(synth_model):
    red = synth_model.reduced_
    A, B = np.asarray(red["A"]), np.asarray(red["B_K_per_mm"])
    U = red["feed_max_mm_min"] / 60.0 * red["dt_s"]
    assert red["state_max_K"] == pytest.approx(state_bound(A, B, U))
    rng = np.random.default_rng(0)
    M = B.size
    worst = 0.0
    for pattern in ("one", "spread", "random"):
        T = np.zeros(M)
        for k in range(20000):
            if pattern == "one":
                u = np.zeros(M)
                u[M // 2] = U
            elif pattern == "spread":
                u = np.full(M, U / M)
            else:
                u = rng.dirichlet(np.ones(M)) * U * rng.uniform()
            T = A @ T + B * u
            worst = max(worst, T.max())
    assert worst <= red["state_max_K"]
    assert worst >= 0.5 * red["state_max_K"]  # the bound is not absurdly loose


def test_reduced_segments_and_step_are_settings(synth_model):
    r8 = build_reduced(synth_model, 8, 30.0)
    assert r8["segments"] == 8 and r8["dt_s"] == 30.0 and len(r8["edges_mm"]) == 9
    with pytest.raises(ValueError, match="reduced segments"):
        build_reduced(synth_model, 0)


class _ConstantHeat(Effect):
    """A test effect: constant power into the last segment."""

    name = "constant_tail_heat"

    def parameters(self):
        return [ParamSpec("W", 1.0, 0.0, 10.0, "W", positive=False)]

    def heat_W(self, ctx, p):
        out = np.zeros((ctx.n_steps, ctx.M))
        out[:, -1] = p["W"]
        return out


def test_reversal_effect_output_hook():
    run = synth.make_run(heat_s=3600.0, cool_s=600.0, sweep_every_s=600.0)
    n = len(run.errors)
    run.errors.direction = np.where(np.arange(n) % 2 == 0, 1, -1).astype(np.int8)
    run.errors.error_um = run.errors.error_um + 0.5 * 3.0 * run.errors.direction
    m = ScrewModel(ambient=True, free="q", geometric_degree=2, effects=[ReversalEffect()]).fit([run])
    assert m.values_["reversal_error.b_um"] == pytest.approx(3.0, abs=0.05)


def test_effects_plug_in_parameters_and_hooks(synth_run):
    run = synth.make_run(heat_s=5400.0, cool_s=1800.0, sweep_every_s=600.0)
    base = ScrewModel(ambient=True, free="q,h", geometric_degree=2).fit([run])
    m = ScrewModel(ambient=True, free="q,h", geometric_degree=2, effects=[BearingHeat()]).fit([run])
    assert "bearing_heat.W_per_m_min" in m.free_
    assert abs(m.values_["bearing_heat.W_per_m_min"]) < 0.05  # data made without bearing heat
    assert m.values_["q_J_per_mm"] == pytest.approx(base.values_["q_J_per_mm"], rel=0.02)
    doc = m.to_document()
    assert [e["name"] for e in doc["thermal"]["effects"]] == ["bearing_heat"]
    # the effect's reduced form (effects.py reduce): heat per mm of travel into the fixed-end segment
    red = doc["thermal"]["reduced"]
    assert "omitted_effects" not in red and red["travel_heat_K_per_mm"][1:] == [0.0] * (red["segments"] - 1)
    assert ScrewModel.from_document(doc).effects[0].name == "bearing_heat"
    # a user-defined effect changes the simulation through its hook
    m.effects = [_ConstantHeat()]
    m.values_ = dict(base.values_, **{"constant_tail_heat.W": 2.0})
    m.params_, m.effect_params_ = m._split(m.values_)
    ctx = m._context(run)
    tail = m.simulate_context(ctx)[-1]
    base_tail = base.simulate_context(base._context(run))[-1]
    assert tail[-1] > base_tail[-1] + 1.0


def test_an_effect_without_a_reduced_form_is_omitted_from_the_reduced_block_not_a_crash():
    # Effect.reduce raises NoReducedForm: fit used to fail with AttributeError ('_ConstantHeat' has no 'reduce')
    run = synth.make_run(heat_s=3600.0, cool_s=600.0, sweep_every_s=600.0)
    m = ScrewModel(ambient=True, free="q", geometric_degree=2, effects=[_ConstantHeat()]).fit([run])
    red = m.reduced_form()
    assert red["omitted_effects"] == ["constant_tail_heat"]
    assert "defines no reduce()" in red["omitted_reasons"]["constant_tail_heat"]


def test_effect_checks_and_ambient_expansion_equals_the_base_term():
    run = synth.make_run(heat_s=3600.0, cool_s=1800.0, sweep_every_s=600.0)
    with pytest.raises(ValueError, match="reversal_error needs bidirectional sweeps"):
        ScrewModel(ambient=True, free="q", effects=[ReversalEffect()]).fit([run])
    from host.learning.screw.effects import AmbientExpansion

    m = ScrewModel(free="q,h,lambda", geometric_degree=2, ambient=False, effects=[AmbientExpansion()]).fit([run])
    assert m.values_["ambient_expansion.um_per_m_K"] == pytest.approx(1e6 * synth.TRUE.alpha_per_K, rel=0.02)


def test_validation_script_writes_table_json_and_plot(tmp_path):
    short = dict(heat_s=5400.0, cool_s=2700.0, sweep_every_s=450.0, noise_um=0.3)
    fit = write_run(synth.make_run(8000, 210, 490, seed=1, **short), str(tmp_path / "fit"))
    other = write_run(synth.make_run(12000, 0, 700, seed=2, **short), str(tmp_path / "other"))
    from host.learning.screw.crossstate import main

    out = tmp_path / "val"
    assert main([fit, other, "--out", str(out)]) == 0
    md = (out / "validation.md").read_text()
    assert "fit heating (fitted)" in md and "fit cool-down" in md and "| other |" in md
    rep = json.loads((out / "validation.json").read_text())
    assert {r["model"] for r in rep["rows"]} >= {"screw (base sensor + motion)", "MLR slope (nut+base)"}
    assert (out / "validation.png").stat().st_size > 10000


def _with_roles(run, **new_roles):
    """The run with some sensors' roles changed in meta.json (the columns stay)."""
    sensors = {k: dict(v) for k, v in run.meta["sensors"].items()}
    for name, role in new_roles.items():
        sensors[name]["role"] = role
    run.meta = dict(run.meta, sensors=sensors)
    return run


def test_air_falls_back_to_the_base_sensor_then_to_a_constant_air_and_says_so():
    # docs/screw-model.md: no 'ambient' sensor -> the first 'base' sensor, else a constant air; each fallback
    # is a warning in statistics.warnings and thermal.air_source records the choice
    import warnings as _w

    from host.learning.screw.identify import IdentifiabilityWarning
    from host.twin import simulate_run

    run = simulate_run("v8000_r210_490", seed=5, noise_um=0.3)
    ambient, base = run.sensors_with_role("ambient"), run.sensors_with_role("base")
    no_air = {n: "structure" for n in ambient}
    cases = [({}, ambient[0], "role ambient", None),
             (no_air, base[0], "base sensor (fallback)", "no sensor with role 'ambient'"),
             (dict(no_air, **{n: "structure" for n in base}), None, "constant (no ambient or base sensor)",
              "the air is taken as constant")]
    for roles, sensor, source, warning in cases:
        r = _with_roles(simulate_run("v8000_r210_490", seed=5, noise_um=0.3), **roles)
        with _w.catch_warnings():
            _w.simplefilter("ignore", IdentifiabilityWarning)
            m = ScrewModel(ambient=True, segments=12, dt_s=30.0).fit([r])
        doc = m.to_document()
        assert (m.air_sensor_, m.air_source_, doc["thermal"]["air_source"]) == (sensor, source, source), roles
        notes = " ".join(m.statistics_["warnings"])
        assert (warning in notes) if warning else "role 'ambient'" not in notes, notes


def test_effect_classes_are_not_named_as_exceptions():
    """An effect is a term of the model, not an error raised: no effect class reads as an exception (issue 20's
    'ReversalEffect'), while the names users type (--option effects=, the document, the CLI) stay as they were."""
    import inspect
    from host.learning.screw import effects

    named_error = [name for name, cls in inspect.getmembers(effects, inspect.isclass)
                   if issubclass(cls, Effect) and name.endswith("Error")]
    assert named_error == []
    assert effects.EFFECTS["reversal_error"] is ReversalEffect
