"""The plant's MQTT topic tree: ``<site>/<line>/<cell>/<kind>`` (contract: ``cell/plant.md``).

One cell publishes under its own prefix; the historian publishes the cell's watermark under
the same prefix. Kinds:

========== ============== ======== ===== ====================================================
kind       published by   retained QoS   payload (:mod:`cell.plant.schema`)
========== ============== ======== ===== ====================================================
status     the cell       yes      1     birth (online, session, state) / Last Will (offline)
cycle      the cell       no       1     one cycle record of the log
event      the cell       no       1     something that happened (not a cycle)
watermark  the historian  yes      1     highest cycle id committed with every one below it
========== ============== ======== ===== ====================================================

A name segment is 1 to 64 of ``A-Z a-z 0-9 _ . -``: never ``/``, ``+`` or ``#`` (MQTT's
level separator and wildcards) and never ``$`` first (broker topics). No I/O.
"""
from __future__ import annotations

import re
from dataclasses import dataclass

from cell.errors import CellError

KINDS = ("status", "cycle", "event", "watermark")
_SEGMENT = re.compile(r"[A-Za-z0-9_.\-]{1,64}")


class TopicError(CellError, ValueError):
    """A site, line or cell name, or a topic, that the tree does not allow; says which."""


def check_segment(what: str, value: str) -> str:
    """``value`` if it is a valid name segment; raises :class:`TopicError` naming ``what``."""
    if not isinstance(value, str) or not _SEGMENT.fullmatch(value):
        raise TopicError(f"{what} {value!r} is not a topic name segment: use 1 to 64 of "
                         "A-Z a-z 0-9 _ . - (no '/', '+', '#')")
    return value


@dataclass(frozen=True)
class CellTopics:
    """The topics of one cell. ``path`` (``site/line/cell``) is the cell's id in the plant."""

    site: str
    line: str
    cell: str

    def __post_init__(self):
        check_segment("site", self.site)
        check_segment("line", self.line)
        check_segment("cell", self.cell)

    @property
    def path(self) -> str:
        return f"{self.site}/{self.line}/{self.cell}"

    def topic(self, kind: str) -> str:
        if kind not in KINDS:
            raise TopicError(f"unknown topic kind {kind!r}; known: {', '.join(KINDS)}")
        return f"{self.path}/{kind}"

    @property
    def status(self) -> str:
        return self.topic("status")

    @property
    def cycle(self) -> str:
        return self.topic("cycle")

    @property
    def event(self) -> str:
        return self.topic("event")

    @property
    def watermark(self) -> str:
        return self.topic("watermark")

    @classmethod
    def from_path(cls, path: str) -> "CellTopics":
        """From a cell id ``site/line/cell``; raises :class:`TopicError`."""
        parts = path.split("/") if isinstance(path, str) else []
        if len(parts) != 3:
            raise TopicError(f"cell id {path!r} is not site/line/cell")
        return cls(*parts)


def parse(topic: str) -> tuple[CellTopics, str]:
    """(the cell's topics, kind) of a topic of the tree; raises :class:`TopicError`."""
    parts = topic.split("/")
    if len(parts) != 4 or parts[3] not in KINDS:
        raise TopicError(f"topic {topic!r} is not <site>/<line>/<cell>/<kind> with kind one of "
                         f"{', '.join(KINDS)}")
    return CellTopics(*parts[:3]), parts[3]


def subscription(kind: str, site: str = "+", line: str = "+", cell: str = "+") -> str:
    """A topic filter for ``kind`` under the given site, line and cell (``+``: any)."""
    if kind not in KINDS:
        raise TopicError(f"unknown topic kind {kind!r}; known: {', '.join(KINDS)}")
    for what, value in (("site", site), ("line", line), ("cell", cell)):
        if value != "+":
            check_segment(what, value)
    return f"{site}/{line}/{cell}/{kind}"
