"""Load YAML into pydantic models with errors that name file, line and field.

Every YAML file the cell reads (cell config, recipes, plant files) goes through here, so
every such error reads the same, in the compiler style editors jump to::

    recipes/bracket-a.yaml:8: part.fiducial_radius_mm: must be greater than 0.2

Only ``yaml.safe_load``/``yaml.compose`` are used (no arbitrary object construction). A
validation error is located by walking the composed node tree along the error's ``loc``
path; all errors are reported, in file order, in our words (:func:`error_text`: "unknown
field; did you mean 'verify'?", not pydantic's "Extra inputs are not permitted"). A key
given twice is an error (plain YAML would silently keep the last one).

**Bounded work.** Before anything is composed, one pass over the parser's events refuses
anchors and aliases (``&a`` / ``*a``: a 2 KB "billion laughs" file expands into billions of
nodes for every walk of the tree) and nesting deeper than :data:`MAX_DEPTH`. The pass is
linear in the text, so what any file can cost is bounded by its size, which every reader
bounds first.
"""
from __future__ import annotations

import difflib
import types
import typing
from pathlib import Path
from typing import Any, TypeVar

import yaml
from pydantic import BaseModel, ValidationError

from cell.errors import ConfigError

M = TypeVar("M", bound=BaseModel)

#: the deepest nesting of mappings and lists a cell file may have (ours need 4)
MAX_DEPTH = 16


def field_name(loc) -> str:
    """``("effects", 0, "params")`` -> ``effects[0].params``."""
    out = ""
    for part in loc:
        out += f"[{part}]" if isinstance(part, int) else (f".{part}" if out else str(part))
    return out or "(top level)"


def node_line(root: yaml.Node | None, loc) -> int | None:
    """1-based line of the deepest node along ``loc`` (the key's line for a mapping entry)."""
    node, line = root, (root.start_mark.line + 1 if root is not None else None)
    for part in loc:
        if isinstance(node, yaml.MappingNode):
            hit = next(((k, v) for k, v in node.value if k.value == str(part)), None)
            if hit is None:
                break
            line, node = hit[0].start_mark.line + 1, hit[1]
        elif isinstance(node, yaml.SequenceNode) and isinstance(part, int) \
                and 0 <= part < len(node.value):
            node = node.value[part]
            line = node.start_mark.line + 1
        else:
            break
    return line


def duplicate_key(node: yaml.Node | None, path=()) -> tuple[tuple, yaml.Node] | None:
    """(path, key node) of the first mapping key given twice, or None."""
    if isinstance(node, yaml.MappingNode):
        seen = set()
        for k, v in node.value:
            if k.value in seen:
                return path + (k.value,), k
            seen.add(k.value)
            found = duplicate_key(v, path + (k.value,))
            if found:
                return found
    elif isinstance(node, yaml.SequenceNode):
        for i, v in enumerate(node.value):
            found = duplicate_key(v, path + (i,))
            if found:
                return found
    return None


def _unwrap(tp: Any) -> Any:
    """``X`` of ``X | None`` (an Optional field), else ``tp``."""
    if typing.get_origin(tp) in (typing.Union, types.UnionType):
        args = [a for a in typing.get_args(tp) if a is not type(None)]
        return args[0] if len(args) == 1 else None
    return tp


def _fields_at(model: type[BaseModel] | None, loc) -> list[str]:
    """The field names a mapping at ``loc`` inside ``model`` may have ([] if unknown)."""
    tp: Any = model
    for part in loc:
        tp = _unwrap(tp)
        if isinstance(tp, type) and issubclass(tp, BaseModel) and isinstance(part, str):
            field = tp.model_fields.get(part)
            tp = field.annotation if field is not None else None
        elif typing.get_origin(tp) in (list, tuple, dict) and typing.get_args(tp):
            args = typing.get_args(tp)
            tp = args[0] if typing.get_origin(tp) is tuple else args[-1]
        else:
            return []
    tp = _unwrap(tp)
    return list(tp.model_fields) if isinstance(tp, type) and issubclass(tp, BaseModel) else []


def error_text(err: dict, model: type[BaseModel] | None = None) -> str:
    """One pydantic error in the cell's words: an unknown key says which keys were meant
    (``did you mean 'verify'?``), a missing one that it is required, and pydantic's "Input
    should be" reads "must be". ``model``: the model validated, for the known field names."""
    kind, msg = err.get("type", ""), str(err.get("msg", ""))
    loc = tuple(err.get("loc", ()))
    if kind == "extra_forbidden":
        known = _fields_at(model, loc[:-1])
        close = difflib.get_close_matches(str(loc[-1]), known, n=1, cutoff=0.6) if loc else []
        hint = f"; did you mean {close[0]!r}?" if close else (
            f"; known fields here: {', '.join(known)}" if known else "")
        return f"unknown field{hint}"
    if kind in ("model_type", "model_attributes_type", "dict_type"):
        known = _fields_at(model, loc)
        fields = f" ({', '.join(known)})" if known else ""
        if err.get("input") is None:
            return f"empty section: write out its fields{fields}"
        return f"must be a mapping of fields{fields}, got {type(err.get('input')).__name__}"
    if kind == "missing":
        return "required, but missing (write it out: it is never taken from a default)"
    for prefix in ("Value error, ", "Assertion failed, "):
        if msg.startswith(prefix):
            msg = msg[len(prefix):]
    return msg.replace("Input should be", "must be").replace("input should be", "must be")


