"""Shared pieces of the plant path's tests: a cell log with records, the outbox and the
historian on the test servers, and what PostgreSQL holds."""
from __future__ import annotations

from pathlib import Path

from cell.cyclelog import CycleLog, CycleRecord, CycleStatus, utc_now
from cell.plant.topics import CellTopics

TOPICS = CellTopics("site1", "line2", "cell-1")


def record(part_id: int) -> CycleRecord:
    """A done cycle as the runner logs it (values made up, types as the log's)."""
    now = utc_now()
    return CycleRecord(part_id=part_id, recipe="bracket-a", recipe_hash="ab" * 8, started_at=now,
                       finished_at=now, status=CycleStatus.DONE, cycle_time_s=1.25,
                       step_times={"APPROACH": 0.5}, method="lattice", target_mm=(400.0, 10.0),
                       initial_error_mm=0.31, final_error_mm=0.004, verify_error_mm=0.005, moves=2,
                       temp_c=21.5, trace=[{"moved": True}], motion={"mode": "corrected"})


def write_log(path: Path, n: int, first_part: int = 1) -> CycleLog:
    """A writer's log at ``path`` with ``n`` more cycles; the caller closes it."""
    log = CycleLog(path)
    for k in range(n):
        log.add_cycle(record(first_part + k))
    return log


def outbox_settings(broker, topics: CellTopics = TOPICS, **kw):
    from cell.plant.outbox import OutboxSettings
    return OutboxSettings(host=broker.host, port=broker.port, topics=topics, keepalive_s=5, **kw)


def historian_settings(broker, dsn: str, **kw):
    from cell.plant.historian import HistorianSettings
    return HistorianSettings(host=broker.host, port=broker.port, dsn=dsn, keepalive_s=5, **kw)


def pg_ids(dsn: str, cell: str = TOPICS.path) -> set[int]:
    """The cycle ids PostgreSQL holds for ``cell`` (empty if the table is not made yet)."""
    import psycopg
    with psycopg.connect(dsn) as db:
        if db.execute("SELECT to_regclass('cycles')").fetchone()[0] is None:
            return set()
        return {r[0] for r in db.execute("SELECT cycle_id FROM cycles WHERE cell = %s", (cell,))}


def log_ids(path: Path) -> set[int]:
    log = CycleLog(path, readonly=True)
    try:
        return {r.id for r in log.cycles()}
    finally:
        log.close()
