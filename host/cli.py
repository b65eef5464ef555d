"""The ``tcomp`` console command: discovers one verb per module in host.commands."""
import argparse
import importlib
import pkgutil
import sys

from host import commands as _commands


class UserError(Exception):
    """A problem with the user's input (file, flag, data): printed without a traceback."""


def _verbs():
    names = sorted(m.name for m in pkgutil.iter_modules(_commands.__path__) if not m.name.startswith("_"))
    return {name.rstrip("_").replace("_", "-"): importlib.import_module("host.commands." + name) for name in names}


def build_parser():
    parser = argparse.ArgumentParser(
        prog="tcomp",
        description="Thermal-error compensation for CNC feed axes: simulate, fit, export, run the firmware.",
    )
    sub = parser.add_subparsers(dest="verb", metavar="VERB")
    sub.required = True
    for verb, module in _verbs().items():
        p = sub.add_parser(verb, help=module.HELP, description=module.HELP)
        module.add_arguments(p)
        p.set_defaults(_run=module.run)
    return parser


def main(argv=None):
    parser = build_parser()
    args = parser.parse_args(argv)
    try:
        return int(args._run(args) or 0)
    except UserError as exc:
        print("tcomp %s: error: %s" % (args.verb, exc), file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        return 130


if __name__ == "__main__":
    sys.exit(main())
