"""The ``tcomp`` console command: the verbs come from the registry in host.cli.verbs, imported lazily."""
import argparse
import importlib
import sys

from host.cli.verbs import VERBS
from host.errors import UserError, os_reason


def sensor_list(text, flag="--sensors"):
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


def build_parser(verb=None):
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
            module = importlib.import_module(module_name)
            module.add_arguments(p)
            p.set_defaults(_run=module.run)
    return parser


def main(argv=None):
    argv = sys.argv[1:] if argv is None else list(argv)
    parser = build_parser(_chosen_verb(argv))
    args = parser.parse_args(argv)
    try:
        return int(args._run(args) or 0)
    except UserError as exc:
        print("tcomp %s: error: %s" % (args.verb, exc), file=sys.stderr)
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
