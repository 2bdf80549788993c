"""What a new user met on bad input (issue 21, item 5), seen as they see it: the real
``cellctl`` run as a process, its exit code, its stdout and its stderr.

Bad input is one line on stderr naming the file (with the line for YAML) and the field, in
our words, exit 2, and nothing on stdout before it.
"""
from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[2]


def cellctl(cwd: Path, *args: str) -> subprocess.CompletedProcess:
    env = dict(os.environ, PYTHONPATH=str(REPO), CELL_PROGRESS="0")
    return subprocess.run([sys.executable, "-m", "cell.cli", *args], cwd=cwd, env=env,
                          stdin=subprocess.DEVNULL, capture_output=True, text=True, timeout=110)


def refused(out: subprocess.CompletedProcess, command: str) -> str:
    """The one error line of a refused command, after ``cellctl COMMAND: error: ``."""
    assert out.returncode == 2, (out.returncode, out.stdout, out.stderr)
    assert out.stdout == "", f"printed before refusing: {out.stdout!r}"
    assert "Traceback" not in out.stderr
    lines = out.stderr.splitlines()
    assert len(lines) == 1, out.stderr
    prefix = f"cellctl {command}: error: "
    assert lines[0].startswith(prefix), lines[0]
    return lines[0][len(prefix):]


# --------------------------------------------------------------------------- calibrate-camera
GOOD_BOARD = "kind: circles\ncols: 9\nrows: 6\npitch_mm: 4.0\nradius_mm: 1.0\norigin_mm: [234.0, 920.0]\n"


@pytest.mark.parametrize("text, message", [
    (GOOD_BOARD.replace("pitch_mm", "pitch"), "board.yaml:4: pitch: unknown field; did you mean 'pitch_mm'?"),
    (GOOD_BOARD.replace("cols: 9\n", ""), "board.yaml:1: cols: required, but missing"),
    (GOOD_BOARD.replace("kind: circles\n", ""), "board.yaml:1: kind: required, but missing"),
    (GOOD_BOARD.replace("circles", "circle"),
     "board.yaml:1: kind: must be 'circles' or 'chessboard', got 'circle'; did you mean 'circles'?"),
    (GOOD_BOARD.replace("cols: 9", "cols: nine"), "board.yaml:2: cols: must be a valid integer"),
    (GOOD_BOARD.replace("rows: 6", "rows: 2"), "board.yaml:3: rows: must be an integer in [3, 100]"),
    (GOOD_BOARD.replace("radius_mm: 1.0", "radius_mm: 2.0"), "board.yaml:5: radius_mm: must be below 0.4 × pitch_mm"),
    (GOOD_BOARD.replace("[234.0, 920.0]", "[234.0]"), "board.yaml:6: origin_mm: must be [x, y] in mm"),
    (GOOD_BOARD.replace("pitch_mm: 4.0", "pitch_mm: .nan"), "board.yaml:4: pitch_mm: must be a finite number"),
    ("- 9\n- 6\n", "board.yaml:1: (top level): the board file must be a mapping of fields"),
    ("", "board.yaml:1: (top level): the board file is empty"),
    ("kind: circles\ncols: 9\nrows: 6\nrows: 7\n", "board.yaml:4: rows: key given twice"),
    (None, "board.yaml: board file not found"),
])
def test_a_bad_board_file_is_named_with_line_and_field(tmp_path, text, message):
    """A wrong key printed ``CircleGridBoard.__init__() got an unexpected keyword argument
    'pitch'``, with no line, and other mistakes Python's or PyYAML's words."""
    if text is not None:
        (tmp_path / "board.yaml").write_text(text)
    (tmp_path / "imgs").mkdir()
    out = cellctl(tmp_path, "calibrate-camera", "--board", "board.yaml", "--images", "imgs",
                  "--out", "cal.json")
    assert refused(out, "calibrate-camera").startswith(message)
    assert not (tmp_path / "cal.json").exists()


def test_the_board_in_a_cell_config_says_which_key_was_meant(tmp_path):
    """The same board, written in the cell config's ``calibration.board``."""
    (tmp_path / "cell.yaml").write_text(
        "calibration:\n  board:\n    kind: circles\n    cols: 7\n    rows: 9\n    pitch: 100\n")
    (tmp_path / "board.yaml").write_text(GOOD_BOARD)
    out = cellctl(tmp_path, "calibrate-camera", "--board", "board.yaml", "--config", "cell.yaml",
                  "--out", "cal.json")
    message = refused(out, "calibrate-camera")
    assert message.startswith("cell.yaml:") and "pitch: unknown field; did you mean 'pitch_mm'?" in message
    assert "__init__" not in message


def _board_images(folder: Path) -> None:
    import cv2

    from cell.vision.calibration import CircleGridBoard
    from cell.vision.camera_model import CameraModel
    from drivers.camera.sim import SimCamera
    board = CircleGridBoard(cols=9, rows=6, pitch_mm=4.0, radius_mm=1.0, origin_mm=(234.0, 920.0))
    cam = SimCamera(CameraModel.nadir(640, 512, 0.08, centre_mm=(250.0, 930.0)), lambda: [board], seed=3)
    cam.open()
    folder.mkdir()
    cv2.imwrite(str(folder / "board1.png"), cam.grab().image)
    cam.close()


