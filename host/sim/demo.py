"""The bundled demo data set (data/demo/): the exact command that made it.

tests/sim checks that running it again reproduces the committed files, and
docs/twin.md quotes ``DEMO_COMMAND``, so the data never drift from the code.
"""
import os

DEMO_DIR = os.path.join("data", "demo")
DEMO_ARGS = ("--protocol", "literature,mixed", "--effects", "ambient_expansion", "--seed", "1")
DEMO_COMMAND = "tcomp simulate --out data/demo " + " ".join(DEMO_ARGS)


def regenerate(out):
    """Write the demo runs into ``out`` (a folder per protocol); returns the CLI exit status."""
    from host.cli import main

    return main(["simulate", "--out", os.fspath(out)] + list(DEMO_ARGS))
