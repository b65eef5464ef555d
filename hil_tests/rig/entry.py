"""What ``tcomp hil`` reaches of the rig, through the entry point group ``tcomp.rig`` (pyproject.toml).

host/cli/verbs/hil.py never imports hil_tests: it loads this module by the entry point ``hil`` with
importlib.metadata and uses only the names below (docs/hil.md, docs/architecture.md "Install and wheel").
"""
from hil_tests.rig.boards import rig_config
from hil_tests.rig.harness import Rig, RigError
from hil_tests.rig.play import play

__all__ = ["Rig", "RigError", "play", "rig_config"]
