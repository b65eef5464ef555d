"""HIL fixtures: the device under test behind one fixture, on the rig or on a real port.

``--port /dev/ttyACM0`` runs the link-level scenarios against a real board
(already flashed, with a table); scenarios that need the rig's simulated
chips, clock or power switch are marked ``rig`` and skipped then. Every rig
scenario runs under MicroPython (unix port) and CPython (``interpreter`` parameter); some also on
the emulated Cortex-M3 board (``qemu``: ports/mps2 under qemu-system-arm).
"""
import os

import pytest

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
SLOW = bool(os.environ.get("TCOMP_SLOW"))


def pytest_addoption(parser):
    parser.addoption("--port", default=None, help="run the HIL scenarios against a real board on this serial port")
    parser.addoption("--baud", default=115200, type=int, help="baud rate of --port")
    parser.addoption("--key", default=None, help="the --port board's key file (tcomp flash --key), for the "
                                                 "scenarios that change its output")


def pytest_configure(config):
    config.addinivalue_line("markers", "rig: needs the simulated board (skipped with --port)")


def pytest_collection_modifyitems(config, items):
    if config.getoption("--port") is None:
        return
    skip = pytest.mark.skip(reason="needs the simulated rig (running against --port)")
    for item in items:
        if "rig" in item.keywords:
            item.add_marker(skip)


# "qemu" (the emulated board) is accepted where a scenario parametrizes it itself (it is slower:
# short scenarios there; docs/hil.md).
INTERPRETERS = ["micropython", "cpython"]


@pytest.fixture(params=INTERPRETERS)
def interpreter(request):
    """``micropython`` is the one TCOMP_MICROPYTHON chooses (hil_tests/rig/interpreters.py); missing, the test fails."""
    if request.param == "micropython":
        from hil_tests.rig import interpreters
        try:
            interpreters.get().require()
        except interpreters.InterpreterMissing as e:
            pytest.fail(str(e))
    if request.param == "qemu":
        import shutil
        from hil_tests.rig.harness import QEMU_IMAGE
        if shutil.which("qemu-system-arm") is None or not os.path.exists(QEMU_IMAGE):
            pytest.fail("QEMU board image missing (make setup installs qemu-system-arm and builds %s)" % QEMU_IMAGE)
    return request.param


@pytest.fixture(scope="session")
def demo_run():
    from host.data.runs import load_run
    return load_run(os.path.join(ROOT, "data", "demo", "mixed"))


@pytest.fixture
def make_rig(tmp_path, interpreter):
    """Factory: ``make_rig(config, table, **kw)`` -> a started Rig, closed after the test."""
    from hil_tests.rig.harness import Rig
    rigs = []

    def make(config, table=None, **kw):
        r = Rig(config, table, interpreter=interpreter, workdir=str(tmp_path / ("rig%d" % len(rigs))), **kw)
        rigs.append(r)
        return r.start()

    yield make
    for r in rigs:
        r.close()


@pytest.fixture
def dut(request, make_rig):
    """The device under test for link-level scenarios: the rig (default) or a real board (--port)."""
    port = request.config.getoption("--port")
    if port:
        if request.node.callspec.params.get("interpreter") == "cpython":
            pytest.skip("one run against the real port is enough")
        from hil_tests.rig.realport import RealDut
        kf = request.config.getoption("--key")
        if kf:
            from host.board.linkauth import read_key
        d = RealDut(port, request.config.getoption("--baud"), read_key(kf) if kf else None)
        yield d
        d.close()
        return
    from hil_tests.rig.boards import export, rig_config, poly_slope_for_run
    from host.data.runs import load_run
    run = load_run(os.path.join(ROOT, "data", "demo", "mixed"))
    sensors = ["T1", "T2", "T4"]
    table = export(poly_slope_for_run(run, sensors)).table
    temps = {s: float(run.temperatures.column(s)[0]) for s in sensors}
    yield make_rig(rig_config(sensors), table, temps=temps)
