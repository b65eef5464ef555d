"""The ``tcomp`` console command: the verbs come from the registry in host.commands, imported lazily."""
import argparse
import importlib
import sys

from host.commands import VERBS


class UserError(Exception):
    """A problem with the user's input (file, flag, data): printed without a traceback."""


def _reason(exc):
    return exc.strerror or str(exc)


def check_output(path, flag="--out"):
    """Raise UserError unless ``path`` can be created as a file; call it before long work starts."""
    import os

    if os.path.isdir(path):
        raise UserError("%s %s: is a folder, expected a file path" % (flag, path))
    parent = os.path.dirname(os.path.abspath(path))
    if not os.path.isdir(parent):
        raise UserError("%s %s: folder %s does not exist" % (flag, path, parent))
    if not os.access(parent, os.W_OK | os.X_OK) or (os.path.exists(path) and not os.access(path, os.W_OK)):
        raise UserError("%s %s: not writable" % (flag, path))


def check_output_dir(path, flag="--out"):
    """Raise UserError unless ``path`` is, or can be created as, a folder (parents included)."""
    import os

    if os.path.exists(path) and not os.path.isdir(path):
        raise UserError("%s %s: exists and is not a folder" % (flag, path))
    probe = os.path.abspath(path)
    while not os.path.exists(probe):
        probe = os.path.dirname(probe)
    if not os.path.isdir(probe):
        raise UserError("%s %s: %s is a file, not a folder" % (flag, path, probe))
    if not os.access(probe, os.W_OK | os.X_OK):
        raise UserError("%s %s: %s is not writable" % (flag, path, probe))


def sensor_list(text, flag="--sensors"):
    """Comma-separated names -> list, None when the flag was not given; an empty list is a UserError."""
    if text is None:
        return None
    names = [s.strip() for s in text.split(",") if s.strip()]
    if not names:
        raise UserError("%s %r: empty sensor list (give comma-separated names, or leave %s out for all)" % (flag, text, flag))
    return names


def open_output(path, mode="w", **kwargs):
    """``open(path, mode)`` for an output file; an OSError becomes "cannot write PATH: reason"."""
    if "b" not in mode:
        kwargs.setdefault("encoding", "utf-8")
    try:
        return open(path, mode, **kwargs)
    except OSError as exc:
        raise UserError("cannot write %s: %s" % (path, _reason(exc)))


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
        print("tcomp %s: error: %s: %s" % (args.verb, exc.filename, _reason(exc)), file=sys.stderr)
        return 2


if __name__ == "__main__":
    sys.exit(main())
