"""The plant messages' JSON payloads, version 1 (contract: ``cell/plant.md``), checked with
pydantic both ways: :func:`cycle_payload` and friends build them, :func:`parse` reads one.

Every payload is one JSON object with ``schema`` (the payload version, :data:`SCHEMA_VERSION`)
and ``cell`` (the cell's id, ``site/line/cell``, which must match the topic). A cycle message
carries one row of the cell's SQLite log:

* ``log_id``: the identity of that log file (a new log starts its row ids at 1 again);
* ``cycle_id``: the row's id in the log, the record's key with ``cell`` and ``log_id``;
* ``prev_id``: the id of the row before it in the log when it was sent (0: none), so the
  historian can tell ids that never existed (or retention deleted) from a record still
  missing: every id strictly between ``prev_id`` and ``cycle_id`` does not exist;
* ``session``, ``seq``: the sender's MQTT session number (its birth message's) and the
  message's number in that session (1, 2, ...; re-sent records get new numbers);
* ``record``: the :class:`~cell.cyclelog.CycleRecord` fields but ``trace`` (large; stays
  in the log) and ``id`` (it is ``cycle_id``).

:func:`parse` raises :class:`PayloadError` naming what is wrong: not JSON, not an object,
an unknown ``schema`` version (said before any field is read), a field missing, unknown,
of the wrong type or out of range, or a ``cell`` that is not the topic's.
"""
from __future__ import annotations

import json
from dataclasses import fields as dataclass_fields
from datetime import datetime, timezone
from typing import Literal

from pydantic import BaseModel, ConfigDict, Field, ValidationError, model_validator

from cell.errors import CellError

SCHEMA_VERSION = 1          #: the payload version this code writes and reads
KNOWN_VERSIONS = (1,)


class PayloadError(CellError, ValueError):
    """A payload that is not a valid plant message; the message names the topic and why."""


class _Strict(BaseModel):
    model_config = ConfigDict(extra="forbid", frozen=True)


class CycleFields(_Strict):
    """The cycle record's fields (:class:`cell.cyclelog.CycleRecord` without trace and id)."""

    part_id: int
    recipe: str
    recipe_hash: str
    started_at: str
    finished_at: str
    status: Literal["done", "fault", "aborted"]
    cycle_time_s: float = Field(ge=0)
    step_times: dict[str, float] = Field(default_factory=dict)
    method: str | None = None
    target_mm: tuple[float, float] | None = None
    initial_error_mm: float | None = None
    final_error_mm: float | None = None
    verify_error_mm: float | None = None
    moves: int | None = None
    fault_code: int = 0
    fault_text: str = ""
    temp_c: float | None = None
    motion: dict = Field(default_factory=dict)
    calibration: str = ""


class _Envelope(_Strict):
    schema_: Literal[1] = Field(SCHEMA_VERSION, alias="schema")
    cell: str = Field(min_length=5, max_length=200)

    model_config = ConfigDict(extra="forbid", frozen=True, populate_by_name=True)


class CycleMessage(_Envelope):
    """``<cell>/cycle``: one log row."""

    log_id: str = Field(min_length=1, max_length=64)
    cycle_id: int = Field(ge=1)
    prev_id: int = Field(ge=0)
    session: int = Field(ge=0)
    seq: int = Field(ge=1)
    record: CycleFields

    @model_validator(mode="after")
    def _prev_below(self) -> "CycleMessage":
        if self.prev_id >= self.cycle_id:
            raise ValueError(f"prev_id {self.prev_id} must be below cycle_id {self.cycle_id}")
        return self


class StatusMessage(_Envelope):
    """``<cell>/status`` (retained): the birth (``online``) or the Last Will (offline)."""

    online: bool
    session: int = Field(ge=0)
    log_id: str | None = None
    at: str


