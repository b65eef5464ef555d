"""The ``tcomp`` console command: the verbs come from the registry in host.cli.verbs, imported lazily."""

from __future__ import annotations

from collections.abc import Sequence
import argparse
import importlib
import sys

from host.cli.verbs import VERBS
from host.errors import UserError, os_reason

# Top-level modules a verb may need that an install can lack -> what to install (pyproject.toml, README:
# the board-side install has no scientific stack; `tcomp[science]` adds it).
INSTALL_OF_MODULE = {
    "numpy": "tcomp[science]",
    "scipy": "tcomp[science]",
    "matplotlib": "tcomp[science]",
    "serial": "tcomp (its dependency pyserial)",
    "mpremote": "tcomp (its dependency mpremote)",
    "pymodbus": "tcomp (its dependency pymodbus)",
}


class MissingInstall(UserError):
    """A verb needs a module of an install (an extra) that is not there: names the module and what to install."""

    def __init__(self, module: str) -> None:
        super().__init__("this verb needs %s, which is not installed: pip install '%s'"
                         % (module, INSTALL_OF_MODULE[module]))


def _missing_install(exc):
    """The MissingInstall for a ModuleNotFoundError of one of INSTALL_OF_MODULE's modules, else None."""
    top = (exc.name or "").partition(".")[0]
    return MissingInstall(top) if top in INSTALL_OF_MODULE else None


def sensor_list(text: str | None, flag: str = "--sensors") -> list[str] | None:
    """Comma-separated names -> list, None when the flag was not given; an empty list is a UserError."""
    if text is None:
        return None
    names = [s.strip() for s in text.split(",") if s.strip()]
    if not names:
        raise UserError("%s %r: empty sensor list (give comma-separated names, or leave %s out for all)" % (flag, text, flag))
    return names


def _chosen_verb(argv):
    """The verb named on the command line (its first word not starting with '-'), or None."""
    for word in argv:
        if not word.startswith("-"):
            return word if word in VERBS else None
    return None


def build_parser(verb: str | None = None) -> argparse.ArgumentParser:
    """The ``tcomp`` parser; only ``verb``'s module is imported (for its arguments), the others stay unloaded."""
    parser = argparse.ArgumentParser(
        prog="tcomp",
        description="Thermal-error compensation for CNC feed axes: simulate, fit, export, run the firmware.",
    )
    sub = parser.add_subparsers(dest="verb", metavar="VERB")
    sub.required = True
    for name, (module_name, summary) in VERBS.items():
        p = sub.add_parser(name, help=summary, description=summary)
        if name == verb:
            try:  # the verb's module, and its arguments (some read tables of a room, e.g. simulate's effects)
                module = importlib.import_module(module_name)
                module.add_arguments(p)
            except ModuleNotFoundError as exc:
                missing = _missing_install(exc)
                if missing is None:
                    raise
                raise missing from exc
            p.set_defaults(_run=module.run)
    return parser


def main(argv: Sequence[str] | None = None) -> int:
    argv = sys.argv[1:] if argv is None else list(argv)
    verb = _chosen_verb(argv)
    try:
        parser = build_parser(verb)
    except MissingInstall as exc:
        print("tcomp %s: error: %s" % (verb, exc), file=sys.stderr)
        return 2
    args = parser.parse_args(argv)
    try:
        return int(args._run(args) or 0)
    except UserError as exc:
        print("tcomp %s: error: %s" % (args.verb, exc), file=sys.stderr)
        return 2
    except ModuleNotFoundError as exc:
        # a verb importing a missing extra's module inside run() (after its arguments parsed)
        missing = _missing_install(exc)
        if missing is None:
            raise
        print("tcomp %s: error: %s" % (args.verb, missing), file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        return 130
    except OSError as exc:
        # Safety net for file-system failures the verb did not anticipate (disk full, permissions):
        # one line naming the path, not a traceback. Verbs should still check their paths up front.
        if exc.filename is None:
            raise
        print("tcomp %s: error: %s: %s" % (args.verb, exc.filename, os_reason(exc)), file=sys.stderr)
        return 2


if __name__ == "__main__":
    sys.exit(main())
