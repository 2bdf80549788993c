"""The plant messages' JSON payloads (contract: ``cell/plant.md``), checked with pydantic
both ways: :func:`cycle_payload` and friends build them, :func:`parse` reads one.

Every payload is one JSON object with ``schema`` (the version of that kind's payload:
:data:`KNOWN_VERSIONS`; cycle, event and watermark are at 1, status at 2, which adds the
cell's state to version 1 and is the one written) and ``cell`` (the cell's id,
``site/line/cell``, which must match the topic). An event's ``data`` is checked against its
kind's model in :mod:`cell.plant.events` when the kind is known. A cycle message
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

SCHEMA_VERSION = 1          #: the version of the cycle, event and watermark payloads
STATUS_VERSION = 2          #: the version of the status payload this code writes
#: the versions this reader knows, per kind (status 2 is status 1 with the cell's state)
KNOWN_VERSIONS: dict[str, tuple[int, ...]] = {"cycle": (1,), "status": (1, 2), "event": (1,), "watermark": (1,)}


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
    schema_: Literal[1, 2] = Field(SCHEMA_VERSION, alias="schema")
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
    """``<cell>/status`` (retained): the birth (``online``) or the Last Will (offline).
    Version 2 adds the cell's state (:mod:`cell.plant.events`): ``state`` (the state
    machine's state, lower case; None: not known, as in a Last Will), ``fault_code`` (0:
    none) and ``fault_text``; a version-1 payload has none of them."""

    online: bool
    session: int = Field(ge=0)
    log_id: str | None = None
    at: str
    state: str | None = Field(None, min_length=1, max_length=32)
    fault_code: int | None = Field(None, ge=0)
    fault_text: str | None = Field(None, max_length=500)

    @model_validator(mode="after")
    def _state_is_version_2(self) -> "StatusMessage":
        given = [k for k in ("state", "fault_code", "fault_text") if getattr(self, k) is not None]
        if self.schema_ == 1 and given:
            raise ValueError(f"{', '.join(given)}: a field of status version 2, not 1")
        return self


class EventMessage(_Envelope):
    """``<cell>/event``: something that happened to the cell that is not a cycle."""

    session: int = Field(ge=0)
    seq: int = Field(ge=1)
    kind: str = Field(pattern=r"^[a-z][a-z0-9_]{0,63}$")
    at: str
    data: dict = Field(default_factory=dict)

    @model_validator(mode="after")
    def _known_kind_data(self) -> "EventMessage":
        # a kind this reader knows has its data checked; one it does not know (added by a
        # newer cell) is taken as it is, its data uninterpreted (cell/plant.md)
        from cell.plant.events import EVENT_KINDS
        model = EVENT_KINDS.get(self.kind)
        if model is not None:
            try:
                model.model_validate(self.data)
            except ValidationError as exc:
                problems = "; ".join(f"data.{'.'.join(map(str, e['loc']))}: {e['msg']}" for e in exc.errors()[:5])
                raise ValueError(f"{self.kind} event: {problems}") from None
        return self


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


def status_payload(cell: str, online: bool, session: int, log_id: str | None = None,
                   state: dict | None = None) -> bytes:
    """A status message, version :data:`STATUS_VERSION`; ``state``: the cell's state
    (:func:`cell.plant.events.cell_state`; None: not known, the three fields null)."""
    st = state or {}
    return _dump(StatusMessage(schema=STATUS_VERSION, cell=cell, online=online, session=session, log_id=log_id,
                               at=utc_now(), state=st.get("state") or None, fault_code=st.get("fault_code"),
                               fault_text=st.get("fault_text")))


def event_payload(cell: str, session: int, seq: int, kind: str, data: dict | None = None,
                  at: str | None = None) -> bytes:
    """An event message; ``at``: when it happened (default now). Raises ``ValueError``
    (pydantic's) for a kind or data the schema refuses."""
    return _dump(EventMessage(cell=cell, session=session, seq=seq, kind=kind, at=at or utc_now(), data=data or {}))


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
        raise PayloadError(f"{where}payload has no 'schema' version (this reader knows "
                           f"{', '.join(map(str, KNOWN_VERSIONS[kind]))} for {kind})")
    known = KNOWN_VERSIONS[kind]
    if data["schema"] not in known or isinstance(data["schema"], bool):
        raise PayloadError(f"{where}unknown schema version {data['schema']!r} for {kind}: this reader "
                           f"knows {', '.join(map(str, known))}; nothing of it was read")
    try:
        msg = MODELS[kind].model_validate(data)
    except ValidationError as exc:
        problems = "; ".join(f"{'.'.join(map(str, e['loc'])) + ': ' if e['loc'] else ''}"
                             f"{e['msg'].removeprefix('Value error, ')}" for e in exc.errors()[:5])
        raise PayloadError(f"{where}invalid {kind} message: {problems}") from None
    if cell is not None and msg.cell != cell:
        raise PayloadError(f"{where}message is for cell {msg.cell!r}, not the topic's {cell!r}")
    return msg
