"""Scenario 3: serial fuzz. Garbage, truncated frames, wrong CRCs, well-formed frames with
out-of-range values and over-long lines, interleaved at random with valid commands.

Every bad line gets exactly one E frame; every valid command gets its reply
(P none, Q -> Q, V -> H, S -> T, R -> A); the firmware never crashes, and
its state (reported position, reference, table) changes only through the
valid commands. Runs against the rig or a real board (--port).
"""
import os

from hypothesis import HealthCheck, given, settings, strategies as st

from firmware.wire import HELLO_NONCE
from host.board.link import command_line, crc16

N_EXAMPLES = 300 if os.environ.get("TCOMP_SLOW") else 60
POS_LIMIT = 100000000

_garbage = st.binary(min_size=1, max_size=60).map(
    lambda b: bytes(c for c in b if c not in b"\r\n$") or b"x")
_in_range = st.integers(-POS_LIMIT, POS_LIMIT)
_out_of_range = st.one_of(st.integers(POS_LIMIT + 1, 10 ** 12), st.integers(-10 ** 12, -POS_LIMIT - 1))


@st.composite
def _bad(draw):
    kind = draw(st.sampled_from(["garbage", "truncated", "crc", "range", "unknown", "fields", "long", "number"]))
    if kind == "garbage":
        return kind, draw(_garbage) + b"\r\n"
    if kind == "truncated":
        full = command_line("Q", draw(_in_range))[:-2]
        k = draw(st.integers(1, len(full) - 1))
        return kind, full[:k] + b"\r\n"
    if kind == "crc":
        body = b"TC,P,%d" % draw(_in_range)
        wrong = crc16(body) ^ draw(st.integers(1, 0xFFFF))
        return kind, b"$" + body + b"*%04X\r\n" % wrong
    if kind == "range":
        return kind, command_line(draw(st.sampled_from(["P", "Q", "R"])), draw(_out_of_range))
    if kind == "unknown":
        return kind, command_line(draw(st.sampled_from(["Z", "K", "PP", "q", "1"])), 5)
    if kind == "fields":
        return kind, command_line("P", 1, 2, 3)  # P takes <pos>[,<spindle rpm>]
    if kind == "number":
        return kind, command_line("Q", draw(st.sampled_from(["12a", "", "-", "1.5", "0x10", "--3"])))
    return kind, b"$TC,P," + b"1" * draw(st.integers(200, 300)) + b"*0000\r\n"


@st.composite
def _valid(draw):
    c = draw(st.sampled_from(["P", "Q", "V", "S", "R"]))
    if c in ("P", "Q"):
        return c, draw(st.integers(0, 700000))
    if c == "R":
        return c, draw(st.integers(0, 700000))
    return c, None


_items = st.lists(st.one_of(_bad().map(lambda b: ("bad",) + b), _valid().map(lambda v: ("valid",) + v)),
                  min_size=1, max_size=10)


def test_serial_fuzz_never_crashes_and_state_changes_only_through_valid_commands(dut):
    dut.advance(3000)
    hello = dut.request("V", kinds=("H",))
    state = {"pos": None}
    COUNT = {"bad": 0, "valid": 0}

    def replies(n0, expect):
        """Non-O frames after index n0, once ``expect`` of them arrived (or 2 s of device time)."""
        for _ in range(200):
            dut.advance(10)
            new = [f for f in dut.frames[n0:] if f.kind != "O"]
            if len(new) >= expect:
                dut.advance(20)  # room for a wrong extra frame to show up
                return [f for f in dut.frames[n0:] if f.kind != "O"]
        return new

    @settings(max_examples=N_EXAMPLES, deadline=None, suppress_health_check=list(HealthCheck), derandomize=True)
    @given(_items)
    def check(items):
        for item in items:
            n0 = len(dut.frames)
            if item[0] == "bad":
                _, kind, data = item
                dut.write(data)
                new = replies(n0, 1)
                assert [f.kind for f in new] == ["E"], (kind, data[:80], [f.raw for f in new])
                COUNT["bad"] += 1
            else:
                _, c, v = item
                dut.send(c, v) if v is not None else dut.send(c)
                want = {"P": [], "Q": ["Q"], "V": ["H"], "S": ["T"], "R": ["A"]}[c]
                new = replies(n0, len(want))
                assert [f.kind for f in new] == want, (c, v, [f.raw for f in new])
                if c == "P":
                    state["pos"] = v
                if c == "Q":
                    assert int(new[0].fields[1]) == v
                if c == "R":
                    assert new[0].fields[0] == "R" and 0 <= int(new[0].fields[1]) <= 700000, new[0].raw
                COUNT["valid"] += 1
            assert dut.alive
        # state: the position in the periodic frames is the last valid report
        dut.advance(1100)
        o = [f for f in dut.frames if f.kind == "O"]
        if state["pos"] is not None:
            assert o[-1].pos_um == state["pos"], o[-1].raw
        assert not dut.reader.decoder.bad, dut.reader.decoder.bad[:3]

    check()
    again = dut.request("V", kinds=("H",))
    # same table, same slot: nothing but valid commands touched it (the session nonce moves on with time)
    def but_nonce(h):
        return h.fields[:HELLO_NONCE] + h.fields[HELLO_NONCE + 1:]

    assert but_nonce(again) == but_nonce(hello)
    print("fuzz: %d bad lines, %d valid commands" % (COUNT["bad"], COUNT["valid"]))
