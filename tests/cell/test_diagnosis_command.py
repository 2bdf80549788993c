"""``cellctl diagnose``: bad input (exit 2, file/line/column), JSON keys and types, the HTML
page, the cycle log as input, and ``validate`` on a few trials."""
import argparse
import csv
import json
import shutil
import sys

import numpy as np
import pytest

from cell import cli
from cell import effects as fx
from cell.commands import diagnose as cmd
from cell.cyclelog import CycleLog, CycleRecord
from cell.errors import CellError
from cell.measurements import write_campaign
from cell.sim.campaigns import Design, make_campaign


def cellctl(argv: list[str]) -> int:
    """``cellctl`` as the CLI runs it (cell.cli.main once the command is listed there)."""
    if "cell.commands.diagnose" in cli.COMMAND_MODULES:
        return cli.main(argv)
    parser = argparse.ArgumentParser(prog="cellctl")
    cmd.register(parser.add_subparsers(dest="command", required=True))
    args = parser.parse_args(argv)
    try:
        return int(args.func(args) or 0)
    except CellError as exc:   # what cell.cli.main does
        print(f"cellctl {args.command}: error: {exc}", file=sys.stderr)
        return 2


@pytest.fixture(scope="module")
def campaign_dir(tmp_path_factory):
    truth = fx.make_effect("backlash", ("j2",), {"j2_backlash_deg": 0.04})
    c = make_campaign([truth], 21, Design(n_points=100, n_moves=3))
    return write_campaign(c, tmp_path_factory.mktemp("c") / "camp")


def copy(src, tmp_path):
    return shutil.copytree(src, tmp_path / "bad")


def edit(path, line: int, col: str, value: str):
    """Set column ``col`` of 1-based ``line`` of a CSV to ``value``."""
    rows = path.read_text().splitlines()
    header = rows[0].split(",")
    cells = rows[line - 1].split(",")
    cells[header.index(col)] = value
    rows[line - 1] = ",".join(cells)
    path.write_text("\n".join(rows) + "\n")


# ------------------------------------------------------------------ bad input
def test_bad_number_names_file_line_and_column(campaign_dir, tmp_path, capsys):
    d = copy(campaign_dir, tmp_path)
    edit(d / "points.csv", 7, "x_mm", "12.x")
    assert cellctl(["diagnose", str(d)]) == 2
    err = capsys.readouterr().err
    assert "points.csv, line 7, column 'x_mm'" in err and "not a number" in err


def test_missing_column_and_missing_model(campaign_dir, tmp_path, capsys):
    d = copy(campaign_dir, tmp_path)
    rows = (d / "paths.csv").read_text().splitlines()
    (d / "paths.csv").write_text("\n".join(r.split(",", 1)[1] for r in rows) + "\n")  # drop 'move'
    assert cellctl(["diagnose", str(d)]) == 2
    assert "paths.csv, line 1, column 'move': missing required column" in capsys.readouterr().err
    (d / "model.yaml").unlink()
    assert cellctl(["diagnose", str(d)]) == 2
    assert "model.yaml: missing" in capsys.readouterr().err


def test_time_going_backwards_in_a_move(campaign_dir, tmp_path, capsys):
    d = copy(campaign_dir, tmp_path)
    edit(d / "paths.csv", 10, "time_s", "0.0")
    assert cellctl(["diagnose", str(d), "--json"]) == 2
    out = capsys.readouterr()
    assert out.out == ""                                         # nothing half-reported
    assert "paths.csv, line 10, column 'time_s'" in out.err and "does not increase" in out.err


def test_load_takes_the_readers_row_lines_blank_lines_skipped(campaign_dir, tmp_path):
    # the lines error messages cite: the reader's, equal to a second reading of the CSV
    d = copy(campaign_dir, tmp_path)
    for name in ("points.csv", "paths.csv"):
        rows = (d / name).read_text().splitlines()
        (d / name).write_text("\n".join(rows[:3] + ["", " , "] + rows[3:8] + [""] + rows[8:]) + "\n")
    c, lines = cmd.load(str(d))
    for table in ("points", "paths"):
        rows = csv.reader((d / f"{table}.csv").read_text().splitlines())
        assert lines[table] == [i for i, row in enumerate(rows, start=1)
                                if i > 1 and any(c.strip() for c in row)]
        assert lines[table][:4] == [2, 3, 6, 7] and len(lines[table]) == len(getattr(c, table)["x_mm"])
    (d / "paths.csv").unlink()
    assert cmd.load(str(d))[1]["paths"] is None


