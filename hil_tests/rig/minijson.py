"""JSON for the QEMU board image, which has no ``json`` module (the MicroPython core it is built
on has no extmod/): ``dumps``, ``loads`` and ``load`` for the rig's spec file and control lines
(objects, arrays, strings, numbers, true/false/null). Board side only; elsewhere ``json``."""

_ESC = {'"': '"', "\\": "\\", "/": "/", "b": "\b", "f": "\f", "n": "\n", "r": "\r", "t": "\t"}


def _str(s):
    out = ['"']
    for c in s:
        o = ord(c)
        if c == '"' or c == "\\":
            out.append("\\" + c)
        elif o < 0x20:
            out.append("\\u%04x" % o)
        else:
            out.append(c)
    out.append('"')
    return "".join(out)


def dumps(obj):
    if obj is None:
        return "null"
    if obj is True:
        return "true"
    if obj is False:
        return "false"
    if isinstance(obj, str):
        return _str(obj)
    if isinstance(obj, (int, float)):
        return repr(obj)
    if isinstance(obj, dict):
        return "{" + ", ".join(_str(str(k)) + ": " + dumps(v) for k, v in obj.items()) + "}"
    if isinstance(obj, (list, tuple)):
        return "[" + ", ".join(dumps(v) for v in obj) + "]"
    raise TypeError("not JSON serialisable: %r" % (obj,))


class _Parser:
    def __init__(self, text):
        self.s = text
        self.i = 0

    def ws(self):
        s = self.s
        n = len(s)
        while self.i < n and s[self.i] in " \t\r\n":
            self.i += 1

    def value(self):
        self.ws()
        s = self.s
        c = s[self.i]
        if c == "{":
            self.i += 1
            d = {}
            self.ws()
            if s[self.i] == "}":
                self.i += 1
                return d
            while True:
                self.ws()
                k = self.string()
                self.ws()
                self.expect(":")
                d[k] = self.value()
                self.ws()
                if s[self.i] == ",":
                    self.i += 1
                    continue
                self.expect("}")
                return d
        if c == "[":
            self.i += 1
            a = []
            self.ws()
            if s[self.i] == "]":
                self.i += 1
                return a
            while True:
                a.append(self.value())
                self.ws()
                if s[self.i] == ",":
                    self.i += 1
                    continue
                self.expect("]")
                return a
        if c == '"':
            return self.string()
        for word, val in (("true", True), ("false", False), ("null", None)):
            if s.startswith(word, self.i):
                self.i += len(word)
                return val
        return self.number()

    def expect(self, c):
        if self.s[self.i] != c:
            raise ValueError("JSON: expected %r at %d" % (c, self.i))
        self.i += 1

    def string(self):
        self.expect('"')
        s = self.s
        out = []
        start = self.i
        while True:
            c = s[self.i]
            if c == '"':
                out.append(s[start:self.i])
                self.i += 1
                return "".join(out)
            if c == "\\":
                out.append(s[start:self.i])
                e = s[self.i + 1]
                if e == "u":
                    out.append(chr(int(s[self.i + 2:self.i + 6], 16)))
                    self.i += 6
                else:
                    out.append(_ESC[e])
                    self.i += 2
                start = self.i
            else:
                self.i += 1

    def number(self):
        s = self.s
        start = self.i
        n = len(s)
        while self.i < n and s[self.i] in "+-0123456789.eE":
            self.i += 1
        t = s[start:self.i]
        if not t:
            raise ValueError("JSON: bad value at %d" % start)
        if "." in t or "e" in t or "E" in t:
            return float(t)
        return int(t)


def loads(text):
    if isinstance(text, (bytes, bytearray)):
        text = text.decode()
    p = _Parser(text)
    v = p.value()
    p.ws()
    if p.i != len(text):
        raise ValueError("JSON: extra data at %d" % p.i)
    return v


def load(f):
    return loads(f.read())
