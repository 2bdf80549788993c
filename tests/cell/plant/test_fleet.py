"""``cellctl fleet report`` and the line status, read from a real PostgreSQL that the
historian's own store filled: shifts in UTC (early 06-14, late 14-22, night 22-06 counted
to the day it starts), p50/p95 against numpy, parts and faults counted, and a database
that cannot answer is a clear error with exit status 2."""
from __future__ import annotations

import json
from datetime import datetime, timezone

import numpy as np
import pytest

from cell.cli import main
from cell.plant import fleet
from tests.cell.plant.helpers import cycle_message, fill_store


def utc(text: str) -> datetime:
    return datetime.fromisoformat(text).replace(tzinfo=timezone.utc)


@pytest.mark.parametrize("at, day, shift", [
    ("2026-11-27 06:00:00", "2026-11-27", "early"), ("2026-11-27 13:59:59", "2026-11-27", "early"),
    ("2026-11-27 14:00:00", "2026-11-27", "late"), ("2026-11-27 22:00:00", "2026-11-27", "night"),
    ("2026-11-28 03:00:00", "2026-11-27", "night"), ("2026-11-28 05:59:59", "2026-11-27", "night")])
def test_shifts_are_three_8_hour_shifts_in_utc_from_06_00(at, day, shift):
    assert fleet.shift_of(utc(at)) == (datetime.fromisoformat(day).date(), shift)
    # another zone's clock names the same moment, so the same shift
    assert fleet.shift_of(utc(at).astimezone(timezone(fleet.timedelta(hours=-5)))) == fleet.shift_of(utc(at))


EARLY = [0.010, 0.020, 0.030, 0.040, 0.100]


def messages():
    """cell-1: 5 done and 1 fault in the early shift of 27 Nov (bracket-a), 2 done of
    recipe plate-b in the night shift (one at 23:00, one at 02:00 the next day);
    cell-2: 3 done in the late shift."""
    out = [cycle_message("s/l/cell-1", k + 1, f"2026-11-27T0{7 + k}:00:00+00:00", final_mm=e, verify_mm=e + 0.001)
           for k, e in enumerate(EARLY)]
    out.append(cycle_message("s/l/cell-1", 6, "2026-11-27T12:30:00+00:00", status="fault", fault_code=31))
    out.append(cycle_message("s/l/cell-1", 7, "2026-11-27T23:00:00+00:00", recipe="plate-b", final_mm=0.2))
    out.append(cycle_message("s/l/cell-1", 8, "2026-11-28T02:00:00+00:00", recipe="plate-b", final_mm=0.4))
    out += [cycle_message("s/l/cell-2", k + 1, f"2026-11-27T1{5 + k}:00:00+00:00", final_mm=0.005 * (k + 1))
            for k in range(3)]
    return out


def test_the_report_per_cell_recipe_and_shift(historian_db, tmp_path, capsys):
    fill_store(historian_db, messages())
    groups = fleet.summarise(fleet.read_cycles(historian_db))
    assert [(g.cell, g.recipe, g.shift, g.parts, g.faults) for g in groups] == [
        ("s/l/cell-1", "bracket-a", "2026-11-27 early 06:00-14:00 UTC", 5, 1),
        ("s/l/cell-1", "plate-b", "2026-11-27 night 22:00-06:00 UTC", 2, 0),
        ("s/l/cell-2", "bracket-a", "2026-11-27 late 14:00-22:00 UTC", 3, 0)]
    g = groups[0]
    assert (g.final_p50_mm, g.final_p95_mm) == pytest.approx(tuple(np.percentile(EARLY, [50, 95])))
    assert g.verify_p95_mm == pytest.approx(np.percentile(np.add(EARLY, 0.001), 95))
    assert groups[1].final_p50_mm == pytest.approx(0.3)

    png = tmp_path / "out" / "fleet.png"
    png.parent.mkdir()
    assert main(["fleet", "report", "--dsn", historian_db, "--png", str(png)]) == 0
    out = capsys.readouterr().out
    assert "2 cell(s), 10 parts; shifts in UTC: early 06:00-14:00, late 14:00-22:00, night 22:00-06:00" in out
    assert "| s/l/cell-1 | bracket-a | 2026-11-27 early 06:00-14:00 UTC | 5 | 1 | 0 | 0.0300 | 0.0880 |" in out
    assert png.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"

    assert main(["fleet", "report", "--dsn", historian_db, "--json", "--cells", "s/l/cell-2"]) == 0
    doc = json.loads(capsys.readouterr().out)
    assert doc["shifts"]["night"] == "22:00-06:00 UTC" and doc["units"] == {"errors": "mm"}
    assert [(g["cell"], g["parts"]) for g in doc["groups"]] == [("s/l/cell-2", 3)]