def test_the_collector_is_as_it_was_after_a_diagnosis(campaign_dir, capsys):
    # the cyclic collector is paused for one diagnosis and left as the caller had it
    import gc
    assert gc.isenabled()
    assert cellctl(["diagnose", str(campaign_dir), "--json"]) == 0
    assert gc.isenabled()
    gc.disable()
    try:
        assert cellctl(["diagnose", str(campaign_dir), "--json"]) == 0
        assert not gc.isenabled()
    finally:
        gc.enable()
    first, second = capsys.readouterr().out.split("\n}\n", 1)
    assert first + "\n}\n" == second


def test_move_split_across_fit_and_holdout(campaign_dir, tmp_path, capsys):
    d = copy(campaign_dir, tmp_path)
    lines = (d / "paths.csv").read_text().splitlines()
    first = "holdout" if lines[1].endswith("fit") else "fit"
    edit(d / "paths.csv", 5, "split", first)
    assert cellctl(["diagnose", str(d)]) == 2
    assert "paths.csv, line 5, column 'split'" in capsys.readouterr().err


def test_no_holdout_rows(campaign_dir, tmp_path, capsys):
    d = copy(campaign_dir, tmp_path)
    for f in ("points.csv", "paths.csv"):
        p = d / f
        p.write_text(p.read_text().replace(",holdout", ",fit"))
    assert cellctl(["diagnose", str(d)]) == 2
    assert "points.csv, column 'split'" in capsys.readouterr().err


def test_not_a_campaign_and_not_found(tmp_path, capsys):
    junk = tmp_path / "junk.txt"
    junk.write_text("hello")
    assert cellctl(["diagnose", str(junk)]) == 2
    assert "neither a campaign directory nor an SQLite cycle log" in capsys.readouterr().err
    assert cellctl(["diagnose", str(tmp_path / "nowhere")]) == 2
    assert "not found" in capsys.readouterr().err


def test_bad_options(campaign_dir, capsys):
    assert cellctl(["diagnose", str(campaign_dir), "--trials", "3"]) == 2
    assert "only with 'cellctl diagnose validate'" in capsys.readouterr().err
    assert cellctl(["diagnose", str(campaign_dir), "--noise-mm", "-1"]) == 2
    assert "--noise-mm -1.0 must be a positive number" in capsys.readouterr().err
    assert cellctl(["diagnose", "validate", "--html", "x"]) == 2
    assert "--html: not with 'validate'" in capsys.readouterr().err


# ------------------------------------------------------------------ output
def test_json_has_the_spec_keys_and_types(campaign_dir, capsys):
    assert cellctl(["diagnose", str(campaign_dir), "--json"]) == 0
    rep = json.loads(capsys.readouterr().out)
    assert rep["format"] == "cell-diagnosis/1"
    g = rep["gap"]
    assert isinstance(g["rms_mm"], float) and isinstance(g["max_mm"], float)
    assert isinstance(g["n"], int) and g["max_mm"] >= g["rms_mm"] > 0
    w = g["where"]
    assert w["subsystem"] in ("none", "kinematics", "transmission", "thermal", "vision", "comms")
    assert w["depends_on"] in ("constant", "angle", "direction", "time", "temperature",
                               "position", "speed")
    assert isinstance(w["joints"], list) and isinstance(w["summary"], str) and w["summary"]
    assert (w["subsystem"], w["joints"], w["depends_on"]) == ("transmission", ["j2"], "direction")
    assert rep["ranking"] and all(
        isinstance(r["effect"], str) and isinstance(r["joints"], list)
        and isinstance(r["params"], dict) and isinstance(r["holdout_rms_mm"], float)
        and isinstance(r["score"], float) for r in rep["ranking"])
    vocab = set(fx.EFFECTS) | {"none"}
    assert {r["effect"] for r in rep["ranking"]} <= vocab
    c = rep["cause"]
    assert c["effect"] == "backlash" and c["joints"] == ["j2"]
    assert set(c["params"]) == set(c["ci95"]) == {"j2_backlash_deg"}
    lo, hi = c["ci95"]["j2_backlash_deg"]
    assert lo < c["params"]["j2_backlash_deg"] < hi
    h = rep["holdout"]
    assert isinstance(h["n"], int) and h["n"] > 0
    assert h["shrink"] == pytest.approx(1 - h["rms_after_mm"] / h["rms_before_mm"], abs=1e-3)
    assert rep["unexplained"] is False


