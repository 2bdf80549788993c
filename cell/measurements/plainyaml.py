"""``model.yaml`` read without importing PyYAML when it is plainly written: :func:`safe_load`.

Importing PyYAML costs about 10 ms of CPU (its reader compiles a large Unicode regex at
import), a tenth of a diagnosis' start-up, for a file of a dozen lines. So, as the plain
checks of :mod:`cell.measurements.checked` do for pydantic, :func:`plain_load` reads the
block style that ``yaml.safe_dump`` writes and people type (mappings, sequences, compact
``- - x`` items, one-line flow ``[…]`` / ``{…}`` collections, full-line comments) with
scalars whose meaning is unmistakable, and gives up (None) on anything else, which
PyYAML then reads and judges, with its own errors:

* a key: a plain identifier (``[A-Za-z_][A-Za-z0-9_]*``), never one of YAML 1.1's
  booleans or nulls; a key given twice gives up;
* a value: a decimal integer without leading zeros (``int``); a number with a '.' and an
  exponent written with its sign or none (``float``, as PyYAML builds it: the sign times
  the float of the rest); a word or words of ``[A-Za-z0-9_./-]`` starting with a letter or
  '_', not a boolean or null (``str``); or a one-line quoted string without escapes,
  quotes or '#' inside (``str``);
* the text: printable ASCII, no tabs, no carriage returns, no '#' but in full-line
  comments, no continuation lines.

Every value it returns is the one ``yaml.safe_load`` returns for the same text
(``tests/cell/test_plainyaml.py`` holds them together; within
:func:`~cell.measurements.checked.pydantic_only` PyYAML reads every file, so the tests
that compare the two checking paths compare the two readers too).
"""
from __future__ import annotations

import re

from cell.measurements.checked import plain

_KEY = re.compile(r"[A-Za-z_][A-Za-z0-9_]*")
_INT = re.compile(r"[-+]?(?:0|[1-9][0-9]{0,17})")
_FLOAT = re.compile(r"[-+]?[0-9]+\.[0-9]*(?:[eE][-+][0-9]+)?")
_WORDS = re.compile(r"[A-Za-z_][A-Za-z0-9_./-]*(?: [A-Za-z0-9_./-]+)*")
_QUOTED = re.compile(r"\"[ !$-\[\]-~]*\"|'[ -&(-~]*'")     # no quote, '\' (in "…") or '#' inside
_SPECIAL = {"yes", "no", "true", "false", "on", "off", "null", "y", "n"}


class _NotPlain(Exception):
    """The text is not plainly written: PyYAML reads it."""


def __getattr__(name: str):
    """``YAMLError``: PyYAML's error class, imported when an ``except`` clause first names
    it (only PyYAML raises it, so only after :func:`safe_load` has imported it)."""
    if name == "YAMLError":
        import yaml
        return yaml.YAMLError
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")


def safe_load(text: str):
    """``yaml.safe_load(text)``: :func:`plain_load`'s value for a plainly written text
    (outside :func:`~cell.measurements.checked.pydantic_only`), PyYAML's otherwise,
    raising what it raises."""
    found = plain(plain_load, text)
    if found is not None:
        return found
    import yaml
    return yaml.safe_load(text)


def plain_load(text: str) -> dict | None:
    """The mapping a plainly written YAML text (module docstring) holds, else None."""
    if not text.isascii() or "\t" in text or "\r" in text or any(c < " " and c != "\n" or c == "\x7f"
                                                                  for c in text):
        return None
    lines = []
    for raw in text.split("\n"):
        body = raw.lstrip(" ")
        if not body or body.startswith("#"):
            continue
        if "#" in body or raw.endswith(" "):
            return None
        lines.append([len(raw) - len(body), body])
    if not lines or lines[0][0] != 0:
        return None
    try:
        at, root = _block(lines, 0, 0)
    except _NotPlain:
        return None
    return root if at == len(lines) and isinstance(root, dict) else None


def _block(lines: list, i: int, ind: int) -> tuple[int, object]:
    """(next line, node) of the block mapping or sequence whose first line is ``i``, at
    indent ``ind``."""
    if lines[i][1] == "-" or lines[i][1].startswith("- "):
        return _sequence(lines, i, ind)
    return _mapping(lines, i, ind)


def _sequence(lines: list, i: int, ind: int) -> tuple[int, list]:
    out = []
    while i < len(lines) and lines[i][0] == ind and (lines[i][1] == "-" or lines[i][1].startswith("- ")):
        rest = lines[i][1][2:]
        if not rest or rest != rest.lstrip(" "):
            raise _NotPlain
        if rest.startswith("- ") or rest == "-" or _entry(rest) is not None:
            lines[i] = [ind + 2, rest]                 # a compact block inside the item
            i, item = _block(lines, i, ind + 2)
        else:
            item = _value(rest)
            i = _after_scalar(lines, i + 1, ind)
        out.append(item)
    return i, out


def _mapping(lines: list, i: int, ind: int) -> tuple[int, dict]:
    out: dict = {}
    while i < len(lines) and lines[i][0] == ind:
        kv = _entry(lines[i][1])
        if kv is None or kv[0] in out:
            raise _NotPlain
        key, rest = kv
        if rest:
            out[key] = _value(rest)
            i = _after_scalar(lines, i + 1, ind)
            continue
        i += 1
        if i < len(lines) and (lines[i][0] > ind or lines[i][0] == ind and (
                lines[i][1] == "-" or lines[i][1].startswith("- "))):
            i, out[key] = _block(lines, i, lines[i][0])
        else:
            raise _NotPlain                            # an empty value: null
    return i, out


def _entry(body: str) -> tuple[str, str] | None:
    """(key, value text) of a ``key: value`` or ``key:`` line, else None."""
    m = _KEY.match(body)
    if m is None or body[m.end():m.end() + 1] != ":" or body[:m.end()].lower() in _SPECIAL:
        return None
    rest = body[m.end() + 1:]
    if rest and not rest.startswith(" "):
        return None
    rest = rest.lstrip(" ")
    return body[:m.end()], rest


def _after_scalar(lines: list, i: int, ind: int) -> int:
    """``i``, refusing a more indented line after a scalar (a continued plain scalar)."""
    if i < len(lines) and lines[i][0] > ind:
        raise _NotPlain
    return i


def _value(text: str):
    """A one-line value: a flow collection or a scalar."""
    if text[0] == "[" and text[-1] == "]":
        inner = text[1:-1].strip(" ")
        return [_scalar(x.strip(" ")) for x in inner.split(",")] if inner else []
    if text[0] == "{" and text[-1] == "}":
        inner = text[1:-1].strip(" ")
        out: dict = {}
        for item in inner.split(",") if inner else []:
            kv = _entry(item.strip(" "))
            if kv is None or not kv[1] or kv[0] in out:
                raise _NotPlain
            out[kv[0]] = _scalar(kv[1])
        return out
    return _scalar(text)


def _scalar(t: str):
    """The value of scalar text ``t`` as PyYAML's safe constructor makes it."""
    if _QUOTED.fullmatch(t):
        return t[1:-1]
    if _INT.fullmatch(t):
        return int(t)
    if _FLOAT.fullmatch(t):
        sign = -1 if t[0] == "-" else 1
        return sign * float(t.lstrip("+-").lower())
    if _WORDS.fullmatch(t) and t.lower() not in _SPECIAL:
        return t
    raise _NotPlain