def test_an_out_path_that_cannot_be_written_is_refused_before_the_work(tmp_path):
    """``--out`` naming a folder: the calibration ran, then ended in IsADirectoryError's
    traceback (and left a temporary file behind)."""
    _board_images(tmp_path / "imgs")
    (tmp_path / "board.yaml").write_text(GOOD_BOARD)
    (tmp_path / "calibrations").mkdir()
    out = cellctl(tmp_path, "calibrate-camera", "--board", "board.yaml", "--images", "imgs",
                  "--no-distortion", "--out", "calibrations")
    assert refused(out, "calibrate-camera").startswith("--out calibrations: is a folder")
    assert sorted(p.name for p in tmp_path.iterdir()) == ["board.yaml", "calibrations", "imgs"]
    assert list((tmp_path / "calibrations").iterdir()) == []


# --------------------------------------------------------------------------- export, report
@pytest.fixture
def log(tmp_path):
    """A cycle log of 12 done parts, each with measured moves, at ``tmp_path/cell.sqlite``."""
    from cell.cyclelog import CycleLog, CycleRecord
    trace = [{"joints_deg": [60.0, 30.0], "point_mm": [250.0, 933.0], "error_mm": 0.5, "moved": True},
             {"joints_deg": [60.1, 29.98], "point_mm": [249.9, 933.1], "error_mm": 0.03, "moved": True}]
    db = CycleLog(tmp_path / "cell.sqlite")
    for i in range(12):
        db.add_cycle(CycleRecord(
            part_id=100 + i, recipe="bracket-a", recipe_hash="h", status="done",
            started_at=f"2026-11-23T10:00:{i:02d}+00:00", finished_at=f"2026-11-23T10:00:{i:02d}+00:00",
            cycle_time_s=1.0, method="lattice", initial_error_mm=0.5, final_error_mm=0.02,
            moves=2, trace=trace))
    db.close()
    return tmp_path / "cell.sqlite"


def test_export_names_a_missing_log_once(tmp_path):
    """``cellctl export DIR --db missing`` printed ``missing: missing: no cycle log here``."""
    out = cellctl(tmp_path, "export", "camp", "--db", "missing.sqlite")
    message = refused(out, "export")
    assert message.count("missing.sqlite") == 1 and "no cycle log" in message
    assert not (tmp_path / "camp").exists()


def test_export_refuses_an_unknown_robot_preset_without_a_traceback(log, tmp_path):
    """``--robot`` was read only when the export ran: a KeyError's traceback, exit 1."""
    out = cellctl(tmp_path, "export", "camp", "--db", str(log), "--robot", "seed999")
    assert out.returncode == 2 and out.stdout == "" and "Traceback" not in out.stderr
    assert "unknown robot preset 'seed999'" in out.stderr and "seed000" in out.stderr
    assert not (tmp_path / "camp").exists()


@pytest.mark.parametrize("args, message", [
    (["--config", "missing.yaml"], "missing.yaml: cell config not found"),
    (["--config", "bad.yaml"], "bad.yaml:2: scheduler.drift_treshold_mm: unknown field; "
                               "did you mean 'drift_threshold_mm'?"),
    (["--recipes", "no-such-folder"], "--recipes no-such-folder: no such folder"),
    (["--png", "notes.txt/acc.png"], "--png notes.txt/acc.png: notes.txt is not a folder"),
    (["--png", "acc.txt"], "--png acc.txt: cannot write a .txt plot"),
])
def test_report_checks_every_input_before_printing_the_table(log, tmp_path, args, message):
    """``cellctl report --config missing.yaml`` printed the whole accuracy table, then
    refused the config; an unwritable ``--png`` ended in a traceback after the table, and
    a mistyped ``--recipes`` folder was silently ignored."""
    (tmp_path / "bad.yaml").write_text("scheduler:\n  drift_treshold_mm: 0.4\n")
    (tmp_path / "notes.txt").write_text("not a folder\n")
    png = ["--png", "acc.png"] if "--png" not in args else []
    out = cellctl(tmp_path, "report", "--db", str(log), *png, *args)
    assert refused(out, "report").startswith(message)
    assert not (tmp_path / "acc.png").exists()


def test_report_with_good_inputs_prints_the_table_and_writes_the_plot(log, tmp_path):
    (tmp_path / "cell.yaml").write_text("scheduler:\n  drift_threshold_mm: 0.4\n")
    out = cellctl(tmp_path, "report", "--db", str(log), "--config", "cell.yaml", "--png", "acc.png")
    assert out.returncode == 0, out.stderr
    assert out.stdout.startswith(f"12 cycles in {log}\n") and "| 1–10 | 100 |" in out.stdout
    assert out.stdout.endswith("plot written to acc.png\n") and (tmp_path / "acc.png").stat().st_size > 1000


# --------------------------------------------------------------------------- plan line
CELL_LINE = ["plan", "line", "--from", "250,930,-20,0", "--to", "300,900,-20,0", "--points", "5"]


