"""What the OPC UA server shows, folded from the Publisher's messages. Pure: no asyncua,
no I/O, no clock; :mod:`cell.opcua.space` writes these values into nodes.

* :class:`CellStatus` — the last ``status`` message: controller state, fault code and
  text, cycles done, active recipe (number and name), recalibration due, and the joints'
  actual positions ``joints`` (j1..j4, deg; mm for j3; None until every station has
  reported one).
* :class:`Result` — one settled cycle (a ``cycle`` message), as ``GetLatestResult``
  returns it and a result-ready event carries it. A figure the cycle did not measure (a
  part faulted before its verify move) is NaN: an OPC UA Double has no null.
"""
from __future__ import annotations

import math
from dataclasses import dataclass, fields

#: joints in the order of every per-joint value, with their unit and OPC 40010 motion profile
AXES = (("j1", "deg", "ROTARY"), ("j2", "deg", "ROTARY"), ("j3", "mm", "LINEAR"), ("j4", "deg", "ROTARY"))


@dataclass(frozen=True)
class CellStatus:
    state: str = "unknown"
    fault_code: int = 0
    fault_text: str = ""
    cycle_count: int = 0
    recipe_number: int = 0
    recipe_name: str = ""
    recalibration_due: bool = False
    joints: tuple[float, ...] | None = None

    @classmethod
    def from_message(cls, msg: dict) -> "CellStatus":
        """From a ``status`` message (:meth:`cell.controller.CellController.status_snapshot`);
        keys it lacks keep their defaults, keys it adds are ignored."""
        joints = msg.get("joints")
        return cls(state=str(msg.get("state", "unknown")), fault_code=int(msg.get("fault_code") or 0),
                   fault_text=str(msg.get("fault_text") or ""), cycle_count=int(msg.get("cycle_count") or 0),
                   recipe_number=int(msg.get("recipe_number") or 0), recipe_name=str(msg.get("recipe_name") or ""),
                   recalibration_due=bool(msg.get("recalibration_due")),
                   joints=tuple(float(q) for q in joints) if joints is not None else None)


@dataclass(frozen=True)
class Result:
    """One settled cycle. ``result_id`` is the cycle log's row id (unique per log)."""

    result_id: int
    part_id: int
    status: str                 #: done, aborted or fault, as the PLC was told
    final_error_mm: float
    verify_error_mm: float
    moves: int
    recipe: str
    fault_code: int
    fault_text: str
    cycle_time_s: float
    finished_at: str            #: ISO 8601, UTC, as logged

    @classmethod
    def from_message(cls, msg: dict) -> "Result":
        """From a ``cycle`` message (:meth:`cell.publish.Publisher.cycle`)."""
        c = msg["cycle"]
        return cls(result_id=int(c.get("id") or 0), part_id=int(c["part_id"]), status=str(c["status"]),
                   final_error_mm=_num(c.get("final_error_mm")), verify_error_mm=_num(c.get("verify_error_mm")),
                   moves=int(c.get("moves") or 0), recipe=str(c.get("recipe") or ""),
                   fault_code=int(c.get("fault_code") or 0), fault_text=str(c.get("fault_text") or ""),
                   cycle_time_s=_num(c.get("cycle_time_s")), finished_at=str(c.get("finished_at") or ""))

    def values(self) -> list:
        """The fields in declaration order (:data:`RESULT_FIELDS`)."""
        return [getattr(self, f.name) for f in fields(self)]


def _num(v) -> float:
    return math.nan if v is None else float(v)


#: (field, OPC UA name, builtin type name, unit or '') of a result: the outputs of
#: GetLatestResult and the fields of ResultReadyEventType, in this order
RESULT_FIELDS = (("result_id", "ResultId", "Int64", ""), ("part_id", "PartId", "Int64", ""),
                 ("status", "Status", "String", ""), ("final_error_mm", "FinalErrorMm", "Double", "mm"),
                 ("verify_error_mm", "VerifyErrorMm", "Double", "mm"), ("moves", "Moves", "Int32", ""),
                 ("recipe", "Recipe", "String", ""), ("fault_code", "FaultCode", "Int32", ""),
                 ("fault_text", "FaultText", "String", ""), ("cycle_time_s", "CycleTimeS", "Double", "s"),
                 ("finished_at", "FinishedAt", "String", ""))
assert tuple(f[0] for f in RESULT_FIELDS) == tuple(f.name for f in fields(Result))


class Fold:
    """Messages in, what changed out: the latest status, the latest result, and the
    results settled since the last :meth:`take` (one result-ready event each)."""

    def __init__(self):
        self.status: CellStatus | None = None
        self.latest: Result | None = None

    def take(self, msgs: list[dict]) -> tuple[CellStatus | None, list[Result]]:
        """Fold ``msgs`` (oldest first); returns the new status if one came (the last of
        them: status is a state, not a history) and every new result in order."""
        status, results = None, []
        for m in msgs:
            if m.get("topic") == "status":
                status = CellStatus.from_message(m)
            elif m.get("topic") == "cycle":
                results.append(Result.from_message(m))
        if status is not None:
            self.status = status
        if results:
            self.latest = results[-1]
        return status, results
