"""Shared fixtures of the screw-model tests: bundled demo runs (data/demo/, made by
the twin) and runs from the model's own forward physics (host/learning/screw/synth.py)."""
import os
import warnings

import pytest

from host.data.runs import load_run
from host.learning.screw import synth
from host.learning.screw.identify import IdentifiabilityWarning
from host.learning.screw.screwmodel import ScrewModel

ROOT = os.path.dirname(os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__)))))
DEMO = os.path.join(ROOT, "data", "demo")
DEMO_FIT = "v8000_r210_490"


def demo_names():
    if not os.path.isdir(DEMO):
        return []
    return sorted(n for n in os.listdir(DEMO) if os.path.isfile(os.path.join(DEMO, n, "meta.json")))


@pytest.fixture(scope="session")
def demo_runs():
    names = demo_names()
    if DEMO_FIT not in names:
        pytest.skip("bundled demo runs (data/demo/%s) are not there" % DEMO_FIT)
    return {n: load_run(os.path.join(DEMO, n)) for n in names}


@pytest.fixture(scope="session")
def demo_model(demo_runs):
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", IdentifiabilityWarning)
        return ScrewModel(ambient=True).fit([demo_runs[DEMO_FIT]])


@pytest.fixture(scope="session")
def synth_run():
    return synth.make_run()


@pytest.fixture(scope="session")
def synth_model(synth_run):
    return ScrewModel(ambient=True).fit([synth_run])