def test_a_database_that_cannot_answer_is_exit_status_2(postgres, historian_db, capsys, monkeypatch):
    from cell.plant.servers import free_port
    away = f"host=127.0.0.1 port={free_port()} user=cell dbname=historian connect_timeout=3"
    assert main(["fleet", "report", "--dsn", away]) == 2
    assert "cannot reach the historian's database" in capsys.readouterr().err
    assert main(["fleet", "report", "--dsn", historian_db]) == 2           # no tables yet
    assert "no historian tables" in capsys.readouterr().err
    fill_store(historian_db, [])                                           # migrated, empty
    assert main(["fleet", "report", "--dsn", historian_db]) == 2
    assert "no cycle records in the historian's database" in capsys.readouterr().err
    monkeypatch.delenv("CELL_HISTORIAN_DSN", raising=False)
    assert main(["fleet", "report"]) == 2
    assert "give --dsn or set CELL_HISTORIAN_DSN" in capsys.readouterr().err


def test_the_line_status_of_each_cell(historian_db):
    import psycopg
    now = utc("2026-11-27 13:00:00")
    msgs = messages()
    gap = cycle_message("s/l/cell-2", 6, "2026-11-27T12:00:00+00:00", final_mm=0.01)   # 4 and 5 missing
    fill_store(historian_db, msgs + [gap.model_copy(update={"prev_id": 4})])
    with psycopg.connect(historian_db) as db:
        db.execute("INSERT INTO cell_status (cell, online, session, log_id, at) VALUES"
                   " ('s/l/cell-1', true, 4, %s, 'x'), ('s/l/cell-3', false, 2, NULL, 'x')", ("a" * 32,))
        db.execute("INSERT INTO cell_status (cell, online, session, log_id, at, state, fault_code, fault_text)"
                   " VALUES ('s/l/cell-4', true, 5, NULL, 'x', 'fault', 31, 'camera lost the part'),"
                   " ('s/l/cell-5', true, 2, NULL, 'x', 'idle', 0, ''),"
                   " ('s/l/cell-6', true, 2, NULL, 'x', 'resetting', 31, '')")
    lines = {c.cell: c for c in fleet.line_status(historian_db, now)}
    assert sorted(lines) == ["s/l/cell-1", "s/l/cell-2", "s/l/cell-3", "s/l/cell-4", "s/l/cell-5", "s/l/cell-6"]
    c1, c2, c3 = lines["s/l/cell-1"], lines["s/l/cell-2"], lines["s/l/cell-3"]
    assert c1.online is True and c1.session == 4 and c1.received == 8 and c1.watermark == 8 and c1.held_above == 0
    assert (c1.last_part, c1.last_recipe, c1.last_outcome) == (8, "plate-b", "done")
    assert c1.state == "online, last cycle done"
    assert c2.online is None and c2.state == "no status heard"
    assert (c2.received, c2.highest_id, c2.watermark, c2.held_above) == (4, 6, 3, 1)
    assert c3.state == "offline" and c3.received == 0 and c3.last_part is None
    # a status of version 2 says the cell's state, and its fault
    assert lines["s/l/cell-4"].state == "online, fault 31: camera lost the part"
    assert (lines["s/l/cell-4"].cell_state, lines["s/l/cell-4"].fault_code) == ("fault", 31)
    assert lines["s/l/cell-5"].state == "online, idle"
    assert lines["s/l/cell-6"].state == "online, resetting (fault 31)"
    # this shift (early of the 27th) and the one before (night of the 26th, nothing)
    early = [s for s in c1.shifts if s["current"]]
    assert early and early[0]["parts"] == 5 and early[0]["faults"] == 1
    assert early[0]["final_p95_mm"] == pytest.approx(np.percentile(EARLY, 95))
