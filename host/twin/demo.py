"""The bundled demo data set (data/demo/): the exact command that made it.

tests/twin checks that running ``tcomp`` with ``DEMO_ARGS`` again reproduces the committed files, and
docs/twin.md quotes ``DEMO_COMMAND``, so the data never drift from the code. (The twin does not call the
CLI itself: the CLI sits above it.)
"""
import os

DEMO_DIR = os.path.join("data", "demo")
DEMO_ARGS = ("--protocol", "literature,mixed", "--effects", "ambient_expansion", "--seed", "1")
DEMO_COMMAND = "tcomp simulate --out data/demo " + " ".join(DEMO_ARGS)

