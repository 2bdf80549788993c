"""Export of logged cycles to the measurement format (round trip) and the report command."""
import numpy as np
import pytest

from cell.cli import main
from cell.cyclelog import CycleLog, CycleRecord
from cell.cyclelog.export import cycles_to_campaign
from cell.measurements import read_campaign, write_campaign


def trace(q0):
    return [{"joints_deg": list(q0), "point_mm": [250.0, 933.0], "error_mm": 0.5, "moved": True},
            {"joints_deg": [q0[0] + 0.1, q0[1] - 0.02], "point_mm": [249.9, 933.1], "error_mm": 0.03, "moved": True},
            {"joints_deg": [q0[0] + 0.1, q0[1] - 0.02], "point_mm": [249.9, 933.1], "error_mm": 0.03, "moved": False},
            {"joints_deg": [q0[0] + 0.1, q0[1] - 0.01], "point_mm": [249.91, 933.1], "error_mm": 0.02, "moved": True}]


@pytest.fixture
def db(tmp_path):
    log = CycleLog(tmp_path / "cell.sqlite")
    for i in range(12):
        log.add_cycle(CycleRecord(
            part_id=100 + i, recipe="bracket-a", recipe_hash="h", status="done" if i != 5 else "fault",
            started_at=f"2026-11-23T10:00:{i:02d}+00:00", finished_at=f"2026-11-23T10:00:{i:02d}+00:00",
            cycle_time_s=1.0, method="lattice", initial_error_mm=0.5, final_error_mm=0.02 + 0.001 * i,
            moves=3, temp_c=21.0 + i, trace=trace((60.0, 30.0))))
    return log


def test_export_round_trips_through_the_exchange_format(db, tmp_path):
    campaign = cycles_to_campaign(db.cycles(status="done"), 500, 500, command_unit_deg=0.01)
    back = read_campaign(write_campaign(campaign, tmp_path / "camp"))
    assert len(back.points["sample"]) == 11 * 3                     # moved steps only
    for k, v in campaign.points.items():
        np.testing.assert_array_equal(back.points[k], v)
    # directions: j1 moved up (+1), j2 moved down (-1) then up (+1)
    assert back.points["j1_dir"][:3].tolist() == [1, 1, 1]
    assert back.points["j2_dir"][:3].tolist() == [1, -1, 1]
    assert back.points["time_s"][3] == 1.0 and back.points["temp_c"][0] == 21.0


def test_export_refuses_empty(tmp_path):
    with pytest.raises(ValueError, match="no logged cycle"):
        cycles_to_campaign([], 500, 500)


def test_report_prints_blocks_and_writes_png(db, tmp_path, capsys):
    png = tmp_path / "trend.png"
    assert main(["report", "--db", str(db.path), "--block", "5", "--png", str(png)]) == 0
    out = capsys.readouterr().out
    assert "12 cycles" in out and out.count("\n| ") == 3 + 1
    assert "| 1–5 | 100 |" in out and png.stat().st_size > 1000


def test_report_and_export_bad_input(tmp_path, capsys):
    assert main(["report", "--db", str(tmp_path / "none.sqlite")]) == 2
    assert "no cycle log" in capsys.readouterr().err
    CycleLog(tmp_path / "empty.sqlite")
    assert main(["export", str(tmp_path / "c"), "--db", str(tmp_path / "empty.sqlite")]) == 2
    assert "no logged cycle" in capsys.readouterr().err
    assert not (tmp_path / "c").exists()


def _tree(d):
    return sorted(str(p.relative_to(d)) for p in d.rglob("*"))


def test_export_into_a_folder_with_other_files_refuses_and_deletes_nothing(db, tmp_path, capsys):
    """Probe (issue 13): export into a folder holding files deleted them, sub-folders too,
    and set the folder's mode to 0700."""
    out = tmp_path / "shared"
    (out / "sub").mkdir(parents=True)
    (out / "notes.txt").write_text("mine")
    (out / "sub" / "keep.txt").write_text("mine too")
    out.chmod(0o755)
    before = _tree(out)
    assert main(["export", str(out), "--db", str(db.path)]) == 2
    err = capsys.readouterr().err
    assert f"{out}: folder is not empty (notes.txt, sub/)" in err and "--force" in err
    assert _tree(out) == before and (out / "notes.txt").read_text() == "mine"
    assert out.stat().st_mode & 0o777 == 0o755
    assert [p for p in tmp_path.iterdir() if p.name.startswith(".")] == []     # no staging left
    # --force writes beside them and deletes nothing
    assert main(["export", str(out), "--db", str(db.path), "--force"]) == 0
    assert set(before) <= set(_tree(out)) and (out / "sub" / "keep.txt").read_text() == "mine too"
    assert len(read_campaign(out).points["sample"]) == 33 and out.stat().st_mode & 0o777 == 0o755


def test_export_replaces_its_own_earlier_export_and_new_folders_get_the_umask_mode(db, tmp_path):
    import os
    out = tmp_path / "camp"
    assert main(["export", str(out), "--db", str(db.path)]) == 0
    mask = os.umask(0)
    os.umask(mask)
    assert out.stat().st_mode & 0o777 == 0o777 & ~mask
    assert main(["export", str(out), "--db", str(db.path)]) == 0          # its own: replaced
    assert len(read_campaign(out).points["sample"]) == 33
    (out / "extra.txt").write_text("someone else's")
    assert main(["export", str(out), "--db", str(db.path)]) == 2          # not only its own now
    assert (out / "extra.txt").exists()


def test_report_png_into_a_folder_names_the_file_it_wrote(db, tmp_path, capsys):
    """Probe: ``--png DIR`` wrote DIR.png and printed DIR."""
    folder = tmp_path / "plots"
    folder.mkdir()
    assert main(["report", "--db", str(db.path), "--png", str(folder)]) == 0
    out = capsys.readouterr().out
    assert f"plot written to {folder / 'accuracy.png'}" in out and (folder / "accuracy.png").stat().st_size > 1000
    assert main(["report", "--db", str(db.path), "--png", str(tmp_path / "trend")]) == 0
    assert f"plot written to {tmp_path / 'trend.png'}" in capsys.readouterr().out
    assert (tmp_path / "trend.png").is_file()


@pytest.mark.parametrize("command", [["report", "--png", ""], ["export", "OUT"], ["diagnose"]])
def test_a_log_damaged_past_its_first_pages_gives_a_message_and_exit_2(db, tmp_path, command, capsys):
    """Probe: a corrupt SQLite file given to report, export or diagnose ended in a raw
    traceback with exit 1. Damage in the first pages was caught at open; damage deeper in
    the file showed only when the cycles were read."""
    import hashlib
    path = db.path
    db.close()
    raw = bytearray(path.read_bytes())
    assert len(raw) >= 4 * 4096
    for page in range(2, len(raw) // 4096):                 # keep the header and schema pages
        raw[page * 4096 + 100: page * 4096 + 600] = b"\xff" * 500
    path.write_bytes(bytes(raw))
    before = hashlib.sha256(path.read_bytes()).hexdigest()
    argv = [a.replace("OUT", str(tmp_path / "out")) for a in command]
    if argv[0] == "diagnose":
        argv.append(str(path))
    else:
        argv += ["--db", str(path)]
    assert main(argv) == 2
    err = capsys.readouterr().err
    assert "cycle log: cannot read: the database is damaged" in err and "mv " in err
    assert hashlib.sha256(path.read_bytes()).hexdigest() == before       # read, never written
    assert not (tmp_path / "out").exists()
