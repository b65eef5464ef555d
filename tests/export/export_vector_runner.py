"""Run evaluation vectors; the same file runs under CPython (imported by the tests) and MicroPython.

A case is a table (hex) and a list of operations:
  ["t", [milli-degC, ...]]  set temperatures, update()
  ["p", um]                 advance_position
  ["s"]                     step
  ["f", mm_min, lo, hi]     set_feed
  ["c"]                     clear_feed
  ["r", um]                 set_reference
  ["l"]                     latch_references (tables certified for latched references)
  ["o"]                     estimate (a screw table's observer start; the cold start without one)
  ["n", rpm]                set_spindle (dynamic)
  ["g", mm_min]             set_feed_rate (dynamic)
  ["e", um]                 record [offset_at(um), ref_offset(), slope(), flags]
Usage on MicroPython: micropython export_vector_runner.py CASES.jsonl  -> prints one JSON result line per case.
"""
import binascii
import json
import sys

from firmware.evaluate import Evaluator
from firmware.table import parse_table


def run_case(table, ops, check=False):
    ev = Evaluator(parse_table(table), check)
    out = []
    temps = ev.temps
    for op in ops:
        k = op[0]
        if k == "t":
            vals = op[1]
            for i in range(len(vals)):
                temps[i] = vals[i]
            ev.update()
        elif k == "p":
            ev.advance_position(op[1])
        elif k == "s":
            ev.step()
        elif k == "f":
            ev.set_feed(op[1], op[2], op[3])
        elif k == "c":
            ev.clear_feed()
        elif k == "r":
            ev.set_reference(op[1])
        elif k == "l":
            ev.latch_references()
        elif k == "o":
            ev.estimate()
        elif k == "n":
            ev.set_spindle(op[1])
        elif k == "g":
            ev.set_feed_rate(op[1])
        elif k == "e":
            out.append([ev.offset_at(op[1]), ev.ref_offset(), ev.slope(), ev.flags])
    return out, ev


def main(path):
    """CASES file: one JSON object {"table": hex, "ops": [...]} per line (one case in memory at a time)."""
    with open(path) as fh:
        while True:
            line = fh.readline()
            if not line:
                break
            if not line.strip():
                continue
            c = json.loads(line)
            out, _ = run_case(binascii.unhexlify(c["table"]), c["ops"])
            c = None
            print(json.dumps(out))


if __name__ == "__main__":
    main(sys.argv[1])