def test_text_report_is_readable(campaign_dir, capsys):
    assert cellctl(["diagnose", str(campaign_dir)]) == 0
    out = capsys.readouterr().out
    assert "cause: backlash on j2 (transmission)" in out
    assert "| rank | candidate |" in out and "holdout (" in out and "shrink" in out


def test_html_page_with_plots(campaign_dir, tmp_path, capsys):
    out = tmp_path / "page"
    assert cellctl(["diagnose", str(campaign_dir), "--html", str(out)]) == 0
    html = (out / "index.html").read_text()
    for png in ("poses.png", "residuals.png", "joints.png", "paths.png"):
        assert (out / png).stat().st_size > 5000
        assert f'src="{png}"' in html
    assert json.loads((out / "report.json").read_text())["cause"]["effect"] == "backlash"
    assert "HTML report written" in capsys.readouterr().out


def test_cycle_log_is_diagnosed(tmp_path, capsys):
    """The cell's own SQLite log: moves of logged cycles become static points."""
    rng = np.random.default_rng(5)
    log = CycleLog(tmp_path / "cell.sqlite")
    # a plant with a joint offset on j1; each cycle: 4 arrivals near a target
    truth = fx.make_effect("joint_offset", ("j1",), {"j1_offset_deg": 0.08})
    from cell.kinematics import Scara
    robot = Scara.preset("seed000")
    for i in range(30):
        q0 = np.array([rng.uniform(-120, 120), rng.uniform(30, 130)])
        trace = []
        for k in range(4):
            q = q0 + rng.normal(0, 0.5, 2)
            xy = fx.simulate_points(robot.g, [truth], q[None], [[1, 1]])[0] + rng.normal(0, 0.005, 2)
            trace.append({"joints_deg": q.tolist(), "point_mm": xy.tolist(), "error_mm": 0.1,
                          "moved": True})
        log.add_cycle(CycleRecord(part_id=i, recipe="r", recipe_hash="h", status="done",
                                  started_at=f"2026-11-23T10:{i:02d}:00+00:00",
                                  finished_at=f"2026-11-23T10:{i:02d}:30+00:00", cycle_time_s=30.0,
                                  temp_c=21.0, trace=trace))
    log.close()
    assert cellctl(["diagnose", str(tmp_path / "cell.sqlite"), "--json"]) == 0
    rep = json.loads(capsys.readouterr().out)
    assert rep["gap"]["n"] == 120
    assert rep["cause"]["effect"] == "joint_offset" and rep["cause"]["joints"] == ["j1"]
    assert "thermal_expansion_per_k" in rep["not_identifiable"]    # one temperature throughout
    empty = tmp_path / "empty.sqlite"
    CycleLog(empty).close()
    assert cellctl(["diagnose", str(empty)]) == 2
    assert "no logged cycle" in capsys.readouterr().err


def test_validate_runs_a_few_trials(capsys):
    assert cellctl(["diagnose", "validate", "--trials", "3", "--seed", "4", "--points", "60"]) == 0
    out = capsys.readouterr().out
    assert "Confusion matrix" in out and "| true \\ answer |" in out
    assert "| 3 |" in out                                       # the trials column
    assert cellctl(["diagnose", "validate", "--trials", "0"]) == 2
    assert "--trials 0 must be ≥ 1" in capsys.readouterr().err


