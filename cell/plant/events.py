"""The cell's state and discrete events as the plant sees them (contract: ``cell/plant.md``).

One table, :data:`EVENT_KINDS`, names every event kind the cell publishes on
``<cell>/event`` and the fields of its ``data``; the payload check
(:mod:`cell.plant.schema`), the historian's table and the contract's list all follow it.
What the cell publishes comes from :mod:`cell.publish` (the controller's one outlet):

* its **state** (:func:`cell_state`): the state machine's state (``idle``, ``approach``,
  ``fault``, ... as :class:`cell.cycle.statemachine.State` names them, lower case), the
  fault code (0: none) and its text, taken from each ``status`` message of the publisher;
  it goes into the cell's retained ``status`` (schema version 2);
* events derived from two consecutive states (:func:`state_events`): ``fault`` (the fault
  code became non-zero or changed to another non-zero code), ``reset`` (it went back to
  0), ``recipe_selected`` (the active recipe number changed);
* events the cell publishes itself on the publisher's ``event`` topic:
  ``recipe_changed`` (the recipe store activated, rejected or removed a recipe file) and
  ``calibration_applied`` (a kinematic calibration was written and is used from now on).

No I/O.
"""
from __future__ import annotations

from typing import Literal

from pydantic import BaseModel, ConfigDict, Field


class _Data(BaseModel):
    model_config = ConfigDict(extra="forbid", frozen=True)


class FaultData(_Data):
    """``fault``: a fault was raised. ``code``: the fault code (docs/plc.md), ``text``: its
    text, ``state``: the state the cell went to."""

    code: int = Field(ge=1)
    text: str = ""
    state: str = ""


class ResetData(_Data):
    """``reset``: the fault ``code`` was cleared (the cell's fault code is 0 again)."""

    code: int = Field(ge=1)
    state: str = ""


class RecipeSelectedData(_Data):
    """``recipe_selected``: the active recipe is now ``number`` (0: none), named ``name``."""

    number: int = Field(ge=0)
    name: str = ""


class RecipeChangedData(_Data):
    """``recipe_changed``: the recipe store did ``action`` with the file ``target``
    (``hash``: the content's SHA-256 prefix, ``result``: its audit text, ``who``)."""

    action: Literal["activate", "reject", "remove"]
    target: str
    hash: str = ""
    result: str = ""
    who: str = ""


class CalibrationAppliedData(_Data):
    """``calibration_applied``: the cell moves with ``calibration`` (its name) from now on;
    ``path`` and ``sha256``: the calibration file written."""

    calibration: str
    path: str = ""
    sha256: str = ""


#: every event kind -> the model of its ``data``
EVENT_KINDS: dict[str, type[_Data]] = {
    "fault": FaultData, "reset": ResetData, "recipe_selected": RecipeSelectedData,
    "recipe_changed": RecipeChangedData, "calibration_applied": CalibrationAppliedData,
}

#: the fields of a status snapshot (cell.publish) that are the cell's state on the plant
STATE_FIELDS = ("state", "fault_code", "fault_text")


def cell_state(snapshot: dict) -> dict:
    """``state``, ``fault_code``, ``fault_text`` of a publisher status message."""
    return {"state": str(snapshot.get("state", "")), "fault_code": int(snapshot.get("fault_code") or 0),
            "fault_text": str(snapshot.get("fault_text") or "")}


def state_events(before: dict | None, after: dict) -> list[tuple[str, dict]]:
    """The events (kind, data) between two publisher status messages (``before`` None:
    the first one seen, which raises ``fault`` if the cell is already faulted)."""
    out: list[tuple[str, dict]] = []
    old_code = int(before.get("fault_code") or 0) if before else 0
    new_code = int(after.get("fault_code") or 0)
    state = str(after.get("state", ""))
    if new_code and new_code != old_code:
        out.append(("fault", {"code": new_code, "text": str(after.get("fault_text") or ""), "state": state}))
    elif old_code and not new_code:
        out.append(("reset", {"code": old_code, "state": state}))
    if before is not None and int(before.get("recipe_number") or 0) != int(after.get("recipe_number") or 0):
        out.append(("recipe_selected", {"number": int(after.get("recipe_number") or 0),
                                        "name": str(after.get("recipe_name") or "")}))
    return out
