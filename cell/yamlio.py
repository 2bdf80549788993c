"""Load YAML into pydantic models with errors that name file, line and field.

Every YAML file the cell reads (cell config, recipes, plant files) goes through here, so
every such error reads the same, in the compiler style editors jump to::

    recipes/bracket-a.yaml:8: part.fiducial_radius_mm: Input should be greater than 0.2

Only ``yaml.safe_load``/``yaml.compose`` are used (no arbitrary object construction). A
validation error is located by walking the composed node tree along the error's ``loc``
path; all errors are reported, in file order. A key given twice is an error (plain YAML
would silently keep the last one).
"""
from __future__ import annotations

from pathlib import Path
from typing import Any, TypeVar

import yaml
from pydantic import BaseModel, ValidationError

from cell.errors import ConfigError

M = TypeVar("M", bound=BaseModel)


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


def validation_message(source: str, exc: ValidationError, root: yaml.Node | None) -> str:
    """Every error of ``exc`` as ``source:line: field: message``, in file order. An error
    raised inside a validator may carry a ``loc`` attribute that refines the field."""
    lines = []
    for err in exc.errors():
        loc = tuple(err["loc"])
        cause = (err.get("ctx") or {}).get("error")
        msg = err["msg"]
        if isinstance(cause, Exception):
            loc += tuple(getattr(cause, "loc", ()))
            msg = str(cause)
        line = node_line(root, loc)
        where = f"{source}:{line}" if line is not None else source
        lines.append((line or 0, f"{where}: {field_name(loc)}: {msg}"))
    return "; ".join(m for _, m in sorted(lines, key=lambda x: x[0]))


def parse_yaml(text: str, source: str, kind: str = "file") -> tuple[Any, yaml.Node | None]:
    """Parse ``text``; returns (data, node tree). Raises ConfigError for malformed YAML, an
    empty document, a top level that is not a mapping, or a key given twice."""
    try:
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
        raise ConfigError(validation_message(source, exc, root)) from None


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
