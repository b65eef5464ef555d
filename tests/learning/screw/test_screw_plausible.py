"""Identified screw parameters outside what a screw's steel can have are flagged, with the accepted range."""
import os

import pytest

from host.data.runs import load_run
from host.learning.screw.screwmodel import ScrewModel, implausible_parameters

ROOT = os.path.dirname(os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__)))))
RUN = os.path.join(ROOT, "data", "demo", "v8000_r210_490")


def test_the_issues_values_are_flagged_with_the_steel_range():
    # the fit issue 22 reports: lambda 286 W/(m K), alpha 6.5e-6 /K; h is no material property
    flagged = implausible_parameters({"lambda_W_mK": 286.0, "alpha_per_K": 6.5e-6, "h_W_m2K": 300.0, "q_J_per_mm": 0.03})
    by = {f["parameter"]: f for f in flagged}
    assert set(by) == {"lambda_W_mK", "alpha_per_K"}
    assert by["lambda_W_mK"]["accepted"] == [20.0, 60.0] and "20..60 W/(m K)" in by["lambda_W_mK"]["warning"]
    assert by["alpha_per_K"]["accepted"] == [10e-6, 13e-6] and "nominal 1.15e-05" in by["alpha_per_K"]["warning"]
    assert implausible_parameters({"lambda_W_mK": 46.0, "alpha_per_K": 11.5e-6, "c_J_kgK": 460.0}) == []


@pytest.mark.filterwarnings("ignore::host.learning.screw.identify.IdentifiabilityWarning")
def test_a_fit_whose_alpha_absorbs_a_tripled_error_is_flagged():
    run = load_run(RUN)
    plain = ScrewModel().fit([run])  # the default free set q, h, lambda: lambda ~54 W/(m K) on this run
    assert plain.statistics_["implausible"] == []
    run.errors.error_um = run.errors.error_um * 3.0  # three times the expansion a steel screw can give
    tripled = ScrewModel(free="q,h,lambda,alpha").fit([run])
    (flag,) = tripled.statistics_["implausible"]
    assert flag["parameter"] == "alpha_per_K" and flag["value"] > 13e-6
    assert flag["warning"] in tripled.statistics_["warnings"]
    assert tripled.to_document()["statistics"]["implausible"][0]["parameter"] == "alpha_per_K"
