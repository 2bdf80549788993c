"""The calibration board's description, validated: ``cellctl calibrate-camera --board FILE``
and the cell config's ``calibration.board`` both go through here.

One pydantic model per board kind (:class:`CirclesSpec`, :class:`ChessboardSpec`) states
the keys, their types and ranges; ``kind`` picks the model. Every mistake is a
:class:`~cell.errors.ConfigError` in the words and the ``FILE:LINE: field: message`` form of
:mod:`cell.yamlio` (a mistyped key says which one was meant, ``pitch: unknown field; did
you mean 'pitch_mm'?``); a file that is missing, empty, not a mapping, too large or uses
YAML aliases is refused the same way. The result is the numeric
:data:`~cell.vision.calibration.Board` the calibration uses.
"""
from __future__ import annotations

import difflib
from pathlib import Path
from typing import Annotated, Any, Literal

from pydantic import (AfterValidator, AllowInfNan, BaseModel, ConfigDict, Field, Strict,
                      ValidationError, ValidationInfo, field_validator)

from cell.errors import ConfigError
from cell.yamlio import (error_text, field_name, node_line, parse_yaml, read_text,
                         validation_message)

#: a board file larger than this is refused unread (a board is described in a few lines)
MAX_BYTES = 64 * 1024


def _count(v: int) -> int:
    """cols, rows: 3 to 100 points (OpenCV's detectors need 3)."""
    if not 3 <= v <= 100:
        raise ValueError("must be an integer in [3, 100]")
    return v


Count = Annotated[int, Strict(), AfterValidator(_count)]
Finite = Annotated[float, Strict(), AllowInfNan(False)]
Length = Annotated[float, Strict(), AllowInfNan(False), Field(gt=0, le=10_000)]


class _Spec(BaseModel):
    model_config = ConfigDict(extra="forbid", frozen=True)

    cols: Count                                   #: points per row
    rows: Count                                   #: points per column
    origin_mm: tuple[Finite, Finite] = (0.0, 0.0)   #: base-frame x, y of point (col 0, row 0), mm
    angle_deg: Finite = 0.0                       #: the col axis from base +x, counter-clockwise

    @field_validator("origin_mm", mode="before")
    @classmethod
    def _pair(cls, v: Any) -> Any:
        if not isinstance(v, (list, tuple)) or len(v) != 2:
            raise ValueError(f"must be [x, y] in mm, got {v!r}")
        return v

    def board(self):
        """The numeric board this spec describes."""
        raise NotImplementedError


class CirclesSpec(_Spec):
    """``kind: circles``: a symmetric grid of dark dots; ``pitch_mm`` centre to centre,
    ``radius_mm`` below 0.4 pitch (the detector needs the gap)."""

    kind: Literal["circles"]
    pitch_mm: Length = 10.0
    radius_mm: Length = 2.5

    @field_validator("radius_mm")
    @classmethod
    def _gap(cls, v: float, info: ValidationInfo) -> float:
        pitch = info.data.get("pitch_mm")
        if pitch is not None and not v < 0.4 * pitch:
            raise ValueError(f"must be below 0.4 × pitch_mm = {0.4 * pitch:g}, got {v:g}")
        return v

    def board(self):
        from cell.vision.calibration import CircleGridBoard
        return CircleGridBoard(cols=self.cols, rows=self.rows, pitch_mm=self.pitch_mm,
                               radius_mm=self.radius_mm, origin_mm=self.origin_mm,
                               angle_deg=self.angle_deg)


class ChessboardSpec(_Spec):
    """``kind: chessboard``: ``cols`` × ``rows`` inner corners, squares of ``square_mm``."""

    kind: Literal["chessboard"]
    square_mm: Length = 10.0

    def board(self):
        from cell.vision.calibration import ChessBoard
        return ChessBoard(cols=self.cols, rows=self.rows, square_mm=self.square_mm,
                          origin_mm=self.origin_mm, angle_deg=self.angle_deg)


KINDS: dict[str, type[_Spec]] = {"circles": CirclesSpec, "chessboard": ChessboardSpec}


def board_from_mapping(data: Any, source: str = "board", root=None):
    """``data`` (a board file's mapping) as a :data:`~cell.vision.calibration.Board`.

    ``source`` names where it came from in messages; ``root`` (the YAML node tree) adds
    line numbers. Raises :class:`ConfigError` ``source[:line]: field: message`` for every
    mistake: not a mapping, ``kind`` missing or unknown, an unknown key (with the key
    meant), a missing, mistyped or out-of-range value.
    """
    def where(loc) -> str:
        line = node_line(root, loc) if root is not None else None
        return f"{source}:{line}" if line is not None else source

    if not isinstance(data, dict):
        raise ConfigError(f"{where(())}: (top level): the board must be a mapping of fields "
                          f"(kind, cols, rows, ...), got {type(data).__name__}")
    kinds = " or ".join(repr(k) for k in KINDS)
    if "kind" not in data:
        raise ConfigError(f"{where(())}: kind: required, but missing (write it out: {kinds})")
    kind = data["kind"]
    if not isinstance(kind, str) or kind not in KINDS:
        close = difflib.get_close_matches(str(kind), list(KINDS), n=1, cutoff=0.6)
        hint = f"; did you mean {close[0]!r}?" if close else ""
        raise ConfigError(f"{where(('kind',))}: kind: must be {kinds}, got {kind!r}{hint}")
    model = KINDS[kind]
    try:
        spec = model.model_validate(data)
    except ValidationError as exc:
        if root is not None:
            raise ConfigError(validation_message(source, exc, root, model)) from None
        err = ConfigError("; ".join(f"{source}: {_mapping_error(e, model)}" for e in exc.errors()))
        first = exc.errors()[0]
        err.loc, err.detail = tuple(first["loc"]), error_text(first, model)   # for a caller with lines
        raise err from None
    return spec.board()


def _mapping_error(err: dict, model: type[_Spec]) -> str:
    """One error of a mapping that has no lines to point at (a config's section, a
    calibration file's record): the field with the value it holds, ``cols = 2 must be ...``."""
    text, field = error_text(err, model), field_name(err["loc"])
    if err.get("type") in ("missing", "extra_forbidden"):
        return f"{field}: {text}"
    return f"{field} = {err.get('input')!r} {text}"


def load_board(path: Path | str):
    """The board described by the YAML file ``path`` (format: :mod:`cell.commands.calibrate`).

    :raises ConfigError: ``path[:line]: field: message``: the file is missing, unreadable,
        larger than :data:`MAX_BYTES`, not UTF-8, malformed, empty, not a mapping, uses
        YAML anchors, or holds a bad board (:func:`board_from_mapping`).
    """
    p = Path(path)
    try:
        size = p.stat().st_size
    except OSError:
        size = 0                                  # read_text says what is wrong
    if size > MAX_BYTES:
        raise ConfigError(f"{p}: board file is {size} bytes; a board is described in a few "
                          f"lines (at most {MAX_BYTES} bytes): is this the right file?")
    text = read_text(p, "board file")
    data, root = parse_yaml(text, str(p), "board file")
    return board_from_mapping(data, str(p), root)
