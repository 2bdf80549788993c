"""Cycle log: durable settings, one row per cycle, hash-chained audit, recipe versions."""
import sqlite3

import pytest

from cell.cyclelog import _SCHEMA, CycleLog, CycleRecord, CycleStatus, utc_now


def record(i, **kw):
    base = dict(part_id=i, recipe="bracket-a", recipe_hash="ab" * 32, started_at=utc_now(),
                finished_at=utc_now(), status="done", cycle_time_s=1.5,
                step_times={"approach": 0.5, "verify": 0.1}, method="lattice",
                target_mm=(250.0, 930.0), initial_error_mm=0.6, final_error_mm=0.03, moves=2,
                trace=[{"joints_deg": [60, 30], "point_mm": [250, 933], "error_mm": 3.0, "moved": True}])
    base.update(kw)
    return CycleRecord(**base)


def test_pragmas_and_round_trip(tmp_path):
    log = CycleLog(tmp_path / "cell.sqlite")
    assert log._db.execute("PRAGMA journal_mode").fetchone()[0] == "wal"
    assert log._db.execute("PRAGMA synchronous").fetchone()[0] == 2        # FULL
    ids = [log.add_cycle(record(i)) for i in range(3)]
    got = log.cycles()
    assert [c.id for c in got] == ids and got[1].part_id == 1
    assert got[0].step_times == {"approach": 0.5, "verify": 0.1}
    assert got[0].trace[0]["point_mm"] == [250, 933] and got[0].target_mm == (250.0, 930.0)
    assert log.cycles(limit=1)[0].part_id == 2
    log.close()
    again = CycleLog(tmp_path / "cell.sqlite")
    assert again.count() == 3


def test_statuses_are_the_logs_and_read_back_as_such(tmp_path):
    # the enum and the table's CHECK constraint name the same three statuses
    assert "CHECK (status IN ('done', 'fault', 'aborted'))" in _SCHEMA
    assert [s.value for s in CycleStatus] == ["done", "fault", "aborted"]
    log = CycleLog(tmp_path / "cell.sqlite")
    log.add_cycle(record(1, status=CycleStatus.FAULT))
    log.add_cycle(record(2))
    got = log.cycles()
    assert [c.status for c in got] == [CycleStatus.FAULT, CycleStatus.DONE]
    assert all(isinstance(c.status, CycleStatus) for c in got)
    assert [c.part_id for c in log.cycles(status=CycleStatus.DONE)] == [2]


def test_bad_status_is_refused_and_nothing_written(tmp_path):
    log = CycleLog(tmp_path / "cell.sqlite")
    with pytest.raises(sqlite3.IntegrityError):
        log.add_cycle(record(1, status="half-done"))
    assert log.count() == 0


def test_retention(tmp_path):
    log = CycleLog(tmp_path / "cell.sqlite")
    log.add_cycle(record(1, finished_at="2020-01-01T00:00:00+00:00"))
    log.add_cycle(record(2))
    assert log.delete_older_than("2021-01-01T00:00:00+00:00") == 1
    assert [c.part_id for c in log.cycles()] == [2]


def test_audit_chain_detects_tampering(tmp_path):
    log = CycleLog(tmp_path / "cell.sqlite")
    for i in range(3):
        log.audit("maint", "activate", f"recipes/r{i}.yaml", "h" * 64, "ok")
    assert log.verify_audit() is None
    log._db.execute("UPDATE audit SET result = 'forged' WHERE id = 2")
    assert log.verify_audit() == 2


def test_recipe_versions(tmp_path):
    log = CycleLog(tmp_path / "cell.sqlite")
    log.remember_recipe("a", "h1", "v1")
    log.remember_recipe("a", "h2", "v2")
    log.remember_recipe("a", "h1", "v1")           # re-activating an old version is not a new row
    assert log.last_recipe_version("a") == ("h2", "v2")
    assert log.last_recipe_version("b") is None


def test_the_last_cycles_are_read_without_reading_the_whole_log(tmp_path):
    """The drift job and the offset memory read the last N done cycles every few seconds; a
    week of production is over a million rows, so only those N may be read."""
    log = CycleLog(tmp_path / "cell.sqlite")
    for i in range(60):
        log.add_cycle(record(i, status="done" if i % 3 else "aborted"))
    statements = []
    log._db.set_trace_callback(statements.append)
    got = log.cycles(limit=4, status="done")
    log._db.set_trace_callback(None)
    assert [c.part_id for c in got] == [55, 56, 58, 59]          # the last four done, in order
    assert [c.part_id for c in log.cycles(limit=2)] == [58, 59]
    assert len(statements) == 1 and "LIMIT" in statements[0]
    log.close()


def test_a_schema_3_log_gains_the_calibration_column_and_keeps_its_rows(tmp_path):
    path = tmp_path / "cell.sqlite"
    log = CycleLog(path)
    log.add_cycle(record(1))
    log.close()
    db = sqlite3.connect(path)                 # what a schema 3 controller left behind
    db.execute("ALTER TABLE cycles DROP COLUMN calibration")
    db.execute("UPDATE meta SET value = '3' WHERE key = 'schema_version'")
    db.commit()
    db.close()
    log = CycleLog(path)
    log.add_cycle(record(2, calibration="v4-0123abcd"))
    assert [(r.part_id, r.calibration) for r in log.cycles()] == [(1, ""), (2, "v4-0123abcd")]
    assert log._db.execute("SELECT value FROM meta WHERE key = 'schema_version'").fetchone()[0] == "4"
    log.close()


def test_a_log_has_one_identity_for_life_and_the_outbox_reads_rows_above_an_id(tmp_path):
    log = CycleLog(tmp_path / "cell.sqlite")
    ids = [log.add_cycle(record(i)) for i in range(6)]
    log._db.execute("DELETE FROM cycles WHERE id IN (?, ?)", (ids[2], ids[3]))   # a gap, as retention makes
    first = log.log_id
    assert first and len(first) == 32
    assert [c.id for c in log.cycles_after(ids[0], limit=2)] == [ids[1], ids[4]]
    assert [c.id for c in log.cycles_after(ids[0], limit=9, below=ids[5])] == [ids[1], ids[4]]
    assert log.id_before(ids[4]) == ids[1] and log.id_before(ids[0]) == 0
    assert log.count_after(ids[1]) == 2
    # what the outbox sends: rows up to the one the PLC has not been told of
    assert [c.id for c in log.settled_after(ids[0], limit=9)] == [ids[1], ids[4], ids[5]]
    rec = record(7)
    log.begin_cycle(rec.part_id, rec.recipe, rec.recipe_hash, rec.started_at)
    assert [c.id for c in log.settled_after(ids[0], limit=9)] == [ids[1], ids[4], ids[5]]    # running: no row
    held = log.add_cycle(rec)
    after = log.add_cycle(record(8))
    assert [c.id for c in log.settled_after(ids[0], limit=9)] == [ids[1], ids[4], ids[5]]    # logged: held back
    log.settle_cycle(rec.started_at, held, rec.status, 0, "")
    assert [c.id for c in log.settled_after(ids[4], limit=9)] == [ids[5], held, after]
    log.close()
    again = CycleLog(tmp_path / "cell.sqlite", readonly=True)
    assert again.log_id == first                       # kept across opens
    again.close()
    fresh = CycleLog(tmp_path / "cell.sqlite", fresh=True)
    assert fresh.log_id != first                       # a fresh log is another log: its ids restart
    fresh.close()
