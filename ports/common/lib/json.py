"""json for tcomp's MicroPython ports (the core has no json module without extmod).

``dumps``/``dump`` write JSON (``separators`` as CPython's default: ", " and ": "; in C when
the port has ``_json``, ports/common/modjson_dumps.c);
``loads``/``load`` parse what CPython's json writes. Enough for the HIL rig's control
channel and the DUT's spec file; not a validating parser.
"""


def _esc(s):
    out = []
    for c in s:
        o = ord(c)
        if c == '"' or c == "\\":
            out.append("\\" + c)
        elif o < 0x20:
            out.append({"\n": "\\n", "\r": "\\r", "\t": "\\t"}.get(c) or "\\u%04x" % o)
        else:
            out.append(c)
    return '"' + "".join(out) + '"'


def _dump(o, parts, item_sep, key_sep):
    if o is None:
        parts.append("null")
    elif o is True:
        parts.append("true")
    elif o is False:
        parts.append("false")
    elif isinstance(o, str):
        parts.append(_esc(o))
    elif isinstance(o, int):
        parts.append(str(o))
    elif isinstance(o, float):
        r = repr(o)
        parts.append({"inf": "Infinity", "-inf": "-Infinity", "nan": "NaN"}.get(r, r))
    elif isinstance(o, dict):
        parts.append("{")
        first = True
        for k, v in o.items():
            if not first:
                parts.append(item_sep)
            first = False
            if not isinstance(k, str):
                k = "true" if k is True else "false" if k is False else "null" if k is None else str(k)
            parts.append(_esc(k))
            parts.append(key_sep)
            _dump(v, parts, item_sep, key_sep)
        parts.append("}")
    elif isinstance(o, (list, tuple)):
        parts.append("[")
        for i, v in enumerate(o):
            if i:
                parts.append(item_sep)
            _dump(v, parts, item_sep, key_sep)
        parts.append("]")
    else:
        raise TypeError("%r is not JSON serializable" % (o,))


def dumps(obj, separators=None):
    if separators is None and _cdumps is not None:
        return _cdumps(obj)
    item_sep, key_sep = separators or (", ", ": ")
    parts = []
    _dump(obj, parts, item_sep, key_sep)
    return "".join(parts)


try:
    from _json import dumps as _cdumps  # ports/common/modjson_dumps.c: the core's JSON printers
except ImportError:
    _cdumps = None


def dump(obj, stream, separators=None):
    stream.write(dumps(obj, separators))


_WS = " \t\n\r"
_CONST = {"true": True, "false": False, "null": None, "NaN": float("nan"), "Infinity": float("inf"),
          "-Infinity": float("-inf")}
_ESC = {'"': '"', "\\": "\\", "/": "/", "b": "\b", "f": "\f", "n": "\n", "r": "\r", "t": "\t"}
_NUM = "+-0123456789.eE"


class _Parser:
    def __init__(self, s):
        self.s = s
        self.i = 0

    def ws(self):
        s, i, n = self.s, self.i, len(self.s)
        while i < n and s[i] in _WS:
            i += 1
        self.i = i

    def fail(self, what):
        raise ValueError("syntax error in JSON at %d: %s" % (self.i, what))

    def value(self):
        self.ws()
        s, i = self.s, self.i
        if i >= len(s):
            self.fail("unexpected end")
        c = s[i]
        if c == "{":
            return self.obj()
        if c == "[":
            return self.arr()
        if c == '"':
            return self.string()
        for word, val in _CONST.items():
            if s.startswith(word, i):
                self.i = i + len(word)
                return val
        j = i
        while j < len(s) and s[j] in _NUM:
            j += 1
        if j == i:
            self.fail("unexpected %r" % c)
        text = s[i:j]
        self.i = j
        if "." in text or "e" in text or "E" in text:
            return float(text)
        return int(text)

    def string(self):
        s = self.s
        i = self.i + 1
        out = []
        while True:
            j = i
            while j < len(s) and s[j] != '"' and s[j] != "\\":
                j += 1
            if j >= len(s):
                self.fail("unterminated string")
            out.append(s[i:j])
            if s[j] == '"':
                self.i = j + 1
                return "".join(out)
            e = s[j + 1:j + 2]
            if e == "u":
                cp = int(s[j + 2:j + 6], 16)
                i = j + 6
                if 0xD800 <= cp < 0xDC00 and s[i:i + 2] == "\\u":  # surrogate pair
                    cp = 0x10000 + ((cp - 0xD800) << 10) + (int(s[i + 2:i + 6], 16) - 0xDC00)
                    i += 6
                out.append(chr(cp))
            elif e in _ESC:
                out.append(_ESC[e])
                i = j + 2
            else:
                self.fail("bad escape")

    def obj(self):
        self.i += 1
        d = {}
        self.ws()
        if self.s[self.i:self.i + 1] == "}":
            self.i += 1
            return d
        while True:
            self.ws()
            if self.s[self.i:self.i + 1] != '"':
                self.fail("expected a key")
            k = self.string()
            self.ws()
            if self.s[self.i:self.i + 1] != ":":
                self.fail("expected ':'")
            self.i += 1
            d[k] = self.value()
            self.ws()
            c = self.s[self.i:self.i + 1]
            self.i += 1
            if c == "}":
                return d
            if c != ",":
                self.fail("expected ',' or '}'")

    def arr(self):
        self.i += 1
        a = []
        self.ws()
        if self.s[self.i:self.i + 1] == "]":
            self.i += 1
            return a
        while True:
            a.append(self.value())
            self.ws()
            c = self.s[self.i:self.i + 1]
            self.i += 1
            if c == "]":
                return a
            if c != ",":
                self.fail("expected ',' or ']'")


def loads(s):
    if isinstance(s, (bytes, bytearray)):
        s = s.decode()
    p = _Parser(s)
    v = p.value()
    p.ws()
    if p.i != len(s):
        p.fail("extra data")
    return v


def load(stream):
    return loads(stream.read())
