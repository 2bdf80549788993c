"""``cellctl audit verify|list`` on a real SQLite cycle log: the chain holds, and each way of
tampering (an edited row, a removed row in the middle, the end cut off) is named by row."""
from __future__ import annotations

import json
import sqlite3

import pytest

from cell.cli import main
from cell.cyclelog import CycleLog


@pytest.fixture
def db(tmp_path):
    path = tmp_path / "cell.sqlite"
    log = CycleLog(path)
    for i in range(5):
        log.audit("maintenance@10.0.0.7", "activate", f"recipes/r{i}.yaml", "h" * 64, "ok")
    log.close()
    return path


def _tamper(path, sql: str) -> None:
    con = sqlite3.connect(path)
    con.execute(sql)
    con.commit()
    con.close()


def test_verify_says_the_chain_holds(db, capsys):
    assert main(["audit", "verify", "--db", str(db)]) == 0
    assert "audit chain holds: 5 rows" in capsys.readouterr().out


@pytest.mark.parametrize("sql, row, words", [
    ("UPDATE audit SET result = 'forged' WHERE id = 3", 3, "content does not match"),
    ("DELETE FROM audit WHERE id = 2", 3, "prev_hash is not the row_hash"),
    ("DELETE FROM audit WHERE id >= 4", 4, "end of the trail was removed"),
])
def test_verify_names_the_first_broken_row_and_what_is_wrong(db, capsys, sql, row, words):
    _tamper(db, sql)
    before = db.read_bytes()
    assert main(["audit", "verify", "--db", str(db)]) == 1
    out = capsys.readouterr().out
    assert f"BROKEN at row {row}" in out and words in out
    assert db.read_bytes() == before          # read-only: verifying changes nothing


def test_list_prints_the_rows_with_who_did_what(db, capsys):
    assert main(["audit", "list", "--db", str(db), "--last", "2", "--json"]) == 0
    rows = json.loads(capsys.readouterr().out)
    assert [r["id"] for r in rows] == [4, 5]
    assert rows[0]["who"] == "maintenance@10.0.0.7" and rows[0]["target"] == "recipes/r3.yaml"


def test_no_log_or_bad_option_is_a_clear_error(tmp_path, capsys):
    assert main(["audit", "verify", "--db", str(tmp_path / "none.sqlite")]) == 2
    assert "no cycle log here" in capsys.readouterr().err
    CycleLog(tmp_path / "y.sqlite").close()
    assert main(["audit", "list", "--db", str(tmp_path / "y.sqlite"), "--last", "0"]) == 2
    assert "--last 0 must be ≥ 1" in capsys.readouterr().err