def test_plan_line_plans_for_the_cells_own_robot_by_default(tmp_path):
    """``plan line`` took seed 002's 200 mm arm by default, so a move between the cell's own
    part positions (near (250, 930) mm) was out of reach."""
    import json

    from cell.config import CellConfig
    out = cellctl(tmp_path, *CELL_LINE, "--json")
    assert out.returncode == 0, out.stderr
    doc = json.loads(out.stdout)
    robot = CellConfig().robot
    assert doc["robot"] == robot.scara().g.name == robot.preset and doc["elbow"] == robot.elbow
    assert len(doc["segments"]) == 5


def test_plan_line_takes_the_robot_of_a_cell_config_or_a_preset(tmp_path):
    (tmp_path / "cell.yaml").write_text(
        "robot:\n  preset: null\n  elbow: left\n  geometry:\n    name: small-arm\n"
        "    l1_mm: 300\n    l2_mm: 250\n")
    out = cellctl(tmp_path, "plan", "line", "--config", "cell.yaml", "--from", "400,100,-20,0",
                  "--to", "350,200,-20,0", "--points", "3")
    assert out.returncode == 0, out.stderr
    assert out.stdout.startswith("line small-arm (l1 = 300 mm, l2 = 250 mm, left elbow): ")
    far = cellctl(tmp_path, "plan", "line", "--config", "cell.yaml", *CELL_LINE[2:])
    assert far.returncode == 2 and "out of reach" in far.stderr and far.stdout == ""
    seed002 = cellctl(tmp_path, "plan", "line", "--robot", "seed002", "--from", "400,0,-50,0",
                      "--to", "300,0,-20,45", "--points", "3")
    assert seed002.returncode == 0, seed002.stderr
    assert seed002.stdout.startswith("line seed002 (l1 = 200 mm, l2 = 200 mm, right elbow): ")
    both = cellctl(tmp_path, "plan", "line", "--robot", "seed002", "--config", "cell.yaml", *CELL_LINE[2:])
    assert both.returncode == 2 and "not allowed with" in both.stderr


def test_plan_line_help_says_which_robot_is_the_default(tmp_path):
    from cell.config import CellConfig
    from cell.robots import PRESETS
    out = cellctl(tmp_path, "plan", "line", "--help")
    assert out.returncode == 0
    text = " ".join(out.stdout.split())
    robot = CellConfig().robot
    g = PRESETS[robot.preset]
    assert (f"The robot is the cell's own: the robot section of --config, else of the built-in "
            f"cell config (preset {robot.preset}, l1 = l2 = {g.l1_mm:g} mm") in text
    assert g.l1_mm == g.l2_mm
    assert "--robot PRESET plan for a robot preset instead of the cell's robot: seed002" in text


TIMELAW = ["plan", "timelaw", "--waypoints", "0,0;10,5;30,20", "--duration-s", "4", "--law", "quintic-poly"]


def test_plan_timelaw_names_the_plot_file_it_wrote(tmp_path):
    """``--plot trend`` (no suffix) or ``--plot FOLDER`` wrote ``trend.png`` / ``FOLDER.png``
    beside it and printed ``plot written to trend`` / ``FOLDER``: a file that is not there."""
    (tmp_path / "plots").mkdir()
    out = cellctl(tmp_path, *TIMELAW, "--plot", "plots")
    assert out.returncode == 0, out.stderr
    assert out.stdout.endswith("plot written to plots/timelaw.png\n")
    assert (tmp_path / "plots" / "timelaw.png").stat().st_size > 1000
    out = cellctl(tmp_path, *TIMELAW, "--plot", "laws")
    assert out.returncode == 0 and out.stdout.endswith("plot written to laws.png\n")
    assert sorted(p.name for p in tmp_path.iterdir()) == ["laws.png", "plots"]


def test_plan_timelaw_refuses_a_plot_format_it_cannot_write(tmp_path):
    """``--plot laws.txt`` ended in matplotlib's ValueError traceback, exit 1."""
    out = cellctl(tmp_path, *TIMELAW, "--plot", "laws.txt")
    assert refused(out, "plan").startswith("--plot laws.txt: cannot write a .txt plot; use one of")
    assert list(tmp_path.iterdir()) == []


def test_export_into_a_place_it_cannot_write_says_so(log, tmp_path):
    """``cellctl export notes.txt/camp`` (a file where a folder must be) and an export into
    a place the system refuses (/proc) ended in a FileExistsError / FileNotFoundError traceback."""
    (tmp_path / "notes.txt").write_text("a file\n")
    out = cellctl(tmp_path, "export", "notes.txt/camp", "--db", str(log))
    assert refused(out, "export") == "notes.txt/camp: notes.txt is not a folder; nothing written"
    out = cellctl(tmp_path, "export", "/proc/camp", "--db", str(log))
    assert refused(out, "export").startswith("/proc/camp: cannot write the campaign: ")
    assert [p.name for p in tmp_path.iterdir() if "camp" in p.name] == []
    assert (tmp_path / "notes.txt").read_text() == "a file\n"
