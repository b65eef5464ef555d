"""`python tools/monitor.py ...` = `tcomp monitor ...` (for a checkout without the console script installed)."""
import os
import sys

sys.path.insert(0, os.path.dirname(os.path.dirname(os.path.abspath(__file__))))

from host.cli import main

if __name__ == "__main__":
    sys.exit(main(["monitor"] + sys.argv[1:]))
