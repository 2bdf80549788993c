"""Shared pieces of the plant path's tests: a cell log with records, the outbox and the
historian on the test servers, and what PostgreSQL holds."""
from __future__ import annotations

from contextlib import contextmanager
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


@contextmanager
def mqtt_client(broker):
    """A plain MQTT 5 client connected to ``broker``, its network loop running (another cell,
    or a stranger, on the plant's topics); stopped and disconnected at the end."""
    import paho.mqtt.client as mqtt
    c = mqtt.Client(mqtt.CallbackAPIVersion.VERSION2, protocol=mqtt.MQTTv5)
    c.connect(broker.host, broker.port)
    c.loop_start()
    try:
        yield c
    finally:
        c.loop_stop()
        c.disconnect()


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


def cycle_message(cell: str, cycle_id: int, finished_at: str, *, log_id: str = "a" * 32, recipe: str = "bracket-a",
                  status: str = "done", final_mm: float | None = 0.004, verify_mm: float | None = 0.005,
                  fault_code: int = 0, part_id: int | None = None):
    """A checked cycle message as the historian takes it (values made up; ``finished_at``
    ISO 8601 UTC places it in a shift)."""
    from cell.plant.schema import CycleFields, CycleMessage
    done = status == "done"
    return CycleMessage(cell=cell, log_id=log_id, cycle_id=cycle_id, prev_id=cycle_id - 1, session=1, seq=cycle_id,
                        record=CycleFields(part_id=part_id or cycle_id, recipe=recipe, recipe_hash="ab" * 8,
                                           started_at=finished_at, finished_at=finished_at, status=status,
                                           cycle_time_s=1.5, final_error_mm=final_mm if done else None,
                                           verify_error_mm=verify_mm if done else None, fault_code=fault_code,
                                           fault_text="camera lost the part" if fault_code else ""))


def fill_store(dsn: str, messages) -> None:
    """Commit ``messages`` through the historian's own store (its migrations, its watermarks)."""
    from cell.plant.store import HistorianStore
    store = HistorianStore(dsn)
    try:
        store.connect()
        store.commit(list(messages))
    finally:
        store.close()
