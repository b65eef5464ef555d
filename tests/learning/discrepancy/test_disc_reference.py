"""tcomp discrepancy notices a wrong or missing error reference (issue 19 §2, §4) on effect-free twin runs."""
import json
import os

import pytest

from host.cli import main as tcomp
from host.data.runs import write_run
from host.twin import simulate_run

NOISE_UM = 0.5
STATES = ("v8000_r210_490", "v6500_r210_490", "v8000_r0_700")


@pytest.fixture(scope="module")
def null_runs(tmp_path_factory):
    """Effect-free runs of three moving states, written in each convention: {reference: [folders]}."""
    root = tmp_path_factory.mktemp("null")
    return {ref: [write_run(simulate_run(p, seed=5, noise_um=NOISE_UM, error_reference=ref), str(root / ref / p)) for p in STATES]
            for ref in ("start", "T3")}


def _declare(folders, reference, where):
    """Copies of ``folders`` whose meta.json declares ``reference`` (None: the key removed)."""
    import shutil

    out = []
    for f in folders:
        dst = os.path.join(where, os.path.basename(f))
        shutil.copytree(f, dst)
        path = os.path.join(dst, "meta.json")
        with open(path) as fh:
            meta = json.load(fh)
        meta.pop("error_reference", None)
        if reference is not None:
            meta["error_reference"] = reference
        with open(path, "w") as fh:
            json.dump(meta, fh)
        out.append(dst)
    return out


def _discrepancy(folders, tmp_path, capsys, report=False):
    """(JSON, stdout, report.md or None); the report (plots, final model fit) only where it is checked: it costs a minute."""
    js, rep = str(tmp_path / "d.json"), str(tmp_path / "report")
    assert tcomp(["discrepancy"] + folders + ["--json", js, "--jobs", "2"] + (["--report", rep] if report else [])) == 0
    out = capsys.readouterr().out
    with open(js) as fh:
        return json.load(fh), out, open(os.path.join(rep, "report.md")).read() if report else None


@pytest.mark.parametrize("reference", ["start", "T3"])
def test_declared_right_no_suggestion_no_effect_and_the_noise(null_runs, tmp_path, capsys, reference):
    js, out, md = _discrepancy(null_runs[reference], tmp_path, capsys)
    assert "error_reference_suggested" not in js
    assert js["effects"] == []
    assert js["rmse_before_um"] <= 1.25 * NOISE_UM, js["rmse_before_um"]
    check = js["error_reference_check"]
    assert check["declared"] == reference and set(check["heldout_rmse_um"]) >= {"start", "T3"}
    assert sum("error reference: held-out RMSE" in line for line in out.splitlines()) == 1 and "the declaration fits" in out


@pytest.mark.parametrize("made, declared", [("T3", None), ("start", "T3")])
def test_declared_wrong_both_ways_the_suggestion_is_right_and_no_effect_is_named(null_runs, tmp_path, capsys, made, declared):
    """Laser errors corrected to T3 but the key left out (declared "start"), and raw errors declared as T3."""
    folders = _declare(null_runs[made], declared, str(tmp_path))
    js, out, md = _discrepancy(folders, tmp_path, capsys, report=declared is None)
    assert js["error_reference_suggested"] == made
    assert js["effects"] == [] and not any(c["accepted"] for c in js["candidates"])
    rm = js["error_reference_check"]["heldout_rmse_um"]
    assert rm[made] <= 1.25 * NOISE_UM < rm[declared or "start"]
    line = [x for x in (md or out).splitlines() if "error reference: held-out RMSE" in x]
    assert len(line) == 1 and ("%.3f um" % rm[made]) in line[0] and ("%.3f um" % rm[declared or "start"]) in line[0]
    assert '"error_reference": "%s"' % made in line[0]