class EventMessage(_Envelope):
    """``<cell>/event``: something that happened to the cell that is not a cycle."""

    session: int = Field(ge=0)
    seq: int = Field(ge=1)
    kind: str = Field(min_length=1, max_length=64)
    at: str
    data: dict = Field(default_factory=dict)


class Watermark(_Envelope):
    """``<cell>/watermark`` (retained, by the historian): every record of log ``log_id``
    with an id up to ``cycle_id`` is committed (0: none yet)."""

    log_id: str = Field(min_length=1, max_length=64)
    cycle_id: int = Field(ge=0)
    at: str


MODELS: dict[str, type[_Envelope]] = {"cycle": CycleMessage, "status": StatusMessage,
                                      "event": EventMessage, "watermark": Watermark}


def utc_now() -> str:
    return datetime.now(timezone.utc).isoformat(timespec="milliseconds")


def _dump(msg: _Envelope) -> bytes:
    return json.dumps(msg.model_dump(by_alias=True), separators=(",", ":")).encode()


def cycle_payload(cell: str, log_id: str, record, prev_id: int, session: int, seq: int) -> bytes:
    """The cycle message of ``record`` (a :class:`~cell.cyclelog.CycleRecord` read back from
    the log, so it has its ``id``), checked against :class:`CycleMessage`."""
    # the fields as they are (no deep copy as asdict makes: the model copies what it keeps)
    fields = {f.name: getattr(record, f.name) for f in dataclass_fields(record) if f.name != "trace"}
    cycle_id = fields.pop("id")
    fields["status"] = str(fields["status"])
    msg = CycleMessage(cell=cell, log_id=log_id, cycle_id=cycle_id, prev_id=prev_id, session=session,
                       seq=seq, record=CycleFields(**fields))
    return _dump(msg)


def status_payload(cell: str, online: bool, session: int, log_id: str | None = None) -> bytes:
    return _dump(StatusMessage(cell=cell, online=online, session=session, log_id=log_id, at=utc_now()))


def event_payload(cell: str, session: int, seq: int, kind: str, data: dict | None = None) -> bytes:
    return _dump(EventMessage(cell=cell, session=session, seq=seq, kind=kind, at=utc_now(), data=data or {}))


def watermark_payload(cell: str, log_id: str, cycle_id: int) -> bytes:
    return _dump(Watermark(cell=cell, log_id=log_id, cycle_id=cycle_id, at=utc_now()))


def parse(kind: str, topic: str, payload: bytes, cell: str | None = None) -> _Envelope:
    """The message of ``kind`` in ``payload`` received on ``topic``; ``cell``: the id the
    topic names (the message's ``cell`` must equal it). Raises :class:`PayloadError`."""
    where = f"{topic}: "
    try:
        data = json.loads(payload)
    except (UnicodeDecodeError, ValueError) as exc:
        raise PayloadError(f"{where}payload is not JSON ({exc}); first bytes: {bytes(payload[:40])!r}") from None
    if not isinstance(data, dict):
        raise PayloadError(f"{where}payload is a JSON {type(data).__name__}, not an object")
    if "schema" not in data:
        raise PayloadError(f"{where}payload has no 'schema' version (this reader knows {KNOWN_VERSIONS})")
    if data["schema"] not in KNOWN_VERSIONS or isinstance(data["schema"], bool):
        raise PayloadError(f"{where}unknown schema version {data['schema']!r}: this reader knows "
                           f"{', '.join(map(str, KNOWN_VERSIONS))}; nothing of it was read")
    try:
        msg = MODELS[kind].model_validate(data)
    except ValidationError as exc:
        problems = "; ".join(f"{'.'.join(map(str, e['loc'])) or 'payload'}: {e['msg']}"
                             for e in exc.errors()[:5])
        raise PayloadError(f"{where}invalid {kind} message: {problems}") from None
    if cell is not None and msg.cell != cell:
        raise PayloadError(f"{where}message is for cell {msg.cell!r}, not the topic's {cell!r}")
    return msg