def validation_message(source: str, exc: ValidationError, root: yaml.Node | None,
                       model: type[BaseModel] | None = None) -> str:
    """Every error of ``exc`` as ``source:line: field: message``, in file order and in the
    cell's words (:func:`error_text`). An error raised inside a validator may carry a
    ``loc`` attribute that refines the field. ``model`` names the known fields of a typo."""
    lines = []
    for err in exc.errors():
        loc = tuple(err["loc"])
        cause = (err.get("ctx") or {}).get("error")
        msg = error_text(err, model)
        if isinstance(cause, Exception):
            loc += tuple(getattr(cause, "loc", ()))
            msg = str(cause)
        line = node_line(root, loc)
        where = f"{source}:{line}" if line is not None else source
        lines.append((line or 0, f"{where}: {field_name(loc)}: {msg}"))
    return "; ".join(m for _, m in sorted(lines, key=lambda x: x[0]))


def bounded(text: str, source: str) -> None:
    """Refuse anchors, aliases and nesting deeper than :data:`MAX_DEPTH` in ``text``, in one
    linear pass over the parser's events, before anything is composed.

    :raises ConfigError: naming ``source``, the line and what was found.
    :raises yaml.YAMLError: the text does not parse (the caller reports it).
    """
    depth = 0
    for ev in yaml.parse(text, Loader=yaml.SafeLoader):
        if isinstance(ev, yaml.AliasEvent) or getattr(ev, "anchor", None) is not None:
            sign = "*" if isinstance(ev, yaml.AliasEvent) else "&"
            raise ConfigError(f"{source}:{ev.start_mark.line + 1}: (file): YAML anchors and aliases "
                              f"({sign}{ev.anchor}) are not allowed in cell files: write the value out")
        if isinstance(ev, (yaml.MappingStartEvent, yaml.SequenceStartEvent)):
            depth += 1
            if depth > MAX_DEPTH:
                raise ConfigError(f"{source}:{ev.start_mark.line + 1}: (file): nested deeper than "
                                  f"{MAX_DEPTH} levels; no cell file needs that many")
        elif isinstance(ev, (yaml.MappingEndEvent, yaml.SequenceEndEvent)):
            depth -= 1


def parse_yaml(text: str, source: str, kind: str = "file") -> tuple[Any, yaml.Node | None]:
    """Parse ``text``; returns (data, node tree). Raises ConfigError for malformed YAML, an
    empty document, a top level that is not a mapping, or a key given twice."""
    try:
        bounded(text, source)
        root = yaml.compose(text, Loader=yaml.SafeLoader)
        data = yaml.safe_load(text)
    except yaml.YAMLError as exc:
        mark = getattr(exc, "problem_mark", None) or getattr(exc, "context_mark", None)
        line = f":{mark.line + 1}" if mark is not None else ""
        problem = getattr(exc, "problem", None) or str(exc)
        if isinstance(exc, yaml.reader.ReaderError):     # a character YAML refuses: no mark
            pos = int(exc.position)
            line = f":{text.count(chr(10), 0, pos) + 1}"
            code = ord(exc.character) if isinstance(exc.character, str) else int(exc.character)
            problem = (f"character code {code:#04x} at column {pos - text.rfind(chr(10), 0, pos)} "
                       "is not allowed in YAML text (binary data, or a control character?)")
        raise ConfigError(f"{source}{line}: malformed YAML: {problem}") from None
    if data is None:
        raise ConfigError(f"{source}:1: (top level): the {kind} is empty")
    if not isinstance(data, dict):
        line = root.start_mark.line + 1 if root is not None else 1
        raise ConfigError(f"{source}:{line}: (top level): the {kind} must be a mapping of fields, "
                          f"got {type(data).__name__}")
    dup = duplicate_key(root)
    if dup:
        loc, key = dup
        raise ConfigError(f"{source}:{key.start_mark.line + 1}: {field_name(loc)}: key given twice")
    return data, root


def parse_model(text: str, model: type[M], source: str, kind: str = "file") -> M:
    """Parse YAML ``text`` into ``model``; ConfigError names source, line and field."""
    data, root = parse_yaml(text, source, kind)
    try:
        return model.model_validate(data)
    except ValidationError as exc:
        raise ConfigError(validation_message(source, exc, root, model)) from None


def read_text(path: Path | str, kind: str = "file") -> str:
    """The file's text; ConfigError if it is missing, unreadable or not UTF-8 (naming the
    line and column of the first bad byte)."""
    p = Path(path)
    try:
        data = p.read_bytes()
    except FileNotFoundError:
        raise ConfigError(f"{p}: {kind} not found") from None
    except OSError as exc:
        raise ConfigError(f"{p}: cannot read {kind}: {exc.strerror or exc}") from None
    return decode_utf8(data, str(p), kind)


def decode_utf8(data: bytes, source: str, kind: str | None = None) -> str:
    """``data`` as UTF-8 text; ConfigError naming ``source``, line and column of the first
    byte that is not UTF-8."""
    try:
        return data.decode("utf-8")
    except UnicodeDecodeError as exc:
        line = data.count(b"\n", 0, exc.start) + 1
        column = exc.start - (data.rfind(b"\n", 0, exc.start) + 1) + 1
        raise ConfigError(f"{source}:{line}: cannot read{' ' + kind if kind else ''}: not UTF-8 text "
                          f"(byte 0x{data[exc.start]:02x} "
                          f"at column {column}; save the file as UTF-8)") from None


def load_model(path: Path | str, model: type[M], kind: str = "file") -> M:
    """Read ``path`` and parse it into ``model`` (see :func:`parse_model`)."""
    return parse_model(read_text(path, kind), model, str(path), kind)
