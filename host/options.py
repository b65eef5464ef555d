"""The one parser of the repeatable ``--option KEY=VALUE`` flag (tcomp fit, select, compare).

A verb passes a table ``{key: converter}``; a converter turns the text after ``=`` into a value or
raises ValueError with the reason, which becomes "--option KEY='TEXT': reason". Without a table
any key is accepted and the value is read as JSON (numbers, true/false, lists) or kept as a word.
"""

from __future__ import annotations

from collections.abc import Callable, Iterable, Mapping
from typing import Any
import json
import math

from host.errors import UserError

# text after '=' -> value; ValueError with the reason when the text is not one
Converter = Callable[[str], Any]


def split_option(item: str, expected: str = "KEY=VALUE", flag: str = "--option") -> tuple[str, str]:
    """'KEY=VALUE' -> (KEY, VALUE) stripped; UserError when the '=' or the key is missing."""
    key, sep, value = item.partition("=")
    key = key.strip()
    if not sep or not key:
        raise UserError("%s %r: expected %s" % (flag, item, expected))
    return key, value.strip()


def json_or_word(text: str) -> Any:
    """A value read as JSON when it is JSON (3, 0.5, true, [1,2]), else the plain word (offset)."""
    try:
        return json.loads(text)
    except ValueError:
        return text


def number(kind: Callable[[str], float], minimum: float | None = None, maximum: float | None = None,
           above: float | None = None) -> Converter:
    """Converter to a finite ``kind`` (int or float): at least ``minimum``, at most ``maximum``, more than
    ``above``, each when given. A bound is what keeps a typo (segments=100000) from a 1 GiB array or a
    negative feed from a meaningless model: an option that sizes memory or has a physical sign has one."""
    def convert(text):
        try:
            value = kind(text)
        except ValueError:
            raise ValueError("not a valid %s" % kind.__name__)
        if not math.isfinite(value):
            raise ValueError("must be a finite number")
        if minimum is not None and value < minimum:
            raise ValueError("must be >= %g" % minimum)
        if above is not None and value <= above:
            raise ValueError("must be > %g" % above)
        if maximum is not None and value > maximum:
            raise ValueError("must be <= %g" % maximum)
        return value
    return convert


def number_or_none(kind: Callable[[str], float], minimum: float | None = None) -> Converter:
    """Converter to ``number(kind, minimum)``, or None for the word none (any case): a setting that can be off."""
    one = number(kind, minimum)

    def convert(text):
        return None if text.strip().lower() == "none" else one(text)
    return convert


def number_or_choice(kind: Callable[[str], float], minimum: float | None, *words: str) -> Converter:
    """Converter to one of ``words`` (exact), else ``number(kind, minimum)``: a setting that is a count or a named rule
    (forward_blocks=4 or forward_blocks=phases)."""
    one = number(kind, minimum)

    def convert(text):
        if text in words:
            return text
        try:
            return one(text)
        except ValueError as exc:
            raise ValueError("expected %s, or a number: %s" % (" or ".join(words), exc))
    return convert


def numbers(kind: Callable[[str], float], minimum: float | None = None) -> Converter:
    """Converter to a list of ``number(kind, minimum)`` values separated by '/' (e.g. 0/1800/7200)."""
    one = number(kind, minimum)

    def convert(text):
        try:
            return [one(x) for x in text.split("/")]
        except ValueError as exc:
            raise ValueError("not a valid list of numbers separated by / (%s)" % exc)
    return convert


def boolean(text: str) -> bool:
    """Converter accepting true or false (any case)."""
    word = text.lower()
    if word not in ("true", "false"):
        raise ValueError("not a valid true or false")
    return word == "true"


def choice(*words: str) -> Converter:
    """Converter accepting one of ``words``."""
    def convert(text):
        if text not in words:
            raise ValueError("expected %s" % " or ".join(words))
        return text
    return convert


def parse_options(items: Iterable[str] | None, converters: Mapping[str, Converter] | None = None, flag: str = "--option") -> dict[str, Any]:
    """``--option`` items -> {key: value}; a bad item is a UserError naming it and the reason."""
    out = {}
    for item in items or ():
        key, text = split_option(item, flag=flag)
        if converters is None:
            out[key] = json_or_word(text)
            continue
        if key not in converters:
            raise UserError("%s %r: expected KEY=VALUE with KEY one of %s" % (flag, item, ", ".join(sorted(converters))))
        try:
            out[key] = converters[key](text)
        except ValueError as exc:
            raise UserError("%s %s=%r: %s" % (flag, key, text, exc))
    return out
