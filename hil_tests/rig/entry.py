"""What the ``tcomp`` verbs reach of the rig, through the entry point group ``tcomp.rig`` (pyproject.toml).

host/cli/verbs/hil.py and host/cli/verbs/board.py never import hil_tests: they load this module by the
entry point ``hil`` with importlib.metadata and use only the names below (docs/hil.md,
docs/architecture.md "Install and wheel"). ``tcomp hil``: ``Rig``, ``RigError``, ``play``, ``rig_config``;
``tcomp board``: ``LiveBoard``, ``board_problem``, ``rig_config``, ``RigError``.
"""
from hil_tests.rig.boards import rig_config
from hil_tests.rig.harness import Rig, RigError
from hil_tests.rig.liveboard import LiveBoard, board_problem
from hil_tests.rig.play import play

__all__ = ["LiveBoard", "Rig", "RigError", "board_problem", "play", "rig_config"]
