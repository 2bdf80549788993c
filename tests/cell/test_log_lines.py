"""Structured log lines from several threads stay one event per line (issue 13: two threads'
lines ran together on one line, because the event and its newline were two writes)."""
from __future__ import annotations

import json
import sys
import threading
import time

from cell import log


class SlowStream:
    """A stream that gives up the GIL inside every write, as a pipe to a slow reader does."""

    def __init__(self):
        self.parts: list[str] = []

    def write(self, s: str) -> int:
        time.sleep(0)
        self.parts.append(s)
        return len(s)

    def flush(self) -> None:
        time.sleep(0)


def test_lines_from_two_threads_never_run_together(monkeypatch):
    stream = SlowStream()
    monkeypatch.setattr(sys, "stderr", stream)
    log.configure("json")
    logger = log.get_logger("test")

    def emit(who: str) -> None:
        for i in range(400):
            logger.info("tick", who=who, i=i)
    threads = [threading.Thread(target=emit, args=(w,)) for w in ("a", "b", "c")]
    for t in threads:
        t.start()
    for t in threads:
        t.join()
    log.configure()
    lines = "".join(stream.parts).splitlines()
    assert len(lines) == 1200
    events = [json.loads(line) for line in lines]          # each line one whole event
    assert sorted((e["who"], e["i"]) for e in events) == sorted((w, i) for w in "abc" for i in range(400))
