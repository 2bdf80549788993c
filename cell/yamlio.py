"""Load YAML into pydantic models with errors that name file, line and field.

Only ``yaml.safe_load``/``yaml.compose`` are used (no arbitrary object construction). A
validation error is located by walking the composed node tree along the error's ``loc``
path, so the message points at the line a maintenance technician has to fix.
"""
from __future__ import annotations

from pathlib import Path
from typing import TypeVar

import yaml
from pydantic import BaseModel, ValidationError

from cell.errors import ConfigError

M = TypeVar("M", bound=BaseModel)


def node_line(text: str, loc: tuple) -> int | None:
    """1-based line of the YAML node at path ``loc`` (keys and list indices), or of the deepest
    parent found; None if the text does not compose."""
    try:
        node = yaml.compose(text)
    except yaml.YAMLError:
        return None
    line = node.start_mark.line + 1 if node is not None else None
    for part in loc:
        if isinstance(node, yaml.MappingNode):
            for key, value in node.value:
                if key.value == str(part):
                    line, node = key.start_mark.line + 1, value
                    break
            else:
                return line
        elif isinstance(node, yaml.SequenceNode) and isinstance(part, int) and part < len(node.value):
            node = node.value[part]
            line = node.start_mark.line + 1
        else:
            return line
    return line


def parse_model(text: str, model: type[M], source: str) -> M:
    """Parse YAML ``text`` into ``model``; raise ConfigError '<source>, line N, field F: why'."""
    try:
        raw = yaml.safe_load(text)
    except yaml.YAMLError as exc:
        mark = getattr(exc, "problem_mark", None)
        where = f"{source}, line {mark.line + 1}" if mark else source
        raise ConfigError(f"{where}: not valid YAML: {getattr(exc, 'problem', None) or exc}") from None
    if not isinstance(raw, dict):
        raise ConfigError(f"{source}, line 1: expected a mapping of keys to values, "
                          f"got {type(raw).__name__}")
    try:
        return model.model_validate(raw)
    except ValidationError as exc:
        err = exc.errors()[0]
        loc = tuple(err["loc"])
        field = ".".join(str(p) for p in loc) or "(top level)"
        line = node_line(text, loc)
        where = f"{source}, line {line}" if line else source
        more = f" (and {len(exc.errors()) - 1} more)" if len(exc.errors()) > 1 else ""
        raise ConfigError(f"{where}, field {field}: {err['msg']}{more}") from None


def load_model(path: Path | str, model: type[M]) -> M:
    """Read ``path`` and parse it into ``model`` (see :func:`parse_model`)."""
    p = Path(path)
    try:
        text = p.read_text(encoding="utf-8")
    except FileNotFoundError:
        raise ConfigError(f"{p}: file not found") from None
    except (OSError, UnicodeDecodeError) as exc:
        raise ConfigError(f"{p}: cannot read: {exc}") from None
    return parse_model(text, model, str(p))