def test_validate_outside_the_vocabulary_option(capsys):
    assert cellctl(["diagnose", "validate", "--trials", "2", "--seed", "3", "--points", "60",
                    "--out-of-vocabulary", "1", "--oov-kinds", "joint_coupling"]) == 0
    out = capsys.readouterr().out
    assert "outside the vocabulary (joint_coupling)" in out
    assert "| joint coupling (outside) |" in out and "outside vocab. named as cause" in out


@pytest.mark.parametrize("argv,message", [
    (["--out-of-vocabulary", "1.5"], "--out-of-vocabulary 1.5 must be a share from 0 to 1"),
    (["--out-of-vocabulary", "nan"], "--out-of-vocabulary nan must be a share from 0 to 1"),
    (["--out-of-vocabulary", "0.5", "--oov-kinds", "lens,reach_sag"],
     "--oov-kinds 'lens,reach_sag': unknown lens; choose from radial_distortion, reach_sag"),
    (["--out-of-vocabulary", "0.5", "--oov-kinds", ","], "unknown empty"),
    (["--oov-kinds", "reach_sag"], "--oov-kinds: give --out-of-vocabulary SHARE > 0 as well"),
])
def test_validate_bad_outside_options(argv, message, capsys):
    assert cellctl(["diagnose", "validate", "--trials", "1"] + argv) == 2
    assert message in capsys.readouterr().err


def test_validate_share_that_is_not_a_number(capsys):
    with pytest.raises(SystemExit) as exc:
        cellctl(["diagnose", "validate", "--out-of-vocabulary", "half"])
    assert exc.value.code == 2
    assert "--out-of-vocabulary: invalid float value: 'half'" in capsys.readouterr().err


def test_outside_options_only_with_validate(campaign_dir, capsys):
    assert cellctl(["diagnose", str(campaign_dir), "--out-of-vocabulary", "0.2"]) == 2
    assert "--out-of-vocabulary: only with 'cellctl diagnose validate'" in capsys.readouterr().err


def test_a_planar_campaign_is_read_as_the_chain_it_is(campaign_dir, capsys):
    # the one diagnosis reads the planar campaign as a two-joint chain seen in x and y (its
    # points and its 3 moves' samples as poses) and answers in the one report's shape
    assert cellctl(["diagnose", str(campaign_dir), "--json"]) == 0
    rep = json.loads(capsys.readouterr().out)
    assert rep["chain"]["kinematics"] == "dh" and rep["chain"]["sensor_axes"] == ["x", "y"]
    assert rep["chain"]["planar"] is True
    assert rep["cause"]["effect"] == "backlash" and rep["cause"]["joints"] == ["j2"], rep["cause"]


def test_a_short_cycle_log_prints_what_it_cannot_figure(tmp_path, capsys):
    # 8 cycles at one target: one place, none to leave out, so the candidates' leave-out
    # errors are undefined (null in JSON); the text shows them as '–' instead of failing
    from cell.kinematics import Scara
    robot = Scara.preset("seed000")
    truth = fx.make_effect("joint_offset", ("j1",), {"j1_offset_deg": 0.08})
    rng = np.random.default_rng(3)
    log = CycleLog(tmp_path / "cell.sqlite")
    for i in range(8):
        q = np.array([20.0, 60.0]) + rng.uniform(-2, 2, 2)
        xy = fx.simulate_points(robot.g, [truth], q[None], [[1, 1]])[0]
        log.add_cycle(CycleRecord(part_id=i, recipe="r", recipe_hash="h", status="done",
                                  started_at=f"2026-11-23T10:{i:02d}:00+00:00",
                                  finished_at=f"2026-11-23T10:{i:02d}:30+00:00", cycle_time_s=30.0,
                                  trace=[{"joints_deg": q.tolist(), "point_mm": xy.tolist(),
                                          "error_mm": 0.3, "moved": True}]))
    log.close()
    assert cellctl(["diagnose", str(tmp_path / "cell.sqlite"), "--json"]) == 0
    rep = json.loads(capsys.readouterr().out)
    assert any(r["cv_rms_mm"] is None for r in rep["ranking"]), rep["ranking"]
    assert cellctl(["diagnose", str(tmp_path / "cell.sqlite")]) == 0
    text = capsys.readouterr().out
    assert "| – |" in text and "cause:" in text
